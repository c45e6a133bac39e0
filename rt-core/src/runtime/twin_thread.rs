//! The twin thread's logic (not real-time; it may allocate): keeps the scene in sync with
//! detections (and forwards each one to the cycle at once), re-verifies the running plan
//! when the scene changes (revoking it when it has become unsafe), runs the lookahead — the
//! whole next episode in the twin with the current policy — whenever the scene or the policy
//! changes or the cycle waits for a plan, and then either approves a Ruckig-smoothed plan
//! (`task_ok && safe`, and every sample passes the shield) or asks for retraining.
//!
//! A new policy is swapped in with one step (it arrives validated and prepared); the cycle
//! never sees a policy's plan before its lookahead has passed. A replacement plan joins the
//! running one at a sample `join_ahead_s` ahead of the arm, starting from that sample's
//! position, velocity and acceleration, so the hand-over is continuous.
//!
//! [`TwinWorker::step`] is one iteration; the `run` binary calls it in a loop between polls
//! of its iceoryx2 subscribers, the tests call it directly.

use super::Joints;
use super::config::RuntimeConfig;
use super::cycle::{CycleReport, Mode, SceneUpdate, TwinIo};
use super::plan::{JoinPoint, Plan};
use super::shield::{Shield, ShieldModel, ShieldViolation};
use super::smoothing::{MotionState, PlanSmoother, SmoothError};

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
    /// The lookahead passed but the smoothed plan did not (smoothing or shield).
    PlanRejected {
        /// Policy id.
        policy_id: u64,
        /// Smoothing error, if that was the cause.
        smooth: Option<SmoothError>,
        /// Shield violation and sample index, if that was the cause.
        shield: Option<(usize, ShieldViolation)>,
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
    /// A new policy was swapped in.
    PolicySwapped {
        /// Its id.
        policy_id: u64,
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
    policy: Option<Box<L::Policy>>,
    scene: Option<L::Scene>,
    report: Option<CycleReport>,
    sent: Option<Plan>,
    next_plan_id: u64,
    next_request_id: u64,
    want_plan: bool,
    waypoints: Vec<Joints>,
    last_mode: Mode,
    refused_seen: u64,
}

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
            scene: None,
            report: None,
            sent: None,
            next_plan_id: 1,
            next_request_id: 1,
            want_plan: true,
            waypoints: Vec::new(),
            last_mode: Mode::Idle,
            refused_seen: 0,
        }
    }

    /// A detection arrived: forwards it to the cycle at once and marks a scene change.
    pub fn on_detection(
        &mut self,
        scene: L::Scene,
        stamp_ns: u64,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        self.io.scenes.send(SceneUpdate { scene, stamp_ns });
        if self.scene != Some(scene) {
            self.scene = Some(scene);
            self.want_plan = true;
            self.reverify_running(events);
        }
    }

    /// A validated, prepared policy arrived: swapped in with one step; the old one is
    /// dropped here, off the cycle.
    pub fn on_policy(&mut self, policy: Box<L::Policy>, events: &mut Vec<TwinEvent<L::Scene>>) {
        let policy_id = L::policy_id(&policy);
        // The old policy is dropped here, on the twin thread.
        drop(self.policy.replace(policy));
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

    /// The lookahead.
    pub fn lookahead_mut(&mut self) -> &mut L {
        &mut self.la
    }

    fn reverify_running(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        let (Some(r), Some(sent), Some(scene)) = (self.report, self.sent.as_ref(), self.scene)
        else {
            return;
        };
        if r.mode != Mode::Following || r.plan_id != sent.id || r.next_index >= sent.len() {
            return;
        }
        let from = r.next_index.saturating_sub(1);
        let prev = sent.q_rad[from];
        let rest = &sent.q_rad[r.next_index..];
        if let Err((i, _)) = self.shield.check_path(&prev, rest, self.period_s, &scene) {
            self.io
                .revoked_plan_id
                .store(sent.id, std::sync::atomic::Ordering::Release);
            events.push(TwinEvent::Revoked {
                plan_id: sent.id,
                at_index: r.next_index + i,
            });
        }
    }

    /// One iteration at `now_ns` (the cycle's clock): takes reports, frees returned plans,
    /// and plans when due. Events are appended to `events`.
    pub fn step(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) {
        self.io.plans.collect_returned();
        if let Some(r) = self.io.reports.latest() {
            if r.mode == Mode::Stopped && self.last_mode != Mode::Stopped {
                self.want_plan = true;
            }
            if r.last_refused_plan_id != 0 && r.last_refused_plan_id != self.refused_seen {
                self.refused_seen = r.last_refused_plan_id;
                self.want_plan = true;
            }
            self.last_mode = r.mode;
            self.report = Some(r);
        }
        if !self.want_plan {
            return;
        }
        let (Some(r), Some(scene)) = (self.report, self.scene) else {
            return;
        };
        if self.policy.is_none() {
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

    fn plan_from(
        &mut self,
        start: MotionState,
        join: Option<JoinPoint>,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        let Some(policy) = self.policy.as_deref() else {
            return;
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
        if !(verdict.task_ok && verdict.safe) {
            events.push(TwinEvent::Retrain {
                request_id: self.next_request_id,
                verdict,
                scene,
            });
            self.next_request_id += 1;
            return;
        }
        if self.waypoints.is_empty() {
            // Already at the goal: nothing to do.
            return;
        }
        let id = self.next_plan_id;
        self.next_plan_id += 1;
        let mut plan = Plan::with_capacity(id, verdict.policy_id, self.period_s, 0);
        plan.join = join;
        if let Err(e) = self.smoother.smooth(
            &start,
            &self.waypoints,
            self.la.step_s(),
            self.shield.model_mut(),
            &mut plan,
        ) {
            events.push(TwinEvent::PlanRejected {
                policy_id: verdict.policy_id,
                smooth: Some(e),
                shield: None,
            });
            return;
        }
        if let Err(v) = self
            .shield
            .check_path(&start.q_rad, &plan.q_rad, self.period_s, &scene)
        {
            events.push(TwinEvent::PlanRejected {
                policy_id: verdict.policy_id,
                smooth: None,
                shield: Some(v),
            });
            return;
        }
        let copy = plan.clone();
        match self.io.plans.send(Box::new(plan)) {
            Ok(()) => {
                self.sent = Some(copy);
                events.push(TwinEvent::PlanApproved {
                    plan_id: id,
                    policy_id: verdict.policy_id,
                    joins: join.is_some(),
                });
            }
            Err(_) => self.want_plan = true,
        }
    }
}
