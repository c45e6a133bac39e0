//! `rt-core run` as a library function: [`serve`] is `start → run_loop → shut_down` around
//! one struct (`Runtime`): it builds the cycle and the twin worker around a robot link,
//! starts the cycle, intake and log threads, runs the twin thread's loop (iceoryx2 in, the
//! worker, iceoryx2 out) on the calling thread until a signal, the time limit, an error or a
//! panic; then it stops the arm and returns the run's figures.
//!
//! Every way out is a controlled stop: SIGINT, SIGTERM and `--seconds` request a shutdown;
//! an error or a panic of the twin loop, and the watchdog (a stalled or dead cycle thread),
//! end the loop with an error, which requests the same shutdown. The cycle then stops the
//! arm along its plan (or brakes), reports it at rest, and puts the controller in its stop
//! state (`SET_STATE 4`) before its thread ends; `serve` waits for that up to
//! [`SHUTDOWN_TIMEOUT`] and returns the error, if any (the binary then exits non-zero).
//! The operator acknowledges a protective stop through [`crate::operator_ack`]'s channel
//! (`rt-core ack`); SIGUSR1 is caught and dropped.

// Set-up and supervision of the process (not the cycle): watchdog, time limit, shutdown wait.
#![allow(clippy::disallowed_methods)]

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use policy::PolicyExpectation;
use twin::{RobotModel, Scene, TaskConfig};

use crate::config::RuntimeConfig;
use crate::cycle::brake::Brake;
use crate::cycle::link::{DryRunLink, LinkError, RobotLink};
use crate::cycle::shield::{Shield, ShieldLimits};
use crate::cycle::thread::{CycleThreadResult, spawn_cycle_thread};
use crate::cycle::twin_model::TwinModel;
use crate::cycle::{self, Cycle, CycleConfig, CycleControl, LoopShared, LoopSummary, TwinIo};
use crate::operator_ack::{AckChannelError, AckServer};
use crate::rt::clock::{Clock, MonotonicClock};
use crate::rt::histogram::Summary;
use crate::rt::rt_setup::{self, RtRequest, RtSetupReport};
use crate::twin_thread::command_log::{CommandLog, CommandLogError};
use crate::twin_thread::intake::{FrameNote, FrameRefusal, IntakeCounters, SceneIntake};
use crate::twin_thread::intake_thread::{IntakeThread, spawn_intake_thread};
use crate::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use crate::twin_thread::node::{ProductionWorker, TwinNode, TwinNodeError};
use crate::twin_thread::path_planner::TwinPathPlanner;
use crate::twin_thread::reaction::{ReactionSummary, SharedReactionMeter};
use crate::twin_thread::scene_path::ScenePath;
use crate::twin_thread::{TwinEvent, TwinWorker};

/// How the twin thread polls between events.
const POLL_PERIOD: Duration = Duration::from_micros(100);

/// The longest wait for the cycle's controlled stop at shutdown (a stop from full speed
/// takes well under a second); after it the cycle thread is told to end at once.
pub const SHUTDOWN_TIMEOUT: Duration = Duration::from_secs(3);

/// The cycle thread must beat at least this often once running, or the watchdog ends the
/// twin loop (and planning) with [`ServeError::CycleStalled`].
const WATCHDOG_TIMEOUT: Duration = Duration::from_millis(250);

/// A fault injected on purpose (tests of the exit paths; hidden `--inject-fault` flag).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InjectedFault {
    /// The twin loop panics once a plan has been followed for `after_ms`.
    TwinPanic {
        /// Time following a plan before the panic, ms.
        after_ms: u64,
    },
}

/// Why an `--inject-fault` value was refused (the command line shows the value itself).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InjectedFaultParseError {
    /// Not a fault this build knows.
    #[error("unknown fault (known: twin-panic:MS)")]
    Unknown,
    /// `twin-panic:MS` with an `MS` that is not a whole number of milliseconds.
    #[error("twin-panic:MS: MS is not a whole number of milliseconds")]
    BadAfterMs(#[from] std::num::ParseIntError),
}

impl std::str::FromStr for InjectedFault {
    type Err = InjectedFaultParseError;

