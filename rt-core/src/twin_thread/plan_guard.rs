//! The plan guard: every plan the worker has handed to the cycle and the cycle has not yet
//! handed back is *live*, and every live plan that can still move the arm is re-verified
//! against every accepted scene — the one running (from the sample the cycle sends next),
//! the one scheduled to join it, and one sent from rest that the cycle has not adopted yet.
//! A failure revokes them all (the cycle stops along the checked path, or refuses a plan it
//! has not adopted).
//!
//! What is live is known from the cycle, never from what was sent last: a plan stays live
//! until its box comes back through the hand-over ([`PlanGuard::returned`]), and which live
//! plan runs, and which were adopted already, is read from the cycle's own words
//! ([`CycleControl::adoption`]: its progress and adoption in one word). A plan the cycle refused
//! therefore never replaces the running one in the guard's view.
//!
//! Join before stopping (issue 33 item 5, `join_before_stopping`): when only the running
//! plan fails, nothing in the scene is seen moving (a box set down, a still scene; a moving
//! one is predicted only a short horizon ahead, so the arm stops at once), and its first
//! unsafe sample lies far enough ahead that the arm can go on
//! for a while and still stop along the plan before it, the guard does not revoke it: it
//! schedules the stop at the last sample from which the stop envelope
//! ([`CycleConfig::brake_horizon_samples`]) still ends before the unsafe one
//! ([`CycleControl::schedule_stop`]). Meanwhile the worker plans a replacement joining the
//! running plan (policy, verified sampling or planner fallback), verified like any plan;
//! the cycle switches to it at its join point and the arm never stops. Without one in time
//! the cycle stops at the scheduled sample. Nothing is given up: every sample the arm
//! passes through before the stop, and the stop's own, was verified clear in this scene,
//! which is the criterion by which a plan found safe everywhere goes on today; each later
//! frame is re-verified the same way and can only move the stop earlier.
//!
//! The guard is shared by the scene path (the intake thread in `rt-core run`, which calls
//! [`PlanGuard::scene`] for every accepted frame) and the twin worker (which registers each
//! plan *before* handing it over and reports returned ones). A plan approved in an older
//! scene than the guard's newest (a frame arrived during a planner search or a lookahead) is
//! verified against the newest at once when it is registered. Neither side holds the lock
//! during a lookahead or a planner search: a verification takes 0.05–0.4 ms.

use std::sync::Arc;

use crate::cycle::plan::Plan;
use crate::cycle::shield::{Shield, ShieldModel};
use crate::cycle::{CycleConfig, CycleControl};

/// Live plans kept at most; older ones are forgotten (a cycle holds at most a running, a
/// pending and a few queued plans; more means boxes were leaked rather than returned).
const MAX_LIVE_PLANS: usize = 16;

/// A revocation the guard made (for the worker's event log).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Revocation {
    /// The plan found unsafe.
    pub plan_id: u64,
    /// Its first unsafe sample.
    pub at_index: usize,
    /// `Some(k)`: not revoked but its stop scheduled from sample `k`, so that a joining
    /// plan may take over first (see the module docs).
    pub stop_due_index: Option<usize>,
}

/// Samples kept between the scheduled stop's envelope and the first unsafe sample (the
/// cycle's own envelope check looks one sample further, between samples during scaled
/// playback), so the scheduled stop, a pause, comes first.
const STOP_DUE_SLACK_SAMPLES: usize = 3;

/// When the guard schedules a stop instead of revoking (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JoinWindow {
    /// The stop envelope's length, samples ([`CycleConfig::brake_horizon_samples`]).
    pub brake_horizon_samples: usize,
    /// The scheduled stop must lie at least this far ahead of the arm, samples: room for
    /// the worker to plan and for its join point (`join_ahead_s` ahead of the arm).
    pub min_lead_samples: usize,
}

impl JoinWindow {
    /// From the runtime configuration: `None` when `join_before_stopping` is off. The lead
    /// is twice `join_ahead_s`: the join point itself, and as long again to plan.
    pub fn from_runtime(cfg: &crate::config::RuntimeConfig) -> Option<Self> {
        cfg.join_before_stopping.then(|| Self {
            brake_horizon_samples: CycleConfig::from_runtime(cfg).brake_horizon_samples,
            min_lead_samples: 2 * (cfg.join_ahead_s * cfg.rate_hz).ceil() as usize,
        })
    }

