//! Planning: where the next episode plan starts (`plan_due`), the library's
//! candidates in order — each policy's lookahead, verified sampling of their perturbed
//! variants, the planner fallback (`plan_from`) — the hand-over of an approved
//! plan to the cycle (registered with the plan guard first), the continuation from where a
//! pause left the arm, and the retrain request when nothing passes.
//!
//! The worker's state, its events, the cycle's reports and the revocations stay in
//! [`super`]; this module only reads them and moves the phase on through
//! [`Phase::next`](super::Phase::next).

use std::sync::Arc;

use shm_schemas::Executor;

use super::approve::{FailedVerdict, GoalCheck};
// Whether a planning that finds no passing policy asks for retraining: not for a plan made
// on a scene still changing (a moment of a moving world), nor for the continuation from
// where a pause left the arm (the policy is judged from the start posture, where the way
// home leads).
use super::moving::RetrainOnFailure;
use super::phase;
use super::policy_library::{Candidate, PLANNER_POLICY_ID};
use super::{
    Hold, Lookahead, SampleTag, Transition, TwinEvent, TwinWorker, Verdict, VerdictSource,
};
use crate::cycle::plan::{JoinPoint, MotionState, Plan};
use crate::cycle::shield::ShieldModel;
use crate::cycle::{CycleReport, Mode};
use crate::twin_thread::scene_path::lock_guard;

/// Live plans the worker keeps at most (a cycle holds a running, a pending and a few
/// queued plans).
const MAX_LIVE_PLANS: usize = 16;

/// What becomes of a plan that passes: sent to the cycle, or only judged (the goal was
/// reached already: the `acceptance` module).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Dispatch {
    /// Sent to the cycle.
    Send,
    /// Judged and published, not sent.
    VerifyOnly,
}

/// Sampled candidates that passed the twin whose smoothed plans are checked at most per
/// policy (best first), before the next policy or the planner fallback.
const MAX_SAMPLED_PLANS_CHECKED: usize = 4;

/// What one candidate of the library did in `plan_from`.
pub(super) enum Tried {
    /// The slot is empty.
    NoPolicy,
    /// A plan was approved and sent (or the arm is already at the goal, or the hand-over
    /// slot was full and planning is due again): nothing more to try.
    Done,
    /// Its lookahead or its smoothed plan failed.
    Failed {
        /// The verdict as published (failed).
        verdict: Verdict,
        /// The lookahead itself found the continuation unsafe.
        lookahead_unsafe: bool,
    },
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// A plan is due and the gates are open: where it starts (at rest, or joining the
    /// running plan `join_ahead` samples ahead of the arm), then the library's candidates.
    pub(super) fn plan_due(&mut self, r: CycleReport, events: &mut Vec<TwinEvent<L::Scene>>) {
        if self.library.current().is_none() {
            return;
        }
        // A stop scheduled on the running plan: a joining plan may be made on a scene
        // still changing (its moving boxes are their predicted occupancy), without asking
        // for retraining on it; every later frame re-verifies it like any plan.
        let stop_due = self.stop_due_on_running();
        let (ready, retrain) = match self.scene.ready() {
            Err(Hold::Unsettled) if stop_due => (
                self.scene.scene().ok_or(Hold::NoScene),
                RetrainOnFailure::No,
            ),
            _ => match self.scene_at_rest() {
                Ok((scene, retrain)) => (Ok(scene), retrain),
                Err(hold) => (Err(hold), RetrainOnFailure::Yes),
            },
        };
        let scene = match ready {
            Ok(scene) => scene,
            Err(Hold::NoGoal) => {
                if self.scene.report_once(Hold::NoGoal) {
                    events.push(TwinEvent::NoGoal {
                        policy_id: self.library.current().map_or(0, L::policy_id),
                    });
                }
                return;
            }
            Err(_) => return,
        };
        let (start, join) = match r.mode {
            Mode::Stopping => return,
            // The goal was reached: no episode plan joins the way home either; a policy
            // received meanwhile is judged once the arm is home (`acceptance`).
            Mode::Following if self.rests_after_goal() => {
                self.planning.taken();
                return;
            }
            Mode::Idle | Mode::Stopped if self.rests_after_goal() => {
                // The goal was reached: a policy received since is judged, nothing driven.
                self.planning.taken();
                self.verify_current(&MotionState::at_rest(r.cmd.q_rad), scene, events);
                return;
            }
            Mode::Idle | Mode::Stopped => (MotionState::at_rest(r.cmd.q_rad), None),
            Mode::Following => match self.live_plan(r.plan_id) {
                Some((s, _)) if r.next_index + self.settings.join_ahead < s.len() => {
                    let index = r.next_index + self.settings.join_ahead;
                    let join = JoinPoint {
                        plan_id: s.id,
                        index,
                    };
                    (s.sample(index), Some(join))
                }
                // The running plan is about to end (or unknown): plan again once at rest.
                _ => return,
            },
        };
        self.planning.taken();
        // A plan joining a moving arm is judged from a state the learner never trains from:
        // once a retraining was asked for the scene, its failure asks for no other.
        let retrain = match join {
            Some(_) if self.library.asked_for(scene) => RetrainOnFailure::No,
            _ => retrain,
        };
        self.plan_from(start, join, scene, retrain, events);
    }