    /// `twin-panic:MS`.
    fn from_str(s: &str) -> Result<Self, InjectedFaultParseError> {
        match s.split_once(':') {
            Some(("twin-panic", ms)) => Ok(InjectedFault::TwinPanic {
                after_ms: ms.parse()?,
            }),
            _ => Err(InjectedFaultParseError::Unknown),
        }
    }
}

/// What `rt-core run` was asked to do besides the configuration.
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// iceoryx2 service prefix.
    pub prefix: String,
    /// Stop after this many seconds (0 = until SIGINT/SIGTERM).
    pub seconds: f64,
    /// Blind run: no lookahead gate, no clearance in the plan check, and the cycle's shield
    /// leaves the obstacle boxes out (the table and every limit still hold). `rt-core run` allows it only on a
    /// loopback robot address (`cycle::xarm_link::check_blind_mode_target`).
    pub no_lookahead: bool,
    /// Dry run (the link withholds every command); a command log is written.
    pub dry_run: bool,
    /// The command log's path (default in dry runs: `dry_run_commands-<unix s>-<pid>.csv`).
    pub command_log: Option<PathBuf>,
    /// A policy blob file to start with.
    pub policy: Option<PathBuf>,
    /// Real-time set-up of the cycle thread.
    pub rt: RtRequest,
    /// Take fresh plans after a lost link returns without an operator's acknowledgement
    /// (simulated arms only).
    pub auto_resume: bool,
    /// A fault to inject (tests only).
    pub inject: Option<InjectedFault>,
    /// The operator's acknowledgement channel (an xArm link; `None`: protective stops are
    /// cleared by no one but the process's own caller, e.g. the in-process arm's tests).
    pub ack_channel: Option<AckChannelOptions>,
}

/// Where the operator's acknowledgement channel opens and who may use it.
#[derive(Debug, Clone, Default)]
pub struct AckChannelOptions {
    /// The socket's path ([`crate::operator_ack::socket_path`] of the arm's lock file).
    pub path: PathBuf,
    /// User ids allowed besides rt-core's own and root (`[operator] ack_uids`).
    pub extra_uids: Vec<u32>,
}

/// The figures of a finished run.
#[derive(Debug, Clone)]
pub struct ServeSummary {
    /// Cycle timing and missed deadlines.
    pub cycle: LoopSummary,
    /// What real-time set-up was granted.
    pub rt: RtSetupReport,
    /// Allocations made on the cycle thread after start-up.
    pub allocations_in_cycle: u64,
    /// Detection capture → checked and handed to the cycle's shield (the intake thread).
    pub detection_to_twin: Summary,
    /// Command lines logged.
    pub commands_logged: u64,
    /// Commands that failed the one check (not sent as picked).
    pub commands_refused: u64,
    /// Stops with an obstacle already inside the stop envelope (the unavoidable case).
    pub envelope_breaches: u64,
    /// Stops the plan guard scheduled that a joining plan made unnecessary (the arm went
    /// on without stopping).
    pub joins_before_stop: u64,
    /// Detection frames accepted and refused (per reason).
    pub intake: IntakeCounters,
    /// Reactions to a scene that made the running plan unsafe: from the causing frame's
    /// capture (and acceptance) to the first changed command ([`SharedReactionMeter`]).
    pub reaction: ReactionSummary,
    /// Reactions seen.
    pub reactions: u64,
}

impl ServeSummary {
    /// Logs the run's figures.
    pub fn log(&self) {
        let (c, age) = (&self.cycle, &self.detection_to_twin);
        tracing::info!(
            detections = age.count,
            p50_us = age.p50_us,
            p99_us = age.p99_us,
            max_us = age.max_us,
            "detection capture -> visible in the twin thread"
        );
        if self.reactions > 0 {
            let (cap, acc) = (
                &self.reaction.capture_to_command,
                &self.reaction.accepted_to_command,
            );
            tracing::info!(
                reactions = self.reactions,
                capture_p50_us = cap.p50_us,
                capture_max_us = cap.max_us,
                accepted_p50_us = acc.p50_us,
                accepted_max_us = acc.max_us,
                "reaction: causing frame -> first changed command"
            );
        }
        tracing::info!(
            accepted = self.intake.accepted,
            without_goal = self.intake.without_goal,
            refused = self.intake.total_refused(),
            "detection frames"
        );
        tracing::info!(
            cycles = c.cycles,
            missed = c.missed_deadlines,
            allocations_in_cycle = self.allocations_in_cycle,
            wake_p999_us = c.wakeup_latency_us.p999_us,
            compute_p999_us = c.cycle_compute_us.p999_us,
            rt = ?self.rt,
            "rt-core run finished"
        );
    }

