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
//! - [`phase`]: the worker's state — [`Excursion`]: the [`Phase`] (episode, continuation,
//!   dwell at goal, pause, returning home, holding after a refused return) and whether a stop
//!   owes the episode again once home — and [`Planning`] (idle, due, back-off). "Why is the
//!   arm holding?" is answered by these and the cycle's state (`docs/twin-worker.md`);
//! - [`scene_view`]: the scene and its gates ([`SceneView::ready`] → [`Hold`]);
//! - [`policy_library`]: the candidates tried in order (current policy, base policy, then —
//!   with `[sampling]` — perturbed variants of each, verified alike ([`Lookahead::sample`]),
//!   and the planner fallback when installed: [`FallbackPlanner`]);
//! - [`path_recorder`]: the executed path and the way home;
//! - `planning`: where a plan starts, the candidates in order (policy, sampling, planner),
//!   the hand-over to the cycle and the continuation after a pause;
//! - [`approve`]: lookahead → smoothing → shield → goal check, or a [`PlanRejection`];
//! - `moving`: planning from rest while the world still moves (`plan_in_moving_world`);
//! - `join`: where a planner-made plan joins the running one (ahead of its search);
//! - [`verdict`]: the [`Lookahead`] trait and its [`Verdict`]; [`event`]: [`TwinEvent`];
//! - [`goal_taken`]: a goal a box has taken, said at once; [`retreat`]: an arm at rest too
//!   close to a box that came to it backs out along the path it came.
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

mod acceptance;
pub mod approve;
pub mod event;
pub mod goal_taken;
mod join;
mod moving;
pub mod path_recorder;
pub mod phase;
mod planning;
pub mod policy_library;
pub mod retreat;
pub mod scene_view;
pub mod verdict;

pub use approve::PlanRejection;
pub use event::{TwinEvent, VerdictSource};
pub use phase::{Excursion, Leg, Phase, Planning, Transition};
pub use policy_library::{FallbackPlanner, PLANNER_POLICY_ID};
pub use scene_view::{Hold, SceneView};
pub use verdict::{GoalApproach, Lookahead, SampleTag, Sampled, Verdict};

use std::sync::Arc;

use shm_schemas::PhaseCode;

use crate::config::RuntimeConfig;
use crate::cycle::plan::{MotionState, Plan};
use crate::cycle::shield::{Shield, ShieldModel};
use crate::cycle::{CycleControl, CycleReport, Mode, TwinIo};
use crate::rt::handoff::{BoxSender, LatestReceiver};
use crate::twin_thread::intake::AcceptedFrame;
use crate::twin_thread::plan_guard::{JoinWindow, PlanGuard};
use crate::twin_thread::scene_path::{ScenePath, SharedGuard, lock_guard, share_guard};
use approve::{Approver, GoalCheck};
use path_recorder::PathRecorder;
use policy_library::PolicyLibrary;

/// Pause after the cycle refused a plan before planning again, ns.
const REFUSAL_BACKOFF_NS: u64 = 500_000_000;

/// The worker's settings, fixed at its start.
#[derive(Debug, Clone, Copy)]
struct Settings {
    /// Return home after the dwell at the goal.
    return_home: bool,
    /// The dwell at the goal, ns.
    dwell_ns: u64,
    /// Samples between the arm and where a replacement plan joins.
    join_ahead: usize,
    /// Motion waits for a passing lookahead (off only for `--no-lookahead`).
    gate: bool,
    /// Verified sampling's wall-time budget per planning, s (`None`: off).
    sampling_budget_s: Option<f64>,
    /// After a pause, plan from where the arm stopped before going home
    /// (`continue_after_pause`).
    continue_after_pause: bool,
    /// Plan from rest on a scene still changing (`plan_in_moving_world`: the `moving` module).
    plan_in_moving_world: bool,
    /// Samples a planner search may last (its budget): the lead of its join point (`join`).
    search_lead: usize,
    /// Refused retrainings for one scene before it is "not learned" (`acceptance`).
    max_refused_retrainings: u32,
    /// A goal reached is not driven again until the goal or the scene changes (camera
    /// goals; `acceptance`).
    rest_after_goal: bool,
}

/// The worker's ends of the hand-overs with the cycle and the plan guard (the scene
/// hand-over is the [`ScenePath`]'s).
struct WorkerIo<M: ShieldModel> {
    plans: BoxSender<Plan>,
    control: Arc<CycleControl>,
    reports: LatestReceiver<CycleReport>,
    /// The plan guard, shared with the scene path.
    guard: SharedGuard<M>,
}

