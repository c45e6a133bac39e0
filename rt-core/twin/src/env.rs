//! The reaching task as an environment: reset, step, scene sampling and whole-episode
//! rollouts. One implementation, used for training (learner), for the lookahead and by the
//! CLI. See the module docs of `twin` for the observation, action and reward layout.
//!
//! All buffers are inside [`TwinEnv`]; `reset`, `step` and `rollout` do not allocate, and
//! the same scene and actions give bit-identical episodes.

use nalgebra::Vector3;
use rand::Rng;
use shm_schemas::{ActionSpace, JOINT_ACT_DIM, JOINT_OBS_DIM};

use super::geometry::{DistanceReport, RobotGeometry};
use super::ik::IkSolver;
use super::kinematics::LinkPoses;
use super::model::RobotModel;
use super::posture::choose_goal_posture;
use super::scene::{BoxObstacle, Goal, Scene};
use super::task::{
    EXTRA_BOX_VALUES, MAX_EPISODE_STEPS, ObservationKind, ObstacleClass, TaskConfig,
};
use super::{ACT_DIM, DOF, Joints, MAX_OBSTACLES, OBS_DIM, PAPER_OBS_DIM};

/// Goals tried before scene sampling gives up on placing a box.
const GOAL_TRIES: usize = 64;

/// Box placements tried per goal.
const BOX_TRIES: usize = 8;

/// IK iterations for the arm's posture at the goal when sampling scenes.
const GOAL_IK_ITERATIONS: u32 = 200;

/// The raw reward terms of one step (before the weights).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RewardTerms {
    /// `r_g = d_{t-1} − d_t`: progress toward the goal target point (m).
    pub progress: f32,
    /// `r_a = −‖a‖` of the clipped action.
    pub action: f32,
    /// `r_o = −1` when the robot–box distance is below `d_thre_m`, else 0.
    pub proximity: f32,
    /// `+success_bonus` on success, `−collision_penalty` on contact, else 0 (already
    /// weighted).
    pub terminal: f32,
}

/// Result of one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// Observation after the step.
    pub obs: [f32; OBS_DIM],
    /// `c1·progress + c2·action + c3·proximity + terminal`.
    pub reward: f32,
    /// The raw terms.
    pub terms: RewardTerms,
    /// The TCP is within tolerance of the goal target point.
    pub task_done: bool,
    /// No contact with a box or the table, and no self-collision.
    pub safe: bool,
    /// A checked pair of the robot's own links (or the tool) came closer than
    /// [`super::SELF_COLLISION_MIN_DISTANCE_M`] (then `safe` is false).
    pub self_collision: bool,
    /// `task_done || !safe`.
    pub terminated: bool,
    /// The step budget is used up (and the episode did not terminate).
    pub truncated: bool,
    /// Robot–box report (nearest box); robot–table report in a scene without boxes.
    pub distance: DistanceReport,
    /// Joints after the step (rad).
    pub joints: Joints,
}

/// Summary of a whole episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeSummary {
    /// The goal was reached.
    pub success: bool,
    /// No contact happened.
    pub safe: bool,
    /// Sum of rewards.
    pub return_: f64,
    /// Steps taken.
    pub steps: u32,
    /// Smallest `StepOutcome::distance` seen (reset included) (m).
    pub min_distance_m: f64,
}

/// The scripted straight-line policy: head for the goal target point at full speed along
/// the straight line (the baseline that a tall box between start and goal defeats).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StraightLinePolicy {
    /// Height of the goal target point (m); the observation carries only the goal's x, y.
    pub target_z_m: f64,
    /// The task's action scale (m).
    pub scale_m: f64,
}

impl StraightLinePolicy {
    /// The action for an observation.
    pub fn act(&self, obs: &[f32; OBS_DIM]) -> [f32; ACT_DIM] {
        let delta = [
            f64::from(obs[1]) - f64::from(obs[3]),
            f64::from(obs[2]) - f64::from(obs[4]),
            self.target_z_m - f64::from(obs[5]),
        ];
        let mut a = delta.map(|d| d / self.scale_m);
        let biggest = a.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        if biggest > 1.0 {
            a = a.map(|v| v / biggest);
        }
        a.map(|v| v as f32)
    }
}

/// The joint-space baseline: straight joint-space interpolation toward the goal posture at
/// full speed — each joint's step proportional to its error, the largest at the task's
/// `action.joint_scale_rad` (the joint-step space's counterpart of
/// [`StraightLinePolicy`]; reads the joint error at observation indices 1–5).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLinePolicy {
    /// The task's joint-step scale (rad).
    pub scale_rad: Joints,
}

