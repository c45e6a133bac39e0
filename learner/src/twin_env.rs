//! The rt-core twin as a training environment, and the scene distributions the learner
//! trains on: the pre-training distribution (the task's broad `[world]`, or the paper's
//! random goal with one random small box between start and goal) and the retraining mix (the reported scene with randomisation around it, plus a
//! share of the old distribution so the policy does not forget it).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::ActionSpace;
use twin::approval::{ApprovalSettings, ApprovalSettingsError, EpisodeApproval, PlanRejection};
use twin::{
    ACT_DIM, JOINT_ACT_DIM, Joints, ObstacleClass, RobotModel, Scene, StepOutcome, TaskConfig,
    TaskConfigError, TwinEnv, UrdfLoadError,
};

use crate::env::{Env, SceneSampler, StepInfo};

/// Why the task could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum TaskLoadError {
    /// The task file.
    #[error("task config {}", .path.display())]
    Task {
        /// File.
        path: PathBuf,
        /// What was wrong.
        #[source]
        source: TaskConfigError,
    },
    /// The robot model.
    #[error("robot model {}", .path.display())]
    Model {
        /// File.
        path: PathBuf,
        /// What was wrong.
        #[source]
        source: UrdfLoadError,
    },
    /// rt-core's runtime configuration (the approval settings).
    #[error("runtime config {}", .path.display())]
    Runtime {
        /// File.
        path: PathBuf,
        /// What was wrong.
        #[source]
        source: ApprovalSettingsError,
    },
}

/// The runtime configuration rt-core approves plans with, looked for beside the task file.
pub const RUNTIME_TOML: &str = "runtime.toml";

/// The twin environment behind the [`Env`] interface.
///
/// An episode that reaches the goal with no contact is a success of an evaluation only when
/// rt-core would approve its plan: [`Env::approve_episode`] runs the twin's one verification
/// ([`EpisodeApproval`]: the end settled onto the goal, Ruckig smoothing with rt-core's
/// settings, the shield on every sample, the goal on the smoothed path) on the episode's
/// waypoints. Evaluations call it, and with them convergence, the kept scenes, the publish
/// gate and the benchmarks' zero-shot columns; training steps do not (verifying them slowed
/// the tall-box retraining past its step budget).
#[derive(Debug, Clone)]
pub struct TwinTask {
    /// The wrapped twin.
    pub env: TwinEnv,
    /// rt-core's approval settings; `None`: no verification beyond the episode.
    approval: Option<ApprovalSettings>,
    /// The verification, built on first use.
    verifier: Option<Box<EpisodeApproval>>,
    /// The current episode's scene.
    scene: Option<Scene>,
    /// The joints after each step of the current episode.
    episode: Vec<Joints>,
    /// Why the last verified episode was refused.
    last_refusal: Option<PlanRejection>,
}

impl TwinTask {
    /// Loads the task file and the robot model beside it (`xarm5.urdf` in the same folder
    /// unless `urdf` is given).
    ///
    /// # Errors
    /// [`TaskLoadError`].
    pub fn load(task: &Path, urdf: Option<&Path>) -> Result<Self, TaskLoadError> {
        let cfg = TaskConfig::load(task).map_err(|source| TaskLoadError::Task {
            path: task.to_path_buf(),
            source,
        })?;
        let urdf_path = urdf
            .map(Path::to_path_buf)
            .unwrap_or_else(|| task.parent().unwrap_or(Path::new(".")).join("xarm5.urdf"));
        let model = RobotModel::load(&urdf_path).map_err(|source| TaskLoadError::Model {
            path: urdf_path.clone(),
            source,
        })?;
        let runtime = task.parent().unwrap_or(Path::new(".")).join(RUNTIME_TOML);
        let approval = if runtime.is_file() {
            ApprovalSettings::load(&runtime).map_err(|source| TaskLoadError::Runtime {
                path: runtime.clone(),
                source,
            })?
        } else {
            ApprovalSettings::shipped().map_err(|source| TaskLoadError::Runtime {
                path: PathBuf::from(RUNTIME_TOML),
                source,
            })?
        };
        Ok(Self::new(TwinEnv::new(model, cfg), Some(approval)))
    }

    /// Over `env`, verifying successful episodes with rt-core's `approval` settings (the
    /// `runtime.toml` beside the task, or the shipped one: [`TwinTask::load`]) or, with
    /// `None`, not at all (the episode's own success).
    pub fn new(env: TwinEnv, approval: Option<ApprovalSettings>) -> Self {
        Self {
            env,
            approval,
            verifier: None,
            scene: None,
            episode: Vec::new(),
            last_refusal: None,
        }
    }

    /// The approval settings successful episodes are verified with.
    pub fn approval(&self) -> Option<&ApprovalSettings> {
        self.approval.as_ref()
    }

