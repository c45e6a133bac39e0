//! [`RobotLink`] for [`XArmDriver`]: the cycle's view of the real (or simulated) arm, and
//! [`XArmLink`], the production link: the driver, the arm's lock ([`ArmLock`]: one owner per
//! arm) and the twin-vs-controller TCP check ([`TcpCheck`]).
//!
//! [`open_xarm`] takes the arm's lock before it connects (a second owner is refused with the
//! holder named), refuses a controller that is not an xArm5 (the driver's handshake), and
//! compares the twin's TCP of the measured joints with the TCP the controller reports
//! *before* servo mode: more than [`MAX_TCP_GAP_M`] apart, nothing is moved. While running,
//! [`XArmLink`] repeats the comparison on every new report (allocation-free FK) and passes
//! a mismatch to the cycle (`LinkState::model_mismatch_m`), which stops under control and
//! latches ([`crate::cycle::StopReason::ModelMismatch`]).
//!
//! Simulation-only rights (blind mode `--no-lookahead`, `--auto-resume`, and
//! `--simulated-sensors`: the launcher's synthetic camera or bundled calibration) go by
//! identity, not by address ([`SimRights`]): the robot address must be loopback (decided
//! first, from the address alone: [`check_blind_mode_target`]) *and* the controller must
//! prove at connect that it is this run's `xarm-sim`, holding the secret the launcher gave
//! it and rt-core ([`xarm::sim_identity`]; the challenge goes out right after `GET_VERSION`,
//! before anything that changes the controller, and again at every reconnect). A loopback
//! forward to a real arm (`ssh -L`, `socat`, a container's proxy) answers no proof: it is a
//! real arm, and [`open_xarm`] refuses it before the lock's holder sends anything else
//! ([`XArmOpenError::NotSimulator`]).
//!
//! Read-only uses do not take the lock: `rt-core xarm probe` without `--servo-test` and
//! `rt-core run --dry-run` send nothing that changes the controller (the dry run withholds
//! every command and leaves the mode as it is), so they may watch an arm another process
//! drives.
//!
//! Error mapping (the cycle's `LinkError` is deliberately small): a controller error code
//! → `ControllerError(code)`; a target refused before it reached the arm (outside the SDK's
//! limits, a jump after a reconnect, the controller not ready) → `Refused`; no fresh
//! report, a full pipeline or an error whose code is still being read → `NoState` (the
//! cycle holds and stops on staleness); everything else (lost connection, malformed bytes)
//! → `Disconnected`.

use std::fmt;
use std::net::IpAddr;
use std::ops::Deref;

use crate::cycle::link::{LinkError, LinkState, RobotLink};
use twin::{Joints, LinkPoses, RobotModel};
use xarm::config::LoopbackCheckError;
use xarm::driver::{DriverState, XArmConfig, XArmDriver, XArmError};
use xarm::owner::{ArmLock, ArmLockError};
use xarm::sim_identity::{SIM_SECRET_ENV, SimIdentityError, SimSecret, SimSecretError};

/// The default largest distance between the twin's TCP of the measured joints and the TCP
/// the controller reports, m (`shield.max_tcp_gap_m` in `assets/runtime.toml`). Beyond it
/// rt-core refuses to start, or stops and latches.
pub const MAX_TCP_GAP_M: f64 = 0.005;

/// The twin's forward kinematics against the TCP the controller reports (its position;
/// the orientation is reported in the errors only). Allocation-free after [`TcpCheck::new`].
#[derive(Debug, Clone)]
pub struct TcpCheck {
    model: RobotModel,
    poses: LinkPoses,
    max_gap_m: f64,
}

impl TcpCheck {
    /// Over the twin's model, with a tolerance of `max_gap_m`.
    pub fn new(model: RobotModel, max_gap_m: f64) -> Self {
        Self {
            model,
            poses: LinkPoses::default(),
            max_gap_m,
        }
    }

    /// The tolerance, m.
    pub fn max_gap_m(&self) -> f64 {
        self.max_gap_m
    }

    /// The twin's TCP position for `q_rad`, mm (the controller's unit), base frame.
    pub fn twin_tcp_mm(&mut self, q_rad: &Joints) -> [f64; 3] {
        self.model.fk_into(q_rad, &mut self.poses);
        let t = self.poses.tcp_m();
        [t.x * 1e3, t.y * 1e3, t.z * 1e3]
    }