impl JointLinePolicy {
    /// The action for an observation of the joint-step layout.
    pub fn act(&self, obs: &[f32; OBS_DIM]) -> [f32; JOINT_ACT_DIM] {
        let mut a: [f64; JOINT_ACT_DIM] =
            std::array::from_fn(|i| f64::from(obs[1 + i]) / self.scale_rad[i]);
        let biggest = a.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        if biggest > 1.0 {
            a = a.map(|v| v / biggest);
        }
        a.map(|v| v as f32)
    }
}

/// The reaching environment. `Clone + Send`; all buffers pre-allocated.
#[derive(Debug, Clone)]
pub struct TwinEnv {
    model: RobotModel,
    geometry: RobotGeometry,
    ik: IkSolver,
    cfg: TaskConfig,
    scene: Scene,
    target_m: Vector3<f64>,
    q: Joints,
    poses: LinkPoses,
    tcp_vel_m_s: Vector3<f64>,
    goal_dist_m: f64,
    step_index: u32,
    obs: [f32; OBS_DIM],
    last_distance: DistanceReport,
    /// Each box's own report (`nearest_boxes` observation only; index = box index).
    box_reports: [DistanceReport; MAX_OBSTACLES],
    /// How many boxes the observation describes (1 for the paper's).
    observed_boxes: usize,
    start_tcp_m: Vector3<f64>,
    /// The space of the actions and the observation layout (Cartesian unless set).
    action_space: ActionSpace,
    /// The episode's goal posture (joint-step space; `None` when none was found, then the
    /// observation reads the current joints as the goal).
    goal_posture: Option<Joints>,
    /// The robot–table distance at the current poses (m).
    table_distance_m: f64,
}

fn uniform<R: Rng + ?Sized>(rng: &mut R, r: [f64; 2]) -> f64 {
    r[0] + (r[1] - r[0]) * rng.random::<f64>()
}

impl TwinEnv {
    /// A new environment over `model` with the task `cfg`; starts on an empty scene with
    /// the goal in the middle of the sampling ranges.
    pub fn new(model: RobotModel, cfg: TaskConfig) -> Self {
        let mut model = model;
        model.set_home(cfg.start.joints_rad);
        // The task's tool, or none: whatever tool `model` carried is replaced.
        model.set_tool(cfg.tool.map(|t| t.capsule()));
        let geometry = RobotGeometry::new(&model);
        let ik = IkSolver::new(&model, cfg.ik);
        let s = &cfg.sampling;
        let goal = Goal {
            center_m: [
                (s.goal_x_m[0] + s.goal_x_m[1]) / 2.0,
                (s.goal_y_m[0] + s.goal_y_m[1]) / 2.0,
                s.table_height_m + s.goal_size_m / 2.0,
            ],
            size_m: s.goal_size_m,
        };
        let scene = Scene::empty(s.table_height_m, goal);
        let start_tcp_m = model.tcp_m(&model.home());
        let observation = cfg.observation();
        let observed_boxes = match observation.kind {
            ObservationKind::Paper => 1,
            ObservationKind::NearestBoxes => observation.boxes as usize,
        };
        let mut env = Self {
            model,
            geometry,
            ik,
            cfg,
            scene,
            target_m: Vector3::zeros(),
            q: [0.0; DOF],
            poses: LinkPoses::default(),
            tcp_vel_m_s: Vector3::zeros(),
            goal_dist_m: 0.0,
            step_index: 0,
            obs: [0.0; OBS_DIM],
            last_distance: DistanceReport::FAR,
            box_reports: [DistanceReport::FAR; MAX_OBSTACLES],
            observed_boxes,
            start_tcp_m,
            action_space: ActionSpace::CartesianStep,
            goal_posture: None,
            table_distance_m: f64::INFINITY,
        };
        let scene = env.scene;
        env.reset(&scene);
        env
    }

    /// The task configuration.
    pub fn config(&self) -> &TaskConfig {
        &self.cfg
    }

    /// The robot model (its home is the task's start posture, its tool the task's).
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The collision geometry.
    pub fn geometry(&self) -> &RobotGeometry {
        &self.geometry
    }

    /// Current joints (rad).
    pub fn joints(&self) -> Joints {
        self.q
    }

    /// Current TCP position (m).
    pub fn tcp_m(&self) -> Vector3<f64> {
        self.poses.tcp_m()
    }

    /// Current link poses.
    pub fn poses(&self) -> &LinkPoses {
        &self.poses
    }

    /// The scene of the current episode.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The goal target point of the current episode (m).
    pub fn target_m(&self) -> Vector3<f64> {
        self.target_m
    }

