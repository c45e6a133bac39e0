//! The simulated controller's state machine: answers every command register like the xArm
//! control box, keeps state/mode/enable/error semantics, and integrates servo targets within
//! the joint limits and the 180°/s joint speed. Pure logic (no sockets, no clock): the server
//! feeds it frames and time, the world check feeds it contacts.

use std::f64::consts::PI;

use xarm::codec::{
    self, FrameError, JointTarget, MAX_FRAME_LEN, PREFIX_LEN, PROTOCOL_HEARTBEAT, PROTOCOL_MODBUS,
    Request, STATUS_ERROR, STATUS_NOT_READY, STATUS_WARNING, VERSION_LEN, WIRE_JOINTS,
};
use xarm::codes::{ControllerError, ControllerWarning};
use xarm::limits::{LIMIT_SLACK_RAD, XARM5_JOINT_LIMITS_RAD};
use xarm::report::{ArmReport, ReportKind};

/// The joint speed limit the simulator enforces (rad/s): 180°/s.
pub const MAX_JOINT_SPEED_RAD_S: f64 = PI;
/// How long the state stays 1 (moving) after a servo command (s).
pub const MOVING_HOLD_S: f64 = 0.1;
/// Version string the simulator reports (an xArm5, firmware 2.6.0).
pub const SIM_VERSION: &str = "5,5,XF1302,AC1302,v2.6.0";

/// Counters the simulator keeps for its summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ControllerCounters {
    /// Command frames answered.
    pub frames: u64,
    /// Frames that could not be parsed (bad length, unknown register, bad payload).
    pub bad_frames: u64,
    /// Servo_j targets accepted.
    pub servo_accepted: u64,
    /// Servo_j targets rejected (not ready, error, out of range).
    pub servo_rejected: u64,
    /// Collisions raised.
    pub collisions: u64,
    /// Emergency/explicit stops (`SET_STATE(4)`).
    pub stops: u64,
}

/// The controller's state.
#[derive(Debug, Clone)]
pub struct Controller {
    state: u8,
    mode: u8,
    enable_bits: u8,
    error: u8,
    warn: u8,
    q_rad: [f64; 5],
    target_rad: [f64; 5],
    dq_rad_s: [f64; 5],
    speed_limit_rad_s: f64,
    moving_until_s: f64,
    now_s: f64,
    tcp_pose: [f32; 6],
    counters: ControllerCounters,
    feedback_type: u8,
    joint_jerk: f32,
    joint_acc: f32,
    tcp_jerk: f32,
    tcp_acc: f32,
}

impl Default for Controller {
    fn default() -> Self {
        Self::new([0.0; 5])
    }
}

fn within_limits(q: &[f32; WIRE_JOINTS]) -> bool {
    q.iter().zip(XARM5_JOINT_LIMITS_RAD).all(|(v, [lo, hi])| {
        let v = f64::from(*v);
        v.is_finite() && v >= lo - LIMIT_SLACK_RAD && v <= hi + LIMIT_SLACK_RAD
    }) && q[5..].iter().all(|v| v.is_finite())
}

impl Controller {
    /// A powered-on controller with the arm at `q_rad`: servos disabled, state 4, mode 0.
    pub fn new(q_rad: [f64; 5]) -> Self {
        Self {
            state: 4,
            mode: 0,
            enable_bits: 0,
            error: 0,
            warn: 0,
            q_rad,
            target_rad: q_rad,
            dq_rad_s: [0.0; 5],
            speed_limit_rad_s: MAX_JOINT_SPEED_RAD_S,
            moving_until_s: 0.0,
            now_s: 0.0,
            tcp_pose: [0.0; 6],
            counters: ControllerCounters::default(),
            feedback_type: 0,
            joint_jerk: 1000.0,
            joint_acc: 20.0,
            tcp_jerk: 10_000.0,
            tcp_acc: 50_000.0,
        }
    }

    /// Current state (1 moving, 2 ready, 3 paused, 4 stopped).
    pub fn state(&self) -> u8 {
        self.state
    }

    /// Current mode.
    pub fn mode(&self) -> u8 {
        self.mode
    }