    /// Distance between the twin's TCP for `q_rad` and the position of the reported pose
    /// (`x, y, z` mm, `roll, pitch, yaw` rad), m.
    pub fn gap_m(&mut self, q_rad: &Joints, reported: &[f32; 6]) -> f64 {
        let twin = self.twin_tcp_mm(q_rad);
        let d2: f64 = twin
            .iter()
            .zip(reported)
            .map(|(a, b)| (a - f64::from(*b)).powi(2))
            .sum();
        d2.sqrt() * 1e-3
    }

    /// `Some(distance)`, m, when the two TCPs lie farther apart than the tolerance (or the
    /// distance is not a number).
    pub fn mismatch_m(&mut self, q_rad: &Joints, reported: &[f32; 6]) -> Option<f64> {
        let gap_m = self.gap_m(q_rad, reported);
        self.beyond_tolerance(gap_m).then_some(gap_m)
    }

    /// A NaN gap is a mismatch too.
    fn beyond_tolerance(&self, gap_m: f64) -> bool {
        gap_m.is_nan() || gap_m > self.max_gap_m
    }

    /// The start check: `Ok(distance)` within the tolerance, else the refusal naming both
    /// poses.
    ///
    /// # Errors
    /// [`TcpMismatchError`].
    pub fn check(&mut self, q_rad: &Joints, reported: &[f32; 6]) -> Result<f64, TcpMismatchError> {
        let gap_m = self.gap_m(q_rad, reported);
        if !self.beyond_tolerance(gap_m) {
            return Ok(gap_m);
        }
        Err(TcpMismatchError {
            q_rad: *q_rad,
            twin_tcp_mm: self.twin_tcp_mm(q_rad),
            reported_tcp_pose: *reported,
            gap_mm: gap_m * 1e3,
            tolerance_mm: self.max_gap_m * 1e3,
        })
    }
}

/// The twin's TCP and the controller's disagree at start: nothing was moved.
#[derive(Debug, Clone, PartialEq)]
pub struct TcpMismatchError {
    /// The measured joints, rad.
    pub q_rad: Joints,
    /// The twin's TCP for them (x, y, z), mm.
    pub twin_tcp_mm: [f64; 3],
    /// The TCP pose the controller reports: x, y, z (mm), roll, pitch, yaw (rad).
    pub reported_tcp_pose: [f32; 6],
    /// The distance between the two positions, mm.
    pub gap_mm: f64,
    /// The tolerance, mm.
    pub tolerance_mm: f64,
}

impl std::error::Error for TcpMismatchError {}

impl fmt::Display for TcpMismatchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [tx, ty, tz] = self.twin_tcp_mm;
        let [x, y, z, roll, pitch, yaw] = self.reported_tcp_pose;
        write!(
            f,
            "TCP mismatch: at the measured joints {:?} rad the twin's TCP is \
             ({tx:.1}, {ty:.1}, {tz:.1}) mm, the controller reports ({x:.1}, {y:.1}, {z:.1}) mm \
             (roll {roll:.3}, pitch {pitch:.3}, yaw {yaw:.3} rad): {:.1} mm apart, more than \
             {:.1} mm. The twin's model (URDF, TCP offset) or the base calibration does not \
             match this arm; refusing to start (nothing was moved)",
            self.q_rad, self.gap_mm, self.tolerance_mm
        )
    }
}

