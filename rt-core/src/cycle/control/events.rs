//! What the cycle says about itself: its [`Mode`], the typed [`CycleEvent`]s it logs through
//! the log ring (formatted only by the thread that drains it), and the [`StopReason`] of the
//! last controlled stop. All `Copy`, so the cycle logs and reports them without allocating.

use crate::cycle::link::LinkError;
use crate::cycle::shield::ShieldViolation;

/// What the cycle is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[repr(u8)]
pub enum Mode {
    /// At rest, waiting for a first plan.
    #[default]
    Idle = 0,
    /// Streaming an approved plan.
    Following = 1,
    /// Braking to zero velocity.
    Stopping = 2,
    /// At rest after a controlled stop; waits for a fresh plan.
    Stopped = 3,
}

/// What the cycle logs: typed and `Copy` (ids stay `u64`), formatted only on the thread
/// that drains the log ring.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CycleEvent {
    /// The cycle started.
    Started {
        /// The cycle period, ns.
        period_ns: u64,
    },
    /// A new plan was adopted.
    PlanAdopted {
        /// Plan id.
        plan_id: u64,
        /// Policy id.
        policy_id: u64,
    },
    /// A plan was scheduled to take over the running one at a join index.
    PlanScheduled {
        /// Plan id.
        plan_id: u64,
        /// Sample of the running plan where it takes over.
        join_index: usize,
    },
    /// A plan was refused (discontinuous, late, or while stopping).
    PlanRefused {
        /// Plan id.
        plan_id: u64,
    },
    /// A plan was completed.
    PlanFinished {
        /// Plan id.
        plan_id: u64,
    },
    /// The running plan reached the sample where the plan guard scheduled its stop
    /// ([`super::CycleControl::schedule_stop`]) with no joining plan taken over: the
    /// cycle stops along it.
    StopDue {
        /// Plan id.
        plan_id: u64,
        /// The sample the stop was due from.
        index: usize,
    },
    /// A joining plan took over from a running plan with a stop scheduled: the arm went on
    /// without stopping.
    JoinedBeforeStop {
        /// The plan left.
        from_plan_id: u64,
        /// The plan joined.
        plan_id: u64,
    },
    /// The twin revoked the running plan (or a pending one).
    PlanRevoked {
        /// Plan id.
        plan_id: u64,
        /// The revocation's cause: capture time of the scene that made it, the cycle's
        /// clock, ns (0 = not known).
        capture_ns: u64,
        /// … and when that scene was accepted, ns (0 = not known).
        accepted_ns: u64,
    },
    /// A controlled stop began.
    StopBegun {
        /// Why.
        reason: StopReason,
    },
    /// The arm stands still after a controlled stop.
    Stopped,
    /// The link refused a command or is lost.
    LinkError {
        /// The link's error.
        error: LinkError,
    },
    /// A command failed the check and was not sent.
    CommandRefused {
        /// Why.
        violation: ShieldViolation,
        /// Capture time of the scene it was checked against, the cycle's clock, ns (0:
        /// none).
        scene_capture_ns: u64,
    },
    /// The controller reports an error; the cycle is latched until acknowledged.
    ArmError {
        /// The controller's error code.
        code: u16,
    },
    /// The twin's TCP and the controller's differ: a controlled stop, latched at rest.
    ModelMismatch {
        /// The distance between the two TCPs, m.
        gap_m: f64,
    },
    /// The link returned while stopping: the stop ends at the measured joints.
    SnappedToMeasured,
    /// A stop ended at once at the last command sent, whatever the (possibly lagging)
    /// measured joints say: the controller holds it as its target (the robot state returned
    /// on the same connection after it had been late or missing, or the cycle itself froze).
    HeldAtLastSent,
    /// The controller left its ready state without the cycle asking (the pendant's stop,
    /// the SDK, `SET_STATE` from another client): latched until acknowledged.
    ControllerStopped {
        /// The controller's state (3 paused, 4 stopped, …).
        state: u8,
    },
    /// The measured joints stopped following the commands sent (a frozen or blocked arm):
    /// a stop, latched until acknowledged.
    TrackingLost {
        /// The largest joint gap between the last command sent and the measured joints,
        /// rad.
        error_rad: f64,
    },
    /// The cycle itself was not run for longer than the freeze bound (the process stopped
    /// by SIGSTOP or a terminal's Ctrl-Z, a paused VM, a long page fault): the controller got
    /// no target meanwhile, so it holds the arm at the last command sent; the stop ends there.
    Frozen {
        /// Time since the cycle before, ns.
        gap_ns: u64,
    },
    /// An acknowledgement arrived while the link was down or the arm was still stopping:
    /// dropped (an operator acknowledges an arm at rest they can see; a new one is needed).
    AcknowledgementDropped,
    /// An acknowledgement named a stop other than the one latched (an earlier one, or one
    /// that never was): refused, the latch stands.
    AcknowledgementRefused {
        /// The stop the acknowledgement named.
        named_seq: u64,
        /// The stop latched now (0 for none).
        latched_seq: u64,
    },
    /// An operator acknowledged the protective stop; motion was re-enabled.
    Acknowledged {
        /// The stop cleared.
        latch_seq: u64,
    },
    /// An acknowledgement could not be passed to the controller.
    AcknowledgeFailed {
        /// The link's error.
        error: LinkError,
    },
    /// Speed and separation monitoring changed the plan's playback scale by a step (or it
    /// reached 0, the arm at rest on the plan, or 1, full speed again).
    SpeedScaled {
        /// The new scale, 0..=1.
        scale: f64,
    },
    /// The cycle stopped.
    Finished,
}

