//! The one view of rt-core's runtime configuration (`assets/runtime.toml`) that other
//! processes read too: `[intake]` (what is accepted from perception, and where a goal may
//! lie), `[shield]` (the TCP's workspace and margins), `[goal]` (where the goal comes from) and
//! `return_home`, each section with its defaults, defined here once; and `[limits]`
//! ([`MotionLimits`]), which the learner's verification of a plan reads with `[shield]`
//! (`twin::approval::ApprovalSettings`). rt-core's
//! `config::RuntimeConfig` holds these sections as its own and validates their ranges at
//! load; `ros-bridge` takes the `Reach` action's [`GoalBounds`] from them
//! ([`RuntimeView::goal_bounds`]) and the launcher the goal source and `return_home`, so no
//! process keeps a copy of another's defaults.
//!
//! ```
//! use shm_schemas::runtime_view::{GoalSource, RuntimeView};
//!
//! let view = RuntimeView::from_toml(
//!     "rate_hz = 250.0\n[shield]\nworkspace_min_m = [-0.8, -0.8, 0.0]\n\
//!      workspace_max_m = [0.8, 0.8, 1.0]\nmin_distance_m = 0.01\njoint_margin_rad = 0.01\n",
//! )
//! .unwrap();
//! assert_eq!(view.goal.source, GoalSource::Camera);
//! assert_eq!(view.goal_bounds().unwrap().max_radius_m, view.intake.goal_max_radius_m);
//! assert!(view.return_home);
//! ```

use std::path::Path;

use serde::{Deserialize, Deserializer};

use crate::GoalBounds;

/// The largest distance kept by default between the twin's TCP and the TCP the controller
/// reports, m (`[shield] max_tcp_gap_m`; the xArm adapter's `MAX_TCP_GAP_M` in rt-core).
pub const DEFAULT_MAX_TCP_GAP_M: f64 = 0.005;

/// What the other processes read of the runtime configuration: the sections above, and
/// nothing of the rest (unknown top-level keys are rt-core's, which validates the whole
/// file when it starts).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct RuntimeView {
    /// `return_home`: whether rt-core brings the arm home after each goal.
    #[serde(default = "default_return_home")]
    pub return_home: bool,
    /// `[intake]`.
    #[serde(default)]
    pub intake: IntakeConfig,
    /// `[shield]` (rt-core requires it; the launcher reads files without it).
    #[serde(default)]
    pub shield: Option<ShieldConfig>,
    /// `[goal]`.
    #[serde(default)]
    pub goal: GoalConfig,
}

/// `return_home`'s default: on.
pub fn default_return_home() -> bool {
    true
}

/// Why the runtime configuration could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeViewError {
    /// The file could not be read.
    #[error("cannot read {path}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not TOML of the expected shape.
    #[error("invalid runtime config")]
    Parse(#[from] toml::de::Error),
}

impl RuntimeView {
    /// Reads the view from a file.
    ///
    /// # Errors
    /// [`RuntimeViewError`] when unreadable or malformed.
    pub fn load(path: &Path) -> Result<Self, RuntimeViewError> {
        let text = std::fs::read_to_string(path).map_err(|source| RuntimeViewError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Ok(Self::from_toml(&text)?)
    }

    /// Parses the view from the file's text.
    ///
    /// # Errors
    /// The TOML error when malformed (a bad `goal.source` is named as such).
    pub fn from_toml(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    /// Where a requested goal (the `Reach` action) may lie; `None` without `[shield]`.
    pub fn goal_bounds(&self) -> Option<GoalBounds> {
        Some(goal_bounds(&self.intake, self.shield.as_ref()?))
    }
}

/// Where a requested goal may lie: `[intake]`'s reach and calibrated area, `[shield]`'s
/// workspace.
pub fn goal_bounds(intake: &IntakeConfig, shield: &ShieldConfig) -> GoalBounds {
    GoalBounds {
        min_radius_m: intake.goal_min_radius_m,
        max_radius_m: intake.goal_max_radius_m,
        table_min_m: intake.calibrated_min_m,
        table_max_m: intake.calibrated_max_m,
        workspace_min_m: shield.workspace_min_m,
        workspace_max_m: shield.workspace_max_m,
    }
}

/// Motion limits of the arm, per joint (`[limits]`; 5 joints, the xArm5's).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionLimits {
    /// Maximum joint velocity, rad/s.
    pub max_velocity_rad_s: [f64; 5],
    /// Maximum joint acceleration, rad/s².
    pub max_acceleration_rad_s2: [f64; 5],
    /// Maximum joint jerk, rad/s³.
    pub max_jerk_rad_s3: [f64; 5],
    /// Lower joint limits, rad.
    pub joint_min_rad: [f64; 5],
    /// Upper joint limits, rad.
    pub joint_max_rad: [f64; 5],
    /// Maximum TCP speed, m/s (the xArm controller faults at 1 m/s in servo mode).
    pub max_tcp_speed_m_s: f64,
}

/// Shield limits and margins.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShieldConfig {
    /// Workspace box of the TCP, lower corner in the base frame, m.
    pub workspace_min_m: [f64; 3],
    /// Workspace box of the TCP, upper corner, m.
    pub workspace_max_m: [f64; 3],
    /// Minimum allowed distance robot ↔ obstacles in the live scene, m.
    pub min_distance_m: f64,
    /// Margin kept from the joint limits, rad.
    pub joint_margin_rad: f64,
    /// Largest distance between the twin's TCP (FK of the measured joints) and the TCP the
    /// controller reports, m: more refuses the start, or stops the arm while running
    /// (`ModelMismatch`, latched until acknowledged).
    #[serde(default = "default_max_tcp_gap_m")]
    pub max_tcp_gap_m: f64,
}

