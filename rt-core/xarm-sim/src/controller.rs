//! The simulated controller's state machine: answers every command register like the xArm
//! control box, keeps state/mode/enable/error semantics, integrates servo targets within
//! the joint limits and the 180°/s joint speed, and raises the protective faults the real
//! controller raises in servo mode when a `servo_j` target would move the arm too fast
//! (see [`ProtectiveLimits`]). Pure logic (no sockets, no clock): the server feeds it frames
//! and time, the world check feeds it contacts.
//!
//! Given the run's secret ([`Controller::set_sim_secret`]), it answers Foresight's identity
//! challenge (register 0xF0, [`xarm::sim_identity`]) with its proof; without one it answers
//! that register as every register it does not have (status bit 0x08, no data), as a real
//! controller is expected to — and is then treated as a real arm.

use std::f64::consts::PI;

use xarm::codec::{
    self, FrameError, JointTarget, MAX_FRAME_LEN, PREFIX_LEN, PROTOCOL_HEARTBEAT, PROTOCOL_MODBUS,
    Request, STATUS_ERROR, STATUS_NOT_READY, STATUS_WARNING, VERSION_LEN, WIRE_JOINTS,
};
use xarm::codes::{ControllerError, ControllerWarning};
use xarm::limits::{LIMIT_SLACK_RAD, XARM5_JOINT_LIMITS_RAD};
use xarm::report::{ArmReport, ReportKind};
use xarm::sim_identity::{NONCE_LEN, SimSecret};

use twin::RobotModel;

/// The joint speed limit the simulator enforces (rad/s): 180°/s.
pub const MAX_JOINT_SPEED_RAD_S: f64 = PI;
/// How long the state stays 1 (moving) after a servo command (s).
pub const MOVING_HOLD_S: f64 = 0.1;
/// Version string the simulator reports (an xArm5, firmware 2.6.0).
pub const SIM_VERSION: &str = "5,5,XF1302,AC1302,v2.6.0";
/// Default TCP speed limit of the servo-mode protective check (m/s).
pub const MAX_TCP_SPEED_M_S: f64 = 1.0;
/// Default servo period the protective check assumes between two `servo_j` targets (s):
/// the 250 Hz stream the controller expects.
pub const SERVO_PERIOD_S: f64 = 0.004;
/// Default relative slack of the protective check (0.25 = 25 % above the limits).
pub const FAULT_TOLERANCE: f64 = 0.25;

/// The controller's protective check in servo mode (mode 1): every accepted `servo_j` target
/// is executed within one servo period, so a target further from the commanded position than
/// the speed limits allow in one period is refused with an error, like the real control box
/// does. On by default.
///
/// A joint faults when `|target − commanded| > max_joint_speed_rad_s × servo_period_s ×
/// (1 + tolerance)`; the TCP (forward kinematics of the robot model) faults when it would
/// move more than `max_tcp_speed_m_s × servo_period_s × (1 + tolerance)`. With the defaults:
/// 0.0157 rad and 5 mm per target.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ProtectiveLimits {
    /// Whether the check runs at all.
    pub enabled: bool,
    /// Joint speed limit (rad/s); default π (the xArm's 180°/s).
    pub max_joint_speed_rad_s: f64,
    /// TCP linear speed limit (m/s); default 1.0.
    pub max_tcp_speed_m_s: f64,
    /// The period one `servo_j` target is executed in (s); default 0.004.
    pub servo_period_s: f64,
    /// Relative slack above the limits (≥ 0); default 0.25.
    pub tolerance: f64,
}

impl Default for ProtectiveLimits {
    fn default() -> Self {
        Self {
            enabled: true,
            max_joint_speed_rad_s: MAX_JOINT_SPEED_RAD_S,
            max_tcp_speed_m_s: MAX_TCP_SPEED_M_S,
            servo_period_s: SERVO_PERIOD_S,
            tolerance: FAULT_TOLERANCE,
        }
    }
}

/// A [`ProtectiveLimits`] field that is out of range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("protective limit {field} must be {expected}, got {value}")]
pub struct ProtectiveLimitsError {
    /// The field's name.
    pub field: &'static str,
    /// What it must be ("positive and finite", "finite and ≥ 0").
    pub expected: &'static str,
    /// The value given.
    pub value: f64,
}

