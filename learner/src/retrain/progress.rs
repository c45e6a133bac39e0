//! The [`RetrainProgress`] messages a retraining is answered with (`learner serve`
//! publishes them): progress along the way, the final phase, or the feasibility check's
//! refusal with its reason in wire form.

use std::time::Instant;

use shm_schemas::{RetrainPhase, RetrainProgress, RetrainRequest};
use twin::InfeasibleReason;

/// A progress message for `req` in `phase`: `steps` taken, the mean return `ret` (0 when not
/// finite) and success rate `succ`, the wall time since `t0` and the published policy id (0:
/// none yet).
pub fn progress(
    req: &RetrainRequest,
    phase: RetrainPhase,
    steps: u64,
    ret: f64,
    succ: f64,
    t0: Instant,
    policy_id: u64,
) -> RetrainProgress {
    RetrainProgress {
        request_id: req.request_id,
        steps_done: steps,
        published_policy_id: policy_id,
        mean_return: if ret.is_finite() { ret } else { 0.0 },
        success_rate: succ,
        wall_time_s: t0.elapsed().as_secs_f64(),
        phase: phase as u8,
        ..Default::default()
    }
}

/// The final answer to `req` when the feasibility check finds no safe way: phase
/// [`RetrainPhase::Infeasible`] with the reason's wire form.
pub fn infeasible_progress(
    req: &RetrainRequest,
    reason: &InfeasibleReason,
    t0: Instant,
) -> RetrainProgress {
    let (kind, blocker, link, by_m) = reason.wire();
    RetrainProgress {
        infeasible_kind: kind,
        infeasible_blocker: blocker,
        infeasible_link: link,
        infeasible_by_m: by_m,
        ..progress(req, RetrainPhase::Infeasible, 0, 0.0, 0.0, t0, 0)
    }
}
