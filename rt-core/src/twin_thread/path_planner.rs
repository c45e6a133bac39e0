//! The planner fallback on the real twin: [`TwinPathPlanner`] asks `twin::feasibility` for a
//! collision-free joint path from the arm to a safe goal posture (the worker's
//! [`FallbackPlanner`]), densified into waypoints the worker smooths and checks like any
//! policy's plan.
//!
//! Planning code: it allocates and reads the wall clock (its budget); it runs on the twin
//! thread, never in the cycle.

use twin::{
    Feasibility, FeasibilityConfig, Joints, PlannerBudget, RobotModel, Scene, TaskConfig, TwinEnv,
    check_feasibility, densify_path,
};

use crate::twin_thread::worker::{FallbackPlanner, GoalApproach, PLANNER_POLICY_ID, Verdict};

/// Largest joint change between two waypoints handed to the smoother, rad: the smoother
/// passes near each waypoint, so the arm follows the planner's checked segments closely.
pub const WAYPOINT_STEP_RAD: f64 = 0.05;

/// The feasibility planner over the twin's model and task.
#[derive(Debug, Clone)]
pub struct TwinPathPlanner {
    env: TwinEnv,
    cfg: FeasibilityConfig,
}

impl TwinPathPlanner {
    /// Over the robot model (the task's tool installed, as the lookahead's) and the task;
    /// each search stops after `budget_s` of wall time.
    pub fn new(model: RobotModel, task: TaskConfig, budget_s: f64) -> Self {
        Self {
            env: TwinEnv::new(model, task),
            cfg: FeasibilityConfig {
                planner: PlannerBudget {
                    max_time_s: budget_s,
                    ..PlannerBudget::default()
                },
                ..FeasibilityConfig::default()
            },
        }
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
        let path = match check_feasibility(&self.env, scene, start_q_rad, self.cfg) {
            Feasibility::Feasible { path, .. } => path,
            Feasibility::Infeasible(_) => {
                return Verdict {
                    task_ok: false,
                    safe: true,
                    min_distance_m: self.clearance_m(scene, start_q_rad),
                    steps: 0,
                    policy_id: PLANNER_POLICY_ID,
                };
            }
        };
        waypoints.extend(densify_path(&path, WAYPOINT_STEP_RAD).into_iter().skip(1));
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
#[allow(clippy::unwrap_used)]
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
        (
            TwinPathPlanner::new(model, task, 2.0),
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
}