    /// After a pause (issue 33 item 5, continuation): an episode plan from where the arm
    /// stopped — the library's candidates as ever (a policy's lookahead prepends the
    /// approach to the task's start posture), then the planner fallback straight to the
    /// goal — checked like any plan, on a settled scene with a goal. True when one was sent;
    /// false leaves the way home along the executed path to the caller. Asks for no
    /// retraining: the policy is judged from the start posture, where the way home leads.
    pub(super) fn continue_from_rest(
        &mut self,
        r: CycleReport,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        if !self.settings.continue_after_pause || !self.settings.gate {
            return false;
        }
        let Ok((scene, _)) = self.scene_at_rest() else {
            return false;
        };
        let sent_before = self.sent.newest_id;
        self.plan_from(
            MotionState::at_rest(r.cmd.q_rad),
            None,
            scene,
            RetrainOnFailure::No,
            events,
        );
        if self.sent.newest_id > sent_before {
            self.excursion.next(Transition::ContinuationSent {
                plan_id: self.sent.newest_id,
            });
            self.planning.taken();
            return true;
        }
        false
    }

    /// Hands a checked plan to the cycle, registered with the plan guard first (so a frame
    /// that arrived since its approval is checked against it, and none can fall between),
    /// and keeps a copy among the live plans; false when the hand-over slot is full
    /// (planning is due again) or the guard refused it (its goal was withdrawn since its
    /// scene was accepted: nothing is planned until a frame from after the withdrawal is
    /// noted, which asks for it).
    pub(super) fn send_plan(&mut self, plan: Plan, scene: L::Scene) -> bool {
        let copy = Arc::new(plan.clone());
        if !lock_guard(&self.io.guard).sent(copy.clone(), scene, self.scene.goal_epoch()) {
            return false;
        }
        if self.io.plans.send(Box::new(plan)).is_err() {
            lock_guard(&self.io.guard).returned(copy.id);
            self.planning.request();
            return false;
        }
        self.sent.newest_id = copy.id;
        if self.sent.live.len() == MAX_LIVE_PLANS {
            // Boxes leaked rather than returned (a full return queue): forget the oldest.
            self.sent.live.remove(0);
        }
        self.sent.live.push((copy, scene));
        true
    }

    /// Plans the next episode from `start`: the library's candidates in order; the first
    /// whose lookahead and smoothed plan pass is approved. When none passes and sampling is
    /// on, each policy's perturbed variants (verified sampling, one budget for all), the
    /// best that passes approved. When none passes, the first failure is what counts: the
    /// planner fallback moves the arm when installed, the running plan is revoked when that
    /// continuation is unsafe in a changed scene, and retraining is asked for (once per
    /// policy and scene).
    fn plan_from(
        &mut self,
        start: MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        retrain: RetrainOnFailure,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let mut first_failure: Option<(Verdict, bool)> = None;
        for candidate in Candidate::ORDER {
            if candidate == Candidate::Base && !self.settings.gate {
                // Without the lookahead gate the current policy's plan is taken as it is.
                break;
            }
            match self.try_policy(candidate, &start, join, scene, Dispatch::Send, events) {
                Tried::NoPolicy => {}
                Tried::Done => return,
                Tried::Failed {
                    verdict,
                    lookahead_unsafe,
                } => {
                    first_failure.get_or_insert((verdict, lookahead_unsafe));
                }
            }
        }
        let Some((verdict, lookahead_unsafe)) = first_failure else {
            return;
        };
        if let (true, Some(budget_s)) = (self.settings.gate, self.settings.sampling_budget_s) {
            let deadline = deadline_in(budget_s);
            for candidate in Candidate::ORDER {
                if let Tried::Done =
                    self.try_sampled(candidate, &start, join, scene, deadline, events)
                {
                    return;
                }
            }
        }
        if self.goal_taken_in(scene, events) {
            // A box has taken the goal: said now (after verified sampling, which may still
            // find a way to a goal posture), no retraining; the arm holds.
            self.revoke_if_unsafe_under_way(lookahead_unsafe, scene, events);
            return;
        }
        if self.settings.gate && self.library.planner_mut().is_some() {
            // No policy passes: retraining is asked for as always, and the planner's path,
            // when it passes the same checks, moves the arm meanwhile.
            if retrain == RetrainOnFailure::Yes {
                self.ask_retrain(verdict, scene, events);
            }
            if self.try_planner(&start, join, scene, events) {
                return;
            }
        }
        self.revoke_if_unsafe_under_way(lookahead_unsafe, scene, events);
        if self.settings.gate && retrain == RetrainOnFailure::Yes {
            self.ask_retrain(verdict, scene, events);
        }
    }

