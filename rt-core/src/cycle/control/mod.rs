//! The control cycle: `new → start → process → stop`, one [`Cycle::process`] call per
//! period. Each call takes the newest scene and plan hand-overs, reads the arm, checks input
//! ages, picks the next command (the next sample of the approved plan, a brake step, or a
//! hold), re-checks it with the shield against the live scene, sends it, and reports.
//!
//! `process` allocates nothing, takes no lock, does no blocking I/O and no formatting: the
//! hand-overs are lock-free SPSC queues ([`crate::rt::handoff`]), plans are returned to the
//! twin for freeing, and events go to the log ring ([`crate::rt::rt_log`]).
//!
//! One check for every command: whatever picked it (a plan sample, a stop step, a hold, the
//! first command after a reconnect), a command passes [`Shield::check_step`] against the
//! last command *sent* before it reaches the link. A plan sample that fails starts a stop;
//! a stop step that fails makes the cycle hold the last command sent and stop there; a hold
//! that fails is not sent (the controller holds the arm).
//!
//! Controlled stops: on a shield violation, a stale scene or robot state, a lost link, a plan
//! revoked by the twin, or a shutdown request, the cycle stops along the running plan by time
//! scaling ([`crate::cycle::brake::PathStop`]; every pose until rest lies on the verified
//! path, and the cycle checks the plan one stop envelope ahead of the arm each period), or
//! with the per-joint brake ([`crate::cycle::brake::Brake`]) when the plan is not valid at
//! the next sample. It then stays [`Mode::Stopped`] until a *fresh* plan (an id above every
//! plan seen before the stop) approved by the twin and starting at the stopped pose arrives.
//! The unavoidable case — an obstacle appearing inside the stop envelope, closer than the
//! arm can stop — is counted ([`CycleReport::envelope_breaches`]).
//!
//! Protective stops: a controller error ([`StopReason::ArmError`]) and, unless
//! [`CycleConfig::auto_resume_after_link_loss`], a lost link latch the cycle: it sends
//! nothing and takes no plan until an operator acknowledges ([`CycleControl::acknowledge`]),
//! which clears the controller's error and re-enables motion through the link. The cycle
//! never clears an error on its own. A model mismatch ([`StopReason::ModelMismatch`]: the
//! twin's TCP and the controller's disagree) stops under control first, then latches the
//! same way once the arm is at rest. When the link returns on a re-opened connection while
//! stopping, the cycle snaps to the measured joints and finishes the stop there (the arm got
//! no command meanwhile, and servo mode, entered again, holds it where it stands). When the
//! robot state returns on the same connection (it was late or missing: a starved or
//! congested controller that still took every command), and after the cycle itself froze,
//! the stop ends at the last command sent instead: the controller holds that target and
//! checks the next one against it, whatever the possibly lagging measured joints say.
//!
//! The controller and the arm are watched too: a controller that leaves its ready state
//! without the cycle asking ([`StopReason::ControllerStopped`]: the pendant's stop, the SDK,
//! another client's `SET_STATE 4`) latches like an arm error, and measured joints that stop
//! following the commands sent ([`StopReason::TrackingLost`], a frozen arm: more than
//! [`CycleConfig::max_tracking_error_rad`] for [`CycleConfig::tracking_error_cycles`]
//! periods) make the controller hold the arm where it stands and latch. Neither applies to
//! a link whose commands do not reach the arm (a dry run, [`RobotLink::commands_reach_arm`]).
//! An acknowledgement given while the link is down or the arm still stopping is dropped
//! ([`CycleEvent::AcknowledgementDropped`]), never kept to re-enable the arm later.
//!
//! The module's files: this one holds [`Cycle`] itself; `events.rs` its [`Mode`],
//! [`CycleEvent`] and [`StopReason`]; `io.rs` the hand-overs ([`CycleIo`], [`TwinIo`],
//! [`CycleControl`], [`wire`]); `config.rs` [`CycleConfig`]; `report.rs` [`CycleReport`];
//! `run_loop.rs` the periodic loop ([`run_loop`]) and its timing figures.

mod config;
mod events;
mod io;
mod report;
mod run_loop;

pub use config::CycleConfig;
pub use events::{CycleEvent, Mode, StopReason};
pub use io::{Adoption, CycleControl, CycleIo, Intruders, SceneUpdate, TwinIo, wire};
pub use report::CycleReport;
pub use run_loop::{LoopShared, LoopStats, LoopSummary, run_loop};

use std::sync::Arc;

use crate::cycle::brake::{Brake, PathStop};
use crate::cycle::link::{LinkError, LinkState, RobotLink};
use crate::cycle::plan::MotionState;
use crate::cycle::plan::Plan;
use crate::cycle::separation::SeparationMonitor;
use crate::cycle::shield::{Shield, ShieldModel, ShieldViolation};
use twin::{Joints, max_joint_gap_rad};