    /// Current error code.
    pub fn error(&self) -> ControllerError {
        ControllerError::from(self.error)
    }

    /// Current warning code.
    pub fn warning(&self) -> ControllerWarning {
        ControllerWarning::from(self.warn)
    }

    /// Actual joints (rad).
    pub fn q_rad(&self) -> [f64; 5] {
        self.q_rad
    }

    /// Commanded target (rad).
    pub fn target_rad(&self) -> [f64; 5] {
        self.target_rad
    }

    /// Counters for the summary.
    pub fn counters(&self) -> ControllerCounters {
        self.counters
    }

    /// Sets the TCP pose the reports and `GET_TCP_POSE` give (mm, rad), from the world's FK.
    pub fn set_tcp_pose(&mut self, pose: [f32; 6]) {
        self.tcp_pose = pose;
    }

    fn all_enabled(&self) -> bool {
        self.enable_bits & 0x1F == 0x1F
    }

    /// Whether servo/motion commands are executed now.
    pub fn can_move(&self) -> bool {
        self.all_enabled() && self.error == 0 && matches!(self.state, 1 | 2)
    }

    /// The status byte of a reply.
    pub fn status(&self) -> u8 {
        let mut s = 0;
        if self.error != 0 {
            s |= STATUS_ERROR;
        }
        if self.warn != 0 {
            s |= STATUS_WARNING;
        }
        if matches!(self.state, 4 | 5) || !self.all_enabled() || self.error != 0 {
            s |= STATUS_NOT_READY;
        }
        s
    }

    fn hold(&mut self) {
        self.target_rad = self.q_rad;
        self.dq_rad_s = [0.0; 5];
    }

    fn system_reset(&mut self) {
        self.hold();
        self.state = 4;
    }

    /// Raises a controller error the way the arm does on a collision: error code set,
    /// motion stopped, state 4.
    pub fn raise_error(&mut self, code: ControllerError) {
        self.error = u8::from(code);
        if code.is_collision() {
            self.counters.collisions += 1;
        }
        self.system_reset();
    }

    /// Advances time to `now_s`: moves toward the target at no more than the joint speed
    /// limit, and updates the state (1 while a servo command is recent, then 2).
    pub fn step(&mut self, now_s: f64) {
        let dt = (now_s - self.now_s).clamp(0.0, 0.1);
        self.now_s = now_s;
        if !self.can_move() {
            self.dq_rad_s = [0.0; 5];
            return;
        }
        let max_step = self.speed_limit_rad_s * dt;
        for i in 0..5 {
            let d = (self.target_rad[i] - self.q_rad[i]).clamp(-max_step, max_step);
            self.q_rad[i] += d;
            self.dq_rad_s[i] = if dt > 0.0 { d / dt } else { 0.0 };
        }
        let at_target = self
            .q_rad
            .iter()
            .zip(self.target_rad)
            .all(|(q, t)| (q - t).abs() < 1e-9);
        self.state = if now_s < self.moving_until_s || !at_target {
            1
        } else {
            2
        };
    }

    fn servo(&mut self, t: &JointTarget, speed_limited: bool) -> bool {
        if !self.can_move() || self.mode != 1 && !speed_limited {
            self.counters.servo_rejected += 1;
            return false;
        }
        if !within_limits(&t.joints_rad) {
            self.warn = u8::from(ControllerWarning::BadParameter);
            self.counters.servo_rejected += 1;
            return false;
        }
        for (dst, src) in self.target_rad.iter_mut().zip(t.joints_rad) {
            *dst = f64::from(src);
        }
        self.speed_limit_rad_s =
            if speed_limited && t.speed_rad_s.is_finite() && t.speed_rad_s > 0.0 {
                f64::from(t.speed_rad_s).min(MAX_JOINT_SPEED_RAD_S)
            } else {
                MAX_JOINT_SPEED_RAD_S
            };
        self.counters.servo_accepted += 1;
        self.moving_until_s = self.now_s + MOVING_HOLD_S;
        self.state = 1;
        true
    }

