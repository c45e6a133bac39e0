//! The planner fallback on the real twin: [`TwinPathPlanner`] asks `twin::feasibility` for
//! safe goal postures and a collision-free joint path to one of them from the arm (the
//! worker's [`FallbackPlanner`]), densified into waypoints the worker smooths and checks
//! like any policy's plan. Only goal postures and paths within the shield's joint limits
//! (the URDF's less the margin) are offered: a path the shield would refuse is no path.
//!
//! Planning code: it allocates and reads the wall clock (its budget); it runs on the twin
//! thread, never in the cycle.

use twin::{
    DOF, FeasibilityConfig, Joints, PlanOutcome, PlannerBudget, RobotModel, Scene, TaskConfig,
    TwinEnv, check_goal_postures, densify_path, plan_path,
};

use crate::config::RuntimeConfig;
use crate::cycle::shield::ShieldLimits;
use crate::twin_thread::worker::{FallbackPlanner, GoalApproach, PLANNER_POLICY_ID, Verdict};

/// Largest joint change between two waypoints handed to the smoother, rad: the smoother
/// passes near each waypoint, so the arm follows the planner's checked segments closely.
pub const WAYPOINT_STEP_RAD: f64 = 0.05;

/// The planner's path keeps this far inside the shield's joint limits, rad: the smoothed
/// plan passes near its waypoints, not exactly through them.
pub const JOINT_LIMIT_ROOM_RAD: f64 = 0.02;

/// The feasibility planner over the twin's model and task.
#[derive(Debug, Clone)]
pub struct TwinPathPlanner {
    env: TwinEnv,
    cfg: FeasibilityConfig,
    /// The shield's lower joint limits (margin included), rad.
    joint_min_rad: Joints,
    /// The shield's upper joint limits (margin included), rad.
    joint_max_rad: Joints,
}

impl TwinPathPlanner {
    /// Over the robot model (the task's tool installed, as the lookahead's), the task and
    /// the runtime configuration (the shield's joint limits; each search stops after
    /// `planner_fallback.budget_s` of wall time).
    pub fn new(model: RobotModel, task: TaskConfig, cfg: &RuntimeConfig) -> Self {
        let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
        Self {
            env: TwinEnv::new(model, task),
            cfg: FeasibilityConfig {
                planner: PlannerBudget {
                    max_time_s: cfg.planner_fallback.budget_s,
                    ..PlannerBudget::default()
                },
                ..FeasibilityConfig::default()
            },
            joint_min_rad: limits.joint_min_rad,
            joint_max_rad: limits.joint_max_rad,
        }
    }

    /// `q` within the shield's joint limits, [`JOINT_LIMIT_ROOM_RAD`] inside them.
    fn within_limits(&self, q: &Joints) -> bool {
        (0..DOF).all(|j| {
            q[j] >= self.joint_min_rad[j] + JOINT_LIMIT_ROOM_RAD
                && q[j] <= self.joint_max_rad[j] - JOINT_LIMIT_ROOM_RAD
        })
    }

    /// The checked path from `start_q_rad` to a safe goal posture within the shield's joint
    /// limits, densified; `None` when there is none.
    fn path(&self, scene: &Scene, start_q_rad: &Joints) -> Option<Vec<Joints>> {
        let goals: Vec<Joints> = check_goal_postures(&self.env, scene, self.cfg.goal_seeds)
            .postures
            .iter()
            .map(|p| p.joints)
            .filter(|q| self.within_limits(q))
            .collect();
        let PlanOutcome::Path { path, .. } =
            plan_path(&self.env, scene, start_q_rad, &goals, self.cfg.planner)
        else {
            return None;
        };
        let dense = densify_path(&path, WAYPOINT_STEP_RAD);
        dense.iter().all(|q| self.within_limits(q)).then_some(dense)
    }

    /// Smallest clearance of `q` to the boxes (to the table without boxes), m.
    fn clearance_m(&self, scene: &Scene, q: &Joints) -> f64 {
        let d = self
            .env
            .geometry()
            .all_distances(&self.env.model().fk(q), scene);
        d.boxes.map_or(d.table.distance_m, |b| b.distance_m)
    }
}

impl FallbackPlanner<Scene> for TwinPathPlanner {
    fn plan(
        &mut self,
        scene: &Scene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        waypoints.clear();
        let Some(path) = self.path(scene, start_q_rad) else {
            return Verdict {
                task_ok: false,
                safe: true,
                min_distance_m: self.clearance_m(scene, start_q_rad),
                steps: 0,
                policy_id: PLANNER_POLICY_ID,
            };
        };
        waypoints.extend(path.into_iter().skip(1));
        let min_distance_m = waypoints
            .iter()
            .map(|q| self.clearance_m(scene, q))
            .fold(f64::INFINITY, f64::min);
        Verdict {
            task_ok: true,
            safe: true,
            min_distance_m,
            steps: waypoints.len() as u32,
            policy_id: PLANNER_POLICY_ID,
        }
    }

    fn goal_approach(&mut self, scene: &Scene, path_q_rad: &[Joints]) -> GoalApproach {
        crate::twin_thread::lookahead::tcp_goal_approach(&self.env, scene, path_q_rad)
    }
}

