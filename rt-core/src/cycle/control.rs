//! The control cycle: `new → start → process → stop`, one [`Cycle::process`] call per
//! period. Each call takes the newest scene and plan hand-overs, reads the arm, checks input
//! ages, picks the next command (the next sample of the approved plan, a brake step, or a
//! hold), re-checks it with the shield against the live scene, sends it, and reports.
//!
//! `process` allocates nothing, takes no lock, does no blocking I/O and no formatting: the
//! hand-overs are lock-free SPSC queues ([`super::handoff`]), plans are returned to the
//! twin for freeing, and events go to the log ring ([`super::rt_log`]).
//!
//! Controlled stops: on a shield violation, a stale scene or robot state, a lost link, or a
//! plan revoked by the twin, the cycle brakes to zero velocity ([`crate::cycle::brake::Brake`])
//! and then stays [`Mode::Stopped`] until a *fresh* plan (an id above every plan seen before
//! the stop) approved by the twin and starting at the stopped pose arrives.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::config::RuntimeConfig;
use crate::cycle::brake::{Brake, MotionState};
use crate::cycle::link::{LinkError, RobotLink};
use crate::cycle::plan::Plan;
use crate::cycle::shield::{Shield, ShieldModel, ShieldViolation};
use crate::rt::clock::Clock;
use crate::rt::handoff::{self, BoxReceiver, BoxSender, LatestReceiver, LatestSender};
use crate::rt::histogram::{Histogram, Summary};
use crate::rt::rt_log::{self, RtLogDrain, RtLogger};
use twin::{DOF, Joints, max_joint_gap_rad};

/// What the cycle is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[repr(u8)]
pub enum Mode {
    /// At rest, waiting for a first plan.
    #[default]
    Idle = 0,
    /// Streaming an approved plan.
    Following = 1,
    /// Braking to zero velocity.
    Stopping = 2,
    /// At rest after a controlled stop; waits for a fresh plan.
    Stopped = 3,
}

/// What the cycle logs: typed and `Copy` (ids stay `u64`), formatted only on the thread
/// that drains the log ring.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CycleEvent {
    /// The cycle started.
    Started {
        /// The cycle period, ns.
        period_ns: u64,
    },
    /// A new plan was adopted.
    PlanAdopted {
        /// Plan id.
        plan_id: u64,
        /// Policy id.
        policy_id: u64,
    },
    /// A plan was scheduled to take over the running one at a join index.
    PlanScheduled {
        /// Plan id.
        plan_id: u64,
        /// Sample of the running plan where it takes over.
        join_index: usize,
    },
    /// A plan was refused (discontinuous, late, or while stopping).
    PlanRefused {
        /// Plan id.
        plan_id: u64,
    },
    /// A plan was completed.
    PlanFinished {
        /// Plan id.
        plan_id: u64,
    },
    /// The twin revoked the running plan.
    PlanRevoked {
        /// Plan id.
        plan_id: u64,
    },
    /// A controlled stop began.
    StopBegun {
        /// Why.
        reason: StopReason,
    },
    /// The arm stands still after a controlled stop.
    Stopped,
    /// The link refused a command or is lost.
    LinkError {
        /// The link's error.
        error: LinkError,
    },
    /// The cycle stopped.
    Finished,
}

/// Why the last controlled stop happened.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum StopReason {
    /// No stop so far.
    #[default]
    None,
    /// The shield refused a command.
    Shield(ShieldViolation),
    /// The latest detection is older than allowed (or none arrived).
    StaleDetection,
    /// The latest robot state is older than allowed.
    StaleRobotState,
    /// The robot link is lost.
    LinkLost,
    /// The twin revoked the running plan (the lookahead found it unsafe).
    Revoked,
}

impl StopReason {
    /// A numeric code for logs and telemetry.
    pub fn code(self) -> u8 {
        match self {
            StopReason::None => 0,
            StopReason::Shield(v) => 10 + v.code(),
            StopReason::StaleDetection => 2,
            StopReason::StaleRobotState => 3,
            StopReason::LinkLost => 4,
            StopReason::Revoked => 5,
        }
    }
}

/// A scene snapshot handed to the cycle with the capture time of its detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneUpdate<S> {
    /// The scene.
    pub scene: S,
    /// Capture time of the detection, on the cycle's clock, ns.
    pub stamp_ns: u64,
}