    /// Answers one request frame (whole frame, as [`codec::frame_len`] delimited it) into
    /// `out`. Returns the reply length, or `Ok(0)` for frames the controller does not answer
    /// (the SDK's heartbeat).
    ///
    /// # Errors
    /// [`FrameError`] for frames that cannot be parsed; the caller decides whether to close
    /// the connection. Unknown registers are answered (status byte with the "invalid" bit),
    /// not errors.
    pub fn handle(
        &mut self,
        frame: &[u8],
        out: &mut [u8; MAX_FRAME_LEN],
    ) -> Result<usize, FrameError> {
        if frame.len() > PREFIX_LEN {
            let protocol = u16::from_be_bytes([frame[2], frame[3]]);
            if protocol == PROTOCOL_HEARTBEAT {
                return Ok(0);
            }
            if protocol == PROTOCOL_MODBUS && frame.len() >= PREFIX_LEN + 2 {
                // Standard Modbus: answer "illegal function".
                self.counters.frames += 1;
                let tid = u16::from_be_bytes([frame[0], frame[1]]);
                let n = codec::encode_response(tid, 0, frame[6], frame[7] | 0x80, &[1], out)
                    .map_err(|_| FrameError::LengthTooLarge { length: 0 })?;
                return Ok(n);
            }
        }
        let (h, req) = match Request::decode(frame) {
            Ok(v) => v,
            Err(FrameError::UnknownRegister(reg)) if frame.len() > PREFIX_LEN => {
                self.counters.frames += 1;
                self.counters.bad_frames += 1;
                let tid = u16::from_be_bytes([frame[0], frame[1]]);
                let protocol = u16::from_be_bytes([frame[2], frame[3]]);
                let status = self.status() | codec::STATUS_INVALID;
                return codec::encode_response(tid, protocol, reg, status, &[], out)
                    .map_err(|_| FrameError::UnknownRegister(reg));
            }
            Err(e) => {
                self.counters.bad_frames += 1;
                return Err(e);
            }
        };
        self.counters.frames += 1;
        let mut data = [0u8; 84];
        let n = self.execute(req, &mut data);
        let status = self.status();
        codec::encode_response(
            h.tid,
            h.protocol,
            u8::from(req.register()),
            status,
            &data[..n],
            out,
        )
        .map_err(|_| FrameError::LengthTooLarge { length: h.length })
    }