    /// Why the last episode that reached the goal with no contact was refused (which
    /// sample, which check, against what), if it was.
    pub fn last_refusal(&self) -> Option<PlanRejection> {
        self.last_refusal
    }

    /// The twin's verification of `episode` (waypoints of a successful, contact-free
    /// episode in `scene`): what rt-core's approval answers for that plan.
    ///
    /// # Errors
    /// The [`PlanRejection`]; `Ok(f64::INFINITY)` without approval settings.
    pub fn verify(&mut self, scene: &Scene, episode: &[Joints]) -> Result<f64, PlanRejection> {
        let Some(settings) = self.approval else {
            return Ok(f64::INFINITY);
        };
        let env = &self.env;
        let verifier = self
            .verifier
            .get_or_insert_with(|| Box::new(EpisodeApproval::new(&settings, env)));
        verifier.approve(env, scene, episode)
    }

    /// Switches the episodes (and so training, evaluation and the observation layout) to
    /// `space` ([`TwinEnv::set_action_space`]); a policy acts in the space of its
    /// checkpoint (`CheckpointMeta::action_space`).
    pub fn set_action_space(&mut self, space: ActionSpace) {
        self.env.set_action_space(space);
    }

    /// Hash of the task configuration.
    pub fn task_hash(&self) -> u64 {
        self.env.config().hash()
    }
}

/// One step of `env` in its action space ([`TwinEnv::action_space`]): `action` holds at
/// least the space's action length (`ACT_DIM` Cartesian, `JOINT_ACT_DIM` joint values).
///
/// # Panics
/// When `action` is shorter than the space's action length.
pub fn step_in_space(env: &mut TwinEnv, action: &[f32]) -> StepOutcome {
    match env.action_space() {
        ActionSpace::CartesianStep => {
            let mut a = [0.0f32; ACT_DIM];
            a.copy_from_slice(&action[..ACT_DIM]);
            env.step(&a)
        }
        ActionSpace::JointStep => {
            let mut a = [0.0f32; JOINT_ACT_DIM];
            a.copy_from_slice(&action[..JOINT_ACT_DIM]);
            env.step_joint(&a)
        }
    }
}

impl Env for TwinTask {
    type Scene = Scene;
    fn obs_dim(&self) -> usize {
        self.env.obs_dim()
    }
    fn act_dim(&self) -> usize {
        self.env.action_space().act_dim()
    }
    fn reset(&mut self, scene: &Scene, obs: &mut [f32]) {
        let full = self.env.reset(scene);
        obs.copy_from_slice(&full[..obs.len()]);
        self.scene = Some(*scene);
        self.episode.clear();
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> StepInfo {
        let out = step_in_space(&mut self.env, action);
        obs.copy_from_slice(&out.obs[..obs.len()]);
        self.episode.push(out.joints);
        StepInfo {
            reward: out.reward,
            terminated: out.terminated,
            truncated: out.truncated,
            success: out.task_done,
            collision: !out.safe,
        }
    }

    fn action_space(&self) -> ActionSpace {
        self.env.action_space()
    }

    /// The verification of the episode that has just reached the goal with no contact;
    /// keeps the refusal ([`TwinTask::last_refusal`]).
    fn approve_episode(&mut self) -> bool {
        let Some(scene) = self.scene else {
            return false;
        };
        let episode = std::mem::take(&mut self.episode);
        let verdict = self.verify(&scene, &episode);
        self.episode = episode;
        self.last_refusal = verdict.err();
        verdict.is_ok()
    }
}

/// Which scenes a [`CurriculumSampler`] draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distribution {
    /// One box of a class between start and goal (the paper's pre-training).
    Class(ObstacleClass),
    /// The task's broad `[world]` distribution (the generalist's pre-training).
    World,
}

/// Pre-training scenes: the task's random goal and one random box of a class, or the broad
/// world distribution.
#[derive(Debug, Clone)]
pub struct CurriculumSampler {
    env: TwinEnv,
    /// What is drawn.
    pub distribution: Distribution,
}

impl CurriculumSampler {
    /// Small-obstacle scenes of `task`.
    pub fn small(task: &TwinTask) -> Self {
        Self {
            env: task.env.clone(),
            distribution: Distribution::Class(ObstacleClass::Small),
        }
    }

    /// The task's `[world]` distribution (small-obstacle scenes if it has none).
    pub fn world(task: &TwinTask) -> Self {
        Self {
            env: task.env.clone(),
            distribution: Distribution::World,
        }
    }

    /// The pre-training distribution of `task`: its `[world]` if it has one, else small
    /// obstacles.
    pub fn pretraining(task: &TwinTask) -> Self {
        if task.env.config().world.is_some() {
            Self::world(task)
        } else {
            Self::small(task)
        }
    }
}

impl SceneSampler<Scene> for CurriculumSampler {
    fn sample(&self, rng: &mut ChaCha8Rng) -> Scene {
        match self.distribution {
            Distribution::Class(class) => self.env.sample_scene(rng, class),
            Distribution::World => self.env.sample_world(rng),
        }
    }
}