fn default_max_tcp_gap_m() -> f64 {
    DEFAULT_MAX_TCP_GAP_M
}

/// What rt-core accepts from perception (`[intake]`): a frame with an object outside the
/// calibrated workspace, a goal out of reach or a stamp that is not fresh is refused whole
/// (counted, and the arm stops: see rt-core's `twin_thread::intake`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntakeConfig {
    /// A goal detected with less confidence than this counts as no goal (no plan). Obstacles
    /// are kept whatever their confidence: a false obstacle costs a detour, a missed one a
    /// collision.
    #[serde(default = "default_min_goal_confidence")]
    pub min_goal_confidence: f32,
    /// The calibrated workspace, lower corner (base frame, m): every detected object's
    /// centre must lie in this box, or the frame is refused (a detection out there means a
    /// wrong calibration or a wrong depth, not an object to plan around).
    #[serde(default = "default_calibrated_min_m")]
    pub calibrated_min_m: [f64; 3],
    /// The calibrated workspace, upper corner, m.
    #[serde(default = "default_calibrated_max_m")]
    pub calibrated_max_m: [f64; 3],
    /// A goal's centre must lie this far or farther from the base axis, m (closer, the arm
    /// would fold onto itself).
    #[serde(default = "default_goal_min_radius_m")]
    pub goal_min_radius_m: f64,
    /// A goal's centre must lie this far or nearer from the base axis, m (the xArm5 reaches
    /// 0.7 m).
    #[serde(default = "default_goal_max_radius_m")]
    pub goal_max_radius_m: f64,
    /// How far ahead of a frame's capture a moving obstacle's occupancy is predicted, s: a
    /// frame that is not settled has each obstacle swept along its velocity over this time
    /// and grown by its velocity's uncertainty (`twin_thread::intake::predicted_occupancy`).
    /// It covers the reaction (the frame's way to the cycle) and the arm's longest stop from
    /// its velocity limits: rt-core refuses a horizon below that floor (default 0.6 s: 0.1 s
    /// of reaction, the xArm5's 0.47 s stop along the plan, a cycle).
    #[serde(default = "default_prediction_horizon_s")]
    pub prediction_horizon_s: f64,
    /// Sigmas of a velocity's uncertainty the predicted occupancy is grown by.
    #[serde(default = "default_uncertainty_sigmas")]
    pub uncertainty_sigmas: f64,
    /// The assumed speed of an intruder whose velocity is not known yet (ISO/TS 15066's
    /// hand-arm speed, 1.6 m/s), m/s: the largest velocity uncertainty counted.
    #[serde(default = "default_intruder_speed_m_s")]
    pub intruder_speed_m_s: f64,
}

impl Default for IntakeConfig {
    fn default() -> Self {
        Self {
            min_goal_confidence: default_min_goal_confidence(),
            calibrated_min_m: default_calibrated_min_m(),
            calibrated_max_m: default_calibrated_max_m(),
            goal_min_radius_m: default_goal_min_radius_m(),
            goal_max_radius_m: default_goal_max_radius_m(),
            prediction_horizon_s: default_prediction_horizon_s(),
            uncertainty_sigmas: default_uncertainty_sigmas(),
            intruder_speed_m_s: default_intruder_speed_m_s(),
        }
    }
}

fn default_prediction_horizon_s() -> f64 {
    0.6
}
fn default_uncertainty_sigmas() -> f64 {
    2.0
}
fn default_intruder_speed_m_s() -> f64 {
    1.6
}

fn default_min_goal_confidence() -> f32 {
    0.5
}
fn default_calibrated_min_m() -> [f64; 3] {
    [-0.8, -0.8, -0.05]
}
fn default_calibrated_max_m() -> [f64; 3] {
    [0.8, 0.8, 1.0]
}
fn default_goal_min_radius_m() -> f64 {
    0.15
}
fn default_goal_max_radius_m() -> f64 {
    0.65
}

/// Which source gives the goal (`[goal] source`): the goal cube the camera sees
/// (`"camera"`, the default) or the ROS 2 `Reach` action served by `ros-bridge`
/// (`"action"`: the camera's goal cube is ignored, its obstacles still count, and nothing is
/// planned while no action goal is active). `rt-core run --goal-source` and
/// `foresight --goal-source` override it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GoalSource {
    /// The goal cube in the detections.
    #[default]
    Camera,
    /// The `Reach` action's goal (iceoryx2 `GoalRequest`s from the bridge).
    Action,
}

impl GoalSource {
    /// Its name in the configuration and on command lines.
    pub fn name(self) -> &'static str {
        match self {
            Self::Camera => "camera",
            Self::Action => "action",
        }
    }
}

/// `[goal]`: where the goal comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalConfig {
    /// The goal's source.
    #[serde(default)]
    pub source: GoalSource,
}

impl<'de> Deserialize<'de> for GoalSource {
    /// `"camera"` or `"action"`; anything else is refused naming the key
    /// (`goal.source = "both": must be "camera" or "action"`).
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let word = String::deserialize(d)?;
        match word.as_str() {
            "camera" => Ok(Self::Camera),
            "action" => Ok(Self::Action),
            other => Err(serde::de::Error::custom(format!(
                "goal.source = {other:?}: must be \"camera\" or \"action\""
            ))),
        }
    }
}
