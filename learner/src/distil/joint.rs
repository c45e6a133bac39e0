//! The joint-step space's teachers (issue 40 item 3): what `learner distil --action-space
//! joint_step` imitates.
//!
//! The goal posture is the one the twin chooses at the reset ([`twin::choose_goal_posture`],
//! as rt-core's lookahead does), so that the student sees in its observation the posture its
//! teacher drives to. The teacher of a world is the joint straight line
//! ([`twin::JointLinePolicy`]) when it reaches the goal with no contact, otherwise pure pursuit in
//! joint space ([`JointPathExpert`]) along the planner's joint path from the start posture to
//! that goal posture ([`plan_path`]): each step aims a little ahead of the nearest point of the
//! path, the per-joint steps scaled by `action.joint_scale_rad` so that the largest is at
//! most 1. A teacher counts only when its episode from the start reaches the goal with no
//! contact in the world as planned (boxes grown by the margin, or as they are) and, with
//! rt-core's settings, rt-core would approve its plan in the world as it is.
//!
//! Training code: it allocates and is not for the real-time cycle.

use twin::approval::{ApprovalSettings, EpisodeApproval};
use twin::{
    DOF, FeasibilityConfig, JOINT_ACT_DIM, Joints, PlanOutcome, Scene, TwinEnv, densify_path,
    plan_path,
};

use super::{Teacher, Untaught};

/// Largest joint change between two points of the followed path (rad).
const SPACING_RAD: f64 = 0.01;

/// How far ahead of the nearest point of the path the expert aims, in points: 0.04 rad, more
/// than one full step at the default 0.03 rad scale, so that it moves at full speed along
/// the path and slows only at its end.
const LOOKAHEAD: usize = 4;

/// How far ahead of its progress the nearest point is looked for, in points (the progress
/// never goes back, so that a path that passes near itself is followed in order).
const WINDOW: usize = 40;

/// The joint step from `q` toward `target`: each joint's change over its scale, all scaled
/// down together so that the largest is at most 1 (the direction kept).
pub fn joint_step_toward(q: &Joints, target: &Joints, scale_rad: &Joints) -> [f32; JOINT_ACT_DIM] {
    let mut a: [f64; JOINT_ACT_DIM] = std::array::from_fn(|i| (target[i] - q[i]) / scale_rad[i]);
    let biggest = a.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    if biggest > 1.0 {
        a = a.map(|v| v / biggest);
    }
    a.map(|v| v as f32)
}

/// Pure pursuit along a joint path: the joint-step teacher of a world the joint straight line
/// does not solve. See the module docs.
#[derive(Debug, Clone)]
pub struct JointPathExpert {
    /// The path, densified to [`SPACING_RAD`].
    points: Vec<Joints>,
    /// The task's joint-step scale (rad).
    scale_rad: Joints,
    /// Index of the nearest point so far.
    progress: usize,
}

impl JointPathExpert {
    /// Along `path` (start posture first, goal posture last) with the task's joint-step
    /// `scale_rad`.
    pub fn new(path: &[Joints], scale_rad: Joints) -> Self {
        Self {
            points: densify_path(path, SPACING_RAD),
            scale_rad,
            progress: 0,
        }
    }

    /// Back to the start of the path (a new episode).
    pub fn restart(&mut self) {
        self.progress = 0;
    }

    /// The action at the joints `q`.
    pub fn action(&mut self, q: &Joints) -> [f32; JOINT_ACT_DIM] {
        let Some(last) = self.points.len().checked_sub(1) else {
            return [0.0; JOINT_ACT_DIM];
        };
        let scaled = |p: &Joints| {
            (0..DOF)
                .map(|i| ((p[i] - q[i]) / self.scale_rad[i]).powi(2))
                .sum::<f64>()
        };
        let from = self.progress.min(last);
        let end = (self.progress + WINDOW).min(last);
        let mut best = from;
        let mut best_d = f64::INFINITY;
        for (k, p) in self.points.iter().enumerate().take(end + 1).skip(from) {
            let d = scaled(p);
            if d < best_d {
                best_d = d;
                best = k;
            }
        }
        self.progress = best;
        let target = self.points[(best + LOOKAHEAD).min(last)];
        joint_step_toward(q, &target, &self.scale_rad)
    }
}

/// Runs `teacher` from the start posture of `scene` toward `goal`: the joints after each
/// step, and whether it reached the goal with no contact.
fn episode(env: &TwinEnv, scene: &Scene, goal: Joints, teacher: &Teacher) -> (Vec<Joints>, bool) {
    let mut tw = env.clone();
    let mut t = teacher.clone();
    t.restart();
    let start = env.config().start.joints_rad;
    let mut obs = tw.reset_toward(scene, &start, Some(goal));
    let max_steps = env.config().episode.max_steps as usize;
    let mut joints = Vec::with_capacity(max_steps);
    let mut action = [0.0f32; JOINT_ACT_DIM];
    for _ in 0..max_steps {
        t.action_into(&tw, &obs, &mut action);
        let out = tw.step_joint(&action);
        obs = out.obs;
        joints.push(out.joints);
        if out.terminated || out.truncated {
            return (joints, out.task_done && out.safe);
        }
    }
    (joints, false)
}

/// Whether `teacher` reaches the goal with no contact in `plan_in` (the world as planned)
/// and, with `approval`, rt-core would approve its plan in `scene` (the world as it is).
fn is_clean(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scene: &Scene,
    plan_in: &Scene,
    goal: Joints,
    teacher: &Teacher,
) -> bool {
    if !episode(env, plan_in, goal, teacher).1 {
        return false;
    }
    let (joints, clean) = episode(env, scene, goal, teacher);
    clean
        && approval.is_none_or(|settings| {
            EpisodeApproval::new(settings, env)
                .approve(env, scene, &joints)
                .is_ok()
        })
}

/// The joint-step teacher of `scene` planned in `plan_in` (`env` in the joint-step space):
/// the joint straight line, else pure pursuit along the planner's path to the goal posture
/// the twin chooses in `scene`. See the module docs.
pub(super) fn joint_teacher(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scene: &Scene,
    plan_in: &Scene,
    cfg: FeasibilityConfig,
) -> Result<Teacher, Untaught> {
    let mut tw = env.clone();
    tw.reset(scene);
    let goal = tw.goal_posture().ok_or(Untaught::Infeasible)?;
    let line = Teacher::JointLine(tw.joint_line_policy());
    if is_clean(env, approval, scene, plan_in, goal, &line) {
        return Ok(line);
    }
    let start = env.config().start.joints_rad;
    match plan_path(env, plan_in, &start, &[goal], cfg.planner) {
        PlanOutcome::Path { path, .. } => {
            let expert = Teacher::JointPath(JointPathExpert::new(
                &path,
                env.config().action.joint_scale_rad(),
            ));
            if is_clean(env, approval, scene, plan_in, goal, &expert) {
                Ok(expert)
            } else {
                Err(Untaught::NoCleanPath)
            }
        }
        PlanOutcome::NoPath { .. } => Err(Untaught::Infeasible),
    }
}