/// Why [`open_xarm`] refused.
#[derive(Debug, thiserror::Error)]
pub enum XArmOpenError {
    /// Another process owns the arm.
    #[error(transparent)]
    Owned(#[from] ArmLockError),
    /// The driver failed or refused the controller (not an xArm5, an error, unreachable).
    #[error(transparent)]
    Driver(#[from] XArmError),
    /// The twin's TCP and the controller's disagree.
    #[error(transparent)]
    TcpMismatch(#[from] TcpMismatchError),
    /// Simulation-only rights were asked for and the controller did not prove it is this
    /// run's `xarm-sim`: it is a real arm.
    #[error(
        "{flags} refused for the robot at {addr}: {reason}. It has not proven it is this \
         run's xarm-sim, so it is a real arm whatever its address (a loopback forward reaches \
         real arms too); nothing was moved (only GET_VERSION and the identity challenge were \
         sent)"
    )]
    NotSimulator {
        /// The simulation-only flags asked for, e.g. `--no-lookahead, --auto-resume`.
        flags: String,
        /// The address as given.
        addr: String,
        /// Why the proof failed.
        reason: SimIdentityError,
    },
}

/// The production link: the driver, the arm's lock (held as long as the link) and the TCP
/// check on every new report. Reads as the driver through `Deref`.
#[derive(Debug)]
pub struct XArmLink {
    driver: XArmDriver,
    tcp: TcpCheck,
    owner: Option<ArmLock>,
    /// Stamp of the report last checked, and its verdict.
    checked: Option<(u64, Option<f64>)>,
}

impl XArmLink {
    /// Over a connected driver; `owner` is the arm's lock (none for read-only uses).
    pub fn new(driver: XArmDriver, tcp: TcpCheck, owner: Option<ArmLock>) -> Self {
        Self {
            driver,
            tcp,
            owner,
            checked: None,
        }
    }

    /// The arm's lock, when this link owns the arm.
    pub fn owner(&self) -> Option<&ArmLock> {
        self.owner.as_ref()
    }

    /// The driver, mutably.
    pub fn driver_mut(&mut self) -> &mut XArmDriver {
        &mut self.driver
    }

    /// Compares the last report's TCP with the twin's (the start check).
    ///
    /// # Errors
    /// [`XArmOpenError::Driver`] without a report, [`XArmOpenError::TcpMismatch`].
    pub fn check_tcp(&mut self) -> Result<f64, XArmOpenError> {
        let s = self.driver.last_state().ok_or(XArmError::NoState)?;
        Ok(self
            .tcp
            .check(&s.report.joints5_rad(), &s.report.tcp_pose)?)
    }

    /// The running check of `s` (once per report).
    fn mismatch_m(&mut self, s: &DriverState) -> Option<f64> {
        match self.checked {
            Some((stamp, verdict)) if stamp == s.stamp_ns => verdict,
            _ => {
                let verdict = self
                    .tcp
                    .mismatch_m(&s.report.joints5_rad(), &s.report.tcp_pose);
                self.checked = Some((s.stamp_ns, verdict));
                verdict
            }
        }
    }
}

impl Deref for XArmLink {
    type Target = XArmDriver;
    fn deref(&self) -> &XArmDriver {
        &self.driver
    }
}

/// A simulation-only flag (`--no-lookahead`, blind mode; `--auto-resume`, resuming after a
/// lost link without the operator) asked for a robot address that is not known to be this
/// machine's loopback: those flags are for `xarm-sim` on this machine only.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "{flag} is refused for the non-loopback robot address {addr}: {why} ({reason}; no \
     connection was attempted)"
)]
pub struct BlindModeError {
    /// The flag refused.
    pub flag: &'static str,
    /// What the flag is for, in words.
    pub why: &'static str,
    /// The address as given (`HOST[:PORT]`).
    pub addr: String,
    /// Why it is not loopback.
    pub reason: LoopbackCheckError,
}

/// What blind mode is, for [`BlindModeError`].
const BLIND_MODE: (&str, &str) = (
    "--no-lookahead",
    "blind mode is a simulation-only demonstration",
);

/// What `--auto-resume` is, for [`BlindModeError`].
const AUTO_RESUME: (&str, &str) = (
    "--auto-resume",
    "resuming after a lost link without the operator's acknowledgement is for simulated \
     arms only",
);

/// Decides, before any connection (nothing is sent to `addr`), whether blind mode may
/// drive the controller at `addr` (`HOST[:PORT]`, as [`open_xarm`] takes it): only if it
/// is, or resolves only to, loopback addresses (127.0.0.0/8, `::1`; `localhost`), i.e.
/// `xarm-sim` on this machine. Call it before [`open_xarm`] whenever `--no-lookahead` is on.
///
/// # Errors
/// [`BlindModeError`] naming the address and why it is refused.
pub fn check_blind_mode_target(addr: &str) -> Result<(), BlindModeError> {
    simulation_only_verdict(
        BLIND_MODE,
        addr,
        XArmConfig::from_addr(addr).check_loopback_only(),
    )
}

