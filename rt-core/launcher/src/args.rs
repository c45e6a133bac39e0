//! The command line of `foresight`: what a run does, where its files are, and its budgets.

use std::path::PathBuf;

/// Command line of `foresight`.
#[derive(Debug, Clone, clap::Parser)]
#[command(
    name = "foresight",
    version,
    about = "Run Foresight's self-improving reaching loop end to end"
)]
pub struct LaunchArgs {
    /// World script (timeline of scenes). Default: the demo world.
    #[arg(long, default_value = "assets/scenes/demo_world.toml")]
    pub world: PathBuf,
    /// Task configuration (goal tolerance, scene sampling).
    #[arg(long, default_value = "assets/task.toml")]
    pub task: PathBuf,
    /// Runtime configuration for `rt-core run`.
    #[arg(long, default_value = "assets/runtime.toml")]
    pub runtime: PathBuf,
    /// Robot model.
    #[arg(long, default_value = "assets/xarm5.urdf")]
    pub urdf: PathBuf,
    /// Pre-trained policy checkpoint the learner resumes from.
    #[arg(long, default_value = "assets/policy")]
    pub checkpoint: PathBuf,
    /// Drive a real xArm5 at this address instead of starting `xarm-sim`.
    #[arg(long)]
    pub robot: Option<String>,
    /// Camera source for perception (`synthetic` plays the world; `ros2`; `file:PATH`).
    #[arg(long, default_value = "synthetic")]
    pub camera: String,
    /// Frame rate of the synthetic camera (Hz). 60 is the ZED's 720p rate; perception
    /// confirms a new object after 3 frames, so a world change is seen within ≈ 50–70 ms.
    #[arg(long, default_value_t = 60.0)]
    pub camera_rate_hz: f64,
    /// Calibration file for a real camera.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Execute the policy without the lookahead gate (shows why Foresight exists).
    #[arg(long)]
    pub no_lookahead: bool,
    /// Compute and log every command but send none to the arm.
    #[arg(long)]
    pub dry_run: bool,
    /// Also publish to ROS 2 (starts the `ros-bridge` process).
    #[arg(long)]
    pub ros: bool,
    /// Randomised scenarios: run this many, each with a world drawn from the task's
    /// sampling ranges (a small obstacle, then a large one).
    #[arg(long, default_value_t = 0)]
    pub runs: u32,
    /// Seed of the randomised scenarios.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Retraining wall-time budget per request (s).
    #[arg(long, default_value_t = 30.0)]
    pub retrain_budget_s: f64,
    /// Retraining step budget per request (a request that runs out is answered with the
    /// best policy so far; the next request resumes where it stopped).
    #[arg(long, default_value_t = 400_000)]
    pub retrain_steps: u64,
    /// Longest one scene may take (s).
    #[arg(long, default_value_t = 90.0)]
    pub phase_timeout_s: f64,
    /// Where run folders go.
    #[arg(long, default_value = "runs")]
    pub out: PathBuf,
}
