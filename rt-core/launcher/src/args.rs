//! The command line of `foresight`: what a run does, where its files are, and its budgets.

use std::path::PathBuf;

use shm_schemas::cli_bounds::{f64_within, int_within};
use xarm::config::{LoopbackCheckError, XArmConfig};
use xarm::sim_identity::{SIM_SECRET_ENV, SimSecret};
use zenoh_relay::link::{LinkArgs, LinkError};

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
    /// Pre-trained policy checkpoint the controller starts with and the learner resumes
    /// from. The default is the best generalist measured on worlds its training never saw
    /// (the distilled one, docs/unseen-worlds.md); the research system's PPO generalist is
    /// `assets/policy` (with `--world assets/scenes/paper_world.toml`: the paper's demo).
    #[arg(long, default_value = "assets/policy-distilled")]
    pub checkpoint: PathBuf,
    /// Drive a real xArm5 at this address instead of starting `xarm-sim`. Whatever the
    /// address, the arm there is a real arm unless it proves it is xarm-sim holding the
    /// secret in FORESIGHT_SIM_SECRET (only then, and only on loopback, are blind mode, the
    /// synthetic camera and the bundled calibration allowed).
    #[arg(long)]
    pub robot: Option<String>,
    /// Camera source for perception (`synthetic` plays the world; `ros2`; `file:PATH`).
    #[arg(long, default_value = "synthetic")]
    pub camera: String,
    /// Frame rate of the synthetic camera (Hz). 60 is the ZED's 720p rate; perception
    /// confirms a new object after 3 frames, so a world change is seen within ≈ 50–70 ms.
    #[arg(long, default_value_t = 60.0, value_parser = f64_within(0.1, 1000.0), allow_negative_numbers = true)]
    pub camera_rate_hz: f64,
    /// Calibration file for a real camera.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Perception's detector: `colour` (HSV thresholds, ≈ 5 ms a frame) or `yolo` (the
    /// project's YOLO model as `<assets>/perception/yolo.toml` describes it, where
    /// `<assets>` is the folder of `--task`; 30–120 ms a frame on the CPU, the camera's
    /// frames it cannot keep up with are dropped oldest first).
    #[arg(long, value_enum, default_value_t = DetectorChoice::Colour)]
    pub detector: DetectorChoice,
    /// Blind run, a simulation-only demonstration of why Foresight exists: execute the
    /// policy without the lookahead gate and without the shield's clearance to the boxes
    /// (the table clearance and every limit still hold). Refused, before any process
    /// starts, with a `--robot` that is not (or does not resolve only to) a loopback
    /// address (127.0.0.0/8, ::1, localhost), or one that does not prove it is xarm-sim
    /// holding FORESIGHT_SIM_SECRET.
    #[arg(long)]
    pub no_lookahead: bool,
    /// Planner fallback: when no policy passes the lookahead, rt-core moves the arm along
    /// the feasibility planner's checked path while the learner retrains, and the retrained
    /// policy replaces it once it passes (`off`: the arm holds until a retrained policy
    /// passes, the paper's behaviour). On by default: README, "Results".
    #[arg(long, value_enum, default_value_t = OnOff::On)]
    pub planner_fallback: OnOff,
    /// Where the goal comes from: `camera` (the goal cube perception sees) or `action` (the
    /// ROS 2 `Reach` action served by the bridge: needs `--ros`; send goals with
    /// `foresight reach --goal X,Y` or any ROS 2 action client). Default: the runtime
    /// configuration's `[goal] source`. The run's summary.json says which was used.
    #[arg(long, value_parser = goal_source_choice())]
    pub goal_source: Option<GoalSourceChoice>,
    /// Compute and log every command but send none to the arm.
    #[arg(long)]
    pub dry_run: bool,
    /// Operator action: let rt-core clear the controller's error and warning at start
    /// (it never does on its own). Acknowledge a protective stop while running with
    /// `rt-core ack --robot HOST` (it shows the latched stop and clears that one, on the
    /// rt-core that owns that arm).
    #[arg(long)]
    pub clear_errors: bool,
    /// Also publish to ROS 2 (starts the `ros-bridge` process).
    #[arg(long)]
    pub ros: bool,
    /// Randomised scenarios: run this many, each with a world drawn from the task's
    /// sampling ranges (a small obstacle, then a large one).
    #[arg(long, default_value_t = 0, value_parser = int_within(0u32, 100_000), allow_negative_numbers = true)]
    pub runs: u32,
    /// Seed of the randomised scenarios.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    pub seed: u64,
    /// What the randomised scenarios (`--runs N`) draw: `pair` — a small obstacle, then a
    /// large one (the paper's setting); `random` — a small-obstacle warm-up, then an unseen
    /// world of the task's broad `[world]` distribution (the unseen-worlds benchmark: a
    /// table and a plot of every world's outcome in `<out>/worlds-seed<S>/`).
    #[arg(long, value_enum, default_value_t = WorldsChoice::Pair)]
    pub worlds: WorldsChoice,
    /// Retraining wall-time budget per request (s, 0.1..=86400).
    #[arg(long, default_value_t = 30.0, value_parser = f64_within(0.1, 86_400.0), allow_negative_numbers = true)]
    pub retrain_budget_s: f64,
    /// Retraining step budget per request (a request that runs out is answered with the
    /// best policy so far; the next request resumes where it stopped).
    #[arg(long, default_value_t = 400_000, value_parser = int_within(1u64, 10_000_000_000), allow_negative_numbers = true)]
    pub retrain_steps: u64,
    /// Hold each retrained policy this long before the learner publishes it (s, 0..=600): a
    /// test aid that makes the learner as slow as on a slower machine (issue 40: a slow
    /// learner must not change the outcome).
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 600.0), allow_negative_numbers = true)]
    pub learner_delay_s: f64,
    /// Longest one scene may take (s, 0.1..=86400).
    #[arg(long, default_value_t = 90.0, value_parser = f64_within(0.1, 86_400.0), allow_negative_numbers = true)]
    pub phase_timeout_s: f64,
    /// Where run folders go.
    #[arg(long, default_value = "runs")]
    pub out: PathBuf,
    /// Do not record the run. By default every run is recorded to `<run folder>/run.mcap`
    /// (ROS 2 messages with their schemas: `ros2 bag info`, `ros2 bag play` and Foxglove
    /// open it).
    #[arg(long)]
    pub no_record: bool,
    /// Largest run recording (MiB, 1..=1048576); recording stops there, with a note.
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u64).range(1..=1_048_576), allow_negative_numbers = true)]
    pub record_max_mib: u64,
    /// The learner runs on another host (a GPU box): start no learner here, but the
    /// controller side of `zenoh-relay`, which carries retrain requests there and policies
    /// back over Zenoh. The other host runs `zenoh-relay learner-host --listen
    /// tcp/0.0.0.0:7447` (docs/components.md, "Two hosts"). Needs `--peer` or `--listen`.
    #[arg(long)]
    pub learner_host: bool,
    /// Where the relay connects / listens (with `--learner-host`).
    #[command(flatten)]
    pub link: LinkArgs,
}

