//! [`CycleReport`]: what the cycle reports after each call, to the twin thread (through the
//! latest-value hand-over) and to telemetry.

use super::{Mode, StopReason};
use crate::cycle::plan::MotionState;
use twin::Joints;

/// What the cycle reports after each call (to the twin and telemetry).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleReport {
    /// Time of the cycle, ns.
    pub t_ns: u64,
    /// Cycles run.
    pub cycles: u64,
    /// Mode after the cycle.
    pub mode: Mode,
    /// The plan running (or last run), 0 for none.
    pub plan_id: u64,
    /// Its policy.
    pub policy_id: u64,
    /// Next sample of that plan to be sent.
    pub next_index: usize,
    /// The command sent.
    pub cmd: MotionState,
    /// The arm's measured joints, rad.
    pub measured_q_rad: Joints,
    /// Clearance of the command to the live scene, m.
    pub clearance_m: f64,
    /// Reason of the last stop.
    pub stop_reason: StopReason,
    /// Stops so far.
    pub stops: u64,
    /// The last plan refused, 0 for none.
    pub last_refused_plan_id: u64,
    /// Plans adopted or joined so far.
    pub plans_taken: u64,
    /// The controller's error code (0 = none).
    pub arm_error_code: u16,
    /// The controller's mode (from its report).
    pub arm_mode: u8,
    /// The controller's state (from its report).
    pub arm_state: u8,
    /// Latched after a protective stop: nothing is sent until an operator acknowledges.
    pub awaiting_ack: bool,
    /// Protective stops latched so far: the number of the one latched now, which an
    /// operator's acknowledgement must name.
    pub latch_seq: u64,
    /// Commands that failed the check and were not sent as picked.
    pub commands_refused: u64,
    /// Stops where the next command already failed the clearance check: an obstacle
    /// appeared inside the stop envelope (the unavoidable case).
    pub envelope_breaches: u64,
    /// A shutdown was requested and the arm is at rest: the cycle may end.
    pub shutdown_complete: bool,
    /// The largest joint gap between the last command sent and the measured joints, rad
    /// (the tracking check's input; 0 when not checked).
    pub tracking_error_rad: f64,
    /// Acknowledgements dropped (given while the link was down or the arm stopping).
    pub acks_dropped: u64,
    /// The plan's playback speed scale, 0..=1 (speed and separation monitoring; 1 when
    /// off).
    pub speed_scale: f64,
    /// The separation the scale was set by: the last command's distance to the live
    /// scene's obstacles, m (infinite when the monitoring is off).
    pub separation_m: f64,
    /// Acknowledgements refused: they named a stop other than the one latched.
    pub acks_refused: u64,
    /// Stops the plan guard scheduled that a joining plan made unnecessary: the arm went
    /// on without stopping (issue 33 item 5).
    pub joins_before_stop: u64,
}
