//! The xArm5 digital twin: robot model, kinematics, scene geometry and the reaching task.
//!
//! One definition of the robot and of the task, used by the learner (training
//! environments), by rt-core's lookahead and safety shield, and by the simulated arm's
//! ground-truth collision check. Everything is loaded and validated once; every per-step
//! query (`fk`, `IkSolver::solve`, `RobotGeometry::distance`, `TwinEnv::step`) works on
//! fixed-size arrays and does not allocate.
//!
//! # Frames and units
//! All positions are metres in the robot base frame (z up, the table top at
//! `Scene::table_height_m`), joint angles radians, times seconds.
//!
//! # API in brief
//! - [`RobotModel`]: `RobotModel::load(path)` / `from_urdf_str` (refused when a moving link
//!   has no collision shape), [`JointLimits`], `home()`, `fk(&q) -> LinkPoses` (frames
//!   `link_base, link1..link5`, plus the TCP), `link_name(i)`, `set_tool` (the task's
//!   `[tool]` capsule on the flange).
//! - [`IkSolver`]: damped least squares on the TCP position, joint limits, null-space pull
//!   toward home: `IkSolver::new(&model, IkConfig).solve(&model, &target_m, &q_start)`.
//! - [`Scene`]: table height, goal cube, up to [`MAX_OBSTACLES`] axis-aligned boxes;
//!   `Scene::from_file(&SceneFile)` / `to_file()`.
//! - [`RobotGeometry`]: one or two capsules per link (from the URDF collision cylinders)
//!   plus the tool's; `distance(&poses, &scene) -> DistanceReport`, `distance_to_boxes`,
//!   `in_contact`, `self_distance` / `self_collision` (non-adjacent link pairs,
//!   [`SELF_PAIRS`], below [`SELF_COLLISION_MIN_DISTANCE_M`]), `all_distances`.
//!   **The table** counts for links 2–5 and the tool only: the base and link 1 stand on
//!   it. The goal cube is not an obstacle.
//! - [`TaskConfig`] (`assets/task.toml`) and [`TwinEnv`]: the reaching MDP, `reset`, `step`,
//!   `sample_scene`, and [`rollout`] (a whole episode with a policy closure).
//! - Feasibility (planning code, allocates): [`check_goal_postures`] (safe IK postures at
//!   the goal target from deterministic seeds), [`plan_path`] (RRT-Connect in joint space
//!   under the task's contact rule, [`is_safe_posture`]) and [`check_feasibility`] (both;
//!   [`Feasibility`] or an [`InfeasibleReason`] in words and as `RetrainProgress` bytes).
//! - Goal-posture choice ([`choose_goal_posture`]): the goal target's IK branches (base
//!   facing / flipped, elbow up / down, wrist pitches, and the IK's own solution from the
//!   start), those in contact or closer than the clearance dropped, the rest ordered by
//!   joint-space distance from the start; [`PostureChoiceError`] says why there is none.
//! - One verification ([`approval`]): "would rt-core approve this plan in this scene" —
//!   Ruckig smoothing with rt-core's settings, the shield on every sample, the goal on the
//!   smoothed path ([`approval::smooth_and_check`], [`approval::EpisodeApproval`]); rt-core's
//!   approver and the learner's evaluation both run it.
//! - Verified sampling ([`Sampler`], [`SamplingSettings`]): K perturbed rollouts of a
//!   policy on a few threads, each verified as the lookahead verifies the deterministic
//!   one, the best that passes kept (rt-core's twin worker before its planner fallback;
//!   `unseen-worlds --samples`, pass@K).
//!
//! # Observation (`[f32; OBS_DIM]`, raw SI units; the policy blob carries normalisation)
//! | index | meaning | unit |
//! |---|---|---|
//! | 0 | `t` = step index / `max_steps` (0 at reset) | 1 |
//! | 1–2 | goal cube centre x, y | m |
//! | 3–5 | TCP position | m |
//! | 6–8 | TCP velocity (last step's displacement / `step_period_s`) | m/s |
//! | 9 | height of the nearest obstacle box (`size_m[2]`) | m |
//! | 10 | width of the nearest obstacle box (larger horizontal extent) | m |
//! | 11–13 | closest point on the robot to that box | m |
//! | 14–16 | closest point on that box to the robot | m |
//!
//! "Nearest box" is the box with the smallest robot distance. In a scene without boxes
//! indices 9–10 are 0 and the closest points are those between the robot and the table.
//!
//! That is the paper's observation (`TaskConfig::obs_dim()` = 17). With `[observation] kind
//! = "nearest_boxes"` and `boxes = k` (the bundled task: k = 3), indices `17 + 6·(j−2)`
//! onward describe the j-th nearest box for j = 2 … k:
//!
//! | offset | meaning | unit |
//! |---|---|---|
//! | +0 | its height | m |
//! | +1 | its width | m |
//! | +2–4 | the closest point on it to the robot | m |
//! | +5 | the robot–box distance, capped at 1 | m |
//!
//! A missing box reads as zeros with distance 1. Values past the task's `obs_dim()` are 0.
//! A blob of this layout records `obs_layout` = `shm_schemas::OBS_LAYOUT_CARTESIAN` (0).
//!
//! ## The joint-step space's observation (layout version 1: `OBS_LAYOUT_JOINT_V1`)
//! With [`TwinEnv::set_action_space`]`(ActionSpace::JointStep)` the observation is
//! [`JOINT_OBS_DIM`] (29) values whatever the task's `[observation]`; `g` is the episode's
//! goal posture ([`choose_goal_posture`] at the reset; the current joints when there is
//! none), `q` the joints:
//!
//! | index | meaning | unit |
//! |---|---|---|
//! | 0 | `t` = step index / `max_steps` | 1 |
//! | 1–5 | joint error `g − q`, joint 1 first | rad |
//! | 6–10 | goal posture `g` | rad |
//! | 11–13 | TCP position | m |
//! | 14–16 | goal target point | m |
//! | 17 | height of the nearest obstacle box | m |
//! | 18 | width of the nearest obstacle box | m |
//! | 19–21 | closest point on the robot to that box | m |
//! | 22–24 | closest point on that box to the robot | m |
//! | 25 | the robot–box distance of that box, capped at 1 | m |
//! | 26–27 | the robot distances of the 2nd and 3rd nearest boxes, capped at 1 (1 if none) | m |
//! | 28 | the robot–table distance (links 2–5 and the tool), capped at 1 | m |
//!
//! Without boxes, 17–18 are 0 and 19–25 describe the table, as in the Cartesian table.
//!
//! # Action
//! The Cartesian step (`[f32; ACT_DIM]`, [`TwinEnv::step`], the paper's): `[dx, dy, dz]`
//! in `[-1, 1]` (clipped), times `action.scale_m`: the TCP displacement asked for this
//! step. The IK turns it into joints.
//!
//! The joint step (`[f32; JOINT_ACT_DIM]`, [`TwinEnv::step_joint`]): five per-joint steps
//! in `[-1, 1]` (clipped), times `action.joint_scale_rad` (rad, each ≤
//! [`MAX_JOINT_SCALE_RAD`]; [`DEFAULT_JOINT_SCALE_RAD`] when absent).
//!
//! In both spaces the joint change per step is then limited to `velocity_rad_s ×
//! step_period_s` and the joints clamped into their limits (one code path); a plan of
//! either space is approved the same way ([`approval`]: the smoother's TCP-speed cap, the
//! shield's step bound on every sample).
//!
//! # Reward
//! `r = c1·r_g + c2·r_a + c3·r_o (+ terminal)` with `r_g = d_{t-1} − d_t` (TCP to the goal
//! target point, m), `r_a = −‖a‖` (clipped action), `r_o = −1` when the robot–box distance
//! is below `d_thre_m`. The goal target point is `goal_hover_m` above the goal cube's top.
//! `terminal` (an addition to the paper's three terms, set both weights to 0 to drop it) is
//! `+success_bonus` on success and `−collision_penalty` on contact (a self-collision is a
//! contact: the same penalty).
//!
//! # Termination
//! `task_done` (TCP within `tolerance_m` of the target point) terminates; contact (any link
//! or the tool closer to a box than `min_box_clearance_m`, links 2–5 or the tool closer
//! than that to the table, or a self-collision: a checked pair of links closer than
//! [`SELF_COLLISION_MIN_DISTANCE_M`], `StepOutcome::self_collision`) terminates with
//! `safe = false` and the collision penalty, as a too-close obstacle does;
//! `truncated` after `max_steps` steps. `StepOutcome::distance` (and
//! `EpisodeSummary::min_distance_m`) is the robot–box report of the nearest box, or the
//! robot–table report in a scene without boxes.
//!
//! # Example
//! ```no_run
//! use std::path::Path;
//! use twin::{RobotModel, Scene, TaskConfig, TwinEnv, rollout};
//! use shm_schemas::scene_file::SceneFile;
//!
//! let model = RobotModel::load(Path::new("assets/xarm5.urdf"))?;
//! let task = TaskConfig::load(Path::new("assets/task.toml"))?;
//! let scene = Scene::from_file(&SceneFile::load(Path::new("assets/scenes/tall_box.toml"))?)?;
//! let mut env = TwinEnv::new(model, task);
//! env.reset(&scene);
//! let policy = env.straight_line_policy();
//! let summary = rollout(&mut env, &scene, |obs| policy.act(obs), None);
//! assert!(!summary.safe); // the straight line runs into the tall box
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![forbid(unsafe_code)]

