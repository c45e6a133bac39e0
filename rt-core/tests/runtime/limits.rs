//! One chain of joint limits: what the runtime streams (`assets/runtime.toml`) lies within
//! the robot model's (`assets/xarm5.urdf`), which lies within what the official SDK lets
//! through for an xArm5 (`xarm::limits`, the controller side's client check).

use rt_core::config::RuntimeConfig;
use twin::DOF;
use xarm::limits::{LIMIT_SLACK_RAD, XARM5_JOINT_LIMITS_RAD};

#[test]
fn runtime_limits_lie_within_the_urdf_which_lies_within_the_sdk() {
    let runtime = RuntimeConfig::xarm5_default().limits;
    let urdf = *crate::twin_common::model().limits();
    // Rounding of the published values (the TOML keeps three decimals).
    const ROUNDING_RAD: f64 = 1e-3;
    for (j, [sdk_lo, sdk_hi]) in XARM5_JOINT_LIMITS_RAD.into_iter().enumerate().take(DOF) {
        assert!(
            runtime.joint_min_rad[j] >= urdf.lower_rad[j] - ROUNDING_RAD
                && runtime.joint_max_rad[j] <= urdf.upper_rad[j] + ROUNDING_RAD,
            "joint {}: runtime [{}, {}] outside the URDF's [{}, {}]",
            j + 1,
            runtime.joint_min_rad[j],
            runtime.joint_max_rad[j],
            urdf.lower_rad[j],
            urdf.upper_rad[j]
        );
        assert!(
            urdf.lower_rad[j] >= sdk_lo - LIMIT_SLACK_RAD
                && urdf.upper_rad[j] <= sdk_hi + LIMIT_SLACK_RAD,
            "joint {}: URDF [{}, {}] outside the SDK's [{sdk_lo}, {sdk_hi}]",
            j + 1,
            urdf.lower_rad[j],
            urdf.upper_rad[j]
        );
        assert!(
            runtime.max_velocity_rad_s[j] <= urdf.velocity_rad_s[j],
            "joint {}: runtime velocity {} above the URDF's {}",
            j + 1,
            runtime.max_velocity_rad_s[j],
            urdf.velocity_rad_s[j]
        );
    }
}
