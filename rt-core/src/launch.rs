//! Start-up of `rt-core run`: from the command line's choices ([`LaunchOptions`]) to a
//! served run ([`crate::twin_thread::serve`]) around a robot link and its figures. [`run`]
//! assembles the configuration, ties the process to its parent and its signals, checks the
//! simulation-only rights, starts the recorder, opens the link, serves on it, and writes the
//! run's summary.
//!
//! The link is `--link sim` (the in-process simulated arm) or `--link xarm --robot HOST` (a
//! real xArm5 or `xarm-sim`). `--dry-run` computes and logs every command and sends none;
//! `--no-lookahead` runs the policy blind, and only on a loopback robot address (`xarm-sim`
//! on this machine): it is refused, before any connection, for any other
//! ([`check_blind_mode_target`]).
//!
//! Every simulation-only right (`--no-lookahead`, `--auto-resume`, `--simulated-sensors`)
//! goes by identity too, not by address alone: rt-core reads the run's secret from
//! `FORESIGHT_SIM_SECRET` (the launcher draws one per run and gives it to the `xarm-sim` it
//! starts and to rt-core, in the environment, never on a command line) and the controller
//! must prove it holds it right after `GET_VERSION`, before anything else is sent
//! ([`SimRights`], [`xarm::sim_identity`]). Without the secret, or without the proof, the arm
//! is a real arm and the run is refused, naming the flags.
//!
//! rt-core is tied to its parent, whoever started it: it asks the kernel for SIGTERM when
//! the parent dies (`PR_SET_PDEATHSIG`), and SIGTERM is the runtime's controlled stop (the
//! arm brakes to rest, the controller is put in its stop state, then the process exits).
//! So is every other signal whose default action would end the process (SIGHUP, SIGQUIT,
//! SIGUSR2, SIGALRM, …; [`process_stop`]): their handlers are installed first thing, before
//! any connection; one that arrives while connecting stops the run at its first cycle.
//! SIGPIPE never ends the process, and a SIGUSR1 before the runtime listens for
//! acknowledgements is dropped. In a `panic = "abort"` build (`--profile deploy`) a panic
//! off the cycle thread brakes the arm before the abort. With `--link xarm` the arm's lock is
//! taken before connecting ([`open_xarm`]): a second rt-core on the same controller is
//! refused with the holder named.

use shm_schemas::error_chain::error_chain;
use std::path::{Path, PathBuf};
use std::time::Duration;

use twin::{RobotModel, TaskConfig, TaskConfigError, UrdfLoadError};

use crate::config::{GoalSource, RuntimeConfig, RuntimeConfigError};
use crate::cycle::link::{InProcessArm, RobotLink};
use crate::cycle::shield::ShieldLimits;
use crate::cycle::xarm_link::{
    AUTO_RESUME_FLAG, BLIND_MODE_FLAG, BlindModeError, SIMULATED_SENSORS, SimRights,
    SimRightsError, XArmOpenError, XArmOpenOptions, check_auto_resume_target,
    check_blind_mode_target, open_xarm, sim_rights_for,
};
use crate::rt::process_stop::{self, SignalInstallError};
use crate::rt::rt_setup::RtRequest;
use crate::twin_thread::serve::{
    AckChannelOptions, InjectedFault, SHUTDOWN_TIMEOUT, ServeError, ServeOptions, serve_on,
};

/// Which robot link the cycle drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkKind {
    /// The in-process simulated arm.
    Sim,
    /// A real xArm5 (or xarm-sim) over TCP ([`LaunchOptions::robot`]).
    Xarm,
}

/// What `rt-core run` was asked for: its command line, parsed (each field is the flag of
/// the same name; `rt-core run --help` says more).
#[derive(Debug, Clone)]
pub struct LaunchOptions {
    /// The runtime configuration (TOML).
    pub config: PathBuf,
    /// The folder with xarm5.urdf and task.toml.
    pub assets: PathBuf,
    /// The robot link.
    pub link: LinkKind,
    /// The robot's address for [`LinkKind::Xarm`].
    pub robot: Option<String>,
    /// Real-time set-up of the cycle thread.
    pub rt: RtRequest,
    /// Stop after this many seconds (0 = until SIGINT/SIGTERM).
    pub seconds: f64,
    /// Service-name prefix (`None`: the config's `service_prefix`).
    pub prefix: Option<String>,
    /// The arm's report port for [`LinkKind::Xarm`] (`None`: the real controller's).
    pub report_port: Option<u16>,
    /// Clear the controller's error and warning at start (an operator's action).
    pub clear_errors: bool,
    /// Resume after a lost link without an operator's acknowledgement (simulated arms).
    pub auto_resume: bool,
    /// The run's camera is simulated: the arm must be xarm-sim.
    pub simulated_sensors: bool,
    /// A fault to inject (tests only).
    pub inject_fault: Option<InjectedFault>,
    /// A policy blob file to start with.
    pub policy: Option<PathBuf>,
    /// Blind run (simulated arms only).
    pub no_lookahead: bool,
    /// Dry run: compute and log every command, send none.
    pub dry_run: bool,
    /// The CSV log of computed commands.
    pub command_log: Option<PathBuf>,
    /// Record the run to this MCAP file.
    pub record: Option<PathBuf>,
    /// Overrides the config's `planner_fallback.enabled`.
    pub planner_fallback: Option<bool>,
    /// Overrides the config's `goal.source`.
    pub goal_source: Option<GoalSource>,
}