/// Randomisation around a reported scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jitter {
    /// Goal and box centres move by up to this in x and y (m).
    pub xy_m: f64,
    /// Box extents are scaled by up to `1 ± size_frac`.
    pub size_frac: f64,
}

impl Default for Jitter {
    fn default() -> Self {
        Self {
            xy_m: 0.02,
            size_frac: 0.1,
        }
    }
}

/// `scene` with goal and boxes moved/scaled at random within `jitter` (boxes stay on the
/// table).
pub fn jittered(scene: &Scene, jitter: Jitter, rng: &mut ChaCha8Rng) -> Scene {
    let mut s = *scene;
    let mut d = |r: f64| {
        if r > 0.0 {
            rng.random_range(-r..=r)
        } else {
            0.0
        }
    };
    s.goal.center_m[0] += d(jitter.xy_m);
    s.goal.center_m[1] += d(jitter.xy_m);
    for b in s.obstacles.iter_mut() {
        b.center_m[0] += d(jitter.xy_m);
        b.center_m[1] += d(jitter.xy_m);
        let bottom = b.center_m[2] - b.size_m[2] / 2.0;
        for k in 0..3 {
            b.size_m[k] *= 1.0 + d(jitter.size_frac);
        }
        b.center_m[2] = bottom + b.size_m[2] / 2.0;
    }
    s
}

/// Retraining scenes: with probability `old_share` a pre-training scene, otherwise the
/// reported scene jittered.
#[derive(Debug)]
pub struct RetrainSampler {
    /// The reported scene.
    pub scene: Scene,
    /// Randomisation around it.
    pub jitter: Jitter,
    /// Share of episodes drawn from the old (pre-training) distribution.
    pub old_share: f64,
    old: CurriculumSampler,
    /// Height curriculum: box heights are scaled by a factor drawn from `[lo, 1]`, with `lo`
    /// (f32 bits) raised by the trainer from a small value to 1 (1 = off).
    height_lo: AtomicU32,
}

impl RetrainSampler {
    /// Around `scene`, with `old_share` of `task`'s pre-training scenes ([`CurriculumSampler::pretraining`]).
    pub fn new(task: &TwinTask, scene: Scene, jitter: Jitter, old_share: f64) -> Self {
        Self {
            scene,
            jitter,
            old_share,
            old: CurriculumSampler::pretraining(task),
            height_lo: AtomicU32::new(1.0f32.to_bits()),
        }
    }

    /// Evaluation scenes for the reported scene: the scene itself and `n - 1` variants
    /// jittered by `scale` × the training jitter (0: `n` copies of the scene), from `seed`.
    pub fn eval_scenes(&self, n: usize, seed: u64, scale: f64) -> Vec<Scene> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let half = Jitter {
            xy_m: self.jitter.xy_m * scale,
            size_frac: self.jitter.size_frac * scale,
        };
        std::iter::once(self.scene)
            .chain((1..n).map(|_| jittered(&self.scene, half, &mut rng)))
            .collect()
    }
}

impl RetrainSampler {
    /// Sets the lower end of the box-height scale (clamped to `[0, 1]`; 1 turns the height
    /// curriculum off).
    pub fn set_height_lo(&self, lo: f32) {
        self.height_lo
            .store(lo.clamp(0.0, 1.0).to_bits(), Ordering::Relaxed);
    }

    /// The lower end of the box-height scale.
    pub fn height_lo(&self) -> f32 {
        f32::from_bits(self.height_lo.load(Ordering::Relaxed))
    }
}

impl SceneSampler<Scene> for RetrainSampler {
    fn sample(&self, rng: &mut ChaCha8Rng) -> Scene {
        if rng.random::<f64>() < self.old_share {
            return self.old.sample(rng);
        }
        let mut s = jittered(&self.scene, self.jitter, rng);
        let lo = f64::from(self.height_lo());
        if lo < 1.0 {
            let k = rng.random_range(lo..=1.0);
            for b in s.obstacles.iter_mut() {
                let bottom = b.center_m[2] - b.size_m[2] / 2.0;
                b.size_m[2] *= k;
                b.center_m[2] = bottom + b.size_m[2] / 2.0;
            }
        }
        s
    }
}

/// Seed of the fixed evaluation scenes of the pre-training distribution (`learner eval`,
/// `pretrain`, `distil`, `retrain` and the unseen-worlds benchmark's kept scenes; distinct
/// from every training stream).
pub const EVAL_SEED: u64 = 0x00E0_A15E;

/// `n` scenes from `sampler` with a fixed seed (the evaluation set).
pub fn fixed_scenes<S: SceneSampler<Scene>>(sampler: &S, n: usize, seed: u64) -> Vec<Scene> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| sampler.sample(&mut rng)).collect()
}
