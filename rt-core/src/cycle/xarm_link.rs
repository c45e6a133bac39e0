//! [`RobotLink`] for [`XArmDriver`]: the cycle's view of the real (or simulated) arm.
//!
//! Error mapping (the cycle's `LinkError` is deliberately small): a controller error code
//! → `ControllerError(code)`; a target refused before it reached the arm (outside the SDK's
//! limits, a jump after a reconnect, the controller not ready) → `Refused`; no fresh
//! report, a full pipeline or an error whose code is still being read → `NoState` (the
//! cycle holds and stops on staleness); everything else (lost connection, malformed bytes)
//! → `Disconnected`.

use crate::cycle::link::{LinkError, LinkState, RobotLink};
use twin::Joints;
use xarm::driver::{XArmConfig, XArmDriver, XArmError};

/// Connects to the controller at `addr` (`HOST[:PORT]`; `report_port` overrides the
/// report stream's port) and, unless `dry_run` (the arm's mode is then left as it is),
/// enters servo mode from the joints where the arm stands.
///
/// # Errors
/// [`XArmError`] from the connection or the servo-mode entry.
pub fn open_xarm(
    addr: &str,
    report_port: Option<u16>,
    dry_run: bool,
) -> Result<XArmDriver, XArmError> {
    let mut cfg = XArmConfig::from_addr(addr);
    if let Some(port) = report_port {
        cfg.report_port = port;
    }
    let mut driver = XArmDriver::connect(cfg)?;
    if dry_run {
        tracing::warn!(
            addr,
            "dry run: the arm's mode is left as it is; no command is sent"
        );
    } else {
        let q = driver.start_servo_mode()?;
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
        let s = XArmDriver::read_state(self, now_ns).map_err(link_error)?;
        Ok(LinkState {
            stamp_ns: s.stamp_ns,
            q_rad: s.report.joints5_rad(),
            dq_rad_s: s.dq_rad_s,
            error_code: u16::from(u8::from(s.error)),
        })
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        XArmDriver::send_servo(self, now_ns, q_rad).map_err(link_error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use xarm::codes::ControllerError;
    use xarm::limits::JointCheckError;

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