    /// The run's figures as one JSON object (what the launcher's report reads).
    pub fn to_json(&self, opts: &ServeOptions) -> serde_json::Value {
        let (c, age) = (&self.cycle, &self.detection_to_twin);
        let h = |x: &Summary| serde_json::json!({"p50": x.p50_us, "p99": x.p99_us, "p999": x.p999_us, "max": x.max_us});
        serde_json::json!({
            "cycles": c.cycles,
            "missed_deadlines": c.missed_deadlines,
            "compute_overruns": c.compute_overruns,
            "allocations_in_cycle": self.allocations_in_cycle,
            "rt": self.rt,
            "wakeup_latency_us": h(&c.wakeup_latency_us),
            "cycle_compute_us": h(&c.cycle_compute_us),
            "detection_to_twin_us": {"p50": age.p50_us, "p99": age.p99_us, "max": age.max_us},
            "reactions": self.reactions,
            "reaction_capture_to_command_us": few_samples(&self.reaction.capture_to_command),
            "reaction_accepted_to_command_us": few_samples(&self.reaction.accepted_to_command),
            "dry_run": opts.dry_run,
            "lookahead_gate": !opts.no_lookahead,
            "commands_logged": self.commands_logged,
            "commands_refused": self.commands_refused,
            "envelope_breaches": self.envelope_breaches,
            "joins_before_stop": self.joins_before_stop,
            "detections_accepted": self.intake.accepted,
            "detections_without_goal": self.intake.without_goal,
            "detections_refused": FrameRefusal::NAMES
                .iter()
                .zip(self.intake.refused)
                .filter(|(_, n)| *n > 0)
                .map(|(k, n)| ((*k).to_owned(), serde_json::json!(n)))
                .collect::<serde_json::Map<_, _>>(),
        })
    }
}

/// A summary of a handful of samples (a run's reactions: one per intrusion) as JSON: the
/// count, median and maximum always; p99 only from 100 samples and p99.9 only from 1 000
/// (`null` below), so a tail percentile is never read off a few samples.
fn few_samples(x: &Summary) -> serde_json::Value {
    let tail = |q: f64, min_count: u64| (x.count >= min_count).then_some(q);
    serde_json::json!({
        "count": x.count,
        "p50": x.p50_us,
        "p99": tail(x.p99_us, 100),
        "p999": tail(x.p999_us, 1_000),
        "max": x.max_us,
    })
}

