//! `foresight`: starts and supervises the whole system — `xarm-sim` (or a real arm with
//! `--robot HOST`), `perception`, `learner serve`, `rt-core run` and optionally the ROS 2
//! bridge — under one unique service prefix, plays a world script against it, prints a
//! running timeline, and leaves a report in `runs/<time>/` (`runs/latest` points at it).
//!
//! The logic lives in `rt_core::launcher` (supervisor, observer, scenario director,
//! report); this file parses the command line and wires them.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use rand::SeedableRng;
use rt_core::launcher::observer::Observer;
use rt_core::launcher::report::{self, View};
use rt_core::launcher::run_dir::{RunDir, write_atomic};
use rt_core::launcher::scenario::{Action, Director, ScenarioConfig, TimelineEvent};
use rt_core::launcher::supervisor::{ProcessEvent, ProcessSpec, Supervisor, send_signal};
use rt_core::runtime::config::RuntimeConfig;
use rt_core::twin::{ObstacleClass, RobotModel, Scene, TaskConfig, TwinEnv};
use shm_schemas::scene_file::{SceneFile, WorldScript};

#[derive(Debug, Parser)]
#[command(
    name = "foresight",
    version,
    about = "Run Foresight's self-improving reaching loop end to end"
)]
struct Args {
    /// World script (timeline of scenes). Default: the demo world.
    #[arg(long, default_value = "assets/scenes/demo_world.toml")]
    world: PathBuf,
    /// Task configuration (goal tolerance, scene sampling).
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Runtime configuration for `rt-core run`.
    #[arg(long, default_value = "assets/runtime.toml")]
    runtime: PathBuf,
    /// Robot model.
    #[arg(long, default_value = "assets/xarm5.urdf")]
    urdf: PathBuf,
    /// Pre-trained policy checkpoint the learner resumes from.
    #[arg(long, default_value = "assets/policy")]
    checkpoint: PathBuf,
    /// Drive a real xArm5 at this address instead of starting `xarm-sim`.
    #[arg(long)]
    robot: Option<String>,
    /// Camera source for perception (`synthetic` plays the world; `ros2`; `file:PATH`).
    #[arg(long, default_value = "synthetic")]
    camera: String,
    /// Frame rate of the synthetic camera (Hz). 60 is the ZED's 720p rate; perception
    /// confirms a new object after 3 frames, so a world change is seen within ≈ 50–70 ms.
    #[arg(long, default_value_t = 60.0)]
    camera_rate_hz: f64,
    /// Calibration file for a real camera.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Execute the policy without the lookahead gate (shows why Foresight exists).
    #[arg(long)]
    no_lookahead: bool,
    /// Compute and log every command but send none to the arm.
    #[arg(long)]
    dry_run: bool,
    /// Also publish to ROS 2 (`rt-core ros-bridge`).
    #[arg(long)]
    ros: bool,
    /// Randomised scenarios: run this many, each with a world drawn from the task's
    /// sampling ranges (a small obstacle, then a large one).
    #[arg(long, default_value_t = 0)]
    runs: u32,
    /// Seed of the randomised scenarios.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Retraining wall-time budget per request (s).
    #[arg(long, default_value_t = 30.0)]
    retrain_budget_s: f64,
    /// Retraining step budget per request (a request that runs out is answered with the
    /// best policy so far; the next request resumes where it stopped).
    #[arg(long, default_value_t = 400_000)]
    retrain_steps: u64,
    /// Longest one scene may take (s).
    #[arg(long, default_value_t = 90.0)]
    phase_timeout_s: f64,
    /// Where run folders go.
    #[arg(long, default_value = "runs")]
    out: PathBuf,
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    match run_all(&args) {
        Ok(ok) => {
            if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            }
        }
        Err(e) => {
            eprintln!("foresight: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// Runs one scenario, or `--runs N` randomised ones; true when every run met its goal.
fn run_all(args: &Args) -> Result<bool> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).context("installing the signal handler")?;
    }
    let task =
        TaskConfig::load(&args.task).with_context(|| format!("loading {}", args.task.display()))?;
    if args.runs == 0 {
        let world = WorldScript::load(&args.world)
            .with_context(|| format!("loading {}", args.world.display()))?;
        let summary = run_scenario(args, &task, world.steps, &stop)?;
        return Ok(judge(args, &summary));
    }
    let model =
        RobotModel::load(&args.urdf).with_context(|| format!("loading {}", args.urdf.display()))?;
    let env = TwinEnv::new(model, task);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let mut all_ok = true;
    let mut collisions = 0;
    for i in 0..args.runs {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let small: Scene = env.sample_scene(&mut rng, ObstacleClass::Small);
        let large: Scene = env.sample_scene(&mut rng, ObstacleClass::Large);
        let (mut a, mut b) = (small.to_file(), large.to_file());
        a.name = format!("random-{i}-small");
        b.name = format!("random-{i}-large");
        println!(
            "=== scenario {}/{} (seed {}) ===",
            i + 1,
            args.runs,
            args.seed
        );
        let summary = run_scenario(args, &task, vec![(0.0, a), (5.0, b)], &stop)?;
        collisions += summary.collisions;
        all_ok &= judge(args, &summary);
    }
    println!(
        "=== {} scenario(s): {collisions} collision(s) in total ===",
        args.runs
    );
    Ok(all_ok)
}