/// What the cycle reports after each call (to the twin and telemetry).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleReport {
    /// Time of the cycle, ns.
    pub t_ns: u64,
    /// Cycles run.
    pub cycles: u64,
    /// Mode after the cycle.
    pub mode: Mode,
    /// The plan running (or last run), 0 for none.
    pub plan_id: u64,
    /// Its policy.
    pub policy_id: u64,
    /// Next sample of that plan to be sent.
    pub next_index: usize,
    /// The command sent.
    pub cmd: MotionState,
    /// The arm's measured joints, rad.
    pub measured_q_rad: Joints,
    /// Clearance of the command to the live scene, m.
    pub clearance_m: f64,
    /// Reason of the last stop.
    pub stop_reason: StopReason,
    /// Stops so far.
    pub stops: u64,
    /// The last plan refused, 0 for none.
    pub last_refused_plan_id: u64,
    /// Plans adopted or joined so far.
    pub plans_taken: u64,
}

/// The cycle's ends of the hand-overs.
pub struct CycleIo<S: Copy + Send + 'static> {
    plans: BoxReceiver<Plan>,
    scenes: LatestReceiver<SceneUpdate<S>>,
    revoked_plan_id: Arc<AtomicU64>,
    reports: LatestSender<CycleReport>,
    log: RtLogger<CycleEvent>,
}

/// The twin's ends of the hand-overs.
pub struct TwinIo<S: Copy + Send + 'static> {
    /// Approved plans to the cycle (and back, for freeing).
    pub plans: BoxSender<Plan>,
    /// Scene snapshots to the cycle.
    pub scenes: LatestSender<SceneUpdate<S>>,
    /// Id of a plan the twin revokes (the cycle stops it).
    pub revoked_plan_id: Arc<AtomicU64>,
    /// The cycle's reports.
    pub reports: LatestReceiver<CycleReport>,
}

/// Makes the hand-overs between a twin worker and a cycle, and the cycle's log ring.
pub fn wire<S: Copy + Send + 'static>() -> (TwinIo<S>, CycleIo<S>, RtLogDrain<CycleEvent>) {
    let (plan_tx, plan_rx) = handoff::channel();
    let (scene_tx, scene_rx) = handoff::latest();
    let (rep_tx, rep_rx) = handoff::latest();
    let (log, drain) = rt_log::ring();
    let revoked = Arc::new(AtomicU64::new(0));
    (
        TwinIo {
            plans: plan_tx,
            scenes: scene_tx,
            revoked_plan_id: revoked.clone(),
            reports: rep_rx,
        },
        CycleIo {
            plans: plan_rx,
            scenes: scene_rx,
            revoked_plan_id: revoked,
            reports: rep_tx,
            log,
        },
        drain,
    )
}

/// Timing parameters of the cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleConfig {
    /// Period, ns.
    pub period_ns: u64,
    /// Maximum detection age, ns.
    pub max_detection_age_ns: u64,
    /// Maximum robot-state age, ns.
    pub max_robot_state_age_ns: u64,
    /// Largest joint gap between the arm's command and a plan's first sample, rad.
    pub start_tolerance_rad: f64,
    /// How many samples ahead of the next command the shield also checks the running plan
    /// against the live scene: about the braking time, so a stop begun now ends before an
    /// obstacle that appears on the path.
    pub brake_horizon_samples: usize,
}

impl CycleConfig {
    /// From the runtime configuration.
    pub fn from_runtime(cfg: &RuntimeConfig) -> Self {
        Self {
            period_ns: cfg.period_ns(),
            max_detection_age_ns: (cfg.stale.max_detection_age_s * 1e9) as u64,
            max_robot_state_age_ns: (cfg.stale.max_robot_state_age_s * 1e9) as u64,
            start_tolerance_rad: 0.02,
            brake_horizon_samples: {
                let l = &cfg.limits;
                let t_s = (0..DOF)
                    .map(|j| {
                        l.max_velocity_rad_s[j] / l.max_acceleration_rad_s2[j]
                            + l.max_acceleration_rad_s2[j] / l.max_jerk_rad_s3[j]
                    })
                    .fold(0.0, f64::max);
                (t_s * cfg.rate_hz).ceil() as usize
            },
        }
    }
}

/// The control cycle.
pub struct Cycle<M: ShieldModel, L: RobotLink> {
    cfg: CycleConfig,
    shield: Shield<M>,
    link: L,
    io: CycleIo<M::Scene>,
    brake: Brake,
    mode: Mode,
    cmd: MotionState,
    plan: Option<Box<Plan>>,
    pending: Option<Box<Plan>>,
    next: usize,
    scene: Option<SceneUpdate<M::Scene>>,
    report: CycleReport,
    newest_plan_id_seen: u64,
    fresh_after_id: u64,
    link_ok: bool,
    started: bool,
}

