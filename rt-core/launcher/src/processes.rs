//! The processes of one run and how the launcher starts them: `xarm-sim` (unless a real
//! robot is given), `perception`, `learner serve`, `rt-core run` and, with `--ros`, the
//! `ros-bridge`, all under the run's unique service prefix and supervised by
//! [`Supervisor`].

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::args::{DetectorChoice, LaunchArgs};
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

/// The `SCHED_FIFO` priority the launcher asks for rt-core's cycle thread: above the kernel's
/// default threaded IRQ handlers (50), below the watchdog-class threads (99).
pub const RT_CORE_PRIORITY: i32 = 80;

/// Starts every process of the run; `live` is the scene file the world director keeps
/// current.
///
/// # Errors
/// Blind mode with a robot off this machine ([`LaunchArgs::check_blind_mode`]), a robot
/// off this machine without a live camera and an explicit calibration
/// ([`LaunchArgs::check_real_arm_sensors`]; nothing is started either), a process cannot be started, or `xarm-sim` does not come up within 15 s.
pub fn start_all(
    sup: &mut Supervisor,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
    live: &Path,
) -> Result<Started> {
    args.check_blind_mode()?;
    args.check_real_arm_sensors()?;
    args.check_learner_host()?;
    // Before anything starts: a `--detector yolo` without its model is refused here, not
    // discovered as a perception process that keeps failing.
    let perception = perception_args(args, prefix, live)?;
    let bins = bin_dir()?;
    let (robot_addr, sim) = match &args.robot {
        Some(host) => (host.clone(), None),
        None => {
            let ports = start_sim(sup, &bins, args, run, live)?;
            (format!("127.0.0.1:{}", ports.command), Some(ports))
        }
    };
    sup.start(ProcessSpec {
        name: "perception".into(),
        program: bins.join("perception"),
        args: perception,
        env: vec![],
        restart: true,
    })?;
    if args.learner_host {
        start_relay(sup, &bins, args, run, prefix)?;
    } else {
        start_learner(sup, &bins, args, run, prefix)?;
    }
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

/// The arguments of `perception run` for this run: the camera (the live scene file for the
/// synthetic one), the service prefix, the frame rate, a real camera's calibration and, with
/// `--detector yolo`, `--yolo-config <assets>/perception/yolo.toml` (the assets folder is
/// the one of `--task`, as for rt-core's `--assets`).
///
/// # Errors
/// `--detector yolo` when that settings file or the model it names is missing.
pub fn perception_args(args: &LaunchArgs, prefix: &str, live: &Path) -> Result<Vec<String>> {
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
    match args.detector {
        DetectorChoice::Colour => {}
        DetectorChoice::Yolo => {
            let config = args.assets_dir().join("perception/yolo.toml");
            check_yolo_config(&config)?;
            perception_args.extend(["--yolo-config".into(), s(&config)]);
        }
    }
    Ok(perception_args)
}

/// The YOLO settings file exists and the model it names (`model`, relative to the file's
/// folder) is there; the rest is perception's to check.
fn check_yolo_config(config: &Path) -> Result<()> {
    let text = std::fs::read_to_string(config).with_context(|| {
        format!(
            "--detector yolo needs the YOLO settings file {}",
            config.display()
        )
    })?;
    let table: toml::Table = toml::from_str(&text)
        .with_context(|| format!("--detector yolo: {} is not valid TOML", config.display()))?;
    if let Some(model) = table.get("model").and_then(toml::Value::as_str) {
        let path = config.parent().unwrap_or(Path::new(".")).join(model);
        if !path.is_file() {
            bail!(
                "--detector yolo: the model {} named in {} is missing (scripts/train-yolo.sh makes it)",
                path.display(),
                config.display()
            );
        }
    }
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

/// The relay's status file in the run folder (read into the report).
pub const RELAY_STATUS: &str = "relay.json";

/// `--learner-host`: the controller side of `zenoh-relay` instead of a local learner. It is
/// restarted if it dies; rt-core keeps its running policy meanwhile, and the relay sends
/// the last retrain request again when it is back (iceoryx2 keeps it in the service's
/// history).
fn start_relay(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
) -> Result<()> {
    let mut relay_args = vec![
        "controller".into(),
        "--prefix".into(),
        prefix.to_owned(),
        "--status".into(),
        s(&run.file(RELAY_STATUS)?),
    ];
    relay_args.extend(args.link.to_args());
    sup.start(ProcessSpec {
        name: "zenoh-relay".into(),
        program: bins.join("zenoh-relay"),
        args: relay_args,
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
    // The cycle thread asks for SCHED_FIFO and the machine's last core (issue 33: reaction
    // depends on the cycle being real-time where it runs); where the OS refuses either, rt-core
    // runs on and its summary line (`"rt"`, copied into the run's summary.json) says so.
    let last_cpu = std::thread::available_parallelism().map_or(0, |n| n.get() - 1);
    rt_args.extend([
        "--rt-priority".into(),
        RT_CORE_PRIORITY.to_string(),
        "--cpu".into(),
        last_cpu.to_string(),
    ]);
    rt_args.extend([
        "--planner-fallback".into(),
        args.planner_fallback.name().into(),
    ]);
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use clap::Parser;

    fn launch_args(extra: &[&str]) -> LaunchArgs {
        LaunchArgs::parse_from(std::iter::once("foresight").chain(extra.iter().copied()))
    }

    fn value_after<'a>(args: &'a [String], flag: &str) -> Option<&'a str> {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .map(String::as_str)
    }

    #[test]
    fn perception_gets_the_yolo_settings_of_the_assets_folder_only_with_detector_yolo() {
        let dir = std::env::temp_dir().join(format!("foresight-perc-args-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("perception/models")).unwrap();
        let task = dir.join("task.toml");
        let live = Path::new("/run/world/live.toml");
        let config = dir.join("perception/yolo.toml");

        let colour = perception_args(
            &launch_args(&["--task", task.to_str().unwrap()]),
            "p1",
            live,
        )
        .unwrap();
        assert_eq!(
            colour,
            [
                "run",
                "--source",
                "synthetic:/run/world/live.toml",
                "--prefix",
                "p1",
                "--rate",
                "60"
            ]
        );

        let yolo = launch_args(&["--task", task.to_str().unwrap(), "--detector", "yolo"]);
        // No settings file, then a file naming a model that is not there: refused, named.
        let e = perception_args(&yolo, "p1", live).unwrap_err();
        assert!(format!("{e:#}").contains("yolo.toml"), "{e:#}");
        std::fs::write(&config, "model = \"models/m.onnx\"\n").unwrap();
        let e = perception_args(&yolo, "p1", live).unwrap_err();
        assert!(format!("{e:#}").contains("m.onnx"), "{e:#}");
        std::fs::write(dir.join("perception/models/m.onnx"), b"onnx").unwrap();
        let a = perception_args(&yolo, "p1", live).unwrap();
        assert_eq!(
            value_after(&a, "--yolo-config"),
            Some(config.to_str().unwrap())
        );
        assert_eq!(
            value_after(&a, "--source"),
            Some("synthetic:/run/world/live.toml")
        );
        assert_eq!(a.iter().filter(|x| *x == "--yolo-config").count(), 1);
        std::fs::remove_dir_all(&dir).ok();
    }
}