fn judge(args: &Args, s: &report::Summary) -> bool {
    if args.no_lookahead {
        true
    } else {
        s.goal_reached && s.collisions == 0
    }
}

fn bin_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating the foresight executable")?;
    Ok(exe.parent().map(Path::to_path_buf).unwrap_or_default())
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Sends one line to `xarm-sim`'s control port and returns its one-line reply.
fn sim_control(port: u16, line: &str) -> Result<String> {
    let mut stream = TcpStream::connect(("127.0.0.1", port))
        .with_context(|| format!("connecting to xarm-sim control port {port}"))?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    writeln!(stream, "{line}")?;
    let mut reply = String::new();
    BufReader::new(stream).read_line(&mut reply)?;
    Ok(reply.trim().to_owned())
}

/// The ports `xarm-sim` announced.
#[derive(Debug, Clone, Copy)]
struct SimPortsSeen {
    command: u16,
    report_real: u16,
    control: u16,
}

/// The ports in `xarm-sim`'s `{"event":"listening","ports":{…}}` line, once it is in its log.
fn read_sim_ports(log: &Path) -> Option<SimPortsSeen> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().find_map(|l| {
        let v: serde_json::Value = serde_json::from_str(l.trim()).ok()?;
        if v["event"] != "listening" {
            return None;
        }
        let port = |k: &str| v["ports"][k].as_u64().and_then(|p| u16::try_from(p).ok());
        Some(SimPortsSeen {
            command: port("command")?,
            report_real: port("report_real")?,
            control: port("control")?,
        })
    })
}

/// `xarm-sim`'s `status` reply (JSON), if it answers.
fn sim_status(port: u16) -> Option<serde_json::Value> {
    sim_control(port, "status")
        .ok()
        .and_then(|r| serde_json::from_str::<serde_json::Value>(&r).ok())
}

/// `xarm-sim`'s collision count, if it answers.
fn sim_collisions(port: u16) -> Option<u64> {
    sim_status(port).and_then(|v| v["collisions"].as_u64())
}

fn print_event(e: &TimelineEvent) {
    println!("{:>8.3} s  {:<20} {}", e.t_s, e.kind, e.detail);
}

