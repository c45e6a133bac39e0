//! The task's configuration (`assets/task.toml`): episode length, step period, action
//! scale, reward weights, success tolerance, sampling ranges, obstacle size classes, the
//! start posture, the per-step IK settings and the optional tool. Loaded and validated
//! once; its [`TaskConfig::hash`] travels with every policy trained on it.
//!
//! The tool (`[tool]`, a gripper on the flange) belongs to the task because it changes
//! what the policy is trained on: with a `[tool]` section the canonical TOML, and so the
//! hash, changes (policies trained without the tool are refused); without one the
//! canonical TOML is byte for byte what it was before the section existed, so the
//! bundled policies still load.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::Joints;
use super::ik::IkConfig;
use super::model::LinkCapsule;

/// Largest tool capsule radius (m).
pub const MAX_TOOL_RADIUS_M: f64 = 0.15;

/// Largest distance of a tool capsule end from the flange (m).
pub const MAX_TOOL_REACH_M: f64 = 0.30;

/// Capacity of a waypoint buffer: the longest episode a task file may configure.
pub const MAX_EPISODE_STEPS: usize = 256;

/// Why a task file was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TaskConfigError {
    /// The file could not be read.
    #[error("cannot read the task file: {0}")]
    Io(std::io::ErrorKind),
    /// Malformed TOML, a missing or an unknown field (the parser's message is logged).
    #[error("malformed task file (bad TOML, or a missing or unknown field)")]
    Parse,
    /// A value out of range; the text names the field.
    #[error("invalid task file: {0}")]
    Invalid(&'static str),
}

/// `[episode]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpisodeConfig {
    /// Steps before truncation (≤ `MAX_EPISODE_STEPS`).
    pub max_steps: u32,
    /// Time per step (s).
    pub step_period_s: f64,
}

/// Step of each joint for an action component of 1 in the joint-step space, rad, when the
/// task does not set `action.joint_scale_rad` (0.6 rad/s at the bundled 20 Hz).
pub const DEFAULT_JOINT_SCALE_RAD: Joints = [0.03; 5];

/// Largest `action.joint_scale_rad` component, rad per step.
pub const MAX_JOINT_SCALE_RAD: f64 = 0.1;

/// `[action]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionConfig {
    /// TCP displacement per step for an action component of 1 (m): the Cartesian-step
    /// space (the paper's).
    pub scale_m: f64,
    /// Step of each joint per step for an action component of 1 (rad, each in
    /// `(0, MAX_JOINT_SCALE_RAD]`): the joint-step space. Absent = [`DEFAULT_JOINT_SCALE_RAD`]
    /// and left out of the canonical TOML (the hash of a task without it is unchanged).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_scale_rad: Option<Joints>,
}

impl ActionConfig {
    /// The joint-step scale: `joint_scale_rad` or [`DEFAULT_JOINT_SCALE_RAD`].
    pub fn joint_scale_rad(&self) -> Joints {
        self.joint_scale_rad.unwrap_or(DEFAULT_JOINT_SCALE_RAD)
    }
}

/// `[reward]`: `r = c1·r_g + c2·r_a + c3·r_o + terminal`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RewardConfig {
    /// Weight of the progress term (1/m).
    pub c1: f64,
    /// Weight of the action term.
    pub c2: f64,
    /// Weight of the proximity term.
    pub c3: f64,
    /// Robot–box distance below which the proximity term is −1 (m).
    pub d_thre_m: f64,
    /// Added on success (0 for the paper's reward).
    pub success_bonus: f64,
    /// Subtracted on contact (0 for the paper's reward).
    pub collision_penalty: f64,
}

/// `[success]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuccessConfig {
    /// TCP distance to the goal target point that counts as reached (m).
    pub tolerance_m: f64,
    /// Height of the goal target point above the goal cube's top face (m).
    pub goal_hover_m: f64,
    /// Robot–box and robot–table distance (from the inflated capsules; the table for links
    /// 2–5) below which a step counts as contact: the episode ends unsafe. At least the runtime shield's
    /// `min_distance_m` plus a few mm for smoothing, so that an episode the lookahead
    /// passes is a plan the shield accepts (rt-core checks this at start). Default 0.
    #[serde(default)]
    pub min_box_clearance_m: f64,
}