/// The same decision as [`check_blind_mode_target`] (one check) for `--auto-resume`: a
/// real arm waits for the operator's acknowledgement after a lost link; only `xarm-sim` on
/// this machine may resume on its own.
///
/// # Errors
/// [`BlindModeError`] naming `--auto-resume`, the address and why it is refused.
pub fn check_auto_resume_target(addr: &str) -> Result<(), BlindModeError> {
    simulation_only_verdict(
        AUTO_RESUME,
        addr,
        XArmConfig::from_addr(addr).check_loopback_only(),
    )
}

/// [`check_blind_mode_target`] with the name resolution injected (`resolve(host, port)`,
/// not called for an IP literal), for tests.
///
/// # Errors
/// As [`check_blind_mode_target`].
pub fn check_blind_mode_target_with<R>(addr: &str, resolve: R) -> Result<(), BlindModeError>
where
    R: FnOnce(&str, u16) -> std::io::Result<Vec<IpAddr>>,
{
    simulation_only_verdict(
        BLIND_MODE,
        addr,
        XArmConfig::from_addr(addr).check_loopback_only_with(resolve),
    )
}

fn simulation_only_verdict(
    (flag, why): (&'static str, &'static str),
    addr: &str,
    checked: Result<(), LoopbackCheckError>,
) -> Result<(), BlindModeError> {
    checked.map_err(|reason| BlindModeError {
        flag,
        why,
        addr: addr.to_owned(),
        reason,
    })
}

/// `--simulated-sensors`, for [`SimRights`]: the launcher's synthetic camera or bundled
/// calibration.
pub const SIMULATED_SENSORS: (&str, &str) = (
    "--simulated-sensors",
    "a real arm is driven only from a live camera and an explicit calibration",
);

/// The blind-mode flag, for [`SimRights`].
pub const BLIND_MODE_FLAG: (&str, &str) = BLIND_MODE;

/// The auto-resume flag, for [`SimRights`].
pub const AUTO_RESUME_FLAG: (&str, &str) = AUTO_RESUME;

/// The simulation-only rights a run asks for, and the secret the controller must prove it
/// holds before they are granted ([`XArmConfig::sim_secret`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SimRights {
    /// The flags asked for, in words (`--no-lookahead, --auto-resume`).
    pub flags: String,
    /// The run's secret.
    pub secret: SimSecret,
}

/// Why simulation-only rights are refused before any connection.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SimRightsError {
    /// The address is not loopback.
    #[error(transparent)]
    NotLoopback(#[from] BlindModeError),
    /// No secret: nothing at the address can prove it is `xarm-sim`.
    #[error(
        "{flags} refused for the robot at {addr}: no simulator secret in {SIM_SECRET_ENV}, so \
         nothing there can prove it is xarm-sim and it is treated as a real arm, whatever its \
         address (foresight gives the xarm-sim it starts and rt-core one secret per run; \
         start xarm-sim by hand with the same {SIM_SECRET_ENV} as rt-core). No connection \
         was attempted"
    )]
    NoSecret {
        /// The flags asked for.
        flags: String,
        /// The address as given.
        addr: String,
    },
    /// The secret in the environment is malformed.
    #[error("{flags} refused for the robot at {addr}: {reason}. No connection was attempted")]
    BadSecret {
        /// The flags asked for.
        flags: String,
        /// The address as given.
        addr: String,
        /// What is wrong with it.
        reason: SimSecretError,
    },
}