/// The cycle as its reports show it.
struct CycleView {
    /// The latest report.
    report: Option<CycleReport>,
    /// The mode of the report before it.
    last_mode: Mode,
    /// The last refused plan seen (a new one starts a back-off).
    refused_seen: u64,
}

/// Plans handed to the cycle and not handed back yet, each with the scene it was approved
/// in (oldest first). Which one runs is read from the cycle's report.
struct SentPlans<S> {
    live: Vec<(Arc<Plan>, S)>,
    /// The newest plan id handed to the cycle.
    newest_id: u64,
}

/// How the arm rests after the plan the cycle ran last.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rest {
    /// At the plan's end.
    AtEnd,
    /// Stopped partway by a controlled stop, with planning due.
    Stopped,
}

/// The twin thread's state.
pub struct TwinWorker<L: Lookahead, M: ShieldModel<Scene = L::Scene>> {
    approver: Approver<L, M>,
    io: WorkerIo<M>,
    library: PolicyLibrary<L::Policy, L::Scene>,
    scene: SceneView<L::Scene>,
    path: PathRecorder,
    excursion: Excursion,
    planning: Planning,
    settings: Settings,
    cycle: CycleView,
    sent: SentPlans<L::Scene>,
    next_request_id: u64,
    /// The scene a box was last said to have taken the goal in ([`goal_taken`]).
    goal: goal_taken::GoalWatch<L::Scene>,
    /// Where a retreat was refused last ([`retreat`]).
    retreat: retreat::RetreatWatch<L::Scene>,
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// A worker over a lookahead and a shield model, talking to a cycle through `io`, and
    /// its scene path: the way of every accepted frame's scene to the cycle and the plan
    /// guard (which checks with a copy of `shield`), to run wherever frames arrive — the
    /// intake thread in `rt-core run` — before the worker is told ([`TwinWorker::note_frame`]).
    pub fn new(
        cfg: &RuntimeConfig,
        la: L,
        shield: Shield<M>,
        io: TwinIo<L::Scene>,
    ) -> (Self, ScenePath<M>)
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
        let path = ScenePath::new(scenes, guard.clone());
        let worker = Self {
            approver: Approver::new(cfg, la, shield),
            io: WorkerIo {
                plans,
                control,
                reports,
                guard,
            },
            library: PolicyLibrary::default(),
            scene: SceneView::default(),
            path: PathRecorder::default(),
            excursion: Excursion::default(),
            planning: Planning::Due,
            settings: Settings {
                return_home: cfg.return_home,
                dwell_ns: (cfg.dwell_at_goal_s * 1e9) as u64,
                join_ahead: (cfg.join_ahead_s / period_s).ceil() as usize,
                gate: true,
                sampling_budget_s: cfg.sampling.enabled.then_some(cfg.sampling.budget_s),
                continue_after_pause: cfg.continue_after_pause,
                plan_in_moving_world: cfg.plan_in_moving_world,
                search_lead: (cfg.planner_fallback.budget_s / period_s).ceil() as usize,
                max_refused_retrainings: cfg.max_refused_retrainings,
                rest_after_goal: cfg.goal.source == shm_schemas::runtime_view::GoalSource::Camera,
            },
            cycle: CycleView {
                report: None,
                last_mode: Mode::Idle,
                refused_seen: 0,
            },
            sent: SentPlans {
                live: Vec::new(),
                newest_id: 0,
            },
            next_request_id: 1,
            goal: goal_taken::GoalWatch::default(),
            retreat: retreat::RetreatWatch::default(),
        };
        (worker, path)
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
        self.settings.gate = false;
    }

    /// An accepted frame that the scene path ([`ScenePath::accepted`]) has handed to the
    /// cycle and the plan guard already — the one door of a frame into the worker, whoever
    /// runs the path (the intake thread in `rt-core run`, the sweep and the tests inline): a
    /// goal cancelled since the last frame revokes the plan under way; the scene change is
    /// marked for planning (without a goal, or not settled, nothing new is planned: the guard
    /// still re-verified the live plans against its obstacles); the guard's revocations are
    /// taken as events.
    pub fn note_frame(
        &mut self,
        frame: &AcceptedFrame<L::Scene>,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        // Plans made on this scene are registered with the plan guard under the withdrawn-
        // goal count it was accepted under, and refused there once a later withdrawal (a
        // cancel or a pre-emption) is known (issue 41 item 1).
        self.scene.set_goal_epoch(frame.goal_epoch);
        self.scene.set_moving_seen(frame.intruders.mask != 0);
        if frame.stop_requested {
            self.note_goal_cancelled(events);
        }
        let change = self
            .scene
            .accept(frame.scene, frame.stamp_ns, frame.goal_seen, frame.settled);
        if change.plan_due {
            self.planning.request();
        }
        // A goal reached stays reached while the arm rests over it (hiding the cube may
        // change the scene seen) and on the way home; a different settled scene seen with
        // the arm at rest elsewhere is a changed world (`acceptance`).
        let at_rest_away = self.cycle.report.is_some_and(|r| r.mode == Mode::Idle)
            && !matches!(self.excursion.phase(), Phase::DwellAtGoal { .. });
        if frame.settled && at_rest_away {
            self.scene.forget_goal_reached_unless(frame.scene);
        }
        self.take_revocations(events);
    }

    /// A refused frame ([`ScenePath::refused`] has told the cycle, which stops the arm):
    /// nothing is planned until an accepted frame arrives.
    pub fn note_refused(&mut self) {
        self.scene.refuse();
        self.planning.request();
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
        let revocations = lock_guard(&self.io.guard).take_revocations();
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
        self.sent.live.iter().find(|(p, _)| p.id == plan_id)
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
        self.cycle.report.as_ref()
    }

    /// The current policy.
    pub fn policy(&self) -> Option<&L::Policy> {
        self.library.current()
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
        self.excursion.phase()
    }

    /// Whether a plan is wanted.
    pub fn planning(&self) -> Planning {
        self.planning
    }

    /// The compact code of the state (verdict diagnostics, the run timeline).
    pub fn phase_code(&self) -> PhaseCode {
        phase::phase_code(
            &self.excursion.phase(),
            &self.planning,
            self.cycle.report.map_or(0, |r| r.t_ns),
        )
    }

    /// One iteration: takes reports, frees returned plans, and plans when due. Events are
    /// appended to `events`.
    pub fn step(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        self.take_reports();
        self.take_revocations(events);
        let backing_out = self.back_out_if_too_close(events);
        self.say_taken_goal_while_backing_out(events);
        if backing_out {
            return;
        }
        match self.scene.ready() {
            Err(Hold::Refused | Hold::NoScene) => return,
            Err(Hold::Unsettled) if self.stop_due_on_running() => {
                // The one plan made on a scene still changing: one joining the running plan
                // before its scheduled stop (see `plan_due`).
                if let Some(r) = self.cycle.report
                    && self.planning.is_due()
                    && !self.planning.backing_off(r.t_ns)
                    && !self.io.control.shutdown_requested()
                {
                    self.plan_due(r, events);
                }
                return;
            }
            // At rest in a moving world: planned on as it is now (the `moving` module).
            Err(Hold::Unsettled) if self.plans_in_moving_world() => {}
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
        let Some(r) = self.cycle.report else {
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
            self.sent.live.retain(|(p, _)| !returned.contains(&p.id));
            let mut guard = lock_guard(&self.io.guard);
            for id in returned {
                guard.returned(id);
            }
        }
        if let Some(r) = self.io.reports.latest() {
            if r.mode == Mode::Stopped && self.cycle.last_mode != Mode::Stopped {
                self.planning.request();
            }
            if r.last_refused_plan_id != 0 && r.last_refused_plan_id != self.cycle.refused_seen {
                self.cycle.refused_seen = r.last_refused_plan_id;
                // The cycle refuses while it cannot move (a link error, a stop under way):
                // plan again after a pause, not at the twin thread's polling rate.
                self.planning.refused(r.t_ns, REFUSAL_BACKOFF_NS);
            }
            self.cycle.last_mode = r.mode;
            self.cycle.report = Some(r);
        }
    }

    /// A lookahead run after a scene change found the policy's continuation unsafe while
    /// a plan is under way: the running and any pending plan are revoked too (the cycle
    /// stops along the checked path).
    fn revoke_under_way(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let Some((running_id, next)) = self.io.control.progress() else {
            return;
        };
        let newest = self.sent.newest_id.max(running_id);
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
        self.cycle.report.is_some_and(|r| {
            r.mode == Mode::Following
                && self
                    .io
                    .control
                    .stop_due()
                    .is_some_and(|(id, _)| id == r.plan_id)
        })
    }

    /// Whether the way home is in hand this iteration (planned now, or waiting out the
    /// dwell at the goal or a back-off); the ordinary planning waits meanwhile. One `match`
    /// over how the arm rests after its last plan and the phase.
    fn return_home_due(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) -> bool {
        let Some((r, rest, sent_id, policy_id)) = self.rest_after_last_plan() else {
            return false;
        };
        let phase = self.excursion.phase();
        let home_open =
            self.settings.return_home && self.path.len() >= 2 && !phase.return_refused_for(sent_id);
        match (rest, phase, self.scene.scene()) {
            (Rest::AtEnd, Phase::ReturningHome, _)
            | (
                Rest::AtEnd,
                Phase::Paused {
                    during: Leg::ReturningHome,
                    ..
                },
                _,
            ) => {
                // Home: the next excursion starts here (after a stop on the way, with the
                // episode again).
                self.path.arrive_home();
                // The episode is owed again, or (the goal reached) a policy received on the
                // way is judged from here (`acceptance`).
                if self.excursion.arrive_home() || self.rests_after_goal() {
                    self.planning.request();
                }
                false
            }
            (_, _, None) => false,
            // The end of a retreat is no goal but a pause of the episode (`retreat`): a
            // continuation from there when one passes, the world waited for while it moves,
            // else home along the executed path and the episode again — as after a stop.
            (Rest::AtEnd, Phase::BackingOut { done: true, .. }, Some(scene))
                if home_open && self.planning.is_due() =>
            {
                self.after_pause(r, sent_id, policy_id, scene, events)
            }
            (Rest::AtEnd, Phase::BackingOut { .. }, _) => false,
            _ if !home_open => false,
            (Rest::Stopped, _, Some(scene)) => {
                self.excursion.next(Transition::Stopped {
                    plan_id: sent_id,
                    now_ns: r.t_ns,
                });
                self.after_pause(r, sent_id, policy_id, scene, events)
            }
            (Rest::AtEnd, _, Some(scene)) => {
                self.excursion.next(Transition::RestingAtGoal {
                    plan_id: sent_id,
                    now_ns: r.t_ns,
                });
                if matches!(self.excursion.phase(), Phase::DwellAtGoal { .. })
                    && let Some(&(_, approved_in)) = self.live_plan(sent_id)
                {
                    // The policy whose plan got there needs no verification in the scene.
                    self.scene.mark_goal_reached(approved_in);
                    self.library.note_judged(policy_id, approved_in);
                }
                if let Phase::DwellAtGoal { since_ns, .. } = self.excursion.phase()
                    && r.t_ns.saturating_sub(since_ns) < self.settings.dwell_ns
                {
                    return true;
                }
                self.send_way_home(r, sent_id, policy_id, scene, false, events)
            }
        }
    }

    /// How the arm rests after the plan the cycle ran last (from its report; not while a
    /// newer one is on its way), with the report and that plan's and its policy's ids.
    fn rest_after_last_plan(&self) -> Option<(CycleReport, Rest, u64, u64)> {
        let r = self.cycle.report?;
        let (sent, _) = self.live_plan(r.plan_id)?;
        if self.sent.live.iter().any(|(p, _)| p.id > r.plan_id) {
            return None;
        }
        let rest = if r.mode == Mode::Idle && r.next_index >= sent.len() {
            Rest::AtEnd
        } else if r.mode == Mode::Stopped && self.planning.is_due() {
            Rest::Stopped
        } else {
            return None;
        };
        Some((r, rest, sent.id, sent.policy_id))
    }

    /// Paused: once no back-off holds planning, a continuation from where the arm stopped
    /// when one passes; only otherwise back along the executed path, cut where the brake
    /// left the arm (off the path, the ordinary planning).
    fn after_pause(
        &mut self,
        r: CycleReport,
        sent_id: u64,
        policy_id: u64,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        if self.planning.backing_off(r.t_ns)
            || self.continue_from_rest(r, events)
            || self.home_waits_for_the_world()
        {
            return true;
        }
        if !self.path.cut_at(&r.cmd.q_rad) || self.path.len() < 2 {
            return false;
        }
        self.send_way_home(r, sent_id, policy_id, scene, true, events)
    }

    /// The way home — the executed path reversed, one waypoint per twin step, ending
    /// exactly at its start — checked in the scene in force and sent (`after_stop`: the
    /// episode then runs again once home); refused, the arm holds and planning takes over.
    /// True when it is in hand (sent, or the hand-over slot full).
    fn send_way_home(
        &mut self,
        r: CycleReport,
        sent_id: u64,
        policy_id: u64,
        scene: L::Scene,
        after_stop: bool,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
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
                self.excursion
                    .next(Transition::ReturnRefused { plan_id: sent_id });
                self.planning.request();
                events.push(TwinEvent::ReturnHomeRefused { why });
                return false;
            }
        };
        let (plan_id, samples) = (plan.id, plan.len());
        if self.send_plan(plan, scene) {
            self.excursion.next(Transition::ReturnSent { after_stop });
            if after_stop {
                self.planning.taken();
            }
            events.push(TwinEvent::ReturningHome { plan_id, samples });
        }
        true
    }
}
