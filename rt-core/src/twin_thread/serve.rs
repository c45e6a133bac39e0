//! `rt-core run` as a library function: [`serve`] builds the cycle and the twin worker
//! around a robot link, starts the cycle thread, and runs the twin thread's loop (iceoryx2
//! in, the worker, iceoryx2 out) on the calling thread until a signal, the time limit or an
//! error; then it stops the cycle thread and returns the run's figures.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use twin::{RobotModel, Scene, TaskConfig};

use crate::config::RuntimeConfig;
use crate::cycle::brake::Brake;
use crate::cycle::link::{DryRunLink, LinkError, RobotLink};
use crate::cycle::shield::{Shield, ShieldLimits};
use crate::cycle::thread::spawn_cycle_thread;
use crate::cycle::twin_model::TwinModel;
use crate::cycle::{self, Cycle, CycleConfig, LoopShared, LoopSummary};
use crate::rt::clock::{Clock, MonotonicClock};
use crate::rt::histogram::Summary;
use crate::rt::rt_setup::{self, RtRequest, RtSetupReport};
use crate::twin_thread::command_log::{CommandLog, CommandLogError};
use crate::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use crate::twin_thread::node::{ProductionWorker, TwinNode, TwinNodeError};
use crate::twin_thread::{TwinEvent, TwinWorker};

/// How the twin thread polls between events.
const POLL_PERIOD: Duration = Duration::from_micros(100);