/// Why the runtime stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The task and the shield disagree on clearance.
    #[error(
        "task success.min_box_clearance_m ({task_m} m) is below the runtime's shield.min_distance_m ({shield_m} m): \
         the lookahead would pass plans the shield refuses; raise the task's clearance (and retrain) \
         or lower the shield's"
    )]
    ClearanceBelowShield {
        /// The task's clearance, m.
        task_m: f64,
        /// The shield's, m.
        shield_m: f64,
    },
    /// The arm could not be read at start.
    #[error("reading the arm: {0}")]
    ArmStart(LinkError),
    /// Signal handlers could not be installed.
    #[error("installing signal handlers: {0}")]
    Signals(std::io::Error),
    /// The operator's acknowledgement channel could not open.
    #[error("operator acknowledgement channel: {0}")]
    AckChannel(AckChannelError),
    /// A thread could not be spawned.
    #[error("spawning a thread: {0}")]
    Spawn(std::io::Error),
    /// The cycle thread panicked (the controller was put in its stop state).
    #[error("the cycle thread panicked")]
    CyclePanicked,
    /// The twin loop panicked (the arm was stopped first).
    #[error("the twin thread panicked: {0}")]
    TwinPanicked(String),
    /// The intake thread ended while the runtime ran (its error is in the log).
    #[error("the intake thread ended: no detection reaches the cycle; planning stopped")]
    IntakeEnded,
    /// The watchdog saw the cycle thread stall or end.
    #[error("watchdog: the cycle thread {0}; planning stopped")]
    CycleStalled(&'static str),
    /// The cycle did not reach rest within the shutdown timeout.
    #[error("the cycle did not stop the arm within {0:?}")]
    ShutdownTimeout(Duration),
    /// An iceoryx2 operation failed.
    #[error(transparent)]
    Node(#[from] TwinNodeError),
    /// The command log could not be written.
    #[error(transparent)]
    CommandLog(#[from] CommandLogError),
}

/// Runs the runtime on `link` until stopped; see the module docs: `Runtime::start`, then
/// `Runtime::run_loop` until a signal, the time limit, an error or a panic, then
/// `Runtime::shut_down` (the arm stops under control before anything else).
///
/// # Errors
/// [`ServeError`].
pub fn serve<L: RobotLink + 'static>(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    link: L,
) -> Result<ServeSummary, ServeError> {
    let mut run = Runtime::start(opts, cfg, model, task, link)?;
    let looped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run.run_loop()))
        .unwrap_or_else(|panic| {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(ServeError::TwinPanicked(msg))
        });
    run.shut_down(looped)
}

/// A running `rt-core run`: the cycle thread, the intake thread and the log thread started,
/// the twin thread's ends (the worker, its iceoryx2 node, the command log) on the calling
/// thread.
struct Runtime<'a, L: RobotLink + 'static> {
    opts: &'a ServeOptions,
    cfg: &'a RuntimeConfig,
    clock: MonotonicClock,
    twin: ProductionWorker,
    node: TwinNode,
    events: Vec<TwinEvent<Scene>>,
    command_log: Option<CommandLog>,
    /// The twin's model, for the published robot state's forward kinematics.
    fk: TwinModel,
    shared: Arc<LoopShared>,
    /// Ends the cycle and log threads at once (after the controlled stop, or its timeout).
    stop: Arc<AtomicBool>,
    /// SIGUSR1 seen (caught, logged and dropped).
    stray_ack_signal: Arc<AtomicBool>,
    _ack_server: Option<AckServer>,
    reactions: SharedReactionMeter,
    cycle_thread: JoinHandle<CycleThreadResult<TwinModel, L>>,
    log_thread: JoinHandle<()>,
    intake_thread: IntakeThread,
    intake_stop: Arc<AtomicBool>,
}

