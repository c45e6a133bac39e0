//! `rt-core run --config FILE`: the runtime. A twin thread (iceoryx2 I/O, scene sync,
//! lookahead, verdicts, plan approval, retrain requests) and a cycle thread (real-time
//! set-up, the control cycle at the configured rate) around a robot link: `--link sim`
//! (the in-process simulated arm) or `--link xarm --robot HOST` (the xArm driver: a real
//! xArm5 or `xarm-sim`).
//!
//! iceoryx2 services (all under the config's `service_prefix`): subscribes to
//! `DetectionFrame` and `PolicyBlob`; publishes `RobotState` (every 4 ms), `TwinVerdict`
//! (every lookahead) and `RetrainRequest` (every failed lookahead). Stops on SIGINT/SIGTERM
//! or after `--seconds`.
//!
//! `--dry-run` computes and logs every command and sends none; `--no-lookahead` runs the
//! policy blind (no lookahead gate, no clearance shield) to show what Foresight prevents.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Args, ValueEnum};
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use rt_core::policy::{PolicyExpectation, PolicyLoader};
use rt_core::runtime::clock::{Clock, MonotonicClock};
use rt_core::runtime::config::RuntimeConfig;
use rt_core::runtime::cycle::{
    self, Cycle, CycleConfig, CycleReport, LoopShared, Mode, StopReason,
};
use rt_core::runtime::cycle_thread::spawn_cycle_thread;
use rt_core::runtime::histogram::Histogram;
use rt_core::runtime::link::{DryRunLink, InProcessArm, RobotLink};
use rt_core::runtime::rt_setup;
use rt_core::runtime::shield::{Shield, ShieldLimits, ShieldModel};
use rt_core::runtime::smoothing::Brake;
use rt_core::runtime::twin_adapter::{LookaheadActions, SceneSnapshot, TwinLookahead, TwinModel};
use rt_core::runtime::twin_thread::{TwinEvent, TwinWorker, Verdict};
use rt_core::twin::{BoxObstacle, Goal, MAX_OBSTACLES, RobotModel, Scene, TaskConfig};
use rt_core::xarm::driver::{XArmConfig, XArmDriver};
use shm_schemas::services::{create_node, loan_zeroed, open_publisher, open_subscriber};
use shm_schemas::{
    DetectionFrame, EpisodeEnd, ObjectClass, ObstacleBox, PolicyBlob, RetrainRequest, RobotState,
    TwinVerdict,
};

use super::bench_loop::load_assets;

/// Which robot link the cycle drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LinkKind {
    /// The in-process simulated arm.
    Sim,
    /// A real xArm5 (or xarm-sim) over TCP (`--robot HOST`).
    Xarm,
}

/// Arguments of `run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Runtime configuration (TOML).
    #[arg(long, default_value = "assets/runtime.toml")]
    config: PathBuf,
    /// Folder with xarm5.urdf and task.toml.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Robot link.
    #[arg(long, value_enum, default_value_t = LinkKind::Sim)]
    link: LinkKind,
    /// Robot address for `--link xarm`.
    #[arg(long)]
    robot: Option<String>,
    /// Real-time set-up of the cycle thread.
    #[command(flatten)]
    rt: super::RtArgs,
    /// Stop after this many seconds (0 = until SIGINT/SIGTERM).
    #[arg(long, default_value_t = 0.0)]
    seconds: f64,
    /// Service-name prefix (overrides the config's `service_prefix`; the launcher gives
    /// every run a unique one).
    #[arg(long)]
    prefix: Option<String>,
    /// Report port of the arm for `--link xarm` (default: the real controller's 30003).
    #[arg(long)]
    report_port: Option<u16>,
    /// A policy blob file to start with (e.g. assets/policy/policy.blob); it is validated
    /// and must pass the lookahead like any policy the learner sends.
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Blind run: execute the policy's plans whatever the lookahead says and without the
    /// shield's clearance check (joint, workspace and speed limits still hold). This is the
    /// demonstration of what Foresight prevents; never use it on a real arm near people.
    #[arg(long)]
    no_lookahead: bool,
    /// Dry run: read the arm, run everything, compute every command, and send none (the
    /// arm's mode is left as it is). Commands are logged to `--command-log`.
    #[arg(long)]
    dry_run: bool,
    /// CSV log of the commands computed while following a plan (`t_ns,cycle,plan_id,q0..q4`
    /// in rad); written in dry runs, or whenever given.
    #[arg(long)]
    command_log: Option<PathBuf>,
}