/// What `rt-core run` was asked to do besides the configuration.
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// iceoryx2 service prefix.
    pub prefix: String,
    /// Stop after this many seconds (0 = until SIGINT/SIGTERM).
    pub seconds: f64,
    /// Blind run: no lookahead gate, no clearance check.
    pub no_lookahead: bool,
    /// Dry run (the link withholds every command); a command log is written.
    pub dry_run: bool,
    /// The command log's path (default in dry runs: `dry_run_commands.csv`).
    pub command_log: Option<PathBuf>,
    /// A policy blob file to start with.
    pub policy: Option<PathBuf>,
    /// Real-time set-up of the cycle thread.
    pub rt: RtRequest,
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
    /// Detection capture → visible in the twin thread.
    pub detection_to_twin: Summary,
    /// Command lines logged.
    pub commands_logged: u64,
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
            "wakeup_latency_us": h(&c.wakeup_latency_us),
            "cycle_compute_us": h(&c.cycle_compute_us),
            "detection_to_twin_us": {"p50": age.p50_us, "p99": age.p99_us, "max": age.max_us},
            "dry_run": opts.dry_run,
            "lookahead_gate": !opts.no_lookahead,
            "commands_logged": self.commands_logged,
        })
    }
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
    /// A thread could not be spawned.
    #[error("spawning a thread: {0}")]
    Spawn(std::io::Error),
    /// The cycle thread panicked.
    #[error("the cycle thread panicked")]
    CyclePanicked,
    /// An iceoryx2 operation failed.
    #[error(transparent)]
    Node(#[from] TwinNodeError),
    /// The command log could not be written.
    #[error(transparent)]
    CommandLog(#[from] CommandLogError),
}

/// Runs the runtime on `link` until stopped; see the module docs.
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
    if task.success.min_box_clearance_m < cfg.shield.min_distance_m {
        return Err(ServeError::ClearanceBelowShield {
            task_m: task.success.min_box_clearance_m,
            shield_m: cfg.shield.min_distance_m,
        });
    }
    let mut limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    if opts.no_lookahead {
        tracing::warn!(
            "--no-lookahead: plans run whatever the lookahead says, and the shield's clearance check is off"
        );
        limits.min_distance_m = f64::NEG_INFINITY;
    }
    let task_hash = task.hash();
    let table_height_m = task.sampling.table_height_m;
    let mut lookahead = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
    lookahead.blind = opts.no_lookahead;
    let (twin_io, cycle_io, log_drain) = cycle::wire::<Scene>();
    let clock = MonotonicClock::new();
    let cyc = start_cycle(cfg, &model, limits, link, cycle_io, &clock)?;
    let mut twin = TwinWorker::new(
        cfg,
        lookahead,
        Shield::new(TwinModel::new(model.clone()), limits),
        twin_io,
    );
    if opts.no_lookahead {
        twin.disable_lookahead_gate();
    }
    let mut command_log = match (&opts.command_log, opts.dry_run) {
        (Some(p), _) => Some(CommandLog::create(p)?),
        (None, true) => Some(CommandLog::create(std::path::Path::new(
            "dry_run_commands.csv",
        ))?),
        (None, false) => None,
    };
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).map_err(ServeError::Signals)?;
    }
    let shared = Arc::new(LoopShared::default());
    let log_thread = log_drain
        .spawn(Duration::from_millis(20), stop.clone())
        .map_err(ServeError::Spawn)?;
    let (mut node, cleanup) =
        TwinNode::open(&opts.prefix, task_hash, table_height_m, !opts.no_lookahead)?;
    tracing::info!(?cleanup, prefix = opts.prefix, "iceoryx2 node up");
    let mut events = Vec::new();
    if let Some(path) = &opts.policy {
        node.load_policy_file(path, &mut twin, &mut events)?;
    }
    let cycle_thread = spawn_cycle_thread(cyc, clock, opts.rt, stop.clone(), shared.clone())
        .map_err(ServeError::Spawn)?;
    let mut fk = TwinModel::new(model);
    let looped = twin_loop(
        opts,
        cfg,
        clock,
        &mut node,
        &mut twin,
        &mut command_log,
        &mut fk,
        &shared,
        &stop,
        &mut events,
    );
    stop.store(true, Ordering::Release);
    let commands_logged = match command_log.take() {
        Some(log) => log.finish()?,
        None => 0,
    };
    let done = cycle_thread.join().map_err(|_| ServeError::CyclePanicked)?;
    let _ = log_thread.join();
    looped?;
    Ok(ServeSummary {
        cycle: done.stats.summary(),
        rt: done.rt,
        allocations_in_cycle: done.allocations,
        detection_to_twin: node.detection_age(),
        commands_logged,
    })
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
    model: &RobotModel,
    limits: ShieldLimits,
    link: L,
    cycle_io: cycle::CycleIo<Scene>,
    clock: &MonotonicClock,
) -> Result<Cycle<TwinModel, L>, ServeError> {
    let mut cyc = Cycle::new(
        CycleConfig::from_runtime(cfg),
        Shield::new(TwinModel::new(model.clone()), limits),
        Brake::new(&cfg.limits),
        link,
        cycle_io,
    );
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

/// The twin thread's loop: receive, step the worker, publish, log, until `stop` or the
/// time limit.
#[allow(clippy::too_many_arguments)]
fn twin_loop(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    clock: MonotonicClock,
    node: &mut TwinNode,
    twin: &mut ProductionWorker,
    command_log: &mut Option<CommandLog>,
    fk: &mut TwinModel,
    shared: &LoopShared,
    stop: &AtomicBool,
    events: &mut Vec<TwinEvent<Scene>>,
) -> Result<(), ServeError> {
    // The twin thread polls its subscribers every 100 µs; a 1 ns timer slack keeps the
    // sleeps close to that.
    let _ = rt_setup::set_timer_slack_ns(1);
    let t0 = Instant::now();
    while !stop.load(Ordering::Acquire) {
        if opts.seconds > 0.0 && t0.elapsed().as_secs_f64() >= opts.seconds {
            break;
        }
        node.receive(twin, clock.now_ns(), events)?;
        twin.step(events);
        let now = clock.now_ns();
        node.publish_events(events, now, cfg.rate_hz)?;
        if let (Some(log), Some(r)) = (command_log.as_mut(), twin.last_report()) {
            log.record(r)?;
        }
        node.publish_state(twin.last_report(), shared, fk, now)?;
        std::thread::sleep(POLL_PERIOD);
    }
    Ok(())
}
