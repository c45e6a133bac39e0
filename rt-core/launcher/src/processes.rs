//! The processes of one run and how the launcher starts them: `xarm-sim` (unless a real
//! robot is given), `perception`, `learner serve`, `rt-core run` and, with `--ros`, the
//! `ros-bridge`, all under the run's unique service prefix and supervised by
//! [`Supervisor`].

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::args::LaunchArgs;
use crate::run_dir::RunDir;
use crate::sim_link::{SimPortsSeen, read_sim_ports, sim_status};
use crate::supervisor::{ProcessSpec, Supervisor};

/// What was started.
#[derive(Debug, Clone, Copy)]
pub struct Started {
    /// The simulated arm's ports (`None` with a real robot).
    pub sim: Option<SimPortsSeen>,
}

/// The folder of the running `foresight` executable (the other binaries sit beside it).
///
/// # Errors
/// The executable cannot be located.
pub fn bin_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating the foresight executable")?;
    Ok(exe.parent().map(Path::to_path_buf).unwrap_or_default())
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Starts every process of the run; `live` is the scene file the world director keeps
/// current.
///
/// # Errors
/// Blind mode with a robot off this machine ([`LaunchArgs::check_blind_mode`]; nothing is
/// started), a process cannot be started, or `xarm-sim` does not come up within 15 s.
pub fn start_all(
    sup: &mut Supervisor,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
    live: &Path,
) -> Result<Started> {
    args.check_blind_mode()?;
    let bins = bin_dir()?;
    let (robot_addr, sim) = match &args.robot {
        Some(host) => (host.clone(), None),
        None => {
            let ports = start_sim(sup, &bins, args, run, live)?;
            (format!("127.0.0.1:{}", ports.command), Some(ports))
        }
    };
    start_perception(sup, &bins, args, prefix, live)?;
    start_learner(sup, &bins, args, run, prefix)?;
    start_rt_core(sup, &bins, args, run, prefix, robot_addr, sim)?;
    if args.ros {
        sup.start(ProcessSpec {
            name: "ros-bridge".into(),
            program: bins.join("ros-bridge"),
            args: vec![
                "--prefix".into(),
                prefix.to_owned(),
                "--urdf".into(),
                s(&args.urdf),
            ],
            env: vec![],
            restart: true,
        })?;
    }
    Ok(Started { sim })
}

/// The simulator binds free ports the OS picks (no clash with another run or with outgoing
/// connections) and announces them in its first stdout line, in its log.
fn start_sim(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    run: &RunDir,
    live: &Path,
) -> Result<SimPortsSeen> {
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
    sim_args.extend(["--scene".into(), s(live), "--urdf".into(), s(&args.urdf)]);
    sup.start(ProcessSpec {
        name: "xarm-sim".into(),
        program: bins.join("xarm-sim"),
        args: sim_args,
        env: vec![],
        restart: false,
    })?;
    let sim_log = run.path.join("logs/xarm-sim.log");
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let _ = sup.poll();
        if let Some(p) = read_sim_ports(&sim_log)
            && sim_status(p.control).is_some()
        {
            return Ok(p);
        }
        if !sup.is_running("xarm-sim") || Instant::now() > deadline {
            bail!("xarm-sim did not come up (see {})", sim_log.display());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn start_perception(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    prefix: &str,
    live: &Path,
) -> Result<()> {
    let source = if args.camera == "synthetic" {
        format!("synthetic:{}", s(live))
    } else {
        args.camera.clone()
    };
    let mut perception_args = vec![
        "run".into(),
        "--source".into(),
        source,
        "--prefix".into(),
        prefix.to_owned(),
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
    Ok(())
}

fn start_learner(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
) -> Result<()> {
    sup.start(ProcessSpec {
        name: "learner".into(),
        program: bins.join("learner"),
        args: vec![
            "serve".into(),
            "--checkpoint".into(),
            s(&args.checkpoint),
            "--prefix".into(),
            prefix.to_owned(),
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
    Ok(())
}

/// How long the launcher waits for rt-core's controlled stop before SIGKILL.
pub const RT_CORE_STOP_GRACE: std::time::Duration = std::time::Duration::from_secs(6);

fn start_rt_core(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
    robot_addr: String,
    sim: Option<SimPortsSeen>,
) -> Result<()> {
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
        prefix.to_owned(),
        "--link".into(),
        "xarm".into(),
        "--robot".into(),
        robot_addr,
        "--policy".into(),
        s(&args.checkpoint.join("policy.blob")),
    ];
    if let Some(p) = sim {
        // xarm-sim: a lost link may resume without an operator (a real arm waits for the
        // acknowledgement, `kill -USR1` of rt-core).
        rt_args.extend([
            "--report-port".into(),
            p.report_real.to_string(),
            "--auto-resume".into(),
        ]);
    }
    if args.no_lookahead {
        rt_args.push("--no-lookahead".into());
    }
    if args.clear_errors {
        rt_args.push("--clear-errors".into());
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
    // On every way out of the launcher (the end, an error, Ctrl-C) rt-core is stopped
    // first and given the time of its controlled stop (rt-core's own limit is 3 s).
    sup.stop_first("rt-core", RT_CORE_STOP_GRACE);
    Ok(())
}