    /// The lookahead found the continuation unsafe in `scene`, a changed scene: the plan
    /// under way is revoked — unless a stop is scheduled on it, where the guard has bounded
    /// it already (safe up to the stop's end): it stops there unless a later frame's plan
    /// joins it first.
    fn revoke_if_unsafe_under_way(
        &mut self,
        lookahead_unsafe: bool,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        if lookahead_unsafe
            && self.sent.live.iter().any(|(_, s)| *s != scene)
            && !self.stop_due_on_running()
        {
            self.revoke_under_way(events);
        }
    }

    /// The planner fallback: its path from `start`, smoothed and checked like a policy's
    /// plan (the shield on every sample, the smoothed path reaching the goal) and sent;
    /// true when a plan was sent (or the arm is at the goal already).
    // The planner's own compute time for its verdict (the twin thread is not real-time).
    #[allow(clippy::disallowed_methods)]
    fn try_planner(
        &mut self,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        let source = VerdictSource {
            phase: self.phase_code(),
            executor: Executor::Planner,
            sample: None,
        };
        // A joining search starts where the arm will be after it (the `join` module).
        let joined;
        let (start, join) = match join {
            None => (start, None),
            Some(j) => match self.join_for_search(j) {
                Some((s, j)) => {
                    joined = s;
                    (&joined, Some(j))
                }
                None => return false,
            },
        };
        let Some(planner) = self.library.planner_mut() else {
            return false;
        };
        let t0 = std::time::Instant::now();
        let verdict = planner.plan(&scene, &start.q_rad, &mut self.approver.waypoints);
        // One verdict per try, published once the smoothed plan was checked.
        let publish = |verdict, events: &mut Vec<TwinEvent<L::Scene>>| {
            events.push(TwinEvent::Verdict {
                verdict,
                scene,
                elapsed_s: t0.elapsed().as_secs_f64(),
                source,
            });
        };
        if !(verdict.task_ok && verdict.safe) {
            publish(verdict, events);
            return false;
        }
        if self.approver.waypoints.is_empty() {
            publish(verdict, events);
            return true;
        }
        let checked = self.approver.smoothed_checked_plan(
            start,
            join,
            PLANNER_POLICY_ID,
            &scene,
            GoalCheck::Planner(planner),
        );
        match checked {
            Ok(plan) => {
                publish(verdict, events);
                if self.join_in_time(join) {
                    self.send_approved(plan, start, join, scene, events);
                }
                true
            }
            Err(why) => {
                events.push(TwinEvent::PlanRejected {
                    policy_id: PLANNER_POLICY_ID,
                    why,
                });
                publish(why.failed_verdict(verdict), events);
                false
            }
        }
    }

