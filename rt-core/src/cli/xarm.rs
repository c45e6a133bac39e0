//! `rt-core xarm …`: driver tools. `probe` connects with our driver and prints the
//! controller's version, state, mode, error/warning and joint state as one JSON object; with
//! `--servo-test` it also streams a small, safe J1-only motion (a few degrees, 100 Hz, smooth
//! start and stop) and reports round-trip timing. It refuses to move when the controller has
//! an error or is paused/resetting.
//!
//! One owner per arm: `--servo-test` moves the arm, so it takes the arm's lock
//! ([`xarm::owner::ArmLock`]) before connecting and is refused while `rt-core run` (or another
//! servo test) drives the same controller. The plain probe only reads (`GET_*` requests) and
//! takes no lock, so it can look at an arm another process drives.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use serde_json::json;
use shm_schemas::cli_bounds::{f64_within, int_within};
use xarm::codes::ControllerError;
use xarm::driver::{XArmConfig, XArmDriver};
use xarm::owner::ArmLock;

/// xArm driver tools.
#[derive(Debug, Subcommand)]
pub enum XarmCommand {
    /// Connect, print the controller's state as JSON; optionally run a small servo test.
    Probe(ProbeArgs),
}

/// `xarm probe` arguments.
#[derive(Debug, Args)]
pub struct ProbeArgs {
    /// Controller address, `HOST[:PORT]` (command port, default 502).
    #[arg(long)]
    addr: String,
    /// Report port (the 100 Hz "real" report; default 30003).
    #[arg(long, default_value_t = 30003, value_parser = int_within(1u16, u16::MAX), allow_negative_numbers = true)]
    report_port: u16,
    /// Stream a small J1 motion at 100 Hz and report round-trip timing.
    #[arg(long)]
    servo_test: bool,
    /// Peak J1 excursion of the servo test (degrees, at most 5).
    #[arg(long, default_value_t = 2.0, value_parser = f64_within(0.0, 5.0), allow_negative_numbers = true)]
    amplitude_deg: f64,
    /// Duration of the servo test (s).
    #[arg(long, default_value_t = 2.0, value_parser = f64_within(0.0, 600.0), allow_negative_numbers = true)]
    duration_s: f64,
}

/// Runs an xarm tool.
pub fn run(cmd: XarmCommand) -> ExitCode {
    let XarmCommand::Probe(args) = cmd;
    match probe(&args) {
        Ok(v) => {
            println!("{v}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            println!("{}", json!({ "ok": false, "error": format!("{e:#}") }));
            ExitCode::FAILURE
        }
    }
}

fn percentile_us(sorted_ns: &[u64], q: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted_ns.len() - 1) as f64 * q).round() as usize;
    sorted_ns[i] as f64 / 1000.0
}

fn probe(a: &ProbeArgs) -> Result<serde_json::Value> {
    let mut cfg = XArmConfig::from_addr(&a.addr);
    cfg.report_port = a.report_port;
    // Moving needs the arm to ourselves: the lock is taken before connecting, and held to
    // the end of the probe.
    let _owner = if a.servo_test {
        Some(ArmLock::acquire(&cfg).with_context(|| format!("--servo-test on {}", a.addr))?)
    } else {
        None
    };
    let mut d = XArmDriver::connect(cfg).with_context(|| format!("connecting to {}", a.addr))?;
    let version = d
        .version()
        .map(|v| v.as_str().to_string())
        .unwrap_or_default();
    let state = d.get_state()?;
    let (err, warn) = d.refresh_error()?;
    let joints = d.get_joints()?;
    let pose = d.get_tcp_pose()?;
    let mode = d.last_state().map(|s| s.report.mode);
    let mut out = json!({
        "ok": true,
        "addr": a.addr,
        "version": version,
        "state": state,
        "mode": mode,
        "error_code": u8::from(err),
        "error": err.to_string(),
        "warning_code": u8::from(warn),
        "joints_rad": joints,
        "tcp_pose_mm_rad": pose,
    });
    if a.servo_test {
        check_servo_test(a, err, state)?;
        out["servo_test"] = servo_test(&mut d, a)?;
    }
    Ok(out)
}

/// Refuses the servo test on a controller with an error, paused or resetting, and outside
/// its bounds.
fn check_servo_test(a: &ProbeArgs, err: ControllerError, state: u8) -> Result<()> {
    if err != ControllerError::None {
        bail!("refusing to move: the controller reports error {err}");
    }
    if !matches!(state, 1 | 2 | 4) {
        bail!("refusing to move: the controller is in state {state} (paused or resetting)");
    }
    if !(a.amplitude_deg > 0.0 && a.amplitude_deg <= 5.0) {
        bail!("--amplitude-deg must be in (0, 5]");
    }
    if !(a.duration_s >= 0.5 && a.duration_s <= 10.0) {
        bail!("--duration-s must be in [0.5, 10]");
    }
    Ok(())
}

/// Streams the J1-only motion at 100 Hz (a raised cosine of `amplitude_deg`), stops the
/// controller, and reports the replies' round-trip times.
fn servo_test(d: &mut XArmDriver, a: &ProbeArgs) -> Result<serde_json::Value> {
    let q0 = d.enter_servo_mode().context("entering servo mode")?;
    let amp_rad = a.amplitude_deg.to_radians();
    let period = Duration::from_millis(10);
    let n = (a.duration_s / 0.01).round() as u32;
    let origin = Instant::now();
    let now_ns = || origin.elapsed().as_nanos() as u64;
    let mut rtt_ns = Vec::with_capacity(n as usize);
    let mut next = Instant::now();
    for k in 0..=n {
        let phase = f64::from(k) / f64::from(n);
        let mut q = q0;
        q[0] += amp_rad * 0.5 * (1.0 - (2.0 * std::f64::consts::PI * phase).cos());
        d.send_servo(now_ns(), &q).context("servo_j")?;
        // Wait for this target's reply (bounded), polling the socket.
        let deadline = Instant::now() + Duration::from_millis(8);
        while d.in_flight() > 0 && Instant::now() < deadline {
            let _ = d.read_state(now_ns());
            std::thread::sleep(Duration::from_micros(50));
        }
        if d.in_flight() == 0 {
            rtt_ns.push(d.stats().last_rtt_ns);
        }
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
    }
    d.flush()?;
    let final_joints = d.get_joints()?;
    d.stop(now_ns());
    d.flush()?;
    rtt_ns.sort_unstable();
    Ok(json!({
        "targets": n + 1,
        "rate_hz": 100,
        "amplitude_deg": a.amplitude_deg,
        "replies_timed": rtt_ns.len(),
        "rtt_us": {
            "p50": percentile_us(&rtt_ns, 0.5),
            "p90": percentile_us(&rtt_ns, 0.9),
            "p99": percentile_us(&rtt_ns, 0.99),
            "max": percentile_us(&rtt_ns, 1.0),
        },
        "not_ready_replies": d.stats().not_ready_replies,
        "final_joints_rad": final_joints,
    }))
}
