//! The twin thread's logic (not real-time; it may allocate): keeps its view of the scene
//! from the detections (each accepted frame has reached the cycle and the plan guard before
//! the worker sees it: [`crate::twin_thread::scene_path`]), runs the lookahead whenever the
//! scene or the policy changes or the cycle waits for a plan, and then either approves a
//! smoothed, checked plan or asks for retraining. Every plan it hands over is registered
//! with the plan guard ([`crate::twin_thread::plan_guard`]) first, which re-verifies all
//! plans the cycle holds against every accepted scene; which plan runs is read from the
//! cycle's report, never assumed from what was sent last. A new policy is swapped in with
//! one step; the cycle never sees a policy's plan before its lookahead has passed.
//!
//! Where things live:
//! - [`phase`]: the worker's state — [`Phase`] (episode, dwell at goal, returning home,
//!   holding after a refused return) and [`Planning`] (idle, due, back-off);
//! - [`scene_view`]: the scene and its gates ([`SceneView::ready`] → [`Hold`]);
//! - [`policy_library`]: the candidates tried in order (current policy, base policy, then —
//!   with `[sampling]` — perturbed variants of each, verified alike ([`Lookahead::sample`]),
//!   and the planner fallback when installed: [`FallbackPlanner`]);
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
pub use verdict::{GoalApproach, Lookahead, SampleTag, Sampled, Verdict};

use std::sync::Arc;

use shm_schemas::{Executor, PhaseCode};

use crate::config::RuntimeConfig;
use crate::cycle::plan::MotionState;
use crate::cycle::plan::{JoinPoint, Plan};
use crate::cycle::shield::{Shield, ShieldModel};
use crate::cycle::{CycleControl, CycleReport, Intruders, Mode, TwinIo};
use crate::rt::handoff::{BoxSender, LatestReceiver};
use crate::twin_thread::plan_guard::{JoinWindow, PlanGuard};
use crate::twin_thread::scene_path::{ScenePath, SharedGuard, lock_guard, share_guard};
use approve::{Approver, GoalCheck};
use path_recorder::PathRecorder;
use policy_library::{Candidate, PolicyLibrary};

/// Pause after the cycle refused a plan before planning again, ns.
const REFUSAL_BACKOFF_NS: u64 = 500_000_000;

/// Live plans the worker keeps at most (a cycle holds a running, a pending and a few
/// queued plans).
const MAX_LIVE_PLANS: usize = 16;

/// Sampled candidates that passed the twin whose smoothed plans are checked at most per
/// policy (best first), before the next policy or the planner fallback.
const MAX_SAMPLED_PLANS_CHECKED: usize = 4;

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

/// Whether a planning that finds no passing policy asks for retraining: not for a joining
/// plan made on a scene still changing (a moment of a moving world), nor for the
/// continuation from where a pause left the arm (the policy is judged from the start
/// posture, where the way home leads).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RetrainOnFailure {
    Yes,
    No,
}

/// The settings of the way home.
#[derive(Debug, Clone, Copy)]
struct HomeSettings {
    /// Return home after the dwell at the goal.
    enabled: bool,
    /// The dwell at the goal, ns.
    dwell_ns: u64,
}

/// The worker's ends of the hand-overs with the cycle (the scene hand-over is the
/// [`ScenePath`]'s).
struct WorkerIo {
    plans: BoxSender<Plan>,
    control: Arc<CycleControl>,
    reports: LatestReceiver<CycleReport>,
}

