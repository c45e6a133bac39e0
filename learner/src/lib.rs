//! Foresight's learner: PPO in tch on the twin (`twin` crate), pre-training, retraining on
//! failed scenes and export of the policy to the `PolicyBlob` that rt-core runs.
//!
//! # Map
//! Start with [`ppo::Trainer`] (one [`ppo::Trainer::iterate`] = one rollout + one update),
//! then [`run::train`] (the loop around it) and [`retrain::RetrainJob`] (one retraining on a
//! reported scene).
//!
//! - [`env`](mod@env): the environment interface ([`env::Env`], [`env::SceneSampler`]) and a toy task
//!   for tests; [`twin_env`]: the twin behind it and the scene distributions (pre-training
//!   curriculum, retraining around a reported scene);
//! - [`net`]: the Gaussian actor-critic (one flat parameter tensor);
//! - [`adam`]: Adam with saveable state; [`normalize`]: running observation/return
//!   statistics; [`random`]: seeded normal samples and saveable random-stream state;
//! - [`ppo`]: configuration, GAE, the loss pieces, threaded rollouts, the trainer and
//!   evaluation;
//! - [`run`]: a training run (periodic evaluation, checkpoints, metrics, stop rules);
//!   [`checkpoint`]: atomic one-file checkpoints; [`metrics`]: `metrics.csv` and the
//!   `reward.svg` curve, drawn by [`chart`];
//! - [`export`]: checkpoint → `PolicyBlob` and the blob file format;
//! - [`retrain`]: the retraining recipe ([`retrain::RetrainJob`], its settings and flags);
//!   [`service`]: the iceoryx2 node around it behind `learner serve`;
//!   [`demonstrations`]: the feasibility planner's path re-tracked into the task's actions
//!   (what a retraining imitates first, [`ppo::bc`]); [`distil`]: the planner distilled
//!   into the generalist by DAgger over a broad world mix (`learner distil`).
//!
//! The `learner` binary (`main.rs`, one module per subcommand under `cli/`) is a thin layer
//! over these modules.
//!
//! ```no_run
//! use learner::{env::{PointReach, PointScene}, ppo::{PpoConfig, Trainer}};
//! let mut t = Trainer::new(PpoConfig::default(), PointReach::default(), 1, tch::Device::Cpu).unwrap();
//! let stats = t.iterate(&PointScene::random);
//! println!("{} steps, mean return {}", stats.steps, stats.mean_return);
//! ```

pub mod adam;
pub mod chart;
pub mod checkpoint;
pub mod demonstrations;
pub mod distil;
pub mod env;
pub mod export;
pub mod metrics;
pub mod net;
pub mod normalize;
pub mod onnx;
pub mod ppo;
pub mod random;
pub mod retrain;
pub mod run;
pub mod service;
pub mod twin_env;

/// Logs of the learner's binaries (`learner`, `unseen-worlds`) to standard error, at the level
/// `RUST_LOG` names (`info` without it).
pub fn init_tracing() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
}
