//! The twin thread's logic (not real-time; it may allocate): keeps the scene in sync with
//! detections (and forwards each one to the cycle at once), re-verifies the running plan
//! when the scene changes (revoking it when it has become unsafe), runs the lookahead — the
//! whole next episode in the twin with the current policy — whenever the scene or the policy
//! changes or the cycle waits for a plan, and then either approves a Ruckig-smoothed plan
//! (`task_ok && safe`, every sample passes the shield, and the smoothed path's TCP comes
//! within the task's goal tolerance of the goal target: [`Lookahead::goal_approach`]) or asks
//! for retraining.
//!
//! Plans are made only on a *settled* scene (perception's `FRAME_SETTLED`: every object
//! confirmed, nothing appearing, disappearing or moving): an intermediate view of a changing
//! world is re-verified against (and may revoke the running plan) but never gets a plan
//! approved — the worker waits for the settled frame.
//!
//! A new policy is swapped in with one step (it arrives validated and prepared); the cycle
//! never sees a policy's plan before its lookahead has passed.
//!
//! Policy library (issue 15, retraining that keeps what it knew): the first policy the
//! worker receives (the bundled generalist) is kept as the *base* when later ones (each
//! retrained for one world) replace it as the current policy. The lookahead tries the
//! current policy first and, when its episode or smoothed plan fails, the base: a world the
//! generalist solves is solved again without retraining even after a fine-tune forgot it,
//! and retraining is asked for only when both fail. Either plan passes the same checks. A replacement plan joins the
//! running one at a sample `join_ahead_s` ahead of the arm, starting from that sample's
//! position, velocity and acceleration, so the hand-over is continuous.
//!
//! Return home: with `return_home`, once an episode's plan has ended at its goal and the
//! arm has rested `dwell_at_goal_s`, the worker plans the way back to where the episode
//! began — its own executed path reversed (joined plans included), smoothed, and checked
//! by the shield in the scene then in force. If that check fails (the world changed around
//! the arm) the arm holds and the ordinary lookahead from its pose takes over. A controlled
//! stop on the way (stale inputs, a revoked plan) is handled the same way at once: back along
//! the path from where the brake left the arm, then the episode again from its start — the
//! posture every episode starts from in training — instead of an unverified approach.
//!
//! [`TwinWorker::step`] is one iteration; the `run` binary calls it in a loop between polls
//! of its iceoryx2 subscribers, the tests call it directly.

use crate::config::RuntimeConfig;
use crate::cycle::brake::MotionState;
use crate::cycle::plan::{JoinPoint, Plan};
use crate::cycle::shield::{Shield, ShieldModel, ShieldViolation};
use crate::cycle::{CycleReport, Mode, SceneUpdate, TwinIo};
use crate::twin_thread::smoother::{PlanSmoother, SmoothError};
use twin::{Joints, max_joint_gap_rad};

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