    /// Steps taken in the current episode.
    pub fn step_index(&self) -> u32 {
        self.step_index
    }

    /// The latest observation.
    pub fn observation(&self) -> [f32; OBS_DIM] {
        self.obs
    }

    /// TCP position at the start posture (m).
    pub fn start_tcp_m(&self) -> Vector3<f64> {
        self.start_tcp_m
    }

    /// The scripted straight-line policy for this task.
    pub fn straight_line_policy(&self) -> StraightLinePolicy {
        StraightLinePolicy {
            target_z_m: self.target_m.z,
            scale_m: self.cfg.action.scale_m,
        }
    }

    /// The observation layout, and whether a reset chooses a goal posture:
    /// [`ActionSpace::CartesianStep`] (the paper's, the default) or
    /// [`ActionSpace::JointStep`]. Takes effect at the next reset. A policy of a space steps
    /// with its method ([`TwinEnv::step`], [`TwinEnv::step_joint`]).
    pub fn set_action_space(&mut self, space: ActionSpace) {
        self.action_space = space;
    }

    /// [`TwinEnv::set_action_space`] by value.
    #[must_use]
    pub fn with_action_space(mut self, space: ActionSpace) -> Self {
        self.set_action_space(space);
        self
    }

    /// The action space and observation layout.
    pub fn action_space(&self) -> ActionSpace {
        self.action_space
    }

    /// The observation length of the current layout: the task's `obs_dim()` for the
    /// Cartesian space, [`JOINT_OBS_DIM`] for the joint-step space.
    pub fn obs_dim(&self) -> usize {
        match self.action_space {
            ActionSpace::CartesianStep => self.cfg.obs_dim(),
            ActionSpace::JointStep => JOINT_OBS_DIM,
        }
    }

    /// The episode's goal posture (joint-step space: chosen at reset by
    /// [`super::choose_goal_posture`] or given to [`TwinEnv::reset_toward`]); `None` in the
    /// Cartesian space or when the scene has none.
    pub fn goal_posture(&self) -> Option<Joints> {
        self.goal_posture
    }

    /// The scripted joint-space baseline for this task.
    pub fn joint_line_policy(&self) -> JointLinePolicy {
        JointLinePolicy {
            scale_rad: self.cfg.action.joint_scale_rad(),
        }
    }

    /// Starts an episode in `scene` from the configured start posture.
    pub fn reset(&mut self, scene: &Scene) -> [f32; OBS_DIM] {
        let start = self.cfg.start.joints_rad;
        self.reset_from(scene, &start)
    }

    /// Starts an episode in `scene` from the posture `joints` (clamped into the limits)
    /// instead of the configured start: e.g. a posture along a planned path, for episodes
    /// that begin part of the way to the goal (a reverse curriculum). Otherwise as
    /// [`TwinEnv::reset`] (step count 0, TCP at rest).
    ///
    /// In the joint-step space the goal posture is chosen here
    /// ([`super::choose_goal_posture`] from `joints`).
    pub fn reset_from(&mut self, scene: &Scene, joints: &Joints) -> [f32; OBS_DIM] {
        let goal = match self.action_space {
            ActionSpace::CartesianStep => None,
            ActionSpace::JointStep => choose_goal_posture(self, scene, joints)
                .ok()
                .map(|c| c.best().joints),
        };
        self.reset_toward(scene, joints, goal)
    }

    /// [`TwinEnv::reset_from`] with the goal posture given (joint-step space: e.g. one
    /// branch of [`super::PostureChoice`] per rollout), not chosen.
    pub fn reset_toward(
        &mut self,
        scene: &Scene,
        joints: &Joints,
        goal_posture: Option<Joints>,
    ) -> [f32; OBS_DIM] {
        self.goal_posture = goal_posture;
        self.scene.clone_from(scene);
        self.target_m = self.scene.goal_target_m(self.cfg.success.goal_hover_m);
        self.q = *joints;
        self.model.limits().clamp(&mut self.q);
        self.model.fk_into(&self.q, &mut self.poses);
        self.tcp_vel_m_s = Vector3::zeros();
        self.goal_dist_m = (self.target_m - self.poses.tcp_m()).norm();
        self.step_index = 0;
        let all = self.distances_now();
        self.last_distance = all.boxes.unwrap_or(all.table);
        self.write_obs();
        self.obs
    }

    /// The robot's distances at the current poses (and each box's report when the
    /// observation describes more than one box).
    fn distances_now(&mut self) -> super::geometry::Distances {
        let all = if self.observed_boxes > 1 || self.action_space == ActionSpace::JointStep {
            self.geometry
                .all_distances_per_box(&self.poses, &self.scene, &mut self.box_reports)
        } else {
            self.geometry.all_distances(&self.poses, &self.scene)
        };
        self.table_distance_m = all.table.distance_m;
        all
    }

