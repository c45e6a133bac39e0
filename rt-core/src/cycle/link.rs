//! The robot link: how the cycle reads the arm's state and sends servo targets. The xArm
//! implementation (TCP, the controller protocol) comes with the driver; [`InProcessArm`] is a
//! simulated arm in the same process for tests and the bench: it integrates each servo
//! target within the joint limits and a per-joint velocity limit.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use twin::{DOF, Joints, max_joint_gap_rad};

/// One reading of the arm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LinkState {
    /// When the reading was taken (cycle clock), ns.
    pub stamp_ns: u64,
    /// Joint positions, rad.
    pub q_rad: Joints,
    /// Joint velocities, rad/s.
    pub dq_rad_s: Joints,
    /// Controller error code (0 = none).
    pub error_code: u16,
    /// Controller mode (0 position, 1 servo, …; 0 for arms without one).
    pub mode: u8,
    /// Controller state (0 ready, 1 moving, 2 paused, 3 stopped, 4 stop requested; 0 for
    /// arms without one).
    pub state: u8,
    /// `Some(distance)`, m, when the twin's TCP of `q_rad` lies farther than the link's
    /// tolerance from the TCP the controller reports (a wrong model or base calibration);
    /// `None` when they agree or the arm reports no TCP. The cycle stops and latches.
    pub model_mismatch_m: Option<f64>,
    /// The connection to the controller this reading came through: a count that changes
    /// whenever the link re-opens it (0 for a link that never does). On one connection the
    /// controller takes the last target it accepted as the reference of the next one (it
    /// holds the arm there when no target comes, and faults on a target more than one
    /// servo period's step from it), whatever the measured joints say; a re-opened
    /// connection enters servo mode again, which holds the arm where it stands.
    pub session: u32,
}

/// Why the link failed (small and `Copy`: it travels through the cycle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LinkError {
    /// The connection to the arm is lost.
    #[error("robot link lost")]
    Disconnected,
    /// The controller reports an error code.
    #[error("controller error {0}")]
    ControllerError(u16),
    /// No fresh reading was available this cycle.
    #[error("no fresh state")]
    NoState,
    /// The target was refused before it reached the arm (outside the controller's joint
    /// limits, a jump after a reconnect, or the controller not ready to move).
    #[error("target refused")]
    Refused,
}

/// The cycle's view of a robot. Implementations must not allocate or block in these calls.
pub trait RobotLink: Send {
    /// The latest state of the arm.
    ///
    /// # Errors
    /// [`LinkError`] when the arm cannot be read.
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError>;

    /// Sends one servo target (joint positions, rad).
    ///
    /// # Errors
    /// [`LinkError`] when the target cannot be delivered.
    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError>;

    /// An operator acknowledged a protective stop: clear the controller's error and
    /// re-enable motion (servo mode) without blocking. Called only on that action, never
    /// on the cycle's own initiative.
    ///
    /// # Errors
    /// [`LinkError`] when the request cannot be passed on.
    fn acknowledge(&mut self, _now_ns: u64) -> Result<(), LinkError> {
        Ok(())
    }

    /// Puts the controller in its stop state once the cycle has ended with the arm at
    /// rest (the xArm's `SET_STATE 4`). Called off the loop, after its last period; may
    /// block up to the link's reply timeout.
    fn stop_controller(&mut self, _now_ns: u64) {}

    /// Asks the controller to hold the arm where it stands and drop its last target,
    /// without blocking (the xArm's `SET_STATE 4`): the cycle found that the arm does not
    /// follow its commands. Motion needs an operator's acknowledgement afterwards.
    fn hold_controller(&mut self, _now_ns: u64) {}

    /// Whether the commands sent reach the arm (false for a dry run): only then does the
    /// cycle hold the controller's state and the measured joints to what it commanded.
    fn commands_reach_arm(&self) -> bool {
        true
    }
}