/// The host-to-host flags are inconsistent.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LearnerHostError {
    /// `--peer` or `--listen` without `--learner-host`.
    #[error("--peer and --listen only mean something with --learner-host")]
    LinkWithoutLearnerHost,
    /// The link settings are refused.
    #[error("--learner-host")]
    Link(#[from] LinkError),
}

/// `on` or `off`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    /// On.
    On,
    /// Off.
    Off,
}

impl OnOff {
    /// The word on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::On => "on",
            Self::Off => "off",
        }
    }
}

/// Where the goal comes from (`--goal-source`, `[goal] source` of the runtime
/// configuration): the runtime view's own type.
pub use shm_schemas::runtime_view::GoalSource as GoalSourceChoice;

/// `--goal-source`'s parser: `camera` or `action`.
fn goal_source_choice() -> impl clap::builder::TypedValueParser<Value = GoalSourceChoice> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(["camera", "action"]).map(|s| match s.as_str() {
        "action" => GoalSourceChoice::Action,
        _ => GoalSourceChoice::Camera,
    })
}

/// `--goal-source action` (or `[goal] source = "action"`) without `--ros`: nothing would
/// serve the Reach action, so no goal could ever be given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the goal source is `action` but --ros is not given: the Reach action is served by the \
     ROS 2 bridge (add --ros, or use --goal-source camera)"
)]
pub struct GoalSourceWithoutRos;