#[cfg(test)]
// The tests time the planner in wall time (figures printed, never fed to a cycle).
#[allow(clippy::unwrap_used, clippy::disallowed_methods)]
mod tests {
    use std::path::PathBuf;

    use shm_schemas::scene_file::SceneFile;
    use twin::{BoxObstacle, Goal, max_joint_gap_rad};

    use super::*;

    fn planner() -> (TwinPathPlanner, Joints) {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let model = model.with_tool(task.tool.map(|t| t.capsule()));
        let cfg = RuntimeConfig::xarm5_default();
        (
            TwinPathPlanner::new(model, task, &cfg),
            task.start.joints_rad,
        )
    }

    #[test]
    fn a_path_around_the_demos_tall_box_reaches_the_goal_in_small_steps() {
        let (mut p, start) = planner();
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes");
        let file = SceneFile::load(&assets.join("tall_box.toml")).unwrap();
        let scene = Scene::from_file(&file).unwrap();
        let mut wps = Vec::new();
        let v = p.plan(&scene, &start, &mut wps);
        assert!(v.task_ok && v.safe, "{v:?}");
        assert_eq!(v.policy_id, PLANNER_POLICY_ID);
        assert!(v.min_distance_m > 0.0, "{v:?}");
        let mut prev = start;
        for q in &wps {
            assert!(max_joint_gap_rad(&prev, q) <= WAYPOINT_STEP_RAD + 1e-9);
            prev = *q;
        }
        assert!(p.goal_approach(&scene, &wps).reached());
    }

    #[test]
    fn a_goal_inside_a_box_has_no_path() {
        let (mut p, start) = planner();
        let mut scene = Scene::empty(
            0.0,
            Goal {
                center_m: [0.40, 0.0, 0.025],
                size_m: 0.05,
            },
        );
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [0.40, 0.0, 0.15],
                size_m: [0.20, 0.20, 0.30],
            })
            .unwrap();
        let mut wps = Vec::new();
        let v = p.plan(&scene, &start, &mut wps);
        assert!(!v.task_ok, "{v:?}");
        assert!(wps.is_empty());
    }

    /// The planner fallback's twin-side latency on random worlds of the task's broad
    /// distribution: planning (goal postures + RRT-Connect), Ruckig smoothing and the shield
    /// over every sample — what separates a settled scene from a plan handed to the cycle
    /// when no policy passes. Prints median and p95; asserts no timing.
    /// `cargo test --release -p rt-core --lib -- --ignored planner_fallback_latency --nocapture`
    #[test]
    #[ignore = "a measurement; prints figures"]
    fn planner_fallback_latency() {
        use rand::SeedableRng;

        use crate::cycle::plan::MotionState;
        use crate::cycle::plan::Plan;
        use crate::twin_thread::serve::plan_shield;
        use crate::twin_thread::smoother::PlanSmoother;

        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let model = model.with_tool(task.tool.map(|t| t.capsule()));
        let cfg = RuntimeConfig::xarm5_default();
        let mut p = TwinPathPlanner::new(model.clone(), task, &cfg);
        let env = TwinEnv::new(model.clone(), task);
        let mut shield = plan_shield(&cfg, &model, false);
        let period_s = 1.0 / cfg.rate_hz;
        let mut smoother = PlanSmoother::new(period_s, cfg.limits, (60.0 * cfg.rate_hz) as usize);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(26);
        let start = task.start.joints_rad;
        let (mut times_s, mut approved, mut no_path, mut rejected) = (Vec::new(), 0, 0, 0);
        let mut wps = Vec::new();
        for _ in 0..200 {
            let scene = env.sample_world(&mut rng);
            let t0 = std::time::Instant::now();
            let v = p.plan(&scene, &start, &mut wps);
            if !v.task_ok {
                no_path += 1;
                continue;
            }
            let mut plan = Plan::with_capacity(1, PLANNER_POLICY_ID, period_s, 0);
            let state = MotionState::at_rest(start);
            let smoothed = smoother.smooth(
                &state,
                &wps,
                task.episode.step_period_s,
                shield.model_mut(),
                &mut plan,
            );
            let checked =
                smoothed.map(|()| shield.check_path(&start, &plan.q_rad, period_s, &scene));
            let goal = p.goal_approach(&scene, &plan.q_rad);
            let ok = matches!(checked, Ok(Ok(_))) && goal.reached();
            if !ok {
                println!("rejected: {checked:?} {goal:?}");
            }
            times_s.push(t0.elapsed().as_secs_f64());
            if ok {
                approved += 1;
            } else {
                rejected += 1;
            }
        }
        times_s.sort_by(f64::total_cmp);
        let q = |f: f64| times_s[((times_s.len() - 1) as f64 * f).round() as usize];
        println!(
            "planner fallback, {} worlds with a path ({approved} approved, {rejected} rejected by \
             the smoothed-plan checks), {no_path} without one: plan + smooth + shield median \
             {:.3} s, p95 {:.3} s, max {:.3} s",
            times_s.len(),
            q(0.5),
            q(0.95),
            q(1.0)
        );
    }
}
