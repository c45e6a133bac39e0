//! `rt-core run --config FILE`: argument parsing and wiring of the runtime
//! ([`rt_core::twin_thread::serve`]) around a robot link: `--link sim` (the in-process
//! simulated arm) or `--link xarm --robot HOST` (a real xArm5 or `xarm-sim`). `--dry-run`
//! computes and logs every command and sends none; `--no-lookahead` runs the policy blind,
//! and only on a loopback robot address (`xarm-sim` on this machine): it is refused, before
//! any connection, for any other (`check_blind_mode_target`).
//!
//! Every simulation-only right (`--no-lookahead`, `--auto-resume`, `--simulated-sensors`)
//! goes by identity too, not by address alone: rt-core reads the run's secret from
//! `FORESIGHT_SIM_SECRET` (the launcher draws one per run and gives it to the `xarm-sim` it
//! starts and to rt-core, in the environment, never on a command line) and the controller
//! must prove it holds it right after `GET_VERSION`, before anything else is sent
//! ([`rt_core::cycle::xarm_link::SimRights`], [`xarm::sim_identity`]). Without the secret,
//! or without the proof, the arm is a real arm and the run is refused, naming the flags.
//!
//! rt-core is tied to its parent, whoever started it: it asks the kernel for SIGTERM when
//! the parent dies (`PR_SET_PDEATHSIG`), and SIGTERM is the runtime's controlled stop (the
//! arm brakes to rest, the controller is put in its stop state, then the process exits).
//! So is every other signal whose default action would end the process (SIGHUP, SIGQUIT,
//! SIGUSR2, SIGALRM, …; [`rt_core::rt::process_stop`]): their handlers are installed first
//! thing, before any connection; one that arrives while connecting stops the run at its
//! first cycle. SIGPIPE never ends the process, and a SIGUSR1 before the runtime listens
//! for acknowledgements is dropped. In a `panic = "abort"` build (`--profile deploy`) a
//! panic off the cycle thread brakes the arm before the abort. With `--link xarm` the arm's
//! lock is taken before connecting
//! ([`rt_core::cycle::xarm_link::open_xarm`]): a second rt-core on the same controller is
//! refused with the holder named.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use rt_core::config::RuntimeConfig;
use rt_core::cycle::link::{InProcessArm, RobotLink};
use rt_core::cycle::shield::ShieldLimits;
use rt_core::cycle::xarm_link::{
    AUTO_RESUME_FLAG, BLIND_MODE_FLAG, SIMULATED_SENSORS, SimRights, XArmOpenError,
    XArmOpenOptions, check_auto_resume_target, check_blind_mode_target, open_xarm, sim_rights_for,
};
use rt_core::rt::process_stop;
use rt_core::twin_thread::serve::{
    AckChannelOptions, InjectedFault, SHUTDOWN_TIMEOUT, ServeOptions, serve_on,
};
use shm_schemas::cli_bounds::{f64_within, int_within};
use twin::{RobotModel, TaskConfig};

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
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 1e7), allow_negative_numbers = true)]
    seconds: f64,
    /// Service-name prefix (overrides the config's `service_prefix`; the launcher gives
    /// every run a unique one).
    #[arg(long)]
    prefix: Option<String>,
    /// Report port of the arm for `--link xarm` (default: the real controller's 30003).
    #[arg(long, value_parser = int_within(1u16, u16::MAX), allow_negative_numbers = true)]
    report_port: Option<u16>,
    /// Operator action: clear the controller's error and warning at start before entering
    /// servo mode. Without it rt-core never sends CLEAN_ERROR: an error at start is
    /// reported and the run refused.
    #[arg(long)]
    clear_errors: bool,
    /// After a lost link returns, take fresh plans (and re-enter servo mode) without an
    /// operator's acknowledgement. For simulated arms (`xarm-sim`, `--link sim`) only: a
    /// real arm waits for the operator's `rt-core ack --robot HOST` (the acknowledgement;
    /// README.md, "Driving a real xArm5 — checklist").
    /// With `--link xarm` it is refused, before any connection, unless `--robot` is (or
    /// resolves only to) a loopback address, as `--no-lookahead` is, and then granted only
    /// to a controller that proves at connect it is xarm-sim holding FORESIGHT_SIM_SECRET.
    #[arg(long)]
    auto_resume: bool,
    /// The run's camera is simulated (the launcher's synthetic camera, a recording, or the
    /// bundled calibration): with `--link xarm`, refuse a robot that is not (or does not
    /// resolve only to) a loopback address, and a controller that does not prove at connect
    /// that it is xarm-sim holding FORESIGHT_SIM_SECRET (a real arm is driven only from a
    /// live camera and an explicit calibration). The launcher passes it.
    #[arg(long)]
    simulated_sensors: bool,
    /// Test hook: inject a fault to exercise an exit path (`twin-panic:MS`, a twin-thread
    /// panic MS ms after a plan starts). Hidden; never for operation.
    #[arg(long, hide = true)]
    inject_fault: Option<InjectedFault>,
    /// A policy blob file to start with (e.g. assets/policy/policy.blob); it is validated
    /// and must pass the lookahead like any policy the learner sends.
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Blind run, a simulation-only demonstration of what Foresight prevents: execute the
    /// policy's plans whatever the lookahead says, and leave the obstacle boxes out of the
    /// shield's clearance check (the table clearance, joint, workspace and speed limits
    /// still hold). With `--link xarm` it is refused, before any connection, unless
    /// `--robot` is (or resolves only to) a loopback address (127.0.0.0/8, ::1, localhost),
    /// and then granted only to a controller that proves at connect it is xarm-sim holding
    /// the run's secret (FORESIGHT_SIM_SECRET, which the launcher sets).
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
    /// Record the run to this MCAP file (ROS 2 messages with their schemas: `ros2 bag
    /// info`/`play` and Foxglove open it), written by a normal thread subscribed to the run's
    /// services, never by the cycle. Off unless given: the launcher records every run itself
    /// (`runs/<run>/run.mcap`), and a bare `rt-core run` under a service manager writes no
    /// file it was not asked for.
    #[arg(long)]
    record: Option<PathBuf>,
    /// When no policy passes the lookahead, move the arm along the feasibility planner's
    /// checked path while the learner retrains (overrides the config's
    /// `planner_fallback.enabled`).
    #[arg(long, value_enum)]
    planner_fallback: Option<Switch>,
    /// Where the goal comes from: `camera` (the goal cube perception sees) or `action` (the
    /// ROS 2 `Reach` action served by ros-bridge). Overrides the config's `goal.source`.
    #[arg(long, value_enum)]
    goal_source: Option<GoalSourceArg>,
}

