//! PPO (clipped surrogate, GAE(λ), value loss, entropy bonus, minibatch Adam, gradient-norm
//! clipping, running observation normalisation and return-based reward scaling) over a vector
//! of environments stepped on worker threads.
//!
//! # Map
//! - [`config`](PpoConfig): hyper-parameters and their validation;
//! - `gae`: [`gae`], advantages and returns of a time-major rollout;
//! - `host_net`: the actor-critic on host `f32` buffers (no tch): batched forward passes of
//!   rollouts, and the update's hand-written backward pass, split by rows over the worker
//!   threads;
//! - `loss`: [`ppo_loss`] and its pieces (clipped surrogate, advantage normalisation);
//! - `rollout`: the threaded rollout collection (scene sampling, action noise, reward
//!   scaling, truncation bootstrap) and [`EpisodeStat`];
//! - `trainer`: [`Trainer`] — start reading here: [`Trainer::iterate`] is one rollout plus
//!   one update;
//! - `evaluation`: deterministic episodes, [`evaluate`], [`successes`] and [`EvalResult`];
//! - [`bc`]: behaviour cloning of the actor (the warm start from demonstrations).
//!
//! # Threads
//! The environments are split into `workers` chunks; each rollout runs every chunk for the
//! whole rollout on its own scoped thread (policy forward pass included, on a read-only
//! shallow copy of the parameters), so threads meet once per rollout, not once per step.
//!
//! # Reproducibility
//! All sampling (scenes, action noise, minibatch shuffles) uses ChaCha8 streams derived from
//! the seed (one per environment, one for the trainer, one for the initial weights). On CPU
//! with the same seed, `n_envs`, `workers` and torch thread count, a run is
//! bit-reproducible. Changing `workers` changes the batch shapes of the forward passes and
//! hence float rounding; on CUDA, kernels are not bit-reproducible.

pub mod bc;
mod config;
mod evaluation;
mod gae;
mod host_net;
mod loss;
mod rollout;
mod trainer;

pub use config::{PpoConfig, PpoConfigValidateError};
pub use evaluation::{EvalResult, evaluate, successes};
pub use gae::gae;
pub use loss::{LossParts, clipped_surrogate, normalize_advantages, ppo_loss};
pub use rollout::EpisodeStat;
pub use trainer::{IterStats, Trainer, TrainerBuildError};

pub use crate::random::{RngState, randn};
