//! The processes of one run and how the launcher starts them: `xarm-sim` (unless a real
//! robot is given), `perception`, `learner serve`, `rt-core run` and, with `--ros`, the
//! `ros-bridge`, all under the run's unique service prefix and supervised by
//! [`Supervisor`].
//!
//! Simulation rights go by identity ([`xarm::sim_identity`]): for each run the launcher
//! draws a fresh 32-byte secret and gives it to the `xarm-sim` it starts and to rt-core in
//! their environment (`FORESIGHT_SIM_SECRET`; never on a command line, which every user can
//! read in `/proc`); rt-core grants blind mode, auto-resume and the simulated sensors only
//! to a controller that proves it holds it. With `--robot`, the secret is the operator's
//! (`FORESIGHT_SIM_SECRET` of `foresight`, [`LaunchArgs::check_sim_identity`]), and only
//! asked for when the run needs simulation-only rights.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::args::{DetectorChoice, LaunchArgs, REAL_CAMERA_SOURCES};
use crate::run_dir::RunDir;
use crate::sim_link::{SimPortsSeen, read_sim_ports, sim_status};
use crate::supervisor::{ProcessSpec, Supervisor};
use xarm::sim_identity::{SIM_SECRET_ENV, SimSecret};

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
/// ([`LaunchArgs::check_real_arm_sensors`]; nothing is started either), a `--robot` asked
/// for simulation-only rights that does not prove it is `xarm-sim`
/// ([`LaunchArgs::check_sim_identity`]; nothing is started), a process cannot be started, or
/// `xarm-sim` does not come up within 15 s.
pub fn start_all(
    sup: &mut Supervisor,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
    live: &Path,
) -> Result<Started> {
    args.check_blind_mode()?;
    args.check_real_arm_sensors()?;
    let robot_secret = args.check_sim_identity()?;
    args.check_learner_host()?;
    // An `action` goal source needs the bridge that serves the Reach action.
    let configured = crate::runtime_view::RuntimeView::load(&args.runtime)
        .with_context(|| format!("loading {}", args.runtime.display()))?
        .goal
        .source;
    let goal_source = args.check_goal_source(configured)?;
    // Before anything starts: a `--detector yolo` without its model is refused here, not
    // discovered as a perception process that keeps failing.
    let perception = perception_args(args, prefix, live)?;
    let bins = bin_dir()?;
    let (robot_addr, sim, secret) = match &args.robot {
        Some(host) => (host.clone(), None, robot_secret),
        None => {
            // This run's secret: only the xarm-sim started here and rt-core hold it.
            let secret = SimSecret::generate().context("drawing the simulator's secret")?;
            let ports = start_sim(sup, &bins, args, run, live, &secret)?;
            (
                format!("127.0.0.1:{}", ports.command),
                Some(ports),
                Some(secret),
            )
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
    start_rt_core(
        sup,
        &bins,
        args,
        run,
        prefix,
        robot_addr,
        sim,
        secret.as_ref(),
    )?;
    if args.ros {
        sup.start(ProcessSpec {
            name: "ros-bridge".into(),
            program: bins.join("ros-bridge"),
            args: vec![
                "--prefix".into(),
                prefix.to_owned(),
                "--urdf".into(),
                s(&args.urdf),
                "--runtime".into(),
                s(&args.runtime),
                "--task".into(),
                s(&args.task),
                "--goal-source".into(),
                goal_source.name().into(),
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
    secret: &SimSecret,
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
        env: vec![(SIM_SECRET_ENV.into(), secret.to_hex())],
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
/// `--detector yolo` when that settings file or the model it names is missing; a live
/// camera without a calibration made for a live camera ([`check_camera_calibration`]).
pub fn perception_args(args: &LaunchArgs, prefix: &str, live: &Path) -> Result<Vec<String>> {
    check_camera_calibration(&args.camera, args.calibration.as_deref())?;
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

/// The synthetic camera's frame id, as perception's calibration files name it
/// (`perception::synthetic::SYNTHETIC_CAMERA_FRAME_ID`; the launcher does not link
/// perception, a test ties the two through the bundled calibration).
const SYNTHETIC_CAMERA_FRAME_ID: &str = "foresight_synthetic_camera";

/// A live camera (`--camera ros2`) is measured only with a calibration made for a live
/// camera (issue 30 item 2): `--calibration` must be given, and its `[camera] frame_id` must
/// be there and not the synthetic camera's (the bundled calibration). Refused here, before
/// anything starts; perception checks the same at its start, and checks each image's
/// `header.frame_id` against the file's. [`crate::launch::run_all`] calls it before any run
/// folder is made; [`perception_args`] again.
///
/// # Errors
/// Naming `--calibration` and why.
pub fn check_camera_calibration(camera: &str, calibration: Option<&Path>) -> Result<()> {
    if !REAL_CAMERA_SOURCES.contains(&camera) {
        return Ok(());
    }
    let Some(path) = calibration else {
        bail!(
            "--camera {camera} needs --calibration FILE: a live camera is measured only with a \
             calibration made for it (`perception calibrate --frame-id FRAME_ID …`, README \
             real-arm checklist step 3); the bundled one is the synthetic camera's"
        );
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading --calibration {}", path.display()))?;
    let table: toml::Table = toml::from_str(&text)
        .with_context(|| format!("--calibration {} is not valid TOML", path.display()))?;
    let frame_id = table
        .get("camera")
        .and_then(|c| c.get("frame_id"))
        .and_then(toml::Value::as_str);
    match frame_id {
        None => bail!(
            "--calibration {} has no [camera] frame_id: it does not say which camera it was made \
             for; re-run `perception calibrate --frame-id FRAME_ID …` for this camera",
            path.display()
        ),
        Some(SYNTHETIC_CAMERA_FRAME_ID) => bail!(
            "--calibration {} was made for the synthetic camera ([camera] frame_id = \
             {SYNTHETIC_CAMERA_FRAME_ID:?}), not for a live camera: it is refused with --camera \
             {camera}; calibrate the camera with `perception calibrate --frame-id FRAME_ID …`",
            path.display()
        ),
        Some(_) => Ok(()),
    }
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
            "--publish-delay-s".into(),
            args.learner_delay_s.to_string(),
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

#[allow(clippy::too_many_arguments)]
fn start_rt_core(
    sup: &mut Supervisor,
    bins: &Path,
    args: &LaunchArgs,
    run: &RunDir,
    prefix: &str,
    robot_addr: String,
    sim: Option<SimPortsSeen>,
    secret: Option<&SimSecret>,
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
        // acknowledgement, `rt-core ack --robot HOST`).
        rt_args.extend([
            "--report-port".into(),
            p.report_real.to_string(),
            "--auto-resume".into(),
        ]);
    }
    if args.no_lookahead {
        rt_args.push("--no-lookahead".into());
    }
    // Perception on the synthetic camera, a recording or the bundled calibration: rt-core
    // drives only a controller that proves it is xarm-sim (a dry run sends nothing that
    // moves the arm, and may plan on them for a real one).
    if args.simulated_sensors() && !args.dry_run {
        rt_args.push("--simulated-sensors".into());
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
    if let Some(source) = args.goal_source {
        rt_args.extend(["--goal-source".into(), source.name().into()]);
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
        env: secret
            .map(|s| vec![(SIM_SECRET_ENV.into(), s.to_hex())])
            .unwrap_or_default(),
        restart: false,
    })?;
    // On every way out of the launcher (the end, an error, Ctrl-C) rt-core is stopped
    // first and given the time of its controlled stop (rt-core's own limit is 3 s).
    sup.stop_first("rt-core", RT_CORE_STOP_GRACE);
    Ok(())
}

#[cfg(test)]
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

    /// Issue 30 item 2: `--camera ros2` needs `--calibration`, and not the bundled one (the
    /// synthetic camera's) nor one that names no camera.
    #[test]
    fn a_live_camera_needs_a_calibration_made_for_a_live_camera() {
        let bundled =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/perception/calibration.toml");
        check_camera_calibration("synthetic", None).unwrap();
        check_camera_calibration("synthetic", Some(&bundled)).unwrap();
        check_camera_calibration("file:rec.mp4", None).unwrap();
        let e = format!("{:#}", check_camera_calibration("ros2", None).unwrap_err());
        assert!(e.contains("--camera ros2 needs --calibration FILE"), "{e}");
        let e = format!(
            "{:#}",
            check_camera_calibration("ros2", Some(&bundled)).unwrap_err()
        );
        assert!(
            e.contains("made for the synthetic camera") && e.contains("calibration.toml"),
            "{e}"
        );
        let dir = std::env::temp_dir().join(format!("foresight-cal-cam-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let text = std::fs::read_to_string(&bundled).unwrap();
        let zed = dir.join("zed.toml");
        std::fs::write(
            &zed,
            text.replace(
                &format!("frame_id = {SYNTHETIC_CAMERA_FRAME_ID:?}"),
                "frame_id = \"zed_left_camera_frame_optical\"",
            ),
        )
        .unwrap();
        check_camera_calibration("ros2", Some(&zed)).unwrap();
        let old = dir.join("old.toml");
        std::fs::write(&old, text.replace("[camera]", "[camera_was]")).unwrap();
        let e = format!(
            "{:#}",
            check_camera_calibration("ros2", Some(&old)).unwrap_err()
        );
        assert!(
            e.contains("no [camera] frame_id") && e.contains("old.toml"),
            "{e}"
        );
        let args = launch_args(&["--camera", "ros2"]);
        let e = format!(
            "{:#}",
            perception_args(&args, "p1", Path::new("/live.toml")).unwrap_err()
        );
        assert!(e.contains("--calibration FILE"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
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