    /// The distances (capped at 1 m; 1 when absent) of the 2nd and 3rd nearest boxes.
    fn further_box_distances(&self) -> [f64; 2] {
        let n = self.scene.obstacles.len().min(MAX_OBSTACLES);
        let nearest = self.last_distance.obstacle;
        let mut out = [1.0; 2];
        let mut taken: [Option<usize>; 2] = [None; 2];
        for slot in 0..2 {
            let mut best: Option<usize> = None;
            for i in 0..n {
                if Some(i) == nearest || taken.contains(&Some(i)) {
                    continue;
                }
                if best
                    .is_none_or(|b| self.box_reports[i].distance_m < self.box_reports[b].distance_m)
                {
                    best = Some(i);
                }
            }
            taken[slot] = best;
            if let Some(i) = best {
                out[slot] = self.box_reports[i].distance_m.min(1.0);
            }
        }
        out
    }

    /// The joint-step space's observation ([`JOINT_OBS_DIM`] values; the crate docs' joint
    /// table, layout version [`shm_schemas::OBS_LAYOUT_JOINT_V1`]).
    fn write_joint_obs(&mut self) {
        let tcp = self.poses.tcp_m();
        let d = self.last_distance;
        let (h, w) = match d.obstacle.and_then(|i| self.scene.obstacles.get(i)) {
            Some(b) => (b.height_m(), b.width_m()),
            None => (0.0, 0.0),
        };
        let further = self.further_box_distances();
        let goal = self.goal_posture.unwrap_or(self.q);
        let o = &mut self.obs;
        o[0] = (f64::from(self.step_index) / f64::from(self.cfg.episode.max_steps)) as f32;
        for i in 0..DOF {
            o[1 + i] = (goal[i] - self.q[i]) as f32;
            o[6 + i] = goal[i] as f32;
        }
        for k in 0..3 {
            o[11 + k] = tcp[k] as f32;
            o[14 + k] = self.target_m[k] as f32;
            o[19 + k] = d.robot_point_m[k] as f32;
            o[22 + k] = d.obstacle_point_m[k] as f32;
        }
        o[17] = h as f32;
        o[18] = w as f32;
        o[25] = d.distance_m.min(1.0) as f32;
        o[26] = further[0] as f32;
        o[27] = further[1] as f32;
        o[28] = self.table_distance_m.min(1.0) as f32;
    }