/// `camera` or `action` (`--goal-source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GoalSourceArg {
    /// The camera's goal cube.
    Camera,
    /// The ROS 2 `Reach` action.
    Action,
}

/// `on` or `off`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Switch {
    /// On.
    On,
    /// Off.
    Off,
}

/// How long a panic (deploy build, `panic = "abort"`) waits for the cycle to brake the arm
/// and put the controller in its stop state before the process aborts: the cycle's own
/// shutdown bound plus the controller's `SET_STATE 4` round trips (up to 3 s).
const PANIC_BRAKE_WAIT: std::time::Duration =
    SHUTDOWN_TIMEOUT.saturating_add(std::time::Duration::from_secs(4));

/// Runs the runtime.
pub fn run(args: RunArgs) -> ExitCode {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        // A log line that cannot be written (stderr on a full disk, a closed pipe) is lost,
        // never reported with `eprintln!`, which panics there — and in the deploy build a
        // panic of the log thread aborted rt-core without braking (issue 30 item 4).
        .log_internal_errors(false)
        .try_init();
    match runtime(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("rt-core run: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Asks the kernel to send this process SIGTERM when its parent dies, then checks that the
/// parent did not die before the request took effect (we would be re-parented and never
/// get the signal).
fn stop_with_parent() -> anyhow::Result<()> {
    let parent = std::os::unix::process::parent_id();
    if let Err(e) = shm_schemas::process_ties::stop_with_parent() {
        anyhow::bail!("prctl(PR_SET_PDEATHSIG): {e}");
    }
    let now = std::os::unix::process::parent_id();
    if now != parent {
        anyhow::bail!(
            "the parent process (pid {parent}) ended while rt-core was starting; not starting"
        );
    }
    Ok(())
}

fn runtime(args: &RunArgs) -> anyhow::Result<()> {
    // First, before anything can move: every signal that would end the process becomes a
    // controlled stop, SIGPIPE and an early SIGUSR1 are harmless, and (deploy builds) a
    // panic brakes before the abort.
    process_stop::install_signal_handlers()?;
    process_stop::install_panic_hook(PANIC_BRAKE_WAIT);
    stop_with_parent()?;
    // iceoryx2's configuration from the installed assets, wherever the process started.
    shm_schemas::services::set_assets_dir(&args.assets);
    // Blind mode never reaches a real arm: decided from the address alone, first.
    if args.no_lookahead
        && args.link == LinkKind::Xarm
        && let Some(host) = args.robot.as_deref()
    {
        check_blind_mode_target(host)?;
    }
    // Neither does resuming without the operator: the same address check.
    if args.auto_resume
        && args.link == LinkKind::Xarm
        && let Some(host) = args.robot.as_deref()
    {
        check_auto_resume_target(host)?;
    }
    // And each of them, with the simulated sensors, needs the run's secret: the controller
    // proves at connect that it is xarm-sim, or it is a real arm.
    let sim_rights = sim_rights(args)?;
    let (mut cfg, model, task) = load_assets(&args.assets, None, Some(&args.config))?;
    if let Some(switch) = args.planner_fallback {
        cfg.planner_fallback.enabled = switch == Switch::On;
    }
    match args.goal_source {
        Some(GoalSourceArg::Camera) => cfg.goal.source = rt_core::config::GoalSource::Camera,
        Some(GoalSourceArg::Action) => cfg.goal.source = rt_core::config::GoalSource::Action,
        None => {}
    }
    let opts = ServeOptions {
        prefix: args
            .prefix
            .clone()
            .unwrap_or_else(|| cfg.service_prefix.clone()),
        seconds: args.seconds,
        no_lookahead: args.no_lookahead,
        dry_run: args.dry_run,
        command_log: args.command_log.clone(),
        policy: args.policy.clone(),
        rt: args.rt.request(),
        auto_resume: args.auto_resume,
        inject: args.inject_fault,
        ack_channel: ack_channel(args, &cfg)?,
    };
    // The recorder subscribes before the runtime starts; a recording that was asked for and
    // cannot start stops the run here, before anything moves.
    let recording = match &args.record {
        Some(path) => {
            let urdf_path = args.assets.join("xarm5.urdf");
            let urdf = std::fs::read_to_string(&urdf_path)
                .with_context(|| format!("--record: reading {}", urdf_path.display()))?;
            let cfg = recorder::RecorderConfig::new(path.clone(), &opts.prefix, urdf);
            Some(recorder::Recorder::start(cfg).context("--record")?)
        }
        None => None,
    };
    let served = serve_link(args, &opts, cfg, model, task, sim_rights);
    if let Some(r) = recording {
        let path = r.path().display().to_string();
        match r.stop() {
            Ok(stats) => tracing::info!(%path, messages = stats.total(), "recording closed"),
            Err(e) => tracing::warn!(%path, "recording ended badly: {e}"),
        }
    }
    served
}

/// The operator's acknowledgement channel of an xArm link: beside the arm's lock file.
fn ack_channel(args: &RunArgs, cfg: &RuntimeConfig) -> anyhow::Result<Option<AckChannelOptions>> {
    let (LinkKind::Xarm, Some(host)) = (args.link, args.robot.as_deref()) else {
        return Ok(None);
    };
    let lock = xarm::owner::lock_path(&xarm::config::XArmConfig::from_addr(host))
        .with_context(|| format!("--robot {host}"))?;
    Ok(Some(AckChannelOptions {
        path: rt_core::operator_ack::socket_path(&lock),
        extra_uids: cfg.operator.ack_uids.clone(),
    }))
}

/// The simulation-only rights `args` asks of an xArm link (`None` without any, or for the
/// in-process arm), with the run's secret from `FORESIGHT_SIM_SECRET`: refused before any
/// connection off loopback or without the secret.
fn sim_rights(args: &RunArgs) -> anyhow::Result<Option<SimRights>> {
    let (LinkKind::Xarm, Some(host)) = (args.link, args.robot.as_deref()) else {
        return Ok(None);
    };
    let asked: Vec<_> = [
        (args.no_lookahead, BLIND_MODE_FLAG),
        (args.auto_resume, AUTO_RESUME_FLAG),
        (args.simulated_sensors, SIMULATED_SENSORS),
    ]
    .into_iter()
    .filter_map(|(on, right)| on.then_some(right))
    .collect();
    if asked.is_empty() {
        return Ok(None);
    }
    Ok(sim_rights_for(
        host,
        &asked,
        xarm::sim_identity::SimSecret::from_env(),
    )?)
}

/// Opens the robot link `args` asks for and serves on it.
fn serve_link(
    args: &RunArgs,
    opts: &ServeOptions,
    cfg: RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    sim_rights: Option<SimRights>,
) -> anyhow::Result<()> {
    match args.link {
        LinkKind::Sim => {
            let arm = InProcessArm::new(
                task.start.joints_rad,
                cfg.limits.joint_min_rad,
                cfg.limits.joint_max_rad,
                [std::f64::consts::PI; 5],
            );
            run_on(opts, &cfg, model, task, arm)
        }
        LinkKind::Xarm => {
            let host = args
                .robot
                .as_deref()
                .context("--link xarm needs --robot HOST")?;
            cfg.check_for_xarm_link()
                .with_context(|| format!("{}", args.config.display()))?;
            let open = XArmOpenOptions {
                report_port: args.report_port,
                dry_run: args.dry_run,
                clear_errors: args.clear_errors,
                max_resume_step_rad: ShieldLimits::from_config(&cfg.limits, &cfg.shield)
                    .max_step_rad(1.0 / cfg.rate_hz),
                resume_after_reconnect: args.auto_resume,
                max_tcp_gap_m: cfg.shield.max_tcp_gap_m,
                sim_rights,
            };
            let link = open_xarm(host, &open, &model).map_err(|e| {
                anyhow::anyhow!(
                    "xArm at {host}: {e}{}",
                    if matches!(
                        e,
                        XArmOpenError::Driver(xarm::driver::XArmError::Controller(_))
                    ) && !args.clear_errors
                    {
                        " (rt-core never clears a controller error on its own: check the arm, \
                         then clear it on the pendant or start with --clear-errors)"
                    } else {
                        ""
                    }
                )
            })?;
            run_on(opts, &cfg, model, task, link)
        }
    }
}

/// Serves on `link` and prints the run's figures.
fn run_on<L: RobotLink + 'static>(
    opts: &ServeOptions,
    cfg: &RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    link: L,
) -> anyhow::Result<()> {
    let served = serve_on(opts, cfg, model, task, link);
    if let Some(sig) = process_stop::stop_signal() {
        tracing::info!(
            signal = process_stop::signal_name(sig),
            "stopped by a signal: the arm was braked to rest and the controller stopped"
        );
    }
    let summary = served?;
    summary.log();
    // One JSON line on stdout with the run's figures, for the launcher's report.
    println!("{}", summary.to_json(opts));
    Ok(())
}