/// `[start]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartConfig {
    /// Joints at reset (rad); also the IK's null-space home.
    pub joints_rad: Joints,
}

/// `[sampling]`: random scenes for training.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingConfig {
    /// Table height (m).
    pub table_height_m: f64,
    /// Goal centre x range (m).
    pub goal_x_m: [f64; 2],
    /// Goal centre y range (m).
    pub goal_y_m: [f64; 2],
    /// Goal cube edge (m).
    pub goal_size_m: f64,
    /// Least horizontal distance between the start TCP and the goal (m).
    pub min_goal_distance_m: f64,
    /// Obstacle position as a fraction of the way from the start TCP to the goal.
    pub obstacle_fraction: [f64; 2],
    /// Sideways offset of the obstacle from the start→goal line (m).
    pub obstacle_lateral_m: [f64; 2],
    /// Least horizontal gap between the obstacle and the goal cube (m).
    pub goal_clearance_m: f64,
}

/// Size ranges of one obstacle class.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSizeRange {
    /// Horizontal extent range, each of x and y (m).
    pub footprint_m: [f64; 2],
    /// Height range (m).
    pub height_m: [f64; 2],
}

/// `[obstacles]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleClasses {
    /// Small boxes (the pre-training curriculum).
    pub small: BoxSizeRange,
    /// Large (tall) boxes.
    pub large: BoxSizeRange,
}

/// Obstacle size class for [`super::TwinEnv::sample_scene`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ObstacleClass {
    /// Small box.
    Small,
    /// Large (tall) box.
    Large,
}

/// `[tool]` (optional): a capsule fixed to the flange, in link5's frame (origin on the
/// flange face, z out of the flange). Every distance query includes it: the boxes, the
/// table and the self-collision check (against the base, link1, link2 and link3), in the
/// task, the lookahead and the shield ([`super::RobotModel::set_tool`]). The TCP stays
/// the flange: raise `success.goal_hover_m` by the tool's length, or reaching the goal
/// point puts the tool into the goal's table.
///
/// ```toml
/// [tool]                     # a 12 cm parallel gripper, enclosed
/// from_m = [0.0, 0.0, 0.0]   # capsule axis, first end (m, flange frame)
/// to_m = [0.0, 0.0, 0.09]    # second end: the gripper's length along the flange axis
/// radius_m = 0.045
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolConfig {
    /// First end of the capsule axis in the flange (link5) frame (m).
    pub from_m: [f64; 3],
    /// Second end of the capsule axis in the flange frame (m).
    pub to_m: [f64; 3],
    /// Capsule radius (m), padding included.
    pub radius_m: f64,
}

impl ToolConfig {
    /// The tool as a capsule in link5's frame.
    pub fn capsule(&self) -> LinkCapsule {
        LinkCapsule {
            frame: super::DOF,
            a_m: self.from_m,
            b_m: self.to_m,
            radius_m: self.radius_m,
        }
    }

    /// Checks the bounds: finite ends within [`MAX_TOOL_REACH_M`] of the flange, a radius
    /// in `(0, MAX_TOOL_RADIUS_M]`.
    ///
    /// # Errors
    /// The name of the first bad field.
    pub fn validate(&self) -> Result<(), &'static str> {
        let within = |p: &[f64; 3]| {
            p.iter().all(|v| v.is_finite())
                && (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() <= MAX_TOOL_REACH_M
        };
        if !within(&self.from_m) {
            return Err("tool.from_m must be finite and within 0.3 m of the flange");
        }
        if !within(&self.to_m) {
            return Err("tool.to_m must be finite and within 0.3 m of the flange");
        }
        if !(pos(self.radius_m) && self.radius_m <= MAX_TOOL_RADIUS_M) {
            return Err("tool.radius_m must be in (0, 0.15] m");
        }
        Ok(())
    }
}