    /// Where the stop of a running plan whose next sample is `next` and first unsafe one
    /// `first_unsafe` is due, when it can wait (`None`: revoke now).
    pub fn stop_due(&self, next: usize, first_unsafe: usize) -> Option<usize> {
        let due = first_unsafe.checked_sub(self.brake_horizon_samples + STOP_DUE_SLACK_SAMPLES)?;
        (due >= next + self.min_lead_samples).then_some(due)
    }
}

/// How a live plan stands with the cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Standing {
    /// The cycle follows it: verify from its next sample.
    Running { next: usize },
    /// Scheduled to join the running plan at `join_index` of it: verify all of it.
    Joining { join_index: usize },
    /// Sent from rest and not adopted while the cycle is not following: verify all of it.
    NotAdopted,
    /// Cannot move the arm (run already, or to be refused): not verified.
    Inert,
}

/// The live plans and their re-verification; see the module docs.
pub struct PlanGuard<M: ShieldModel> {
    shield: Shield<M>,
    period_s: f64,
    control: Arc<CycleControl>,
    /// Plans handed to the cycle and not handed back, oldest first.
    live: Vec<Arc<Plan>>,
    scene: Option<M::Scene>,
    /// The current scene's capture and acceptance times, the cycle's clock, ns (0: not
    /// known): a revocation names them as its cause.
    scene_times_ns: (u64, u64),
    /// The cycle clock's origin on the monotonic clock, ns, for the acceptance time (`None`:
    /// not stamped, as in tests on a manual clock).
    clock_origin_ns: Option<u64>,
    revocations: Vec<Revocation>,
    verifications: u64,
    /// Schedule the running plan's stop rather than revoke it, where it can wait.
    join_window: Option<JoinWindow>,
    /// Obstacles of the current scene are seen moving: no stop waits.
    scene_moving: bool,
    /// Action goals withdrawn so far, as the intake counts them ([`PlanGuard::withdraw_goal`]).
    goal_epoch: u64,
}

impl<M: ShieldModel> PlanGuard<M> {
    /// A guard checking with `shield` (the worker's plan check) at the cycle period
    /// `period_s`, revoking through `control`.
    pub fn new(shield: Shield<M>, period_s: f64, control: Arc<CycleControl>) -> Self {
        Self {
            shield,
            period_s,
            control,
            live: Vec::with_capacity(MAX_LIVE_PLANS),
            scene: None,
            scene_times_ns: (0, 0),
            clock_origin_ns: None,
            revocations: Vec::new(),
            verifications: 0,
            join_window: None,
            scene_moving: false,
            goal_epoch: 0,
        }
    }

    /// Lets a running plan that fails far enough ahead go on until a scheduled stop, so a
    /// joining plan may take over without stopping (`None`: revoke at once, as without).
    pub fn set_join_window(&mut self, window: Option<JoinWindow>) {
        self.join_window = window;
    }

    /// Stamps each accepted scene with the time it reached the guard, on the cycle's clock
    /// whose origin is `origin_ns` on the monotonic clock (`rt-core run`).
    pub fn set_clock_origin(&mut self, origin_ns: u64) {
        self.clock_origin_ns = Some(origin_ns);
    }

    /// An accepted scene captured at `capture_ns` (the cycle's clock): as
    /// [`PlanGuard::scene`], and a revocation it causes carries its capture and acceptance
    /// times to the cycle's log (the reaction time's start).
    ///
    /// In a scene in which obstacles are seen moving (`moving`), no stop is scheduled: a
    /// failing plan is revoked at once. A moving obstacle is predicted only over the intake's
    /// horizon (`prediction_horizon_s`: the reaction plus the stop), shorter than any wait for
    /// a join plus the stop: where it will be when the arm passes is not verified, so the arm
    /// does not go on towards it.
    pub fn scene_captured_moving(&mut self, scene: M::Scene, capture_ns: u64, moving: bool) {
        self.scene_moving = moving;
        let accepted_ns = self.clock_origin_ns.map_or(0, |origin| {
            shm_schemas::clock::monotonic_now_ns().saturating_sub(origin)
        });
        if self.scene != Some(scene) {
            self.scene_times_ns = (capture_ns, accepted_ns);
        }
        self.scene(scene);
    }