impl<M: ShieldModel, L: RobotLink> Cycle<M, L> {
    /// A cycle over `shield` and `link`, with its hand-overs (see [`wire`]). Allocates
    /// nothing later.
    pub fn new(
        cfg: CycleConfig,
        shield: Shield<M>,
        brake: Brake,
        link: L,
        io: CycleIo<M::Scene>,
    ) -> Self {
        Self {
            cfg,
            shield,
            link,
            io,
            brake,
            mode: Mode::Idle,
            cmd: MotionState::default(),
            plan: None,
            pending: None,
            next: 0,
            scene: None,
            report: CycleReport::default(),
            newest_plan_id_seen: 0,
            fresh_after_id: 0,
            link_ok: true,
            started: false,
        }
    }

    /// Reads the arm once and holds its pose.
    ///
    /// # Errors
    /// The link's error when the arm cannot be read.
    pub fn start(&mut self, now_ns: u64) -> Result<(), LinkError> {
        let st = self.link.read_state(now_ns)?;
        self.cmd = MotionState::at_rest(st.q_rad);
        self.report.measured_q_rad = st.q_rad;
        self.mode = Mode::Idle;
        self.started = true;
        self.io.log.log(
            now_ns,
            CycleEvent::Started {
                period_ns: self.cfg.period_ns,
            },
        );
        self.publish(now_ns);
        Ok(())
    }