impl ProtectiveLimits {
    /// The defaults with the check switched off.
    pub fn off() -> Self {
        Self {
            enabled: false,
            ..Self::default()
        }
    }

    /// Largest joint step one target may make (rad).
    pub fn max_joint_step_rad(&self) -> f64 {
        self.max_joint_speed_rad_s * self.servo_period_s * (1.0 + self.tolerance)
    }

    /// Largest TCP step one target may make (m).
    pub fn max_tcp_step_m(&self) -> f64 {
        self.max_tcp_speed_m_s * self.servo_period_s * (1.0 + self.tolerance)
    }

    /// Checks that the speeds and the period are positive and finite and the tolerance is
    /// finite and not negative (also when the check is off).
    ///
    /// # Errors
    /// [`ProtectiveLimitsError`] naming the first bad field.
    pub fn validate(&self) -> Result<(), ProtectiveLimitsError> {
        let positive = [
            ("max_joint_speed_rad_s", self.max_joint_speed_rad_s),
            ("max_tcp_speed_m_s", self.max_tcp_speed_m_s),
            ("servo_period_s", self.servo_period_s),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(ProtectiveLimitsError {
                    field,
                    expected: "positive and finite",
                    value,
                });
            }
        }
        // The controller's servo period: 0.1 ms … 1 s (a subnormal "positive" period would
        // turn every target into a fault).
        if !(1e-4..=1.0).contains(&self.servo_period_s) {
            return Err(ProtectiveLimitsError {
                field: "servo_period_s",
                expected: "between 0.0001 and 1 s",
                value: self.servo_period_s,
            });
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(ProtectiveLimitsError {
                field: "tolerance",
                expected: "finite and >= 0",
                value: self.tolerance,
            });
        }
        Ok(())
    }
}

/// A protective fault the controller raised on a `servo_j` target.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ProtectiveFault {
    /// A joint would have moved faster than the joint speed limit: error 24
    /// ([`ControllerError::SpeedLimit`], the xArm's "speed exceeds limit", which the control
    /// box raises for joint speed).
    JointSpeed {
        /// Joint index (0-based).
        joint: usize,
        /// The step the target asked for (rad).
        step_rad: f64,
        /// The largest step allowed (rad).
        limit_rad: f64,
    },
    /// The TCP would have moved faster than the linear speed limit: error 60
    /// ([`ControllerError::LinearSpeed`], "linear speed exceeds limit").
    TcpSpeed {
        /// The TCP step the target asked for (m).
        step_m: f64,
        /// The largest step allowed (m).
        limit_m: f64,
    },
}

impl ProtectiveFault {
    /// The controller error code this fault raises.
    pub fn code(&self) -> ControllerError {
        match self {
            Self::JointSpeed { .. } => ControllerError::SpeedLimit,
            Self::TcpSpeed { .. } => ControllerError::LinearSpeed,
        }
    }
}

/// Figures about the `servo_j` stream as received on the wire, for tests: steps between
/// consecutive `servo_j` frames this controller received (over every connection and state,
/// accepted or not; non-finite targets are skipped; the first frame has no step).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ServoStreamStats {
    /// Largest per-joint step between consecutive targets (rad), max over joints and frames.
    pub max_joint_step_rad: f64,
    /// Largest TCP step between consecutive targets (m); 0 without a robot model.
    pub max_tcp_step_m: f64,
    /// The last protective fault raised, if any.
    pub last_fault: Option<ProtectiveFault>,
}