/// The twin thread's state.
pub struct TwinWorker<L: Lookahead, M: ShieldModel<Scene = L::Scene>> {
    approver: Approver<L, M>,
    io: WorkerIo,
    /// The plan guard, shared with the scene path.
    guard: SharedGuard<M>,
    /// The scene path, while it runs inline (it is taken for the intake thread in
    /// `rt-core run`: [`TwinWorker::take_scene_path`]).
    scene_path: Option<ScenePath<M>>,
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
    /// Verified sampling's wall-time budget per planning, s (`None`: off).
    sampling_budget_s: Option<f64>,
    report: Option<CycleReport>,
    last_mode: Mode,
    refused_seen: u64,
    /// Plans handed to the cycle and not handed back yet, each with the scene it was
    /// approved in (oldest first). Which one runs is read from the cycle's report.
    live: Vec<(Arc<Plan>, L::Scene)>,
    /// The newest plan id handed to the cycle.
    newest_sent_id: u64,
    next_request_id: u64,
    /// After a pause, plan from where the arm stopped before going home
    /// (`continue_after_pause`).
    continue_after_pause: bool,
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// A worker over a lookahead and a shield model, talking to a cycle through `io`. The
    /// plan guard checks with a copy of `shield`.
    pub fn new(cfg: &RuntimeConfig, la: L, shield: Shield<M>, io: TwinIo<L::Scene>) -> Self
    where
        M: Clone,
    {
        let period_s = 1.0 / cfg.rate_hz;
        let mut plan_guard = PlanGuard::new(
            Shield::new(shield.model().clone(), *shield.limits()),
            period_s,
            io.control.clone(),
        );
        plan_guard.set_join_window(JoinWindow::from_runtime(cfg));
        let guard = share_guard(plan_guard);
        let TwinIo {
            plans,
            scenes,
            control,
            reports,
        } = io;
        Self {
            approver: Approver::new(cfg, la, shield),
            io: WorkerIo {
                plans,
                control,
                reports,
            },
            scene_path: Some(ScenePath::new(scenes, guard.clone())),
            guard,
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
            sampling_budget_s: cfg.sampling.enabled.then_some(cfg.sampling.budget_s),
            report: None,
            last_mode: Mode::Idle,
            refused_seen: 0,
            live: Vec::new(),
            newest_sent_id: 0,
            next_request_id: 1,
            continue_after_pause: cfg.continue_after_pause,
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

    /// The scene path, for the intake thread (`rt-core run`): from then on the caller hands
    /// each frame's scene to the cycle and the plan guard itself, and tells the worker with
    /// [`TwinWorker::note_detection`] / [`TwinWorker::note_refused_detection`].
    pub fn take_scene_path(&mut self) -> Option<ScenePath<M>> {
        self.scene_path.take()
    }

    /// An accepted detection arrived (captured at `stamp_ns` on the cycle's clock; with a
    /// goal or without one; `settled` or not): through the scene path (while inline) to the
    /// cycle and the plan guard at once — every live plan is re-verified against it and
    /// revoked when unsafe — then noted for planning ([`TwinWorker::note_detection`]).
    pub fn on_detection(
        &mut self,
        scene: L::Scene,
        stamp_ns: u64,
        goal_seen: bool,
        settled: bool,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        self.on_moving_detection(scene, stamp_ns, goal_seen, settled, Intruders::NONE, events);
    }

    /// [`TwinWorker::on_detection`] with the obstacles perception saw moving (the intake's
    /// [`crate::twin_thread::intake::AcceptedFrame::intruders`]), for speed and separation
    /// monitoring on the cycle.
    pub fn on_moving_detection(
        &mut self,
        scene: L::Scene,
        stamp_ns: u64,
        goal_seen: bool,
        settled: bool,
        intruders: Intruders,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        if let Some(path) = self.scene_path.as_mut() {
            path.accepted(scene, stamp_ns, intruders);
        }
        self.note_detection(scene, stamp_ns, goal_seen, settled, events);
    }

    /// An accepted detection that the scene path has already handed to the cycle and the
    /// plan guard: marks a scene change for planning. Without a goal, or not settled, nothing
    /// new is planned (the guard still re-verified the live plans against its obstacles).
    pub fn note_detection(
        &mut self,
        scene: L::Scene,
        stamp_ns: u64,
        goal_seen: bool,
        settled: bool,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let change = self.scene.accept(scene, stamp_ns, goal_seen, settled);
        if change.plan_due {
            self.planning.request();
        }
        self.take_revocations(events);
    }

    /// A detection frame was refused (see `twin_thread::intake`): through the scene path
    /// (while inline) the cycle is told at once (it stops the arm, keeping the last trusted
    /// scene for the shield), then noted ([`TwinWorker::note_refused_detection`]).
    pub fn on_refused_detection(&mut self) {
        if let Some(path) = self.scene_path.as_mut() {
            path.refused();
        }
        self.note_refused_detection();
    }

    /// A refused frame the scene path has already told the cycle of: nothing is planned
    /// until an accepted frame arrives.
    pub fn note_refused_detection(&mut self) {
        self.scene.refuse();
        self.planning.request();
    }

    /// The frame about to be noted was accepted under `goal_epoch` withdrawn action goals
    /// ([`crate::twin_thread::intake::AcceptedFrame::goal_epoch`]): the plans made on its
    /// scene are registered with the plan guard under it, and refused there once a later
    /// withdrawal is known (issue 41 item 1).
    pub fn note_goal_epoch(&mut self, goal_epoch: u64) {
        self.scene.set_goal_epoch(goal_epoch);
    }

    /// The goal the arm was moving toward was cancelled (the `Reach` action, goal source
    /// `action`): the running and any pending plan are revoked — the cycle stops along the
    /// checked path — and nothing new is planned until a goal is given again.
    pub fn note_goal_cancelled(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        self.revoke_under_way(events);
        self.planning.request();
    }

    /// The plan guard's revocations since the last look, as events; planning is due again.
    fn take_revocations(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let revocations = lock_guard(&self.guard).take_revocations();
        for r in revocations {
            self.planning.request();
            events.push(match r.stop_due_index {
                None => TwinEvent::Revoked {
                    plan_id: r.plan_id,
                    at_index: r.at_index,
                },
                Some(stop_due_index) => TwinEvent::StopScheduled {
                    plan_id: r.plan_id,
                    at_index: r.at_index,
                    stop_due_index,
                },
            });
        }
    }

    /// The plan handed to the cycle with id `plan_id`, if the cycle has not handed it back.
    fn live_plan(&self, plan_id: u64) -> Option<&(Arc<Plan>, L::Scene)> {
        self.live.iter().find(|(p, _)| p.id == plan_id)
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
        self.take_revocations(events);
        match self.scene.ready() {
            Err(Hold::Refused | Hold::NoScene) => return,
            Err(Hold::Unsettled) if self.stop_due_on_running() => {
                // The one plan made on a scene still changing: one joining the running plan
                // before its scheduled stop (see `plan_due`).
                if let Some(r) = self.report
                    && self.planning.is_due()
                    && !self.planning.backing_off(r.t_ns)
                    && !self.io.control.shutdown_requested()
                {
                    self.plan_due(r, events);
                }
                return;
            }
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
        let mut returned = Vec::new();
        self.io.plans.collect_returned_with(|p| returned.push(p.id));
        if !returned.is_empty() {
            self.live.retain(|(p, _)| !returned.contains(&p.id));
            let mut guard = lock_guard(&self.guard);
            for id in returned {
                guard.returned(id);
            }
        }
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

    /// A lookahead run after a scene change found the policy's continuation unsafe while
    /// a plan is under way: the running and any pending plan are revoked too (the cycle
    /// stops along the checked path).
    fn revoke_under_way(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let Some((running_id, next)) = self.io.control.progress() else {
            return;
        };
        let newest = self.newest_sent_id.max(running_id);
        if newest <= self.io.control.revoked_up_to() {
            return;
        }
        // The cause: the scene the lookahead ran on (its acceptance time is the intake
        // thread's, not known here).
        self.io
            .control
            .revoke_up_to_because(newest, self.scene.stamp_ns(), 0);
        events.push(TwinEvent::Revoked {
            plan_id: running_id,
            at_index: next,
        });
    }

    /// Whether the plan guard has scheduled a stop on the plan the cycle runs (as of its
    /// last report): a joining plan may then be made on a scene still changing.
    fn stop_due_on_running(&self) -> bool {
        self.report.is_some_and(|r| {
            r.mode == Mode::Following
                && self
                    .io
                    .control
                    .stop_due()
                    .is_some_and(|(id, _)| id == r.plan_id)
        })
    }

    /// A plan is due and the gates are open: where it starts (at rest, or joining the
    /// running plan `join_ahead` samples ahead of the arm), then the library's candidates.
    fn plan_due(&mut self, r: CycleReport, events: &mut Vec<TwinEvent<L::Scene>>) {
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
            other => (other, RetrainOnFailure::Yes),
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
            Mode::Idle | Mode::Stopped => (MotionState::at_rest(r.cmd.q_rad), None),
            Mode::Following => match self.live_plan(r.plan_id) {
                Some((s, _)) if r.next_index + self.join_ahead < s.len() => {
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
        self.plan_from(start, join, scene, retrain, events);
    }

    /// Whether the way home is in hand this iteration (planned now, or waiting out the
    /// dwell at the goal or a back-off); the ordinary planning waits meanwhile.
    fn return_home_due(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) -> bool {
        // The plan the cycle ran last, from its report; not while a newer one is on its way.
        let Some(r) = self.report else {
            return false;
        };
        let Some((sent, _)) = self.live_plan(r.plan_id) else {
            return false;
        };
        if self.live.iter().any(|(p, _)| p.id > r.plan_id) {
            return false;
        }
        let (sent_id, policy_id, sent_len) = (sent.id, sent.policy_id, sent.len());
        let at_end = r.mode == Mode::Idle && r.next_index >= sent_len;
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
            // Continue from where the arm stopped when a plan from there passes; only
            // otherwise back along the executed path.
            if self.continue_from_rest(r, events) {
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

    /// After a pause (issue 33 item 5, continuation): an episode plan from where the arm
    /// stopped — the library's candidates as ever (a policy's lookahead prepends the
    /// approach to the task's start posture), then the planner fallback straight to the
    /// goal — checked like any plan, on a settled scene with a goal. True when one was sent;
    /// false leaves the way home along the executed path to the caller. Asks for no
    /// retraining: the policy is judged from the start posture, where the way home leads.
    fn continue_from_rest(
        &mut self,
        r: CycleReport,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        if !self.continue_after_pause || !self.gate {
            return false;
        }
        let Ok(scene) = self.scene.ready() else {
            return false;
        };
        let sent_before = self.newest_sent_id;
        self.plan_from(
            MotionState::at_rest(r.cmd.q_rad),
            None,
            scene,
            RetrainOnFailure::No,
            events,
        );
        if self.newest_sent_id > sent_before {
            self.planning.taken();
            return true;
        }
        false
    }

    /// Hands a checked plan to the cycle, registered with the plan guard first (so a frame
    /// that arrived since its approval is checked against it, and none can fall between),
    /// and keeps a copy among the live plans; false when the hand-over slot is full or the
    /// guard refused it (its goal was withdrawn since its scene was accepted: nothing is
    /// planned again until a frame from after the withdrawal is noted, which asks for it).
    fn send_plan(&mut self, plan: Plan, scene: L::Scene) -> bool {
        let copy = Arc::new(plan.clone());
        if !lock_guard(&self.guard).sent(copy.clone(), scene, self.scene.goal_epoch()) {
            return false;
        }
        if self.io.plans.send(Box::new(plan)).is_err() {
            lock_guard(&self.guard).returned(copy.id);
            self.planning.request();
            return false;
        }
        self.newest_sent_id = copy.id;
        if self.live.len() == MAX_LIVE_PLANS {
            // Boxes leaked rather than returned (a full return queue): forget the oldest.
            self.live.remove(0);
        }
        self.live.push((copy, scene));
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
        if let (true, Some(budget_s)) = (self.gate, self.sampling_budget_s) {
            let deadline = deadline_in(budget_s);
            for candidate in Candidate::ORDER {
                if let Tried::Done =
                    self.try_sampled(candidate, &start, join, scene, deadline, events)
                {
                    return;
                }
            }
        }
        if self.gate && self.library.planner_mut().is_some() {
            // No policy passes: retraining is asked for as always, and the planner's path,
            // when it passes the same checks, moves the arm meanwhile.
            if retrain == RetrainOnFailure::Yes {
                self.ask_retrain(verdict, scene, events);
            }
            if self.try_planner(&start, join, scene, events) {
                return;
            }
        }
        // With a stop scheduled on the running plan the guard has bounded it already (safe
        // up to the stop's end): it stops there unless a later frame's plan joins it first.
        if lookahead_unsafe
            && self.live.iter().any(|(_, s)| *s != scene)
            && !self.stop_due_on_running()
        {
            self.revoke_under_way(events);
        }
        if self.gate && retrain == RetrainOnFailure::Yes {
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
            sample: None,
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
            sample: None,
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
                &self.phase,
                &self.planning,
                self.report.map_or(0, |r| r.t_ns),
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
        if let Some((sent, _)) = self.live.last() {
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

/// The instant `budget_s` from now (the twin thread's wall clock: it is not real-time).
#[allow(clippy::disallowed_methods)]
fn deadline_in(budget_s: f64) -> std::time::Instant {
    std::time::Instant::now() + std::time::Duration::from_secs_f64(budget_s)
}
