//! [`CycleConfig`]: the cycle's timing parameters (period, input ages, braking horizon,
//! tracking tolerance), derived once from the runtime configuration.

use crate::config::RuntimeConfig;
use crate::cycle::brake::PathStop;
use crate::cycle::separation::SeparationParams;
use twin::DOF;

/// Timing parameters of the cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleConfig {
    /// Period, ns.
    pub period_ns: u64,
    /// Maximum detection age, ns.
    pub max_detection_age_ns: u64,
    /// Maximum robot-state age, ns.
    pub max_robot_state_age_ns: u64,
    /// Largest joint gap between the arm's command and a plan's first sample, rad.
    pub start_tolerance_rad: f64,
    /// How many samples ahead of the next command the shield also checks the running plan
    /// against the live scene: about the braking time, so a stop begun now ends before an
    /// obstacle that appears on the path.
    pub brake_horizon_samples: usize,
    /// After the link returns, take fresh plans without an operator's acknowledgement
    /// (opt-in for simulated arms; a real arm waits for the operator).
    pub auto_resume_after_link_loss: bool,
    /// The measured joints may trail the last command sent by this much (largest joint
    /// gap), rad (`tracking.max_error_rad`).
    pub max_tracking_error_rad: f64,
    /// More than [`CycleConfig::max_tracking_error_rad`] for this many periods in a row is
    /// a frozen arm: a latched stop (`tracking.max_error_cycles`).
    pub tracking_error_cycles: u32,
    /// Longest time between two cycles while the arm moves, ns: a longer gap (the process
    /// stopped, a paused VM, a long page fault) is a stop at the measured joints
    /// ([`super::StopReason::Frozen`]), never a resumption from where the plan's clock left
    /// off. `FREEZE_BOUND_PERIODS` periods (at least `FREEZE_BOUND_MIN_PERIODS`).
    pub max_cycle_gap_ns: u64,
    /// Speed and separation monitoring (`[separation]`): the playback scale by separation.
    pub separation: SeparationParams,
}

/// Periods a cycle may come late before it counts as a freeze: 40 ms at 250 Hz, above a
/// shared CI machine's worst wake-up seen (11 ms at p99), so a loaded machine does not
/// latch a real arm; a stopped process is stopped for seconds.
pub const FREEZE_BOUND_PERIODS: u64 = 10;

/// The freeze bound's floor, in periods (issue 41 item 5: it was 100 ms, above the bound
/// itself at 250 Hz, so freezes of 40–100 ms went undetected). The bound is never below
/// two periods: one whole period missed.
pub const FREEZE_BOUND_MIN_PERIODS: u64 = 2;

impl CycleConfig {
    /// From the runtime configuration.
    pub fn from_runtime(cfg: &RuntimeConfig) -> Self {
        Self {
            period_ns: cfg.period_ns(),
            max_detection_age_ns: (cfg.stale.max_detection_age_s * 1e9) as u64,
            max_cycle_gap_ns: FREEZE_BOUND_PERIODS.max(FREEZE_BOUND_MIN_PERIODS) * cfg.period_ns(),
            max_robot_state_age_ns: (cfg.stale.max_robot_state_age_s * 1e9) as u64,
            start_tolerance_rad: 0.02,
            brake_horizon_samples: {
                // The longer of the per-joint brake's and the path stop's travel at full
                // speed, in samples.
                let l = &cfg.limits;
                let brake_s = (0..DOF)
                    .map(|j| {
                        l.max_velocity_rad_s[j] / l.max_acceleration_rad_s2[j]
                            + l.max_acceleration_rad_s2[j] / l.max_jerk_rad_s3[j]
                    })
                    .fold(0.0, f64::max);
                let path_s = 0.5
                    * PathStop::duration_s(
                        &l.max_velocity_rad_s,
                        &l.max_acceleration_rad_s2,
                        1.0 / cfg.rate_hz,
                    );
                (brake_s.max(path_s) * cfg.rate_hz).ceil() as usize
            },
            auto_resume_after_link_loss: false,
            max_tracking_error_rad: cfg.tracking.max_error_rad,
            tracking_error_cycles: cfg.tracking.max_error_cycles,
            separation: SeparationParams::from_runtime(cfg),
        }
    }
}
