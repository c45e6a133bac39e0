//! The planner's path re-tracked in the twin: every configuration along it, at a finer
//! joint resolution than the planner checked, against the task's contact rule, and the
//! end against the goal tolerance. The planner-fallback column of the benchmark: 100 % by
//! construction for a path the planner found (the fallback's ceiling, not a learned skill).

use twin::{Joints, Scene, TwinEnv, densify_path, is_safe_posture};

/// Joint resolution of the re-check (rad): finer than the planner's default 0.02 rad.
pub const TRACK_STEP_RAD: f64 = 0.01;

/// What re-tracking a path found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathCheck {
    /// Every configuration passes the task's contact rule (`twin::is_safe_posture`).
    pub safe: bool,
    /// The last configuration's TCP is within `success.tolerance_m` of the goal target.
    pub reached: bool,
    /// Configurations checked.
    pub configurations: usize,
    /// TCP distance to the goal target at the end (m).
    pub end_error_m: f64,
}

impl PathCheck {
    /// Safe and reached.
    pub fn ok(&self) -> bool {
        self.safe && self.reached
    }
}

/// Re-tracks `path` (starting at `start`, which is checked too) in `scene`: densified to
/// [`TRACK_STEP_RAD`], each configuration checked with the task's contact rule.
pub fn track_path(env: &TwinEnv, scene: &Scene, start: &Joints, path: &[Joints]) -> PathCheck {
    let mut full = Vec::with_capacity(path.len() + 1);
    full.push(*start);
    full.extend_from_slice(path);
    let dense = densify_path(&full, TRACK_STEP_RAD);
    let safe = dense.iter().all(|q| is_safe_posture(env, scene, q));
    let cfg = env.config();
    let target = scene.goal_target_m(cfg.success.goal_hover_m);
    let end = dense.last().copied().unwrap_or(*start);
    let end_error_m = (env.model().tcp_m(&end) - target).norm();
    PathCheck {
        safe,
        reached: end_error_m <= cfg.success.tolerance_m,
        configurations: dense.len(),
        end_error_m,
    }
}
