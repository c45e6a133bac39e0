//! Adapters from the real twin (`crate::twin`) and policy inference (`crate::policy`) to the
//! runtime's traits: [`TwinModel`] (the shield's kinematics and clearance on the twin's
//! capsule geometry) and [`TwinLookahead`] (the whole episode through `twin::rollout` with an
//! [`MlpPolicy`]).
//!
//! The twin's episodes start from the task's start posture (`[start] joints_rad`). When the
//! arm stands elsewhere, the lookahead prepends a joint-space approach to the start posture
//! (at most `approach_speed_rad_s`); that approach is not part of the episode, but like every
//! sample of a plan it is checked by the shield against the scene before approval and again
//! in the cycle.

use crate::policy::MlpPolicy;
use crate::twin::{
    BoxObstacle, Goal, LinkPoses, MAX_EPISODE_STEPS, MAX_OBSTACLES, RobotGeometry, RobotModel,
    Scene, TaskConfig, TwinEnv, rollout_until,
};

use super::shield::ShieldModel;
use super::twin_thread::{Lookahead, Verdict};
use super::{DOF, Joints, max_joint_gap_rad};

/// A `Copy` snapshot of a twin scene (what travels to the cycle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneSnapshot {
    /// Table top height, m.
    pub table_height_m: f64,
    /// The goal cube.
    pub goal: Goal,
    /// Obstacle boxes (the first `count`).
    pub obstacles: [BoxObstacle; MAX_OBSTACLES],
    /// Boxes in use.
    pub count: usize,
}

impl SceneSnapshot {
    /// From a twin scene.
    pub fn from_scene(scene: &Scene) -> Self {
        let mut obstacles = [BoxObstacle {
            center_m: [0.0; 3],
            size_m: [0.0; 3],
        }; MAX_OBSTACLES];
        for (o, b) in obstacles.iter_mut().zip(scene.obstacles.iter()) {
            *o = *b;
        }
        Self {
            table_height_m: scene.table_height_m,
            goal: scene.goal,
            obstacles,
            count: scene.obstacles.len().min(MAX_OBSTACLES),
        }
    }

    /// Into a twin scene (no heap).
    pub fn write_scene(&self, out: &mut Scene) {
        out.table_height_m = self.table_height_m;
        out.goal = self.goal;
        out.obstacles.clear();
        for b in &self.obstacles[..self.count] {
            let _ = out.obstacles.push(*b);
        }
    }

    /// A twin scene.
    pub fn to_scene(&self) -> Scene {
        let mut s = Scene::empty(self.table_height_m, self.goal);
        self.write_scene(&mut s);
        s
    }
}

/// The shield model on the twin: FK and capsule distances to the scene's boxes and to the
/// table (links 2–5, as in the task's contact rule). Allocation-free.
#[derive(Debug, Clone)]
pub struct TwinModel {
    model: RobotModel,
    geometry: RobotGeometry,
    poses: LinkPoses,
    cached: Option<SceneSnapshot>,
    scene: Scene,
}

impl TwinModel {
    /// Over a loaded robot model.
    pub fn new(model: RobotModel) -> Self {
        let geometry = RobotGeometry::new(&model);
        Self {
            model,
            geometry,
            poses: LinkPoses::default(),
            cached: None,
            scene: Scene::empty(
                0.0,
                Goal {
                    center_m: [0.0; 3],
                    size_m: 0.05,
                },
            ),
        }
    }
}

impl ShieldModel for TwinModel {
    type Scene = SceneSnapshot;

    fn tcp_position_m(&mut self, q_rad: &Joints) -> [f64; 3] {
        let p = self.model.tcp_m(q_rad);
        [p.x, p.y, p.z]
    }

    fn min_distance_m(&mut self, q_rad: &Joints, scene: &SceneSnapshot) -> f64 {
        if self.cached.as_ref() != Some(scene) {
            scene.write_scene(&mut self.scene);
            self.cached = Some(*scene);
        }
        self.model.fk_into(q_rad, &mut self.poses);
        // The boxes and the table (links 2–5): the TCP workspace box alone does not keep
        // the wrist off the table.
        self.geometry.distance(&self.poses, &self.scene).distance_m
    }
}

/// How the lookahead picks the executed actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LookaheadActions {
    /// The policy's actions (production).
    Policy,
    /// The task's scripted straight-line actions, while still evaluating the policy at
    /// every step (the bench: random-weight policies, plans that always pass).
    ScriptedWithPolicyCost,
}

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
}

impl Lookahead for TwinLookahead {
    type Scene = SceneSnapshot;
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
        scene: &SceneSnapshot,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        let scene = scene.to_scene();
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
                &scene,
                |obs| policy.act(obs),
                Some(&mut self.wps),
                !self.blind,
            ),
            LookaheadActions::ScriptedWithPolicyCost => {
                self.env.reset(&scene);
                let scripted = self.env.straight_line_policy();
                rollout_until(
                    &mut self.env,
                    &scene,
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
        Verdict {
            task_ok: summary.success,
            safe: summary.safe,
            min_distance_m: summary.min_distance_m,
            steps: summary.steps,
            policy_id: policy.policy_id(),
        }
    }
}