    /// One policy of the library: its lookahead, then (when it passes) its smoothed,
    /// shield-checked plan, sent to the cycle (or, `VerifyOnly`, only judged). One verdict
    /// is published per try, after the smoothed plan was checked: its `plan_approved` is
    /// rt-core's final word on the plan.
    // The lookahead's own compute time for its verdict (the twin thread is not real-time).
    #[allow(clippy::disallowed_methods)]
    pub(super) fn try_policy(
        &mut self,
        candidate: Candidate,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        dispatch: Dispatch,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> Tried {
        let Some(policy) = self.library.get(candidate) else {
            return Tried::NoPolicy;
        };
        let source = VerdictSource {
            phase: self.verdict_phase(dispatch),
            executor: Executor::Policy,
            sample: None,
        };
        let t0 = std::time::Instant::now();
        let verdict = self.approver.lookahead(policy, &scene, &start.q_rad);
        let publish = |verdict, events: &mut Vec<TwinEvent<L::Scene>>| {
            events.push(TwinEvent::Verdict {
                verdict,
                scene,
                elapsed_s: t0.elapsed().as_secs_f64(),
                source,
            });
        };
        if self.settings.gate && !(verdict.task_ok && verdict.safe) {
            publish(verdict, events);
            return Tried::Failed {
                verdict,
                lookahead_unsafe: !verdict.safe,
            };
        }
        if self.approver.waypoints.is_empty() {
            // Already at the goal: nothing to do.
            publish(verdict, events);
            return Tried::Done;
        }
        let goal_check = match self.library.get(candidate) {
            Some(policy) if self.settings.gate => GoalCheck::Policy(policy),
            _ => GoalCheck::None,
        };
        let plan = match self.approver.smoothed_checked_plan(
            start,
            join,
            verdict.policy_id,
            &scene,
            goal_check,
        ) {
            Ok(plan) => plan,
            Err(why) => {
                events.push(TwinEvent::PlanRejected {
                    policy_id: verdict.policy_id,
                    why,
                });
                // The lookahead passed but the plan the arm would follow does not: the
                // verdict is published as failed (and, when no policy passes, retraining
                // is asked for) instead of waiting for a plan that will not come.
                let failed = why.failed_verdict(verdict);
                publish(failed, events);
                return Tried::Failed {
                    verdict: failed,
                    lookahead_unsafe: false,
                };
            }
        };
        publish(verdict, events);
        if dispatch == Dispatch::Send {
            self.send_approved(plan, start, join, scene, events);
        }
        Tried::Done
    }

    /// Verified sampling of one policy of the library (its deterministic rollout failed):
    /// its perturbed variants until `deadline`, then the smoothed, checked plans of the
    /// passing ones best first (at most [`MAX_SAMPLED_PLANS_CHECKED`]); the first whose plan
    /// passes is sent, with a verdict saying which sample it was. Nothing is published for
    /// a sampling where none passes (the deterministic verdict stands).
    // The sampling's own compute time for its verdict (the twin thread is not real-time).
    #[allow(clippy::disallowed_methods)]
    fn try_sampled(
        &mut self,
        candidate: Candidate,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        deadline: std::time::Instant,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> Tried {
        let Some(policy) = self.library.get(candidate) else {
            return Tried::NoPolicy;
        };
        let t0 = std::time::Instant::now();
        let sampled = self
            .approver
            .lookahead_mut()
            .sample(policy, &scene, deadline);
        let source = |index| VerdictSource {
            phase: phase::phase_code(
                &self.excursion.phase(),
                &self.planning,
                self.cycle.report.map_or(0, |r| r.t_ns),
            ),
            executor: Executor::Policy,
            sample: Some(SampleTag {
                index,
                of: sampled.of,
            }),
        };
        let mut failed = None;
        for &index in sampled.ranked.iter().take(MAX_SAMPLED_PLANS_CHECKED) {
            let Some(verdict) = self
                .approver
                .sampled_plan(policy, &scene, &start.q_rad, index)
            else {
                continue;
            };
            let checked = self.approver.smoothed_checked_plan(
                start,
                join,
                verdict.policy_id,
                &scene,
                GoalCheck::Policy(policy),
            );
            match checked {
                Ok(plan) => {
                    events.push(TwinEvent::Verdict {
                        verdict,
                        scene,
                        elapsed_s: t0.elapsed().as_secs_f64(),
                        source: source(index),
                    });
                    self.send_approved(plan, start, join, scene, events);
                    return Tried::Done;
                }
                Err(why) => {
                    events.push(TwinEvent::PlanRejected {
                        policy_id: verdict.policy_id,
                        why,
                    });
                    failed.get_or_insert((why.failed_verdict(verdict), index));
                }
            }
        }
        match failed {
            Some((verdict, index)) => {
                events.push(TwinEvent::Verdict {
                    verdict,
                    scene,
                    elapsed_s: t0.elapsed().as_secs_f64(),
                    source: source(index),
                });
                Tried::Failed {
                    verdict,
                    lookahead_unsafe: false,
                }
            }
            None => Tried::NoPolicy,
        }
    }

    /// Sends an approved episode plan (a policy's or the planner's) and records it on the
    /// executed path; when the hand-over slot is full, planning is due again.
    fn send_approved(
        &mut self,
        plan: Plan,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let (plan_id, policy_id) = (plan.id, plan.policy_id);
        if !self.send_plan(plan, scene) {
            return;
        }
        if let Some((sent, _)) = self.sent.live.last() {
            self.path
                .record_episode_plan(start, join, self.excursion.phase().returning(), sent);
            self.excursion.next(Transition::EpisodePlanSent);
        }
        events.push(TwinEvent::PlanApproved {
            plan_id,
            policy_id,
            joins: join.is_some(),
        });
    }
}

/// The instant `budget_s` from now (the twin thread's wall clock: it is not real-time).
#[allow(clippy::disallowed_methods)]
fn deadline_in(budget_s: f64) -> std::time::Instant {
    std::time::Instant::now() + std::time::Duration::from_secs_f64(budget_s)
}