/// Which observation the policy sees (`[observation] kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObservationKind {
    /// The research system's 17 values: the nearest box only (the default when the task
    /// file has no `[observation]`, so the paper's setting stays reproducible).
    #[default]
    Paper,
    /// The paper's 17 values, then for the 2nd … k-th nearest boxes (by robot distance)
    /// 6 values each: height, width, the closest point on that box to the robot (x, y, z)
    /// and the robot–box distance (capped at 1 m). Missing boxes read as zeros with
    /// distance 1 m.
    NearestBoxes,
}

/// Most boxes the `nearest_boxes` observation describes (`[observation] boxes`).
pub const MAX_OBSERVED_BOXES: u32 = 3;

/// Values per extra box of the `nearest_boxes` observation.
pub const EXTRA_BOX_VALUES: usize = 6;

/// `[observation]` (optional; absent = the paper's observation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservationConfig {
    /// The layout.
    pub kind: ObservationKind,
    /// Boxes described (`nearest_boxes`: 1..=3; the paper's: 1).
    pub boxes: u32,
}

/// `[world]` (optional): the broad world distribution of the generalist policy's
/// pre-training and of the unseen-worlds benchmark ([`super::TwinEnv::sample_world`]).
///
/// A world is a goal drawn as in `[sampling]` and `boxes` boxes; each box is, by the
/// shares, on the straight start→goal path (`on_path_share`, at a fraction
/// `sampling.obstacle_fraction` of the way with `sampling.obstacle_lateral_m` sideways),
/// beside the goal (`near_goal_share`, `goal_clearance_m` to `goal_clearance_m +
/// near_goal_gap_m` from the goal cube), a wall across the path (`wall_share`, one extent
/// `wall_length_m`, the other the footprint's low end), or anywhere in `x_m` × `y_m`.
/// Box footprints and heights are uniform in the ranges. A box is redrawn when it would
/// touch the arm at its start posture (within `reward.d_thre_m`) or at the goal posture
/// the IK finds from the start (within half of that), or come nearer the goal cube than
/// `sampling.goal_clearance_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldConfig {
    /// Box count range (1..=3 … up to 8).
    pub boxes: [u32; 2],
    /// Horizontal extent range, each of x and y (m).
    pub footprint_m: [f64; 2],
    /// Height range (m).
    pub height_m: [f64; 2],
    /// Range of box centres' x for boxes placed anywhere (m).
    pub x_m: [f64; 2],
    /// Range of box centres' y for boxes placed anywhere (m).
    pub y_m: [f64; 2],
    /// Share of boxes on the straight path.
    pub on_path_share: f64,
    /// Share of boxes beside the goal.
    pub near_goal_share: f64,
    /// Share of boxes that are walls across the path.
    pub wall_share: f64,
    /// A wall's long extent (m).
    pub wall_length_m: [f64; 2],
    /// How far beyond `sampling.goal_clearance_m` a box beside the goal may be (m).
    pub near_goal_gap_m: f64,
}

/// Most boxes a `[world]` may ask for.
pub const MAX_WORLD_BOXES: u32 = 8;

impl WorldConfig {
    /// Checks the bounds.
    ///
    /// # Errors
    /// The name of the first bad field.
    pub fn validate(&self) -> Result<(), &'static str> {
        if self.boxes[0] > self.boxes[1] || self.boxes[1] > MAX_WORLD_BOXES {
            return Err("world.boxes must be a [low, high] range within 0..=8");
        }
        let sizes = [self.footprint_m, self.height_m, self.wall_length_m];
        if !sizes.iter().all(|r| range_ok(r) && pos(r[0]) && r[1] < 1.0) {
            return Err(
                "world.footprint_m / height_m / wall_length_m must be positive [low, high] ranges below 1 m",
            );
        }
        if !range_ok(&self.x_m)
            || !range_ok(&self.y_m)
            || self.x_m.iter().chain(&self.y_m).any(|v| v.abs() > 1.0)
        {
            return Err("world.x_m / y_m must be [low, high] ranges within ±1 m of the base");
        }
        let shares = [self.on_path_share, self.near_goal_share, self.wall_share];
        if !shares.iter().all(|v| v.is_finite() && *v >= 0.0) || shares.iter().sum::<f64>() > 1.0 {
            return Err(
                "world.on_path_share, near_goal_share and wall_share must be ≥ 0 and sum to at most 1",
            );
        }
        if !(self.near_goal_gap_m.is_finite() && (0.0..0.5).contains(&self.near_goal_gap_m)) {
            return Err("world.near_goal_gap_m must be in [0, 0.5) m");
        }
        Ok(())
    }
}

