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
    /// The scene the current policy answers: the last retrain request's when it arrived.
    answers: Option<S>,
    /// Retrained policies refused in a scene (judged from the task's start posture).
    refused: Option<(S, u32)>,
    /// The last scene declared "not learned": no more retraining is asked for it.
    not_learned: Option<S>,
    /// The policy and scene last judged by a verification (the goal reached already).
    verified: Option<(u64, S)>,
}

/// What a policy failing in a scene asks for ([`PolicyLibrary::on_failure`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnFailure {
    /// Retraining, for the first time for this policy and scene; `refusals` of the
    /// retrained policies that answered this scene were refused so far (this one included).
    Retrain {
        /// Refused retrained policies for the scene.
        refusals: u32,
        /// This failure is one of them: the current policy, retrained for this scene.
        refused: bool,
    },
    /// Nothing new: asked already for this policy and scene, or the scene is not learned.
    Nothing,
    /// The scene is "not learned" now: its `refusals`-th retrained policy was refused,
    /// the bound.
    NotLearned {
        /// Refused retrained policies for the scene.
        refusals: u32,
    },
}

impl<P, S: Copy + PartialEq> Default for PolicyLibrary<P, S> {
    fn default() -> Self {
        Self {
            current: None,
            base: None,
            planner: None,
            last_retrain: None,
            answers: None,
            refused: None,
            not_learned: None,
            verified: None,
        }
    }
}

impl<P, S: Copy + PartialEq> PolicyLibrary<P, S> {
    /// A new policy becomes the current one. The first one ever received is kept as the
    /// base; any other replaced one is returned (to be dropped off the cycle).
    pub fn receive(&mut self, policy: Box<P>) -> Option<Box<P>> {
        self.answers = self.last_retrain.map(|(_, scene)| scene);
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

    /// What `policy_id` failing in `scene` asks for (`current_id`: the current policy's
    /// id). Retraining once per failing policy and scene. A failure of the current policy in
    /// the scene it was retrained for is a refused retraining: after `max_refused` of them
    /// the scene is "not learned", and nothing more is asked for it (until another scene).
    pub fn on_failure(
        &mut self,
        policy_id: u64,
        current_id: Option<u64>,
        scene: S,
        max_refused: u32,
    ) -> OnFailure {
        if self.not_learned == Some(scene) || self.last_retrain == Some((policy_id, scene)) {
            return OnFailure::Nothing;
        }
        let mut refusals = match self.refused {
            Some((s, n)) if s == scene => n,
            _ => 0,
        };
        let refused = self.answers == Some(scene) && current_id == Some(policy_id);
        if refused {
            refusals += 1;
        }
        self.refused = Some((scene, refusals));
        if refusals >= max_refused {
            self.not_learned = Some(scene);
            return OnFailure::NotLearned { refusals };
        }
        self.last_retrain = Some((policy_id, scene));
        OnFailure::Retrain { refusals, refused }
    }

    /// Whether a retraining was asked for `scene` last (a plan joining a moving arm then
    /// asks for none: the learner judges its policies from the task's start posture).
    pub fn asked_for(&self, scene: S) -> bool {
        self.last_retrain.is_some_and(|(_, s)| s == scene) || self.not_learned == Some(scene)
    }

    /// `policy_id` was judged in `scene` (its plan reached the goal there): no verification.
    pub fn note_judged(&mut self, policy_id: u64, scene: S) {
        self.verified = Some((policy_id, scene));
    }

    /// Whether `policy_id` is still to be judged in `scene` by a verification; true once
    /// per pair (and remembered).
    pub fn should_verify(&mut self, policy_id: u64, scene: S) -> bool {
        if self.verified == Some((policy_id, scene)) {
            return false;
        }
        self.verified = Some((policy_id, scene));
        true
    }
}