impl<'a, L: RobotLink + 'static> Runtime<'a, L> {
    /// Builds the cycle and the worker around `link`, installs the signal handlers and the
    /// operator's acknowledgement channel, and starts the log, intake and cycle threads.
    fn start(
        opts: &'a ServeOptions,
        cfg: &'a RuntimeConfig,
        model: RobotModel,
        task: TaskConfig,
        link: L,
    ) -> Result<Self, ServeError> {
        if task.success.min_box_clearance_m < cfg.shield.min_distance_m {
            return Err(ServeError::ClearanceBelowShield {
                task_m: task.success.min_box_clearance_m,
                shield_m: cfg.shield.min_distance_m,
            });
        }
        // The task's tool (gripper) shape counts in every distance query: the lookahead,
        // both shields and the state model all use this model.
        let model = model.with_tool(task.tool.map(|t| t.capsule()));
        let (twin_io, cycle_io, log_drain) = cycle::wire::<Scene>();
        let clock = MonotonicClock::new();
        let cyc = start_cycle(
            cfg,
            opts,
            cycle_shield(cfg, &model, opts.no_lookahead),
            link,
            cycle_io,
            &clock,
        )?;
        let (mut twin, scene_path) = build_worker(opts, cfg, &model, task, twin_io);
        let command_log = open_command_log(opts)?;
        let control = cyc.control().clone();
        let stray_ack_signal = install_signals(&control)?;
        let _ack_server = start_ack_server(opts, &control)?;
        // `stop` ends the cycle thread at once (after a controlled stop, or when it timed
        // out); a shutdown (signals, time limit, errors) goes through the cycle's
        // controlled stop.
        let stop = Arc::new(AtomicBool::new(false));
        let shared = Arc::new(LoopShared::default());
        let reactions = SharedReactionMeter::default();
        let meter = reactions.clone();
        let log_thread = log_drain
            .spawn_observed(Duration::from_millis(20), stop.clone(), move |r| {
                meter.observe(r);
            })
            .map_err(ServeError::Spawn)?;
        let (intake_thread, intake_stop, frames) =
            start_intake(opts, cfg, &task, scene_path, &clock)?;
        let (node, cleanup) = TwinNode::open(
            &opts.prefix,
            PolicyExpectation::for_task_obs(task.hash(), task.obs_dim()),
            frames,
            !opts.no_lookahead,
        )?;
        tracing::info!(?cleanup, prefix = opts.prefix, "iceoryx2 node up");
        let mut events = Vec::new();
        if let Some(path) = &opts.policy {
            node.load_policy_file(path, &mut twin, &mut events)?;
        }
        let cycle_thread = spawn_cycle_thread(cyc, clock, opts.rt, stop.clone(), shared.clone())
            .map_err(ServeError::Spawn)?;
        Ok(Self {
            opts,
            cfg,
            clock,
            twin,
            node,
            events,
            command_log,
            fk: TwinModel::new(model),
            shared,
            stop,
            stray_ack_signal,
            _ack_server,
            reactions,
            cycle_thread,
            log_thread,
            intake_thread,
            intake_stop,
        })
    }

    /// The twin thread's loop: receive, step the worker, publish, log, until a shutdown is
    /// requested or the time limit; an error or the watchdog ends it with an error.
    fn run_loop(&mut self) -> Result<(), ServeError> {
        // The twin thread polls its subscribers every 100 µs; a 1 ns timer slack keeps the
        // sleeps close to that.
        let _ = rt_setup::set_timer_slack_ns(1);
        let t0 = Instant::now();
        let control = self.twin.control().clone();
        let mut beat = (
            self.shared.heartbeat.load(Ordering::Acquire),
            Instant::now(),
        );
        let mut following_since: Option<Instant> = None;
        while !control.shutdown_requested() {
            if self.opts.seconds > 0.0 && t0.elapsed().as_secs_f64() >= self.opts.seconds {
                tracing::info!(seconds = self.opts.seconds, "time limit: stopping the arm");
                break;
            }
            self.watch_threads(&mut beat)?;
            if self.stray_ack_signal.swap(false, Ordering::AcqRel) {
                tracing::warn!(
                    "SIGUSR1 ignored: it acknowledges nothing (any process of this user can send \
                     it, and it names no stop); acknowledge with `rt-core ack --robot HOST`"
                );
            }
            self.node.receive(&mut self.twin, &mut self.events)?;
            self.twin.step(&mut self.events);
            let now = self.clock.now_ns();
            self.node
                .publish_events(&mut self.events, now, self.cfg.rate_hz)?;
            if let (Some(log), Some(r)) = (self.command_log.as_mut(), self.twin.last_report()) {
                log.record(r)?;
            }
            self.node
                .publish_state(self.twin.last_report(), &self.shared, &mut self.fk, now)?;
            if let Some(InjectedFault::TwinPanic { after_ms }) = self.opts.inject {
                let following = self
                    .twin
                    .last_report()
                    .is_some_and(|r| r.mode == cycle::Mode::Following);
                match (following, following_since) {
                    (true, None) => following_since = Some(Instant::now()),
                    (true, Some(t)) if t.elapsed() >= Duration::from_millis(after_ms) => {
                        panic!("injected fault: twin-thread panic {after_ms} ms into a plan")
                    }
                    _ => {}
                }
            }
            std::thread::sleep(POLL_PERIOD);
        }
        Ok(())
    }

    /// The watchdog: a cycle thread that has ended or stopped beating (`beat`: its last
    /// heartbeat and when it changed), or an intake thread that has ended, ends the loop.
    fn watch_threads(&self, beat: &mut (u64, Instant)) -> Result<(), ServeError> {
        if self.shared.finished.load(Ordering::Acquire) {
            return Err(ServeError::CycleStalled("has ended"));
        }
        if self.intake_thread.is_finished() {
            // No scene reaches the cycle any more (it would stop on stale detections).
            return Err(ServeError::IntakeEnded);
        }
        let now_beat = self.shared.heartbeat.load(Ordering::Acquire);
        if now_beat != beat.0 {
            *beat = (now_beat, Instant::now());
        } else if now_beat > 0 && beat.1.elapsed() > WATCHDOG_TIMEOUT {
            return Err(ServeError::CycleStalled("stopped beating"));
        }
        Ok(())
    }

    /// Whatever ended the loop (`looped`), the arm stops under control before anything
    /// else: a shutdown is requested and waited for up to [`SHUTDOWN_TIMEOUT`] (the robot
    /// state still published), then the threads end and the run's figures are gathered.
    fn shut_down(mut self, looped: Result<(), ServeError>) -> Result<ServeSummary, ServeError> {
        self.twin.control().request_shutdown();
        if let Err(e) = &looped {
            tracing::error!(error = %e, "stopping the arm under control before exiting");
        }
        let deadline = Instant::now() + SHUTDOWN_TIMEOUT;
        while !self.cycle_thread.is_finished() && Instant::now() < deadline {
            self.twin.take_reports();
            let now = self.clock.now_ns();
            let _ =
                self.node
                    .publish_state(self.twin.last_report(), &self.shared, &mut self.fk, now);
            std::thread::sleep(Duration::from_millis(2));
        }
        let timed_out = !self.cycle_thread.is_finished();
        self.stop.store(true, Ordering::Release);
        if timed_out {
            // A stalled cycle thread: give it a moment to see `stop`, then leave without it
            // (the process exit ends it; the controller stops streaming).
            let grace = Instant::now() + Duration::from_secs(1);
            while !self.cycle_thread.is_finished() && Instant::now() < grace {
                std::thread::sleep(Duration::from_millis(5));
            }
            if !self.cycle_thread.is_finished() {
                let _ = self.log_thread.join();
                return Err(looped
                    .err()
                    .unwrap_or(ServeError::ShutdownTimeout(SHUTDOWN_TIMEOUT)));
            }
        }
        let commands_logged = match self.command_log.take() {
            Some(log) => log.finish(),
            None => Ok(0),
        };
        let done = self
            .cycle_thread
            .join()
            .map_err(|_| ServeError::CyclePanicked);
        // The arm is at rest: the intake thread may end.
        self.intake_stop.store(true, Ordering::Release);
        let intake_figures = self.intake_thread.join();
        // The cycle's last report (at rest) goes out before the exit.
        self.twin.take_reports();
        let now = self.clock.now_ns();
        let _ =
            self.node
                .publish_final_state(self.twin.last_report(), &self.shared, &mut self.fk, now);
        let _ = self.log_thread.join();
        looped?;
        let done = done?;
        if timed_out {
            return Err(ServeError::ShutdownTimeout(SHUTDOWN_TIMEOUT));
        }
        let intake_figures = intake_figures?;
        let r = done.cycle.report();
        tracing::info!(
            stops = r.stops,
            commands_refused = r.commands_refused,
            envelope_breaches = r.envelope_breaches,
            arm_error_code = r.arm_error_code,
            "the arm is at rest; controller stop state requested"
        );
        let (reaction, reactions) = self.reactions.summary();
        Ok(ServeSummary {
            cycle: done.stats.summary(),
            rt: done.rt,
            allocations_in_cycle: done.allocations,
            detection_to_twin: intake_figures.detection_age,
            commands_logged: commands_logged?,
            commands_refused: r.commands_refused,
            envelope_breaches: r.envelope_breaches,
            joins_before_stop: r.joins_before_stop,
            intake: intake_figures.counters,
            reaction,
            reactions,
        })
    }
}