/// Decides, before any connection, whether the simulation-only rights `asked` (flag, what
/// it is for) may be asked of the controller at `addr`: none asked, `Ok(None)`; otherwise
/// the address must be loopback (as [`check_blind_mode_target`]) and `secret` (rt-core's
/// [`SIM_SECRET_ENV`]) present. The rights are granted only once the controller has
/// proven it holds `secret` ([`open_xarm`] with [`XArmOpenOptions::sim_rights`]).
///
/// # Errors
/// [`SimRightsError`] naming the flags, the address and why.
pub fn sim_rights_for(
    addr: &str,
    asked: &[(&'static str, &'static str)],
    secret: Result<Option<SimSecret>, SimSecretError>,
) -> Result<Option<SimRights>, SimRightsError> {
    let Some(first) = asked.first() else {
        return Ok(None);
    };
    simulation_only_verdict(
        *first,
        addr,
        XArmConfig::from_addr(addr).check_loopback_only(),
    )?;
    let flags = asked.iter().map(|(f, _)| *f).collect::<Vec<_>>().join(", ");
    match secret {
        Ok(Some(secret)) => Ok(Some(SimRights { flags, secret })),
        Ok(None) => Err(SimRightsError::NoSecret {
            flags,
            addr: addr.to_owned(),
        }),
        Err(reason) => Err(SimRightsError::BadSecret {
            flags,
            addr: addr.to_owned(),
            reason,
        }),
    }
}

/// How [`open_xarm`] connects.
#[derive(Debug, Clone, PartialEq)]
pub struct XArmOpenOptions {
    /// Overrides the report stream's port.
    pub report_port: Option<u16>,
    /// Leave the arm's mode as it is and send nothing.
    pub dry_run: bool,
    /// The operator asked (`--clear-errors`) to clear the controller's error and warning
    /// before entering servo mode. Without it an error at start is reported, not cleared.
    pub clear_errors: bool,
    /// The first target after a reconnect or an acknowledgement may differ from the
    /// reported joints by this much (one period at the joint velocity limit), rad.
    pub max_resume_step_rad: f64,
    /// Re-enter servo mode after a reconnect without an operator (simulated arms only).
    pub resume_after_reconnect: bool,
    /// Largest distance between the twin's TCP and the controller's reported TCP, m
    /// (`shield.max_tcp_gap_m`; [`MAX_TCP_GAP_M`] by default).
    pub max_tcp_gap_m: f64,
    /// Simulation-only rights asked for ([`sim_rights_for`]): the controller must prove it
    /// is this run's `xarm-sim` at connect, and at every reconnect, or nothing more is sent.
    /// `None`: no challenge; the arm is driven as a real arm.
    pub sim_rights: Option<SimRights>,
}

/// Connects to the controller at `addr` (`HOST[:PORT]`) and, unless `dry_run` (the arm's
/// mode is then left as it is), enters servo mode from the joints where the arm stands.
/// In order: the arm's lock (not for a dry run, which sends nothing), the connection (the
/// handshake refuses anything but an xArm5; with `opts.sim_rights`, anything but this run's
/// `xarm-sim`), the TCP check against `model` (tolerance
/// `opts.max_tcp_gap_m`), then servo mode. The controller's error is cleared only with
/// `clear_errors` (an operator's action).
///
/// # Errors
/// [`XArmOpenError::Owned`] when another process owns the arm (nothing was sent);
/// [`XArmOpenError::NotSimulator`] when simulation-only rights were asked for and the
/// controller did not prove it is `xarm-sim` (only `GET_VERSION` and the challenge were
/// sent); [`XArmOpenError::TcpMismatch`] (nothing was moved); [`XArmOpenError::Driver`] from the
/// connection or the servo-mode entry ([`XArmError::NotXArm5`]; [`XArmError::Controller`]
/// when the controller reports an error and `clear_errors` is off).
pub fn open_xarm(
    addr: &str,
    opts: &XArmOpenOptions,
    model: &RobotModel,
) -> Result<XArmLink, XArmOpenError> {
    let mut cfg = XArmConfig::from_addr(addr);
    if let Some(port) = opts.report_port {
        cfg.report_port = port;
    }
    cfg.max_resume_step_rad = opts.max_resume_step_rad;
    cfg.resume_after_reconnect = opts.resume_after_reconnect;
    cfg.sim_secret = opts.sim_rights.as_ref().map(|r| r.secret.clone());
    let owner = if opts.dry_run {
        None
    } else {
        Some(ArmLock::acquire(&cfg)?)
    };
    let driver = XArmDriver::connect(cfg).map_err(|e| match (e, &opts.sim_rights) {
        (XArmError::NotSimulator(reason), Some(rights)) => XArmOpenError::NotSimulator {
            flags: rights.flags.clone(),
            addr: addr.to_owned(),
            reason,
        },
        (e, _) => XArmOpenError::Driver(e),
    })?;
    if let Some(rights) = &opts.sim_rights {
        tracing::info!(
            addr,
            flags = rights.flags,
            "the controller proved it is this run's xarm-sim: simulation-only rights granted"
        );
    }
    let mut link = XArmLink::new(
        driver,
        TcpCheck::new(model.clone(), opts.max_tcp_gap_m),
        owner,
    );
    let gap_m = link.check_tcp()?;
    tracing::info!(
        addr,
        gap_mm = gap_m * 1e3,
        "the twin's TCP matches the controller's"
    );
    let driver = link.driver_mut();
    if opts.dry_run {
        tracing::warn!(
            addr,
            "dry run: the arm's mode is left as it is; no command is sent"
        );
    } else {
        let q = if opts.clear_errors {
            tracing::warn!(
                addr,
                "--clear-errors: clearing the controller's error and warning"
            );
            driver.start_servo_mode()?
        } else {
            driver.enter_servo_mode()?
        };
        tracing::info!(addr, joints_rad = ?q, "xArm in servo mode");
    }
    Ok(link)
}

