//! [`PolicyLibrary`]: the candidates the lookahead tries, in order — the current policy (the
//! latest received, retrained for one world), then the base (the first received: the
//! bundled generalist, kept when retrained ones replace it).
//!
//! A world the generalist solves is solved again without retraining even after a
//! fine-tune forgot it; retraining is asked for only when every policy fails, once per
//! failing policy and scene (the learner restarts its training on every new request).
//!
//! Last, when installed (`planner_fallback`), the [`FallbackPlanner`]: a collision-free
//! joint path to a goal posture, smoothed and checked like a policy's plan, that moves the
//! arm while the learner retrains. A policy that passes replaces it at the next planning.

use twin::Joints;

use super::{GoalApproach, Verdict};

/// The policy id the planner fallback's verdicts and plans carry (no policy: 0, as a
/// policy blob's id is never 0).
pub const PLANNER_POLICY_ID: u64 = 0;

/// A planner whose collision-free path the worker executes when no policy passes.
pub trait FallbackPlanner<S>: Send + 'static {
    /// Plans from `start_q_rad` to a goal posture in `scene`; writes the waypoints (the
    /// start excluded) into `waypoints`. The verdict (policy id [`PLANNER_POLICY_ID`]) says
    /// whether a path was found (`task_ok`) and its smallest clearance.
    fn plan(&mut self, scene: &S, start_q_rad: &Joints, waypoints: &mut Vec<Joints>) -> Verdict;

    /// How near the TCP comes to the goal along `path_q_rad`, judged as the lookahead
    /// judges it (`Lookahead::goal_approach`).
    fn goal_approach(&mut self, scene: &S, path_q_rad: &[Joints]) -> GoalApproach;
}

/// A candidate of the library.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Candidate {
    /// The latest policy received.
    Current,
    /// The first policy received (the bundled generalist).
    Base,
}

impl Candidate {
    /// The order the lookahead tries them in.
    pub const ORDER: [Candidate; 2] = [Candidate::Current, Candidate::Base];
}

/// The policies the worker holds, and the planner fallback.
pub struct PolicyLibrary<P, S> {
    current: Option<Box<P>>,
    base: Option<Box<P>>,
    planner: Option<Box<dyn FallbackPlanner<S>>>,
    /// The policy and scene of the last retrain request.
    last_retrain: Option<(u64, S)>,
}

impl<P, S: Copy + PartialEq> Default for PolicyLibrary<P, S> {
    fn default() -> Self {
        Self {
            current: None,
            base: None,
            planner: None,
            last_retrain: None,
        }
    }
}

impl<P, S: Copy + PartialEq> PolicyLibrary<P, S> {
    /// A new policy becomes the current one. The first one ever received is kept as the
    /// base; any other replaced one is returned (to be dropped off the cycle).
    pub fn receive(&mut self, policy: Box<P>) -> Option<Box<P>> {
        let old = self.current.replace(policy);
        if self.base.is_none() {
            self.base = old;
            None
        } else {
            old
        }
    }

    /// The policy of a candidate.
    pub fn get(&self, c: Candidate) -> Option<&P> {
        match c {
            Candidate::Current => self.current.as_deref(),
            Candidate::Base => self.base.as_deref(),
        }
    }

    /// The current policy.
    pub fn current(&self) -> Option<&P> {
        self.current.as_deref()
    }

    /// Installs the planner fallback.
    pub fn set_planner(&mut self, planner: Box<dyn FallbackPlanner<S>>) {
        self.planner = Some(planner);
    }

    /// The planner fallback, when installed.
    pub fn planner_mut(&mut self) -> Option<&mut (dyn FallbackPlanner<S> + 'static)> {
        self.planner.as_deref_mut()
    }

    /// Whether retraining should be asked for `policy_id` failing in `scene`: true once per
    /// pair (and remembered).
    pub fn should_ask_retrain(&mut self, policy_id: u64, scene: S) -> bool {
        if self.last_retrain == Some((policy_id, scene)) {
            return false;
        }
        self.last_retrain = Some((policy_id, scene));
        true
    }
}
