//! `rt-core bench-loop`: the latency and jitter harness. Runs the full cycle — the twin's
//! shield model on a synthetic scene, Ruckig-smoothed plans from the twin lookahead with
//! real policy blobs (random weights) hot-swapped every few milliseconds, the in-process
//! arm — on a real clock for a few seconds, and prints one JSON object: wake-up latency and
//! cycle compute histograms (µs), missed deadlines, allocations counted on the cycle thread,
//! swaps, lookahead times. A watchdog aborts with exit code 3 when the cycle stops beating.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::Args;
use policy::{MlpPolicy, PolicyExpectation, PolicyLoader};
use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::cycle::thread::spawn_cycle_thread;
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::{self, Cycle, CycleConfig, CycleEvent, CycleReport, LoopShared, LoopSummary};
use rt_core::launch::load_assets;
use rt_core::rt::clock::{Clock, MonotonicClock};
use rt_core::rt::rt_log::RtLogDrain;
use rt_core::rt::rt_setup::RtSetupReport;
use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use rt_core::twin_thread::{TwinEvent, TwinWorker};
use shm_schemas::PolicyBlobBuilder;
use shm_schemas::cli_bounds::{f64_within, int_within};
use twin::{ACT_DIM, BoxObstacle, Goal, OBS_DIM, RobotModel, Scene, TaskConfig};

/// Arguments of `bench-loop`.
#[derive(Debug, Args)]
pub struct BenchLoopArgs {
    /// Cycle rate, Hz.
    #[arg(long, default_value_t = 250.0, value_parser = f64_within(1.0, 10_000.0), allow_negative_numbers = true)]
    rate: f64,
    /// Duration of the measured run, s.
    #[arg(long, default_value_t = 3.0, value_parser = f64_within(0.001, 86_400.0), allow_negative_numbers = true)]
    seconds: f64,
    /// Real-time set-up of the cycle thread.
    #[command(flatten)]
    rt: super::RtArgs,
    /// Period of policy hot-swaps, ms (0 = none after the first).
    #[arg(long, default_value_t = 50, value_parser = int_within(1u64, 3_600_000), allow_negative_numbers = true)]
    swap_every_ms: u64,
    /// Folder with runtime.toml, xarm5.urdf and task.toml.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
}

/// The bench's synthetic scene: a goal in reach and one small box off the path.
pub(crate) fn synthetic_scene() -> Scene {
    let mut s = Scene::empty(
        0.0,
        Goal {
            center_m: [0.35, 0.15, 0.025],
            size_m: 0.05,
        },
    );
    let _ = s.obstacles.push(BoxObstacle {
        center_m: [0.30, -0.30, 0.03],
        size_m: [0.04, 0.04, 0.06],
    });
    s
}

/// A prepared random-weight policy for the running task.
pub(crate) fn random_policy(
    loader: &PolicyLoader,
    id: u64,
    task_hash: u64,
) -> anyhow::Result<Box<MlpPolicy>> {
    let blob = PolicyBlobBuilder::random(id, task_hash, OBS_DIM, &[64, 64], ACT_DIM, id)
        .build()
        .map_err(|e| anyhow::anyhow!("building a random policy blob: {e:?}"))?;
    let p = loader
        .prepare(&blob)
        .map_err(|e| anyhow::anyhow!("random policy rejected: {e:?}"))?;
    Ok(Box::new(p))
}

fn percentile_ms(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i] * 1e3
}

/// Times whole lookahead episodes with random-weight policies (policy actions, so most run
/// to the step limit): median and max in ms, and the mean number of steps.
fn full_lookahead_ms(
    model: &RobotModel,
    task: &TaskConfig,
    task_hash: u64,
) -> anyhow::Result<serde_json::Value> {
    use rt_core::twin_thread::Lookahead;
    let loader = PolicyLoader::new(PolicyExpectation::for_task(task_hash));
    let mut la = TwinLookahead::new(model.clone(), *task, LookaheadActions::Policy);
    let start = la.start_q_rad();
    let scene = synthetic_scene();
    let mut wps = Vec::with_capacity(512);
    let mut times = Vec::new();
    let mut steps = 0u64;
    for id in 0..30 {
        let p = random_policy(&loader, 1000 + id, task_hash)?;
        let t0 = Instant::now();
        let v = la.lookahead(&p, &scene, &start, &mut wps);
        times.push(t0.elapsed().as_secs_f64());
        steps += u64::from(v.steps);
    }
    times.sort_by(f64::total_cmp);
    Ok(serde_json::json!({
        "runs": times.len(),
        "mean_steps": steps as f64 / times.len() as f64,
        "p50_ms": percentile_ms(&times, 0.5),
        "max_ms": percentile_ms(&times, 1.0),
    }))
}