    /// Registers a plan about to be handed to the cycle (call it *before* the hand-over, so
    /// no frame can fall between the two), approved in `approved_in`, a scene accepted under
    /// `goal_epoch` ([`crate::twin_thread::intake::AcceptedFrame::goal_epoch`]). When the
    /// guard has seen a newer scene meanwhile, the live plans are verified against it at once.
    ///
    /// Returns false, registering nothing, when a goal was withdrawn after that scene was
    /// accepted: the plan may head for the withdrawn goal and must not be handed over.
    #[must_use]
    pub fn sent(&mut self, plan: Arc<Plan>, approved_in: M::Scene, goal_epoch: u64) -> bool {
        if goal_epoch < self.goal_epoch {
            return false;
        }
        if self.live.len() == MAX_LIVE_PLANS {
            self.live.remove(0);
        }
        self.live.push(plan);
        if let Some(scene) = self.scene
            && scene != approved_in
        {
            self.verify(scene);
        }
        true
    }

    /// The action goal was withdrawn — cancelled, or pre-empted by a newer one — and
    /// `goal_epoch` goals have been withdrawn in all (issue 41 item 1). Every live plan is
    /// revoked at once, whatever the twin thread is doing: the running one stops along its
    /// checked path, a joining one or one sent from rest and not adopted yet is refused by
    /// the cycle. A plan approved on a scene from before the withdrawal, still on its way
    /// (a planner search or a lookahead under way), is refused at registration
    /// ([`PlanGuard::sent`]). Called by the scene path on the intake thread, within one poll
    /// of the request's arrival.
    pub fn withdraw_goal(&mut self, goal_epoch: u64) {
        if goal_epoch <= self.goal_epoch {
            return;
        }
        self.goal_epoch = goal_epoch;
        let Some(newest) = self.live.iter().map(|p| p.id).max() else {
            return;
        };
        if newest <= self.control.revoked_up_to() {
            return;
        }
        let (plan_id, at_index) = self.control.progress().unwrap_or((newest, 0));
        self.control.revoke_up_to_because(newest, 0, 0);
        self.revocations.push(Revocation {
            plan_id,
            at_index,
            stop_due_index: None,
        });
    }

    /// Action goals withdrawn so far, as last told ([`PlanGuard::withdraw_goal`]).
    pub fn goal_epoch(&self) -> u64 {
        self.goal_epoch
    }

    /// The cycle handed plan `plan_id` back (refused, replaced, revoked, or at the end).
    pub fn returned(&mut self, plan_id: u64) {
        self.live.retain(|p| p.id != plan_id);
    }

    /// An accepted scene: when it differs from the last one, every live plan that can still
    /// move the arm is re-verified against it.
    pub fn scene(&mut self, scene: M::Scene) {
        if self.scene == Some(scene) {
            return;
        }
        self.scene = Some(scene);
        self.verify(scene);
    }

    /// Revocations made since the last call (oldest first).
    pub fn take_revocations(&mut self) -> Vec<Revocation> {
        std::mem::take(&mut self.revocations)
    }

    /// Re-verifications run so far (one per live plan checked).
    pub fn verifications(&self) -> u64 {
        self.verifications
    }

    fn standing(&self, plan: &Plan) -> Standing {
        let revoked = self.control.revoked_up_to();
        if plan.id <= revoked {
            return Standing::Inert;
        }
        // Progress and adoption from one load: read apart, a frame between the cycle's
        // adoption and its next report saw "not following" and "adopted" together and left
        // the new plan unverified (issue 41 item 3).
        let adoption = self.control.adoption();
        match (adoption.following, plan.join) {
            (Some((running, next)), _) if plan.id == running => Standing::Running { next },
            (Some((running, _)), Some(j)) if j.plan_id == running => Standing::Joining {
                join_index: j.index,
            },
            (None, None) if plan.id > adoption.adopted_up_to => Standing::NotAdopted,
            _ => Standing::Inert,
        }
    }

