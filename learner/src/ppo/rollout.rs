//! Rollout collection: the environments are split into chunks, one per worker thread, and
//! each thread runs its chunk for the whole rollout (scene sampling, normalisation, batched
//! policy forward pass on a read-only shallow copy of the network, Gaussian action noise,
//! reward scaling and the truncation bootstrap), so threads meet once per rollout. The
//! forward passes run on a host copy of the parameters ([`HostNet`]), taken once per rollout.
//!
//! [`collect`] is the entry point; [`ChunkBuf`] is what one worker hands back to the
//! trainer's update.

use rand_chacha::ChaCha8Rng;
use tch::{Device, Tensor};

use super::host_net::{ForwardWork, HostNet};

use crate::env::{Env, SceneSampler, StepInfo};
use crate::net::{ActorCritic, HALF_LOG_2PI};
use crate::normalize::ObsNormalizer;
use crate::random::randn;

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

/// One environment with its random stream and episode bookkeeping.
#[derive(Debug, Clone)]
pub(super) struct Slot<E> {
    pub(super) env: E,
    pub(super) rng: ChaCha8Rng,
    obs: Vec<f32>,
    needs_reset: bool,
    disc_ret: f64,
    ep: EpisodeStat,
}

impl<E: Env> Slot<E> {
    /// A slot whose first episode starts at the next rollout.
    pub(super) fn new(env: E, rng: ChaCha8Rng) -> Self {
        let obs = vec![0.0; env.obs_dim()];
        Self {
            env,
            rng,
            obs,
            needs_reset: true,
            disc_ret: 0.0,
            ep: EpisodeStat::default(),
        }
    }

    /// Abandons the episode in progress; the next rollout starts a new one.
    pub(super) fn restart(&mut self) {
        self.needs_reset = true;
        self.disc_ret = 0.0;
        self.ep = EpisodeStat::default();
    }
}

/// What one worker collected, time-major (`[n_steps][n]`).
#[derive(Default)]
pub(super) struct ChunkBuf {
    /// Environments in the chunk.
    pub(super) n: usize,
    /// Raw observations (for the observation statistics).
    pub(super) raw_obs: Vec<f32>,
    /// Normalised observations (the policy's inputs).
    pub(super) obs: Vec<f32>,
    /// Sampled (unclipped) actions.
    pub(super) actions: Vec<f32>,
    /// Their log-probabilities under the rollout policy.
    pub(super) logp: Vec<f32>,
    /// Values of the observations.
    pub(super) values: Vec<f32>,
    /// Scaled, clipped rewards (truncation bootstrap folded in).
    pub(super) rewards: Vec<f32>,
    /// Episode ended after this step.
    pub(super) ends: Vec<bool>,
    /// Values of the observations after the rollout.
    pub(super) last_values: Vec<f32>,
    /// Discounted raw returns so far (for the reward scale).
    pub(super) disc_returns: Vec<f32>,
    /// Episodes finished during the rollout.
    pub(super) episodes: Vec<EpisodeStat>,
}

impl ChunkBuf {
    fn with_capacity(n: usize, n_steps: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            n,
            raw_obs: Vec::with_capacity(n_steps * n * obs_dim),
            obs: Vec::with_capacity(n_steps * n * obs_dim),
            actions: Vec::with_capacity(n_steps * n * act_dim),
            logp: Vec::with_capacity(n_steps * n),
            values: Vec::with_capacity(n_steps * n),
            rewards: Vec::with_capacity(n_steps * n),
            ends: Vec::with_capacity(n_steps * n),
            ..Default::default()
        }
    }
}

/// What every worker of a rollout shares, read-only.
pub(super) struct RolloutParams<'a> {
    /// Observation normaliser in force.
    pub(super) norm: &'a ObsNormalizer,
    /// The policy's log standard deviation (host copy).
    pub(super) log_std: &'a [f32],
    /// Steps per environment.
    pub(super) n_steps: usize,
    /// Discount (for the discounted return and the truncation bootstrap).
    pub(super) gamma: f64,
    /// Reward scale (1 / std of the discounted return, or 1).
    pub(super) reward_scale: f32,
    /// Clip of scaled rewards.
    pub(super) clip_reward: f32,
}

/// Runs every slot for `p.n_steps` steps on `workers` threads (sharing one host snapshot of
/// `net`'s parameters); one buffer per chunk, in slot order.
pub(super) fn collect<E: Env, S: SceneSampler<E::Scene>>(
    slots: &mut [Slot<E>],
    net: &ActorCritic,
    sampler: &S,
    workers: usize,
    p: &RolloutParams<'_>,
) -> Vec<ChunkBuf> {
    let per = slots.len().div_ceil(workers.max(1)).max(1);
    let host = HostNet::of(net);
    let host = &host;
    std::thread::scope(|s| {
        let handles: Vec<_> = slots
            .chunks_mut(per)
            .map(|chunk| s.spawn(move || run_chunk(chunk, host, sampler, p)))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_default())
            .collect()
    })
}