/// Counters the simulator keeps for its summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ControllerCounters {
    /// Command frames answered.
    pub frames: u64,
    /// Frames that could not be parsed (bad length, unknown register, bad payload).
    pub bad_frames: u64,
    /// Servo_j targets accepted.
    pub servo_accepted: u64,
    /// Servo_j targets rejected (not ready, error, out of range, protective fault).
    pub servo_rejected: u64,
    /// Collisions raised.
    pub collisions: u64,
    /// Emergency/explicit stops (`SET_STATE(4)` and `SET_STATE(6)`).
    pub stops: u64,
    /// `SET_STATE(4)` requests received.
    pub stop_requests: u64,
    /// `CLEAN_ERR` requests received.
    pub clean_error_requests: u64,
    /// Protective faults raised (joint speed + TCP speed).
    pub protective_faults: u64,
    /// Joint speed faults (error 24).
    pub joint_speed_faults: u64,
    /// TCP speed faults (error 60).
    pub tcp_speed_faults: u64,
    /// Identity challenges (register 0xF0) received.
    pub identity_challenges: u64,
    /// Identity challenges answered with a proof (the simulator holds a secret).
    pub identity_proofs: u64,
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
    limits: ProtectiveLimits,
    model: Option<RobotModel>,
    stream: ServoStreamStats,
    last_wire_target: Option<([f64; 5], Option<[f64; 3]>)>,
    /// Fault injection: the arm accepts targets and does not move (a frozen or blocked arm).
    frozen: bool,
    /// The run's secret: with it the identity challenge is answered with a proof.
    sim_secret: Option<SimSecret>,
}

impl Default for Controller {
    fn default() -> Self {
        Self::new([0.0; 5])
    }
}

fn joints_f64(t: &JointTarget) -> [f64; 5] {
    let mut q = [0.0; 5];
    for (dst, src) in q.iter_mut().zip(t.joints_rad) {
        *dst = f64::from(src);
    }
    q
}

/// The joint with the largest |b − a| and that step (rad).
fn max_joint_step(a: &[f64; 5], b: &[f64; 5]) -> (usize, f64) {
    let mut best = (0, 0.0);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let d = (y - x).abs();
        if d > best.1 {
            best = (i, d);
        }
    }
    best
}

