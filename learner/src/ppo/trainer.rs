//! The PPO trainer ([`Trainer`]): network, optimiser, normalisation statistics and the
//! environment slots; [`Trainer::iterate`] collects one rollout (see [`super::rollout`]),
//! computes GAE and runs the minibatch epochs of the clipped-surrogate update.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use tch::{Device, Tensor};

use super::config::{PpoConfig, PpoConfigValidateError};
use super::evaluation::{EvalResult, evaluate};
use super::gae::gae;
use super::host_net::{AdamCfg, HostUpdate, LossCfg};
use super::loss::{LossParts, ppo_loss};
use super::rollout::{ChunkBuf, EpisodeStat, RolloutParams, Slot, collect};
use crate::adam::{Adam, clip_grad_norm};
use crate::env::{Env, SceneSampler};
use crate::net::{ActorCritic, NetSpec};
use crate::normalize::{ObsNormalizer, RunningMeanStd};
use crate::random::RngState;

/// What one iteration (rollout + update) measured.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct IterStats {
    /// Environment steps so far (after this iteration).
    pub steps: u64,
    /// Iterations so far.
    pub iteration: u64,
    /// Episodes finished in this rollout.
    pub episodes: usize,
    /// Mean raw return of those episodes (NaN if none).
    pub mean_return: f64,
    /// Success rate of those episodes.
    pub success_rate: f64,
    /// Collision rate of those episodes.
    pub collision_rate: f64,
    /// Mean policy loss over minibatches.
    pub policy_loss: f64,
    /// Mean value loss over minibatches.
    pub value_loss: f64,
    /// Policy entropy (last minibatch).
    pub entropy: f64,
    /// Mean approximate KL over minibatches.
    pub approx_kl: f64,
    /// Mean clip fraction.
    pub clip_fraction: f64,
    /// Rollout wall time (s).
    pub rollout_s: f64,
    /// Update wall time (s).
    pub update_s: f64,
}

/// Why [`Trainer::new`] refused to build a trainer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrainerBuildError {
    /// The PPO configuration is invalid.
    #[error("PPO configuration")]
    Config(#[from] PpoConfigValidateError),
}

/// The PPO trainer: networks, optimiser, normalisation statistics and environments.
pub struct Trainer<E: Env + Clone> {
    /// Hyper-parameters.
    pub cfg: PpoConfig,
    /// The actor-critic.
    pub net: ActorCritic,
    /// The optimiser.
    pub adam: Adam,
    /// Observation statistics.
    pub obs_rms: RunningMeanStd,
    /// Discounted-return statistics (reward scaling).
    pub ret_rms: RunningMeanStd,
    /// Environment steps taken.
    pub steps: u64,
    /// Iterations done.
    pub iteration: u64,
    /// Stream for minibatch shuffles.
    pub rng: ChaCha8Rng,
    slots: Vec<Slot<E>>,
    template: E,
}

/// One rollout flattened into host vectors (row-major), after GAE.
#[derive(Default)]
struct HostBatch {
    obs: Vec<f32>,
    actions: Vec<f32>,
    logp: Vec<f32>,
    adv: Vec<f32>,
    returns: Vec<f32>,
}

/// A host tensor's values (a flat `f32` tensor on any device).
fn to_host(t: &Tensor) -> Vec<f32> {
    let t = t.detach().to_device(Device::Cpu).contiguous();
    let n = t.numel();
    let mut v = vec![0.0f32; n];
    t.copy_data(&mut v, n);
    v
}

/// One rollout flattened into tensors on the network's device, ready for minibatches.
struct Batch {
    obs: Tensor,
    actions: Tensor,
    logp: Tensor,
    adv: Tensor,
    returns: Tensor,
    len: usize,
}

