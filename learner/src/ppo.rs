//! PPO (clipped surrogate, GAE(λ), value loss, entropy bonus, minibatch Adam, gradient-norm
//! clipping, running observation normalisation and return-based reward scaling) over a vector
//! of environments stepped on worker threads.
//!
//! # Threads
//! The environments are split into `workers` chunks; each rollout runs every chunk for the
//! whole rollout on its own scoped thread (policy forward pass included, on a read-only
//! shallow copy of the parameters), so threads meet once per rollout, not once per step.
//!
//! # Reproducibility
//! All sampling (scenes, action noise, minibatch shuffles) uses ChaCha8 streams derived from
//! the seed (one per environment, one for the trainer, one for the initial weights). On CPU with the same seed, `n_envs`, `workers` and torch thread
//! count, a run is bit-reproducible. Changing `workers` changes the batch shapes of the
//! forward passes and hence float rounding; on CUDA, kernels are not bit-reproducible.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::adam::{Adam, clip_grad_norm};
use crate::env::{Env, SceneSampler, StepInfo};
use crate::net::{ActorCritic, HALF_LOG_2PI, NetSpec};
use crate::normalize::{ObsNormalizer, RunningMeanStd};

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
    /// Epochs over each rollout (SB3: 10).
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
            n_epochs: 10,
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

impl PpoConfig {
    /// Checks ranges.
    ///
    /// # Errors
    /// A message naming the first bad value.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64, n: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{n} = {v} must be > 0"))
            }
        };
        if self.n_envs == 0 || self.n_steps == 0 || self.batch_size == 0 || self.n_epochs == 0 {
            return Err("n_envs, n_steps, batch_size and n_epochs must be ≥ 1".into());
        }
        pos(self.learning_rate, "learning_rate")?;
        pos(self.clip_range, "clip_range")?;
        pos(self.max_grad_norm, "max_grad_norm")?;
        if !(0.0..=1.0).contains(&self.gamma) || !(0.0..=1.0).contains(&self.gae_lambda) {
            return Err("gamma and gae_lambda must be in [0, 1]".into());
        }
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err("hidden must list at least one non-zero width".into());
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

/// Generalised advantage estimation over a time-major `[T][n_envs]` rollout.
///
/// `ends[i]` marks that the episode ended after step `i` (the next stored step belongs to a
/// new episode; a truncation's bootstrap value must already be folded into `rewards[i]`).
/// `last_values[e]` is the value of the observation following the rollout.
/// Returns `(advantages, returns)` with `returns = advantages + values`.
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    ends: &[bool],
    last_values: &[f32],
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let n = last_values.len();
    let len = rewards.len();
    let mut adv = vec![0.0f32; len];
    if n == 0 {
        return (adv, Vec::new());
    }
    let t_len = len / n;
    let mut running = vec![0.0f32; n];
    for t in (0..t_len).rev() {
        for e in 0..n {
            let i = t * n + e;
            let next_v = if t + 1 == t_len {
                last_values[e]
            } else {
                values[i + n]
            };
            let nonterminal = if ends[i] { 0.0 } else { 1.0 };
            let delta = rewards[i] + gamma * next_v * nonterminal - values[i];
            running[e] = delta + gamma * lambda * nonterminal * running[e];
            adv[i] = running[e];
        }
    }
    let ret = adv.iter().zip(values).map(|(a, v)| a + v).collect();
    (adv, ret)
}

/// The pieces of the PPO loss for one minibatch.
#[derive(Debug)]
pub struct LossParts {
    /// Clipped surrogate policy loss (to minimise).
    pub policy: Tensor,
    /// Mean squared value error.
    pub value: Tensor,
    /// Policy entropy.
    pub entropy: Tensor,
    /// `mean((r - 1) - ln r)`, the low-variance KL estimate.
    pub approx_kl: Tensor,
    /// Fraction of samples whose ratio was clipped.
    pub clip_fraction: Tensor,
}