impl LaunchArgs {
    /// The goal source in force: `--goal-source`, else the runtime configuration's.
    pub fn goal_source(&self, configured: GoalSourceChoice) -> GoalSourceChoice {
        self.goal_source.unwrap_or(configured)
    }

    /// Checks that an `action` goal source has the bridge that serves the action.
    ///
    /// # Errors
    /// [`GoalSourceWithoutRos`].
    pub fn check_goal_source(
        &self,
        configured: GoalSourceChoice,
    ) -> Result<GoalSourceChoice, GoalSourceWithoutRos> {
        let source = self.goal_source(configured);
        if source == GoalSourceChoice::Action && !self.ros {
            return Err(GoalSourceWithoutRos);
        }
        Ok(source)
    }
}

/// What `--runs N` draws (`--worlds`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum WorldsChoice {
    /// A small obstacle, then a large one.
    #[default]
    Pair,
    /// A small-obstacle warm-up, then a world of the task's `[world]` distribution.
    Random,
}

/// Which detector `perception run` uses (`--detector`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum DetectorChoice {
    /// Per-class HSV thresholds (perception's default).
    #[default]
    #[value(alias = "color")]
    Colour,
    /// The YOLO model of `<assets>/perception/yolo.toml`.
    Yolo,
}

impl DetectorChoice {
    /// The name on the command line and in the run summary.
    pub fn name(self) -> &'static str {
        match self {
            Self::Colour => "colour",
            Self::Yolo => "yolo",
        }
    }
}

/// `--no-lookahead` with a `--robot` that is not known to be this machine's loopback.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--no-lookahead is refused for the non-loopback robot address {addr}: blind mode is a \
     simulation-only demonstration ({reason}; no process was started, no connection was attempted)"
)]
pub struct BlindModeRefused {
    /// The `--robot` address as given.
    pub addr: String,
    /// Why it is not loopback.
    pub reason: LoopbackCheckError,
}

/// A `--robot` off this machine without a real camera source and an explicit calibration:
/// a real arm is never driven from an imaginary world (the synthetic camera plays the world
/// script, not the arm's table; the bundled calibration is another camera's).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--robot {addr} is a real arm ({reason}): it is driven only from a real camera and an \
     explicit calibration file, give --camera ros2 and --calibration FILE ({missing}); \
     --dry-run plans on synthetic data and sends nothing that moves the arm (no process was \
     started, no connection was attempted)"
)]
pub struct RealArmSensorsRefused {
    /// The `--robot` address as given.
    pub addr: String,
    /// Why it is not loopback.
    pub reason: LoopbackCheckError,
    /// What is missing, in words.
    pub missing: String,
}

/// The camera sources that watch the arm's own table (`--camera`): the ROS 2 topics of a
/// live camera. The synthetic camera plays the world script; `file:` plays a recording.
pub const REAL_CAMERA_SOURCES: [&str; 1] = ["ros2"];

/// A `--robot` on loopback asked for simulation-only rights and has not proven it is
/// `xarm-sim` holding the run's secret ([`xarm::sim_identity`]): it is a real arm (a
/// loopback forward, `ssh -L` or `socat`, reaches real arms too).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--robot {addr} has not proven it is xarm-sim ({why}): it is treated as a real arm, and a \
     real arm is not driven {asks}. Give --camera ros2 and --calibration FILE and leave out \
     --no-lookahead, or start that xarm-sim with {SIM_SECRET_ENV} and give foresight the \
     same (no process was started)"
)]
pub struct SimIdentityRefused {
    /// The `--robot` address as given.
    pub addr: String,
    /// Why it has not proven it, in words.
    pub why: String,
    /// The simulation-only things asked for, in words.
    pub asks: String,
}