/// A simulated arm in the same process. Each servo target is clamped into the joint limits
/// and approached at no more than the velocity limit over the time since the last command.
#[derive(Debug, Clone)]
pub struct InProcessArm {
    q_rad: Joints,
    dq_rad_s: Joints,
    last_ns: Option<u64>,
    joint_min_rad: Joints,
    joint_max_rad: Joints,
    max_velocity_rad_s: Joints,
    connected: Arc<AtomicBool>,
    commands: u64,
    controller_stops: u64,
    last_target_rad: Option<Joints>,
    max_target_step_rad: f64,
    /// Connections so far: a read after a cut counts a new one ([`LinkState::session`]).
    session: u32,
    cut_seen: bool,
    /// A target came since the last reading: without one the arm holds still, and reads
    /// at rest (a controller holding its last target).
    sent_since_read: bool,
}

impl InProcessArm {
    /// An arm at `q0_rad`.
    pub fn new(
        q0_rad: Joints,
        joint_min_rad: Joints,
        joint_max_rad: Joints,
        max_velocity_rad_s: Joints,
    ) -> Self {
        Self {
            q_rad: q0_rad,
            dq_rad_s: [0.0; DOF],
            last_ns: None,
            joint_min_rad,
            joint_max_rad,
            max_velocity_rad_s,
            connected: Arc::new(AtomicBool::new(true)),
            commands: 0,
            controller_stops: 0,
            last_target_rad: None,
            max_target_step_rad: 0.0,
            session: 0,
            cut_seen: false,
            sent_since_read: false,
        }
    }

    /// A handle that cuts (`store(false)`) or restores the connection from another thread.
    pub fn connection(&self) -> Arc<AtomicBool> {
        self.connected.clone()
    }

    /// Commands accepted so far.
    pub fn commands(&self) -> u64 {
        self.commands
    }

    /// Current joint positions, rad.
    pub fn q_rad(&self) -> Joints {
        self.q_rad
    }

    /// The largest change of one joint between two consecutive targets received, rad
    /// (what a controller would see as a jump).
    pub fn max_target_step_rad(&self) -> f64 {
        self.max_target_step_rad
    }

    /// How often the controller was put in its stop state.
    pub fn controller_stops(&self) -> u64 {
        self.controller_stops
    }
}

impl RobotLink for InProcessArm {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        if !self.connected.load(Ordering::Acquire) {
            self.cut_seen = true;
            return Err(LinkError::Disconnected);
        }
        if std::mem::take(&mut self.cut_seen) {
            // The connection was cut and is back: a re-opened connection.
            self.session = self.session.wrapping_add(1);
        }
        if !std::mem::take(&mut self.sent_since_read) {
            self.dq_rad_s = [0.0; DOF];
        }
        Ok(LinkState {
            stamp_ns: now_ns,
            q_rad: self.q_rad,
            dq_rad_s: self.dq_rad_s,
            error_code: 0,
            mode: 1,
            state: if self.controller_stops > 0 { 4 } else { 0 },
            model_mismatch_m: None,
            session: self.session,
        })
    }

    fn stop_controller(&mut self, _now_ns: u64) {
        self.controller_stops += 1;
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        if !self.connected.load(Ordering::Acquire) {
            self.cut_seen = true;
            return Err(LinkError::Disconnected);
        }
        let dt_s = self
            .last_ns
            .map_or(0.0, |t| now_ns.saturating_sub(t) as f64 * 1e-9);
        self.last_ns = Some(now_ns);
        if let Some(prev) = self.last_target_rad {
            let step = max_joint_gap_rad(&prev, q_rad);
            self.max_target_step_rad = self.max_target_step_rad.max(step);
        }
        self.last_target_rad = Some(*q_rad);
        #[allow(clippy::needless_range_loop)] // j indexes six per-joint arrays
        for j in 0..DOF {
            let target = q_rad[j].clamp(self.joint_min_rad[j], self.joint_max_rad[j]);
            let max_step = self.max_velocity_rad_s[j] * dt_s;
            let step = if dt_s > 0.0 {
                (target - self.q_rad[j]).clamp(-max_step, max_step)
            } else {
                0.0
            };
            self.q_rad[j] += step;
            self.dq_rad_s[j] = if dt_s > 0.0 { step / dt_s } else { 0.0 };
        }
        self.commands += 1;
        self.sent_since_read = true;
        Ok(())
    }
}