    /// The 2nd … k-th nearest boxes (indices `17..obs_dim`): see the crate docs.
    fn write_extra_boxes(&mut self) {
        let n = self.scene.obstacles.len().min(MAX_OBSTACLES);
        let nearest = self.last_distance.obstacle;
        // Up to 2 picks by ascending distance, skipping the nearest (already in 9–16);
        // ties go to the lower index. No allocation: k ≤ 3, n ≤ 16.
        let mut picked: [Option<usize>; 2] = [None; 2];
        for slot in 0..self.observed_boxes.saturating_sub(1).min(2) {
            let mut best: Option<usize> = None;
            for i in 0..n {
                if Some(i) == nearest || picked.contains(&Some(i)) {
                    continue;
                }
                let closer = best.is_none_or(|b| {
                    self.box_reports[i].distance_m < self.box_reports[b].distance_m
                });
                if closer {
                    best = Some(i);
                }
            }
            picked[slot] = best;
        }
        for (slot, pick) in picked.into_iter().enumerate() {
            let base = PAPER_OBS_DIM + EXTRA_BOX_VALUES * slot;
            let values = match pick {
                Some(i) if slot + 1 < self.observed_boxes => {
                    let b = &self.scene.obstacles[i];
                    let r = &self.box_reports[i];
                    [
                        b.height_m(),
                        b.width_m(),
                        r.obstacle_point_m[0],
                        r.obstacle_point_m[1],
                        r.obstacle_point_m[2],
                        r.distance_m.min(1.0),
                    ]
                }
                _ => [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            };
            if slot + 1 < self.observed_boxes {
                for (k, v) in values.iter().enumerate() {
                    self.obs[base + k] = *v as f32;
                }
            } else {
                self.obs[base..base + EXTRA_BOX_VALUES].fill(0.0);
            }
        }
    }

    /// The arm's poses at the goal target of `scene` (empty of boxes yet) by IK from home;
    /// `None` when the IK does not get there or only by folding the arm into itself. The
    /// samplers draw goals only where it does, and leave room for these poses.
    fn goal_poses(&self, scene: &Scene) -> Option<LinkPoses> {
        let goal_target = scene.goal_target_m(self.cfg.success.goal_hover_m);
        let at_goal = self.ik.solve_with(
            &self.model,
            &goal_target,
            &self.model.home(),
            GOAL_IK_ITERATIONS,
        );
        if !at_goal.reached {
            return None;
        }
        let poses = self.model.fk(&at_goal.joints);
        self.geometry
            .self_collision(&poses)
            .is_none()
            .then_some(poses)
    }

    fn write_obs(&mut self) {
        if self.action_space == ActionSpace::JointStep {
            self.write_joint_obs();
            return;
        }
        let tcp = self.poses.tcp_m();
        let d = &self.last_distance;
        let (h, w) = match d.obstacle.and_then(|i| self.scene.obstacles.get(i)) {
            Some(b) => (b.height_m(), b.width_m()),
            None => (0.0, 0.0),
        };
        let o = &mut self.obs;
        o[0] = (f64::from(self.step_index) / f64::from(self.cfg.episode.max_steps)) as f32;
        o[1] = self.scene.goal.center_m[0] as f32;
        o[2] = self.scene.goal.center_m[1] as f32;
        for k in 0..3 {
            o[3 + k] = tcp[k] as f32;
            o[6 + k] = self.tcp_vel_m_s[k] as f32;
            o[11 + k] = d.robot_point_m[k] as f32;
            o[14 + k] = d.obstacle_point_m[k] as f32;
        }
        o[9] = h as f32;
        o[10] = w as f32;
        self.write_extra_boxes();
    }

    /// Advances one step with `action` (clipped to `[-1, 1]`; NaN counts as 0).
    ///
    /// # Performance
    /// One IK solve, one FK, one distance query; no allocation.
    pub fn step(&mut self, action: &[f32; ACT_DIM]) -> StepOutcome {
        let a = action.map(clip_action);
        let a_norm = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let scale = self.cfg.action.scale_m;
        let tcp_prev = self.poses.tcp_m();
        let target = tcp_prev + Vector3::new(a[0], a[1], a[2]) * scale;
        let sol = self.ik.solve(&self.model, &target, &self.q);
        self.advance_toward(&sol.joints, a_norm, tcp_prev)
    }

    /// Advances one step in the joint-step space with `action` (clipped to `[-1, 1]`; NaN
    /// counts as 0): joint i asked to move by `action[i] × action.joint_scale_rad[i]`. From
    /// there on exactly as [`TwinEnv::step`] (the same per-joint step bound, joint limits,
    /// contact rule, reward and termination; `r_a` is minus the norm of the five clipped
    /// components).
    ///
    /// # Performance
    /// One FK, one distance query; no allocation.
    pub fn step_joint(&mut self, action: &[f32; JOINT_ACT_DIM]) -> StepOutcome {
        let a = action.map(clip_action);
        let a_norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
        let scale = self.cfg.action.joint_scale_rad();
        let tcp_prev = self.poses.tcp_m();
        let target: Joints = std::array::from_fn(|i| self.q[i] + a[i] * scale[i]);
        self.advance_toward(&target, a_norm, tcp_prev)
    }

    /// The one path from a step's joint target to its outcome, shared by both action
    /// spaces: each joint moves toward `target` by at most `velocity_rad_s × step_period_s`,
    /// the joints are clamped into their limits, then contact, reward, termination and the
    /// observation.
    fn advance_toward(
        &mut self,
        target: &Joints,
        a_norm: f64,
        tcp_prev: Vector3<f64>,
    ) -> StepOutcome {
        let dt = self.cfg.episode.step_period_s;
        let limits = self.model.limits();
        for ((q, t), v) in self.q.iter_mut().zip(target).zip(&limits.velocity_rad_s) {
            let max_dq = v * dt;
            let dq = (t - *q).clamp(-max_dq, max_dq);
            *q += dq;
        }
        limits.clamp(&mut self.q);
        self.model.fk_into(&self.q, &mut self.poses);
        let tcp = self.poses.tcp_m();
        self.tcp_vel_m_s = (tcp - tcp_prev) / dt;
        self.step_index += 1;

        let all = self.distances_now();
        let (boxes, table) = (all.boxes, all.table);
        let clearance_m = self.cfg.success.min_box_clearance_m;
        // Closer than the clearance to a box or (links 2–5, the tool) to the table is
        // contact: the runtime's shield keeps `shield.min_distance_m` from both. A
        // self-collision is contact too (the shield refuses it as well).
        let self_collision = all.own.colliding();
        let contact = self_collision
            || table.colliding
            || table.distance_m < clearance_m
            || boxes.is_some_and(|b| b.colliding || b.distance_m < clearance_m);
        self.last_distance = boxes.unwrap_or(table);

        let goal_dist_m = (self.target_m - tcp).norm();
        let r = &self.cfg.reward;
        let progress = self.goal_dist_m - goal_dist_m;
        self.goal_dist_m = goal_dist_m;
        let proximity = match boxes {
            Some(b) if b.distance_m < r.d_thre_m => -1.0,
            _ => 0.0,
        };
        let task_done = goal_dist_m <= self.cfg.success.tolerance_m;
        let safe = !contact;
        let terminated = task_done || !safe;
        let truncated = !terminated && self.step_index >= self.cfg.episode.max_steps;
        let terminal = if !safe {
            -r.collision_penalty
        } else if task_done {
            r.success_bonus
        } else {
            0.0
        };
        let reward = r.c1 * progress + r.c2 * (-a_norm) + r.c3 * proximity + terminal;
        self.write_obs();
        StepOutcome {
            obs: self.obs,
            reward: reward as f32,
            terms: RewardTerms {
                progress: progress as f32,
                action: (-a_norm) as f32,
                proximity: proximity as f32,
                terminal: terminal as f32,
            },
            task_done,
            safe,
            self_collision,
            terminated,
            truncated,
            distance: self.last_distance,
            joints: self.q,
        }
    }

    /// A random scene for training: a goal in the sampling ranges (at least
    /// `min_goal_distance_m` from the start TCP) and one box of `class` placed between the
    /// start TCP and the goal, clear of the goal cube, at least `d_thre_m` from the robot at
    /// its start posture and `d_thre_m / 2` from the robot at the goal (so every sampled
    /// scene can be solved). If no placement fits after 64 goals × 8 placements the scene
    /// has no box. Deterministic for a given RNG state.
    pub fn sample_scene<R: Rng + ?Sized>(&self, rng: &mut R, class: ObstacleClass) -> Scene {
        let s = &self.cfg.sampling;
        let start = self.start_tcp_m;
        let sizes = match class {
            ObstacleClass::Small => self.cfg.obstacles.small,
            ObstacleClass::Large => self.cfg.obstacles.large,
        };
        let start_poses = self.model.fk(&self.model.home());
        let margin = self.cfg.reward.d_thre_m;
        let mut scene = Scene::empty(s.table_height_m, self.scene.goal);
        for _ in 0..GOAL_TRIES {
            let goal_xy = [uniform(rng, s.goal_x_m), uniform(rng, s.goal_y_m)];
            let dir = [goal_xy[0] - start.x, goal_xy[1] - start.y];
            let len = (dir[0] * dir[0] + dir[1] * dir[1]).sqrt();
            if len < s.min_goal_distance_m.max(1e-6) {
                continue;
            }
            let goal = Goal {
                center_m: [
                    goal_xy[0],
                    goal_xy[1],
                    s.table_height_m + s.goal_size_m / 2.0,
                ],
                size_m: s.goal_size_m,
            };
            scene = Scene::empty(s.table_height_m, goal);
            // The arm at the goal: a box must leave room for it (the xArm5 is a planar
            // linkage in the plane of joint 1, so a tall box in that plane, nearer than the
            // goal, makes the goal unreachable).
            let Some(goal_poses) = self.goal_poses(&scene) else {
                continue;
            };
            let (ux, uy) = (dir[0] / len, dir[1] / len);
            for _ in 0..BOX_TRIES {
                let f = uniform(rng, s.obstacle_fraction);
                let lat = uniform(rng, s.obstacle_lateral_m);
                let sx = uniform(rng, sizes.footprint_m);
                let sy = uniform(rng, sizes.footprint_m);
                let h = uniform(rng, sizes.height_m);
                let b = BoxObstacle {
                    center_m: [
                        start.x + f * dir[0] - uy * lat,
                        start.y + f * dir[1] + ux * lat,
                        s.table_height_m + h / 2.0,
                    ],
                    size_m: [sx, sy, h],
                };
                let gap_x = (b.center_m[0] - goal.center_m[0]).abs() - (sx + goal.size_m) / 2.0;
                let gap_y = (b.center_m[1] - goal.center_m[1]).abs() - (sy + goal.size_m) / 2.0;
                if gap_x.max(gap_y) < s.goal_clearance_m {
                    continue;
                }
                scene.obstacles.clear();
                let _ = scene.obstacles.push(b);
                if !self.geometry.in_contact(&start_poses, &scene, margin)
                    && !self.geometry.in_contact(&goal_poses, &scene, margin / 2.0)
                {
                    return scene;
                }
            }
            scene.obstacles.clear();
        }
        scene
    }
}

/// An action clipped to `[-1, 1]`, NaN as 0.
fn clip_action(v: f32) -> f64 {
    if v.is_nan() {
        0.0
    } else {
        f64::from(v).clamp(-1.0, 1.0)
    }
}

/// Where [`TwinEnv::sample_world`] put a box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Placement {
    OnPath,
    NearGoal,
    Wall,
    Anywhere,
}

