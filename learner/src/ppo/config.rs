//! PPO hyper-parameters ([`PpoConfig`], defaults after SB3 with the deviations documented on
//! each field) and their validation ([`PpoConfigValidateError`]).

use serde::{Deserialize, Serialize};

/// PPO hyper-parameters. Defaults follow SB3's PPO except where noted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PpoConfig {
    /// Parallel environments. SB3: 1 (per `n_steps` 2048). Here 64 × 32 = 2048 samples per
    /// rollout, the same rollout size, but the policy forward pass is batched over 64 envs.
    pub n_envs: usize,
    /// Steps per environment per rollout.
    pub n_steps: usize,
    /// Minibatch size. SB3: 64. Here 512: 4 minibatches per epoch instead of 32 — each
    /// gradient step costs about the same at 64 or 512 rows on a CPU, so this is ~8× less
    /// update time; the learning rate is kept.
    pub batch_size: usize,
    /// Epochs over each rollout (SB3: 10). Here 5 (since 2026-11-27): measured on `[world]`
    /// pre-training (`--hidden 128,128`, seeds 1–3, 1.2e6 steps), 5 epochs reach the same
    /// success as 10 from 6e5 steps on (92 / 94 / 94 / 96 % against 93 / 94 / 93 / 94 % at
    /// 6e5 / 8e5 / 1e6 / 1.2e6, means of the 3 seeds) in 13–14.5 s of wall time instead of
    /// 21–25 s; below 6e5 steps 10 epochs learn more per step (70 % against 58 % at 2e5), so
    /// to the same success 5 epochs take ~35 % less time (learner README, "Throughput").
    pub n_epochs: usize,
    /// Adam learning rate (SB3: 3e-4).
    pub learning_rate: f64,
    /// Discount (SB3: 0.99).
    pub gamma: f64,
    /// GAE λ (SB3: 0.95).
    pub gae_lambda: f64,
    /// Surrogate clip range (SB3: 0.2).
    pub clip_range: f64,
    /// Entropy bonus coefficient (SB3: 0.0).
    pub ent_coef: f64,
    /// Value-loss coefficient (SB3: 0.5).
    pub vf_coef: f64,
    /// Gradient-norm clip (SB3: 0.5).
    pub max_grad_norm: f64,
    /// Normalise observations with running statistics (SB3 `VecNormalize`).
    pub norm_obs: bool,
    /// Scale rewards by the running std of the discounted return (SB3 `VecNormalize`).
    pub norm_reward: bool,
    /// Clip of normalised observations (SB3: 10).
    pub clip_obs: f32,
    /// Clip of scaled rewards (SB3: 10).
    pub clip_reward: f32,
    /// Hidden layer widths of actor and critic (SB3: [64, 64]).
    pub hidden: Vec<usize>,
    /// Rollout worker threads (0: one per available core, at most `n_envs`).
    pub workers: usize,
    /// Keep updating the observation and return statistics (off: frozen, e.g. while
    /// retraining, so the inputs the pre-trained network knows keep their meaning).
    pub update_stats: bool,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            n_envs: 64,
            n_steps: 32,
            batch_size: 512,
            n_epochs: 5,
            learning_rate: 3e-4,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip_range: 0.2,
            ent_coef: 0.0,
            vf_coef: 0.5,
            max_grad_norm: 0.5,
            norm_obs: true,
            norm_reward: true,
            clip_obs: 10.0,
            clip_reward: 10.0,
            hidden: vec![64, 64],
            workers: 0,
            update_stats: true,
        }
    }
}

/// Why a [`PpoConfig`] is rejected by [`PpoConfig::validate`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PpoConfigValidateError {
    /// A count (`n_envs`, `n_steps`, `batch_size`, `n_epochs`) is zero.
    #[error("{field} = 0 must be ≥ 1")]
    ZeroCount {
        /// The field.
        field: &'static str,
    },
    /// A rate or limit (`learning_rate`, `clip_range`, `max_grad_norm`) is not a positive
    /// finite number.
    #[error("{field} = {value} must be > 0")]
    NotPositive {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// A discount factor (`gamma`, `gae_lambda`) is outside `[0, 1]`.
    #[error("{field} = {value} must be in [0, 1]")]
    NotUnitInterval {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// `hidden` is empty or lists a zero width.
    #[error("hidden = {hidden:?} must list at least one non-zero width")]
    Hidden {
        /// The value.
        hidden: Vec<usize>,
    },
}

impl PpoConfig {
    /// Checks ranges.
    ///
    /// # Errors
    /// [`PpoConfigValidateError`] naming the first bad field.
    pub fn validate(&self) -> Result<(), PpoConfigValidateError> {
        use PpoConfigValidateError as E;
        let counts = [
            ("n_envs", self.n_envs),
            ("n_steps", self.n_steps),
            ("batch_size", self.batch_size),
            ("n_epochs", self.n_epochs),
        ];
        if let Some(&(field, _)) = counts.iter().find(|(_, v)| *v == 0) {
            return Err(E::ZeroCount { field });
        }
        let positive = [
            ("learning_rate", self.learning_rate),
            ("clip_range", self.clip_range),
            ("max_grad_norm", self.max_grad_norm),
        ];
        if let Some(&(field, value)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            return Err(E::NotPositive { field, value });
        }
        let unit = [("gamma", self.gamma), ("gae_lambda", self.gae_lambda)];
        if let Some(&(field, value)) = unit.iter().find(|(_, v)| !(0.0..=1.0).contains(v)) {
            return Err(E::NotUnitInterval { field, value });
        }
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err(E::Hidden {
                hidden: self.hidden.clone(),
            });
        }
        Ok(())
    }

    /// Worker threads actually used.
    pub fn effective_workers(&self) -> usize {
        let w = if self.workers == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            self.workers
        };
        w.clamp(1, self.n_envs.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_bad_field() {
        assert_eq!(PpoConfig::default().validate(), Ok(()));
        let bad = |f: fn(&mut PpoConfig)| {
            let mut c = PpoConfig::default();
            f(&mut c);
            c.validate().unwrap_err().to_string()
        };
        assert_eq!(bad(|c| c.batch_size = 0), "batch_size = 0 must be ≥ 1");
        assert_eq!(
            bad(|c| c.clip_range = -0.1),
            "clip_range = -0.1 must be > 0"
        );
        assert_eq!(
            bad(|c| c.learning_rate = f64::NAN),
            "learning_rate = NaN must be > 0"
        );
        assert_eq!(
            bad(|c| c.gae_lambda = 1.5),
            "gae_lambda = 1.5 must be in [0, 1]"
        );
        assert_eq!(
            bad(|c| c.hidden = vec![64, 0]),
            "hidden = [64, 0] must list at least one non-zero width"
        );
    }
}