/// Maps a driver error to the cycle's link error.
pub fn link_error(e: XArmError) -> LinkError {
    match e {
        XArmError::Controller(c) => LinkError::ControllerError(u16::from(u8::from(c))),
        XArmError::NoState | XArmError::Backlog | XArmError::ErrorPending => LinkError::NoState,
        XArmError::NotReady { .. } | XArmError::ResumeJump { .. } | XArmError::JointLimit(_) => {
            LinkError::Refused
        }
        XArmError::Io(_)
        | XArmError::Timeout
        | XArmError::Disconnected
        | XArmError::Frame(_)
        | XArmError::Report(_)
        | XArmError::NotXArm5 { .. }
        | XArmError::NotSimulator(_) => LinkError::Disconnected,
    }
}

// The adapter is the one place the runtime calls the driver's `read_state`/`send_servo`
// (banned elsewhere in rt-core by clippy.toml: the cycle goes through `RobotLink`).
#[allow(clippy::disallowed_methods)]
impl RobotLink for XArmDriver {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        let s = match XArmDriver::read_state(self, now_ns) {
            Ok(s) => s,
            // A controller error with a fresh report: the cycle gets the state and the
            // code (it latches a protective stop where the arm stands).
            Err(XArmError::Controller(code)) => match self.last_state() {
                Some(s) if now_ns.saturating_sub(s.stamp_ns) <= self.config().stale_after_ns => {
                    DriverState { error: code, ..s }
                }
                _ => return Err(link_error(XArmError::Controller(code))),
            },
            Err(e) => return Err(link_error(e)),
        };
        Ok(LinkState {
            stamp_ns: s.stamp_ns,
            q_rad: s.report.joints5_rad(),
            dq_rad_s: s.dq_rad_s,
            error_code: u16::from(u8::from(s.error)),
            mode: s.report.mode,
            state: s.report.state,
            model_mismatch_m: None,
            session: s.reconnects,
        })
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        XArmDriver::send_servo(self, now_ns, q_rad).map_err(link_error)
    }

    fn acknowledge(&mut self, now_ns: u64) -> Result<(), LinkError> {
        XArmDriver::acknowledge(self, now_ns).map_err(link_error)
    }

    fn hold_controller(&mut self, now_ns: u64) {
        // One pipelined SET_STATE(4): the controller stops where the arm stands.
        XArmDriver::stop(self, now_ns);
    }

    fn stop_controller(&mut self, _now_ns: u64) {
        // Blocking (the loop has ended): SET_STATE 4 until the controller reads 4.
        if let Err(e) = XArmDriver::emergency_stop(self) {
            tracing::error!(error = %e, "could not put the controller in its stop state");
        } else {
            tracing::info!("controller in its stop state (SET_STATE 4)");
        }
    }
}