/// Why the last controlled stop happened.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum StopReason {
    /// No stop so far.
    #[default]
    None,
    /// The shield refused a command.
    Shield(ShieldViolation),
    /// The latest detection is older than allowed (or none arrived).
    StaleDetection,
    /// The latest robot state is older than allowed.
    StaleRobotState,
    /// The robot link is lost.
    LinkLost,
    /// The twin revoked the running plan (the lookahead found it unsafe).
    Revoked,
    /// The controller reports an error (the code is in the report).
    ArmError(u16),
    /// The process is shutting down (signal, time limit, error, panic).
    Shutdown,
    /// The twin refused the latest detection frame (it does not fit, its stamp is not
    /// fresh, an object lies outside the calibrated workspace, a second publisher): the
    /// scene cannot be trusted until a good frame arrives.
    DetectionRefused,
    /// The twin's TCP of the measured joints and the TCP the controller reports differ by
    /// more than the link's tolerance (a wrong model or base calibration): latched, like an
    /// arm error, once the arm is at rest, until an operator acknowledges.
    ModelMismatch,
    /// The controller left its ready state without the cycle asking (the pendant's stop,
    /// the SDK, `SET_STATE 4` from another client): latched like an arm error, until an
    /// operator acknowledges.
    ControllerStopped {
        /// The controller's state when it was seen (3 paused, 4 stopped, …).
        state: u8,
    },
    /// The measured joints did not follow the commands sent for
    /// [`CycleConfig::tracking_error_cycles`](super::CycleConfig::tracking_error_cycles) periods in a row (more than
    /// [`CycleConfig::max_tracking_error_rad`](super::CycleConfig::max_tracking_error_rad) apart): a frozen or blocked arm. Stopped and
    /// latched until an operator acknowledges.
    TrackingLost,
    /// The cycle was not run for longer than the freeze bound while the arm moved
    /// ([`CycleConfig::max_cycle_gap_ns`](super::CycleConfig::max_cycle_gap_ns)): the
    /// stop ends at the measured joints, latched until an operator acknowledges (unless the
    /// arm is simulated and auto-resumes, as after a lost link).
    Frozen,
}

impl StopReason {
    /// A numeric code for logs and telemetry.
    pub fn code(self) -> u8 {
        match self {
            StopReason::None => 0,
            StopReason::Shield(v) => 10 + v.code(),
            StopReason::StaleDetection => 2,
            StopReason::StaleRobotState => 3,
            StopReason::LinkLost => 4,
            StopReason::Revoked => 5,
            StopReason::ArmError(_) => 6,
            StopReason::Shutdown => 7,
            StopReason::DetectionRefused => 8,
            StopReason::ModelMismatch => 9,
            StopReason::ControllerStopped { .. } => 20,
            StopReason::TrackingLost => 21,
            StopReason::Frozen => 22,
        }
    }

    /// What a [`StopReason::code`] means, in words (for the operator's acknowledgement,
    /// which names the stop it clears).
    pub fn describe_code(code: u8) -> &'static str {
        match code {
            0 => "no stop",
            2 => "stale detection",
            3 => "stale robot state",
            4 => "lost link to the controller",
            5 => "plan revoked by the twin",
            6 => "controller error",
            7 => "shutdown",
            8 => "detection refused",
            9 => "model mismatch (twin and controller TCPs differ)",
            10..=19 => "a command the shield refused",
            20 => "controller left its ready state (pendant, SDK or another client)",
            21 => "tracking lost (the arm did not follow its commands)",
            22 => "frozen cycle (the process was not run)",
            _ => "unknown stop",
        }
    }
}
