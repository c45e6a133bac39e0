//! The twin thread's logic (not real-time; it may allocate): keeps the scene in sync with
//! detections (forwarding each one to the cycle at once), re-verifies the running plan when
//! the scene changes (revoking it when it has become unsafe), runs the lookahead whenever
//! the scene or the policy changes or the cycle waits for a plan, and then either approves
//! a smoothed, checked plan or asks for retraining. A new policy is swapped in with one
//! step; the cycle never sees a policy's plan before its lookahead has passed.
//!
//! Where things live:
//! - [`phase`]: the worker's state — [`Phase`] (episode, dwell at goal, returning home,
//!   holding after a refused return) and [`Planning`] (idle, due, back-off);
//! - [`scene_view`]: the scene and its gates ([`SceneView::ready`] → [`Hold`]);
//! - [`policy_library`]: the candidates tried in order (current policy, base policy, and
//!   the planner fallback when installed: [`FallbackPlanner`]);
//! - [`path_recorder`]: the executed path and the way home;
//! - [`approve`]: lookahead → smoothing → shield → goal check, or a [`PlanRejection`];
//! - [`verdict`]: the [`Lookahead`] trait and its [`Verdict`]; [`event`]: [`TwinEvent`].
//!
//! A replacement plan joins the running one at a sample `join_ahead_s` ahead of the arm
//! ([`Plan::sample`]), so the hand-over is continuous. With `return_home`, once an episode's
//! plan has ended at its goal and the arm has rested `dwell_at_goal_s`, the arm goes back
//! along its executed path (checked in the scene then in force; refused → it holds and the
//! lookahead takes over). A controlled stop on the way is handled the same way at once: back
//! along the path, then the episode again from its start.
//!
//! [`TwinWorker::step`] is one iteration; the `run` binary calls it in a loop between polls
//! of its iceoryx2 subscribers, the tests call it directly.

pub mod approve;
pub mod event;
pub mod path_recorder;
pub mod phase;
pub mod policy_library;
pub mod scene_view;
pub mod verdict;

pub use approve::PlanRejection;
pub use event::{TwinEvent, VerdictSource};
pub use phase::{Phase, Planning, Transition};
pub use policy_library::{FallbackPlanner, PLANNER_POLICY_ID};
pub use scene_view::{Hold, SceneView};
pub use verdict::{GoalApproach, Lookahead, Verdict};

use shm_schemas::{Executor, PhaseCode};

use crate::config::RuntimeConfig;
use crate::cycle::brake::MotionState;
use crate::cycle::plan::{JoinPoint, Plan};
use crate::cycle::shield::{Shield, ShieldModel};
use crate::cycle::{CycleReport, Mode, SceneUpdate, TwinIo};
use approve::{Approver, GoalCheck};
use path_recorder::PathRecorder;
use policy_library::{Candidate, PolicyLibrary};

/// Pause after the cycle refused a plan before planning again, ns.
const REFUSAL_BACKOFF_NS: u64 = 500_000_000;

/// What one candidate of the library did in [`TwinWorker::plan_from`].
enum Tried {
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

/// The settings of the way home.
#[derive(Debug, Clone, Copy)]
struct HomeSettings {
    /// Return home after the dwell at the goal.
    enabled: bool,
    /// The dwell at the goal, ns.
    dwell_ns: u64,
}

/// The twin thread's state.
pub struct TwinWorker<L: Lookahead, M: ShieldModel<Scene = L::Scene>> {
    approver: Approver<L, M>,
    io: TwinIo<L::Scene>,
    library: PolicyLibrary<L::Policy, L::Scene>,
    scene: SceneView<L::Scene>,
    path: PathRecorder,
    phase: Phase,
    planning: Planning,
    home: HomeSettings,
    /// Samples between the arm and where a replacement plan joins.
    join_ahead: usize,
    /// Motion waits for a passing lookahead (off only for `--no-lookahead`).
    gate: bool,
    report: Option<CycleReport>,
    last_mode: Mode,
    refused_seen: u64,
    /// The plan sent last, and the scene it was approved in.
    sent: Option<(Plan, L::Scene)>,
    /// The plan `sent` joins (still running until the join point), if `sent` is a join.
    joined: Option<Plan>,
    next_request_id: u64,
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// A worker over a lookahead and a shield model, talking to a cycle through `io`.
    pub fn new(cfg: &RuntimeConfig, la: L, shield: Shield<M>, io: TwinIo<L::Scene>) -> Self {
        let period_s = 1.0 / cfg.rate_hz;
        Self {
            approver: Approver::new(cfg, la, shield),
            io,
            library: PolicyLibrary::default(),
            scene: SceneView::default(),
            path: PathRecorder::default(),
            phase: Phase::Episode,
            planning: Planning::Due,
            home: HomeSettings {
                enabled: cfg.return_home,
                dwell_ns: (cfg.dwell_at_goal_s * 1e9) as u64,
            },
            join_ahead: (cfg.join_ahead_s / period_s).ceil() as usize,
            gate: true,
            report: None,
            last_mode: Mode::Idle,
            refused_seen: 0,
            sent: None,
            joined: None,
            next_request_id: 1,
        }
    }

