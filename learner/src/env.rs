//! The environment interface the PPO trainer runs against, and a tiny point-reaching task
//! used by the tests (the real task is the rt-core twin, adapted in [`crate::twin_env`]).
//!
//! An environment owns its episode state; scenes (what an episode looks like: goal, obstacles)
//! are drawn by a [`SceneSampler`] so the same environment serves pre-training, evaluation on
//! fixed scenes and retraining around a reported scene.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schemas::ActionSpace;

/// What one step reports besides the observation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepInfo {
    /// Reward of this step.
    pub reward: f32,
    /// The episode ended by the task (success, collision, …): no bootstrapping.
    pub terminated: bool,
    /// The episode was cut by the step limit: the value of the last observation is bootstrapped.
    pub truncated: bool,
    /// The task was achieved at this step.
    pub success: bool,
    /// A contact/unsafe state happened at this step.
    pub collision: bool,
}

/// A reinforcement-learning environment with a continuous action in `[-1, 1]^act_dim`.
pub trait Env: Send {
    /// The description of an episode's world (goal, obstacles).
    type Scene: Clone + Send + Sync;
    /// Observation length.
    fn obs_dim(&self) -> usize;
    /// Action length.
    fn act_dim(&self) -> usize;
    /// Starts an episode in `scene`, writing the first observation into `obs`.
    fn reset(&mut self, scene: &Self::Scene, obs: &mut [f32]);
    /// Applies `action` (already clipped to `[-1, 1]`), writing the next observation into `obs`.
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> StepInfo;

    /// Whether the deployment would approve the plan of the episode that has just ended
    /// with `success` and no contact (the twin: rt-core's verification of the smoothed path,
    /// `twin::approval`). Evaluations ask it once per such episode; an episode it refuses
    /// is no success. Training steps never ask (it costs a smoothing per episode). Default:
    /// approved.
    fn approve_episode(&mut self) -> bool {
        true
    }

    /// The action space a policy of this environment acts in, as its checkpoints record it
    /// (`CheckpointMeta::action_space`). Default: the paper's Cartesian step.
    fn action_space(&self) -> ActionSpace {
        ActionSpace::CartesianStep
    }
}

/// Draws the scene of each new episode.
pub trait SceneSampler<S>: Sync {
    /// A scene for a new episode.
    fn sample(&self, rng: &mut ChaCha8Rng) -> S;
}

impl<S, F: Fn(&mut ChaCha8Rng) -> S + Sync> SceneSampler<S> for F {
    fn sample(&self, rng: &mut ChaCha8Rng) -> S {
        self(rng)
    }
}

/// Scene of the [`PointReach`] toy task: a goal position in `[-1, 1]^2` and a start position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointScene {
    /// Goal position.
    pub goal: [f32; 2],
    /// Start position.
    pub start: [f32; 2],
}

impl PointScene {
    /// A random scene: start and goal uniform in `[-1, 1]^2`.
    pub fn random(rng: &mut ChaCha8Rng) -> Self {
        Self {
            goal: [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)],
            start: [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)],
        }
    }
}

/// A point in the plane moved by velocity commands toward a goal (dense reward: progress
/// toward the goal, a bonus on reaching it). Small, fast and solvable in a few thousand steps:
/// it is what the tests train on.
#[derive(Debug, Clone, Default)]
pub struct PointReach {
    pos: [f32; 2],
    goal: [f32; 2],
    steps: u32,
}

impl PointReach {
    /// Episode length limit (steps).
    pub const MAX_STEPS: u32 = 50;
    /// Distance counting as reached.
    pub const TOLERANCE: f32 = 0.1;
    /// Largest displacement per step.
    pub const STEP_SIZE: f32 = 0.1;

    fn dist(&self) -> f32 {
        ((self.pos[0] - self.goal[0]).powi(2) + (self.pos[1] - self.goal[1]).powi(2)).sqrt()
    }

    fn write_obs(&self, obs: &mut [f32]) {
        obs[0] = self.pos[0];
        obs[1] = self.pos[1];
        obs[2] = self.goal[0] - self.pos[0];
        obs[3] = self.goal[1] - self.pos[1];
    }
}

impl Env for PointReach {
    type Scene = PointScene;
    fn obs_dim(&self) -> usize {
        4
    }
    fn act_dim(&self) -> usize {
        2
    }
    fn reset(&mut self, scene: &PointScene, obs: &mut [f32]) {
        self.pos = scene.start;
        self.goal = scene.goal;
        self.steps = 0;
        self.write_obs(obs);
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> StepInfo {
        let before = self.dist();
        for (p, a) in self.pos.iter_mut().zip(action) {
            *p = (*p + a.clamp(-1.0, 1.0) * Self::STEP_SIZE).clamp(-1.5, 1.5);
        }
        self.steps += 1;
        let after = self.dist();
        let success = after < Self::TOLERANCE;
        self.write_obs(obs);
        StepInfo {
            reward: 10.0 * (before - after) + if success { 1.0 } else { 0.0 },
            terminated: success,
            truncated: !success && self.steps >= Self::MAX_STEPS,
            success,
            collision: false,
        }
    }
}