impl LaunchArgs {
    /// The assets folder: the folder of `--task` (rt-core gets it as `--assets` too).
    pub fn assets_dir(&self) -> PathBuf {
        self.task
            .parent()
            .map(std::path::Path::to_path_buf)
            .unwrap_or_default()
    }

    /// With `--learner-host`, the link flags are usable; without it, none is given.
    ///
    /// # Errors
    /// [`LearnerHostError`] naming the flag.
    pub fn check_learner_host(&self) -> Result<(), LearnerHostError> {
        if self.learner_host {
            // The robot PC's keys (`--link-keys`) are loaded here so that a missing or
            // unusable key file is named before anything starts.
            self.link.load_keys(zenoh_relay::wire::Side::Controller)?;
        } else if !self.link.peers.is_empty() || !self.link.listen.is_empty() {
            return Err(LearnerHostError::LinkWithoutLearnerHost);
        }
        Ok(())
    }

    /// A real arm is driven only from real sensors: with a `--robot` that is not (or does
    /// not resolve only to) a loopback address, `--camera` must be a live camera
    /// ([`REAL_CAMERA_SOURCES`]) and `--calibration` a file given explicitly (never the
    /// bundled one), unless `--dry-run` (nothing that moves the arm is sent; every report
    /// line then says the data are synthetic, [`Self::synthetic_data_note`]). Decided from
    /// the address alone, before any process starts; a loopback address must then still
    /// prove it is `xarm-sim` ([`Self::check_sim_identity`]).
    ///
    /// # Errors
    /// [`RealArmSensorsRefused`] naming `--camera`, `--calibration` and the address.
    pub fn check_real_arm_sensors(&self) -> Result<(), RealArmSensorsRefused> {
        let Some(addr) = &self.robot else {
            return Ok(());
        };
        if self.dry_run {
            return Ok(());
        }
        let Err(reason) = XArmConfig::from_addr(addr).check_loopback_only() else {
            return Ok(());
        };
        let mut missing = Vec::new();
        if !REAL_CAMERA_SOURCES.contains(&self.camera.as_str()) {
            missing.push(format!("--camera {} is not a live camera", self.camera));
        }
        if self.calibration.is_none() {
            missing.push("no --calibration was given".to_owned());
        }
        if missing.is_empty() {
            return Ok(());
        }
        Err(RealArmSensorsRefused {
            addr: addr.clone(),
            reason,
            missing: missing.join(", "),
        })
    }

    /// Whether perception runs on simulated sensors: the synthetic camera or a recording
    /// (not a live camera), or the bundled calibration (no `--calibration`).
    pub fn simulated_sensors(&self) -> bool {
        !REAL_CAMERA_SOURCES.contains(&self.camera.as_str()) || self.calibration.is_none()
    }

    /// What this run asks of a `--robot` that only `xarm-sim` may be given, in words: blind
    /// mode, and — unless `--dry-run`, which sends nothing that moves the arm — a camera
    /// that is not live and the bundled calibration. Empty: a real arm may be driven so.
    pub fn simulation_only_asks(&self) -> Vec<String> {
        let mut asks = Vec::new();
        if self.no_lookahead {
            asks.push("blind (--no-lookahead)".to_owned());
        }
        if !self.dry_run {
            if !REAL_CAMERA_SOURCES.contains(&self.camera.as_str()) {
                asks.push(format!("from the {} camera (--camera {0})", self.camera));
            }
            if self.calibration.is_none() {
                asks.push("with the bundled calibration (no --calibration)".to_owned());
            }
        }
        asks
    }