/// Runs the runtime.
pub fn run(args: RunArgs) -> ExitCode {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
    match runtime(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("rt-core run: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Scene snapshot from a detection frame: goal and obstacles, positions snapped to a 5 mm
/// grid so sensor noise does not count as a scene change (a change re-runs the lookahead).
fn scene_from_detection(
    frame: &DetectionFrame,
    table_height_m: f64,
    last_goal: &mut Goal,
) -> SceneSnapshot {
    let snap = |v: f32| (f64::from(v) / 0.005).round() * 0.005;
    let mut scene = Scene::empty(table_height_m, *last_goal);
    for o in frame.objects() {
        let center_m = [
            snap(o.center_m[0]),
            snap(o.center_m[1]),
            snap(o.center_m[2]),
        ];
        let size_m = [snap(o.size_m[0]), snap(o.size_m[1]), snap(o.size_m[2])];
        match o.class() {
            Ok(ObjectClass::Goal) => {
                *last_goal = Goal {
                    center_m,
                    size_m: size_m[0].max(0.005),
                };
                scene.goal = *last_goal;
            }
            Ok(ObjectClass::Obstacle) => {
                if scene.obstacles.len() < MAX_OBSTACLES {
                    // Snap the top and the bottom (not the centre and the height): a box
                    // standing on the table must not reach below it after rounding, or the
                    // learner would refuse the scene of a retrain request.
                    let top = snap(o.center_m[2] + o.size_m[2] / 2.0);
                    let bottom = snap(o.center_m[2] - o.size_m[2] / 2.0).max(table_height_m);
                    let height = (top - bottom).max(0.005);
                    let _ = scene.obstacles.push(BoxObstacle {
                        center_m: [center_m[0], center_m[1], bottom + height / 2.0],
                        size_m: [size_m[0].max(0.005), size_m[1].max(0.005), height],
                    });
                }
            }
            Err(_) => {}
        }
    }
    SceneSnapshot::from_scene(&scene)
}

fn stop_code(reason: StopReason) -> shm_schemas::StopReason {
    use shm_schemas::StopReason as S;
    match reason {
        StopReason::None => S::None,
        StopReason::Shield(_) | StopReason::Revoked => S::ShieldViolation,
        StopReason::StaleDetection => S::StaleDetections,
        StopReason::StaleRobotState => S::StaleRobotState,
        StopReason::LinkLost => S::LinkLost,
    }
}

/// The published verdict; with the lookahead gate off (`--no-lookahead`) every plan goes
/// to the arm, so every verdict reads approved.
fn twin_verdict(
    v: &Verdict,
    id: u64,
    seq: u64,
    now_ns: u64,
    elapsed_s: f64,
    gate: bool,
) -> TwinVerdict {
    let mut t = TwinVerdict {
        verdict_id: id,
        scene_sequence: seq,
        policy_id: v.policy_id,
        computed_time_ns: now_ns,
        min_distance_m: v.min_distance_m.clamp(-10.0, 10.0),
        episode_return: 0.0,
        steps: v.steps,
        lookahead_compute_us: (elapsed_s * 1e6).min(f64::from(u32::MAX)) as u32,
        episode_end: if v.task_ok {
            EpisodeEnd::Success as u8
        } else if !v.safe {
            EpisodeEnd::Collision as u8
        } else {
            EpisodeEnd::Timeout as u8
        },
        ..TwinVerdict::default()
    };
    t.set_flags(v.task_ok, v.safe, (v.task_ok && v.safe) || !gate);
    t
}

fn runtime(args: &RunArgs) -> anyhow::Result<()> {
    let (cfg, model, task) = load_assets(&args.assets, None, Some(&args.config))?;
    match args.link {
        LinkKind::Sim => {
            let arm = InProcessArm::new(
                task.start.joints_rad,
                cfg.limits.joint_min_rad,
                cfg.limits.joint_max_rad,
                [std::f64::consts::PI; 5],
            );
            if args.dry_run {
                return serve(args, cfg, model, task, DryRunLink::new(arm));
            }
            serve(args, cfg, model, task, arm)
        }
        LinkKind::Xarm => {
            let host = args
                .robot
                .as_deref()
                .context("--link xarm needs --robot HOST")?;
            let mut xarm_cfg = XArmConfig::from_addr(host);
            if let Some(port) = args.report_port {
                xarm_cfg.report_port = port;
            }
            let mut driver = XArmDriver::connect(xarm_cfg)
                .map_err(|e| anyhow::anyhow!("connecting to the xArm at {host}: {e:?}"))?;
            // A lost link is re-opened by a helper thread: the cycle never blocks on it.
            driver
                .reconnect_off_cycle()
                .context("starting the xArm reconnect helper")?;
            if args.dry_run {
                tracing::warn!(
                    host,
                    "dry run: the arm's mode is left as it is; no command is sent"
                );
                return serve(args, cfg, model, task, DryRunLink::new(driver));
            }
            let q = driver
                .start_servo_mode()
                .map_err(|e| anyhow::anyhow!("entering servo mode: {e:?}"))?;
            tracing::info!(host, joints_rad = ?q, "xArm in servo mode");
            serve(args, cfg, model, task, driver)
        }
    }
}

fn serve<L: RobotLink + 'static>(
    args: &RunArgs,
    cfg: RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    link: L,
) -> anyhow::Result<()> {
    if task.success.min_box_clearance_m < cfg.shield.min_distance_m {
        anyhow::bail!(
            "task success.min_box_clearance_m ({} m) is below the runtime's shield.min_distance_m ({} m): \
             the lookahead would pass plans the shield refuses; raise the task's clearance (and retrain) \
             or lower the shield's",
            task.success.min_box_clearance_m,
            cfg.shield.min_distance_m
        );
    }
    let mut limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    if args.no_lookahead {
        tracing::warn!(
            "--no-lookahead: plans run whatever the lookahead says, and the shield's clearance check is off"
        );
        limits.min_distance_m = f64::NEG_INFINITY;
    }
    let task_hash = task.hash();
    let table_height_m = task.sampling.table_height_m;
    let mut lookahead = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
    lookahead.blind = args.no_lookahead;
    let (twin_io, cycle_io, log_drain) = cycle::wire::<SceneSnapshot>();
    let clock = MonotonicClock::new();
    let mut cyc = Cycle::new(
        CycleConfig::from_runtime(&cfg),
        Shield::new(TwinModel::new(model.clone()), limits),
        Brake::new(&cfg.limits),
        link,
        cycle_io,
    );
    // The first report of a real link may take a few cycles to arrive.
    let mut started = cyc.start(clock.now_ns());
    for _ in 0..200 {
        if started.is_ok() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
        started = cyc.start(clock.now_ns());
    }
    started.map_err(|e| anyhow::anyhow!("reading the arm: {e}"))?;
    let mut twin = TwinWorker::new(
        &cfg,
        lookahead,
        Shield::new(TwinModel::new(model.clone()), limits),
        twin_io,
    );
    if args.no_lookahead {
        twin.disable_lookahead_gate();
    }
    let mut fk = TwinModel::new(model);
    let mut command_log = match (&args.command_log, args.dry_run) {
        (Some(p), _) => Some(CommandLog::create(p)?),
        (None, true) => Some(CommandLog::create(std::path::Path::new(
            "dry_run_commands.csv",
        ))?),
        (None, false) => None,
    };

    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).context("installing signal handlers")?;
    }
    let shared = Arc::new(LoopShared::default());
    let log_thread = log_drain.spawn(Duration::from_millis(20), stop.clone())?;

    // iceoryx2 I/O (twin thread = this thread).
    let prefix = args
        .prefix
        .clone()
        .unwrap_or_else(|| cfg.service_prefix.clone());
    let (node, cleanup) =
        create_node::<ipc::Service>("rt-core").context("creating the iceoryx2 node")?;
    tracing::info!(?cleanup, prefix, "iceoryx2 node up");
    let det_sub = open_subscriber::<DetectionFrame, _>(&node, &prefix).context("detections")?;
    let pol_sub = open_subscriber::<PolicyBlob, _>(&node, &prefix).context("policies")?;
    let state_pub = open_publisher::<RobotState, _>(&node, &prefix).context("robot state")?;
    let verdict_pub = open_publisher::<TwinVerdict, _>(&node, &prefix).context("verdicts")?;
    let retrain_pub =
        open_publisher::<RetrainRequest, _>(&node, &prefix).context("retrain requests")?;
    let loader = PolicyLoader::new(PolicyExpectation::for_task(task_hash));
    if let Some(path) = &args.policy {
        let bytes =
            std::fs::read(path).with_context(|| format!("reading policy {}", path.display()))?;
        let blob = PolicyBlob::from_bytes(&bytes)
            .map_err(|e| anyhow::anyhow!("policy {} is invalid: {e}", path.display()))?;
        let policy = loader
            .prepare(&blob)
            .map_err(|e| anyhow::anyhow!("policy {} rejected: {e:?}", path.display()))?;
        tracing::info!(policy_id = policy.policy_id(), path = %path.display(), "start policy loaded; it must pass the lookahead");
        let mut start_events = Vec::new();
        twin.on_policy(Box::new(policy), &mut start_events);
    }

    // Cycle thread.
    let req = args.rt.request();
    let cycle_thread = spawn_cycle_thread(cyc, clock, req, stop.clone(), shared.clone())?;

    // The twin thread polls its subscribers every 100 µs; a 1 ns timer slack keeps the
    // sleeps close to that.
    let _ = rt_setup::set_timer_slack_ns(1);
    let t0 = Instant::now();
    let mut events = Vec::new();
    let mut last_goal = Scene::empty(
        table_height_m,
        Goal {
            center_m: [0.35, 0.0, table_height_m + 0.025],
            size_m: 0.05,
        },
    )
    .goal;
    let (mut verdict_id, mut scene_seq, mut last_state_ns) = (0u64, 0u64, 0u64);
    let mut last_cycles = 0;
    let mut detection_age = Histogram::new();
    let mut last_connections_update = Instant::now();
    while !stop.load(Ordering::Acquire) {
        if args.seconds > 0.0 && t0.elapsed().as_secs_f64() >= args.seconds {
            break;
        }
        while let Some(sample) = det_sub.receive().context("receiving detections")? {
            let frame = *sample.payload();
            if let Err(e) = frame.validate() {
                tracing::warn!(sequence = frame.sequence, "detection frame rejected: {e}");
                continue;
            }
            scene_seq = frame.sequence;
            // Capture time is CLOCK_MONOTONIC of this machine: its age, carried into the
            // cycle's clock, is what the staleness check sees (receipt time when absent).
            let mono_now = rt_setup::monotonic_now_ns();
            let age_ns = if frame.capture_time_ns == 0 || frame.capture_time_ns > mono_now {
                0
            } else {
                mono_now - frame.capture_time_ns
            };
            detection_age.record_ns(age_ns);
            let scene = scene_from_detection(&frame, table_height_m, &mut last_goal);
            twin.on_detection(scene, clock.now_ns().saturating_sub(age_ns), &mut events);
        }
        while let Some(sample) = pol_sub.receive().context("receiving policies")? {
            let blob: &PolicyBlob = sample.payload();
            match loader.prepare(blob) {
                Ok(p) => {
                    tracing::info!(
                        policy_id = p.policy_id(),
                        "policy accepted; re-running the lookahead"
                    );
                    twin.on_policy(Box::new(p), &mut events);
                }
                Err(reason) => tracing::warn!(
                    policy_id = blob.policy_id,
                    ?reason,
                    rejected_total = loader.counters().total_rejected(),
                    "policy blob rejected; the running policy stays"
                ),
            }
        }
        twin.step(&mut events);
        let now = clock.now_ns();
        let mut last_verdict: Option<TwinVerdict> = None;
        for e in events.drain(..) {
            match e {
                TwinEvent::Verdict {
                    verdict, elapsed_s, ..
                } => {
                    verdict_id += 1;
                    let v = twin_verdict(
                        &verdict,
                        verdict_id,
                        scene_seq,
                        now,
                        elapsed_s,
                        !args.no_lookahead,
                    );
                    tracing::info!(
                        policy_id = verdict.policy_id,
                        task_ok = verdict.task_ok,
                        safe = verdict.safe,
                        steps = verdict.steps,
                        min_distance_m = verdict.min_distance_m,
                        lookahead_ms = elapsed_s * 1e3,
                        "lookahead"
                    );
                    last_verdict = Some(v);
                    let mut s = loan_zeroed(&verdict_pub).context("loaning a verdict")?;
                    *s.payload_mut() = v;
                    s.send().context("sending a verdict")?;
                }
                TwinEvent::Retrain {
                    request_id,
                    verdict,
                    scene,
                } => {
                    let mut s = loan_zeroed(&retrain_pub).context("loaning a retrain request")?;
                    let r = s.payload_mut();
                    r.request_id = request_id;
                    r.request_time_ns = now;
                    r.task_config_hash = task_hash;
                    r.failed_policy_id = verdict.policy_id;
                    r.scene_sequence = scene_seq;
                    r.table_height_m = scene.table_height_m;
                    r.goal_center_m = scene.goal.center_m;
                    r.goal_size_m = scene.goal.size_m;
                    r.obstacle_count = scene.count as u32;
                    for (slot, b) in r.obstacles.iter_mut().zip(&scene.obstacles[..scene.count]) {
                        *slot = ObstacleBox {
                            center_m: b.center_m,
                            size_m: b.size_m,
                        };
                    }
                    r.verdict = last_verdict.unwrap_or_default();
                    tracing::warn!(
                        request_id,
                        policy_id = verdict.policy_id,
                        "lookahead failed: retrain requested"
                    );
                    s.send().context("sending a retrain request")?;
                }
                TwinEvent::PlanApproved {
                    plan_id,
                    policy_id,
                    joins,
                } => tracing::info!(plan_id, policy_id, joins, "plan approved"),
                TwinEvent::PlanRejected {
                    policy_id,
                    smooth,
                    shield,
                } => tracing::warn!(
                    policy_id,
                    ?smooth,
                    ?shield,
                    "plan rejected after the lookahead"
                ),
                TwinEvent::Revoked { plan_id, at_index } => {
                    tracing::warn!(
                        plan_id,
                        at_index,
                        "scene change: running plan unsafe, controlled stop"
                    )
                }
                TwinEvent::PolicySwapped { policy_id } => {
                    tracing::info!(policy_id, "policy swapped in")
                }
                TwinEvent::ReturningHome { plan_id, samples } => tracing::info!(
                    plan_id,
                    duration_s = samples as f64 / cfg.rate_hz,
                    "goal reached: returning home along the executed path"
                ),
                TwinEvent::ReturnHomeRefused { shield, smooth } => tracing::warn!(
                    ?shield,
                    ?smooth,
                    "the way home is unsafe in the current scene: holding; the lookahead takes over"
                ),
            }
        }
        // A learner that (re)connects gets the last retrain request from the service's
        // history: a learner killed mid-retraining and restarted by the launcher picks the
        // request up again instead of leaving the arm waiting.
        if last_connections_update.elapsed() >= Duration::from_millis(100) {
            last_connections_update = Instant::now();
            if let Err(e) = retrain_pub.update_connections() {
                tracing::debug!("retrain request connections: {e:?}");
            }
        }
        if let (Some(log), Some(r)) = (command_log.as_mut(), twin.last_report()) {
            log.record(r)?;
        }
        if now.saturating_sub(last_state_ns) >= 4_000_000
            && let Some(r) = twin.last_report().copied()
            && r.cycles != last_cycles
        {
            last_cycles = r.cycles;
            last_state_ns = now;
            publish_state(&state_pub, &r, &shared, &mut fk)?;
        }
        std::thread::sleep(Duration::from_micros(100));
    }
    stop.store(true, Ordering::Release);
    let commands_logged = match command_log.take() {
        Some(log) => log.finish()?,
        None => 0,
    };
    let done = cycle_thread
        .join()
        .map_err(|_| anyhow::anyhow!("cycle thread panicked"))?;
    let (summary, rt, allocs) = (done.stats.summary(), done.rt, done.allocations);
    let _ = log_thread.join();
    let age = detection_age.summary();
    tracing::info!(
        detections = age.count,
        p50_us = age.p50_us,
        p99_us = age.p99_us,
        max_us = age.max_us,
        "detection capture -> visible in the twin thread"
    );
    tracing::info!(
        cycles = summary.cycles,
        missed = summary.missed_deadlines,
        allocations_in_cycle = allocs,
        wake_p999_us = summary.wakeup_latency_us.p999_us,
        compute_p999_us = summary.cycle_compute_us.p999_us,
        ?rt,
        "rt-core run finished"
    );
    // One JSON line on stdout with the run's cycle figures, for the launcher's report.
    let h = |x: &rt_core::runtime::histogram::Summary| serde_json::json!({"p50": x.p50_us, "p99": x.p99_us, "p999": x.p999_us, "max": x.max_us});
    println!(
        "{}",
        serde_json::json!({
            "cycles": summary.cycles,
            "missed_deadlines": summary.missed_deadlines,
            "allocations_in_cycle": allocs,
            "wakeup_latency_us": h(&summary.wakeup_latency_us),
            "cycle_compute_us": h(&summary.cycle_compute_us),
            "detection_to_twin_us": {"p50": age.p50_us, "p99": age.p99_us, "max": age.max_us},
            "dry_run": args.dry_run,
            "lookahead_gate": !args.no_lookahead,
            "commands_logged": commands_logged,
        })
    );
    Ok(())
}