/// Clipped surrogate `-mean(min(r A, clip(r, 1-ε, 1+ε) A))` with `r = exp(logp - logp_old)`,
/// plus the approximate KL and the clip fraction. `adv` is used as given.
pub fn clipped_surrogate(
    logp: &Tensor,
    logp_old: &Tensor,
    adv: &Tensor,
    clip: f64,
) -> (Tensor, Tensor, Tensor) {
    let log_ratio = logp - logp_old;
    let ratio = log_ratio.exp();
    let s1 = &ratio * adv;
    let s2 = ratio.clamp(1.0 - clip, 1.0 + clip) * adv;
    let loss = -s1.minimum(&s2).mean(Kind::Float);
    let kl = tch::no_grad(|| ((&ratio - 1.0) - &log_ratio).mean(Kind::Float));
    let cf = tch::no_grad(|| {
        (&ratio - 1.0)
            .abs()
            .gt(clip)
            .to_kind(Kind::Float)
            .mean(Kind::Float)
    });
    (loss, kl, cf)
}

/// Normalises advantages to zero mean and unit std (per minibatch, as SB3).
pub fn normalize_advantages(adv: &Tensor) -> Tensor {
    if adv.size()[0] < 2 {
        return adv.shallow_clone();
    }
    (adv - adv.mean(Kind::Float)) / (adv.std(true) + 1e-8)
}

/// Computes all loss pieces for one minibatch.
pub fn ppo_loss(
    net: &ActorCritic,
    obs: &Tensor,
    actions: &Tensor,
    logp_old: &Tensor,
    adv: &Tensor,
    returns: &Tensor,
    clip: f64,
) -> LossParts {
    let (logp, entropy) = net.log_prob_entropy(obs, actions);
    let adv = normalize_advantages(adv);
    let (policy, approx_kl, clip_fraction) = clipped_surrogate(&logp, logp_old, &adv, clip);
    let v = net.value(obs);
    let value = (returns - v).square().mean(Kind::Float);
    LossParts {
        policy,
        value,
        entropy,
        approx_kl,
        clip_fraction,
    }
}

/// Statistics of one finished episode.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EpisodeStat {
    /// Sum of raw rewards.
    pub ret: f64,
    /// Steps.
    pub len: u32,
    /// Ended in success without any contact.
    pub success: bool,
    /// Had a contact.
    pub collision: bool,
}

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

/// Result of a deterministic evaluation.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    /// Episodes run.
    pub episodes: usize,
    /// Fraction that succeeded with no contact.
    pub success_rate: f64,
    /// Fraction with a contact.
    pub collision_rate: f64,
    /// Mean raw return.
    pub mean_return: f64,
}

/// The state of a ChaCha8 stream, enough to continue it exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RngState {
    /// Seed.
    pub seed: [u8; 32],
    /// Stream.
    pub stream: u64,
    /// Word position (as two halves for JSON).
    pub word_pos: [u64; 2],
}

impl RngState {
    /// Captures `rng`.
    pub fn of(rng: &ChaCha8Rng) -> Self {
        let wp = rng.get_word_pos();
        Self {
            seed: rng.get_seed(),
            stream: rng.get_stream(),
            word_pos: [(wp >> 64) as u64, wp as u64],
        }
    }
    /// Recreates the stream.
    pub fn restore(&self) -> ChaCha8Rng {
        let mut r = ChaCha8Rng::from_seed(self.seed);
        r.set_stream(self.stream);
        r.set_word_pos((u128::from(self.word_pos[0]) << 64) | u128::from(self.word_pos[1]));
        r
    }
}

/// One environment with its random stream and episode bookkeeping.
#[derive(Debug, Clone)]
struct Slot<E> {
    env: E,
    rng: ChaCha8Rng,
    obs: Vec<f32>,
    needs_reset: bool,
    disc_ret: f64,
    ep: EpisodeStat,
}

/// What one worker collected.
#[derive(Default)]
struct ChunkBuf {
    n: usize,
    raw_obs: Vec<f32>,
    obs: Vec<f32>,
    actions: Vec<f32>,
    logp: Vec<f32>,
    values: Vec<f32>,
    rewards: Vec<f32>,
    ends: Vec<bool>,
    last_values: Vec<f32>,
    disc_returns: Vec<f32>,
    episodes: Vec<EpisodeStat>,
}