impl<E: Env + Clone> Trainer<E> {
    /// A fresh trainer: network initialised from `seed`, environments cloned from `template`.
    ///
    /// # Errors
    /// [`TrainerBuildError::Config`] when the configuration does not validate.
    pub fn new(
        cfg: PpoConfig,
        template: E,
        seed: u64,
        device: Device,
    ) -> Result<Self, TrainerBuildError> {
        cfg.validate()?;
        let spec = NetSpec {
            obs_dim: template.obs_dim(),
            act_dim: template.act_dim(),
            hidden: cfg.hidden.clone(),
        };
        let net = ActorCritic::new(spec, device, seed);
        let adam = Adam::new(&net.theta, cfg.learning_rate);
        let obs_dim = template.obs_dim();
        let slots = (0..cfg.n_envs)
            .map(|e| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(e as u64 + 1);
                Slot::new(template.clone(), rng)
            })
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(0);
        Ok(Self {
            obs_rms: RunningMeanStd::new(obs_dim),
            ret_rms: RunningMeanStd::new(1),
            cfg,
            net,
            adam,
            steps: 0,
            iteration: 0,
            rng,
            slots,
            template,
        })
    }

    /// The random-stream states of the environments (for checkpoints).
    pub fn env_rng_states(&self) -> Vec<RngState> {
        self.slots.iter().map(|s| RngState::of(&s.rng)).collect()
    }

    /// Restores environment random streams and starts fresh episodes everywhere.
    pub fn restore_env_rngs(&mut self, states: &[RngState]) {
        for (slot, st) in self.slots.iter_mut().zip(states) {
            slot.rng = st.restore();
        }
        self.restart_episodes();
    }

    /// Abandons the episodes in progress (e.g. when the scene distribution changes).
    pub fn restart_episodes(&mut self) {
        for slot in &mut self.slots {
            slot.restart();
        }
    }

    /// The environment the episodes are cloned from.
    pub fn template(&self) -> &E {
        &self.template
    }

    /// The frozen observation normaliser in force.
    pub fn obs_normalizer(&self) -> ObsNormalizer {
        if self.cfg.norm_obs {
            ObsNormalizer::from_stats(&self.obs_rms, self.cfg.clip_obs)
        } else {
            let d = self.obs_rms.dim();
            ObsNormalizer {
                mean: vec![0.0; d],
                inv_std: vec![1.0; d],
                clip: f32::MAX,
            }
        }
    }

    fn reward_scale(&self) -> f32 {
        if self.cfg.norm_reward {
            (1.0 / (self.ret_rms.var[0] + 1e-8).sqrt()) as f32
        } else {
            1.0
        }
    }

    /// Collects one rollout and runs the PPO update on it.
    pub fn iterate<S: SceneSampler<E::Scene>>(&mut self, sampler: &S) -> IterStats {
        let t0 = Instant::now();
        let bufs = self.rollout(sampler);
        let rollout_s = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let mut stats = self.update(&bufs);
        stats.update_s = t1.elapsed().as_secs_f64();
        stats.rollout_s = rollout_s;
        let eps: Vec<&EpisodeStat> = bufs.iter().flat_map(|b| b.episodes.iter()).collect();
        stats.episodes = eps.len();
        let n = eps.len().max(1) as f64;
        stats.mean_return = if eps.is_empty() {
            f64::NAN
        } else {
            eps.iter().map(|e| e.ret).sum::<f64>() / n
        };
        stats.success_rate = eps.iter().filter(|e| e.success).count() as f64 / n;
        stats.collision_rate = eps.iter().filter(|e| e.collision).count() as f64 / n;
        stats.steps = self.steps;
        stats.iteration = self.iteration;
        stats
    }

    fn rollout<S: SceneSampler<E::Scene>>(&mut self, sampler: &S) -> Vec<ChunkBuf> {
        let norm = self.obs_normalizer();
        let log_std: Vec<f32> = {
            let t = self.net.log_std().detach().to_device(Device::Cpu);
            let n = self.net.spec.act_dim;
            let mut v = vec![0.0; n];
            t.copy_data(&mut v, n);
            v
        };
        let params = RolloutParams {
            norm: &norm,
            log_std: &log_std,
            n_steps: self.cfg.n_steps,
            gamma: self.cfg.gamma,
            reward_scale: self.reward_scale(),
            clip_reward: self.cfg.clip_reward,
        };
        let workers = self.cfg.effective_workers();
        let bufs = collect(&mut self.slots, &self.net, sampler, workers, &params);
        let total: usize = bufs.iter().map(|b| b.n * self.cfg.n_steps).sum();
        self.steps += total as u64;
        if self.cfg.update_stats {
            for b in &bufs {
                self.obs_rms.update(&b.raw_obs);
                self.ret_rms.update(&b.disc_returns);
            }
        }
        bufs
    }

    /// GAE per chunk, then everything concatenated (row-major host vectors).
    fn host_batch(&self, bufs: &[ChunkBuf]) -> HostBatch {
        let (g, l) = (self.cfg.gamma as f32, self.cfg.gae_lambda as f32);
        let mut hb = HostBatch::default();
        for b in bufs {
            if b.n == 0 {
                continue;
            }
            let (ad, re) = gae(&b.rewards, &b.values, &b.ends, &b.last_values, g, l);
            hb.obs.extend_from_slice(&b.obs);
            hb.actions.extend_from_slice(&b.actions);
            hb.logp.extend_from_slice(&b.logp);
            hb.adv.extend(ad);
            hb.returns.extend(re);
        }
        hb
    }

    /// The host batch as tensors on the network's device (the tch update path).
    fn batch(&self, hb: &HostBatch) -> Batch {
        let d = self.net.spec.obs_dim;
        let a = self.net.spec.act_dim;
        let n = hb.logp.len();
        let dev = self.net.device();
        Batch {
            obs: Tensor::from_slice(&hb.obs)
                .view([n as i64, d as i64])
                .to_device(dev),
            actions: Tensor::from_slice(&hb.actions)
                .view([n as i64, a as i64])
                .to_device(dev),
            logp: Tensor::from_slice(&hb.logp).to_device(dev),
            adv: Tensor::from_slice(&hb.adv).to_device(dev),
            returns: Tensor::from_slice(&hb.returns).to_device(dev),
            len: n,
        }
    }

    fn update(&mut self, bufs: &[ChunkBuf]) -> IterStats {
        let hb = self.host_batch(bufs);
        let host = if self.net.device() == Device::Cpu {
            HostUpdate::new(
                self.net.spec.clone(),
                self.net.flat(),
                to_host(&self.adam.m),
                to_host(&self.adam.v),
                self.adam.t,
                self.cfg.effective_workers(),
            )
        } else {
            None
        };
        let mut st = match host {
            Some(h) => self.update_host(&hb, h),
            None => self.update_tch(&hb),
        };
        let count = (self.cfg.n_epochs * hb.logp.len().div_ceil(self.cfg.batch_size)).max(1) as f64;
        st.policy_loss /= count;
        st.value_loss /= count;
        st.approx_kl /= count;
        st.clip_fraction /= count;
        self.iteration += 1;
        st
    }

    /// The minibatch order of one epoch: a Fisher–Yates shuffle with the trainer's stream.
    fn shuffle(&mut self, idx: &mut [i64]) {
        for i in (1..idx.len()).rev() {
            let j = self.rng.random_range(0..=i);
            idx.swap(i, j);
        }
    }

    /// The update on host buffers ([`HostUpdate`]); the parameters and Adam moments are
    /// copied back into the tensors at the end. Loss sums are not yet averaged.
    fn update_host(&mut self, hb: &HostBatch, mut h: HostUpdate) -> IterStats {
        let mut idx: Vec<i64> = (0..hb.logp.len() as i64).collect();
        let mut st = IterStats::default();
        let loss_cfg = LossCfg {
            clip: self.cfg.clip_range as f32,
            vf_coef: self.cfg.vf_coef as f32,
            ent_coef: self.cfg.ent_coef as f32,
        };
        let adam_cfg = AdamCfg {
            lr: self.adam.lr,
            beta1: self.adam.beta1,
            beta2: self.adam.beta2,
            eps: self.adam.eps,
            max_grad_norm: self.cfg.max_grad_norm,
        };
        for _ in 0..self.cfg.n_epochs {
            self.shuffle(&mut idx);
            for mb in idx.chunks(self.cfg.batch_size) {
                h.load(&hb.obs, &hb.actions, &hb.logp, &hb.adv, &hb.returns, mb);
                let r = h.gradient(loss_cfg);
                h.apply(adam_cfg);
                st.policy_loss += r.policy;
                st.value_loss += r.value;
                st.approx_kl += r.approx_kl;
                st.clip_fraction += r.clip_fraction;
                st.entropy = r.entropy;
            }
        }
        tch::no_grad(|| {
            self.net.theta.copy_(&Tensor::from_slice(h.theta()));
            self.adam.m.copy_(&Tensor::from_slice(&h.m));
            self.adam.v.copy_(&Tensor::from_slice(&h.v));
        });
        self.adam.t = h.t;
        st
    }

    /// The update with tch autograd (other devices than the CPU). Loss sums are not yet
    /// averaged.
    fn update_tch(&mut self, hb: &HostBatch) -> IterStats {
        let batch = self.batch(hb);
        let mut idx: Vec<i64> = (0..batch.len as i64).collect();
        let mut st = IterStats::default();
        for _ in 0..self.cfg.n_epochs {
            self.shuffle(&mut idx);
            for mb in idx.chunks(self.cfg.batch_size) {
                let p = self.minibatch_step(&batch, mb);
                st.policy_loss += p.policy.double_value(&[]);
                st.value_loss += p.value.double_value(&[]);
                st.approx_kl += p.approx_kl.double_value(&[]);
                st.clip_fraction += p.clip_fraction.double_value(&[]);
                st.entropy = p.entropy.double_value(&[]);
            }
        }
        st
    }

    /// One gradient step on the rows `mb` of `batch`; returns the loss pieces.
    fn minibatch_step(&mut self, batch: &Batch, mb: &[i64]) -> LossParts {
        let it = Tensor::from_slice(mb).to_device(self.net.device());
        let p = ppo_loss(
            &self.net,
            &batch.obs.index_select(0, &it),
            &batch.actions.index_select(0, &it),
            &batch.logp.index_select(0, &it),
            &batch.adv.index_select(0, &it),
            &batch.returns.index_select(0, &it),
            self.cfg.clip_range,
        );
        let loss = &p.policy + &p.value * self.cfg.vf_coef - &p.entropy * self.cfg.ent_coef;
        self.net.theta.zero_grad();
        loss.backward();
        let grad = self.net.theta.grad();
        clip_grad_norm(&grad, self.cfg.max_grad_norm);
        self.adam.step(&self.net.theta, &grad);
        p
    }

    /// Runs one deterministic episode (mean action) per scene and reports rates.
    pub fn evaluate(&self, scenes: &[E::Scene]) -> EvalResult {
        evaluate(
            &self.net,
            &self.obs_normalizer(),
            &self.template,
            scenes,
            self.cfg.effective_workers(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::{PointReach, PointScene};

    fn small_cfg(workers: usize) -> PpoConfig {
        PpoConfig {
            n_envs: 8,
            n_steps: 64,
            batch_size: 128,
            workers,
            ..Default::default()
        }
    }

    #[test]
    fn training_is_reproducible_for_a_seed() {
        let run = || {
            let mut t = Trainer::new(small_cfg(2), PointReach::default(), 11, Device::Cpu).unwrap();
            for _ in 0..3 {
                t.iterate(&PointScene::random);
            }
            t.net.flat()
        };
        let (a, b) = (run(), run());
        assert!(a == b, "two runs with one seed differ");
    }

    #[test]
    fn short_training_improves_the_point_reach_task() {
        let mut rng = ChaCha8Rng::seed_from_u64(1234);
        let scenes: Vec<PointScene> = (0..64).map(|_| PointScene::random(&mut rng)).collect();
        let mut t = Trainer::new(small_cfg(2), PointReach::default(), 5, Device::Cpu).unwrap();
        let before = t.evaluate(&scenes);
        for _ in 0..40 {
            t.iterate(&PointScene::random);
        }
        let after = t.evaluate(&scenes);
        assert!(
            after.mean_return > before.mean_return + 5.0
                && after.success_rate > before.success_rate + 0.15,
            "before {before:?} after {after:?}"
        );
        assert_eq!(t.steps, 40 * 8 * 64);
    }
}