/// The twin worker of `rt-core run` and its scene path: the lookahead (blind with
/// `--no-lookahead`, verified sampling when configured), the plan check, and the planner
/// fallback when configured.
fn build_worker(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    model: &RobotModel,
    task: TaskConfig,
    twin_io: TwinIo<Scene>,
) -> (ProductionWorker, ScenePath<TwinModel>) {
    if opts.no_lookahead {
        tracing::warn!(
            "--no-lookahead: plans run whatever the lookahead says; the cycle's shield leaves the \
             obstacle boxes out of its clearance (the table and every limit still hold)"
        );
    }
    let planner = (cfg.planner_fallback.enabled && !opts.no_lookahead)
        .then(|| TwinPathPlanner::new(model.clone(), task, cfg));
    let mut lookahead = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
    lookahead.blind = opts.no_lookahead;
    if cfg.sampling.enabled && !opts.no_lookahead {
        lookahead.set_sampling(Some(cfg.sampling.settings()));
        tracing::info!(
            candidates = cfg.sampling.candidates,
            budget_s = cfg.sampling.budget_s,
            threads = cfg.sampling.threads,
            "verified sampling on: when no policy's rollout passes, perturbed variants are \
             rolled out and verified before the planner fallback"
        );
    }
    let (mut twin, scene_path) = TwinWorker::new(
        cfg,
        lookahead,
        plan_shield(cfg, model, opts.no_lookahead),
        twin_io,
    );
    if opts.no_lookahead {
        twin.disable_lookahead_gate();
    }
    if let Some(planner) = planner {
        tracing::info!(
            budget_s = cfg.planner_fallback.budget_s,
            "planner fallback on: when no policy passes, the planner's checked path moves the arm"
        );
        twin.set_fallback_planner(Box::new(planner));
    }
    (twin, scene_path)
}