/// The command log: one CSV line per cycle that followed a plan, from the cycle's reports
/// (written by the twin thread; the cycle only fills its report). Lines are whole; the file
/// is flushed at least every 100 ms and at the end.
struct CommandLog {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    last_cycle: u64,
    lines: u64,
    flushed: Instant,
}

impl CommandLog {
    fn create(path: &std::path::Path) -> anyhow::Result<Self> {
        use std::io::Write;
        let file = std::fs::File::create(path)
            .with_context(|| format!("creating the command log {}", path.display()))?;
        let mut out = std::io::BufWriter::new(file);
        writeln!(out, "t_ns,cycle,plan_id,q0_rad,q1_rad,q2_rad,q3_rad,q4_rad")?;
        tracing::info!(path = %path.display(), "logging computed commands");
        Ok(Self {
            path: path.to_path_buf(),
            out,
            last_cycle: 0,
            lines: 0,
            flushed: Instant::now(),
        })
    }

    fn record(&mut self, r: &CycleReport) -> anyhow::Result<()> {
        use std::io::Write;
        if r.cycles == self.last_cycle {
            return Ok(());
        }
        self.last_cycle = r.cycles;
        if r.mode == Mode::Following {
            let q = r.cmd.q_rad;
            writeln!(
                self.out,
                "{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6}",
                r.t_ns, r.cycles, r.plan_id, q[0], q[1], q[2], q[3], q[4]
            )
            .with_context(|| format!("writing {}", self.path.display()))?;
            self.lines += 1;
        }
        if self.flushed.elapsed() >= Duration::from_millis(100) {
            self.out.flush()?;
            self.flushed = Instant::now();
        }
        Ok(())
    }