    /// Verifies every live plan that can still move the arm against `scene`; a failure
    /// revokes every live plan up to the newest one checked.
    fn verify(&mut self, scene: M::Scene) {
        let mut first_bad: Option<Revocation> = None;
        // The running plan failing where its stop can wait: (plan, next, first unsafe).
        let mut running_bad: Option<(u64, usize, usize)> = None;
        let mut newest_checked = 0;
        for i in 0..self.live.len() {
            let plan = self.live[i].clone();
            let bad = match self.standing(&plan) {
                Standing::Inert => continue,
                Standing::Running { next } => {
                    let bad = if next >= plan.len() {
                        None
                    } else {
                        let prev = plan.q_rad[next.saturating_sub(1)];
                        self.first_unsafe(&prev, &plan.q_rad[next..], &scene)
                            .map(|k| next + k)
                    };
                    if let (Some(k), Some(w), false) = (bad, self.join_window, self.scene_moving)
                        && w.stop_due(next, k).is_some()
                    {
                        newest_checked = newest_checked.max(plan.id);
                        running_bad = Some((plan.id, next, k));
                        continue;
                    }
                    bad
                }
                Standing::Joining { join_index } => {
                    match self.first_unsafe_joining(&plan, join_index, &scene) {
                        Some(bad) => bad,
                        // Its join point is past the running plan's end: the cycle refuses it.
                        None => continue,
                    }
                }
                Standing::NotAdopted => match plan.q_rad.first() {
                    Some(q0) => self.first_unsafe(q0, &plan.q_rad, &scene),
                    None => None,
                },
            };
            newest_checked = newest_checked.max(plan.id);
            if let Some(at_index) = bad {
                first_bad.get_or_insert(Revocation {
                    plan_id: plan.id,
                    at_index,
                    stop_due_index: None,
                });
            }
        }
        // Only the running plan fails, far enough ahead: its stop is scheduled (any other
        // failure revokes all, the running plan with them, as below).
        if first_bad.is_none()
            && let (Some((plan_id, next, k)), Some(w)) = (running_bad, self.join_window)
            && let Some(due) = w.stop_due(next, k)
        {
            self.control.schedule_stop(plan_id, due);
            self.revocations.push(Revocation {
                plan_id,
                at_index: k,
                stop_due_index: Some(due),
            });
            return;
        }
        if first_bad.is_none()
            && let Some((plan_id, _, at_index)) = running_bad
        {
            first_bad = Some(Revocation {
                plan_id,
                at_index,
                stop_due_index: None,
            });
        }
        if let Some(r) = first_bad {
            let (capture_ns, accepted_ns) = self.scene_times_ns;
            self.control
                .revoke_up_to_because(newest_checked, capture_ns, accepted_ns);
            self.revocations.push(r);
        }
    }

    /// The first unsafe sample of `plan`, scheduled to join the running plan at
    /// `join_index`, from the running plan's sample there; `None` when its join point is
    /// past the running plan's end (or that plan is gone): nothing to check.
    fn first_unsafe_joining(
        &mut self,
        plan: &Plan,
        join_index: usize,
        scene: &M::Scene,
    ) -> Option<Option<usize>> {
        let running = self
            .live
            .iter()
            .find(|p| Some(p.id) == plan.join.map(|j| j.plan_id))
            .cloned()?;
        (join_index < running.len())
            .then(|| self.first_unsafe(&running.q_rad[join_index], &plan.q_rad, scene))
    }

    fn first_unsafe(
        &mut self,
        prev: &twin::Joints,
        path: &[twin::Joints],
        scene: &M::Scene,
    ) -> Option<usize> {
        self.verifications += 1;
        self.shield
            .check_path(prev, path, self.period_s, scene)
            .err()
            .map(|(i, _)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_waits_only_where_it_still_ends_before_the_danger_with_room_to_join() {
        let w = JoinWindow {
            brake_horizon_samples: 50,
            min_lead_samples: 50,
        };
        // Unsafe at 200, arm at 10: the stop is due at 200 − 50 − slack.
        assert_eq!(w.stop_due(10, 200), Some(200 - 50 - STOP_DUE_SLACK_SAMPLES));
        // Too near: no room to plan and join before the stop — revoke now.
        assert_eq!(w.stop_due(100, 200), None);
        // Inside the stop envelope already.
        assert_eq!(w.stop_due(0, 40), None);
    }

    #[test]
    fn a_scheduled_stop_only_moves_earlier_for_the_same_plan() {
        let c = CycleControl::default();
        assert_eq!(c.stop_due(), None);
        c.schedule_stop(7, 300);
        c.schedule_stop(7, 400);
        assert_eq!(c.stop_due(), Some((7, 300)), "a later frame moved it later");
        c.schedule_stop(7, 250);
        assert_eq!(c.stop_due(), Some((7, 250)));
        c.schedule_stop(8, 500);
        assert_eq!(
            c.stop_due(),
            Some((8, 500)),
            "a new plan's stop replaces it"
        );
    }
}