    /// Ends the cycle: returns any plans to the twin and gives the link back.
    pub fn stop(mut self, now_ns: u64) -> L {
        if let Some(p) = self.plan.take() {
            self.io.plans.give_back(p);
        }
        if let Some(p) = self.pending.take() {
            self.io.plans.give_back(p);
        }
        self.io.log.log(now_ns, CycleEvent::Finished);
        self.link
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The last report.
    pub fn report(&self) -> &CycleReport {
        &self.report
    }

    /// The link (e.g. to inspect a simulated arm).
    pub fn link(&self) -> &L {
        &self.link
    }

    fn begin_stop(&mut self, now_ns: u64, reason: StopReason) {
        if let Some(p) = self.pending.take() {
            self.io.plans.give_back(p);
        }
        match self.mode {
            Mode::Following => {
                self.brake.start(self.cmd);
                self.mode = Mode::Stopping;
            }
            Mode::Idle => self.mode = Mode::Stopped,
            Mode::Stopping | Mode::Stopped => return,
        }
        self.fresh_after_id = self.newest_plan_id_seen;
        self.report.stop_reason = reason;
        self.report.stops += 1;
        self.io.log.log(now_ns, CycleEvent::StopBegun { reason });
    }

    fn refuse(&mut self, now_ns: u64, p: Box<Plan>) {
        self.report.last_refused_plan_id = p.id;
        self.io
            .log
            .log(now_ns, CycleEvent::PlanRefused { plan_id: p.id });
        self.io.plans.give_back(p);
    }

    fn consider(&mut self, now_ns: u64, p: Box<Plan>, inputs_ok: bool) {
        self.newest_plan_id_seen = self.newest_plan_id_seen.max(p.id);
        match self.mode {
            Mode::Idle | Mode::Stopped => {
                let close = p.q_rad.first().is_some_and(|q0| {
                    max_joint_gap_rad(q0, &self.cmd.q_rad) <= self.cfg.start_tolerance_rad
                });
                if p.join.is_none() && p.id > self.fresh_after_id && close && inputs_ok {
                    if let Some(old) = self.plan.replace(p) {
                        self.io.plans.give_back(old);
                    }
                    self.next = 0;
                    self.mode = Mode::Following;
                    self.report.plans_taken += 1;
                    let (id, pol) = self.plan.as_ref().map_or((0, 0), |p| (p.id, p.policy_id));
                    self.io.log.log(
                        now_ns,
                        CycleEvent::PlanAdopted {
                            plan_id: id,
                            policy_id: pol,
                        },
                    );
                } else {
                    self.refuse(now_ns, p);
                }
            }
            Mode::Following => {
                let running = self.plan.as_ref().map_or(0, |r| r.id);
                match p.join {
                    Some(j) if j.plan_id == running && j.index >= self.next && !p.is_empty() => {
                        self.io.log.log(
                            now_ns,
                            CycleEvent::PlanScheduled {
                                plan_id: p.id,
                                join_index: j.index,
                            },
                        );
                        if let Some(old) = self.pending.replace(p) {
                            self.io.plans.give_back(old);
                        }
                    }
                    _ => self.refuse(now_ns, p),
                }
            }
            Mode::Stopping => self.refuse(now_ns, p),
        }
    }

    /// One cycle at `now_ns`. Returns the mode after it.
    pub fn process(&mut self, now_ns: u64) -> Mode {
        let dt_s = self.cfg.period_ns as f64 * 1e-9;
        if let Some(s) = self.io.scenes.latest() {
            self.scene = Some(s);
        }
        // Inputs.
        let mut inputs_ok = self.started;
        match self.link.read_state(now_ns) {
            Ok(st) => {
                if !self.link_ok && matches!(self.mode, Mode::Idle | Mode::Stopped) {
                    // The link is back while at rest: hold where the arm is, not where the
                    // commands left off (the arm got none while the link was down, a brake
                    // may have run on without it, and a restarted controller may report the
                    // arm elsewhere). A fresh plan must then start from this pose.
                    self.cmd = MotionState::at_rest(st.q_rad);
                }
                self.link_ok = true;
                self.report.measured_q_rad = st.q_rad;
                if now_ns.saturating_sub(st.stamp_ns) > self.cfg.max_robot_state_age_ns {
                    inputs_ok = false;
                    self.begin_stop(now_ns, StopReason::StaleRobotState);
                }
            }
            Err(e) => {
                if self.link_ok {
                    self.io.log.log(now_ns, CycleEvent::LinkError { error: e });
                }
                self.link_ok = false;
                inputs_ok = false;
                self.begin_stop(now_ns, StopReason::LinkLost);
            }
        }
        let scene_fresh = self
            .scene
            .is_some_and(|s| now_ns.saturating_sub(s.stamp_ns) <= self.cfg.max_detection_age_ns);
        if !scene_fresh {
            inputs_ok = false;
            if self.mode == Mode::Following {
                self.begin_stop(now_ns, StopReason::StaleDetection);
            }
        }
        let revoked = self.io.revoked_plan_id.load(Ordering::Acquire);
        if self.mode == Mode::Following && self.plan.as_ref().is_some_and(|p| p.id == revoked) {
            self.io
                .log
                .log(now_ns, CycleEvent::PlanRevoked { plan_id: revoked });
            self.begin_stop(now_ns, StopReason::Revoked);
        }
        while let Some(p) = self.io.plans.take() {
            self.consider(now_ns, p, inputs_ok);
        }
        // Command.
        let prev_q = self.cmd.q_rad;
        match self.mode {
            Mode::Following => self.follow(now_ns, dt_s, &prev_q),
            Mode::Stopping => {
                self.cmd = *self.brake.step(dt_s);
                if self.brake.is_stopped() {
                    self.mode = Mode::Stopped;
                    self.io.log.log(now_ns, CycleEvent::Stopped);
                }
            }
            Mode::Idle | Mode::Stopped => {
                self.cmd = MotionState::at_rest(self.cmd.q_rad);
            }
        }
        if self.link_ok
            && let Err(e) = self.link.send_servo(now_ns, &self.cmd.q_rad)
        {
            self.io.log.log(now_ns, CycleEvent::LinkError { error: e });
            self.link_ok = false;
            self.begin_stop(now_ns, StopReason::LinkLost);
        }
        self.publish(now_ns);
        self.mode
    }

    fn follow(&mut self, now_ns: u64, dt_s: f64, prev_q: &Joints) {
        // Switch to a scheduled plan at its join point.
        if let Some(pending) = &self.pending
            && pending.join.is_some_and(|j| j.index + 1 == self.next)
            && let Some(p) = self.pending.take()
        {
            self.report.plans_taken += 1;
            self.io.log.log(
                now_ns,
                CycleEvent::PlanAdopted {
                    plan_id: p.id,
                    policy_id: p.policy_id,
                },
            );
            if let Some(old) = self.plan.replace(p) {
                self.io.plans.give_back(old);
            }
            self.next = 0;
        }
        let Some(plan) = self.plan.as_ref() else {
            self.mode = Mode::Idle;
            return;
        };
        if self.next >= plan.len() {
            self.io
                .log
                .log(now_ns, CycleEvent::PlanFinished { plan_id: plan.id });
            self.mode = Mode::Idle;
            self.cmd = MotionState::at_rest(self.cmd.q_rad);
            return;
        }
        let k = self.next;
        let candidate = MotionState {
            q_rad: plan.q_rad[k],
            dq_rad_s: plan.dq_rad_s[k],
            ddq_rad_s2: plan.ddq_rad_s2[k],
        };
        let ahead = plan.q_rad[(k + self.cfg.brake_horizon_samples).min(plan.len() - 1)];
        let verdict = match &self.scene {
            Some(s) => self
                .shield
                .check_step(prev_q, &candidate.q_rad, dt_s, &s.scene)
                .and_then(|d| self.shield.check_pose(&ahead, &s.scene).map(|_| d)),
            None => Err(ShieldViolation::NonFinite),
        };
        match verdict {
            Ok(d) => {
                self.report.clearance_m = d;
                self.cmd = candidate;
                self.next += 1;
            }
            Err(v) => {
                self.begin_stop(now_ns, StopReason::Shield(v));
                self.cmd = *self.brake.step(dt_s);
            }
        }
    }

    fn publish(&mut self, now_ns: u64) {
        let r = &mut self.report;
        r.t_ns = now_ns;
        r.cycles += 1;
        r.mode = self.mode;
        if let Some(p) = &self.plan {
            r.plan_id = p.id;
            r.policy_id = p.policy_id;
        }
        r.next_index = self.next;
        r.cmd = self.cmd;
        let report = *r;
        self.io.reports.send(report);
    }
}

/// Timing figures of a loop run.
#[derive(Default)]
pub struct LoopStats {
    /// Wake-up latency (actual wake − deadline).
    pub wake: Histogram,
    /// Compute time of `process`.
    pub compute: Histogram,
    /// Deadlines missed (a cycle that ended after the next deadline), whatever the cause:
    /// a late wake-up (the OS) or a long compute (the cycle).
    pub missed_deadlines: u64,
    /// Cycles whose own compute took longer than the period: the part of the missed
    /// deadlines that the cycle's code answers for, whatever the OS did to the wake-up.
    pub compute_overruns: u64,
    /// Cycles run.
    pub cycles: u64,
}

/// Summary of a loop run (JSON for the bench).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct LoopSummary {
    /// Cycles run.
    pub cycles: u64,
    /// Deadlines missed.
    pub missed_deadlines: u64,
    /// Cycles whose compute alone exceeded the period.
    pub compute_overruns: u64,
    /// Wake-up latency, µs.
    pub wakeup_latency_us: Summary,
    /// Compute time, µs.
    pub cycle_compute_us: Summary,
}

