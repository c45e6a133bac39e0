//! [`RobotLink`] for [`XArmDriver`]: the cycle's view of the real (or simulated) arm.
//!
//! Error mapping (the cycle's `LinkError` is deliberately small): a controller error code
//! → `ControllerError(code)`; no fresh report, a full pipeline, a refused (not-ready) target,
//! an error whose code is still being read or a target that would jump after a reconnect →
//! `NoState` (the cycle holds and stops on staleness); everything else (lost connection,
//! malformed bytes, a target outside the SDK's limits) → `Disconnected`.

use super::driver::{XArmDriver, XArmError};
use crate::runtime::Joints;
use crate::runtime::link::{LinkError, LinkState, RobotLink};

/// Maps a driver error to the cycle's link error.
pub fn link_error(e: XArmError) -> LinkError {
    match e {
        XArmError::Controller(c) => LinkError::ControllerError(u16::from(u8::from(c))),
        XArmError::NoState
        | XArmError::Backlog
        | XArmError::NotReady { .. }
        | XArmError::ErrorPending
        | XArmError::ResumeJump { .. } => LinkError::NoState,
        XArmError::Io(_)
        | XArmError::Timeout
        | XArmError::Disconnected
        | XArmError::Frame(_)
        | XArmError::Report(_)
        | XArmError::JointLimit(_) => LinkError::Disconnected,
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
    use crate::xarm::codes::ControllerError;
    use crate::xarm::limits::JointCheckError;

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
            LinkError::Disconnected
        );
    }
}
