//! Acceptance of retrained policies (issue 40 item 2): a loop that converges, or says why.
//!
//! - A retrained policy that fails in the scene it was retrained for — judged from the
//!   task's start posture, where the learner trains — is a refused retraining
//!   ([`TwinEvent::RetrainingRefused`]), and the next request carries its verdict. After
//!   `max_refused_retrainings` of them the scene is "not learned" ([`TwinEvent::NotLearned`])
//!   and no more retraining is asked for it; the planner fallback, where it is on, keeps
//!   the arm working.
//! - A plan joining a moving arm is judged from a state the learner never trains from: its
//!   failure asks for no retraining once one was asked for the scene.
//! - With camera goals, a goal already reached is not driven again: the arm rests at home
//!   until the goal or the scene changes. A policy received meanwhile is judged from the
//!   task's start posture (a verdict in phase [`PhaseCode::Verification`]: rt-core's
//!   acceptance or refusal of it) and its plan is not sent.

use shm_schemas::PhaseCode;

use super::planning::{Dispatch, Tried};
use super::policy_library::{Candidate, OnFailure};
use super::{Lookahead, TwinEvent, TwinWorker, Verdict};
use crate::cycle::plan::MotionState;
use crate::cycle::shield::ShieldModel;

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// Whether the goal of the scene was reached already and the arm is to rest: camera
    /// goals only (each `Reach` goal is a request to drive).
    pub(super) fn rests_after_goal(&self) -> bool {
        self.settings.rest_after_goal && self.scene.goal_reached()
    }

    /// The goal of `scene` was reached: the current policy, when not judged in it yet, is
    /// judged from `start` (the arm at rest, home) and its plan is not sent. A refusal
    /// counts as a failed retraining like any other.
    pub(super) fn verify_current(
        &mut self,
        start: &MotionState,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let Some(policy_id) = self.library.current().map(L::policy_id) else {
            return;
        };
        if !self.library.should_verify(policy_id, scene) {
            return;
        }
        if let Tried::Failed { verdict, .. } = self.try_policy(
            Candidate::Current,
            start,
            None,
            scene,
            Dispatch::VerifyOnly,
            events,
        ) {
            self.ask_retrain(verdict, scene, events);
        }
    }

    /// After `verdict` failed in `scene`: retraining is asked for (once per policy and
    /// scene), with a refused retraining said as such, or the scene is declared not
    /// learned at the bound.
    pub(super) fn ask_retrain(
        &mut self,
        verdict: Verdict,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let current_id = self.library.current().map(L::policy_id);
        let max_refused = self.settings.max_refused_retrainings;
        match self
            .library
            .on_failure(verdict.policy_id, current_id, scene, max_refused)
        {
            OnFailure::Nothing => {}
            OnFailure::NotLearned { refusals } => events.push(TwinEvent::NotLearned {
                verdict,
                scene,
                refusals,
            }),
            OnFailure::Retrain { refusals, refused } => {
                if refused {
                    events.push(TwinEvent::RetrainingRefused { verdict, refusals });
                }
                events.push(TwinEvent::Retrain {
                    request_id: self.next_request_id,
                    verdict,
                    scene,
                });
                self.next_request_id += 1;
            }
        }
    }

    /// The phase a verdict of `dispatch` is published in.
    pub(super) fn verdict_phase(&self, dispatch: Dispatch) -> PhaseCode {
        match dispatch {
            Dispatch::Send => self.phase_code(),
            Dispatch::VerifyOnly => PhaseCode::Verification,
        }
    }
}
