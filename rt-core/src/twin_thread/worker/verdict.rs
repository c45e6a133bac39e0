//! What the worker asks of a lookahead ([`Lookahead`]: the whole next episode in the twin
//! with a policy, perturbed variants of it (verified sampling), and how near a path comes to
//! the goal) and what one answers ([`Verdict`], [`Sampled`], [`GoalApproach`]).

use std::time::Instant;

use twin::{InfeasibleReason, Joints};

/// Result of one lookahead.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Verdict {
    /// The episode reached the goal.
    pub task_ok: bool,
    /// No contact / clearance violation during the episode.
    pub safe: bool,
    /// Smallest clearance during the episode, m.
    pub min_distance_m: f64,
    /// Steps run.
    pub steps: u32,
    /// The policy evaluated.
    pub policy_id: u64,
}

/// The whole next episode in the twin with a policy.
pub trait Lookahead: Send + 'static {
    /// The scene type (shared with the shield model).
    type Scene: Copy + Send + PartialEq + 'static;
    /// A validated, prepared policy.
    type Policy: Send + 'static;

    /// Duration of one policy step, s.
    fn step_s(&self) -> f64;

    /// The id of a policy.
    fn policy_id(policy: &Self::Policy) -> u64;

    /// Rolls `policy` out from `start_q_rad` in `scene`; writes one waypoint per step.
    fn lookahead(
        &mut self,
        policy: &Self::Policy,
        scene: &Self::Scene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict;

    /// Verified sampling, after `policy`'s deterministic rollout failed in `scene`: rolls
    /// out its perturbed variants until `deadline`, each verified as [`Lookahead::lookahead`]
    /// verifies the deterministic one, and returns those that passed, best first. The
    /// default samples nothing (a lookahead without a sampler).
    fn sample(
        &mut self,
        _policy: &Self::Policy,
        _scene: &Self::Scene,
        _deadline: Instant,
    ) -> Sampled {
        Sampled::default()
    }

    /// The plan of candidate `index` of the last [`Lookahead::sample`] (of `policy` in
    /// `scene`) from `start_q_rad`, written to `waypoints` as [`Lookahead::lookahead`]
    /// writes them, with its verdict; `None` when there is no such candidate.
    fn sampled_plan(
        &mut self,
        _policy: &Self::Policy,
        _scene: &Self::Scene,
        _start_q_rad: &Joints,
        _index: usize,
        _waypoints: &mut Vec<Joints>,
    ) -> Option<Verdict> {
        None
    }

    /// Whether a box has taken the goal in `scene` (the goal of `policy`'s task): it
    /// overlaps the goal cube, or blocks every goal posture — why, in the feasibility
    /// check's words ([`InfeasibleReason::NoGoalPosture`] naming the box). Asked when every
    /// candidate failed on a settled scene (`worker::goal_taken`). The default: never (a
    /// lookahead without a notion of goal postures).
    fn goal_taken(
        &mut self,
        _policy: &Self::Policy,
        _scene: &Self::Scene,
    ) -> Option<InfeasibleReason> {
        None
    }

    /// How near the TCP comes to the goal along `path_q_rad` (the smoothed plan the arm
    /// would follow), judged as the lookahead judges `task_ok`: the same target point and
    /// the same tolerance, so "goal reached" has one meaning for the twin and the arm.
    ///
    /// # Performance
    /// Called for every plan the worker would approve; must not allocate.
    fn goal_approach(
        &mut self,
        policy: &Self::Policy,
        scene: &Self::Scene,
        path_q_rad: &[Joints],
    ) -> GoalApproach;
}

/// The closest approach of a path's TCP to the goal target point (the twin's verification's).
pub use twin::approval::GoalApproach;

/// What one verified sampling did ([`Lookahead::sample`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sampled {
    /// K: the candidates configured, the deterministic rollout (index 0) included.
    pub of: usize,
    /// Perturbed candidates rolled out before the deadline.
    pub tried: usize,
    /// The candidates that passed, best first (fewest steps, then the largest clearance):
    /// their indices.
    pub ranked: Vec<usize>,
    /// Wall time, s.
    pub elapsed_s: f64,
}

/// Which sampled candidate a verdict is for: "sample `index` of `of`".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleTag {
    /// The candidate (1.. ; 0 would be the deterministic rollout).
    pub index: usize,
    /// K.
    pub of: usize,
}
