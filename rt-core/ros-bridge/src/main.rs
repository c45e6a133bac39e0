//! `ros-bridge`: republishes a run's robot state, scene and verdicts over ROS 2 (DDS) for
//! RViz and other ROS 2 tools (`foresight --ros` starts it). See the `ros_bridge` library.

#![forbid(unsafe_code)]

use shm_schemas::error_chain::error_chain;
use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use ros_bridge::RosBridgeConfig;
use ros_bridge::reach::{ReachSettings, runtime_goal_settings};
use shm_schemas::cli_bounds::{f64_within, int_within};
use twin::{RobotModel, TaskConfig};

/// Republishes a Foresight run's robot state, scene and verdicts over ROS 2.
#[derive(Debug, Parser)]
#[command(name = "ros-bridge", version, about)]
pub struct RosBridgeArgs {
    /// iceoryx2 service-name prefix of the run to bridge.
    #[arg(long, default_value = "")]
    prefix: String,
    /// Robot model (for `/tf` and `/robot_description`).
    #[arg(long, default_value = "assets/xarm5.urdf")]
    urdf: PathBuf,
    /// DDS domain id (defaults to $ROS_DOMAIN_ID, else 0).
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0, value_parser = int_within(0u16, 232), allow_negative_numbers = true)]
    domain_id: u16,
    /// Interface address DDS may use (repeatable). Default: loopback only. Pass the robot
    /// PC's address to be seen from other hosts.
    #[arg(long = "ros-network", default_value = "127.0.0.1")]
    networks: Vec<IpAddr>,
    /// `/joint_states` and `/tf` rate (Hz, at least 50).
    #[arg(long, default_value_t = 100.0, value_parser = f64_within(50.0, 1000.0), allow_negative_numbers = true)]
    rate_hz: f64,
    /// Fixed frame of all published poses (the URDF's base link).
    #[arg(long, default_value = "link_base")]
    frame_id: String,
    /// rt-core's runtime configuration: the bounds a `Reach` goal is checked against, and
    /// the goal source.
    #[arg(long, default_value = "assets/runtime.toml")]
    runtime: PathBuf,
    /// Task configuration: the table height, the goal hover and the tolerance of "reached".
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Where rt-core takes its goal from (overrides the runtime configuration's
    /// `goal.source`, as the launcher's `--goal-source` does for rt-core): with `camera`,
    /// every `Reach` goal is refused.
    #[arg(long, value_parser = ["camera", "action"])]
    goal_source: Option<String>,
    /// Stop after this many seconds (0 = run until SIGINT/SIGTERM).
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 1e7), allow_negative_numbers = true)]
    seconds: f64,
}

fn main() -> ExitCode {
    run(RosBridgeArgs::parse())
}

/// Runs the bridge; prints its statistics as one JSON object when it stops.
fn run(args: RosBridgeArgs) -> ExitCode {
    if !(args.rate_hz.is_finite() && (50.0..=1000.0).contains(&args.rate_hz)) {
        eprintln!(
            "ros-bridge: --rate-hz must be within 50..=1000, got {}",
            args.rate_hz
        );
        return ExitCode::from(2);
    }
    let urdf = match std::fs::read_to_string(&args.urdf) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("ros-bridge: cannot read {}: {e}", args.urdf.display());
            return ExitCode::from(2);
        }
    };
    let model = match RobotModel::from_urdf_str(&urdf) {
        Ok(m) => m,
        Err(e) => {
            eprintln!(
                "ros-bridge: invalid robot model {}: {e}",
                args.urdf.display()
            );
            return ExitCode::from(2);
        }
    };
    let reach = match reach_settings(&args) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("ros-bridge: {e}");
            return ExitCode::from(2);
        }
    };
    if reach.goal_source_action && !reach.dds_loopback_only {
        eprintln!(
            "ros-bridge: DDS uses {:?}, not loopback only: every Reach goal is refused \
             (goals are taken only from programs on this machine; docs/real-arm.md)",
            args.networks
        );
    }
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, stop.clone()) {
            eprintln!("ros-bridge: cannot install signal handler: {e}");
        }
    }
    if args.seconds > 0.0 {
        let stop = stop.clone();
        let secs = args.seconds;
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(secs));
            stop.store(true, Ordering::Relaxed);
        });
    }
    let cfg = RosBridgeConfig {
        prefix: args.prefix,
        domain_id: args.domain_id,
        networks: args.networks,
        rate_hz: args.rate_hz,
        frame_id: args.frame_id,
        urdf,
        node_name: "foresight_bridge".into(),
        reach,
    };
    match ros_bridge::run(&cfg, &model, &stop) {
        Ok(stats) => {
            println!("{}", serde_json::to_string(&stats).unwrap_or_default());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("ros-bridge: {}", error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

/// The `Reach` action's settings from `--runtime`, `--task` and `--goal-source`.
fn reach_settings(args: &RosBridgeArgs) -> Result<ReachSettings, String> {
    let text = std::fs::read_to_string(&args.runtime)
        .map_err(|e| format!("cannot read {}: {e}", args.runtime.display()))?;
    let (bounds, action) = runtime_goal_settings(&text)
        .map_err(|e| format!("invalid {}: {e}", args.runtime.display()))?;
    let task = TaskConfig::load(&args.task)
        .map_err(|e| format!("invalid task {}: {e}", args.task.display()))?;
    Ok(ReachSettings {
        goal_source_action: match args.goal_source.as_deref() {
            Some(source) => source == "action",
            None => action,
        },
        bounds,
        table_height_m: task.sampling.table_height_m,
        goal_hover_m: task.success.goal_hover_m,
        tolerance_m: task.success.tolerance_m,
        dds_loopback_only: ros_bridge::reach::loopback_only(&args.networks),
    })
}