/// The command log: `opts.command_log`, or `dry_run_commands-<unix s>-<pid>.csv` in a dry run; none
/// otherwise.
fn open_command_log(opts: &ServeOptions) -> Result<Option<CommandLog>, ServeError> {
    Ok(match (&opts.command_log, opts.dry_run) {
        (Some(p), _) => Some(CommandLog::create(p)?),
        (None, true) => {
            // A name of its own per run: a log never replaces another.
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            let name = format!("dry_run_commands-{secs}-{}.csv", std::process::id());
            Some(CommandLog::create(std::path::Path::new(&name))?)
        }
        (None, false) => None,
    })
}

/// The operator's acknowledgement channel, when `opts.ack_channel` asks for one.
fn start_ack_server(
    opts: &ServeOptions,
    control: &Arc<CycleControl>,
) -> Result<Option<AckServer>, ServeError> {
    match &opts.ack_channel {
        Some(a) => AckServer::start(a.path.clone(), control.clone(), a.extra_uids.clone())
            .map(Some)
            .map_err(ServeError::AckChannel),
        None => Ok(None),
    }
}

/// SIGINT and SIGTERM request the cycle's controlled stop; SIGUSR1 (the acknowledgement of
/// earlier versions) clears nothing: any process of the same user can send it and it names
/// no stop. It is caught, and the returned flag set, to be logged and dropped; the operator
/// acknowledges through the channel beside the arm's lock (`rt-core ack`).
fn install_signals(control: &CycleControl) -> Result<Arc<AtomicBool>, ServeError> {
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, control.shutdown_flag()).map_err(ServeError::Signals)?;
    }
    let stray_ack_signal = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, stray_ack_signal.clone())
        .map_err(ServeError::Signals)?;
    Ok(stray_ack_signal)
}

