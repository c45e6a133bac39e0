//! `xarm-sim`: a simulated xArm5 control box on the real controller protocol.
//!
//! Listens on the command port and the four report ports (502, 30000–30003 by default, or
//! shifted with `--port-offset`), plus a line-based control port (`scene <path>`,
//! `status`, `error <code>`, `shutdown`). In servo mode a `servo_j` target that would move
//! the arm too fast raises a protective fault (error 24 or 60), as on the real controller;
//! `--max-joint-speed-rad-s`, `--max-tcp-speed-m-s`, `--servo-period-ms`,
//! `--fault-tolerance` tune it and `--no-protective-faults` turns it off. Prints one JSON line `{"event":"listening",…}` when ready and one
//! `{"event":"summary",…}` line at exit (SIGINT, SIGTERM or `shutdown`).
//!
//! Its identity: with the run's secret in `FORESIGHT_SIM_SECRET` (64 hex digits; the
//! launcher draws one per run and gives it to `xarm-sim` and `rt-core`, never on a command
//! line) it proves to rt-core that it is `xarm-sim` ([`xarm::sim_identity`]), which is what
//! grants a run blind mode, auto-resume and the synthetic camera. Without it, it passes for
//! a real arm on 127.0.0.1.
//!
//! ```text
//! xarm-sim --port-offset 10000 --scene assets/scenes/small_box.toml \
//!          --swap-scene-at 10s assets/scenes/tall_box.toml
//! ```

#![forbid(unsafe_code)]

use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Parser;
use shm_schemas::cli_bounds::{f64_within, int_within};
use shm_schemas::scene_file::{LiveScene, SceneFile, WorldScript};
use xarm::sim_identity::{SIM_SECRET_ENV, SimSecret};
use xarm_sim::server::default_urdf;
use xarm_sim::world::World;
use xarm_sim::{ProtectiveLimits, SimOptions, SimPorts, SimServer};

/// Simulated xArm5 controller.
#[derive(Debug, Parser)]
#[command(name = "xarm-sim", version, about)]
struct Args {
    /// Address to bind.
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Added to every default port (502, 30000–30003, control 30010).
    #[arg(long, default_value_t = 0, value_parser = int_within(0u16, 35_000), allow_negative_numbers = true)]
    port_offset: u16,
    /// Command port (overrides the offset).
    #[arg(long, allow_negative_numbers = true)]
    command_port: Option<u16>,
    /// Real-time report port (30000).
    #[arg(long, allow_negative_numbers = true)]
    report_rt_port: Option<u16>,
    /// Normal report port (30001).
    #[arg(long, allow_negative_numbers = true)]
    report_normal_port: Option<u16>,
    /// Rich report port (30002).
    #[arg(long, allow_negative_numbers = true)]
    report_rich_port: Option<u16>,
    /// Real report port (30003).
    #[arg(long, allow_negative_numbers = true)]
    report_real_port: Option<u16>,
    /// Control port (line-based: `scene <path>`, `status`, `shutdown`).
    #[arg(long, allow_negative_numbers = true)]
    control_port: Option<u16>,
    /// Ground-truth scene at start (a live scene file's `in_force_since_monotonic_ns` is the
    /// origin of its boxes' paths; without it, the simulator's start).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// World script (timeline of scenes); combined with `--scene` and `--swap-scene-at`.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Swap the scene at a time: `--swap-scene-at 10s tall.toml` (repeatable).
    #[arg(long, num_args = 2, value_names = ["TIME", "SCENE"], action = clap::ArgAction::Append)]
    swap_scene_at: Vec<String>,
    /// Robot model.
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// Contact margin (m).
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 0.5), allow_negative_numbers = true)]
    contact_margin_m: f64,
    /// Initial joints, 5 comma-separated values (rad); default: the model's home posture.
    #[arg(long, value_delimiter = ',', num_args = 5, value_parser = f64_within(-7.0, 7.0), allow_hyphen_values = true)]
    q0_rad: Option<Vec<f64>>,
    /// Protective fault: joint speed limit (rad/s) a servo_j target may ask for.
    #[arg(long, default_value_t = xarm_sim::controller::MAX_JOINT_SPEED_RAD_S, value_parser = f64_within(0.001, 100.0), allow_negative_numbers = true)]
    max_joint_speed_rad_s: f64,
    /// Protective fault: TCP speed limit (m/s) a servo_j target may ask for.
    #[arg(long, default_value_t = xarm_sim::controller::MAX_TCP_SPEED_M_S, value_parser = f64_within(0.001, 100.0), allow_negative_numbers = true)]
    max_tcp_speed_m_s: f64,
    /// Protective fault: the servo period one target is executed in (ms).
    #[arg(long, default_value_t = 1e3 * xarm_sim::controller::SERVO_PERIOD_S, value_parser = f64_within(0.1, 1000.0), allow_negative_numbers = true)]
    servo_period_ms: f64,
    /// Protective fault: relative slack above the limits (0.25 = 25 %).
    #[arg(long, default_value_t = xarm_sim::controller::FAULT_TOLERANCE, value_parser = f64_within(0.0, 10.0), allow_negative_numbers = true)]
    fault_tolerance: f64,
    /// Turn the protective faults (joint and TCP speed) off.
    #[arg(long)]
    no_protective_faults: bool,
}

