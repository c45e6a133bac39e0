//! One verification: "would rt-core approve this plan in this scene".
//!
//! rt-core hands the cycle only a plan that passes, in this order: the episode in the twin
//! (the policy's rollout, contact-free and reaching the goal, its end settled onto the goal
//! target: [`settle_on_goal`]), Ruckig smoothing at the cycle period within the arm's limits
//! ([`PlanSmoother`]), the shield on every smoothed sample in the scene ([`Shield`]) and the
//! goal reached by the smoothed path ([`tcp_goal_approach`]). [`smooth_and_check`] is the
//! smoothing and the per-sample check, which rt-core's approver runs on every plan;
//! [`EpisodeApproval`] is the whole verification of one episode, which the learner runs on
//! every evaluated episode that reaches the goal with no contact and on its demonstrations,
//! so that a policy the learner calls converged on a scene is one rt-core approves there (issue 40: the learner counted clearance at the waypoints, rt-core refused
//! the smoothed path between them).
//!
//! The settings are rt-core's ([`ApprovalSettings`], read from `assets/runtime.toml`);
//! `[limits]` and `[shield]` are defined once, in `shm_schemas::runtime_view`, the view of
//! that file the processes other than rt-core read (the learner is one now), rather than
//! here: the bridge and the launcher already read `[shield]` from there, and rt-core's
//! `RuntimeConfig` holds the same types.
//!
//! ```no_run
//! use std::path::Path;
//! use twin::{RobotModel, TaskConfig, TwinEnv, approval::{ApprovalSettings, EpisodeApproval}};
//! # fn f(scene: twin::Scene, episode: Vec<twin::Joints>) -> Result<(), Box<dyn std::error::Error>> {
//! let model = RobotModel::load(Path::new("assets/xarm5.urdf"))?;
//! let env = TwinEnv::new(model, TaskConfig::load(Path::new("assets/task.toml"))?);
//! let mut approval = EpisodeApproval::new(&ApprovalSettings::shipped()?, &env);
//! match approval.approve(&env, &scene, &episode) {
//!     Ok(clearance_m) => println!("approved, clearance {clearance_m:.3} m"),
//!     Err(why) => println!("refused: {why}"),
//! }
//! # Ok(()) }
//! ```

pub mod settings;
pub mod shield;
pub mod shield_model;
pub mod smoother;

pub use settings::{
    ApprovalSettings, ApprovalSettingsError, DEFAULT_MAX_TCP_GAP_M, MotionLimits,
    SHIPPED_RUNTIME_TOML, ShieldConfig,
};
pub use shield::{Shield, ShieldLimits, ShieldModel, ShieldViolation};
pub use shield_model::TwinModel;
pub use smoother::{MotionState, PlanSamples, PlanSmoother, SmoothError, SmoothedPath};

use crate::{DOF, IkSolver, Joints, Scene, TwinEnv, is_safe_posture};

/// Most waypoints [`settle_on_goal`] appends to settle the TCP on the goal target.
pub const SETTLE_STEPS: usize = 3;

/// The settling stops once the TCP is this close to the goal target, m.
pub const SETTLE_DONE_M: f64 = 0.001;

/// The closest approach of a path's TCP to the goal target point, and the tolerance that
/// counts as reaching it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalApproach {
    /// Smallest TCP distance to the goal target point along the path, m (infinite for an
    /// empty path).
    pub closest_m: f64,
    /// Distance that counts as reached (the task's `success.tolerance_m`), m.
    pub tolerance_m: f64,
}

impl GoalApproach {
    /// The path reaches the goal: `closest_m <= tolerance_m`.
    pub fn reached(&self) -> bool {
        self.closest_m <= self.tolerance_m
    }
}

/// Why a plan is not approved.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PlanRejection {
    /// Ruckig could not smooth the waypoints.
    #[error("smoothing: {0}")]
    Smoothing(SmoothError),
    /// A sample fails the shield in the scene.
    #[error("shield at sample {index}: {violation}")]
    Shield {
        /// The first failing sample.
        index: usize,
        /// Why.
        violation: ShieldViolation,
    },
    /// The smoothed path's TCP does not come within the goal tolerance of the goal target.
    #[error(
        "the smoothed path misses the goal: closest {:.4} m, tolerance {:.4} m",
        .0.closest_m,
        .0.tolerance_m
    )]
    MissesGoal(GoalApproach),
}

