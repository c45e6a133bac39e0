//! [`RobotState`]: the arm's state and the control cycle's statistics, published every
//! cycle (rt-core → anyone).

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, finite_f32, finite_f64, flag};

/// Joints of the xArm5.
pub const N_JOINTS: usize = 5;

/// Why the cycle is in a controlled stop. Stored as a `u8`; convert with `try_from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum StopReason {
    /// Not stopped.
    None = 0,
    /// No approved plan yet (start-up, or waiting after a stop).
    NoPlan = 1,
    /// The shield rejected a command (limits, workspace, clearance).
    ShieldViolation = 2,
    /// Detections older than the configured age.
    StaleDetections = 3,
    /// Robot state older than the configured age.
    StaleRobotState = 4,
    /// The link to the arm was lost.
    LinkLost = 5,
    /// The arm controller reported an error.
    ArmError = 6,
    /// An operator or shutdown request.
    Requested = 7,
    /// A detection frame was refused (overfull, stale stamp, outside the calibrated
    /// workspace, a second publisher): the scene cannot be trusted.
    DetectionRefused = 8,
    /// The twin's model and the controller disagree (e.g. the TCP pose it reports).
    ModelMismatch = 9,
}

impl TryFrom<u8> for StopReason {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        Ok(match value {
            0 => Self::None,
            1 => Self::NoPlan,
            2 => Self::ShieldViolation,
            3 => Self::StaleDetections,
            4 => Self::StaleRobotState,
            5 => Self::LinkLost,
            6 => Self::ArmError,
            7 => Self::Requested,
            8 => Self::DetectionRefused,
            9 => Self::ModelMismatch,
            _ => {
                return Err(SchemaError::BadEnum {
                    field: "stop_reason",
                    value: u32::from(value),
                });
            }
        })
    }
}

/// The arm and the cycle, once per cycle. The `arm_*` codes are the xArm controller's raw
/// report values (mode, state, error and warning codes as documented by UFactory), passed
/// through unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::RobotState.v2")]
pub struct RobotState {
    /// When the state was sampled, `CLOCK_MONOTONIC` (ns).
    pub time_ns: u64,
    /// Cycles run since start.
    pub cycle_count: u64,
    /// Cycles that overran their period since start.
    pub missed_deadlines: u64,
    /// The policy currently in use (0 = none).
    pub active_policy_id: u64,
    /// Measured joint positions (rad).
    pub joints_rad: [f64; N_JOINTS],
    /// Measured (or estimated) joint velocities (rad/s).
    pub joint_velocities_rad_s: [f64; N_JOINTS],
    /// The joint position commanded this cycle (rad).
    pub command_joints_rad: [f64; N_JOINTS],
    /// TCP position in the base frame (m).
    pub tcp_m: [f64; 3],
    /// Compute time of the last cycle (µs).
    pub last_compute_us: f32,
    /// 99th percentile of cycle compute time over a recent window (µs).
    pub p99_compute_us: f32,
    /// xArm mode (raw).
    pub arm_mode: u8,
    /// xArm state (raw).
    pub arm_state: u8,
    /// xArm error code (raw, 0 = none).
    pub arm_error_code: u8,
    /// xArm warning code (raw, 0 = none).
    pub arm_warning_code: u8,
    /// 1 while the cycle holds the arm in a controlled stop.
    pub controlled_stop: u8,
    /// [`StopReason`] as a byte.
    pub stop_reason: u8,
    /// 1 while the link to the arm is up.
    pub link_ok: u8,
    /// Reserved, zero.
    pub reserved: u8,
}

const _: () = assert!(size_of::<RobotState>() == 32 + 18 * 8 + 8 + 8);

impl RobotState {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 2;

    /// `controlled_stop == 1`.
    pub fn is_stopped(&self) -> bool {
        self.controlled_stop == 1
    }

    /// The stop reason, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn stop_reason(&self) -> Result<StopReason, SchemaError> {
        StopReason::try_from(self.stop_reason)
    }

    /// Checks flags, the stop-reason byte and finite numbers.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        flag("controlled_stop", self.controlled_stop)?;
        flag("link_ok", self.link_ok)?;
        self.stop_reason()?;
        finite_f64("joints_rad", &self.joints_rad)?;
        finite_f64("joint_velocities_rad_s", &self.joint_velocities_rad_s)?;
        finite_f64("command_joints_rad", &self.command_joints_rad)?;
        finite_f64("tcp_m", &self.tcp_m)?;
        finite_f32("last_compute_us", &[self.last_compute_us])?;
        finite_f32("p99_compute_us", &[self.p99_compute_us])?;
        Ok(())
    }
}