    /// Carries out one decoded request; writes the reply's data and returns its length.
    fn execute(&mut self, req: Request, data: &mut [u8; 84]) -> usize {
        let mut n = 0usize;
        match req {
            Request::GetVersion => {
                let v = SIM_VERSION.as_bytes();
                data[..v.len()].copy_from_slice(v);
                n = VERSION_LEN;
            }
            Request::GetRobotSn => {
                data[..13].copy_from_slice(b"XF1302\0AC1302");
                n = VERSION_LEN;
            }
            Request::MotionEnable { servo_id, enable } => {
                let mask = match servo_id {
                    8 => 0x1F,
                    1..=5 => 1 << (servo_id - 1),
                    _ => 0,
                };
                if enable {
                    self.enable_bits |= mask;
                } else {
                    self.enable_bits &= !mask;
                }
                self.system_reset();
            }
            Request::SetState(s) => self.set_state(s),
            Request::GetState => {
                data[0] = self.state;
                n = 1;
            }
            Request::GetCmdNum => n = 2,
            Request::GetError => {
                data[0] = self.error;
                data[1] = self.warn;
                n = 2;
            }
            Request::CleanError => {
                if self.error != 0 {
                    self.error = 0;
                    self.system_reset();
                }
            }
            Request::CleanWarn => self.warn = 0,
            Request::SetMode { mode, .. } => {
                if mode <= 11 {
                    self.mode = mode;
                    self.system_reset();
                } else {
                    self.warn = u8::from(ControllerWarning::BadParameter);
                }
            }
            Request::ServoJ(t) => {
                self.servo(&t, false);
            }
            Request::MoveJoint(t) => {
                if self.mode == 0 {
                    self.servo(&t, true);
                } else {
                    self.counters.servo_rejected += 1;
                }
                n = 2;
            }
            Request::ServoCart { .. } => {
                // Cartesian servoing is not simulated: refuse like a controller that cannot
                // solve it.
                self.warn = u8::from(ControllerWarning::NoSolution);
            }
            Request::SetTcpJerk(v) => self.tcp_jerk = v,
            Request::SetTcpMaxAcc(v) => self.tcp_acc = v,
            Request::SetJointJerk(v) => self.joint_jerk = v,
            Request::SetJointMaxAcc(v) => self.joint_acc = v,
            Request::GetTcpPose | Request::GetTcpPoseAa => {
                for (i, v) in self.tcp_pose.iter().enumerate() {
                    data[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
                }
                n = 24;
            }
            Request::GetJointPos(k) => n = self.write_joints(k, data),
            Request::SetFeedbackType(t) => self.feedback_type = t,
            Request::FeedbackCheck => {}
        }
        n
    }

    /// `SET_STATE`: 0 starts motion (when enabled and error-free), 3 pauses, 4 and 6 stop.
    fn set_state(&mut self, s: u8) {
        match s {
            0 => {
                if self.all_enabled() && self.error == 0 {
                    self.hold();
                    self.state = 2;
                }
            }
            3 => {
                self.hold();
                if self.state != 4 {
                    self.state = 3;
                }
            }
            4 | 6 => {
                self.counters.stops += 1;
                self.system_reset();
            }
            _ => self.warn = u8::from(ControllerWarning::BadParameter),
        }
    }

    /// `GET_JOINT_POS` with `k` ∈ 1..=3 blocks (positions, velocities, efforts).
    fn write_joints(&self, k: Option<u8>, data: &mut [u8; 84]) -> usize {
        let k = usize::from(k.unwrap_or(1).clamp(1, 3));
        for i in 0..5 {
            let mut v = [self.q_rad[i] as f32, self.dq_rad_s[i] as f32, 0.0];
            if k == 1 {
                v[1] = 0.0;
            }
            for (j, x) in v.iter().take(k).enumerate() {
                let at = 4 * (j * WIRE_JOINTS + i);
                data[at..at + 4].copy_from_slice(&x.to_le_bytes());
            }
        }
        4 * WIRE_JOINTS * k
    }

    /// A report of `kind` describing the current state.
    pub fn report(&self, kind: ReportKind, timestamp_us: u64) -> ArmReport {
        let mut r = ArmReport::empty(kind);
        r.state = self.state;
        r.mode = self.mode;
        for i in 0..5 {
            r.joints_rad[i] = self.q_rad[i] as f32;
            r.target_joints_rad[i] = self.target_rad[i] as f32;
        }
        r.tcp_pose = self.tcp_pose;
        r.timestamp_us = timestamp_us;
        if matches!(kind, ReportKind::Normal | ReportKind::Rich) {
            r.error_code = Some(self.error);
            r.warn_code = Some(self.warn);
            r.enable_bits = Some(self.enable_bits & 0x1F);
            r.brake_bits = Some(self.enable_bits & 0x1F);
        }
        r
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use xarm::codec::Response;

    /// A controller taken through enable, mode 1 and state 0 (transactions 1–3), as the
    /// SDK does before streaming servo_j.
    fn servo_ready() -> Controller {
        let mut c = Controller::default();
        ask(
            &mut c,
            Request::MotionEnable {
                servo_id: 8,
                enable: true,
            },
            1,
        );
        ask(
            &mut c,
            Request::SetMode {
                mode: 1,
                detection: Some(0),
            },
            2,
        );
        ask(&mut c, Request::SetState(0), 3);
        c
    }

    fn ask(c: &mut Controller, req: Request, tid: u16) -> (u8, Vec<u8>) {
        let mut buf = [0u8; 64];
        let n = req.encode(tid, 3, &mut buf).unwrap();
        let mut out = [0u8; MAX_FRAME_LEN];
        let m = c.handle(&buf[..n], &mut out).unwrap();
        let r = Response::parse(&out[..m]).unwrap();
        r.check(tid, 3, u8::from(req.register())).unwrap();
        (r.status, r.data.to_vec())
    }

    #[test]
    fn servo_j_is_refused_until_enabled_mode_1_and_state_0() {
        let mut c = Controller::default();
        let target = Request::ServoJ(JointTarget::xarm5(&[0.1, 0.0, 0.0, 0.0, 0.0]));
        let (s, _) = ask(&mut c, target, 1);
        assert_ne!(s & STATUS_NOT_READY, 0);
        ask(
            &mut c,
            Request::MotionEnable {
                servo_id: 8,
                enable: true,
            },
            2,
        );
        ask(
            &mut c,
            Request::SetMode {
                mode: 1,
                detection: Some(0),
            },
            3,
        );
        let (s, _) = ask(&mut c, target, 4);
        assert_ne!(s & STATUS_NOT_READY, 0, "still state 4");
        let (s, _) = ask(&mut c, Request::SetState(0), 5);
        assert_eq!(s, 0);
        assert_eq!(ask(&mut c, Request::GetState, 6).1, vec![2]);
        let (s, _) = ask(&mut c, target, 7);
        assert_eq!(s, 0);
        assert_eq!(c.counters().servo_accepted, 1);
        assert_eq!(c.counters().servo_rejected, 2);
        // 180°/s: after 10 ms the joint has moved at most π/100 rad.
        c.step(0.01);
        assert!((c.q_rad()[0] - PI / 100.0).abs() < 1e-9);
        c.step(0.2);
        assert!((c.q_rad()[0] - 0.1).abs() < 1e-6);
        let (_, d) = ask(&mut c, Request::GetJointPos(None), 8);
        assert_eq!(d.len(), 28);
        assert!((f32::from_le_bytes([d[0], d[1], d[2], d[3]]) - 0.1).abs() < 1e-6);
    }

    #[test]
    fn collision_sets_error_31_stops_and_needs_clearing() {
        let mut c = servo_ready();
        ask(
            &mut c,
            Request::ServoJ(JointTarget::xarm5(&[1.0, 0.0, 0.0, 0.0, 0.0])),
            4,
        );
        c.step(0.05);
        c.raise_error(ControllerError::Collision);
        let q = c.q_rad();
        c.step(0.2);
        assert_eq!(c.q_rad(), q, "the arm stopped");
        assert_eq!(c.state(), 4);
        let (s, d) = ask(&mut c, Request::GetError, 5);
        assert_eq!(d, vec![31, 0]);
        assert_eq!(
            s & (STATUS_ERROR | STATUS_NOT_READY),
            STATUS_ERROR | STATUS_NOT_READY
        );
        ask(&mut c, Request::SetState(0), 6);
        assert_eq!(c.state(), 4, "cannot start with an error");
        ask(&mut c, Request::CleanError, 7);
        ask(&mut c, Request::SetState(0), 8);
        assert_eq!(c.state(), 2);
        assert_eq!(c.counters().collisions, 1);
    }

    #[test]
    fn out_of_range_targets_do_not_move_and_unknown_registers_are_answered() {
        let mut c = servo_ready();
        let (s, _) = ask(
            &mut c,
            Request::ServoJ(JointTarget::xarm5(&[0.0, -2.5, 0.0, 0.0, 0.0])),
            4,
        );
        assert_ne!(s & STATUS_WARNING, 0);
        c.step(0.1);
        assert_eq!(c.q_rad(), [0.0; 5]);
        let mut out = [0u8; MAX_FRAME_LEN];
        let n = c.handle(&[0, 9, 0, 3, 0, 1, 0x77], &mut out).unwrap();
        let r = Response::parse(&out[..n]).unwrap();
        assert_eq!(
            (r.register, r.status & codec::STATUS_INVALID),
            (0x77, codec::STATUS_INVALID)
        );
        assert_eq!(
            c.handle(&[0, 0, 0, 1, 0, 2, 0, 0], &mut out),
            Ok(0),
            "heartbeat"
        );
        assert!(c.handle(&[0, 9, 0, 3, 0, 3, 0x0b, 8], &mut out).is_err());
    }
}
