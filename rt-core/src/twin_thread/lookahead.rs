//! The lookahead on the real twin: [`TwinLookahead`] runs the whole next episode through
//! `twin::rollout` with an [`MlpPolicy`] (the worker's [`Lookahead`] trait).
//!
//! The twin's episodes start from the task's start posture (`[start] joints_rad`). When the
//! arm stands elsewhere, the lookahead prepends a joint-space approach to the start posture
//! (at most `approach_speed_rad_s`); that approach is not part of the episode, but like every
//! sample of a plan it is checked by the shield against the scene before approval and again
//! in the cycle.
//!
//! "Goal reached" has one meaning: the TCP within the task's `success.tolerance_m` of
//! `scene.goal_target_m(success.goal_hover_m)`, on this lookahead's model (the task's tool
//! installed) — what `twin::TwinEnv::step` calls `task_done`, and what
//! [`TwinLookahead::goal_approach`] measures on the smoothed plan before it is approved.

use policy::MlpPolicy;
use twin::{
    DOF, IkSolver, Joints, MAX_EPISODE_STEPS, RobotModel, Scene, TaskConfig, TwinEnv,
    is_safe_posture, max_joint_gap_rad, rollout_until,
};

use crate::twin_thread::worker::{GoalApproach, Lookahead, Verdict};

/// How the lookahead picks the executed actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LookaheadActions {
    /// The policy's actions (production).
    Policy,
    /// The task's scripted straight-line actions, while still evaluating the policy at
    /// every step (the bench: random-weight policies, plans that always pass).
    ScriptedWithPolicyCost,
}

/// Most waypoints [`TwinLookahead`] appends to settle the TCP on the goal target.
pub const SETTLE_STEPS: usize = 3;

/// The settling stops once the TCP is this close to the goal target, m.
pub const SETTLE_DONE_M: f64 = 0.001;

/// The lookahead on the twin: `twin::rollout` with an [`MlpPolicy`].
#[derive(Debug, Clone)]
pub struct TwinLookahead {
    env: TwinEnv,
    start_q_rad: Joints,
    step_s: f64,
    wps: heapless::Vec<Joints, MAX_EPISODE_STEPS>,
    actions: LookaheadActions,
    /// Speed of the approach to the start posture, rad/s.
    pub approach_speed_rad_s: f64,
    /// Blind (`--no-lookahead`): the episode runs on through contact, as the policy would
    /// on an arm nobody checks.
    pub blind: bool,
}

impl TwinLookahead {
    /// Over a robot model and the task.
    pub fn new(model: RobotModel, task: TaskConfig, actions: LookaheadActions) -> Self {
        let start_q_rad = task.start.joints_rad;
        let step_s = task.episode.step_period_s;
        Self {
            env: TwinEnv::new(model, task),
            start_q_rad,
            step_s,
            wps: heapless::Vec::new(),
            actions,
            approach_speed_rad_s: 0.5,
            blind: false,
        }
    }

    /// The task's start posture, rad.
    pub fn start_q_rad(&self) -> Joints {
        self.start_q_rad
    }

    /// Settles a successful episode's end on the goal target: the episode counts as done
    /// once the TCP is within `success.tolerance_m`, so its last waypoint may lie anywhere
    /// up to the tolerance from the target the *camera* saw, and a millimetre of perception
    /// error then puts the real goal just outside it (issue 15: the twin declared 17 mm, the
    /// referee measured 20.4 mm against 20). Up to [`SETTLE_STEPS`] IK waypoints bring the
    /// TCP onto the target; each must be closer than the one before, within the joints'
    /// velocity limits for one step and a safe posture by the episode's own contact rule
    /// (the shield then checks every smoothed sample as for any plan). Where a step is not
    /// possible, the plan ends where the episode did.
    ///
    /// # Performance
    /// At most [`SETTLE_STEPS`] IK solves and distance queries.
    fn settle_on_goal(&self, scene: &Scene, waypoints: &mut Vec<Joints>) {
        let Some(mut q) = waypoints.last().copied() else {
            return;
        };
        let cfg = self.env.config();
        let model = self.env.model();
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
                (0..DOF).all(|j| (next[j] - q[j]).abs() <= limits.velocity_rad_s[j] * self.step_s);
            let next_dist_m = (model.tcp_m(&next) - target_m).norm();
            if !(within_speed && next_dist_m < dist_m && is_safe_posture(&self.env, scene, &next)) {
                return;
            }
            waypoints.push(next);
            q = next;
            dist_m = next_dist_m;
        }
    }
}

impl Lookahead for TwinLookahead {
    type Scene = Scene;
    type Policy = MlpPolicy;

    fn step_s(&self) -> f64 {
        self.step_s
    }

    fn policy_id(policy: &MlpPolicy) -> u64 {
        policy.policy_id()
    }