/// Periods an acknowledgement is retried when the link cannot pass it on (≈ 0.2 s at
/// 250 Hz); then the operator must acknowledge again.
const ACK_ATTEMPTS: u32 = 50;

/// Fastest measured joint speed at which the arm counts as at rest for an operator's
/// acknowledgement, rad/s (issue 41 item 5).
const ACK_REST_SPEED_RAD_S: f64 = 0.01;

/// How the running stop moves the arm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StopMotion {
    /// Along the running plan (time scaling).
    AlongPlan,
    /// Per-joint brake (the plan is not valid at the next sample, or there is none).
    Brake,
}

/// The control cycle.
pub struct Cycle<M: ShieldModel, L: RobotLink> {
    cfg: CycleConfig,
    shield: Shield<M>,
    link: L,
    io: CycleIo<M::Scene>,
    brake: Brake,
    path_stop: PathStop,
    stop_motion: StopMotion,
    mode: Mode,
    cmd: MotionState,
    /// The last command that reached the link: every new command is checked against it.
    last_sent: MotionState,
    plan: Option<Box<Plan>>,
    pending: Option<Box<Plan>>,
    next: usize,
    scene: Option<SceneUpdate<M::Scene>>,
    report: CycleReport,
    newest_plan_id_seen: u64,
    fresh_after_id: u64,
    link_ok: bool,
    started: bool,
    /// The stop an operator's acknowledgement named, taken from [`CycleControl`] and kept
    /// while the link cannot pass it on (0 for none).
    pending_ack: u64,
    ack_failures: u32,
    /// A model-mismatch stop is under way: latched once the arm is at rest.
    mismatch_latch_pending: bool,
    /// The controller has been seen ready (state 0, 1 or 2) since the cycle started, the
    /// link returned or an acknowledgement: from then on, a stopped state the cycle did
    /// not ask for latches (before, a report from before servo mode may still read 4).
    controller_ready_seen: bool,
    /// Periods in a row with the measured joints beyond the tracking tolerance.
    tracking_bad_cycles: u32,
    /// Time of the cycle before (0 before the first), ns: a longer gap than
    /// [`CycleConfig::max_cycle_gap_ns`] is a freeze.
    last_cycle_ns: u64,
    /// Speed and separation monitoring: the running plan's playback scale.
    separation: SeparationMonitor,
    /// Where the last command lies beyond plan sample `next − 1`, in samples (0 on a
    /// sample; between samples only during scaled playback).
    play_frac: f64,
    /// The playback scale of the last command taken along the plan (a stop along the plan
    /// falls from it).
    play_scale: f64,
    /// The link's connection of the last reading ([`crate::cycle::link::LinkState::session`]):
    /// while it stays the same, the controller's reference is the last command sent.
    session: u32,
    /// The last reading measured every joint slower than [`ACK_REST_SPEED_RAD_S`].
    measured_at_rest: bool,
}