impl TwinEnv {
    /// A random world of the task's broad distribution (`[world]`, see
    /// [`super::WorldConfig`]): a goal as in [`TwinEnv::sample_scene`] and a box count drawn
    /// from `world.boxes`, each box placed on the path, beside the goal, as a wall or
    /// anywhere, redrawn (up to 8 times, then left out) when it would touch the arm at the
    /// start or at the goal posture or crowd the goal cube. Without `[world]`, a
    /// small-obstacle scene. Deterministic for a given RNG state; not every world drawn is
    /// feasible (a planner decides that: `twin::feasibility`).
    pub fn sample_world<R: Rng + ?Sized>(&self, rng: &mut R) -> Scene {
        let Some(w) = self.cfg.world else {
            return self.sample_scene(rng, ObstacleClass::Small);
        };
        let s = &self.cfg.sampling;
        let start = self.start_tcp_m;
        let start_poses = self.model.fk(&self.model.home());
        let margin = self.cfg.reward.d_thre_m;
        for _ in 0..GOAL_TRIES {
            let goal_xy = [uniform(rng, s.goal_x_m), uniform(rng, s.goal_y_m)];
            let dir = [goal_xy[0] - start.x, goal_xy[1] - start.y];
            let len = (dir[0] * dir[0] + dir[1] * dir[1]).sqrt();
            if len < s.min_goal_distance_m.max(1e-6) {
                continue;
            }
            let goal = Goal {
                center_m: [
                    goal_xy[0],
                    goal_xy[1],
                    s.table_height_m + s.goal_size_m / 2.0,
                ],
                size_m: s.goal_size_m,
            };
            let mut scene = Scene::empty(s.table_height_m, goal);
            let Some(goal_poses) = self.goal_poses(&scene) else {
                continue;
            };
            let (ux, uy) = (dir[0] / len, dir[1] / len);
            let count = rng.random_range(w.boxes[0]..=w.boxes[1]) as usize;
            for _ in 0..count.min(MAX_OBSTACLES) {
                let pick = rng.random::<f64>();
                let placement = if pick < w.on_path_share {
                    Placement::OnPath
                } else if pick < w.on_path_share + w.near_goal_share {
                    Placement::NearGoal
                } else if pick < w.on_path_share + w.near_goal_share + w.wall_share {
                    Placement::Wall
                } else {
                    Placement::Anywhere
                };
                for _ in 0..BOX_TRIES {
                    let mut sx = uniform(rng, w.footprint_m);
                    let mut sy = uniform(rng, w.footprint_m);
                    let h = uniform(rng, w.height_m);
                    let (cx, cy) = match placement {
                        Placement::OnPath | Placement::Wall => {
                            let f = uniform(rng, s.obstacle_fraction);
                            let lat = uniform(rng, s.obstacle_lateral_m);
                            if placement == Placement::Wall {
                                // Across the path: the long extent along the axis nearer
                                // to perpendicular to it.
                                let long = uniform(rng, w.wall_length_m);
                                let thin = w.footprint_m[0];
                                if ux.abs() > uy.abs() {
                                    (sx, sy) = (thin, long);
                                } else {
                                    (sx, sy) = (long, thin);
                                }
                            }
                            (
                                start.x + f * dir[0] - uy * lat,
                                start.y + f * dir[1] + ux * lat,
                            )
                        }
                        Placement::NearGoal => {
                            let angle = rng.random::<f64>() * std::f64::consts::TAU;
                            let gap = s.goal_clearance_m
                                + 0.005
                                + rng.random::<f64>() * w.near_goal_gap_m;
                            let reach = (s.goal_size_m + sx.max(sy)) / 2.0 + gap;
                            // Chebyshev placement: a square ring around the goal cube.
                            let (c, sn) = (angle.cos(), angle.sin());
                            let k = reach / c.abs().max(sn.abs());
                            (goal_xy[0] + k * c, goal_xy[1] + k * sn)
                        }
                        Placement::Anywhere => (uniform(rng, w.x_m), uniform(rng, w.y_m)),
                    };
                    let b = BoxObstacle {
                        center_m: [cx, cy, s.table_height_m + h / 2.0],
                        size_m: [sx, sy, h],
                    };
                    let gap_x = (cx - goal.center_m[0]).abs() - (sx + goal.size_m) / 2.0;
                    let gap_y = (cy - goal.center_m[1]).abs() - (sy + goal.size_m) / 2.0;
                    if gap_x.max(gap_y) < s.goal_clearance_m {
                        continue;
                    }
                    if scene.obstacles.push(b).is_err() {
                        break;
                    }
                    if self.geometry.in_contact(&start_poses, &scene, margin)
                        || self.geometry.in_contact(&goal_poses, &scene, margin / 2.0)
                    {
                        let _ = scene.obstacles.pop();
                        continue;
                    }
                    break;
                }
            }
            if scene.obstacles.len() >= w.boxes[0] as usize {
                return scene;
            }
        }
        Scene::empty(s.table_height_m, self.scene.goal)
    }
}

