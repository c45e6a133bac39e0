//! [`RobotLink`] for [`XArmDriver`]: the cycle's view of the real (or simulated) arm.
//!
//! Error mapping (the cycle's `LinkError` is deliberately small): a controller error code
//! → `ControllerError(code)`; a target refused before it reached the arm (outside the SDK's
//! limits, a jump after a reconnect, the controller not ready) → `Refused`; no fresh
//! report, a full pipeline or an error whose code is still being read → `NoState` (the
//! cycle holds and stops on staleness); everything else (lost connection, malformed bytes)
//! → `Disconnected`.

use crate::cycle::link::{LinkError, LinkState, RobotLink};
use std::net::IpAddr;
use twin::Joints;
use xarm::config::LoopbackCheckError;
use xarm::driver::{DriverState, XArmConfig, XArmDriver, XArmError};

/// `--no-lookahead` (blind mode) asked for a robot address that is not known to be this
/// machine's loopback: blind mode is a demonstration on the simulated arm only.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--no-lookahead is refused for the non-loopback robot address {addr}: blind mode is a \
     simulation-only demonstration ({reason}; no connection was attempted)"
)]
pub struct BlindModeError {
    /// The address as given (`HOST[:PORT]`).
    pub addr: String,
    /// Why it is not loopback.
    pub reason: LoopbackCheckError,
}

/// Decides, before any connection (nothing is sent to `addr`), whether blind mode may
/// drive the controller at `addr` (`HOST[:PORT]`, as [`open_xarm`] takes it): only if it
/// is, or resolves only to, loopback addresses (127.0.0.0/8, `::1`; `localhost`), i.e.
/// `xarm-sim` on this machine. Call it before [`open_xarm`] whenever `--no-lookahead` is on.
///
/// # Errors
/// [`BlindModeError`] naming the address and why it is refused.
pub fn check_blind_mode_target(addr: &str) -> Result<(), BlindModeError> {
    blind_mode_verdict(addr, XArmConfig::from_addr(addr).check_loopback_only())
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
    blind_mode_verdict(
        addr,
        XArmConfig::from_addr(addr).check_loopback_only_with(resolve),
    )
}

fn blind_mode_verdict(
    addr: &str,
    checked: Result<(), LoopbackCheckError>,
) -> Result<(), BlindModeError> {
    checked.map_err(|reason| BlindModeError {
        addr: addr.to_owned(),
        reason,
    })
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
}

/// Connects to the controller at `addr` (`HOST[:PORT]`) and, unless `dry_run` (the arm's
/// mode is then left as it is), enters servo mode from the joints where the arm stands.
/// The controller's error is cleared only with `clear_errors` (an operator's action).
///
/// # Errors
/// [`XArmError`] from the connection or the servo-mode entry
/// ([`XArmError::Controller`] when the controller reports an error and `clear_errors` is off).
pub fn open_xarm(addr: &str, opts: &XArmOpenOptions) -> Result<XArmDriver, XArmError> {
    let mut cfg = XArmConfig::from_addr(addr);
    if let Some(port) = opts.report_port {
        cfg.report_port = port;
    }
    cfg.max_resume_step_rad = opts.max_resume_step_rad;
    cfg.resume_after_reconnect = opts.resume_after_reconnect;
    let mut driver = XArmDriver::connect(cfg)?;
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
    Ok(driver)
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
        | XArmError::Report(_) => LinkError::Disconnected,
    }
}

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
        })
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        XArmDriver::send_servo(self, now_ns, q_rad).map_err(link_error)
    }

    fn acknowledge(&mut self, now_ns: u64) -> Result<(), LinkError> {
        XArmDriver::acknowledge(self, now_ns).map_err(link_error)
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