    /// Installs the planner fallback (`planner_fallback`): when no policy passes, the
    /// planner's collision-free path is smoothed, checked like a policy's plan (shield,
    /// goal reached) and executed while the learner retrains; a policy that passes
    /// replaces it at the next planning. Without the lookahead gate it is never used.
    pub fn set_fallback_planner(&mut self, planner: Box<dyn FallbackPlanner<L::Scene>>) {
        self.library.set_planner(planner);
    }

    /// Turns the lookahead gate off (`rt-core run --no-lookahead`, the demonstration of
    /// what Foresight prevents): every lookahead's plan is executed whatever its verdict,
    /// and no retraining is requested. Verdicts are still computed and reported.
    pub fn disable_lookahead_gate(&mut self) {
        self.gate = false;
    }

    /// An accepted detection arrived (captured at `stamp_ns` on the cycle's clock; with a
    /// goal or without one; `settled` or not): forwards it to the cycle at once and marks a
    /// scene change. Without a goal, or not settled, the obstacles count (the running plan is
    /// re-verified against them and revoked when unsafe) but nothing new is planned.
    pub fn on_detection(
        &mut self,
        scene: L::Scene,
        stamp_ns: u64,
        goal_seen: bool,
        settled: bool,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        self.io.scenes.send(SceneUpdate {
            scene,
            stamp_ns,
            refused: false,
        });
        let change = self.scene.accept(scene, stamp_ns, goal_seen, settled);
        if change.plan_due {
            self.planning.request();
        }
        if change.scene_changed {
            self.reverify_running(events);
        }
    }

    /// A detection frame was refused (see `twin_thread::intake`): the cycle is told at once
    /// (it stops the arm, keeping the last trusted scene for the shield) and nothing is
    /// planned until an accepted frame arrives.
    pub fn on_refused_detection(&mut self) {
        self.scene.refuse();
        self.planning.request();
        if let Some(scene) = self.scene.scene() {
            self.io.scenes.send(SceneUpdate {
                scene,
                stamp_ns: self.scene.stamp_ns(),
                refused: true,
            });
        }
    }

    /// A validated, prepared policy arrived: swapped in with one step as the current
    /// policy (the first one ever received is kept as the base); a replaced one is dropped
    /// here, off the cycle.
    pub fn on_policy(&mut self, policy: Box<L::Policy>, events: &mut Vec<TwinEvent<L::Scene>>) {
        let policy_id = L::policy_id(&policy);
        drop(self.library.receive(policy));
        self.planning.request();
        events.push(TwinEvent::PolicySwapped { policy_id });
    }

    /// The latest cycle report seen.
    pub fn last_report(&self) -> Option<&CycleReport> {
        self.report.as_ref()
    }

    /// The current policy.
    pub fn policy(&self) -> Option<&L::Policy> {
        self.library.current()
    }

    /// The base policy (the first received), once another has replaced it as current.
    pub fn base_policy(&self) -> Option<&L::Policy> {
        self.library.base()
    }

    /// The lookahead.
    pub fn lookahead_mut(&mut self) -> &mut L {
        self.approver.lookahead_mut()
    }

    /// The control flags shared with the cycle (shutdown, acknowledgement, revocation).
    pub fn control(&self) -> &std::sync::Arc<crate::cycle::CycleControl> {
        &self.io.control
    }

    /// Where the worker is in its excursion.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Whether a plan is wanted.
    pub fn planning(&self) -> Planning {
        self.planning
    }