/// Smooths `waypoints` (one every `step_s`, from `start`) with `smoother` into `plan` and
/// checks every sample with `shield` in `scene`: rt-core's approval of a plan before its goal
/// check, and the learner's through [`EpisodeApproval`]. Returns the smallest clearance along
/// the smoothed path, m.
///
/// # Errors
/// [`PlanRejection::Smoothing`] or [`PlanRejection::Shield`] (the first failing sample).
///
/// # Performance
/// Allocates (Ruckig's wrapper); one forward kinematics and distance query per sample.
pub fn smooth_and_check<M: ShieldModel, P: PlanSamples>(
    smoother: &mut PlanSmoother,
    shield: &mut Shield<M>,
    start: &MotionState,
    waypoints: &[Joints],
    step_s: f64,
    scene: &M::Scene,
    plan: &mut P,
) -> Result<f64, PlanRejection> {
    smoother
        .smooth(start, waypoints, step_s, shield.model_mut(), plan)
        .map_err(PlanRejection::Smoothing)?;
    let period_s = smoother.period_s();
    shield
        .check_path(&start.q_rad, plan.positions(), period_s, scene)
        .map_err(|(index, violation)| PlanRejection::Shield { index, violation })
}

/// The TCP's closest approach to `scene.goal_target_m(success.goal_hover_m)` along
/// `path_q_rad`, against `success.tolerance_m`, on `env`'s model: "goal reached" as
/// [`TwinEnv::step`]'s `task_done` means it (the lookahead's and the planner fallback's goal
/// check on a smoothed plan).
///
/// # Performance
/// One forward kinematics per sample; no allocation.
pub fn tcp_goal_approach(env: &TwinEnv, scene: &Scene, path_q_rad: &[Joints]) -> GoalApproach {
    let success = env.config().success;
    let target_m = scene.goal_target_m(success.goal_hover_m);
    let model = env.model();
    let closest_m = path_q_rad
        .iter()
        .map(|q| (model.fk(q).tcp_m() - target_m).norm())
        .fold(f64::INFINITY, f64::min);
    GoalApproach {
        closest_m,
        tolerance_m: success.tolerance_m,
    }
}

/// Settles a successful episode's end on the goal target: the episode counts as done once
/// the TCP is within `success.tolerance_m`, so its last waypoint may lie anywhere up to the
/// tolerance from the target the *camera* saw, and a millimetre of perception error then puts
/// the real goal just outside it (issue 15: the twin declared 17 mm, the referee measured
/// 20.4 mm against 20). Up to [`SETTLE_STEPS`] IK waypoints bring the TCP onto the target;
/// each must be closer than the one before, within the joints' velocity limits for one step
/// of `step_s` and a safe posture by the episode's own contact rule (the shield then checks
/// every smoothed sample as for any plan). Where a step is not possible, the plan ends where
/// the episode did.
///
/// # Performance
/// At most [`SETTLE_STEPS`] IK solves and distance queries.
pub fn settle_on_goal(env: &TwinEnv, step_s: f64, scene: &Scene, waypoints: &mut Vec<Joints>) {
    let Some(mut q) = waypoints.last().copied() else {
        return;
    };
    let cfg = env.config();
    let model = env.model();
    let target_m = scene.goal_target_m(cfg.success.goal_hover_m);
    let mut dist_m = (model.tcp_m(&q) - target_m).norm();
    let ik = IkSolver::new(model, cfg.ik);
    let limits = model.limits();
    for _ in 0..SETTLE_STEPS {
        if dist_m <= SETTLE_DONE_M {
            return;
        }
        let next = ik.solve(model, &target_m, &q).joints;
        let within_speed =
            (0..DOF).all(|j| (next[j] - q[j]).abs() <= limits.velocity_rad_s[j] * step_s);
        let next_dist_m = (model.tcp_m(&next) - target_m).norm();
        if !(within_speed && next_dist_m < dist_m && is_safe_posture(env, scene, &next)) {
            return;
        }
        waypoints.push(next);
        q = next;
        dist_m = next_dist_m;
    }
}

/// The whole verification of one episode, as rt-core runs it on a policy's plan from the
/// task's start posture at rest: the episode's waypoints settled onto the goal, smoothed and
/// checked on every sample ([`smooth_and_check`]), the goal reached on the smoothed path.
/// Owns its buffers (reused from one episode to the next).
#[derive(Clone)]
pub struct EpisodeApproval {
    smoother: PlanSmoother,
    shield: Shield<TwinModel>,
    waypoints: Vec<Joints>,
    path: SmoothedPath,
}