/// Something the twin did that the outside should know (publish, log, assert on).
#[derive(Debug, Clone, PartialEq)]
pub enum TwinEvent<S> {
    /// A lookahead ran.
    Verdict {
        /// Its result.
        verdict: Verdict,
        /// The scene it ran in.
        scene: S,
        /// How long it took, s.
        elapsed_s: f64,
    },
    /// A plan was approved and handed to the cycle.
    PlanApproved {
        /// Plan id.
        plan_id: u64,
        /// Policy id.
        policy_id: u64,
        /// Whether it joins a running plan.
        joins: bool,
    },
    /// The lookahead passed but the smoothed plan did not (smoothing, shield, or its path
    /// misses the goal).
    PlanRejected {
        /// Policy id.
        policy_id: u64,
        /// Smoothing error, if that was the cause.
        smooth: Option<SmoothError>,
        /// Shield violation and sample index, if that was the cause.
        shield: Option<(usize, ShieldViolation)>,
        /// The smoothed path's closest approach to the goal, if missing the goal was the
        /// cause.
        goal: Option<GoalApproach>,
    },
    /// The running plan became unsafe in the new scene and was revoked.
    Revoked {
        /// Plan id.
        plan_id: u64,
        /// The first unsafe sample.
        at_index: usize,
    },
    /// The policy failed the lookahead: retraining is requested for this scene.
    Retrain {
        /// Request id (increasing).
        request_id: u64,
        /// The failed verdict.
        verdict: Verdict,
        /// The scene.
        scene: S,
    },
    /// The arm returns to where its episode began along its executed path.
    ReturningHome {
        /// Plan id.
        plan_id: u64,
        /// Samples in the plan.
        samples: usize,
    },
    /// The way home is unsafe in the scene now in force; the arm holds.
    ReturnHomeRefused {
        /// Shield violation and sample index, if that was the cause.
        shield: Option<(usize, ShieldViolation)>,
        /// Smoothing error, if that was the cause.
        smooth: Option<SmoothError>,
    },
    /// A new policy was swapped in.
    PolicySwapped {
        /// Its id.
        policy_id: u64,
    },
    /// A plan is due but the latest detection frame has no goal: nothing is planned, the
    /// arm holds (reported once per stretch without a goal).
    NoGoal {
        /// The current policy, 0 for none.
        policy_id: u64,
    },
    /// A plan is due but the latest detection frame is not settled (the world is changing):
    /// nothing is planned until a settled frame arrives (reported once per unsettled
    /// stretch).
    AwaitingSettledScene {
        /// Capture time of that frame (cycle clock), ns.
        stamp_ns: u64,
    },
}

/// The twin thread's state.
pub struct TwinWorker<L: Lookahead, M: ShieldModel<Scene = L::Scene>> {
    la: L,
    shield: Shield<M>,
    smoother: PlanSmoother,
    io: TwinIo<L::Scene>,
    period_s: f64,
    join_ahead: usize,
    /// The current policy (the latest received).
    policy: Option<Box<L::Policy>>,
    /// The first policy received, kept as the fallback once another replaces it.
    base: Option<Box<L::Policy>>,
    scene: Option<L::Scene>,
    report: Option<CycleReport>,
    sent: Option<Plan>,
    /// The scene `sent` was approved in.
    scene_of_sent: Option<L::Scene>,
    /// The plan `sent` joins (still running until the join point), if `sent` is a join.
    joined: Option<Plan>,
    next_plan_id: u64,
    next_request_id: u64,
    want_plan: bool,
    waypoints: Vec<Joints>,
    last_mode: Mode,
    refused_seen: u64,
    return_home: bool,
    dwell_ns: u64,
    /// Cycle-rate samples from where the excursion began (at rest) to the end of the last
    /// approved episode plan.
    path_from_home: Vec<Joints>,
    /// Where the sent plan's samples start in `path_from_home`.
    sent_offset: usize,
    /// The sent plan is a return home.
    sent_is_return: bool,
    /// Plan whose end the arm has rested at since (cycle clock, ns).
    rest_since_ns: Option<(u64, u64)>,
    /// The plan whose return home was refused (not retried).
    return_refused_for: u64,
    /// The return under way follows a stop on the way: run the episode again once home.
    replan_at_home: bool,
    /// The policy and scene of the last retrain request: a failing lookahead asks once per
    /// pair (the learner restarts its training on every new request).
    last_retrain: Option<(u64, L::Scene)>,
    /// Motion waits for a passing lookahead (off only for `--no-lookahead`).
    gate: bool,
    /// After a refusal, no planning before this (cycle clock, ns).
    no_plan_before_ns: u64,
    /// The latest accepted frame carries a goal; without one nothing is planned.
    goal_seen: bool,
    /// [`TwinEvent::NoGoal`] was reported for the current stretch without a goal.
    no_goal_reported: bool,
    /// The latest frame was refused: no planning until a good frame arrives.
    scene_refused: bool,
    /// Capture stamp of the latest accepted frame (cycle clock), ns.
    scene_stamp_ns: u64,
    /// The latest accepted frame is settled: plans may be approved on its scene.
    scene_settled: bool,
    /// [`TwinEvent::AwaitingSettledScene`] was reported for the current unsettled stretch.
    unsettled_reported: bool,
}

/// Why a smoothed plan was not approved: the smoothing error, the shield's first violation
/// (sample index and kind), or the smoothed path's miss of the goal.
type NotApproved = (
    Option<SmoothError>,
    Option<(usize, ShieldViolation)>,
    Option<GoalApproach>,
);