/// A dry run (`rt-core run --dry-run`): reads the real arm, computes every command as in a
/// live run, and sends none. The withheld commands are counted here; the runtime logs them
/// from the cycle's reports.
#[derive(Debug)]
pub struct DryRunLink<L: RobotLink> {
    inner: L,
    withheld: u64,
}

impl<L: RobotLink> DryRunLink<L> {
    /// Wraps `inner`; nothing reaches its `send_servo`.
    pub fn new(inner: L) -> Self {
        Self { inner, withheld: 0 }
    }

    /// Commands computed and withheld so far.
    pub fn withheld(&self) -> u64 {
        self.withheld
    }
}

impl<L: RobotLink> RobotLink for DryRunLink<L> {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        self.inner.read_state(now_ns)
    }

    fn send_servo(&mut self, _now_ns: u64, _q_rad: &Joints) -> Result<(), LinkError> {
        self.withheld += 1;
        Ok(())
    }

    // A dry run passes nothing on: no error clearing, no stop state (the arm's mode is
    // left as it is).
    fn acknowledge(&mut self, _now_ns: u64) -> Result<(), LinkError> {
        Ok(())
    }

    fn stop_controller(&mut self, _now_ns: u64) {}

    fn commands_reach_arm(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dry_run_reads_the_arm_and_moves_nothing() {
        let mut d = DryRunLink::new(arm());
        d.send_servo(0, &[0.0; DOF]).unwrap();
        d.send_servo(4_000_000, &[0.3; DOF]).unwrap();
        assert_eq!(d.read_state(4_000_000).unwrap().q_rad, [0.0; DOF]);
        assert_eq!(d.inner.commands(), 0);
        assert_eq!(d.withheld(), 2);
    }

    fn arm() -> InProcessArm {
        InProcessArm::new([0.0; DOF], [-1.0; DOF], [1.0; DOF], [1.0; DOF])
    }

    #[test]
    fn targets_are_followed_within_velocity_and_joint_limits() {
        let mut a = arm();
        a.send_servo(0, &[0.0; DOF]).unwrap();
        a.send_servo(4_000_000, &[0.002, -0.5, 5.0, 0.0, 0.0])
            .unwrap();
        let q = a.read_state(4_000_000).unwrap().q_rad;
        assert!((q[0] - 0.002).abs() < 1e-12);
        assert!((q[1] + 0.004).abs() < 1e-12, "velocity limit: {q:?}");
        for _ in 0..1000 {
            a.send_servo(a.last_ns.unwrap() + 4_000_000, &[0.0, 0.0, 5.0, 0.0, 0.0])
                .unwrap();
        }
        assert_eq!(a.q_rad()[2], 1.0, "joint limit");
    }

    #[test]
    fn a_cut_connection_fails_reads_and_commands() {
        let mut a = arm();
        a.connection().store(false, Ordering::Release);
        assert_eq!(a.read_state(0), Err(LinkError::Disconnected));
        assert_eq!(a.send_servo(0, &[0.0; DOF]), Err(LinkError::Disconnected));
    }

    #[test]
    fn a_restored_connection_is_a_new_session() {
        let mut a = arm();
        let first = a.read_state(0).unwrap().session;
        assert_eq!(a.read_state(4_000_000).unwrap().session, first);
        a.connection().store(false, Ordering::Release);
        assert!(a.read_state(8_000_000).is_err());
        a.connection().store(true, Ordering::Release);
        let back = a.read_state(12_000_000).unwrap().session;
        assert_ne!(back, first, "a re-opened connection");
        assert_eq!(a.read_state(16_000_000).unwrap().session, back);
    }
}