impl std::fmt::Debug for EpisodeApproval {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EpisodeApproval")
            .field("period_s", &self.smoother.period_s())
            .field("limits", self.shield.limits())
            .finish_non_exhaustive()
    }
}

impl EpisodeApproval {
    /// With rt-core's `settings`, on `env`'s model (the task's tool installed) — the plan
    /// shield rt-core builds (`twin_thread::serve::plan_shield`, lookahead on).
    pub fn new(settings: &ApprovalSettings, env: &TwinEnv) -> Self {
        Self {
            smoother: PlanSmoother::new(
                settings.period_s(),
                settings.limits,
                settings.max_plan_samples(),
            ),
            shield: Shield::new(
                TwinModel::new(env.model().clone()),
                ShieldLimits::from_config(&settings.limits, &settings.shield),
            ),
            waypoints: Vec::new(),
            path: SmoothedPath::default(),
        }
    }

    /// Would rt-core approve the plan of `episode` — the joints after each step of an
    /// episode in `scene` from the task's start posture that reached the goal with no contact
    /// (`rollout_until`'s waypoints) — with the arm at rest at the start posture? Returns the
    /// smallest clearance along the smoothed path, m.
    ///
    /// # Errors
    /// The [`PlanRejection`].
    pub fn approve(
        &mut self,
        env: &TwinEnv,
        scene: &Scene,
        episode: &[Joints],
    ) -> Result<f64, PlanRejection> {
        let step_s = env.config().episode.step_period_s;
        self.waypoints.clear();
        self.waypoints.extend_from_slice(episode);
        settle_on_goal(env, step_s, scene, &mut self.waypoints);
        let start = MotionState::at_rest(env.config().start.joints_rad);
        let clearance_m = smooth_and_check(
            &mut self.smoother,
            &mut self.shield,
            &start,
            &self.waypoints,
            step_s,
            scene,
            &mut self.path,
        )?;
        let approach = tcp_goal_approach(env, scene, &self.path.q_rad);
        if !approach.reached() {
            return Err(PlanRejection::MissesGoal(approach));
        }
        Ok(clearance_m)
    }

    /// The smoothed path of the last [`Self::approve`] (as far as it got).
    pub fn smoothed(&self) -> &SmoothedPath {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::{Goal, MAX_EPISODE_STEPS, RobotModel, TaskConfig, rollout_until};

    fn env() -> TwinEnv {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).expect("urdf");
        let task = TaskConfig::load(&assets.join("task.toml")).expect("task");
        TwinEnv::new(model, task)
    }

    /// The straight line to a free goal is approved with rt-core's shipped settings, its
    /// smoothed path ending on the goal; with a clearance the path cannot keep, the refusal
    /// names the first failing sample and the shield's check.
    #[test]
    fn an_episode_is_approved_or_refused_with_the_sample_and_the_check() {
        let mut env = env();
        let scene = Scene::empty(
            0.0,
            Goal {
                center_m: [0.35, 0.15, 0.025],
                size_m: 0.05,
            },
        );
        let line = env.straight_line_policy();
        let mut wps = heapless::Vec::<Joints, MAX_EPISODE_STEPS>::new();
        let summary = rollout_until(&mut env, &scene, |o| line.act(o), Some(&mut wps), true);
        assert!(summary.success && summary.safe, "{summary:?}");

        let settings = ApprovalSettings::shipped().expect("shipped runtime.toml");
        let mut approval = EpisodeApproval::new(&settings, &env);
        let clearance_m = approval.approve(&env, &scene, &wps).expect("approved");
        assert!(
            clearance_m >= settings.shield.min_distance_m,
            "{clearance_m}"
        );
        let path = approval.smoothed();
        assert!(path.q_rad.len() > wps.len());
        assert!(tcp_goal_approach(&env, &scene, &path.q_rad).reached());

        let mut strict = settings;
        strict.shield.min_distance_m = 0.19;
        let refused = EpisodeApproval::new(&strict, &env).approve(&env, &scene, &wps);
        match refused {
            Err(PlanRejection::Shield {
                index,
                violation: ShieldViolation::Clearance { distance_m },
            }) => {
                assert!(distance_m < 0.19, "{distance_m}");
                let why = refused.expect_err("refused").to_string();
                assert!(why.contains(&format!("sample {index}")), "{why}");
            }
            other => panic!("expected a clearance refusal, got {other:?}"),
        }
    }
}