impl<M: ShieldModel, L: RobotLink> Cycle<M, L> {
    /// A cycle over `shield` and `link`, with its hand-overs (see [`wire`]). Allocates
    /// nothing later. `brake` carries the arm's limits for both kinds of stop.
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
            path_stop: PathStop::from_brake(&brake),
            brake,
            stop_motion: StopMotion::Brake,
            mode: Mode::Idle,
            cmd: MotionState::default(),
            last_sent: MotionState::default(),
            plan: None,
            pending: None,
            next: 0,
            scene: None,
            report: CycleReport::default(),
            newest_plan_id_seen: 0,
            fresh_after_id: 0,
            link_ok: true,
            started: false,
            pending_ack: 0,
            ack_failures: 0,
            mismatch_latch_pending: false,
            controller_ready_seen: false,
            tracking_bad_cycles: 0,
            last_cycle_ns: 0,
            separation: SeparationMonitor::new(cfg.separation),
            play_frac: 0.0,
            play_scale: 1.0,
            session: 0,
            measured_at_rest: false,
        }
    }

    /// Reads the arm once and holds its pose.
    ///
    /// # Errors
    /// The link's error when the arm cannot be read.
    pub fn start(&mut self, now_ns: u64) -> Result<(), LinkError> {
        let st = self.link.read_state(now_ns)?;
        self.cmd = MotionState::at_rest(st.q_rad);
        self.last_sent = MotionState::at_rest(st.q_rad);
        self.report.measured_q_rad = st.q_rad;
        self.session = st.session;
        self.mode = Mode::Idle;
        self.started = true;
        // An acknowledgement given before the cycle ran names no stop of this run.
        let _ = self.io.control.take_ack_request();
        self.io.log.log(
            now_ns,
            CycleEvent::Started {
                period_ns: self.cfg.period_ns,
            },
        );
        if st.error_code != 0 {
            self.on_arm_error(now_ns, st.error_code, st.q_rad);
        }
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

    /// The link, mutably (the cycle thread puts the controller in its stop state through
    /// it once the loop has ended).
    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }

    /// The control flags shared with the twin thread and the process.
    pub fn control(&self) -> &Arc<CycleControl> {
        &self.io.control
    }

    fn begin_stop(&mut self, now_ns: u64, reason: StopReason, motion: StopMotion) {
        if let Some(p) = self.pending.take() {
            self.io.plans.give_back(p);
        }
        match self.mode {
            Mode::Following => {
                let along = motion == StopMotion::AlongPlan && self.plan.is_some();
                if along {
                    let at = self.next.saturating_sub(1) as f64 + self.play_frac;
                    self.path_stop
                        .start_scaled(self.cmd, at, self.play_scale, self.dt_s());
                    self.stop_motion = StopMotion::AlongPlan;
                } else {
                    self.brake.start(self.cmd);
                    self.stop_motion = StopMotion::Brake;
                }
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

    /// Ends any stop at once at the last command sent, at rest: the controller still holds
    /// it as its target (the same connection, no stop or reset of the controller since), so
    /// it is the reference the controller checks the next target against.
    fn stop_at_last_sent(&mut self, now_ns: u64) {
        let q = self.last_sent.q_rad;
        self.cmd = MotionState::at_rest(q);
        self.last_sent = MotionState::at_rest(q);
        if self.mode == Mode::Stopping || self.mode == Mode::Following {
            self.mode = Mode::Stopped;
            self.io.log.log(now_ns, CycleEvent::HeldAtLastSent);
            self.io.log.log(now_ns, CycleEvent::Stopped);
        }
    }

    /// Ends any stop at once at `q_rad` (the arm stands there: a controller that stopped
    /// it, or a link that was down while the brake ran on without it).
    fn snap_to(&mut self, now_ns: u64, q_rad: Joints) {
        self.cmd = MotionState::at_rest(q_rad);
        self.last_sent = MotionState::at_rest(q_rad);
        if self.mode == Mode::Stopping || self.mode == Mode::Following {
            self.mode = Mode::Stopped;
            self.io.log.log(now_ns, CycleEvent::SnappedToMeasured);
            self.io.log.log(now_ns, CycleEvent::Stopped);
        }
    }

    fn on_arm_error(&mut self, now_ns: u64, code: u16, measured_q_rad: Joints) {
        if self.report.arm_error_code != code {
            self.io.log.log(now_ns, CycleEvent::ArmError { code });
        }
        self.report.arm_error_code = code;
        if !self.report.awaiting_ack || self.report.stop_reason != StopReason::ArmError(code) {
            // The controller has stopped the arm itself: the stop ends where it stands.
            self.begin_stop(now_ns, StopReason::ArmError(code), StopMotion::Brake);
            self.report.stop_reason = StopReason::ArmError(code);
            self.latch();
        }
        self.snap_to(now_ns, measured_q_rad);
    }

    /// The controller's reported state: ready (0, 1 moving, 2 ready) arms the check; any
    /// other state once armed (3 paused, 4 stopped, …) is a stop the cycle did not ask for
    /// (the pendant, the SDK, another client's `SET_STATE 4`): the controller holds the arm
    /// where it stands, so the stop ends there and latches like an arm error. Returns
    /// whether the state allows motion.
    fn watch_controller_state(&mut self, now_ns: u64, state: u8, measured_q_rad: Joints) -> bool {
        if state <= 2 {
            self.controller_ready_seen = true;
            return true;
        }
        if !self.controller_ready_seen || self.report.awaiting_ack {
            // Not yet ready since (re-)enabling, or already latched: no motion either way.
            return false;
        }
        self.io
            .log
            .log(now_ns, CycleEvent::ControllerStopped { state });
        let reason = StopReason::ControllerStopped { state };
        self.begin_stop(now_ns, reason, StopMotion::Brake);
        self.report.stop_reason = reason;
        self.latch();
        self.mismatch_latch_pending = false;
        self.snap_to(now_ns, measured_q_rad);
        false
    }

    /// Compares the measured joints with the last command sent: more than
    /// [`CycleConfig::max_tracking_error_rad`] apart for
    /// [`CycleConfig::tracking_error_cycles`] periods in a row is a frozen (or blocked) arm.
    /// Streaming on (or braking the commands along the plan) would leave the controller a
    /// target the arm reaches at once when it comes free; instead the controller is asked
    /// to hold the arm where it stands ([`RobotLink::hold_controller`], the xArm's
    /// `SET_STATE 4`, non-blocking), the stop ends at the measured joints and latches until
    /// an operator acknowledges. Returns whether tracking allows motion. Allocation-free.
    fn watch_tracking(&mut self, now_ns: u64, measured_q_rad: &Joints) -> bool {
        if self.report.awaiting_ack {
            self.tracking_bad_cycles = 0;
            self.report.tracking_error_rad = 0.0;
            return true;
        }
        let error_rad = max_joint_gap_rad(&self.last_sent.q_rad, measured_q_rad);
        self.report.tracking_error_rad = error_rad;
        // NaN counts as beyond.
        if error_rad <= self.cfg.max_tracking_error_rad {
            self.tracking_bad_cycles = 0;
            return true;
        }
        self.tracking_bad_cycles = self.tracking_bad_cycles.saturating_add(1);
        if self.tracking_bad_cycles < self.cfg.tracking_error_cycles {
            return true;
        }
        self.io
            .log
            .log(now_ns, CycleEvent::TrackingLost { error_rad });
        self.link.hold_controller(now_ns);
        self.begin_stop(now_ns, StopReason::TrackingLost, StopMotion::Brake);
        self.report.stop_reason = StopReason::TrackingLost;
        self.latch();
        self.mismatch_latch_pending = false;
        self.tracking_bad_cycles = 0;
        self.snap_to(now_ns, *measured_q_rad);
        false
    }

    /// The twin's TCP and the controller's disagree: a controlled stop along the plan (the
    /// arm is still commanded to rest), latched once at rest. Ignored while a latch stands.
    fn on_model_mismatch(&mut self, now_ns: u64, gap_m: f64) {
        if self.report.awaiting_ack || self.mismatch_latch_pending {
            return;
        }
        self.io.log.log(now_ns, CycleEvent::ModelMismatch { gap_m });
        self.begin_stop(now_ns, StopReason::ModelMismatch, StopMotion::AlongPlan);
        self.report.stop_reason = StopReason::ModelMismatch;
        self.mismatch_latch_pending = true;
    }

    /// The cycle was not run for `gap_ns` (longer than the freeze bound). While the arm
    /// moved (or stopped), the controller got no target meanwhile and holds the arm at the
    /// last one: the stop ends at the last command sent at once — streaming on from where
    /// the plan's clock left off would jump the arm from rest to the plan's speed, and the
    /// measured joints may lag that target (a state late after a stall of the whole machine),
    /// so a command at them would be a jump back the controller faults on. Latched until
    /// an operator acknowledges, unless the arm is simulated and auto-resumes
    /// ([`CycleConfig::auto_resume_after_link_loss`]). At rest a gap changes nothing.
    fn on_freeze(&mut self, now_ns: u64, gap_ns: u64) {
        if !matches!(self.mode, Mode::Following | Mode::Stopping) {
            return;
        }
        self.io.log.log(now_ns, CycleEvent::Frozen { gap_ns });
        self.begin_stop(now_ns, StopReason::Frozen, StopMotion::Brake);
        self.report.stop_reason = StopReason::Frozen;
        if !self.cfg.auto_resume_after_link_loss && self.link.commands_reach_arm() {
            self.latch();
        }
        if self.link.commands_reach_arm() {
            // A link that returned on a re-opened connection this period has already put
            // the last command sent at the measured joints (`read_inputs`).
            self.stop_at_last_sent(now_ns);
        } else {
            // A dry run: the arm got none of the commands; it stands where measured.
            let q = self.report.measured_q_rad;
            self.snap_to(now_ns, q);
        }
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
        if self.report.awaiting_ack
            || self.io.control.shutdown_requested()
            || p.id <= self.io.control.revoked_up_to()
        {
            self.refuse(now_ns, p);
            return;
        }
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
                    self.play_frac = 0.0;
                    self.mode = Mode::Following;
                    self.report.plans_taken += 1;
                    let (id, pol) = self.plan.as_ref().map_or((0, 0), |p| (p.id, p.policy_id));
                    self.io.control.note_adopted(id);
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

    fn dt_s(&self) -> f64 {
        self.cfg.period_ns as f64 * 1e-9
    }

    /// Reads the arm; returns whether the inputs allow motion.
    fn read_inputs(&mut self, now_ns: u64) -> bool {
        match self.link.read_state(now_ns) {
            Ok(st) => self.take_state(now_ns, &st),
            Err(e) => {
                self.on_read_error(now_ns, e);
                false
            }
        }
    }

    /// A state read from the arm: the link's return handled, then the controller's error,
    /// the model check, the controller's state, tracking and the state's age watched;
    /// returns whether the inputs allow motion.
    fn take_state(&mut self, now_ns: u64, st: &LinkState) -> bool {
        let mut inputs_ok = self.started;
        let returned = !self.link_ok;
        let same_connection = st.session == self.session;
        self.session = st.session;
        self.link_ok = true;
        self.report.measured_q_rad = st.q_rad;
        self.measured_at_rest = st.dq_rad_s.iter().all(|v| v.abs() <= ACK_REST_SPEED_RAD_S);
        self.report.arm_mode = st.mode;
        self.report.arm_state = st.state;
        if returned {
            self.on_link_returned(now_ns, st.q_rad, same_connection);
        }
        if st.error_code != 0 {
            inputs_ok = false;
            self.on_arm_error(now_ns, st.error_code, st.q_rad);
        } else if self.report.arm_error_code != 0 {
            // Cleared on the controller (by the operator); the latch stays until
            // acknowledged here.
            self.report.arm_error_code = 0;
        }
        if let Some(gap_m) = st.model_mismatch_m {
            inputs_ok = false;
            self.on_model_mismatch(now_ns, gap_m);
        }
        // A reading older than the state-age limit shows the joints from before the
        // commands sent since: it stops the arm as stale (below, a pause), and is
        // never taken for an arm that stopped following them (a latched fault).
        let stale = now_ns.saturating_sub(st.stamp_ns) > self.cfg.max_robot_state_age_ns;
        if st.error_code == 0 && self.started && self.link.commands_reach_arm() {
            if !self.watch_controller_state(now_ns, st.state, st.q_rad) {
                inputs_ok = false;
            }
            if !stale && !self.watch_tracking(now_ns, &st.q_rad) {
                inputs_ok = false;
            }
        }
        if stale {
            inputs_ok = false;
            self.begin_stop(now_ns, StopReason::StaleRobotState, StopMotion::AlongPlan);
        }
        inputs_ok
    }

    /// The link is back after a failed reading, the arm measured at `measured_q_rad`.
    fn on_link_returned(&mut self, now_ns: u64, measured_q_rad: Joints, same_connection: bool) {
        if same_connection && !self.report.awaiting_ack && self.link.commands_reach_arm() {
            // The state was late or missing on the same connection (a starved or
            // congested controller): the controller kept every command sent and
            // holds the arm at the last one, its reference for the next target.
            // The measured joints may lag it (reports from before the stall), and
            // a command at them would be a jump back the controller faults on
            // (error 24). A stop under way ends there.
            self.stop_at_last_sent(now_ns);
        } else {
            // The link is back on a re-opened connection (or after a latched stop):
            // hold where the arm is, not where the commands left off (the arm got
            // none while the link was down, a stop may have run on without it, and
            // a restarted controller may report the arm elsewhere; servo mode,
            // entered again, holds it where it stands). A stop under way ends here;
            // a fresh plan must start from this pose.
            self.snap_to(now_ns, measured_q_rad);
            // A re-opened connection may report the state from before servo mode.
            self.controller_ready_seen = false;
            self.tracking_bad_cycles = 0;
        }
    }

    /// The arm could not be read: a controller error latches and brakes; a lost connection
    /// latches (unless resuming on its own); any failed reading stops along the plan.
    fn on_read_error(&mut self, now_ns: u64, e: LinkError) {
        if self.link_ok {
            self.io.log.log(now_ns, CycleEvent::LinkError { error: e });
        }
        self.link_ok = false;
        if let LinkError::ControllerError(code) = e {
            // An error without a readable state: latched like any controller error.
            self.report.arm_error_code = code;
            self.latch();
            self.begin_stop(now_ns, StopReason::ArmError(code), StopMotion::Brake);
        } else {
            // A lost connection latches; a reading that is late or pending (no
            // fresh report, an error code still being read) only stops.
            if e == LinkError::Disconnected && !self.cfg.auto_resume_after_link_loss && self.started
            {
                self.latch();
            }
            self.begin_stop(now_ns, StopReason::LinkLost, StopMotion::AlongPlan);
        }
    }

    /// Latches the stop under way: nothing is sent until an operator acknowledges it by
    /// its number ([`CycleReport::latch_seq`], counted here once per latch).
    fn latch(&mut self) {
        if !self.report.awaiting_ack {
            self.report.latch_seq += 1;
        }
        self.report.awaiting_ack = true;
    }

    /// Takes an operator's acknowledgement of the stop latched now, by its number: clears
    /// the controller's error and re-enables motion through the link, then holds where the
    /// arm is until a fresh plan arrives. One naming another stop is refused; one given
    /// while the link is down or the arm still stopping is dropped.
    fn take_acknowledgement(&mut self, now_ns: u64) {
        let named = self.io.control.take_ack_request();
        if named != 0 {
            self.pending_ack = named;
            self.ack_failures = 0;
        }
        if self.pending_ack == 0 {
            return;
        }
        let latched_seq = if self.report.awaiting_ack {
            self.report.latch_seq
        } else {
            0
        };
        if self.pending_ack != latched_seq {
            // An earlier stop's acknowledgement (or one for none) never clears this one.
            self.io.log.log(
                now_ns,
                CycleEvent::AcknowledgementRefused {
                    named_seq: self.pending_ack,
                    latched_seq,
                },
            );
            self.pending_ack = 0;
            self.report.acks_refused += 1;
            return;
        }
        if !self.link_ok || self.mode == Mode::Stopping || !self.measured_at_rest {
            // Dropped, never kept for later: an operator acknowledges an arm at rest on a
            // live link (measured at rest, issue 41 item 5: not merely commanded so), and a
            // new acknowledgement is needed once it is.
            self.pending_ack = 0;
            self.report.acks_dropped += 1;
            self.io.log.log(now_ns, CycleEvent::AcknowledgementDropped);
            return;
        }
        match self.link.acknowledge(now_ns) {
            Ok(()) => {
                self.pending_ack = 0;
                self.ack_failures = 0;
                self.report.awaiting_ack = false;
                self.report.arm_error_code = 0;
                // The controller re-enters servo mode now; its reports may still read the
                // stopped state for a while.
                self.controller_ready_seen = false;
                self.tracking_bad_cycles = 0;
                let q = self.report.measured_q_rad;
                self.snap_to(now_ns, q);
                self.fresh_after_id = self.newest_plan_id_seen;
                self.io.log.log(
                    now_ns,
                    CycleEvent::Acknowledged {
                        latch_seq: latched_seq,
                    },
                );
            }
            Err(error) => {
                // Tried again next period (e.g. a full pipeline); logged once.
                if self.ack_failures == 0 {
                    self.io
                        .log
                        .log(now_ns, CycleEvent::AcknowledgeFailed { error });
                }
                self.ack_failures = self.ack_failures.saturating_add(1);
                if self.ack_failures > ACK_ATTEMPTS {
                    self.pending_ack = 0;
                    self.ack_failures = 0;
                }
            }
        }
    }

    /// One cycle at `now_ns`. Returns the mode after it.
    pub fn process(&mut self, now_ns: u64) -> Mode {
        let dt_s = self.dt_s();
        let inputs_ok = self.take_inputs(now_ns);
        self.take_revocations(now_ns);
        self.watch_separation(now_ns, dt_s);
        while let Some(p) = self.io.plans.take() {
            self.consider(now_ns, p, inputs_ok);
        }
        self.take_acknowledgement(now_ns);
        // Command: picked by the mode, then the one check before it is sent.
        match self.mode {
            Mode::Following => self.follow(now_ns, dt_s),
            Mode::Stopping => self.stop_step(now_ns, dt_s),
            Mode::Idle | Mode::Stopped => {
                self.cmd = MotionState::at_rest(self.cmd.q_rad);
            }
        }
        if self.link_ok && !self.report.awaiting_ack && self.checked(now_ns, dt_s) {
            self.send_command(now_ns);
        }
        if self.mismatch_latch_pending && matches!(self.mode, Mode::Idle | Mode::Stopped) {
            self.mismatch_latch_pending = false;
            self.latch();
        }
        self.report.shutdown_complete =
            self.io.control.shutdown_requested() && matches!(self.mode, Mode::Idle | Mode::Stopped);
        self.publish(now_ns);
        self.mode
    }

    /// The newest scene, the arm's state, the cycle's own timing and a shutdown request;
    /// returns whether they allow motion (a stop is begun where they do not).
    fn take_inputs(&mut self, now_ns: u64) -> bool {
        if let Some(s) = self.io.scenes.latest() {
            self.scene = Some(s);
        }
        let mut inputs_ok = self.read_inputs(now_ns);
        let gap_ns = now_ns.saturating_sub(self.last_cycle_ns);
        if self.last_cycle_ns != 0 && gap_ns > self.cfg.max_cycle_gap_ns {
            inputs_ok = false;
            self.on_freeze(now_ns, gap_ns);
        }
        self.last_cycle_ns = now_ns;
        let refused = self.scene.is_some_and(|s| s.refused);
        let scene_fresh = self.scene.is_some_and(|s| {
            !s.refused && now_ns.saturating_sub(s.stamp_ns) <= self.cfg.max_detection_age_ns
        });
        if !scene_fresh {
            inputs_ok = false;
            if self.mode == Mode::Following {
                let reason = if refused {
                    StopReason::DetectionRefused
                } else {
                    StopReason::StaleDetection
                };
                self.begin_stop(now_ns, reason, StopMotion::AlongPlan);
            }
        }
        if self.io.control.shutdown_requested() {
            inputs_ok = false;
            self.begin_stop(now_ns, StopReason::Shutdown, StopMotion::AlongPlan);
        }
        inputs_ok
    }

    /// The twin's revocations: a revoked pending plan is handed back, a revoked running
    /// plan stops along its path; each logged once, with the scene that caused it.
    fn take_revocations(&mut self, now_ns: u64) {
        let revoked = self.io.control.revoked_up_to();
        if self.pending.as_ref().is_some_and(|p| p.id <= revoked)
            && let Some(p) = self.pending.take()
        {
            self.log_revoked(now_ns, p.id);
            self.io.plans.give_back(p);
        }
        if self.mode == Mode::Following && self.plan.as_ref().is_some_and(|p| p.id <= revoked) {
            let plan_id = self.plan.as_ref().map_or(0, |p| p.id);
            self.log_revoked(now_ns, plan_id);
            self.begin_stop(now_ns, StopReason::Revoked, StopMotion::AlongPlan);
        }
    }

    /// Logs plan `plan_id`'s revocation with its cause's capture and acceptance times.
    fn log_revoked(&mut self, now_ns: u64, plan_id: u64) {
        let (capture_ns, accepted_ns) = self.io.control.revoke_cause();
        self.io.log.log(
            now_ns,
            CycleEvent::PlanRevoked {
                plan_id,
                capture_ns,
                accepted_ns,
            },
        );
    }

    /// Sends the checked command; a failed send is handled as the link says (a controller
    /// error, a lost connection, a command refused before the wire).
    fn send_command(&mut self, now_ns: u64) {
        match self.link.send_servo(now_ns, &self.cmd.q_rad) {
            Ok(()) => self.last_sent = self.cmd,
            Err(e) => {
                self.io.log.log(now_ns, CycleEvent::LinkError { error: e });
                if let LinkError::ControllerError(code) = e {
                    let q = self.report.measured_q_rad;
                    self.on_arm_error(now_ns, code, q);
                } else if e == LinkError::Disconnected {
                    self.link_ok = false;
                    if !self.cfg.auto_resume_after_link_loss {
                        self.latch();
                    }
                    self.begin_stop(now_ns, StopReason::LinkLost, StopMotion::AlongPlan);
                } else {
                    // Refused before the wire or pending (a full pipeline, an error bit
                    // whose code is being read): this command did not go out; stop.
                    self.report.commands_refused += 1;
                    self.begin_stop(now_ns, StopReason::LinkLost, StopMotion::AlongPlan);
                }
            }
        }
    }

    /// The one check of the command picked this cycle, against the last command sent.
    /// On a refusal it falls back — a plan sample to a brake step, a stop step to holding
    /// the last command sent — and returns whether a command passed (false: send nothing).
    fn checked(&mut self, now_ns: u64, dt_s: f64) -> bool {
        for _ in 0..3 {
            let verdict = match &self.scene {
                Some(s) => {
                    self.shield
                        .check_step(&self.last_sent.q_rad, &self.cmd.q_rad, dt_s, &s.scene)
                }
                None if self.cmd.q_rad == self.last_sent.q_rad => self
                    .shield
                    .check_motion(&self.last_sent.q_rad, &self.cmd.q_rad, dt_s)
                    .map(|()| f64::INFINITY),
                None => Err(ShieldViolation::NoScene),
            };
            let violation = match verdict {
                Ok(d) => {
                    self.report.clearance_m = d;
                    return true;
                }
                Err(v) => v,
            };
            self.report.commands_refused += 1;
            let scene_capture_ns = self.scene.map_or(0, |s| s.stamp_ns);
            self.io.log.log(
                now_ns,
                CycleEvent::CommandRefused {
                    violation,
                    scene_capture_ns,
                },
            );
            if matches!(violation, ShieldViolation::Clearance { .. })
                && matches!(self.mode, Mode::Following | Mode::Stopping)
            {
                self.report.envelope_breaches += 1;
            }
            match self.mode {
                Mode::Following => {
                    // The plan is not valid at this sample: per-joint brake from the last
                    // command sent.
                    self.cmd = self.last_sent;
                    self.begin_stop(now_ns, StopReason::Shield(violation), StopMotion::Brake);
                    self.cmd = *self.brake.step(dt_s);
                }
                _ if self.cmd.q_rad != self.last_sent.q_rad => {
                    // A stop step failed: hold the last command sent and stop there.
                    if self.mode == Mode::Stopping {
                        self.mode = Mode::Stopped;
                        self.io.log.log(now_ns, CycleEvent::Stopped);
                    }
                    self.cmd = MotionState::at_rest(self.last_sent.q_rad);
                }
                _ => return false,
            }
        }
        false
    }

    fn stop_step(&mut self, now_ns: u64, dt_s: f64) {
        let (state, stopped) = match (self.stop_motion, self.plan.as_deref()) {
            (StopMotion::AlongPlan, Some(plan)) => {
                let st = *self.path_stop.step(plan, dt_s);
                (st, self.path_stop.is_stopped())
            }
            _ => {
                let st = *self.brake.step(dt_s);
                (st, self.brake.is_stopped())
            }
        };
        self.cmd = state;
        if stopped {
            self.mode = Mode::Stopped;
            self.io.log.log(now_ns, CycleEvent::Stopped);
        }
    }

    /// One period of a plan: a scheduled plan taken at its join point, then a stop the
    /// guard scheduled (reached), the plan's end, or its next sample.
    fn follow(&mut self, now_ns: u64, dt_s: f64) {
        self.adopt_at_join(now_ns);
        let Some(plan) = self.plan.as_ref() else {
            self.mode = Mode::Idle;
            return;
        };
        // A stop the guard scheduled on this plan, no joining plan having taken over by
        // its sample: stop along the plan now (a pause, as a revocation).
        if let Some((due_id, due_index)) = self.io.control.stop_due()
            && due_id == plan.id
            && self.next >= due_index
        {
            let plan_id = plan.id;
            self.io.log.log(
                now_ns,
                CycleEvent::StopDue {
                    plan_id,
                    index: due_index,
                },
            );
            self.begin_stop(now_ns, StopReason::Revoked, StopMotion::AlongPlan);
            self.stop_step(now_ns, dt_s);
            return;
        }
        if self.next >= plan.len() {
            self.io
                .log
                .log(now_ns, CycleEvent::PlanFinished { plan_id: plan.id });
            self.mode = Mode::Idle;
            self.cmd = MotionState::at_rest(self.cmd.q_rad);
            return;
        }
        self.play_next(now_ns, dt_s);
    }

    /// Switches to the scheduled plan when the running one reached its join point.
    fn adopt_at_join(&mut self, now_ns: u64) {
        if let Some(pending) = &self.pending
            && pending.join.is_some_and(|j| j.index + 1 == self.next)
            && let Some(p) = self.pending.take()
        {
            self.report.plans_taken += 1;
            self.io.control.note_adopted(p.id);
            self.io.log.log(
                now_ns,
                CycleEvent::PlanAdopted {
                    plan_id: p.id,
                    policy_id: p.policy_id,
                },
            );
            if let Some(old) = self.plan.replace(p) {
                if self
                    .io
                    .control
                    .stop_due()
                    .is_some_and(|(id, _)| id == old.id)
                {
                    // The guard had scheduled a stop on the plan just left: the joining
                    // plan, re-verified, took over before it (issue 33 item 5).
                    self.report.joins_before_stop += 1;
                    self.io.log.log(
                        now_ns,
                        CycleEvent::JoinedBeforeStop {
                            from_plan_id: old.id,
                            plan_id: self.plan.as_ref().map_or(0, |p| p.id),
                        },
                    );
                }
                self.io.plans.give_back(old);
            }
            // The new plan's first sample is the running plan's join sample: between
            // samples (scaled playback) the arm goes on from there, not back to it.
            self.next = usize::from(self.play_frac > 0.0);
        }
    }

    /// The running plan's next command: the next sample, or during scaled playback the
    /// point the playback reached, taken when the far end of the stop envelope is clear of
    /// the live scene; otherwise a stop along the plan.
    fn play_next(&mut self, now_ns: u64, dt_s: f64) {
        let Some(plan) = self.plan.as_ref() else {
            return;
        };
        // The next sample, or during scaled playback the point between samples `k` and
        // `k + 1` (`frac` beyond `k`) the playback reached.
        let (k, frac, candidate) = self.separation.playback(plan, self.next, self.play_frac);
        // The stop envelope's far end: a stop begun now ends before it, so it must be
        // clear of the live scene (checked here one sample further each period).
        let ahead_k = k + usize::from(frac > 0.0) + self.cfg.brake_horizon_samples;
        let ahead = plan.q_rad[ahead_k.min(plan.len() - 1)];
        let ahead_ok = match &self.scene {
            // Below the clearance only when backing out from where the arm is.
            Some(s) => self
                .shield
                .check_pose_from(&self.last_sent.q_rad, &ahead, &s.scene)
                .map(|_| ()),
            None => Err(ShieldViolation::NoScene),
        };
        match ahead_ok {
            Ok(()) => {
                self.cmd = candidate;
                self.next = k + 1;
                self.play_frac = frac;
                self.play_scale = self.separation.scale();
            }
            Err(v) => {
                // The path is valid up to here: stop along it.
                self.begin_stop(now_ns, StopReason::Shield(v), StopMotion::AlongPlan);
                self.stop_step(now_ns, dt_s);
            }
        }
    }

    /// Speed and separation monitoring ([`crate::cycle::separation`]): the separation of
    /// the last command sent from the live scene's obstacles sets the playback scale of the
    /// running plan (rate-limited); a change by a step is logged. No trusted scene counts as
    /// no separation (the stale-input stop brakes meanwhile). Off, nothing is computed.
    fn watch_separation(&mut self, now_ns: u64, dt_s: f64) {
        if !self.separation.enabled() {
            return;
        }
        let (separation_m, tracked_speed_m_s) = match &self.scene {
            Some(s) if !s.refused => (
                self.shield.model_mut().intruder_distance_m(
                    &self.last_sent.q_rad,
                    &s.scene,
                    s.intruders.mask,
                ),
                s.intruders.speed_m_s,
            ),
            _ => (0.0, 0.0),
        };
        // The moving obstacles only, at the configured intruder speed or their measured
        // one when larger.
        if let Some(scale) = self
            .separation
            .update(separation_m, tracked_speed_m_s, dt_s)
        {
            self.io.log.log(now_ns, CycleEvent::SpeedScaled { scale });
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
        r.speed_scale = self.separation.scale();
        r.separation_m = self.separation.separation_m();
        match (&self.plan, self.mode) {
            (Some(p), Mode::Following) => self.io.control.set_progress(p.id, self.next),
            _ => self.io.control.set_not_following(),
        }
        let latch = r
            .awaiting_ack
            .then_some((r.latch_seq, r.stop_reason.code()));
        self.io.control.set_latched(latch);
        let report = *r;
        self.io.reports.send(report);
    }
}
