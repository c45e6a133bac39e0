//! `rt-core run --config FILE`: the runtime's flags, handed to [`rt_core::launch::run`]
//! (which says how a run starts, what each simulation-only right asks of the arm, and how
//! the process stops).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use rt_core::config::GoalSource;
use rt_core::launch::{self, LaunchOptions, LinkKind};
use rt_core::twin_thread::serve::InjectedFault;
use shm_schemas::cli_bounds::{f64_within, int_within};

use super::one_of;

/// Arguments of `run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Runtime configuration (TOML).
    #[arg(long, default_value = "assets/runtime.toml")]
    config: PathBuf,
    /// Folder with xarm5.urdf and task.toml.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Robot link: `sim` (the in-process simulated arm) or `xarm` (a real xArm5, or
    /// xarm-sim, over TCP: `--robot HOST`).
    #[arg(long, default_value = "sim", value_parser = one_of(["sim", "xarm"], [LinkKind::Sim, LinkKind::Xarm]))]
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
    /// `planner_fallback.enabled`): `on` or `off`.
    #[arg(long, value_parser = one_of(["on", "off"], [true, false]))]
    planner_fallback: Option<bool>,
    /// Where the goal comes from: `camera` (the goal cube perception sees) or `action` (the
    /// ROS 2 `Reach` action served by ros-bridge). Overrides the config's `goal.source`.
    #[arg(long, value_parser = one_of(["camera", "action"], [GoalSource::Camera, GoalSource::Action]))]
    goal_source: Option<GoalSource>,
}

/// Runs the runtime.
pub fn run(args: RunArgs) -> ExitCode {
    super::init_tracing();
    match launch::run(&args.into_options()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("rt-core run: {:#}", anyhow::Error::new(e));
            ExitCode::FAILURE
        }
    }
}

impl RunArgs {
    /// The parsed flags, as the library takes them.
    fn into_options(self) -> LaunchOptions {
        LaunchOptions {
            config: self.config,
            assets: self.assets,
            link: self.link,
            robot: self.robot,
            rt: self.rt.request(),
            seconds: self.seconds,
            prefix: self.prefix,
            report_port: self.report_port,
            clear_errors: self.clear_errors,
            auto_resume: self.auto_resume,
            simulated_sensors: self.simulated_sensors,
            inject_fault: self.inject_fault,
            policy: self.policy,
            no_lookahead: self.no_lookahead,
            dry_run: self.dry_run,
            command_log: self.command_log,
            record: self.record,
            planner_fallback: self.planner_fallback,
            goal_source: self.goal_source,
        }
    }
}