pub mod approval;
mod env;
mod feasibility;
mod geometry;
mod ik;
mod kinematics;
mod model;
mod planner;
mod posture;
mod sampling;
mod scene;
mod task;

pub use env::{
    EpisodeSummary, JointLinePolicy, RewardTerms, StepOutcome, StraightLinePolicy, TwinEnv,
    rollout, rollout_joint, rollout_until,
};
pub use feasibility::{
    Blocker, Feasibility, FeasibilityConfig, GOAL_IK_ITERATIONS, GoalPosture, GoalPostureCheck,
    InfeasibleReason, LINK_TOOL, MAX_GOAL_POSTURES, check_feasibility, check_goal_postures,
};
pub use geometry::{
    DistanceReport, Distances, RobotGeometry, SELF_COLLISION_MIN_DISTANCE_M, SELF_PAIRS,
    SelfDistance,
};
pub use ik::{IkConfig, IkResult, IkSolver};
pub use kinematics::LinkPoses;
pub use model::{
    ACCELERATION_LIMIT_RAD_S2, COLLISION_MARGIN_M, JERK_LIMIT_RAD_S3, JointLimits, LinkCapsule,
    LinkName, MAX_CAPSULES, N_FRAMES, RobotModel, TOOL_FRAME, UrdfLoadError,
};
pub use planner::{PlanOutcome, PlannerBudget, densify_path, is_safe_posture, plan_path};
pub use posture::{
    BaseSide, Branch, BranchPosture, Elbow, MAX_BRANCH_POSTURES, POSTURE_IK_ITERATIONS,
    PostureChoice, PostureChoiceError, choose_goal_posture,
};
pub use sampling::{
    MAX_SAMPLE_THREADS, MAX_SAMPLES, Sample, SampleReport, Sampler, SamplingSettings,
};
pub use scene::{BoxObstacle, Goal, Obstacles, Scene, SceneError};
pub use shm_schemas::scene_file::MAX_OBSTACLES;
pub use task::{
    DEFAULT_JOINT_SCALE_RAD, EXTRA_BOX_VALUES, MAX_EPISODE_STEPS, MAX_JOINT_SCALE_RAD,
    MAX_OBSERVED_BOXES, MAX_TOOL_RADIUS_M, MAX_TOOL_REACH_M, MAX_WORLD_BOXES, ObservationConfig,
    ObservationKind, ObstacleClass, TaskConfig, TaskConfigError, ToolConfig, WorldConfig,
};

/// Number of actuated joints of the xArm5.
pub const DOF: usize = 5;

/// A joint configuration (rad), joint 1 first.
pub type Joints = [f64; DOF];

/// Lengths of the observation and action vectors: the policy contract's (`shm-schemas`).
pub use shm_schemas::{ACT_DIM, JOINT_ACT_DIM, JOINT_OBS_DIM, OBS_DIM, PAPER_OBS_DIM};

/// The largest per-joint difference between two joint vectors, rad (no allocation: the
/// controller's cycle uses it too).
pub fn max_joint_gap_rad(a: &Joints, b: &Joints) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