impl LoopStats {
    /// The summary.
    pub fn summary(&self) -> LoopSummary {
        LoopSummary {
            cycles: self.cycles,
            missed_deadlines: self.missed_deadlines,
            compute_overruns: self.compute_overruns,
            wakeup_latency_us: self.wake.summary(),
            cycle_compute_us: self.compute.summary(),
        }
    }
}

/// Counters of a running loop that other threads may read (relaxed atomics).
#[derive(Debug, Default)]
pub struct LoopShared {
    /// Cycles run (a watchdog checks that it moves).
    pub heartbeat: AtomicU64,
    /// Deadlines missed so far.
    pub missed_deadlines: AtomicU64,
    /// Compute time of the last cycle, ns.
    pub last_compute_ns: AtomicU64,
}

/// Drives `cycle` every `period_ns` on `clock` until `stop` is set, recording timing into
/// `stats` and publishing counters in `shared`. Allocation-free.
pub fn run_loop<M: ShieldModel, L: RobotLink, C: Clock>(
    cycle: &mut Cycle<M, L>,
    clock: &C,
    stop: &AtomicBool,
    shared: &LoopShared,
    stats: &mut LoopStats,
) {
    let period = cycle.cfg.period_ns;
    let mut deadline = clock.now_ns() + period;
    while !stop.load(Ordering::Acquire) {
        clock.sleep_until_ns(deadline);
        let wake = clock.now_ns();
        stats.wake.record_ns(wake.saturating_sub(deadline));
        cycle.process(wake);
        let done = clock.now_ns();
        let compute = done.saturating_sub(wake);
        stats.compute.record_ns(compute);
        stats.cycles += 1;
        if compute > period {
            stats.compute_overruns += 1;
        }
        shared.last_compute_ns.store(compute, Ordering::Relaxed);
        shared.heartbeat.fetch_add(1, Ordering::Release);
        deadline += period;
        if done > deadline {
            let behind = (done - deadline) / period + 1;
            stats.missed_deadlines += behind;
            shared.missed_deadlines.fetch_add(behind, Ordering::Relaxed);
            deadline += behind * period;
        }
    }
}
