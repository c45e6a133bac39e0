//! [`TwinEvent`]: what the worker did that the outside should know — published (verdicts,
//! retrain requests), logged, counted by the sweep, asserted on by tests.

use shm_schemas::{Executor, PhaseCode};
use twin::InfeasibleReason;

use super::approve::PlanRejection;
use super::{SampleTag, Verdict};

/// Who produced a verdict, and the worker's phase then (diagnostics of the published
/// verdict and the run timeline).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VerdictSource {
    /// The worker's phase.
    pub phase: PhaseCode,
    /// A policy's lookahead or the planner fallback.
    pub executor: Executor,
    /// A sampled candidate's verdict (verified sampling): which; `None` for the
    /// deterministic rollout and the planner.
    pub sample: Option<SampleTag>,
}

/// Something the twin did that the outside should know (publish, log, assert on).
#[derive(Debug, Clone, PartialEq)]
pub enum TwinEvent<S> {
    /// A lookahead ran.
    Verdict {
        /// Its result.
        verdict: Verdict,
        /// The scene it ran in.
        scene: S,
        /// How long it took, s.
        elapsed_s: f64,
        /// Who made it, in which phase of the worker.
        source: VerdictSource,
    },
    /// A plan was approved and handed to the cycle.
    PlanApproved {
        /// Plan id.
        plan_id: u64,
        /// Policy id.
        policy_id: u64,
        /// Whether it joins a running plan.
        joins: bool,
    },
    /// The lookahead passed but the smoothed plan did not (smoothing, shield, or its path
    /// misses the goal). For a sampled candidate, `policy_id` is its policy's.
    PlanRejected {
        /// Policy id.
        policy_id: u64,
        /// Why.
        why: PlanRejection,
    },
    /// The running plan became unsafe in the new scene and was revoked.
    Revoked {
        /// Plan id.
        plan_id: u64,
        /// The first unsafe sample.
        at_index: usize,
    },
    /// The running plan fails ahead in the new scene, far enough ahead that its stop was
    /// scheduled rather than made at once: a joining plan may take over first (issue 33
    /// item 5, [`crate::twin_thread::plan_guard`]).
    StopScheduled {
        /// Plan id.
        plan_id: u64,
        /// The first unsafe sample.
        at_index: usize,
        /// The sample the cycle stops from unless a joining plan took over.
        stop_due_index: usize,
    },
    /// The policy failed the lookahead: retraining is requested for this scene.
    Retrain {
        /// Request id (increasing).
        request_id: u64,
        /// The failed verdict.
        verdict: Verdict,
        /// The scene.
        scene: S,
    },
    /// A retrained policy failed in the scene it was retrained for, judged from the task's
    /// start posture (its verdict says why; the smoothed plan's `PlanRejected` before it,
    /// which sample and check): a failed retraining (issue 40 item 2).
    RetrainingRefused {
        /// The refused verdict.
        verdict: Verdict,
        /// Retrained policies refused for this scene so far.
        refusals: u32,
    },
    /// The scene is "not learned": its retrained policies were refused `refusals` times
    /// (`max_refused_retrainings`); no more retraining is asked for it.
    NotLearned {
        /// The last refused verdict.
        verdict: Verdict,
        /// The scene.
        scene: S,
        /// Retrained policies refused for this scene.
        refusals: u32,
    },
    /// The arm returns to where its episode began along its executed path.
    ReturningHome {
        /// Plan id.
        plan_id: u64,
        /// Samples in the plan.
        samples: usize,
    },
    /// The way home is unsafe in the scene now in force; the arm holds.
    ReturnHomeRefused {
        /// Why.
        why: PlanRejection,
    },
    /// The arm rested too close to a box and backs out along the path it came
    /// ([`crate::twin_thread::worker::retreat`]): the retreat was approved and sent.
    BackingOut {
        /// Plan id.
        plan_id: u64,
        /// Samples in the plan.
        samples: usize,
        /// The clearance where it ends, m.
        clearance_m: f64,
    },
    /// A new policy was swapped in.
    PolicySwapped {
        /// Its id.
        policy_id: u64,
    },
    /// A plan is due but the latest detection frame has no goal: nothing is planned, the
    /// arm holds (reported once per stretch without a goal).
    NoGoal {
        /// The current policy, 0 for none.
        policy_id: u64,
    },
    /// Every candidate failed on a settled scene whose goal a box has taken (it overlaps the
    /// goal cube or blocks every goal posture): said at once, on that frame's planning, once
    /// per scene; no retraining is asked for and the arm holds (the plan guard has bounded
    /// the running plan in this scene). A later scene without it makes the goal live again
    /// ([`crate::twin_thread::worker::goal_taken`]).
    GoalTaken {
        /// Why, in the feasibility check's words (`infeasible: <reason>`).
        reason: InfeasibleReason,
        /// The current policy.
        policy_id: u64,
        /// The scene.
        scene: S,
    },
    /// A plan is due but the latest detection frame is not settled (the world is changing):
    /// nothing is planned until a settled frame arrives (reported once per unsettled
    /// stretch).
    AwaitingSettledScene {
        /// Capture time of that frame (cycle clock), ns.
        stamp_ns: u64,
    },
}