impl RobotLink for XArmLink {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        let mut st = RobotLink::read_state(&mut self.driver, now_ns)?;
        if let Some(s) = self.driver.last_state() {
            st.model_mismatch_m = self.mismatch_m(&s);
        }
        Ok(st)
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        RobotLink::send_servo(&mut self.driver, now_ns, q_rad)
    }

    fn acknowledge(&mut self, now_ns: u64) -> Result<(), LinkError> {
        RobotLink::acknowledge(&mut self.driver, now_ns)
    }

    fn hold_controller(&mut self, now_ns: u64) {
        RobotLink::hold_controller(&mut self.driver, now_ns);
    }

    fn stop_controller(&mut self, now_ns: u64) {
        RobotLink::stop_controller(&mut self.driver, now_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use xarm::codes::ControllerError;
    use xarm::limits::JointCheckError;

    #[test]
    fn blind_mode_is_allowed_on_loopback_only() {
        for addr in [
            "127.0.0.1",
            "127.0.0.1:5020",
            "127.0.1.1",
            "::1",
            "[::1]:502",
            "localhost",
            "localhost:5020",
        ] {
            assert_eq!(check_blind_mode_target(addr), Ok(()), "{addr}");
        }
        for addr in ["10.0.0.2", "192.168.1.195", "192.168.1.195:502", "0.0.0.0"] {
            let e = check_blind_mode_target(addr).expect_err(addr);
            assert!(
                matches!(e.reason, LoopbackCheckError::NotLoopback(_)),
                "{addr}"
            );
            let msg = e.to_string();
            assert!(
                msg.contains(&format!("non-loopback robot address {addr}"))
                    && msg.contains("simulation-only"),
                "{msg}"
            );
        }
    }

    /// Issue 25 item 7: `--auto-resume` is decided by the same address check as blind mode.
    #[test]
    fn auto_resume_is_refused_off_loopback_by_the_same_check() {
        for addr in ["127.0.0.1:5020", "[::1]:502", "localhost"] {
            assert_eq!(check_auto_resume_target(addr), Ok(()), "{addr}");
        }
        for addr in ["10.0.0.2", "192.168.1.195:502", "0.0.0.0"] {
            let e = check_auto_resume_target(addr).expect_err(addr);
            assert_eq!(
                e.reason,
                check_blind_mode_target(addr).expect_err(addr).reason
            );
            let msg = e.to_string();
            assert!(
                msg.starts_with(&format!(
                    "--auto-resume is refused for the non-loopback robot address {addr}"
                )) && msg.contains("no connection was attempted"),
                "{msg}"
            );
        }
    }

    /// Issue 30 item 1: simulation rights go by identity; before any connection they need a
    /// loopback address and the run's secret, and name every flag asked for.
    #[test]
    fn simulation_rights_need_loopback_and_the_secret_before_any_connection() {
        let secret = SimSecret::generate().expect("random");
        assert_eq!(
            sim_rights_for("192.168.1.195", &[], Ok(None)),
            Ok(None),
            "nothing asked, nothing needed"
        );
        let both = [BLIND_MODE_FLAG, AUTO_RESUME_FLAG];
        let granted = sim_rights_for("127.0.0.1:5020", &both, Ok(Some(secret.clone())))
            .expect("loopback with a secret")
            .expect("rights asked");
        assert_eq!(granted.flags, "--no-lookahead, --auto-resume");
        assert_eq!(granted.secret, secret);
        let e = sim_rights_for("10.0.0.2", &[SIMULATED_SENSORS], Ok(Some(secret)))
            .expect_err("off loopback");
        assert!(
            e.to_string().starts_with(
                "--simulated-sensors is refused for the non-loopback robot address 10.0.0.2"
            ),
            "{e}"
        );
        let e = sim_rights_for("127.0.0.1:5020", &both, Ok(None)).expect_err("no secret");
        let m = e.to_string();
        assert!(
            m.starts_with("--no-lookahead, --auto-resume refused for the robot at 127.0.0.1:5020")
                && m.contains("no simulator secret in FORESIGHT_SIM_SECRET")
                && m.contains("treated as a real arm")
                && m.contains("No connection was attempted"),
            "{m}"
        );
        let e = sim_rights_for(
            "localhost",
            &[AUTO_RESUME_FLAG],
            Err(SimSecretError::NotHex),
        )
        .expect_err("bad secret");
        assert!(e.to_string().contains("not a hexadecimal digit"), "{e}");
        let refused = XArmOpenError::NotSimulator {
            flags: "--no-lookahead".into(),
            addr: "127.0.0.1:502".into(),
            reason: SimIdentityError::Unsupported { status: 0x18 },
        };
        let m = refused.to_string();
        assert!(
            m.starts_with("--no-lookahead refused for the robot at 127.0.0.1:502")
                && m.contains("real arm")
                && m.contains("nothing was moved"),
            "{m}"
        );
        assert_eq!(
            link_error(XArmError::NotSimulator(SimIdentityError::WrongProof)),
            LinkError::Disconnected
        );
    }

    #[test]
    fn blind_mode_refuses_a_name_resolving_elsewhere() {
        let far: IpAddr = "192.168.1.195".parse().expect("ip");
        let lo: IpAddr = "127.0.0.1".parse().expect("ip");
        assert_eq!(
            check_blind_mode_target_with("xarm.lab", |_, _| Ok(vec![lo])),
            Ok(())
        );
        for ips in [vec![far], vec![lo, far]] {
            assert_eq!(
                check_blind_mode_target_with("xarm.lab", move |_, _| Ok(ips)),
                Err(BlindModeError {
                    flag: "--no-lookahead",
                    why: BLIND_MODE.1,
                    addr: "xarm.lab".into(),
                    reason: LoopbackCheckError::NotLoopback(far)
                })
            );
        }
        let unresolved = check_blind_mode_target_with("xarm.lab", |_, _| {
            Err(std::io::ErrorKind::NotFound.into())
        });
        assert!(
            matches!(
                unresolved,
                Err(BlindModeError {
                    reason: LoopbackCheckError::Unresolved(_),
                    ..
                })
            ),
            "{unresolved:?}"
        );
    }

    fn model() -> RobotModel {
        let urdf = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .ancestors()
            .map(|d| d.join("assets/xarm5.urdf"))
            .find(|p| p.is_file())
            .expect("assets/xarm5.urdf above the crate");
        RobotModel::load(&urdf).expect("urdf")
    }

    #[test]
    fn the_tcp_check_refuses_a_reported_tcp_beyond_5_mm_naming_both_poses() {
        let mut check = TcpCheck::new(model(), MAX_TCP_GAP_M);
        let q = [0.3, -0.4, -0.5, 0.9, 0.2];
        let t = check.twin_tcp_mm(&q);
        let pose = |dx_mm: f64| {
            [
                (t[0] + dx_mm) as f32,
                t[1] as f32,
                t[2] as f32,
                3.1,
                0.0,
                0.3,
            ]
        };
        assert!(check.gap_m(&q, &pose(0.0)) < 1e-6);
        assert_eq!(check.mismatch_m(&q, &pose(4.0)), None);
        assert!(check.check(&q, &pose(4.0)).is_ok());
        let gap = check
            .mismatch_m(&q, &pose(10.0))
            .expect("10 mm is a mismatch");
        assert!((gap - 0.010).abs() < 1e-6, "{gap}");
        let e = check.check(&q, &pose(10.0)).expect_err("refused");
        assert!((e.gap_mm - 10.0).abs() < 1e-3, "{e:?}");
        let msg = e.to_string();
        let twin_x = format!("{:.1}", t[0]);
        let reported_x = format!("{:.1}", t[0] + 10.0);
        assert!(
            msg.contains(&twin_x) && msg.contains(&reported_x) && msg.contains("10.0 mm apart"),
            "{msg}"
        );
        let mut nan = pose(0.0);
        nan[0] = f32::NAN;
        assert!(check.mismatch_m(&q, &nan).is_some());
    }

    #[test]
    fn errors_map_onto_the_cycle_vocabulary() {
        assert_eq!(
            link_error(XArmError::Controller(ControllerError::Collision)),
            LinkError::ControllerError(31)
        );
        assert_eq!(link_error(XArmError::NoState), LinkError::NoState);
        assert_eq!(link_error(XArmError::Disconnected), LinkError::Disconnected);
        assert_eq!(
            link_error(XArmError::JointLimit(JointCheckError::OutOfRange {
                joint: 1
            })),
            LinkError::Refused
        );
        assert_eq!(
            link_error(XArmError::ResumeJump { joint: 0 }),
            LinkError::Refused
        );
    }
}