fn parse_time_s(s: &str) -> Result<f64> {
    let t = s.trim();
    let (num, scale) = if let Some(v) = t.strip_suffix("ms") {
        (v, 1e-3)
    } else if let Some(v) = t.strip_suffix('s') {
        (v, 1.0)
    } else {
        (t, 1.0)
    };
    let v: f64 = num.parse().with_context(|| format!("bad time {s:?}"))?;
    if !v.is_finite() || v < 0.0 {
        bail!("bad time {s:?}");
    }
    Ok(v * scale)
}

fn options(a: &Args) -> Result<SimOptions> {
    let mut ports = SimPorts::with_offset(a.port_offset);
    let set = |p: &mut u16, v: Option<u16>| {
        if let Some(v) = v {
            *p = v;
        }
    };
    set(&mut ports.command, a.command_port);
    set(&mut ports.report_rt, a.report_rt_port);
    set(&mut ports.report_normal, a.report_normal_port);
    set(&mut ports.report_rich, a.report_rich_port);
    set(&mut ports.report_real, a.report_real_port);
    set(&mut ports.control, a.control_port);
    let mut scenes: Vec<(f64, SceneFile)> = Vec::new();
    let mut first_scene_in_force_since_ns = None;
    if let Some(w) = &a.world {
        let script =
            WorldScript::load(w).with_context(|| format!("world script {}", w.display()))?;
        scenes.extend(script.steps);
    }
    if let Some(s) = &a.scene {
        let live = LiveScene::load(s).with_context(|| format!("scene {}", s.display()))?;
        scenes.retain(|(at, _)| *at > 0.0);
        scenes.push((0.0, live.scene));
        first_scene_in_force_since_ns = live.in_force_since_monotonic_ns;
    }
    for pair in a.swap_scene_at.chunks(2) {
        let [t, path] = pair else {
            bail!("--swap-scene-at needs TIME SCENE")
        };
        let scene =
            SceneFile::load(&PathBuf::from(path)).with_context(|| format!("scene {path}"))?;
        scenes.push((parse_time_s(t)?, scene));
    }
    scenes.sort_by(|x, y| x.0.total_cmp(&y.0));
    let urdf = a.urdf.clone().unwrap_or_else(default_urdf);
    let q0_rad = match &a.q0_rad {
        Some(v) => {
            let mut q = [0.0; 5];
            q.copy_from_slice(&v[..5]);
            q
        }
        None => World::load(&urdf, 0.0)?.home(),
    };
    let protective = ProtectiveLimits {
        enabled: !a.no_protective_faults,
        max_joint_speed_rad_s: a.max_joint_speed_rad_s,
        max_tcp_speed_m_s: a.max_tcp_speed_m_s,
        servo_period_s: a.servo_period_ms * 1e-3,
        tolerance: a.fault_tolerance,
    };
    protective.validate().map_err(|e| {
        let flag = match e.field {
            "max_joint_speed_rad_s" => "--max-joint-speed-rad-s",
            "max_tcp_speed_m_s" => "--max-tcp-speed-m-s",
            "servo_period_s" => "--servo-period-ms",
            _ => "--fault-tolerance",
        };
        anyhow::anyhow!("{flag}: {e}")
    })?;
    let sim_secret = SimSecret::from_env().with_context(|| format!("reading {SIM_SECRET_ENV}"))?;
    Ok(SimOptions {
        sim_secret,
        bind: a.bind,
        ports,
        urdf,
        scenes,
        first_scene_in_force_since_ns,
        contact_margin_m: a.contact_margin_m,
        q0_rad,
        protective,
    })
}

fn run() -> Result<()> {
    let args = Args::parse();
    let opts = options(&args)?;
    let stop = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGINT, stop.clone())?;
    signal_hook::flag::register(signal_hook::consts::SIGTERM, stop.clone())?;
    if opts.sim_secret.is_some() {
        tracing::info!("{SIM_SECRET_ENV} set: this simulator proves it is xarm-sim");
    } else {
        tracing::warn!(
            "no {SIM_SECRET_ENV}: this simulator cannot prove it is xarm-sim and is treated as \
             a real arm (no blind mode, auto-resume or synthetic camera)"
        );
    }
    let server = SimServer::start(opts).context("starting xarm-sim")?;
    println!(
        "{}",
        serde_json::json!({ "event": "listening", "ports": server.ports() })
    );
    while !stop.load(Ordering::Relaxed) && !server.shutdown_requested() {
        std::thread::sleep(Duration::from_millis(20));
    }
    let summary = server.shutdown();
    let mut v = serde_json::to_value(&summary)?;
    if let Some(o) = v.as_object_mut() {
        o.insert("event".into(), "summary".into());
    }
    println!("{v}");
    Ok(())
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .init();
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xarm-sim: {e:#}");
            ExitCode::FAILURE
        }
    }
}