/// Why the configuration, the robot model or the task could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum AssetsError {
    /// The runtime configuration.
    #[error("loading {}", .path.display())]
    Config {
        /// Its path.
        path: PathBuf,
        /// Why.
        #[source]
        source: RuntimeConfigError,
    },
    /// The configuration with the overridden rate.
    #[error("--rate")]
    Rate(#[source] RuntimeConfigError),
    /// The robot model.
    #[error("loading xarm5.urdf")]
    Model(#[source] UrdfLoadError),
    /// The configuration does not fit the robot model.
    #[error("{} against xarm5.urdf", .path.display())]
    AgainstModel {
        /// The configuration's path.
        path: PathBuf,
        /// Why.
        #[source]
        source: RuntimeConfigError,
    },
    /// The task.
    #[error("loading task.toml")]
    Task(#[source] TaskConfigError),
}

/// Why `rt-core run` could not start, or ended with an error.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The signal handlers could not be installed.
    #[error(transparent)]
    Signals(#[from] SignalInstallError),
    /// The kernel refused to tie the process to its parent.
    #[error("prctl(PR_SET_PDEATHSIG)")]
    ParentTie(#[source] std::io::Error),
    /// The parent ended before the tie took effect.
    #[error("the parent process (pid {0}) ended while rt-core was starting; not starting")]
    ParentGone(u32),
    /// A simulation-only flag with a robot address that is not loopback.
    #[error(transparent)]
    NotLoopback(#[from] BlindModeError),
    /// Simulation-only rights without the run's secret.
    #[error(transparent)]
    SimRights(#[from] SimRightsError),
    /// The configuration, the model or the task.
    #[error(transparent)]
    Assets(#[from] AssetsError),
    /// The robot's address names no arm lock (and no acknowledgement channel).
    #[error("--robot {host}")]
    RobotAddress {
        /// `--robot`.
        host: String,
        /// Why.
        #[source]
        source: Box<xarm::owner::ArmLockError>,
    },
    /// `--record` could not read the URDF it stores.
    #[error("--record: reading {}", .path.display())]
    RecordUrdf {
        /// The URDF's path.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// `--record` could not start the recorder.
    #[error("--record")]
    Record(#[source] recorder::RecorderStartError),
    /// `--link xarm` without `--robot`.
    #[error("--link xarm needs --robot HOST")]
    NoRobot,
    /// The configuration is not fit for an xArm link.
    #[error("{}", .config.display())]
    NotForXarm {
        /// The configuration's path.
        config: PathBuf,
        /// Why.
        #[source]
        source: RuntimeConfigError,
    },
    /// The xArm link could not open.
    #[error("xArm at {host}: {error}{}", if *.kept_controller_error { KEPT_ERROR_HINT } else { "" })]
    Open {
        /// `--robot`.
        host: String,
        /// Why (in the message, as it was always worded).
        error: Box<XArmOpenError>,
        /// A controller error at start, and no `--clear-errors`.
        kept_controller_error: bool,
    },
    /// The runtime ended with an error.
    #[error(transparent)]
    Serve(#[from] ServeError),
}

/// What a controller error at start tells the operator.
const KEPT_ERROR_HINT: &str = " (rt-core never clears a controller error on its own: check \
                               the arm, then clear it on the pendant or start with \
                               --clear-errors)";

/// How long a panic (deploy build, `panic = "abort"`) waits for the cycle to brake the arm
/// and put the controller in its stop state before the process aborts: the cycle's own
/// shutdown bound plus the controller's `SET_STATE 4` round trips (up to 3 s).
pub const PANIC_BRAKE_WAIT: Duration = SHUTDOWN_TIMEOUT.saturating_add(Duration::from_secs(4));

/// Loads the runtime config (`config`, default `assets/runtime.toml`, with `rate_hz`
/// overridden), the robot model and the task from `assets`.
///
/// # Errors
/// [`AssetsError`], naming the file.
pub fn load_assets(
    assets: &Path,
    rate_hz: Option<f64>,
    config: Option<&Path>,
) -> Result<(RuntimeConfig, RobotModel, TaskConfig), AssetsError> {
    let path = config.map_or_else(|| assets.join("runtime.toml"), Path::to_path_buf);
    let mut cfg = match RuntimeConfig::load(&path) {
        Ok(cfg) => cfg,
        Err(source) => return Err(AssetsError::Config { path, source }),
    };
    if let Some(r) = rate_hz {
        cfg.rate_hz = r;
        cfg.validate().map_err(AssetsError::Rate)?;
        cfg.raise_horizon_to_floor();
    }
    if let Some(said) = cfg.horizon_raised() {
        tracing::warn!("{said}");
    }
    let model = RobotModel::load(&assets.join("xarm5.urdf")).map_err(AssetsError::Model)?;
    if let Err(source) = cfg.check_against_model(&model) {
        return Err(AssetsError::AgainstModel { path, source });
    }
    let task = TaskConfig::load(&assets.join("task.toml")).map_err(AssetsError::Task)?;
    Ok((cfg, model, task))
}

/// Runs `rt-core run` (see the module docs) and, at a normal end, logs the run's figures
/// and prints them as one JSON line on stdout, for the launcher's report.
///
/// # Errors
/// [`LaunchError`]: before anything moves, or the runtime's own ([`ServeError`]).
pub fn run(opts: &LaunchOptions) -> Result<(), LaunchError> {
    // First, before anything can move: every signal that would end the process becomes a
    // controlled stop, SIGPIPE and an early SIGUSR1 are harmless, and (deploy builds) a
    // panic brakes before the abort.
    process_stop::install_signal_handlers()?;
    process_stop::install_panic_hook(PANIC_BRAKE_WAIT);
    stop_with_parent()?;
    // iceoryx2's configuration from the installed assets, wherever the process started.
    shm_schemas::services::set_assets_dir(&opts.assets);
    // Blind mode never reaches a real arm: decided from the address alone, first. Neither
    // does resuming without the operator: the same address check.
    if let Some(host) = xarm_host(opts) {
        if opts.no_lookahead {
            check_blind_mode_target(host)?;
        }
        if opts.auto_resume {
            check_auto_resume_target(host)?;
        }
    }
    // And each of them, with the simulated sensors, needs the run's secret: the controller
    // proves at connect that it is xarm-sim, or it is a real arm.
    let sim_rights = sim_rights(opts)?;
    let (mut cfg, model, task) = load_assets(&opts.assets, None, Some(&opts.config))?;
    if let Some(on) = opts.planner_fallback {
        cfg.planner_fallback.enabled = on;
    }
    if let Some(source) = opts.goal_source {
        cfg.goal.source = source;
    }
    let serve = ServeOptions {
        prefix: opts
            .prefix
            .clone()
            .unwrap_or_else(|| cfg.service_prefix.clone()),
        seconds: opts.seconds,
        no_lookahead: opts.no_lookahead,
        dry_run: opts.dry_run,
        command_log: opts.command_log.clone(),
        policy: opts.policy.clone(),
        rt: opts.rt,
        auto_resume: opts.auto_resume,
        inject: opts.inject_fault,
        ack_channel: ack_channel(opts, &cfg)?,
    };
    // The recorder subscribes before the runtime starts; a recording that was asked for and
    // cannot start stops the run here, before anything moves.
    let recording = match &opts.record {
        Some(path) => {
            let urdf_path = opts.assets.join("xarm5.urdf");
            let urdf = match std::fs::read_to_string(&urdf_path) {
                Ok(urdf) => urdf,
                Err(source) => {
                    return Err(LaunchError::RecordUrdf {
                        path: urdf_path,
                        source,
                    });
                }
            };
            let cfg = recorder::RecorderConfig::new(path.clone(), &serve.prefix, urdf);
            Some(recorder::Recorder::start(cfg).map_err(LaunchError::Record)?)
        }
        None => None,
    };
    let served = serve_link(opts, &serve, cfg, model, task, sim_rights);
    if let Some(r) = recording {
        let path = r.path().display().to_string();
        match r.stop() {
            Ok(stats) => tracing::info!(%path, messages = stats.total(), "recording closed"),
            Err(e) => tracing::warn!(%path, "recording ended badly: {}", error_chain(&e)),
        }
    }
    served
}

/// The robot's address of an xArm link (`None` for the in-process arm, or without one).
fn xarm_host(opts: &LaunchOptions) -> Option<&str> {
    match opts.link {
        LinkKind::Xarm => opts.robot.as_deref(),
        LinkKind::Sim => None,
    }
}

/// Asks the kernel to send this process SIGTERM when its parent dies, then checks that the
/// parent did not die before the request took effect (we would be re-parented and never
/// get the signal).
fn stop_with_parent() -> Result<(), LaunchError> {
    let parent = std::os::unix::process::parent_id();
    shm_schemas::process_ties::stop_with_parent().map_err(LaunchError::ParentTie)?;
    if std::os::unix::process::parent_id() != parent {
        return Err(LaunchError::ParentGone(parent));
    }
    Ok(())
}

/// The operator's acknowledgement channel of an xArm link: beside the arm's lock file.
fn ack_channel(
    opts: &LaunchOptions,
    cfg: &RuntimeConfig,
) -> Result<Option<AckChannelOptions>, LaunchError> {
    let Some(host) = xarm_host(opts) else {
        return Ok(None);
    };
    let lock =
        xarm::owner::lock_path(&xarm::config::XArmConfig::from_addr(host)).map_err(|source| {
            LaunchError::RobotAddress {
                host: host.to_owned(),
                source: Box::new(source),
            }
        })?;
    Ok(Some(AckChannelOptions {
        path: crate::operator_ack::socket_path(&lock),
        extra_uids: cfg.operator.ack_uids.clone(),
    }))
}

/// The simulation-only rights `opts` asks of an xArm link (`None` without any, or for the
/// in-process arm), with the run's secret from `FORESIGHT_SIM_SECRET`: refused before any
/// connection off loopback or without the secret.
fn sim_rights(opts: &LaunchOptions) -> Result<Option<SimRights>, LaunchError> {
    let Some(host) = xarm_host(opts) else {
        return Ok(None);
    };
    let asked: Vec<_> = [
        (opts.no_lookahead, BLIND_MODE_FLAG),
        (opts.auto_resume, AUTO_RESUME_FLAG),
        (opts.simulated_sensors, SIMULATED_SENSORS),
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

/// Opens the robot link `opts` asks for and serves on it.
fn serve_link(
    opts: &LaunchOptions,
    serve: &ServeOptions,
    cfg: RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    sim_rights: Option<SimRights>,
) -> Result<(), LaunchError> {
    match opts.link {
        LinkKind::Sim => {
            let arm = InProcessArm::new(
                task.start.joints_rad,
                cfg.limits.joint_min_rad,
                cfg.limits.joint_max_rad,
                [std::f64::consts::PI; 5],
            );
            run_on(serve, &cfg, model, task, arm)
        }
        LinkKind::Xarm => {
            let host = opts.robot.as_deref().ok_or(LaunchError::NoRobot)?;
            if let Err(source) = cfg.check_for_xarm_link() {
                return Err(LaunchError::NotForXarm {
                    config: opts.config.clone(),
                    source,
                });
            }
            let open = XArmOpenOptions {
                report_port: opts.report_port,
                dry_run: opts.dry_run,
                clear_errors: opts.clear_errors,
                max_resume_step_rad: ShieldLimits::from_config(&cfg.limits, &cfg.shield)
                    .max_step_rad(1.0 / cfg.rate_hz),
                resume_after_reconnect: opts.auto_resume,
                max_tcp_gap_m: cfg.shield.max_tcp_gap_m,
                sim_rights,
            };
            let link = open_xarm(host, &open, &model).map_err(|error| LaunchError::Open {
                host: host.to_owned(),
                kept_controller_error: matches!(
                    error,
                    XArmOpenError::Driver(xarm::driver::XArmError::Controller(_))
                ) && !opts.clear_errors,
                error: Box::new(error),
            })?;
            run_on(serve, &cfg, model, task, link)
        }
    }
}

/// Serves on `link` and writes the run's figures (the log, and one JSON line on stdout).
fn run_on<L: RobotLink + 'static>(
    serve: &ServeOptions,
    cfg: &RuntimeConfig,
    model: RobotModel,
    task: TaskConfig,
    link: L,
) -> Result<(), LaunchError> {
    let served = serve_on(serve, cfg, model, task, link);
    if let Some(sig) = process_stop::stop_signal() {
        tracing::info!(
            signal = process_stop::signal_name(sig),
            "stopped by a signal: the arm was braked to rest and the controller stopped"
        );
    }
    let summary = served?;
    summary.log();
    // One JSON line on stdout with the run's figures, for the launcher's report.
    println!("{}", summary.to_json(serve));
    Ok(())
}