fn distance_m(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (y - x) * (y - x))
        .sum::<f64>()
        .sqrt()
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
            limits: ProtectiveLimits::default(),
            model: None,
            stream: ServoStreamStats::default(),
            last_wire_target: None,
            frozen: false,
            sim_secret: None,
        }
    }

    /// The run's secret, which the identity challenge's proof is made with (`None`: the
    /// challenge is answered as an unknown register, and the simulator passes for a real arm).
    pub fn set_sim_secret(&mut self, secret: Option<SimSecret>) {
        self.sim_secret = secret;
    }

    /// The reply to an identity challenge: the proof with a secret; without one, the reply
    /// to any register the controller does not have.
    fn answer_identity(
        &mut self,
        tid: u16,
        protocol: u16,
        nonce: &[u8; NONCE_LEN],
        out: &mut [u8; MAX_FRAME_LEN],
    ) -> Result<usize, FrameError> {
        self.counters.identity_challenges += 1;
        let register = u8::from(xarm::codec::Register::SimIdentity);
        let n = match &self.sim_secret {
            Some(secret) => {
                self.counters.identity_proofs += 1;
                let proof = secret.proof(nonce);
                codec::encode_response(tid, protocol, register, self.status(), &proof, out)
            }
            None => {
                self.counters.bad_frames += 1;
                let status = self.status() | codec::STATUS_INVALID;
                codec::encode_response(tid, protocol, register, status, &[], out)
            }
        };
        n.map_err(|_| FrameError::UnknownRegister(register))
    }

    /// Gives the controller the robot model, for the TCP speed check and the TCP step figure.
    /// Without one only the joint speed check runs.
    pub fn set_model(&mut self, model: RobotModel) {
        self.model = Some(model);
    }

    /// Replaces the protective limits. The caller validates them
    /// ([`ProtectiveLimits::validate`]).
    pub fn set_protective_limits(&mut self, limits: ProtectiveLimits) {
        self.limits = limits;
    }

    /// The protective limits in force.
    pub fn protective_limits(&self) -> ProtectiveLimits {
        self.limits
    }

    /// Figures about the received `servo_j` stream.
    pub fn servo_stream(&self) -> ServoStreamStats {
        self.stream
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
    /// motion stopped, state 4. Every later motion command is answered with the error bit
    /// until `CLEAN_ERR`. [`ControllerError::None`] is ignored.
    pub fn raise_error(&mut self, code: ControllerError) {
        if code == ControllerError::None {
            return;
        }
        self.error = u8::from(code);
        if code.is_collision() {
            self.counters.collisions += 1;
        }
        self.system_reset();
    }

    /// Fault injection (control port `freeze on|off`): while frozen the controller accepts
    /// every target as usual and reports itself moving, but the joints do not move.
    pub fn set_frozen(&mut self, frozen: bool) {
        self.frozen = frozen;
    }

    /// Whether the arm is frozen (fault injection).
    pub fn frozen(&self) -> bool {
        self.frozen
    }

    /// `SET_STATE(s)` as another client sends it (the pendant, the SDK; control port
    /// `state <s>`).
    pub fn request_state(&mut self, s: u8) {
        self.set_state(s);
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
        if self.frozen {
            self.dq_rad_s = [0.0; 5];
            self.state = if now_s < self.moving_until_s { 1 } else { 2 };
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

    fn tcp_m(&self, q: &[f64; 5]) -> Option<[f64; 3]> {
        self.model.as_ref().map(|m| {
            let p = m.tcp_m(q);
            [p.x, p.y, p.z]
        })
    }

    /// Records the step from the previous `servo_j` frame received to this one.
    fn record_wire_target(&mut self, t: &JointTarget) {
        if !t.joints_rad[..5].iter().all(|v| v.is_finite()) {
            return;
        }
        let q = joints_f64(t);
        let tcp = self.tcp_m(&q);
        if let Some((prev_q, prev_tcp)) = self.last_wire_target {
            let step = max_joint_step(&prev_q, &q).1;
            self.stream.max_joint_step_rad = self.stream.max_joint_step_rad.max(step);
            if let (Some(a), Some(b)) = (prev_tcp, tcp) {
                self.stream.max_tcp_step_m = self.stream.max_tcp_step_m.max(distance_m(&a, &b));
            }
        }
        self.last_wire_target = Some((q, tcp));
    }

    /// The servo-mode protective check of `target` against the commanded position.
    ///
    /// The reference is `target_rad`, the position the arm was last commanded to, not the
    /// integrated `q_rad`: the real controller executes each `servo_j` target within one
    /// servo period, so what it limits is the step between consecutive set-points; `q_rad`
    /// trails the set-point by up to one physics tick and would fault a compliant stream on
    /// scheduling jitter. After any stop, mode change, enable or `SET_STATE(0)` the
    /// commanded position is reset to the actual joints (`hold`), so the first target after
    /// a (re)connect is compared with where the arm stands, and a jump faults.
    fn protective_check(&self, target: &[f64; 5]) -> Option<ProtectiveFault> {
        if !self.limits.enabled {
            return None;
        }
        let limit_rad = self.limits.max_joint_step_rad();
        let (joint, step_rad) = max_joint_step(&self.target_rad, target);
        if step_rad > limit_rad {
            return Some(ProtectiveFault::JointSpeed {
                joint,
                step_rad,
                limit_rad,
            });
        }
        if let (Some(a), Some(b)) = (self.tcp_m(&self.target_rad), self.tcp_m(target)) {
            let step_m = distance_m(&a, &b);
            let limit_m = self.limits.max_tcp_step_m();
            if step_m > limit_m {
                return Some(ProtectiveFault::TcpSpeed { step_m, limit_m });
            }
        }
        None
    }

    /// Raises a protective fault: the target is not executed, the error is set and the arm
    /// stops (state 4), like any other controller error.
    fn protective_fault(&mut self, fault: ProtectiveFault) {
        self.counters.protective_faults += 1;
        match fault {
            ProtectiveFault::JointSpeed { .. } => self.counters.joint_speed_faults += 1,
            ProtectiveFault::TcpSpeed { .. } => self.counters.tcp_speed_faults += 1,
        }
        self.stream.last_fault = Some(fault);
        self.raise_error(fault.code());
    }

    fn servo(&mut self, t: &JointTarget, speed_limited: bool) -> bool {
        if !speed_limited {
            self.record_wire_target(t);
        }
        if !self.can_move() || self.mode != 1 && !speed_limited {
            self.counters.servo_rejected += 1;
            return false;
        }
        if !within_limits(&t.joints_rad) {
            self.warn = u8::from(ControllerWarning::BadParameter);
            self.counters.servo_rejected += 1;
            return false;
        }
        let target = joints_f64(t);
        if !speed_limited && let Some(fault) = self.protective_check(&target) {
            self.counters.servo_rejected += 1;
            self.protective_fault(fault);
            return false;
        }
        self.target_rad = target;
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
        if let Request::SimIdentity(nonce) = req {
            return self.answer_identity(h.tid, h.protocol, &nonce, out);
        }
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
                self.counters.clean_error_requests += 1;
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
            // Answered in `handle` before any state is touched.
            Request::FeedbackCheck | Request::SimIdentity(_) => {}
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
                if s == 4 {
                    self.counters.stop_requests += 1;
                }
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
mod tests {
    use super::*;
    use xarm::codec::Response;

    /// Issue 30 item 1: with the run's secret the identity challenge gets its proof; without
    /// one, the reply to a register the controller does not have, and nothing changes.
    #[test]
    fn the_identity_challenge_is_answered_with_a_proof_only_with_the_secret() {
        let secret = SimSecret::generate().unwrap();
        let nonce = [9u8; NONCE_LEN];
        let mut frame = [0u8; 64];
        let n = Request::SimIdentity(nonce)
            .encode(7, codec::PROTOCOL_PRIVATE, &mut frame)
            .unwrap();
        let mut out = [0u8; MAX_FRAME_LEN];
        for held in [Some(secret.clone()), None] {
            let mut c = Controller::new([0.0; 5]);
            c.set_sim_secret(held.clone());
            let m = c.handle(&frame[..n], &mut out).unwrap();
            let r = Response::parse(&out[..m]).unwrap();
            r.check(7, codec::PROTOCOL_PRIVATE, 0xF0).unwrap();
            let verdict = xarm::sim_identity::check_reply(&secret, &nonce, r.status, r.data);
            assert_eq!(verdict.is_ok(), held.is_some(), "{verdict:?}");
            if held.is_none() {
                assert_ne!(r.status & codec::STATUS_INVALID, 0);
                assert!(r.data.is_empty());
            }
            assert_eq!((c.state(), c.mode()), (4, 0), "nothing changed");
            assert_eq!(c.counters().identity_challenges, 1);
            assert_eq!(c.counters().identity_proofs, u64::from(held.is_some()));
        }
    }

    /// A controller taken through enable, mode 1 and state 0 (transactions 1–3), as the
    /// SDK does before streaming servo_j.
    fn servo_ready() -> Controller {
        let mut c = Controller::default();
        enable_servo(&mut c);
        c
    }

    /// Enable, mode 1, state 0 (transactions 1–3).
    fn enable_servo(c: &mut Controller) {
        ask(
            c,
            Request::MotionEnable {
                servo_id: 8,
                enable: true,
            },
            1,
        );
        ask(
            c,
            Request::SetMode {
                mode: 1,
                detection: Some(0),
            },
            2,
        );
        ask(c, Request::SetState(0), 3);
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
    fn a_frozen_arm_accepts_targets_and_stays_put() {
        let (mut c, home) = servo_ready_at_home();
        c.set_frozen(true);
        let mut q = home;
        q[0] += 0.001;
        servo_j(&mut c, &q, 10);
        c.step(c.now_s + 0.004);
        assert_eq!(c.q_rad(), home, "frozen");
        assert_eq!(c.state(), 1, "reports itself moving");
        c.set_frozen(false);
        c.step(c.now_s + 0.004);
        assert!((c.q_rad()[0] - q[0]).abs() < 1e-9, "follows again");
        c.request_state(4);
        assert_eq!(c.state(), 4, "stopped by another client");
    }

    #[test]
    fn servo_j_is_refused_until_enabled_mode_1_and_state_0() {
        let mut c = Controller::default();
        // A far target, to see the 180°/s integration: without the protective check, which
        // would fault a 0.1 rad step (tested below).
        c.set_protective_limits(ProtectiveLimits::off());
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
            Request::ServoJ(JointTarget::xarm5(&[0.01, 0.0, 0.0, 0.0, 0.0])),
            4,
        );
        c.step(0.002);
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
    // ---- protective faults -------------------------------------------------------------

    fn model() -> RobotModel {
        RobotModel::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/xarm5.urdf"),
        )
        .unwrap()
    }

    /// A controller with the robot model, the arm at home, in servo mode and state 2.
    fn servo_ready_at_home() -> (Controller, [f64; 5]) {
        let m = model();
        let q0 = m.home();
        let mut c = Controller::new(q0);
        c.set_model(m);
        enable_servo(&mut c);
        assert_eq!((c.state(), c.mode()), (2, 1));
        (c, q0)
    }

    fn servo_j(c: &mut Controller, q: &[f64; 5], tid: u16) -> u8 {
        ask(c, Request::ServoJ(JointTarget::xarm5(q)), tid).0
    }

    fn tcp_distance_m(m: &RobotModel, a: &[f64; 5], b: &[f64; 5]) -> f64 {
        (m.tcp_m(a) - m.tcp_m(b)).norm()
    }

    #[test]
    fn default_limits_are_the_xarm_figures() {
        let l = ProtectiveLimits::default();
        assert!(l.enabled);
        assert_eq!(l.max_joint_speed_rad_s, PI);
        assert_eq!(l.max_tcp_speed_m_s, 1.0);
        assert_eq!(l.servo_period_s, 0.004);
        assert_eq!(l.tolerance, 0.25);
        assert!((l.max_joint_step_rad() - PI * 0.005).abs() < 1e-12);
        assert!((l.max_tcp_step_m() - 0.005).abs() < 1e-12);
        assert_eq!(Controller::default().protective_limits(), l);
    }

    #[test]
    fn a_slow_target_stream_passes_with_no_fault() {
        let (mut c, q0) = servo_ready_at_home();
        let n = 250u16;
        let mut q = q0;
        for k in 1..=n {
            q = q0;
            q[0] += 0.002 * f64::from(k);
            q[3] -= 0.001 * f64::from(k);
            let s = servo_j(&mut c, &q, 3 + k);
            assert_eq!(s, 0, "target {k} accepted");
            c.step(0.004 * f64::from(k));
        }
        c.step(1.5);
        assert_eq!(c.error(), ControllerError::None);
        assert_eq!(c.counters().servo_accepted, u64::from(n));
        assert_eq!(c.counters().protective_faults, 0);
        assert_eq!(c.servo_stream().last_fault, None);
        for (i, (got, want)) in c.q_rad().iter().zip(q).enumerate() {
            assert!((got - want).abs() < 1e-6, "joint {i} reached");
        }
        let st = c.servo_stream();
        assert!(
            (st.max_joint_step_rad - 0.002).abs() < 1e-6,
            "{}",
            st.max_joint_step_rad
        );
        assert!(
            st.max_tcp_step_m > 0.0 && st.max_tcp_step_m < 0.005,
            "{}",
            st.max_tcp_step_m
        );
    }

    #[test]
    fn a_joint_jump_faults_with_code_24_and_stops_motion() {
        let (mut c, q0) = servo_ready_at_home();
        let mut ok = q0;
        ok[1] += 0.005;
        assert_eq!(servo_j(&mut c, &ok, 4), 0);
        c.step(0.004);
        let q_before = c.q_rad();
        // 0.018 rad in one 4 ms target: 4.5 rad/s > π × 1.25.
        let mut jump = ok;
        jump[0] += 0.018;
        let s = servo_j(&mut c, &jump, 5);
        assert_eq!(
            s & (STATUS_ERROR | STATUS_NOT_READY),
            STATUS_ERROR | STATUS_NOT_READY
        );
        assert_eq!(c.error(), ControllerError::SpeedLimit);
        assert_eq!(c.state(), 4);
        assert_eq!(c.target_rad(), c.q_rad(), "motion stopped where the arm is");
        let (_, d) = ask(&mut c, Request::GetError, 6);
        assert_eq!(d, vec![24, 0]);
        assert_eq!(ask(&mut c, Request::GetState, 7).1, vec![4]);
        let r = c.report(ReportKind::Normal, 0);
        assert_eq!((r.error_code, r.state), (Some(24), 4));
        // Further targets (even a small one) get the error bit and the arm does not move.
        let q_stop = c.q_rad();
        assert!(
            (q_stop[0] - q_before[0]).abs() < 1e-12,
            "the jump was not executed"
        );
        let mut small = ok;
        small[0] += 0.001;
        let s = servo_j(&mut c, &small, 8);
        assert_ne!(s & STATUS_ERROR, 0);
        c.step(0.5);
        assert_eq!(c.q_rad(), q_stop, "the arm does not move");
        let k = c.counters();
        assert_eq!(
            (
                k.protective_faults,
                k.joint_speed_faults,
                k.tcp_speed_faults
            ),
            (1, 1, 0)
        );
        assert_eq!((k.servo_accepted, k.servo_rejected), (1, 2));
        assert_eq!(k.collisions, 0);
        match c.servo_stream().last_fault {
            Some(ProtectiveFault::JointSpeed {
                joint,
                step_rad,
                limit_rad,
            }) => {
                assert_eq!(joint, 0);
                assert!((step_rad - 0.018).abs() < 1e-6, "{step_rad}");
                assert!((limit_rad - PI * 0.005).abs() < 1e-12);
            }
            other => panic!("expected a joint speed fault, got {other:?}"),
        }
        let st = c.servo_stream();
        assert!((st.max_joint_step_rad - 0.018).abs() < 1e-6);
    }

    /// A target whose joints each stay within the joint step but whose TCP moves > 5 mm.
    fn tcp_fast_target(m: &RobotModel, q0: &[f64; 5]) -> [f64; 5] {
        let lim = ProtectiveLimits::default();
        let dq = 0.9 * lim.max_joint_step_rad();
        // The sign pattern on J1..J3 that moves the TCP furthest.
        let mut q = *q0;
        for signs in 0..8u8 {
            let mut c = *q0;
            for (j, v) in c.iter_mut().take(3).enumerate() {
                *v += if signs >> j & 1 == 1 { dq } else { -dq };
            }
            if tcp_distance_m(m, q0, &c) > tcp_distance_m(m, q0, &q) {
                q = c;
            }
        }
        let d = tcp_distance_m(m, q0, &q);
        assert!(
            d > 1.2 * lim.max_tcp_step_m(),
            "test precondition: TCP step {d} m"
        );
        q
    }

    #[test]
    fn a_tcp_speed_violation_faults_with_code_60() {
        let (mut c, q0) = servo_ready_at_home();
        let m = model();
        let fast = tcp_fast_target(&m, &q0);
        let s = servo_j(&mut c, &fast, 4);
        assert_ne!(s & STATUS_ERROR, 0);
        assert_eq!(c.error(), ControllerError::LinearSpeed);
        assert_eq!(ask(&mut c, Request::GetError, 5).1, vec![60, 0]);
        assert_eq!(c.state(), 4);
        c.step(0.2);
        assert_eq!(c.q_rad(), q0, "the target was not executed");
        let k = c.counters();
        assert_eq!(
            (
                k.protective_faults,
                k.joint_speed_faults,
                k.tcp_speed_faults
            ),
            (1, 0, 1)
        );
        let expected = tcp_distance_m(&m, &q0, &fast);
        match c.servo_stream().last_fault {
            Some(ProtectiveFault::TcpSpeed { step_m, limit_m }) => {
                assert!((step_m - expected).abs() < 1e-5, "{step_m} vs {expected}");
                assert!((limit_m - 0.005).abs() < 1e-12);
            }
            other => panic!("expected a TCP speed fault, got {other:?}"),
        }
        // The same target passes once the TCP limit is raised: the TCP check tripped.
        let (mut c2, _) = servo_ready_at_home();
        c2.set_protective_limits(ProtectiveLimits {
            max_tcp_speed_m_s: 10.0,
            ..ProtectiveLimits::default()
        });
        assert_eq!(servo_j(&mut c2, &fast, 4), 0);
    }

    #[test]
    fn counters_and_max_steps_follow_the_wire() {
        let (mut c, q0) = servo_ready_at_home();
        let m = model();
        let steps = [0.001, 0.006, 0.003];
        let mut prev = q0;
        let mut max_tcp = 0.0f64;
        let mut first = true;
        for (k, dq) in steps.iter().enumerate() {
            let mut q = prev;
            q[2] -= dq;
            assert_eq!(servo_j(&mut c, &q, 4 + k as u16), 0);
            if !first {
                max_tcp = max_tcp.max(tcp_distance_m(&m, &prev, &q));
            }
            first = false;
            prev = q;
        }
        let st = c.servo_stream();
        // The first frame has no predecessor: the largest step is 0.006, not 0.001.
        assert!((st.max_joint_step_rad - 0.006).abs() < 1e-6, "{st:?}");
        assert!((st.max_tcp_step_m - max_tcp).abs() < 1e-5, "{st:?}");
        // Frames refused while stopped still count on the wire.
        ask(&mut c, Request::SetState(4), 10);
        ask(&mut c, Request::SetState(4), 11);
        ask(&mut c, Request::SetState(6), 12);
        let mut far = prev;
        far[4] += 0.05;
        assert_ne!(servo_j(&mut c, &far, 13) & STATUS_NOT_READY, 0);
        let st = c.servo_stream();
        assert!((st.max_joint_step_rad - 0.05).abs() < 1e-6, "{st:?}");
        assert_eq!(st.last_fault, None, "refused while stopped: no fault");
        ask(&mut c, Request::CleanError, 14);
        let k = c.counters();
        assert_eq!((k.stop_requests, k.stops), (2, 3));
        assert_eq!(k.clean_error_requests, 1);
        assert_eq!(k.protective_faults, 0);
        assert_eq!(c.state(), 4);
    }

    #[test]
    fn clean_error_and_re_enable_resume_after_a_fault() {
        let (mut c, q0) = servo_ready_at_home();
        let mut jump = q0;
        jump[3] += 0.05;
        assert_ne!(servo_j(&mut c, &jump, 4) & STATUS_ERROR, 0);
        ask(&mut c, Request::SetState(0), 5);
        assert_eq!(c.state(), 4, "cannot start with an error");
        let (s, _) = ask(&mut c, Request::CleanError, 6);
        assert_eq!(s & STATUS_ERROR, 0);
        assert_eq!(c.error(), ControllerError::None);
        enable_servo(&mut c);
        assert_eq!(c.state(), 2);
        let mut q = q0;
        q[3] += 0.01;
        assert_eq!(servo_j(&mut c, &q, 7), 0);
        c.step(0.1);
        assert!((c.q_rad()[3] - q[3]).abs() < 1e-6, "the arm moves again");
        let k = c.counters();
        assert_eq!((k.clean_error_requests, k.joint_speed_faults), (1, 1));
        assert_eq!(k.servo_accepted, 1);
    }

    #[test]
    fn the_check_can_be_turned_off_and_limits_are_validated() {
        let (mut c, q0) = servo_ready_at_home();
        c.set_protective_limits(ProtectiveLimits::off());
        let mut jump = q0;
        jump[0] += 0.1;
        assert_eq!(servo_j(&mut c, &jump, 4), 0);
        assert_eq!(c.counters().protective_faults, 0);

        assert_eq!(ProtectiveLimits::default().validate(), Ok(()));
        assert_eq!(ProtectiveLimits::off().validate(), Ok(()));
        let bad = [
            (
                ProtectiveLimits {
                    max_joint_speed_rad_s: 0.0,
                    ..ProtectiveLimits::default()
                },
                "max_joint_speed_rad_s",
            ),
            (
                ProtectiveLimits {
                    max_tcp_speed_m_s: f64::INFINITY,
                    ..ProtectiveLimits::default()
                },
                "max_tcp_speed_m_s",
            ),
            (
                ProtectiveLimits {
                    servo_period_s: f64::NAN,
                    ..ProtectiveLimits::default()
                },
                "servo_period_s",
            ),
            (
                ProtectiveLimits {
                    tolerance: -0.1,
                    ..ProtectiveLimits::default()
                },
                "tolerance",
            ),
        ];
        for (l, field) in bad {
            let e = l.validate().unwrap_err();
            assert_eq!(e.field, field);
            assert!(e.to_string().contains(field), "{e}");
        }
    }

    #[test]
    fn a_joint_step_just_under_the_limit_passes_and_just_over_faults() {
        let lim = ProtectiveLimits::default().max_joint_step_rad();
        let (mut c, q0) = servo_ready_at_home();
        let mut q = q0;
        q[4] += lim - 1e-4;
        assert_eq!(servo_j(&mut c, &q, 4), 0);
        q[4] += lim + 1e-4;
        assert_ne!(servo_j(&mut c, &q, 5) & STATUS_ERROR, 0);
        assert_eq!(c.error(), ControllerError::SpeedLimit);
    }
}