/// Starts the intake thread: detections go their own way — each accepted scene to the
/// cycle and the plan guard on `scene_path`, then noted to the twin thread for planning
/// (the returned receiver). Returns the thread and its stop flag too.
fn start_intake(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    task: &TaskConfig,
    scene_path: ScenePath<TwinModel>,
    clock: &MonotonicClock,
) -> Result<(IntakeThread, Arc<AtomicBool>, mpsc::Receiver<FrameNote>), ServeError> {
    let mut intake = SceneIntake::new(
        cfg.intake,
        (cfg.stale.max_detection_age_s * 1e9) as u64,
        task.sampling.table_height_m,
        clock.origin_ns(),
    )
    .with_covered_age_s(cfg.separation.reaction_time_s);
    if cfg.goal.source == crate::config::GoalSource::Action {
        intake = intake.with_requested_goals(cfg.goal_bounds(), task.success.goal_hover_m);
    }
    let (frame_notes, frames) = mpsc::channel();
    scene_path.set_clock_origin(clock.origin_ns());
    let intake_stop = Arc::new(AtomicBool::new(false));
    let intake_thread = spawn_intake_thread(
        &opts.prefix,
        intake,
        scene_path,
        frame_notes,
        intake_stop.clone(),
    )?;
    Ok((intake_thread, intake_stop, frames))
}

/// The cycle's shield in `rt-core run`, the check of every command sent: the configured
/// limits over the twin's model. `blind` (`--no-lookahead`) leaves the obstacle boxes out
/// of the clearance ([`TwinModel::with_boxes_ignored`]); the table clearance, the joint,
/// workspace and speed limits still hold.
pub fn cycle_shield(cfg: &RuntimeConfig, model: &RobotModel, blind: bool) -> Shield<TwinModel> {
    Shield::new(
        TwinModel::new(model.clone()).with_boxes_ignored(blind),
        ShieldLimits::from_config(&cfg.limits, &cfg.shield),
    )
}

/// The twin worker's plan check in `rt-core run` (before approval, and again when the
/// scene changes): the cycle's shield, except that `blind` (`--no-lookahead`) turns its
/// clearance off altogether, so that a blind plan starts whatever the twin says of it (the
/// demonstration); the cycle's shield ([`cycle_shield`]) still stops it at the table or a
/// limit.
pub fn plan_shield(cfg: &RuntimeConfig, model: &RobotModel, blind: bool) -> Shield<TwinModel> {
    let mut limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    if blind {
        limits.min_distance_m = f64::NEG_INFINITY;
    }
    Shield::new(TwinModel::new(model.clone()), limits)
}

/// [`serve`] on `link`, wrapped in a [`DryRunLink`] that withholds every command when
/// `opts.dry_run`.
///
/// # Errors
/// [`ServeError`].
pub fn serve_on<L: RobotLink + 'static>(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    link: L,
) -> Result<ServeSummary, ServeError> {
    if opts.dry_run {
        serve(opts, cfg, model, task, DryRunLink::new(link))
    } else {
        serve(opts, cfg, model, task, link)
    }
}

/// Builds the cycle and reads the arm once (a real link's first report may take a few
/// cycles to arrive).
fn start_cycle<L: RobotLink>(
    cfg: &RuntimeConfig,
    opts: &ServeOptions,
    shield: Shield<TwinModel>,
    link: L,
    cycle_io: cycle::CycleIo<Scene>,
    clock: &MonotonicClock,
) -> Result<Cycle<TwinModel, L>, ServeError> {
    let mut cycle_cfg = CycleConfig::from_runtime(cfg);
    cycle_cfg.auto_resume_after_link_loss = opts.auto_resume;
    let mut cyc = Cycle::new(cycle_cfg, shield, Brake::new(&cfg.limits), link, cycle_io);
    let mut started = cyc.start(clock.now_ns());
    for _ in 0..200 {
        if started.is_ok() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
        started = cyc.start(clock.now_ns());
    }
    started.map_err(ServeError::ArmStart)?;
    Ok(cyc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_few_reactions_give_no_tail_percentile() {
        let s = |count| Summary {
            count,
            p50_us: 1.0,
            p99_us: 2.0,
            p999_us: 3.0,
            max_us: 4.0,
        };
        let one = few_samples(&s(16));
        assert_eq!(one["count"], 16);
        assert_eq!(one["p50"], 1.0);
        assert_eq!(one["max"], 4.0);
        assert!(one["p99"].is_null() && one["p999"].is_null(), "{one}");
        let many = few_samples(&s(150));
        assert_eq!(many["p99"], 2.0);
        assert!(many["p999"].is_null(), "{many}");
        assert_eq!(few_samples(&s(1_000))["p999"], 3.0);
    }
}