#[allow(clippy::too_many_lines)]
fn run_scenario(
    args: &Args,
    task: &TaskConfig,
    world: Vec<(f64, SceneFile)>,
    stop: &Arc<AtomicBool>,
) -> Result<report::Summary> {
    let bins = bin_dir()?;
    let runtime = RuntimeConfig::load(&args.runtime)
        .with_context(|| format!("loading {}", args.runtime.display()))?;
    let run = RunDir::create(&args.out).context("creating the run folder")?;
    let prefix = format!(
        "fs{}_{}",
        std::process::id(),
        run.path
            .file_name()
            .map(|n| n.to_string_lossy().replace('-', ""))
            .unwrap_or_default()
    );
    println!(
        "foresight: run folder {}, service prefix {prefix}",
        run.path.display()
    );

    // The world as the launcher sets it: every scene saved, the one in force in live.toml.
    let mut scene_paths = Vec::new();
    for (i, (_, scene)) in world.iter().enumerate() {
        let p = run.file(&format!("world/scene_{i}.toml"))?;
        write_atomic(&p, scene.to_toml_string().as_bytes())?;
        scene_paths.push(p);
    }
    let live = run.file("world/live.toml")?;
    write_atomic(&live, world[0].1.to_toml_string().as_bytes())?;

    let mut sup = Supervisor::new(&run.file("logs/.keep")?.with_file_name(""));
    // The simulator binds free ports the OS picks (no clash with another run or with
    // outgoing connections) and announces them in its first stdout line, in its log.
    let mut sim_ports: Option<SimPortsSeen> = None;
    let robot_addr = match &args.robot {
        Some(host) => host.clone(),
        None => {
            let mut sim_args: Vec<String> = vec!["--bind".into(), "127.0.0.1".into()];
            for flag in [
                "--command-port",
                "--report-rt-port",
                "--report-normal-port",
                "--report-rich-port",
                "--report-real-port",
                "--control-port",
            ] {
                sim_args.extend([flag.into(), "0".into()]);
            }
            sim_args.extend(["--scene".into(), s(&live), "--urdf".into(), s(&args.urdf)]);
            sup.start(ProcessSpec {
                name: "xarm-sim".into(),
                program: bins.join("xarm-sim"),
                args: sim_args,
                env: vec![],
                restart: false,
            })?;
            let sim_log = run.path.join("logs/xarm-sim.log");
            let deadline = Instant::now() + Duration::from_secs(15);
            let ports = loop {
                let _ = sup.poll();
                if let Some(p) = read_sim_ports(&sim_log)
                    && sim_status(p.control).is_some()
                {
                    break p;
                }
                if !sup.is_running("xarm-sim") || Instant::now() > deadline {
                    bail!("xarm-sim did not come up (see {})", sim_log.display());
                }
                std::thread::sleep(Duration::from_millis(50));
            };
            sim_ports = Some(ports);
            format!("127.0.0.1:{}", ports.command)
        }
    };
    let source = if args.camera == "synthetic" {
        format!("synthetic:{}", s(&live))
    } else {
        args.camera.clone()
    };
    let mut perception_args = vec![
        "run".into(),
        "--source".into(),
        source,
        "--prefix".into(),
        prefix.clone(),
        "--rate".into(),
        args.camera_rate_hz.to_string(),
    ];
    if let Some(c) = &args.calibration {
        perception_args.extend(["--calibration".into(), s(c)]);
    }
    sup.start(ProcessSpec {
        name: "perception".into(),
        program: bins.join("perception"),
        args: perception_args,
        env: vec![],
        restart: true,
    })?;
    sup.start(ProcessSpec {
        name: "learner".into(),
        program: bins.join("learner"),
        args: vec![
            "serve".into(),
            "--checkpoint".into(),
            s(&args.checkpoint),
            "--prefix".into(),
            prefix.clone(),
            "--task".into(),
            s(&args.task),
            "--out".into(),
            s(&run.file("retrain/.keep")?.with_file_name("")),
            "--time-budget-s".into(),
            args.retrain_budget_s.to_string(),
            "--max-steps".into(),
            args.retrain_steps.to_string(),
        ],
        env: vec![],
        restart: true,
    })?;
    let assets = args
        .task
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let mut rt_args = vec![
        "run".into(),
        "--config".into(),
        s(&args.runtime),
        "--assets".into(),
        s(&assets),
        "--prefix".into(),
        prefix.clone(),
        "--link".into(),
        "xarm".into(),
        "--robot".into(),
        robot_addr,
        "--policy".into(),
        s(&args.checkpoint.join("policy.blob")),
    ];
    if let Some(p) = sim_ports {
        rt_args.extend(["--report-port".into(), p.report_real.to_string()]);
    }
    if args.no_lookahead {
        rt_args.push("--no-lookahead".into());
    }
    if args.dry_run {
        rt_args.extend([
            "--dry-run".into(),
            "--command-log".into(),
            s(&run.file("commands.csv")?),
        ]);
    }
    sup.start(ProcessSpec {
        name: "rt-core".into(),
        program: bins.join("rt-core"),
        args: rt_args,
        env: vec![],
        restart: false,
    })?;
    if args.ros {
        sup.start(ProcessSpec {
            name: "ros-bridge".into(),
            program: bins.join("rt-core"),
            args: vec![
                "ros-bridge".into(),
                "--prefix".into(),
                prefix.clone(),
                "--urdf".into(),
                s(&args.urdf),
            ],
            env: vec![],
            restart: true,
        })?;
    }

    let observer = {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            match Observer::open(&prefix) {
                Ok(o) => break o,
                Err(e) if Instant::now() > deadline => {
                    return Err(e).context("subscribing to the run's services");
                }
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    };
    let mut director = Director::new(ScenarioConfig {
        world: world.clone(),
        goal_tolerance_m: task.success.tolerance_m,
        goal_hover_m: task.success.goal_hover_m,
        phase_timeout_s: args.phase_timeout_s,
        settle_s: 1.0,
        lookahead: !args.no_lookahead,
        home_q_rad: runtime.return_home.then_some(task.start.joints_rad),
    });
    let t0 = Instant::now();
    let timeline_path = run.file("timeline.jsonl")?;
    let mut timeline = std::fs::File::create(&timeline_path)?;
    let mut printed = 0;
    let mut extra_events: Vec<TimelineEvent> = Vec::new();
    let overall_timeout =
        Duration::from_secs_f64(args.phase_timeout_s * (world.len() as f64) + 60.0);
    let mut notes = Vec::new();
    let (mut last_status_s, mut collisions_seen, mut blind_collided) =
        (f64::NEG_INFINITY, 0, false);
    loop {
        let t_s = t0.elapsed().as_secs_f64();
        if stop.load(Ordering::Relaxed) {
            notes.push("interrupted (Ctrl-C)".to_owned());
            break;
        }
        if t0.elapsed() > overall_timeout {
            notes.push(format!(
                "gave up after {:.0} s",
                overall_timeout.as_secs_f64()
            ));
            break;
        }
        for ev in sup.poll() {
            let detail = match &ev {
                ProcessEvent::Exited {
                    name,
                    status,
                    will_restart,
                } => {
                    format!(
                        "{name} exited ({status}){}",
                        if *will_restart { "; restarting" } else { "" }
                    )
                }
                ProcessEvent::Restarted { name, restarts } => {
                    format!("{name} restarted (#{restarts})")
                }
            };
            extra_events.push(TimelineEvent {
                t_s,
                kind: "process",
                detail,
            });
        }
        if !sup.is_running("rt-core") {
            let log = run.path.join("logs/rt-core.log");
            notes.push(match last_error_line(&log) {
                Some(line) => format!("rt-core exited: {line}"),
                None => "rt-core exited".to_owned(),
            });
            break;
        }
        // Ground truth from the simulated arm, twice a second.
        if let Some(sim) = sim_ports
            && t_s - last_status_s >= 0.5
        {
            last_status_s = t_s;
            if let Some(n) = sim_collisions(sim.control)
                && n > collisions_seen
            {
                extra_events.push(TimelineEvent {
                    t_s,
                    kind: "collision",
                    detail: format!("xarm-sim reports {n} collision(s)"),
                });
                collisions_seen = n;
                if args.no_lookahead {
                    notes.push(
                        "the blind run collided: this is what the lookahead prevents".to_owned(),
                    );
                    blind_collided = true;
                }
            }
        }
        let obs = observer.poll();
        let actions = director.step(t_s, &obs);
        for a in actions {
            match a {
                Action::SwitchScene(k) => {
                    write_atomic(&live, world[k].1.to_toml_string().as_bytes())?;
                    if let Some(sim) = sim_ports {
                        let reply =
                            sim_control(sim.control, &format!("scene {}", s(&scene_paths[k])))?;
                        if reply != "ok" {
                            bail!("xarm-sim refused the scene change: {reply}");
                        }
                    }
                }
                Action::Finish => {}
            }
        }
        let mut new: Vec<TimelineEvent> = director.events()[printed..].to_vec();
        printed = director.events().len();
        new.append(&mut extra_events);
        for e in &new {
            print_event(e);
            let _ = writeln!(timeline, "{}", serde_json::to_string(e).unwrap_or_default());
        }
        if director.is_done() || blind_collided {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = timeline.flush();

    // Ground truth from the arm, then an orderly stop.
    let sim_status = sim_ports.and_then(|sim| {
        let status = sim_status(sim.control);
        if status.is_none() {
            notes.push("could not read xarm-sim's status".into());
        }
        status
    });
    let collisions = sim_status
        .as_ref()
        .and_then(|v| v["collisions"].as_u64())
        .unwrap_or(0);
    let arm_rejected_commands = sim_status
        .as_ref()
        .and_then(|v| v["counters"]["servo_rejected"].as_u64());
    if let Some(pid) = sup.pid("rt-core") {
        send_signal(pid, "INT");
    }
    sup.stop_all(Duration::from_secs(5));
    let (p99, p999) = read_cycle_stats(&run.path.join("logs/rt-core.log"));
    let restarts = ["perception", "learner"]
        .iter()
        .map(|n| u64::from(sup.restarts(n)))
        .sum();
    let mut summary = director.summary(collisions, p999, restarts, args.seed);
    summary.arm_rejected_commands = arm_rejected_commands;
    summary.cycle_p99_us = p99.or(summary.cycle_p99_us);
    summary.notes.extend(notes);

    write_report(&run, args, &world, &director, &summary)?;
    println!(
        "\n{}",
        serde_json::to_string_pretty(&summary).unwrap_or_default()
    );
    println!("report: {}", run.path.join("report.md").display());
    Ok(summary)
}

/// The last `ERROR` line of a process log (why it exited, when it says so), trimmed.
fn last_error_line(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find(|l| l.contains(" ERROR ")).map(|l| {
        l.split_once(" ERROR ")
            .map_or(l, |(_, rest)| rest)
            .trim()
            .to_owned()
    })
}

/// Cycle compute p99 and p99.9 (µs) from the JSON line `rt-core run` prints at exit.
fn read_cycle_stats(log: &Path) -> (Option<f64>, Option<f64>) {
    let Ok(text) = std::fs::read_to_string(log) else {
        return (None, None);
    };
    text.lines()
        .rev()
        .find_map(|l| {
            let v: serde_json::Value = serde_json::from_str(l.trim()).ok()?;
            let c = v.get("cycle_compute_us")?;
            Some((
                c.get("p99").and_then(serde_json::Value::as_f64),
                c.get("p999").and_then(serde_json::Value::as_f64),
            ))
        })
        .unwrap_or((None, None))
}

fn write_report(
    run: &RunDir,
    args: &Args,
    world: &[(f64, SceneFile)],
    director: &Director,
    summary: &report::Summary,
) -> Result<()> {
    report::write_summary(&run.path.join("summary.json"), summary)?;
    report::plot_path(
        &run.path.join("tcp_path_top.png"),
        View::Top,
        director.path(),
        world,
    )?;
    report::plot_path(
        &run.path.join("tcp_path_side.png"),
        View::Side,
        director.path(),
        world,
    )?;
    let mut images = vec![
        ("TCP path, top view", "tcp_path_top.png"),
        ("TCP path, side view", "tcp_path_side.png"),
    ];
    let mut curves = Vec::new();
    if let Some(csv) = find_csv(&args.checkpoint)
        && let Ok(c) = report::read_reward_curve(&csv)
    {
        curves.push(("pre-training (bundled policy)".to_owned(), c));
    }
    let retrain_dir = run.path.join("retrain");
    if let Some(csv) = find_csv(&retrain_dir)
        && let Ok(c) = report::read_reward_curve(&csv)
    {
        curves.push(("retraining on the new scene".to_owned(), c));
    }
    if !curves.is_empty() {
        report::plot_reward_curves(
            &run.path.join("reward_curves.png"),
            "Reward curves",
            &curves,
        )?;
        images.push(("Reward curves", "reward_curves.png"));
    }
    let timeline: Vec<String> = director
        .events()
        .iter()
        .map(|e| format!("{:>8.3} s  {:<20} {}", e.t_s, e.kind, e.detail))
        .collect();
    report::write_markdown(
        &run.path.join("report.md"),
        summary,
        &timeline,
        &images,
        &[
            ("summary.json", "summary.json"),
            ("verdict timeline (JSONL)", "timeline.jsonl"),
            ("process logs", "logs/"),
            ("world scenes", "world/"),
        ],
    )?;
    Ok(())
}

/// The newest `*.csv` under `dir` (depth ≤ 3).
fn find_csv(dir: &Path) -> Option<PathBuf> {
    fn walk(dir: &Path, depth: u32, best: &mut Option<(std::time::SystemTime, PathBuf)>) {
        let Ok(rd) = std::fs::read_dir(dir) else {
            return;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() && depth < 3 {
                walk(&p, depth + 1, best);
            } else if p.extension().is_some_and(|x| x == "csv")
                && let Ok(m) = e.metadata().and_then(|m| m.modified())
                && best.as_ref().is_none_or(|(t, _)| m > *t)
            {
                *best = Some((m, p));
            }
        }
    }
    let mut best = None;
    walk(dir, 0, &mut best);
    best.map(|(_, p)| p)
}
