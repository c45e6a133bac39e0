//! What the worker asks of a lookahead ([`Lookahead`]: the whole next episode in the twin
//! with a policy, and how near a path comes to the goal) and what one answers
//! ([`Verdict`], [`GoalApproach`]).

use twin::Joints;

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

/// The closest approach of a path's TCP to the goal target point, and the tolerance that
/// counts as reaching it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalApproach {
    /// Smallest TCP distance to the goal target point along the path, m (infinite for an
    /// empty path).
    pub closest_m: f64,
    /// Distance that counts as reached (the task's `success.tolerance_m`), m.
    pub tolerance_m: f64,
}

impl GoalApproach {
    /// The path reaches the goal: `closest_m <= tolerance_m`.
    pub fn reached(&self) -> bool {
        self.closest_m <= self.tolerance_m
    }
}