/// A standard normal sample (Box–Muller).
pub fn randn(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// Batched deterministic-or-sampled policy forward on normalised observations `[n * obs_dim]`:
/// returns action means and values.
fn forward(net: &ActorCritic, obs: &[f32], n: usize, want_value: bool) -> (Vec<f32>, Vec<f32>) {
    let dev = net.device();
    tch::no_grad(|| {
        let x = Tensor::from_slice(obs)
            .view([n as i64, net.spec.obs_dim as i64])
            .to_device(dev);
        let m = net.actor_mean(&x).to_device(Device::Cpu).contiguous();
        let mut mean = vec![0.0f32; n * net.spec.act_dim];
        m.copy_data(&mut mean, n * net.spec.act_dim);
        let mut val = Vec::new();
        if want_value {
            let v = net.value(&x).to_device(Device::Cpu).contiguous();
            val = vec![0.0f32; n];
            v.copy_data(&mut val, n);
        }
        (mean, val)
    })
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

impl<E: Env + Clone> Trainer<E> {
    /// A fresh trainer: network initialised from `seed`, environments cloned from `template`.
    ///
    /// # Errors
    /// The configuration's validation message.
    pub fn new(cfg: PpoConfig, template: E, seed: u64, device: Device) -> Result<Self, String> {
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
                Slot {
                    env: template.clone(),
                    rng,
                    obs: vec![0.0; obs_dim],
                    needs_reset: true,
                    disc_ret: 0.0,
                    ep: EpisodeStat::default(),
                }
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
            slot.needs_reset = true;
            slot.disc_ret = 0.0;
            slot.ep = EpisodeStat::default();
        }
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
        let workers = self.cfg.effective_workers();
        let per = self.slots.len().div_ceil(workers);
        let norm = self.obs_normalizer();
        let rscale = self.reward_scale();
        let clip_r = self.cfg.clip_reward;
        let gamma = self.cfg.gamma;
        let n_steps = self.cfg.n_steps;
        let log_std: Vec<f32> = {
            let t = self.net.log_std().detach().to_device(Device::Cpu);
            let n = self.net.spec.act_dim;
            let mut v = vec![0.0; n];
            t.copy_data(&mut v, n);
            v
        };
        let nets: Vec<ActorCritic> = self
            .slots
            .chunks(per)
            .map(|_| self.net.detached())
            .collect();
        let bufs: Vec<ChunkBuf> = std::thread::scope(|s| {
            let handles: Vec<_> = self
                .slots
                .chunks_mut(per)
                .zip(nets)
                .map(|(chunk, net)| {
                    let norm = &norm;
                    let log_std = &log_std;
                    s.spawn(move || {
                        run_chunk(
                            chunk, &net, norm, log_std, sampler, n_steps, gamma, rscale, clip_r,
                        )
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_default())
                .collect()
        });
        let total: usize = bufs.iter().map(|b| b.n * n_steps).sum();
        self.steps += total as u64;
        if self.cfg.update_stats {
            for b in &bufs {
                self.obs_rms.update(&b.raw_obs);
                self.ret_rms.update(&b.disc_returns);
            }
        }
        bufs
    }

    fn update(&mut self, bufs: &[ChunkBuf]) -> IterStats {
        let (g, l) = (self.cfg.gamma as f32, self.cfg.gae_lambda as f32);
        let d = self.net.spec.obs_dim;
        let a = self.net.spec.act_dim;
        let (mut obs, mut act, mut logp, mut adv, mut ret) =
            (vec![], vec![], vec![], vec![], vec![]);
        for b in bufs {
            if b.n == 0 {
                continue;
            }
            let (ad, re) = gae(&b.rewards, &b.values, &b.ends, &b.last_values, g, l);
            obs.extend_from_slice(&b.obs);
            act.extend_from_slice(&b.actions);
            logp.extend_from_slice(&b.logp);
            adv.extend(ad);
            ret.extend(re);
        }
        let n = logp.len();
        let dev = self.net.device();
        let obs_t = Tensor::from_slice(&obs)
            .view([n as i64, d as i64])
            .to_device(dev);
        let act_t = Tensor::from_slice(&act)
            .view([n as i64, a as i64])
            .to_device(dev);
        let logp_t = Tensor::from_slice(&logp).to_device(dev);
        let adv_t = Tensor::from_slice(&adv).to_device(dev);
        let ret_t = Tensor::from_slice(&ret).to_device(dev);
        let mut idx: Vec<i64> = (0..n as i64).collect();
        let mut st = IterStats::default();
        let mut count = 0.0;
        for _ in 0..self.cfg.n_epochs {
            // Fisher–Yates with the trainer's stream.
            for i in (1..idx.len()).rev() {
                let j = self.rng.random_range(0..=i);
                idx.swap(i, j);
            }
            for mb in idx.chunks(self.cfg.batch_size) {
                let it = Tensor::from_slice(mb).to_device(dev);
                let p = ppo_loss(
                    &self.net,
                    &obs_t.index_select(0, &it),
                    &act_t.index_select(0, &it),
                    &logp_t.index_select(0, &it),
                    &adv_t.index_select(0, &it),
                    &ret_t.index_select(0, &it),
                    self.cfg.clip_range,
                );
                let loss = &p.policy + &p.value * self.cfg.vf_coef - &p.entropy * self.cfg.ent_coef;
                self.net.theta.zero_grad();
                loss.backward();
                let grad = self.net.theta.grad();
                clip_grad_norm(&grad, self.cfg.max_grad_norm);
                self.adam.step(&self.net.theta, &grad);
                st.policy_loss += p.policy.double_value(&[]);
                st.value_loss += p.value.double_value(&[]);
                st.approx_kl += p.approx_kl.double_value(&[]);
                st.clip_fraction += p.clip_fraction.double_value(&[]);
                st.entropy = p.entropy.double_value(&[]);
                count += 1.0;
            }
        }
        st.policy_loss /= count;
        st.value_loss /= count;
        st.approx_kl /= count;
        st.clip_fraction /= count;
        self.iteration += 1;
        st
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

#[allow(clippy::too_many_arguments)]
fn run_chunk<E: Env, S: SceneSampler<E::Scene>>(
    chunk: &mut [Slot<E>],
    net: &ActorCritic,
    norm: &ObsNormalizer,
    log_std: &[f32],
    sampler: &S,
    n_steps: usize,
    gamma: f64,
    rscale: f32,
    clip_r: f32,
) -> ChunkBuf {
    let n = chunk.len();
    let d = net.spec.obs_dim;
    let a = net.spec.act_dim;
    let std: Vec<f32> = log_std.iter().map(|l| l.exp()).collect();
    let logp_const: f32 = log_std.iter().map(|l| -l - HALF_LOG_2PI).sum();
    let mut b = ChunkBuf {
        n,
        raw_obs: Vec::with_capacity(n_steps * n * d),
        obs: Vec::with_capacity(n_steps * n * d),
        actions: Vec::with_capacity(n_steps * n * a),
        logp: Vec::with_capacity(n_steps * n),
        values: Vec::with_capacity(n_steps * n),
        rewards: Vec::with_capacity(n_steps * n),
        ends: Vec::with_capacity(n_steps * n),
        ..Default::default()
    };
    let mut cur = vec![0.0f32; n * d];
    let mut act = vec![0.0f32; a];
    let mut clipped = vec![0.0f32; a];
    for _ in 0..n_steps {
        for (e, slot) in chunk.iter_mut().enumerate() {
            if slot.needs_reset {
                let scene = sampler.sample(&mut slot.rng);
                slot.env.reset(&scene, &mut slot.obs);
                slot.needs_reset = false;
                slot.ep = EpisodeStat::default();
                slot.disc_ret = 0.0;
            }
            b.raw_obs.extend_from_slice(&slot.obs);
            norm.apply(&slot.obs, &mut cur[e * d..(e + 1) * d]);
        }
        b.obs.extend_from_slice(&cur);
        let (mean, values) = forward(net, &cur, n, true);
        b.values.extend_from_slice(&values);
        for (e, slot) in chunk.iter_mut().enumerate() {
            let mut lp = logp_const;
            for k in 0..a {
                let z = randn(&mut slot.rng);
                act[k] = mean[e * a + k] + std[k] * z;
                clipped[k] = act[k].clamp(-1.0, 1.0);
                lp -= 0.5 * z * z;
            }
            b.actions.extend_from_slice(&act);
            b.logp.push(lp);
            let info: StepInfo = slot.env.step(&clipped, &mut slot.obs);
            slot.ep.ret += f64::from(info.reward);
            slot.ep.len += 1;
            slot.ep.collision |= info.collision;
            slot.disc_ret = slot.disc_ret * gamma + f64::from(info.reward);
            b.disc_returns.push(slot.disc_ret as f32);
            let mut r = (info.reward * rscale).clamp(-clip_r, clip_r);
            let end = info.terminated || info.truncated;
            if info.truncated && !info.terminated {
                let mut o = vec![0.0f32; d];
                norm.apply(&slot.obs, &mut o);
                let (_, v) = forward(net, &o, 1, true);
                r += gamma as f32 * v[0];
            }
            b.rewards.push(r);
            b.ends.push(end);
            if end {
                slot.ep.success = info.success && !slot.ep.collision;
                b.episodes.push(slot.ep);
                slot.needs_reset = true;
            }
        }
    }
    // Values of the observations after the rollout (for episodes still running).
    for (e, slot) in chunk.iter().enumerate() {
        norm.apply(&slot.obs, &mut cur[e * d..(e + 1) * d]);
    }
    let (_, last) = forward(net, &cur, n, true);
    b.last_values = last;
    b
}

/// Runs one deterministic episode (clipped mean action) per scene with `net` and reports
/// success/collision rates and the mean raw return. Episodes run batched on `workers` threads.
pub fn evaluate<E: Env + Clone>(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    template: &E,
    scenes: &[E::Scene],
    workers: usize,
) -> EvalResult {
    if scenes.is_empty() {
        return EvalResult::default();
    }
    let per = scenes.len().div_ceil(workers.max(1));
    let stats: Vec<EpisodeStat> = std::thread::scope(|s| {
        let hs: Vec<_> = scenes
            .chunks(per)
            .map(|chunk| {
                let net = net.detached();
                let tmpl = template.clone();
                s.spawn(move || eval_chunk(&net, norm, &tmpl, chunk))
            })
            .collect();
        hs.into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    });
    let n = stats.len().max(1) as f64;
    EvalResult {
        episodes: stats.len(),
        success_rate: stats.iter().filter(|e| e.success).count() as f64 / n,
        collision_rate: stats.iter().filter(|e| e.collision).count() as f64 / n,
        mean_return: stats.iter().map(|e| e.ret).sum::<f64>() / n,
    }
}

fn eval_chunk<E: Env + Clone>(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    template: &E,
    scenes: &[E::Scene],
) -> Vec<EpisodeStat> {
    let d = net.spec.obs_dim;
    let a = net.spec.act_dim;
    let n = scenes.len();
    let mut envs: Vec<E> = (0..n).map(|_| template.clone()).collect();
    let mut raw = vec![vec![0.0f32; d]; n];
    let mut stats = vec![EpisodeStat::default(); n];
    let mut live: Vec<usize> = (0..n).collect();
    for ((env, scene), o) in envs.iter_mut().zip(scenes).zip(raw.iter_mut()) {
        env.reset(scene, o);
    }
    let mut act = vec![0.0f32; a];
    while !live.is_empty() {
        let mut x = vec![0.0f32; live.len() * d];
        for (k, &i) in live.iter().enumerate() {
            norm.apply(&raw[i], &mut x[k * d..(k + 1) * d]);
        }
        let (mean, _) = forward(net, &x, live.len(), false);
        let mut still = Vec::with_capacity(live.len());
        for (k, &i) in live.iter().enumerate() {
            for j in 0..a {
                act[j] = mean[k * a + j].clamp(-1.0, 1.0);
            }
            let info = envs[i].step(&act, &mut raw[i]);
            let st = &mut stats[i];
            st.ret += f64::from(info.reward);
            st.len += 1;
            st.collision |= info.collision;
            if info.terminated || info.truncated {
                st.success = info.success && !st.collision;
            } else {
                still.push(i);
            }
        }
        live = still;
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::{PointReach, PointScene};

    #[test]
    fn gae_matches_a_hand_computed_case() {
        // One env, three steps, episode ends after step 1 (terminal), then a new one.
        let r = [1.0f32, 2.0, 3.0];
        let v = [0.5f32, 1.0, 1.5];
        let ends = [false, true, false];
        let (g, l) = (0.9f32, 0.8f32);
        let (adv, ret) = gae(&r, &v, &ends, &[2.0], g, l);
        // t=2: δ = 3 + 0.9*2 - 1.5 = 3.3, A = 3.3
        // t=1: δ = 2 + 0 - 1 = 1 (terminal), A = 1
        // t=0: δ = 1 + 0.9*1 - 0.5 = 1.4, A = 1.4 + 0.72*1 = 2.12
        let want = [2.12f32, 1.0, 3.3];
        for i in 0..3 {
            assert!((adv[i] - want[i]).abs() < 1e-5, "adv[{i}] = {}", adv[i]);
            assert!((ret[i] - (want[i] + v[i])).abs() < 1e-5);
        }
    }

    #[test]
    fn gae_keeps_environments_apart_in_time_major_layout() {
        // Two envs interleaved [t][e]; env 1 is the same as env 0 shifted by rewards.
        let r = [1.0f32, 0.0, 1.0, 0.0];
        let v = [0.0f32; 4];
        let (adv, _) = gae(&r, &v, &[false; 4], &[0.0, 0.0], 1.0, 1.0);
        assert_eq!(adv, vec![2.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn surrogate_clips_the_ratio_on_the_side_that_would_gain() {
        let adv = Tensor::from_slice(&[1.0f32, -1.0, 1.0]);
        let old = Tensor::from_slice(&[0.0f32, 0.0, 0.0]);
        // ratios e^0.5 ≈ 1.65 (A>0: clipped to 1.2), e^0.5 (A<0: unclipped, -1.65), 1.0
        let new = Tensor::from_slice(&[0.5f32, 0.5, 0.0]);
        let (loss, kl, cf) = clipped_surrogate(&new, &old, &adv, 0.2);
        let r = 0.5f64.exp();
        let want = -(1.2 - r + 1.0) / 3.0;
        assert!(
            (loss.double_value(&[]) - want).abs() < 1e-5,
            "{}",
            loss.double_value(&[])
        );
        let want_kl = 2.0 * ((r - 1.0) - 0.5) / 3.0;
        assert!((kl.double_value(&[]) - want_kl).abs() < 1e-5);
        assert!((cf.double_value(&[]) - 2.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn surrogate_gradient_vanishes_once_clipped() {
        let logp = Tensor::from_slice(&[0.5f32]).set_requires_grad(true);
        let (loss, _, _) = clipped_surrogate(
            &logp,
            &Tensor::from_slice(&[0.0f32]),
            &Tensor::from_slice(&[1.0f32]),
            0.2,
        );
        loss.backward();
        assert_eq!(logp.grad().double_value(&[0]), 0.0);
        let logp = Tensor::from_slice(&[0.1f32]).set_requires_grad(true);
        let (loss, _, _) = clipped_surrogate(
            &logp,
            &Tensor::from_slice(&[0.0f32]),
            &Tensor::from_slice(&[1.0f32]),
            0.2,
        );
        loss.backward();
        assert!((logp.grad().double_value(&[0]) + 0.1f64.exp()).abs() < 1e-5);
    }

    #[test]
    fn advantages_are_normalised_per_minibatch() {
        let a = normalize_advantages(&Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0]));
        assert!(a.mean(Kind::Float).double_value(&[]).abs() < 1e-6);
        assert!((a.std(true).double_value(&[]) - 1.0).abs() < 1e-4);
    }

    #[test]
    fn value_loss_is_the_mean_squared_error() {
        let net = ActorCritic::new(
            NetSpec {
                obs_dim: 2,
                act_dim: 1,
                hidden: vec![4],
            },
            Device::Cpu,
            0,
        );
        let obs = Tensor::from_slice(&[0.1f32, 0.2, -0.3, 0.4]).view([2, 2]);
        let v = net.value(&obs).detach();
        let ret = &v + Tensor::from_slice(&[1.0f32, -3.0]);
        let act = Tensor::zeros([2, 1], (Kind::Float, Device::Cpu));
        let lp = net.log_prob_entropy(&obs, &act).0.detach();
        let p = ppo_loss(
            &net,
            &obs,
            &act,
            &lp,
            &Tensor::from_slice(&[1.0f32, -1.0]),
            &ret,
            0.2,
        );
        assert!((p.value.double_value(&[]) - 5.0).abs() < 1e-5);
        // ratio 1 everywhere: loss = -mean(normalised adv) = 0, KL 0.
        assert!(p.policy.double_value(&[]).abs() < 1e-6);
        assert!(p.approx_kl.double_value(&[]).abs() < 1e-7);
    }

    #[test]
    fn rng_state_round_trips_mid_stream() {
        let mut r = ChaCha8Rng::seed_from_u64(9);
        r.set_stream(4);
        let _: u64 = r.random();
        let _: u32 = r.random();
        let st = RngState::of(&r);
        let mut back = st.restore();
        for _ in 0..10 {
            assert_eq!(r.random::<u64>(), back.random::<u64>());
        }
    }

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