/// Runs one whole episode in `scene` with `policy`, from the start posture until
/// termination or truncation. Joints after every step go to `waypoints_out` (cleared
/// first) when given.
///
/// # Performance
/// No allocation (the policy closure permitting).
pub fn rollout<P>(
    env: &mut TwinEnv,
    scene: &Scene,
    policy: P,
    waypoints_out: Option<&mut heapless::Vec<Joints, MAX_EPISODE_STEPS>>,
) -> EpisodeSummary
where
    P: FnMut(&[f32; OBS_DIM]) -> [f32; ACT_DIM],
{
    rollout_until(env, scene, policy, waypoints_out, true)
}

/// [`rollout`], or with `stop_at_contact = false` a blind one that keeps stepping through
/// contact until the goal or the step budget (what executing the policy without the
/// lookahead does; `safe` is then false if any step was in contact).
///
/// # Performance
/// No allocation (the policy closure permitting).
pub fn rollout_until<P>(
    env: &mut TwinEnv,
    scene: &Scene,
    mut policy: P,
    waypoints_out: Option<&mut heapless::Vec<Joints, MAX_EPISODE_STEPS>>,
    stop_at_contact: bool,
) -> EpisodeSummary
where
    P: FnMut(&[f32; OBS_DIM]) -> [f32; ACT_DIM],
{
    rollout_with(
        env,
        scene,
        |env, obs| env.step(&policy(obs)),
        waypoints_out,
        stop_at_contact,
    )
}

