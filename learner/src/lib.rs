//! Foresight's learner: PPO in tch on the rt-core twin.
//!
//! - [`env`]: the environment interface ([`env::Env`]) and a toy task for tests;
//! - [`net`]: the Gaussian actor-critic (one flat parameter tensor);
//! - [`adam`]: Adam with saveable state;
//! - [`normalize`]: running observation/return statistics;
//! - [`ppo`]: GAE, the loss pieces, the vectorised trainer and evaluation.
//!
//! ```no_run
//! use learner::{env::{PointReach, PointScene}, ppo::{PpoConfig, Trainer}};
//! let mut t = Trainer::new(PpoConfig::default(), PointReach::default(), 1, tch::Device::Cpu).unwrap();
//! let stats = t.iterate(&PointScene::random);
//! println!("{} steps, mean return {}", stats.steps, stats.mean_return);
//! ```

pub mod adam;
pub mod checkpoint;
pub mod env;
pub mod export;
pub mod metrics;
pub mod net;
pub mod normalize;
pub mod ppo;
pub mod run;
pub mod service;
pub mod twin_env;
