//! Deterministic evaluation: one episode per scene with the clipped mean action, batched
//! over the live episodes and split over worker threads; reports success and collision
//! rates and the mean raw return ([`EvalResult`]). An episode succeeds when it reaches the
//! goal with no contact and the environment approves it ([`Env::approve_episode`]: for the
//! twin, rt-core's verification of the smoothed plan).

use serde::{Deserialize, Serialize};

use super::rollout::{EpisodeStat, forward};
use crate::env::Env;
use crate::net::ActorCritic;
use crate::normalize::ObsNormalizer;

/// Result of a deterministic evaluation.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    /// Episodes run.
    pub episodes: usize,
    /// Fraction that succeeded with no contact and was approved ([`Env::approve_episode`]).
    pub success_rate: f64,
    /// Fraction with a contact.
    pub collision_rate: f64,
    /// Mean raw return.
    pub mean_return: f64,
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
    let stats = episode_stats(net, norm, template, scenes, workers);
    let n = stats.len().max(1) as f64;
    EvalResult {
        episodes: stats.len(),
        success_rate: stats.iter().filter(|e| e.success).count() as f64 / n,
        collision_rate: stats.iter().filter(|e| e.collision).count() as f64 / n,
        mean_return: stats.iter().map(|e| e.ret).sum::<f64>() / n,
    }
}

/// Like [`evaluate`], but whether each scene's episode succeeded with no contact, in the
/// order of `scenes` (to combine policies scene by scene, as the lookahead's policy library
/// does).
pub fn successes<E: Env + Clone>(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    template: &E,
    scenes: &[E::Scene],
    workers: usize,
) -> Vec<bool> {
    if scenes.is_empty() {
        return Vec::new();
    }
    episode_stats(net, norm, template, scenes, workers)
        .iter()
        .map(|e| e.success)
        .collect()
}

/// One episode per scene, in the order of `scenes` (chunks joined in order).
fn episode_stats<E: Env + Clone>(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    template: &E,
    scenes: &[E::Scene],
    workers: usize,
) -> Vec<EpisodeStat> {
    let per = scenes.len().div_ceil(workers.max(1));
    std::thread::scope(|s| {
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
    })
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
                // A success is an episode rt-core would approve (the smoothed path checked
                // by the shield on every sample), not only one that reached the goal.
                st.success = info.success && !st.collision && envs[i].approve_episode();
            } else {
                still.push(i);
            }
        }
        live = still;
    }
    stats
}