    /// Simulation rights by identity, not address: a `--robot` that is asked for anything
    /// only `xarm-sim` may have ([`Self::simulation_only_asks`]) must prove it is `xarm-sim`
    /// holding the secret in `FORESIGHT_SIM_SECRET`, asked over the xArm protocol before
    /// any process starts ([`xarm::sim_identity::ask`]: `GET_VERSION` and the challenge on
    /// the command port, nothing else). Call it after [`Self::check_blind_mode`] and
    /// [`Self::check_real_arm_sensors`], which refuse an address off this machine without
    /// connecting. Returns the secret to give rt-core (`None`: no `--robot`, the launcher's
    /// own `xarm-sim` gets a fresh one; or nothing simulation-only was asked for).
    ///
    /// # Errors
    /// [`SimIdentityRefused`] naming the address, why and what was asked for.
    pub fn check_sim_identity(&self) -> Result<Option<SimSecret>, SimIdentityRefused> {
        let Some(addr) = &self.robot else {
            return Ok(None);
        };
        let asks = self.simulation_only_asks();
        if asks.is_empty() {
            return Ok(None);
        }
        let refused = |why: String| SimIdentityRefused {
            addr: addr.clone(),
            why,
            asks: asks.join(", "),
        };
        let cfg = XArmConfig::from_addr(addr);
        if let Err(reason) = cfg.check_loopback_only() {
            return Err(refused(format!("{reason}; no connection was attempted")));
        }
        let secret = match SimSecret::from_env() {
            Ok(Some(s)) => s,
            Ok(None) => {
                return Err(refused(format!(
                    "no simulator secret in {SIM_SECRET_ENV}; no connection was attempted"
                )));
            }
            Err(e) => return Err(refused(format!("{e}; no connection was attempted"))),
        };
        xarm::sim_identity::ask(&cfg, &secret).map_err(|e| refused(e.to_string()))?;
        Ok(Some(secret))
    }