    /// The compact code of the state (verdict diagnostics, the run timeline).
    pub fn phase_code(&self) -> PhaseCode {
        phase::phase_code(
            &self.phase,
            &self.planning,
            self.report.map_or(0, |r| r.t_ns),
        )
    }

    /// One iteration: takes reports, frees returned plans, and plans when due. Events are
    /// appended to `events`.
    pub fn step(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        self.take_reports();
        match self.scene.ready() {
            Err(Hold::Refused | Hold::NoScene) => return,
            Err(Hold::Unsettled) => {
                // No plan of any kind reaches the cycle from an unsettled scene; the running
                // plan was re-verified against it on arrival.
                if self.planning.is_due() && self.scene.report_once(Hold::Unsettled) {
                    events.push(TwinEvent::AwaitingSettledScene {
                        stamp_ns: self.scene.stamp_ns(),
                    });
                }
                return;
            }
            Ok(_) | Err(Hold::NoGoal) => {}
        }
        if self.return_home_due(events) || !self.planning.is_due() {
            return;
        }
        let Some(r) = self.report else {
            return;
        };
        if self.planning.backing_off(r.t_ns)
            || r.awaiting_ack
            || self.io.control.shutdown_requested()
        {
            return;
        }
        self.plan_due(r, events);
    }

    /// Takes the cycle's newest report and frees returned plans (no planning).
    pub fn take_reports(&mut self) {
        self.io.plans.collect_returned();
        if let Some(r) = self.io.reports.latest() {
            if r.mode == Mode::Stopped && self.last_mode != Mode::Stopped {
                self.planning.request();
            }
            if r.last_refused_plan_id != 0 && r.last_refused_plan_id != self.refused_seen {
                self.refused_seen = r.last_refused_plan_id;
                // The cycle refuses while it cannot move (a link error, a stop under way):
                // plan again after a pause, not at the twin thread's polling rate.
                self.planning.refused(r.t_ns, REFUSAL_BACKOFF_NS);
            }
            self.last_mode = r.mode;
            self.report = Some(r);
        }
    }

    /// Re-verifies, against the scene now in force, the plan the cycle is following — from
    /// the sample the cycle will send next (its own progress word, not the last report) —
    /// and the plan scheduled to join it, if any. A failure revokes both.
    fn reverify_running(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let Some(scene) = self.scene.scene() else {
            return;
        };
        let Some((running_id, next)) = self.io.control.progress() else {
            return;
        };
        let (running, pending) = match (self.sent.as_ref().map(|s| &s.0), self.joined.as_ref()) {
            (Some(s), _) if s.id == running_id => (s, None),
            (Some(s), Some(j)) if j.id == running_id => (j, Some(s)),
            _ => return,
        };
        let mut first_bad: Option<(u64, usize)> = None;
        if next < running.len() {
            let prev = running.q_rad[next.saturating_sub(1)];
            if let Some(i) = self
                .approver
                .first_unsafe(&prev, &running.q_rad[next..], &scene)
            {
                first_bad = Some((running.id, next + i));
            }
        }
        if first_bad.is_none()
            && let Some(p) = pending
            && let Some(j) = p.join
            && j.index < running.len()
            && let Some(i) = self
                .approver
                .first_unsafe(&running.q_rad[j.index], &p.q_rad, &scene)
        {
            first_bad = Some((p.id, i));
        }
        if let Some((plan_id, at_index)) = first_bad {
            let newest = pending.map_or(running.id, |p| p.id);
            self.io.control.revoke_up_to(newest);
            self.planning.request();
            events.push(TwinEvent::Revoked { plan_id, at_index });
        }
    }

    /// A lookahead run after a scene change found the policy's continuation unsafe while
    /// a plan is under way: the running and any pending plan are revoked too (the cycle
    /// stops along the checked path).
    fn revoke_under_way(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let Some((running_id, next)) = self.io.control.progress() else {
            return;
        };
        let newest = self
            .sent
            .as_ref()
            .map_or(running_id, |(s, _)| s.id.max(running_id));
        if newest <= self.io.control.revoked_up_to() {
            return;
        }
        self.io.control.revoke_up_to(newest);
        events.push(TwinEvent::Revoked {
            plan_id: running_id,
            at_index: next,
        });
    }