/// Runs the bench.
pub fn run(args: BenchLoopArgs) -> ExitCode {
    match bench(&args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("bench-loop: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn bench(args: &BenchLoopArgs) -> anyhow::Result<ExitCode> {
    let (cfg, model, task) = load_assets(&args.assets, Some(args.rate), None)?;
    let task_hash = task.hash();
    let full = full_lookahead_ms(&model, &task, task_hash)?;
    let clock = MonotonicClock::new();
    let (cyc, twin, log_drain) = build_parts(&cfg, model, task, &clock)?;

    let stop = Arc::new(AtomicBool::new(false));
    let shared = Arc::new(LoopShared::default());
    let log_thread = log_drain.spawn(Duration::from_millis(20), stop.clone())?;

    // Twin thread: detections at 30 Hz, a new random policy every swap period.
    let loader = PolicyLoader::new(PolicyExpectation::for_task(task_hash));
    let swap_every = Duration::from_millis(args.swap_every_ms);
    let twin_stop = stop.clone();
    let twin_thread = std::thread::Builder::new()
        .name("twin".into())
        .spawn(move || drive_twin(twin, &loader, task_hash, clock, swap_every, &twin_stop))?;

    // Cycle thread.
    let req = args.rt.request();
    let cycle_thread = spawn_cycle_thread(cyc, clock, req, stop.clone(), shared.clone())?;

    if let Some(beats) = watch_heartbeat(&shared, args.seconds) {
        println!(
            "{}",
            serde_json::json!({"error": "watchdog: the cycle stopped beating", "cycles": beats})
        );
        return Ok(ExitCode::from(3));
    }
    stop.store(true, Ordering::Release);
    let done = cycle_thread
        .join()
        .map_err(|_| anyhow::anyhow!("cycle thread panicked"))?;
    let cycle = CycleCounts {
        stats: done.stats.summary(),
        rt: done.rt,
        allocations: done.allocations,
        report: *done.cycle.report(),
    };
    let twin = twin_thread
        .join()
        .map_err(|_| anyhow::anyhow!("twin thread panicked"))??;
    let _ = log_thread.join();
    println!(
        "{}",
        bench_json(cfg.rate_hz, args.seconds, &cycle, twin, full)
    );
    Ok(ExitCode::SUCCESS)
}

/// The bench's cycle (shield on the twin's model, the in-process arm), started, and its twin
/// worker with the scripted lookahead, wired to each other.
#[allow(clippy::type_complexity)]
fn build_parts(
    cfg: &RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    clock: &MonotonicClock,
) -> anyhow::Result<(
    Cycle<TwinModel, InProcessArm>,
    TwinWorker<TwinLookahead, TwinModel>,
    RtLogDrain<CycleEvent>,
)> {
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let lookahead = TwinLookahead::new(
        model.clone(),
        task,
        LookaheadActions::ScriptedWithPolicyCost,
    );
    let (twin_io, cycle_io, log_drain) = cycle::wire::<Scene>();
    let arm = InProcessArm::new(
        lookahead.start_q_rad(),
        cfg.limits.joint_min_rad,
        cfg.limits.joint_max_rad,
        [std::f64::consts::PI; 5],
    );
    let mut cyc = Cycle::new(
        CycleConfig::from_runtime(cfg),
        Shield::new(TwinModel::new(model.clone()), limits),
        Brake::new(&cfg.limits),
        arm,
        cycle_io,
    );
    cyc.start(clock.now_ns())
        .map_err(|e| anyhow::anyhow!("starting the cycle: {e}"))?;
    let twin = TwinWorker::new(
        cfg,
        lookahead,
        Shield::new(TwinModel::new(model), limits),
        twin_io,
    );
    Ok((cyc, twin, log_drain))
}

/// What the bench's cycle thread left behind.
struct CycleCounts {
    stats: LoopSummary,
    rt: RtSetupReport,
    allocations: u64,
    report: CycleReport,
}

/// The bench's one JSON object.
fn bench_json(
    rate_hz: f64,
    seconds: f64,
    cycle: &CycleCounts,
    twin: TwinCounts,
    full: serde_json::Value,
) -> serde_json::Value {
    let TwinCounts {
        mut lookahead_s,
        swaps,
        approved,
        retrains,
        rejected,
    } = twin;
    lookahead_s.sort_by(f64::total_cmp);
    let s = &cycle.stats;
    let ratio = |n: u64| {
        if s.cycles > 0 {
            n as f64 / s.cycles as f64
        } else {
            0.0
        }
    };
    serde_json::json!({
        "rate_hz": rate_hz,
        "seconds": seconds,
        "cycles": s.cycles,
        "missed_deadlines": s.missed_deadlines,
        "missed_ratio": ratio(s.missed_deadlines),
        "compute_overruns": s.compute_overruns,
        "compute_overrun_ratio": ratio(s.compute_overruns),
        "wakeup_latency_us": s.wakeup_latency_us,
        "cycle_compute_us": s.cycle_compute_us,
        "allocations_in_cycle": cycle.allocations,
        "policy_swaps": swaps,
        "plans_approved": approved,
        "plans_taken_by_cycle": cycle.report.plans_taken,
        "plans_rejected": rejected,
        "retrain_requests": retrains,
        "stops": cycle.report.stops,
        "lookahead_ms": {
            "count": lookahead_s.len(),
            "p50": percentile_ms(&lookahead_s, 0.5),
            "p99": percentile_ms(&lookahead_s, 0.99),
            "max": percentile_ms(&lookahead_s, 1.0),
        },
        "full_lookahead": full,
        "rt_setup": cycle.rt,
    })
}

/// What the bench's twin thread counted.
struct TwinCounts {
    lookahead_s: Vec<f64>,
    swaps: u64,
    approved: u64,
    retrains: u64,
    rejected: u64,
}

/// The bench's twin thread: detections at 30 Hz, a new random policy every `swap_every`
/// (once only when zero), the worker stepped every millisecond.
fn drive_twin(
    mut twin: TwinWorker<TwinLookahead, TwinModel>,
    loader: &PolicyLoader,
    task_hash: u64,
    clock: MonotonicClock,
    swap_every: Duration,
    stop: &AtomicBool,
) -> anyhow::Result<TwinCounts> {
    let scene = synthetic_scene();
    let mut events = Vec::new();
    let mut c = TwinCounts {
        lookahead_s: Vec::new(),
        swaps: 0,
        approved: 0,
        retrains: 0,
        rejected: 0,
    };
    let mut next_id = 1;
    let mut last_det = Instant::now() - Duration::from_secs(1);
    let mut last_swap: Option<Instant> = None;
    while !stop.load(Ordering::Acquire) {
        if last_det.elapsed() >= Duration::from_millis(33) {
            // A fixed synthetic scene, not a camera's view: with a goal and settled.
            twin.on_detection(scene, clock.now_ns(), true, true, &mut events);
            last_det = Instant::now();
        }
        let due = match last_swap {
            None => true,
            Some(t) => !swap_every.is_zero() && t.elapsed() >= swap_every,
        };
        if due {
            twin.on_policy(random_policy(loader, next_id, task_hash)?, &mut events);
            next_id += 1;
            c.swaps += 1;
            last_swap = Some(Instant::now());
        }
        twin.step(&mut events);
        for e in events.drain(..) {
            match e {
                TwinEvent::Verdict { elapsed_s, .. } => c.lookahead_s.push(elapsed_s),
                TwinEvent::PlanApproved { .. } => c.approved += 1,
                TwinEvent::Retrain { .. } => c.retrains += 1,
                TwinEvent::PlanRejected { .. } => c.rejected += 1,
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(c)
}

/// Watches the cycle's heartbeat for `seconds`; the last beat count if it stopped moving
/// for 2 s (a stalled or dead cycle thread).
fn watch_heartbeat(shared: &LoopShared, seconds: f64) -> Option<u64> {
    let t0 = Instant::now();
    let mut last_beat = 0;
    let mut last_change = Instant::now();
    while t0.elapsed().as_secs_f64() < seconds {
        std::thread::sleep(Duration::from_millis(100));
        let b = shared.heartbeat.load(Ordering::Acquire);
        if b != last_beat {
            last_beat = b;
            last_change = Instant::now();
        } else if last_change.elapsed() > Duration::from_secs(2) {
            return Some(b);
        }
    }
    None
}
