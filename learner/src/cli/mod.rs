//! The subcommands of the `learner` binary, one module each; every module owns its
//! `clap::Args` struct and a `run` function (the only place, with `main.rs`, where `anyhow`
//! is used):
//!
//! - [`pretrain`]: PPO on the task's pre-training distribution (its broad `[world]`, or
//!   random small-obstacle scenes), checkpoints in `--out`;
//! - [`eval`]: evaluate a checkpoint (JSON);
//! - [`bench`]: training throughput (JSON);
//! - [`export`]: a checkpoint's policy as a `PolicyBlob` file;
//! - [`serve`]: the retraining service over iceoryx2;
//! - [`retrain`]: one retraining offline, as `serve` does for one request;
//! - [`distil`]: the planner distilled into a policy (DAgger).
//!
//! Shared here: the PPO flags of `pretrain` and `bench` ([`PpoArgs`]), the seed of the fixed
//! evaluation scenes (re-exported from [`learner::twin_env::EVAL_SEED`]) and scene-file
//! loading. The flags of a retraining are the library's ([`learner::retrain::RetrainFlags`]);
//! the unseen-worlds benchmark is its own binary (`learner/unseen-worlds`).

pub mod bench;
pub mod distil;
pub mod eval;
pub mod export;
pub mod pretrain;
pub mod retrain;
pub mod serve;

use std::path::Path;

use anyhow::{Context, Result};
use learner::ppo::PpoConfig;
use shm_schemas::scene_file::SceneFile;
use twin::Scene;

pub use learner::twin_env::EVAL_SEED;

/// PPO overrides shared by `pretrain` and `bench` (unset: [`PpoConfig::default`]).
#[derive(clap::Args, Clone)]
pub struct PpoArgs {
    /// Parallel environments.
    #[arg(long, value_parser = shm_schemas::cli_bounds::int_within(1usize, 65_536), allow_negative_numbers = true)]
    envs: Option<usize>,
    /// Rollout worker threads (0 = one per core).
    #[arg(long, value_parser = shm_schemas::cli_bounds::int_within(0usize, 256), allow_negative_numbers = true)]
    workers: Option<usize>,
    /// Steps per environment per rollout.
    #[arg(long, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1_000_000), allow_negative_numbers = true)]
    n_steps: Option<usize>,
    /// Minibatch size.
    #[arg(long, value_parser = shm_schemas::cli_bounds::int_within(1usize, 10_000_000), allow_negative_numbers = true)]
    batch: Option<usize>,
    /// Epochs per rollout.
    #[arg(long, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1000), allow_negative_numbers = true)]
    epochs: Option<usize>,
    /// Learning rate.
    #[arg(long, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    lr: Option<f64>,
    /// Hidden layer widths, comma-separated (e.g. `128,128`; each ≤ 256).
    #[arg(long, value_delimiter = ',', value_parser = shm_schemas::cli_bounds::int_within(1usize, 256), allow_negative_numbers = true)]
    hidden: Option<Vec<usize>>,
    /// Entropy bonus coefficient.
    #[arg(long, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    ent_coef: Option<f64>,
    /// Torch intra-op threads.
    #[arg(long, default_value_t = 1, value_parser = shm_schemas::cli_bounds::int_within(1i32, 256), allow_negative_numbers = true)]
    pub torch_threads: i32,
}

impl PpoArgs {
    /// The default configuration with the given overrides.
    pub fn config(&self) -> PpoConfig {
        let mut c = PpoConfig::default();
        if let Some(v) = self.envs {
            c.n_envs = v;
        }
        if let Some(v) = self.workers {
            c.workers = v;
        }
        if let Some(v) = self.n_steps {
            c.n_steps = v;
        }
        if let Some(v) = self.batch {
            c.batch_size = v;
        }
        if let Some(v) = self.epochs {
            c.n_epochs = v;
        }
        if let Some(v) = self.lr {
            c.learning_rate = v;
        }
        if let Some(v) = &self.hidden {
            c.hidden.clone_from(v);
        }
        if let Some(v) = self.ent_coef {
            c.ent_coef = v;
        }
        c
    }
}

/// Loads a scene file as a twin scene.
///
/// # Errors
/// The file cannot be read or parsed, or does not describe a valid scene.
pub fn load_scene(path: &Path) -> Result<Scene> {
    let file = SceneFile::load(path).with_context(|| format!("scene {}", path.display()))?;
    Scene::from_file(&file).map_err(|e| anyhow::anyhow!("scene {}: {e:?}", path.display()))
}