    /// In a dry run on synthetic data (the synthetic camera or a recording, or no explicit
    /// calibration) the words every report line carries; `None` otherwise.
    pub fn synthetic_data_note(&self) -> Option<&'static str> {
        let synthetic =
            !REAL_CAMERA_SOURCES.contains(&self.camera.as_str()) || self.calibration.is_none();
        (self.dry_run && self.robot.is_some() && synthetic)
            .then_some("[DRY RUN on synthetic camera data, nothing sent to the arm]")
    }

    /// Blind mode never reaches a real arm: with `--no-lookahead`, a `--robot` address must
    /// be, or resolve only to, loopback addresses (decided from the address alone, nothing
    /// is sent to it; a loopback one must then prove it is `xarm-sim`,
    /// [`Self::check_sim_identity`]). Without `--robot` the launcher's own `xarm-sim` on
    /// 127.0.0.1 is used, with this run's secret.
    ///
    /// # Errors
    /// [`BlindModeRefused`] naming the address and why.
    pub fn check_blind_mode(&self) -> Result<(), BlindModeRefused> {
        match (&self.robot, self.no_lookahead) {
            (Some(addr), true) => {
                XArmConfig::from_addr(addr)
                    .check_loopback_only()
                    .map_err(|reason| BlindModeRefused {
                        addr: addr.clone(),
                        reason,
                    })
            }
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use shm_schemas::error_chain::error_chain;

    fn args(extra: &[&str]) -> LaunchArgs {
        LaunchArgs::parse_from(std::iter::once("foresight").chain(extra.iter().copied()))
    }

    #[test]
    fn the_detector_is_colour_unless_yolo_is_asked_for() {
        assert_eq!(args(&[]).detector, DetectorChoice::Colour);
        assert_eq!(args(&["--detector", "yolo"]).detector, DetectorChoice::Yolo);
        assert_eq!(
            args(&["--detector", "color"]).detector,
            DetectorChoice::Colour
        );
        assert!(LaunchArgs::try_parse_from(["foresight", "--detector", "sift"]).is_err());
        assert_eq!(
            args(&["--task", "/x/assets/task.toml"]).assets_dir(),
            PathBuf::from("/x/assets")
        );
    }

    #[test]
    fn learner_host_needs_a_way_to_the_other_host_and_link_flags_need_learner_host() {
        assert_eq!(args(&[]).check_learner_host(), Ok(()));
        assert!(matches!(
            args(&["--learner-host"]).check_learner_host(),
            Err(LearnerHostError::Link(LinkError::Nowhere))
        ));
        // Issue 25 item 1: no unauthenticated link; the keys are checked before anything starts.
        let e = error_chain(
            &args(&["--learner-host", "--peer", "tcp/10.0.0.2:7447"])
                .check_learner_host()
                .unwrap_err(),
        )
        .to_string();
        assert!(
            e.contains("--link-keys") && e.contains("zenoh-relay keygen"),
            "{e}"
        );
        let keys = std::env::temp_dir().join(format!("launcher-link-keys-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&keys);
        zenoh_relay::keys::generate(&keys).unwrap();
        let robot_pc = keys.join("robot-pc").display().to_string();
        let learner_host = keys.join("learner-host").display().to_string();
        let e = error_chain(
            &args(&[
                "--learner-host",
                "--peer",
                "tcp/10.0.0.2:7447",
                "--link-keys",
                &learner_host,
            ])
            .check_learner_host()
            .unwrap_err(),
        )
        .to_string();
        assert!(
            e.contains("controller.key") && e.contains("robot-pc"),
            "{e}"
        );
        let ok = args(&[
            "--learner-host",
            "--peer",
            "tcp/10.0.0.2:7447",
            "--link-keys",
            &robot_pc,
        ]);
        assert_eq!(ok.check_learner_host(), Ok(()));
        assert_eq!(ok.link.peers, ["tcp/10.0.0.2:7447"]);
        std::fs::remove_dir_all(&keys).ok();
        let e = args(&["--learner-host", "--peer", "10.0.0.2"])
            .check_learner_host()
            .unwrap_err();
        assert!(
            error_chain(&e).to_string().contains("--peer 10.0.0.2"),
            "{e}"
        );
        assert_eq!(
            args(&["--listen", "tcp/0.0.0.0:7447"]).check_learner_host(),
            Err(LearnerHostError::LinkWithoutLearnerHost)
        );
    }

    /// Issue 25 item 2: a real arm needs a live camera and an explicit calibration.
    #[test]
    fn a_robot_off_this_machine_needs_a_real_camera_and_an_explicit_calibration() {
        for (extra, names) in [
            (
                &[][..],
                "--camera synthetic is not a live camera, no --calibration",
            ),
            (&["--camera", "ros2"][..], "no --calibration"),
            (&["--calibration", "cal.toml"][..], "--camera synthetic"),
            (
                &["--camera", "file:rec.mp4", "--calibration", "cal.toml"][..],
                "--camera file:rec.mp4 is not a live camera",
            ),
        ] {
            for robot in ["10.0.0.2", "192.168.1.195:502"] {
                let mut a = vec!["--robot", robot];
                a.extend_from_slice(extra);
                let e = args(&a).check_real_arm_sensors().expect_err(robot);
                let m = e.to_string();
                assert!(
                    m.contains(&format!("--robot {robot} is a real arm"))
                        && m.contains("--camera ros2 and --calibration FILE")
                        && m.contains(names)
                        && m.contains("no process was started"),
                    "{m}"
                );
                assert_eq!(args(&a).synthetic_data_note(), None);
                // A dry run may plan on synthetic data, and says so.
                a.push("--dry-run");
                assert_eq!(args(&a).check_real_arm_sensors(), Ok(()));
                assert!(
                    args(&a)
                        .synthetic_data_note()
                        .is_some_and(|n| n.contains("DRY RUN"))
                );
            }
        }
        for ok in [
            args(&[]),
            args(&["--robot", "127.0.0.1:5020"]),
            args(&["--robot", "localhost"]),
            args(&[
                "--robot",
                "192.168.1.195",
                "--camera",
                "ros2",
                "--calibration",
                "cal.toml",
            ]),
        ] {
            assert_eq!(ok.check_real_arm_sensors(), Ok(()), "{ok:?}");
            assert_eq!(ok.synthetic_data_note(), None, "{ok:?}");
        }
    }

    /// Issue 25 item 13: every float flag refuses NaN, infinities, negatives and huge values
    /// with clap's error naming the flag.
    #[test]
    fn float_flags_are_bounded() {
        for flag in [
            "--camera-rate-hz",
            "--retrain-budget-s",
            "--phase-timeout-s",
        ] {
            for bad in ["NaN", "inf", "-1", "1e300"] {
                let e = LaunchArgs::try_parse_from(["foresight", flag, bad])
                    .expect_err(bad)
                    .to_string();
                assert!(e.contains(flag), "{flag} {bad}: {e}");
            }
        }
    }

    /// Issue 30 item 1: what only `xarm-sim` may be given, and the refusals decided before
    /// any connection (the proof itself: `tests/tests/sim_identity.rs`).
    #[test]
    fn simulation_rights_go_by_identity_not_address() {
        let synthetic = [
            "from the synthetic camera (--camera synthetic)",
            "with the bundled calibration (no --calibration)",
        ];
        assert_eq!(
            args(&["--robot", "127.0.0.1:5020"]).simulation_only_asks(),
            synthetic
        );
        assert_eq!(
            args(&["--robot", "127.0.0.1:5020", "--no-lookahead", "--dry-run"])
                .simulation_only_asks(),
            ["blind (--no-lookahead)"]
        );
        let real = ["--camera", "ros2", "--calibration", "cal.toml"];
        for ok in [
            args(&[]),
            args(&["--no-lookahead"]),
            args(&["--robot", "127.0.0.1:5020", "--dry-run"]),
            args(&[&["--robot", "127.0.0.1:5020"][..], &real[..]].concat()),
        ] {
            // No --robot (the launcher's own xarm-sim gets a fresh secret), or nothing
            // simulation-only asked: no secret needed, nothing is asked of the arm.
            assert_eq!(ok.check_sim_identity(), Ok(None), "{ok:?}");
        }
        assert!(args(&["--robot", "127.0.0.1:5020"]).simulated_sensors());
        assert!(!args(&real).simulated_sensors());
        let e = args(&["--robot", "10.0.0.2", "--no-lookahead"])
            .check_sim_identity()
            .expect_err("off loopback");
        assert!(e.to_string().contains("no connection was attempted"), "{e}");
        if std::env::var_os(SIM_SECRET_ENV).is_none() {
            let e = args(&["--robot", "127.0.0.1:5020", "--no-lookahead"])
                .check_sim_identity()
                .expect_err("no secret");
            let m = e.to_string();
            assert!(
                m.starts_with("--robot 127.0.0.1:5020 has not proven it is xarm-sim")
                    && m.contains("no simulator secret in FORESIGHT_SIM_SECRET")
                    && m.contains("treated as a real arm")
                    && m.contains("blind (--no-lookahead)")
                    && m.contains(synthetic[0])
                    && m.contains(synthetic[1])
                    && m.contains("no process was started"),
                "{m}"
            );
        }
    }

    #[test]
    fn blind_mode_is_refused_for_a_robot_off_this_machine() {
        for robot in ["10.0.0.2", "192.168.1.195", "192.0.2.10:502"] {
            let e = args(&["--robot", robot, "--no-lookahead"])
                .check_blind_mode()
                .expect_err(robot);
            assert!(
                e.to_string()
                    .contains(&format!("non-loopback robot address {robot}")),
                "{e}"
            );
        }
        for ok in [
            args(&["--no-lookahead"]),
            args(&["--robot", "127.0.0.1:5020", "--no-lookahead"]),
            args(&["--robot", "[::1]:5020", "--no-lookahead"]),
            args(&["--robot", "localhost", "--no-lookahead"]),
            args(&["--robot", "192.168.1.195"]),
        ] {
            assert_eq!(ok.check_blind_mode(), Ok(()), "{ok:?}");
        }
    }
}
