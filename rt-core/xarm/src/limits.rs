//! Client-side joint limits of the xArm5 (robot type 5), checked exactly as the official SDK
//! checks them before `set_servo_angle_j`: each of the first five values must lie within
//! `[min − 0.1°, max + 0.1°]`, otherwise nothing goes on the wire (the SDK's code −8).

use std::f64::consts::{PI, TAU};

/// xArm5 joint limits (rad), `[min, max]` per joint, from the SDK's table for type 5.
pub const XARM5_JOINT_LIMITS_RAD: [[f64; 2]; 5] = [
    [-TAU, TAU],
    [-2.059_488, 2.094_395],
    [-3.926_99, 0.191_986],
    [-1.692_969, PI],
    [-TAU, TAU],
];

/// Slack the SDK allows beyond each limit: 0.1° in radians.
pub const LIMIT_SLACK_RAD: f64 = 0.1 * PI / 180.0;

/// Why a joint target was refused before sending.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum JointCheckError {
    /// Joint `joint` (0-based) is outside its limits (with slack).
    #[error("joint {} target is out of range", .joint + 1)]
    OutOfRange {
        /// 0-based joint index.
        joint: u8,
    },
    /// Joint `joint` (0-based) is NaN or infinite.
    #[error("joint {} target is not finite", .joint + 1)]
    NotFinite {
        /// 0-based joint index.
        joint: u8,
    },
}

/// Checks a 5-joint target against [`XARM5_JOINT_LIMITS_RAD`] with [`LIMIT_SLACK_RAD`].
///
/// # Errors
/// The first offending joint.
pub fn check_xarm5_joints(q_rad: &[f64; 5]) -> Result<(), JointCheckError> {
    for (i, (q, [lo, hi])) in q_rad.iter().zip(XARM5_JOINT_LIMITS_RAD).enumerate() {
        let joint = i as u8;
        if !q.is_finite() {
            return Err(JointCheckError::NotFinite { joint });
        }
        if *q < lo - LIMIT_SLACK_RAD || *q > hi + LIMIT_SLACK_RAD {
            return Err(JointCheckError::OutOfRange { joint });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_within_slack_and_rejects_beyond() {
        assert!(check_xarm5_joints(&[0.0; 5]).is_ok());
        let mut q = [0.0; 5];
        q[1] = 2.094_395 + LIMIT_SLACK_RAD * 0.99;
        assert!(check_xarm5_joints(&q).is_ok());
        q[1] = 2.094_395 + LIMIT_SLACK_RAD * 1.01;
        assert_eq!(
            check_xarm5_joints(&q),
            Err(JointCheckError::OutOfRange { joint: 1 })
        );
        // The SDK's captured example: J2 = −2.5 rad is refused.
        assert_eq!(
            check_xarm5_joints(&[0.0, -2.5, 0.0, 0.0, 0.0]),
            Err(JointCheckError::OutOfRange { joint: 1 })
        );
        assert_eq!(
            check_xarm5_joints(&[0.0, 0.0, 0.3, 0.0, 0.0]),
            Err(JointCheckError::OutOfRange { joint: 2 })
        );
        assert_eq!(
            check_xarm5_joints(&[0.0, 0.0, 0.0, 0.0, f64::NAN]),
            Err(JointCheckError::NotFinite { joint: 4 })
        );
    }
}