/// The whole task configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskConfig {
    /// Episode length and step period.
    pub episode: EpisodeConfig,
    /// Action scaling.
    pub action: ActionConfig,
    /// Reward weights.
    pub reward: RewardConfig,
    /// Success criterion.
    pub success: SuccessConfig,
    /// Start posture.
    pub start: StartConfig,
    /// Scene sampling.
    pub sampling: SamplingConfig,
    /// Obstacle classes.
    pub obstacles: ObstacleClasses,
    /// Per-step IK settings.
    pub ik: IkConfig,
    /// The tool on the flange, if any. Absent, it is left out of the canonical TOML (the
    /// hash of a task without a tool is unchanged by this field's existence).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<ToolConfig>,
    /// The observation; absent = the paper's (left out of the canonical TOML then, like
    /// `tool`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observation: Option<ObservationConfig>,
    /// The broad world distribution, if the task has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world: Option<WorldConfig>,
}

fn range_ok(r: &[f64; 2]) -> bool {
    r[0].is_finite() && r[1].is_finite() && r[0] <= r[1]
}

fn pos(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

impl TaskConfig {
    /// Reads and validates a task file.
    ///
    /// # Errors
    /// [`TaskConfigError`].
    pub fn load(path: &Path) -> Result<Self, TaskConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| TaskConfigError::Io(e.kind()))?;
        Self::from_toml_str(&text)
    }

    /// Parses and validates task TOML.
    ///
    /// # Errors
    /// [`TaskConfigError::Parse`] or [`TaskConfigError::Invalid`].
    pub fn from_toml_str(text: &str) -> Result<Self, TaskConfigError> {
        let cfg: Self = toml::from_str(text).map_err(|e| {
            tracing::warn!("task file: {e}");
            TaskConfigError::Parse
        })?;
        cfg.validate().map_err(TaskConfigError::Invalid)?;
        Ok(cfg)
    }

    /// Checks every range.
    ///
    /// # Errors
    /// The name of the first bad field.
    pub fn validate(&self) -> Result<(), &'static str> {
        let e = &self.episode;
        if e.max_steps == 0 || e.max_steps as usize > MAX_EPISODE_STEPS {
            return Err("episode.max_steps must be in 1..=MAX_EPISODE_STEPS (256)");
        }
        if !(pos(e.step_period_s) && e.step_period_s <= 1.0) {
            return Err("episode.step_period_s must be in (0, 1] s");
        }
        if !(pos(self.action.scale_m) && self.action.scale_m <= 0.1) {
            return Err("action.scale_m must be in (0, 0.1] m");
        }
        if !self
            .action
            .joint_scale_rad()
            .iter()
            .all(|v| pos(*v) && *v <= MAX_JOINT_SCALE_RAD)
        {
            return Err("action.joint_scale_rad must be in (0, 0.1] rad for every joint");
        }
        let r = &self.reward;
        if ![r.c1, r.c2, r.c3, r.success_bonus, r.collision_penalty]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
        {
            return Err(
                "reward weights (c1, c2, c3, success_bonus, collision_penalty) must be finite and ≥ 0",
            );
        }
        if !(r.d_thre_m.is_finite() && r.d_thre_m >= 0.0 && r.d_thre_m < 1.0) {
            return Err("reward.d_thre_m must be in [0, 1) m");
        }
        let s = &self.success;
        if !(pos(s.tolerance_m) && s.tolerance_m < 0.5) {
            return Err("success.tolerance_m must be in (0, 0.5) m");
        }
        if !(s.goal_hover_m.is_finite() && (0.0..0.5).contains(&s.goal_hover_m)) {
            return Err("success.goal_hover_m must be in [0, 0.5) m");
        }
        if !(s.min_box_clearance_m.is_finite() && (0.0..0.2).contains(&s.min_box_clearance_m)) {
            return Err("success.min_box_clearance_m must be in [0, 0.2) m");
        }
        if !self.start.joints_rad.iter().all(|v| v.is_finite()) {
            return Err("start.joints_rad must be finite");
        }
        let g = &self.sampling;
        if !g.table_height_m.is_finite() || g.table_height_m.abs() > 1.0 {
            return Err("sampling.table_height_m must be within ±1 m");
        }
        if !range_ok(&g.goal_x_m) || !range_ok(&g.goal_y_m) {
            return Err("sampling.goal_x_m / goal_y_m must be [low, high] ranges");
        }
        if g.goal_x_m.iter().chain(&g.goal_y_m).any(|v| v.abs() > 1.0) {
            return Err("sampling goal ranges must lie within ±1 m of the base");
        }
        if !(pos(g.goal_size_m) && g.goal_size_m < 0.5) {
            return Err("sampling.goal_size_m must be in (0, 0.5) m");
        }
        if !(g.min_goal_distance_m.is_finite() && g.min_goal_distance_m >= 0.0) {
            return Err("sampling.min_goal_distance_m must be ≥ 0");
        }
        if !range_ok(&g.obstacle_fraction)
            || g.obstacle_fraction[0] < 0.0
            || g.obstacle_fraction[1] > 1.0
        {
            return Err("sampling.obstacle_fraction must be a range within [0, 1]");
        }
        if !range_ok(&g.obstacle_lateral_m) {
            return Err("sampling.obstacle_lateral_m must be a [low, high] range");
        }
        if !(g.goal_clearance_m.is_finite() && g.goal_clearance_m >= 0.0) {
            return Err("sampling.goal_clearance_m must be ≥ 0");
        }
        for c in [&self.obstacles.small, &self.obstacles.large] {
            if !range_ok(&c.footprint_m)
                || !range_ok(&c.height_m)
                || !pos(c.footprint_m[0])
                || !pos(c.height_m[0])
                || c.footprint_m[1] >= 1.0
                || c.height_m[1] >= 1.0
            {
                return Err("obstacles.small/large ranges must be positive [low, high] below 1 m");
            }
        }
        self.ik.validate()?;
        if let Some(o) = &self.observation {
            let ok = match o.kind {
                ObservationKind::Paper => o.boxes == 1,
                ObservationKind::NearestBoxes => (1..=MAX_OBSERVED_BOXES).contains(&o.boxes),
            };
            if !ok {
                return Err(
                    "observation.boxes must be 1 for kind = \"paper\" and 1..=3 for \"nearest_boxes\"",
                );
            }
        }
        if let Some(w) = &self.world {
            w.validate()?;
        }
        match &self.tool {
            Some(t) => t.validate(),
            None => Ok(()),
        }
    }

    /// The observation's layout (the paper's when the file has no `[observation]`).
    pub fn observation(&self) -> ObservationConfig {
        self.observation.unwrap_or(ObservationConfig {
            kind: ObservationKind::Paper,
            boxes: 1,
        })
    }

    /// Length of this task's observation: a prefix of the twin's `[f32; OBS_DIM]`.
    pub fn obs_dim(&self) -> usize {
        let o = self.observation();
        match o.kind {
            ObservationKind::Paper => shm_schemas::PAPER_OBS_DIM,
            ObservationKind::NearestBoxes => {
                shm_schemas::PAPER_OBS_DIM + EXTRA_BOX_VALUES * (o.boxes as usize - 1)
            }
        }
    }

    /// The canonical TOML of this configuration (what [`TaskConfig::hash`] hashes).
    pub fn to_toml_string(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// Stable 64-bit FNV-1a hash of the canonical TOML serialisation. Equal configurations
    /// hash equal on every machine; any changed value changes the hash.
    pub fn hash(&self) -> u64 {
        shm_schemas::checksum::fnv1a_64(self.to_toml_string().as_bytes())
    }
}