/// Batched policy forward with tch on normalised observations `[n * obs_dim]`: returns action
/// means and (when `want_value`) values. Evaluations use it; rollouts use [`HostNet`] (tested
/// against it).
pub(super) fn forward(
    net: &ActorCritic,
    obs: &[f32],
    n: usize,
    want_value: bool,
) -> (Vec<f32>, Vec<f32>) {
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

/// The Gaussian exploration noise of one rollout: per-dimension std and the constant part
/// of the log-probability.
struct Noise {
    std: Vec<f32>,
    logp_const: f32,
}

impl Noise {
    fn new(log_std: &[f32]) -> Self {
        Self {
            std: log_std.iter().map(|l| l.exp()).collect(),
            logp_const: log_std.iter().map(|l| -l - HALF_LOG_2PI).sum(),
        }
    }

    /// Samples `act = mean + std · z` (and its clip to `[-1, 1]` into `clipped`); returns
    /// the log-probability of `act`.
    fn sample(
        &self,
        rng: &mut ChaCha8Rng,
        mean: &[f32],
        act: &mut [f32],
        clipped: &mut [f32],
    ) -> f32 {
        let mut lp = self.logp_const;
        for k in 0..act.len() {
            let z = randn(rng);
            act[k] = mean[k] + self.std[k] * z;
            clipped[k] = act[k].clamp(-1.0, 1.0);
            lp -= 0.5 * z * z;
        }
        lp
    }
}

fn run_chunk<E: Env, S: SceneSampler<E::Scene>>(
    chunk: &mut [Slot<E>],
    net: &HostNet,
    sampler: &S,
    p: &RolloutParams<'_>,
) -> ChunkBuf {
    let n = chunk.len();
    let d = net.spec.obs_dim;
    let a = net.spec.act_dim;
    let noise = Noise::new(p.log_std);
    let mut b = ChunkBuf::with_capacity(n, p.n_steps, d, a);
    let mut cur = vec![0.0f32; n * d];
    let mut act = vec![0.0f32; a];
    let mut clipped = vec![0.0f32; a];
    let mut work = ForwardWork::default();
    let mut mean = vec![0.0f32; n * a];
    let mut values = vec![0.0f32; n];
    let mut one = Bootstrap {
        obs: vec![0.0f32; d],
        mean: vec![0.0f32; a],
        work: ForwardWork::default(),
    };
    for _ in 0..p.n_steps {
        observe(chunk, sampler, p.norm, &mut cur, &mut b);
        b.obs.extend_from_slice(&cur);
        net.forward(&cur, n, &mut work, &mut mean, Some(&mut values));
        b.values.extend_from_slice(&values);
        for (e, slot) in chunk.iter_mut().enumerate() {
            let lp = noise.sample(
                &mut slot.rng,
                &mean[e * a..(e + 1) * a],
                &mut act,
                &mut clipped,
            );
            b.actions.extend_from_slice(&act);
            b.logp.push(lp);
            step_slot(slot, &clipped, net, &mut one, p, &mut b);
        }
    }
    // Values of the observations after the rollout (for episodes still running).
    for (e, slot) in chunk.iter().enumerate() {
        p.norm.apply(&slot.obs, &mut cur[e * d..(e + 1) * d]);
    }
    net.forward(&cur, n, &mut work, &mut mean, Some(&mut values));
    b.last_values = values;
    b
}

/// Buffers of the one-observation value pass of the truncation bootstrap.
struct Bootstrap {
    obs: Vec<f32>,
    mean: Vec<f32>,
    work: ForwardWork,
}

/// Starts new episodes where needed, records the raw observations and writes the normalised
/// ones into `cur` (`[n * obs_dim]`).
fn observe<E: Env, S: SceneSampler<E::Scene>>(
    chunk: &mut [Slot<E>],
    sampler: &S,
    norm: &ObsNormalizer,
    cur: &mut [f32],
    b: &mut ChunkBuf,
) {
    let d = cur.len() / chunk.len().max(1);
    for (e, slot) in chunk.iter_mut().enumerate() {
        if slot.needs_reset {
            let scene = sampler.sample(&mut slot.rng);
            slot.env.reset(&scene, &mut slot.obs);
            slot.restart();
            slot.needs_reset = false;
        }
        b.raw_obs.extend_from_slice(&slot.obs);
        norm.apply(&slot.obs, &mut cur[e * d..(e + 1) * d]);
    }
}

/// Steps one environment with `clipped` and records reward, end and episode statistics.
fn step_slot<E: Env>(
    slot: &mut Slot<E>,
    clipped: &[f32],
    net: &HostNet,
    one: &mut Bootstrap,
    p: &RolloutParams<'_>,
    b: &mut ChunkBuf,
) {
    let info: StepInfo = slot.env.step(clipped, &mut slot.obs);
    slot.ep.ret += f64::from(info.reward);
    slot.ep.len += 1;
    slot.ep.collision |= info.collision;
    slot.disc_ret = slot.disc_ret * p.gamma + f64::from(info.reward);
    b.disc_returns.push(slot.disc_ret as f32);
    let mut r = (info.reward * p.reward_scale).clamp(-p.clip_reward, p.clip_reward);
    let end = info.terminated || info.truncated;
    if info.truncated && !info.terminated {
        p.norm.apply(&slot.obs, &mut one.obs);
        let mut v = [0.0f32];
        net.forward(&one.obs, 1, &mut one.work, &mut one.mean, Some(&mut v));
        r += p.gamma as f32 * v[0];
    }
    b.rewards.push(r);
    b.ends.push(end);
    if end {
        slot.ep.success = info.success && !slot.ep.collision;
        b.episodes.push(slot.ep);
        slot.needs_reset = true;
    }
}