    /// A plan is due and the gates are open: where it starts (at rest, or joining the
    /// running plan `join_ahead` samples ahead of the arm), then the library's candidates.
    fn plan_due(&mut self, r: CycleReport, events: &mut Vec<TwinEvent<L::Scene>>) {
        if self.library.current().is_none() {
            return;
        }
        let scene = match self.scene.ready() {
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
            Mode::Idle | Mode::Stopped => (MotionState::at_rest(r.cmd.q_rad), None),
            Mode::Following => match self.sent.as_ref() {
                Some((s, _)) if s.id == r.plan_id && r.next_index + self.join_ahead < s.len() => {
                    let index = r.next_index + self.join_ahead;
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
        self.plan_from(start, join, scene, events);
    }

    /// Whether the way home is in hand this iteration (planned now, or waiting out the
    /// dwell at the goal or a back-off); the ordinary planning waits meanwhile.
    fn return_home_due(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) -> bool {
        let (Some(r), Some((sent, _))) = (self.report, self.sent.as_ref()) else {
            return false;
        };
        let (sent_id, policy_id, sent_len) = (sent.id, sent.policy_id, sent.len());
        let at_end = r.mode == Mode::Idle && r.plan_id == sent_id && r.next_index >= sent_len;
        let stopped = r.mode == Mode::Stopped && self.planning.is_due();
        if !at_end && !stopped {
            return false;
        }
        if at_end && self.phase == Phase::ReturningHome {
            // Home: the next excursion starts here (after a stop on the way, with the
            // episode again).
            if self.path.arrive_home() {
                self.planning.request();
            }
            return false;
        }
        if !self.home.enabled || self.path.len() < 2 || self.phase.return_refused_for(sent_id) {
            return false;
        }
        let Some(scene) = self.scene.scene() else {
            return false;
        };
        if stopped {
            if self.planning.backing_off(r.t_ns) {
                return true;
            }
            // Cut the path where the brake left the arm; off the path, plan as usual.
            if !self.path.cut_at(&r.cmd.q_rad) || self.path.len() < 2 {
                return false;
            }
        } else {
            self.phase = self.phase.next(Transition::RestingAtGoal {
                plan_id: sent_id,
                now_ns: r.t_ns,
            });
            if let Phase::DwellAtGoal { since_ns, .. } = self.phase
                && r.t_ns.saturating_sub(since_ns) < self.home.dwell_ns
            {
                return true;
            }
        }
        // The executed path reversed, one waypoint per twin step; ends exactly at its start.
        let stride = self.approver.samples_per_step();
        self.path.way_home(stride, &mut self.approver.waypoints);
        let start = MotionState::at_rest(r.cmd.q_rad);
        let plan = match self.approver.smoothed_checked_plan(
            &start,
            None,
            policy_id,
            &scene,
            GoalCheck::None,
        ) {
            Ok(plan) => plan,
            Err(why) => {
                self.phase = self
                    .phase
                    .next(Transition::ReturnRefused { plan_id: sent_id });
                self.planning.request();
                events.push(TwinEvent::ReturnHomeRefused { why });
                return false;
            }
        };
        let (plan_id, samples) = (plan.id, plan.len());
        if self.send_plan(plan, scene) {
            self.phase = self.phase.next(Transition::ReturnSent);
            if stopped {
                self.path.interrupt();
                self.planning.taken();
            }
            events.push(TwinEvent::ReturningHome { plan_id, samples });
        }
        true
    }

    /// Hands a checked plan to the cycle and keeps a copy as the sent plan; false when the
    /// hand-over slot is full.
    fn send_plan(&mut self, plan: Plan, scene: L::Scene) -> bool {
        let copy = plan.clone();
        let joins = plan.join.is_some();
        if self.io.plans.send(Box::new(plan)).is_err() {
            return false;
        }
        let previous = self.sent.replace((copy, scene));
        self.joined = if joins { previous.map(|p| p.0) } else { None };
        true
    }

    /// Plans the next episode from `start`: the library's candidates in order; the first
    /// whose lookahead and smoothed plan pass is approved. When none passes, the first
    /// failure is what counts: the running plan is revoked when that continuation is unsafe
    /// in a changed scene, and retraining is asked for (once per policy and scene).
    fn plan_from(
        &mut self,
        start: MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let mut first_failure: Option<(Verdict, bool)> = None;
        for candidate in Candidate::ORDER {
            if candidate == Candidate::Base && !self.gate {
                // Without the lookahead gate the current policy's plan is taken as it is.
                break;
            }
            match self.try_policy(candidate, &start, join, scene, events) {
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
        if self.gate && self.library.planner_mut().is_some() {
            // No policy passes: retraining is asked for as always, and the planner's path,
            // when it passes the same checks, moves the arm meanwhile.
            self.ask_retrain(verdict, scene, events);
            if self.try_planner(&start, join, scene, events) {
                return;
            }
        }
        if lookahead_unsafe && self.sent.as_ref().is_some_and(|(_, s)| *s != scene) {
            self.revoke_under_way(events);
        }
        if self.gate {
            self.ask_retrain(verdict, scene, events);
        }
    }

    /// Asks for retraining after `verdict` failed in `scene` (once per policy and scene).
    fn ask_retrain(
        &mut self,
        verdict: Verdict,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        if self.library.should_ask_retrain(verdict.policy_id, scene) {
            events.push(TwinEvent::Retrain {
                request_id: self.next_request_id,
                verdict,
                scene,
            });
            self.next_request_id += 1;
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
        };
        let Some(planner) = self.library.planner_mut() else {
            return false;
        };
        let t0 = std::time::Instant::now();
        let verdict = planner.plan(&scene, &start.q_rad, &mut self.approver.waypoints);
        events.push(TwinEvent::Verdict {
            verdict,
            scene,
            elapsed_s: t0.elapsed().as_secs_f64(),
            source,
        });
        if !(verdict.task_ok && verdict.safe) {
            return false;
        }
        if self.approver.waypoints.is_empty() {
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
                self.send_approved(plan, start, join, scene, events);
                true
            }
            Err(why) => {
                events.push(TwinEvent::PlanRejected {
                    policy_id: PLANNER_POLICY_ID,
                    why,
                });
                events.push(TwinEvent::Verdict {
                    verdict: why.failed_verdict(verdict),
                    scene,
                    elapsed_s: t0.elapsed().as_secs_f64(),
                    source,
                });
                false
            }
        }
    }

    /// One policy of the library: its lookahead, then (when it passes) its smoothed,
    /// shield-checked plan, sent to the cycle.
    // The lookahead's own compute time for its verdict (the twin thread is not real-time).
    #[allow(clippy::disallowed_methods)]
    fn try_policy(
        &mut self,
        candidate: Candidate,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> Tried {
        let Some(policy) = self.library.get(candidate) else {
            return Tried::NoPolicy;
        };
        let source = VerdictSource {
            phase: self.phase_code(),
            executor: Executor::Policy,
        };
        let t0 = std::time::Instant::now();
        let verdict = self.approver.lookahead(policy, &scene, &start.q_rad);
        events.push(TwinEvent::Verdict {
            verdict,
            scene,
            elapsed_s: t0.elapsed().as_secs_f64(),
            source,
        });
        if self.gate && !(verdict.task_ok && verdict.safe) {
            return Tried::Failed {
                verdict,
                lookahead_unsafe: !verdict.safe,
            };
        }
        if self.approver.waypoints.is_empty() {
            // Already at the goal: nothing to do.
            return Tried::Done;
        }
        let goal_check = match self.library.get(candidate) {
            Some(policy) if self.gate => GoalCheck::Policy(policy),
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
                // The lookahead passed but the plan the arm would follow does not: publish
                // the verdict as failed (and, when no policy passes, ask for retraining)
                // instead of waiting for a plan that will not come.
                let failed = why.failed_verdict(verdict);
                events.push(TwinEvent::Verdict {
                    verdict: failed,
                    scene,
                    elapsed_s: t0.elapsed().as_secs_f64(),
                    source,
                });
                return Tried::Failed {
                    verdict: failed,
                    lookahead_unsafe: false,
                };
            }
        };
        self.send_approved(plan, start, join, scene, events);
        Tried::Done
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
            self.planning.request();
            return;
        }
        if let Some((sent, _)) = self.sent.as_ref() {
            self.path
                .record_episode_plan(start, join, self.phase.returning(), sent);
            self.phase = self.phase.next(Transition::EpisodePlanSent);
        }
        events.push(TwinEvent::PlanApproved {
            plan_id,
            policy_id,
            joins: join.is_some(),
        });
    }
}