    fn finish(mut self) -> anyhow::Result<u64> {
        use std::io::Write;
        self.out
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))?;
        Ok(self.lines)
    }
}

fn publish_state(
    publisher: &iceoryx2::port::publisher::Publisher<ipc::Service, RobotState, ()>,
    r: &CycleReport,
    shared: &LoopShared,
    fk: &mut TwinModel,
) -> anyhow::Result<()> {
    let mut s = loan_zeroed(publisher).context("loaning a robot state")?;
    let st = s.payload_mut();
    st.time_ns = r.t_ns;
    st.cycle_count = r.cycles;
    st.missed_deadlines = shared.missed_deadlines.load(Ordering::Relaxed);
    st.active_policy_id = r.policy_id;
    st.joints_rad = r.measured_q_rad;
    st.joint_velocities_rad_s = r.cmd.dq_rad_s;
    st.command_joints_rad = r.cmd.q_rad;
    st.tcp_m = fk.tcp_position_m(&r.measured_q_rad);
    st.last_compute_us = shared.last_compute_ns.load(Ordering::Relaxed) as f32 / 1000.0;
    st.controlled_stop = u8::from(matches!(r.mode, Mode::Stopping | Mode::Stopped));
    st.stop_reason = stop_code(r.stop_reason) as u8;
    st.link_ok = u8::from(r.stop_reason != StopReason::LinkLost || r.mode == Mode::Following);
    s.send().context("sending a robot state")?;
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use shm_schemas::DetectedObject;
    use shm_schemas::scene_file::SceneFile;

    /// A tall box on the table whose centre and height both round up (0.1614 → 0.160 and
    /// 0.3227 → 0.325 on the 5 mm grid) once made a box reaching 2.5 mm below the table:
    /// a scene the learner refused, leaving the arm waiting for a policy that never came.
    #[test]
    fn a_detected_box_on_the_table_stays_on_it_after_snapping() {
        let mut frame = DetectionFrame::default();
        assert!(frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.9,
            [0.28, -0.32, 0.025],
            [0.05, 0.05, 0.05]
        )));
        assert!(frame.push(DetectedObject::new(
            2,
            ObjectClass::Obstacle,
            0.9,
            [0.2887, -0.1333, 0.16136],
            [0.053, 0.0518, 0.32272]
        )));
        let mut goal = Goal {
            center_m: [0.3, 0.0, 0.025],
            size_m: 0.05,
        };
        let scene = scene_from_detection(&frame, 0.0, &mut goal).to_scene();
        let b = scene.obstacles[0];
        let bottom = b.center_m[2] - b.size_m[2] / 2.0;
        assert!(bottom >= -1e-12, "box bottom {bottom} below the table");
        assert!((b.center_m[2] + b.size_m[2] / 2.0 - 0.3227).abs() <= 0.0025);
        // The scene a retrain request carries validates like a scene file.
        let file = SceneFile {
            name: "detected".into(),
            table: shm_schemas::scene_file::TableSpec { height_m: 0.0 },
            goal: shm_schemas::scene_file::GoalSpec {
                center_m: scene.goal.center_m,
                size_m: scene.goal.size_m,
            },
            obstacles: vec![shm_schemas::scene_file::BoxSpec {
                center_m: b.center_m,
                size_m: b.size_m,
            }],
        };
        file.validate().unwrap();
    }
}