/// Whether [`TwinWorker::smoothed_checked_plan`] also checks that the path reaches the goal
/// (an episode plan) or not (the way home).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GoalCheck {
    /// The smoothed path must come within the goal tolerance of the goal target.
    Reach,
    /// No goal check.
    None,
}

/// A policy of the library: the current one, or the base kept as its fallback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PolicySlot {
    /// The latest policy received.
    Current,
    /// The first policy received (the bundled generalist).
    Base,
}

/// What one policy of the library did in [`TwinWorker::plan_from`].
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

/// A rest pose this close (every joint) to a sample of the recorded path lies on it, rad.
const ON_PATH_TOLERANCE_RAD: f64 = 0.05;

/// Pause after the cycle refused a plan before planning again, ns.
const REFUSAL_BACKOFF_NS: u64 = 500_000_000;

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// A worker over a lookahead and a shield model, talking to a cycle through `io`.
    pub fn new(cfg: &RuntimeConfig, la: L, shield: Shield<M>, io: TwinIo<L::Scene>) -> Self {
        let period_s = 1.0 / cfg.rate_hz;
        Self {
            la,
            shield,
            smoother: PlanSmoother::new(period_s, cfg.limits, (60.0 * cfg.rate_hz) as usize),
            io,
            period_s,
            join_ahead: (cfg.join_ahead_s / period_s).ceil() as usize,
            policy: None,
            base: None,
            scene: None,
            report: None,
            sent: None,
            joined: None,
            scene_of_sent: None,
            next_plan_id: 1,
            next_request_id: 1,
            want_plan: true,
            waypoints: Vec::new(),
            last_mode: Mode::Idle,
            refused_seen: 0,
            return_home: cfg.return_home,
            dwell_ns: (cfg.dwell_at_goal_s * 1e9) as u64,
            path_from_home: Vec::new(),
            sent_offset: 0,
            sent_is_return: false,
            rest_since_ns: None,
            return_refused_for: 0,
            replan_at_home: false,
            last_retrain: None,
            gate: true,
            no_plan_before_ns: 0,
            goal_seen: false,
            no_goal_reported: false,
            scene_refused: false,
            scene_stamp_ns: 0,
            scene_settled: false,
            unsettled_reported: false,
        }
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
    /// re-verified against them and revoked when unsafe) but nothing new is planned; a
    /// settled frame then lets the planning waiting for it go ahead. Scenes that do not come
    /// from a camera (a fixed scene, a bench) are settled.
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
        self.scene_stamp_ns = stamp_ns;
        if self.scene_refused {
            self.scene_refused = false;
            self.want_plan = true;
        }
        if goal_seen != self.goal_seen {
            self.goal_seen = goal_seen;
            self.no_goal_reported = false;
            self.want_plan = true;
        }
        if settled != self.scene_settled {
            // A plan due while unsettled stays due (`want_plan`): it is made on the first
            // settled frame. Settling alone (the same scene) asks for no new plan.
            self.scene_settled = settled;
            self.unsettled_reported = false;
        }
        if self.scene != Some(scene) {
            self.scene = Some(scene);
            self.want_plan = true;
            self.reverify_running(events);
        }
    }

    /// A detection frame was refused (see `twin_thread::intake`): the cycle is told at once
    /// (it stops the arm, keeping the last trusted scene for the shield) and nothing is
    /// planned until an accepted frame arrives.
    pub fn on_refused_detection(&mut self) {
        self.scene_refused = true;
        self.want_plan = true;
        if let Some(scene) = self.scene {
            self.io.scenes.send(SceneUpdate {
                scene,
                stamp_ns: self.scene_stamp_ns,
                refused: true,
            });
        }
    }

    /// A validated, prepared policy arrived: swapped in with one step as the current
    /// policy. The first one ever received is kept as the base (the fallback of the
    /// lookahead); any other replaced one is dropped here, off the cycle.
    pub fn on_policy(&mut self, policy: Box<L::Policy>, events: &mut Vec<TwinEvent<L::Scene>>) {
        let policy_id = L::policy_id(&policy);
        let old = self.policy.replace(policy);
        if self.base.is_none() {
            self.base = old;
        } else {
            // The replaced retrained policy is dropped here, on the twin thread.
            drop(old);
        }
        self.want_plan = true;
        events.push(TwinEvent::PolicySwapped { policy_id });
    }

    /// The latest cycle report seen.
    pub fn last_report(&self) -> Option<&CycleReport> {
        self.report.as_ref()
    }

    /// The current policy.
    pub fn policy(&self) -> Option<&L::Policy> {
        self.policy.as_deref()
    }

    /// The base policy (the first received), once another has replaced it as current.
    pub fn base_policy(&self) -> Option<&L::Policy> {
        self.base.as_deref()
    }

    /// The lookahead.
    pub fn lookahead_mut(&mut self) -> &mut L {
        &mut self.la
    }

    /// The control flags shared with the cycle (shutdown, acknowledgement, revocation).
    pub fn control(&self) -> &std::sync::Arc<crate::cycle::CycleControl> {
        &self.io.control
    }

    /// Re-verifies, against the scene now in force, the plan the cycle is following — from
    /// the sample the cycle will send next (its own progress word, not the last report) —
    /// and the plan scheduled to join it, if any. A failure revokes both.
    fn reverify_running(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let Some(scene) = self.scene else {
            return;
        };
        let Some((running_id, next)) = self.io.control.progress() else {
            return;
        };
        let (running, pending) = match (self.sent.as_ref(), self.joined.as_ref()) {
            (Some(s), _) if s.id == running_id => (s, None),
            (Some(s), Some(j)) if j.id == running_id => (j, Some(s)),
            _ => return,
        };
        let mut first_bad: Option<(u64, usize)> = None;
        if next < running.len() {
            let prev = running.q_rad[next.saturating_sub(1)];
            if let Err((i, _)) =
                self.shield
                    .check_path(&prev, &running.q_rad[next..], self.period_s, &scene)
            {
                first_bad = Some((running.id, next + i));
            }
        }
        if first_bad.is_none()
            && let Some(p) = pending
            && let Some(j) = p.join
            && j.index < running.len()
            && let Err((i, _)) =
                self.shield
                    .check_path(&running.q_rad[j.index], &p.q_rad, self.period_s, &scene)
        {
            first_bad = Some((p.id, i));
        }
        if let Some((plan_id, at_index)) = first_bad {
            let newest = pending.map_or(running.id, |p| p.id);
            self.io.control.revoke_up_to(newest);
            self.want_plan = true;
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
            .map_or(running_id, |s| s.id.max(running_id));
        if newest <= self.io.control.revoked_up_to() {
            return;
        }
        self.io.control.revoke_up_to(newest);
        events.push(TwinEvent::Revoked {
            plan_id: running_id,
            at_index: next,
        });
    }

    /// One iteration at `now_ns` (the cycle's clock): takes reports, frees returned plans,
    /// and plans when due. Events are appended to `events`.
    pub fn step(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        self.take_reports();
        if self.scene_refused {
            return;
        }
        if !self.scene_settled {
            // No plan of any kind reaches the cycle from an unsettled scene; the running
            // plan was re-verified against it on arrival.
            if self.want_plan && self.scene.is_some() && !self.unsettled_reported {
                self.unsettled_reported = true;
                events.push(TwinEvent::AwaitingSettledScene {
                    stamp_ns: self.scene_stamp_ns,
                });
            }
            return;
        }
        if self.return_home_due(events) {
            return;
        }
        if !self.want_plan {
            return;
        }
        let (Some(r), Some(_)) = (self.report, self.scene) else {
            return;
        };
        if r.t_ns < self.no_plan_before_ns || r.awaiting_ack || self.io.control.shutdown_requested()
        {
            return;
        }
        self.plan_due(events);
    }

    /// Takes the cycle's newest report and frees returned plans (no planning).
    pub fn take_reports(&mut self) {
        self.io.plans.collect_returned();
        if let Some(r) = self.io.reports.latest() {
            if r.mode == Mode::Stopped && self.last_mode != Mode::Stopped {
                self.want_plan = true;
            }
            if r.last_refused_plan_id != 0 && r.last_refused_plan_id != self.refused_seen {
                self.refused_seen = r.last_refused_plan_id;
                self.want_plan = true;
                // The cycle refuses while it cannot move (a link error, a stop under way):
                // plan again after a pause, not at the twin thread's polling rate.
                self.no_plan_before_ns = r.t_ns.saturating_add(REFUSAL_BACKOFF_NS);
            }
            self.last_mode = r.mode;
            self.report = Some(r);
        }
    }

    fn plan_due(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let (Some(r), Some(scene)) = (self.report, self.scene) else {
            return;
        };
        if self.policy.is_none() {
            return;
        }
        if !self.goal_seen {
            if !self.no_goal_reported {
                self.no_goal_reported = true;
                events.push(TwinEvent::NoGoal {
                    policy_id: self.policy.as_deref().map_or(0, L::policy_id),
                });
            }
            return;
        }
        // Where the plan starts.
        let (start, join) = match r.mode {
            Mode::Stopping => return,
            Mode::Idle | Mode::Stopped => (MotionState::at_rest(r.cmd.q_rad), None),
            Mode::Following => match self.sent.as_ref() {
                Some(s) if s.id == r.plan_id && r.next_index + self.join_ahead < s.len() => {
                    let k = r.next_index + self.join_ahead;
                    (
                        MotionState {
                            q_rad: s.q_rad[k],
                            dq_rad_s: s.dq_rad_s[k],
                            ddq_rad_s2: s.ddq_rad_s2[k],
                        },
                        Some(JoinPoint {
                            plan_id: s.id,
                            index: k,
                        }),
                    )
                }
                // The running plan is about to end (or unknown): plan again once at rest.
                _ => return,
            },
        };
        self.want_plan = false;
        self.plan_from(start, join, scene, events);
    }

    /// Extends the executed path with an approved episode plan.
    fn record_episode_plan(&mut self, start: &MotionState, join: Option<JoinPoint>, plan: &Plan) {
        match join {
            Some(j) if !self.sent_is_return => {
                self.path_from_home.truncate(self.sent_offset + j.index);
            }
            _ => {
                // From rest: on the recorded path the path is cut there; anywhere else a
                // new excursion begins here.
                if !self.cut_path_at(&start.q_rad) {
                    self.path_from_home.clear();
                    self.path_from_home.push(start.q_rad);
                }
            }
        }
        self.sent_offset = self.path_from_home.len();
        self.path_from_home.extend_from_slice(&plan.q_rad);
        self.sent_is_return = false;
        self.rest_since_ns = None;
    }

    /// Where the arm rests at `q` on the recorded path (the end of the last plan, a brake's
    /// end near one of its samples, a return cut short), cuts the path there, ending exactly
    /// at `q`, and returns true; false (path untouched) when `q` is off the path.
    fn cut_path_at(&mut self, q: &Joints) -> bool {
        let Some((i, gap)) = self
            .path_from_home
            .iter()
            .enumerate()
            .map(|(i, p)| (i, max_joint_gap_rad(p, q)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|(_, g)| *g <= ON_PATH_TOLERANCE_RAD)
        else {
            return false;
        };
        self.path_from_home.truncate(i + 1);
        if gap > 1e-9 {
            self.path_from_home.push(*q);
        }
        true
    }

    /// Whether the return home is in hand this iteration (planned now, or waiting out the
    /// dwell at the goal); the ordinary planning waits meanwhile.
    fn return_home_due(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) -> bool {
        let (Some(r), Some(sent)) = (self.report, self.sent.as_ref()) else {
            return false;
        };
        let (sent_id, policy_id) = (sent.id, sent.policy_id);
        let at_end = r.mode == Mode::Idle && r.plan_id == sent_id && r.next_index >= sent.len();
        let stopped = r.mode == Mode::Stopped && self.want_plan;
        if !at_end && !stopped {
            return false;
        }
        if at_end && self.sent_is_return {
            // Home: the next excursion starts here.
            self.path_from_home.clear();
            if std::mem::take(&mut self.replan_at_home) {
                self.want_plan = true;
            }
            return false;
        }
        if !self.return_home || self.path_from_home.len() < 2 || self.return_refused_for == sent_id
        {
            return false;
        }
        let Some(scene) = self.scene else {
            return false;
        };
        if stopped {
            if r.t_ns < self.no_plan_before_ns {
                return true;
            }
            // Cut the path where the brake left the arm; off the path, plan as usual.
            if !self.cut_path_at(&r.cmd.q_rad) || self.path_from_home.len() < 2 {
                return false;
            }
        } else {
            let since = match self.rest_since_ns {
                Some((id, t)) if id == sent_id => t,
                _ => {
                    self.rest_since_ns = Some((sent_id, r.t_ns));
                    r.t_ns
                }
            };
            if r.t_ns.saturating_sub(since) < self.dwell_ns {
                return true;
            }
        }
        // The executed path reversed, one waypoint per twin step; ends exactly at its start.
        let stride = ((self.la.step_s() / self.period_s).round() as usize).max(1);
        let n = self.path_from_home.len();
        self.waypoints.clear();
        let mut i = n - 1;
        while i > stride {
            i -= stride;
            self.waypoints.push(self.path_from_home[i]);
        }
        self.waypoints.push(self.path_from_home[0]);
        let start = MotionState::at_rest(r.cmd.q_rad);
        let plan = match self.smoothed_checked_plan(
            &start,
            None,
            policy_id,
            &scene,
            GoalCheck::None,
            PolicySlot::Current,
        ) {
            Ok(plan) => plan,
            Err((smooth, shield, _)) => {
                self.return_refused_for = sent_id;
                self.want_plan = true;
                events.push(TwinEvent::ReturnHomeRefused { shield, smooth });
                return false;
            }
        };
        let (plan_id, samples) = (plan.id, plan.len());
        if self.send_plan(plan) {
            self.sent_is_return = true;
            if stopped {
                self.want_plan = false;
                self.replan_at_home = true;
            }
            events.push(TwinEvent::ReturningHome { plan_id, samples });
        } else {
            self.return_refused_for = 0;
        }
        true
    }

    /// Smooths `self.waypoints` from `start` into a new plan and checks every sample with
    /// the shield in `scene` (what every plan passes before it reaches the cycle); with
    /// [`GoalCheck::Reach`] (an episode plan, the lookahead gate on) also that the smoothed
    /// path's TCP comes within the task's tolerance of the goal target — the plan the arm
    /// follows must reach the goal the lookahead declared reached, not only its waypoints.
    fn smoothed_checked_plan(
        &mut self,
        start: &MotionState,
        join: Option<JoinPoint>,
        policy_id: u64,
        scene: &L::Scene,
        goal: GoalCheck,
        slot: PolicySlot,
    ) -> Result<Plan, NotApproved> {
        let id = self.next_plan_id;
        self.next_plan_id += 1;
        let mut plan = Plan::with_capacity(id, policy_id, self.period_s, 0);
        plan.join = join;
        self.smoother
            .smooth(
                start,
                &self.waypoints,
                self.la.step_s(),
                self.shield.model_mut(),
                &mut plan,
            )
            .map_err(|e| (Some(e), None, None))?;
        self.shield
            .check_path(&start.q_rad, &plan.q_rad, self.period_s, scene)
            .map_err(|v| (None, Some(v), None))?;
        let policy = match slot {
            PolicySlot::Current => self.policy.as_deref(),
            PolicySlot::Base => self.base.as_deref(),
        };
        if goal == GoalCheck::Reach
            && let Some(policy) = policy
        {
            let approach = self.la.goal_approach(policy, scene, &plan.q_rad);
            if !approach.reached() {
                return Err((None, None, Some(approach)));
            }
        }
        Ok(plan)
    }

    /// Hands a checked plan to the cycle and keeps a copy as the sent plan; false when the
    /// hand-over slot is full.
    fn send_plan(&mut self, plan: Plan) -> bool {
        let copy = plan.clone();
        let joins = plan.join.is_some();
        if self.io.plans.send(Box::new(plan)).is_err() {
            return false;
        }
        let previous = self.sent.replace(copy);
        self.joined = if joins { previous } else { None };
        self.scene_of_sent = self.scene;
        true
    }

    /// Plans the next episode from `start`: the current policy first, then the base (the
    /// policy library); the first whose lookahead and smoothed plan pass is approved. When
    /// none passes, the current policy's failure is what counts: the running plan is revoked
    /// when that continuation is unsafe in a changed scene, and retraining is asked for
    /// (once per policy and scene).
    fn plan_from(
        &mut self,
        start: MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let mut first_failure: Option<(Verdict, bool)> = None;
        for slot in [PolicySlot::Current, PolicySlot::Base] {
            if slot == PolicySlot::Base && !self.gate {
                // Without the lookahead gate the current policy's plan is taken as it is.
                break;
            }
            match self.try_policy(slot, &start, join, scene, events) {
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
        if lookahead_unsafe && self.scene_of_sent.is_some_and(|s| s != scene) {
            self.revoke_under_way(events);
        }
        if self.gate && self.last_retrain != Some((verdict.policy_id, scene)) {
            self.last_retrain = Some((verdict.policy_id, scene));
            events.push(TwinEvent::Retrain {
                request_id: self.next_request_id,
                verdict,
                scene,
            });
            self.next_request_id += 1;
        }
    }

    /// One policy of the library: its lookahead, then (when it passes) its smoothed,
    /// shield-checked plan, sent to the cycle.
    fn try_policy(
        &mut self,
        slot: PolicySlot,
        start: &MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> Tried {
        let policy = match slot {
            PolicySlot::Current => self.policy.as_deref(),
            PolicySlot::Base => self.base.as_deref(),
        };
        let Some(policy) = policy else {
            return Tried::NoPolicy;
        };
        let t0 = std::time::Instant::now();
        let verdict = self
            .la
            .lookahead(policy, &scene, &start.q_rad, &mut self.waypoints);
        events.push(TwinEvent::Verdict {
            verdict,
            scene,
            elapsed_s: t0.elapsed().as_secs_f64(),
        });
        if self.gate && !(verdict.task_ok && verdict.safe) {
            return Tried::Failed {
                verdict,
                lookahead_unsafe: !verdict.safe,
            };
        }
        if self.waypoints.is_empty() {
            // Already at the goal: nothing to do.
            return Tried::Done;
        }
        let goal_check = if self.gate {
            GoalCheck::Reach
        } else {
            GoalCheck::None
        };
        let plan = match self.smoothed_checked_plan(
            start,
            join,
            verdict.policy_id,
            &scene,
            goal_check,
            slot,
        ) {
            Ok(plan) => plan,
            Err((smooth, shield, goal)) => {
                events.push(TwinEvent::PlanRejected {
                    policy_id: verdict.policy_id,
                    smooth,
                    shield,
                    goal,
                });
                // The lookahead passed but the plan the arm would follow does not: publish
                // the verdict as failed (and, when no policy passes, ask for retraining)
                // instead of waiting for a plan that will not come. A smoothed path that
                // misses the goal fails the task, not safety.
                let failed = if goal.is_some() {
                    Verdict {
                        task_ok: false,
                        ..verdict
                    }
                } else {
                    Verdict {
                        safe: false,
                        min_distance_m: match shield {
                            Some((_, ShieldViolation::Clearance { distance_m })) => {
                                distance_m.min(verdict.min_distance_m)
                            }
                            _ => verdict.min_distance_m,
                        },
                        ..verdict
                    }
                };
                events.push(TwinEvent::Verdict {
                    verdict: failed,
                    scene,
                    elapsed_s: t0.elapsed().as_secs_f64(),
                });
                return Tried::Failed {
                    verdict: failed,
                    lookahead_unsafe: false,
                };
            }
        };
        let plan_id = plan.id;
        if !self.send_plan(plan) {
            self.want_plan = true;
            return Tried::Done;
        }
        if let Some(sent) = self.sent.take() {
            self.record_episode_plan(start, join, &sent);
            self.sent = Some(sent);
        }
        events.push(TwinEvent::PlanApproved {
            plan_id,
            policy_id: verdict.policy_id,
            joins: join.is_some(),
        });
        Tried::Done
    }
}