    fn lookahead(
        &mut self,
        policy: &MlpPolicy,
        scene: &Scene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        waypoints.clear();
        let gap = max_joint_gap_rad(&self.start_q_rad, start_q_rad);
        if gap > 1e-3 {
            let n = (gap / (self.approach_speed_rad_s * self.step_s))
                .ceil()
                .max(1.0) as usize;
            for k in 1..=n {
                let t = k as f64 / n as f64;
                let mut q = [0.0; DOF];
                for j in 0..DOF {
                    q[j] = start_q_rad[j] + (self.start_q_rad[j] - start_q_rad[j]) * t;
                }
                waypoints.push(q);
            }
        }
        let summary = match self.actions {
            LookaheadActions::Policy => rollout_until(
                &mut self.env,
                scene,
                |obs| policy.act(obs),
                Some(&mut self.wps),
                !self.blind,
            ),
            LookaheadActions::ScriptedWithPolicyCost => {
                self.env.reset(scene);
                let scripted = self.env.straight_line_policy();
                rollout_until(
                    &mut self.env,
                    scene,
                    |obs| {
                        std::hint::black_box(policy.act(obs));
                        scripted.act(obs)
                    },
                    Some(&mut self.wps),
                    !self.blind,
                )
            }
        };
        waypoints.extend_from_slice(&self.wps);
        if summary.success && summary.safe && !self.blind {
            self.settle_on_goal(scene, waypoints);
        }
        Verdict {
            task_ok: summary.success,
            safe: summary.safe,
            min_distance_m: summary.min_distance_m,
            steps: summary.steps,
            policy_id: policy.policy_id(),
        }
    }

    /// The TCP's closest approach to `scene.goal_target_m(success.goal_hover_m)` along the
    /// path, against `success.tolerance_m`: the target, tolerance and TCP (the model with the
    /// task's tool) of `twin::TwinEnv::step`'s `task_done`.
    ///
    /// # Performance
    /// One forward kinematics per sample; no allocation.
    fn goal_approach(
        &mut self,
        _policy: &MlpPolicy,
        scene: &Scene,
        path_q_rad: &[Joints],
    ) -> GoalApproach {
        tcp_goal_approach(&self.env, scene, path_q_rad)
    }
}

/// The TCP's closest approach to `scene.goal_target_m(success.goal_hover_m)` along
/// `path_q_rad`, against `success.tolerance_m`, on `env`'s model: "goal reached" as
/// `twin::TwinEnv::step`'s `task_done` means it (the lookahead's and the planner
/// fallback's goal check).
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::path::PathBuf;

    use twin::{BoxObstacle, Goal, IkSolver, RobotModel, Scene, TaskConfig, is_safe_posture};

    use super::*;

    /// The settling of a plan's end onto the goal target adds no waypoint that breaks the
    /// episode's contact rule: with a box placed so that the posture at the target is too
    /// close to it while the episode's end, 17 mm away, is clear, no waypoint toward it is
    /// added.
    #[test]
    fn settling_onto_the_goal_never_adds_an_unsafe_waypoint() {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let la = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
        let goal = Goal {
            center_m: [0.35, 0.0, 0.025],
            size_m: 0.05,
        };
        let free = Scene::empty(0.0, goal);
        let target = free.goal_target_m(task.success.goal_hover_m);
        let ik = IkSolver::new(&model, task.ik);
        let start = task.start.joints_rad;
        let at_target = ik.solve(&model, &target, &start).joints;
        let end_point = target - nalgebra::Vector3::new(0.017, 0.0, 0.0);
        let episode_end = ik.solve(&model, &end_point, &at_target).joints;
        assert!((model.tcp_m(&episode_end) - target).norm() > 0.015);

        // In the free scene the plan is settled onto the target.
        let mut waypoints = vec![episode_end];
        la.settle_on_goal(&free, &mut waypoints);
        let end_m = (model.tcp_m(waypoints.last().unwrap()) - target).norm();
        assert!(end_m <= SETTLE_DONE_M, "{end_m}");

        // A box beyond the target (+x), moved toward it until the posture at the target
        // breaks the contact rule while the episode's end (17 mm nearer the base) keeps it.
        let env = la.env.clone();
        let mut blocked = None;
        for mm in 0..200 {
            let face_x = target.x + 0.20 - f64::from(mm) * 0.001;
            let mut scene = free;
            scene
                .obstacles
                .push(BoxObstacle {
                    center_m: [face_x + 0.05, 0.0, 0.20],
                    size_m: [0.10, 0.30, 0.40],
                })
                .unwrap();
            if !is_safe_posture(&env, &scene, &at_target) {
                assert!(is_safe_posture(&env, &scene, &episode_end), "no such box");
                blocked = Some(scene);
                break;
            }
        }
        let blocked = blocked.expect("a box that blocks the target posture");
        let mut waypoints = vec![episode_end];
        la.settle_on_goal(&blocked, &mut waypoints);
        for q in &waypoints {
            assert!(is_safe_posture(&env, &blocked, q), "unsafe waypoint {q:?}");
        }
    }
}