/// [`rollout_until`] for a joint-step policy: the environment is switched to the joint-step
/// space ([`TwinEnv::set_action_space`]), the goal posture chosen at the reset, and every
/// step taken with [`TwinEnv::step_joint`].
///
/// # Performance
/// One goal-posture choice, then no allocation (the policy closure permitting).
pub fn rollout_joint<P>(
    env: &mut TwinEnv,
    scene: &Scene,
    mut policy: P,
    waypoints_out: Option<&mut heapless::Vec<Joints, MAX_EPISODE_STEPS>>,
    stop_at_contact: bool,
) -> EpisodeSummary
where
    P: FnMut(&[f32; OBS_DIM]) -> [f32; JOINT_ACT_DIM],
{
    env.set_action_space(ActionSpace::JointStep);
    rollout_with(
        env,
        scene,
        |env, obs| env.step_joint(&policy(obs)),
        waypoints_out,
        stop_at_contact,
    )
}

/// The episode loop of both spaces: reset, then `step` until the end.
fn rollout_with<S>(
    env: &mut TwinEnv,
    scene: &Scene,
    mut step: S,
    mut waypoints_out: Option<&mut heapless::Vec<Joints, MAX_EPISODE_STEPS>>,
    stop_at_contact: bool,
) -> EpisodeSummary
where
    S: FnMut(&mut TwinEnv, &[f32; OBS_DIM]) -> StepOutcome,
{
    let mut obs = env.reset(scene);
    if let Some(w) = waypoints_out.as_deref_mut() {
        w.clear();
    }
    let mut summary = EpisodeSummary {
        success: false,
        safe: true,
        return_: 0.0,
        steps: 0,
        min_distance_m: env.last_distance.distance_m,
    };
    loop {
        let out = step(env, &obs);
        obs = out.obs;
        summary.steps += 1;
        summary.return_ += f64::from(out.reward);
        summary.min_distance_m = summary.min_distance_m.min(out.distance.distance_m);
        summary.success = out.task_done;
        summary.safe &= out.safe;
        if let Some(w) = waypoints_out.as_deref_mut() {
            let _ = w.push(out.joints);
        }
        let ended = if stop_at_contact {
            out.terminated
        } else {
            out.task_done
        };
        if ended || out.truncated || summary.steps >= env.config().episode.max_steps {
            break;
        }
    }
    summary
}
