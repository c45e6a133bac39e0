//! Behaviour cloning: a warm start of the actor on (observation, action) pairs before PPO
//! fine-tunes it — the planner's demonstrations ([`crate::demonstrations`]) mixed with
//! *anchor* pairs, the base policy's own mean actions along its own episodes on scenes it
//! already solves, so that imitating the new way does not overwrite the old skill.
//!
//! The loss is the mean squared error between the actor's mean action (of the normalised
//! observation, as the rollout and the exported policy see it) and the target action. Only
//! the actor mean gets a gradient (the critic and the log-std are not in the graph). A
//! fresh [`Adam`] is used, so PPO's optimiser state is left as it was.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use tch::{Kind, Tensor};

use crate::adam::{Adam, clip_grad_norm};
use crate::env::Env;
use crate::net::ActorCritic;
use crate::normalize::ObsNormalizer;

/// (observation, action) pairs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BcSet {
    /// Raw observations, `len × obs_dim`.
    pub obs: Vec<f32>,
    /// Target actions, `len × act_dim`.
    pub actions: Vec<f32>,
}

impl BcSet {
    /// Pairs in the set for an observation length `obs_dim`.
    pub fn len(&self, obs_dim: usize) -> usize {
        self.obs.len() / obs_dim.max(1)
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.obs.is_empty()
    }

    /// Appends `obs` (raw) and `actions`.
    pub fn extend(&mut self, obs: &[f32], actions: &[f32]) {
        self.obs.extend_from_slice(obs);
        self.actions.extend_from_slice(actions);
    }
}

/// Settings of [`behaviour_clone`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BcConfig {
    /// Gradient steps.
    pub steps: usize,
    /// Rows per step.
    pub batch: usize,
    /// Learning rate.
    pub lr: f64,
    /// Share of each batch drawn from the demonstrations (the rest from the anchors; all
    /// from the demonstrations when there are no anchors).
    pub demo_share: f64,
    /// Gradient-norm clip.
    pub max_grad_norm: f64,
}

impl Default for BcConfig {
    /// 300 steps of 256 rows, lr 1e-3, half demonstrations, clip 1.
    fn default() -> Self {
        Self {
            steps: 300,
            batch: 256,
            lr: 1e-3,
            demo_share: 0.5,
            max_grad_norm: 1.0,
        }
    }
}

/// What [`behaviour_clone`] achieved: imitation losses (MSE) before and after.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct BcReport {
    /// Demonstration pairs.
    pub demo_pairs: usize,
    /// Anchor pairs.
    pub anchor_pairs: usize,
    /// Loss on the demonstrations before.
    pub demo_loss_before: f64,
    /// Loss on the demonstrations after.
    pub demo_loss_after: f64,
    /// Loss on the anchors before.
    pub anchor_loss_before: f64,
    /// Loss on the anchors after.
    pub anchor_loss_after: f64,
    /// Gradient steps taken.
    pub steps: usize,
}

/// The set's normalised observations `[n, obs_dim]` and actions `[n, act_dim]` on the
/// network's device.
fn tensors(net: &ActorCritic, norm: &ObsNormalizer, set: &BcSet) -> (Tensor, Tensor) {
    let d = net.spec.obs_dim;
    let a = net.spec.act_dim;
    let n = set.len(d);
    let mut x = vec![0.0f32; n * d];
    for (raw, out) in set.obs.chunks_exact(d).zip(x.chunks_exact_mut(d)) {
        norm.apply(raw, out);
    }
    let dev = net.device();
    (
        Tensor::from_slice(&x)
            .view([n as i64, d as i64])
            .to_device(dev),
        Tensor::from_slice(&set.actions[..n * a])
            .view([n as i64, a as i64])
            .to_device(dev),
    )
}

fn mse(net: &ActorCritic, x: &Tensor, y: &Tensor) -> Tensor {
    (net.actor_mean(x) - y).square().mean(Kind::Float)
}

/// The imitation loss (MSE of the actor's mean action against the set's actions); 0 for an
/// empty set.
pub fn imitation_loss(net: &ActorCritic, norm: &ObsNormalizer, set: &BcSet) -> f64 {
    if set.is_empty() {
        return 0.0;
    }
    let (x, y) = tensors(net, norm, set);
    tch::no_grad(|| mse(net, &x, &y).double_value(&[]))
}

/// `cfg.steps` Adam steps of the actor on minibatches mixing `demos` and `anchors` (see
/// [`BcConfig::demo_share`]), drawn with `rng`. Nothing happens when `demos` is empty.
pub fn behaviour_clone(
    net: &mut ActorCritic,
    norm: &ObsNormalizer,
    demos: &BcSet,
    anchors: &BcSet,
    cfg: &BcConfig,
    rng: &mut ChaCha8Rng,
) -> BcReport {
    let d = net.spec.obs_dim;
    let mut report = BcReport {
        demo_pairs: demos.len(d),
        anchor_pairs: anchors.len(d),
        ..Default::default()
    };
    if demos.is_empty() {
        return report;
    }
    let (dx, dy) = tensors(net, norm, demos);
    let anchor = (!anchors.is_empty()).then(|| tensors(net, norm, anchors));
    let loss_of = |net: &ActorCritic, x: &Tensor, y: &Tensor| {
        tch::no_grad(|| mse(net, x, y).double_value(&[]))
    };
    report.demo_loss_before = loss_of(net, &dx, &dy);
    if let Some((ax, ay)) = &anchor {
        report.anchor_loss_before = loss_of(net, ax, ay);
    }
    let batch = cfg.batch.max(1);
    let n_demo = if anchor.is_some() {
        ((batch as f64 * cfg.demo_share.clamp(0.0, 1.0)).round() as usize).clamp(1, batch)
    } else {
        batch
    };
    let n_anchor = batch - n_demo;
    let dev = net.device();
    let pick = |rng: &mut ChaCha8Rng, n: usize, of: usize| -> Tensor {
        let idx: Vec<i64> = (0..n).map(|_| rng.random_range(0..of) as i64).collect();
        Tensor::from_slice(&idx).to_device(dev)
    };
    let mut adam = Adam::new(&net.theta, cfg.lr);
    for _ in 0..cfg.steps {
        let i = pick(rng, n_demo, report.demo_pairs);
        let mut loss = mse(net, &dx.index_select(0, &i), &dy.index_select(0, &i))
            * (n_demo as f64 / batch as f64);
        if let Some((ax, ay)) = &anchor
            && n_anchor > 0
        {
            let j = pick(rng, n_anchor, report.anchor_pairs);
            loss += mse(net, &ax.index_select(0, &j), &ay.index_select(0, &j))
                * (n_anchor as f64 / batch as f64);
        }
        net.theta.zero_grad();
        loss.backward();
        let grad = net.theta.grad();
        clip_grad_norm(&grad, cfg.max_grad_norm);
        adam.step(&net.theta, &grad);
        report.steps += 1;
    }
    net.theta.zero_grad();
    report.demo_loss_after = loss_of(net, &dx, &dy);
    if let Some((ax, ay)) = &anchor {
        report.anchor_loss_after = loss_of(net, ax, ay);
    }
    report
}

/// The policy's own (raw observation, mean action) pairs along one deterministic episode
/// per scene of `scenes` (the episode steps with the mean clipped into `[-1, 1]`; the pair
/// keeps the unclipped mean, so that the anchors' loss is exactly 0 for the policy they
/// come from): the anchors of [`behaviour_clone`].
pub fn policy_pairs<E: Env + Clone>(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    template: &E,
    scenes: &[E::Scene],
) -> BcSet {
    let d = net.spec.obs_dim;
    let a = net.spec.act_dim;
    let mut set = BcSet::default();
    let mut env = template.clone();
    let mut raw = vec![0.0f32; d];
    let mut x = vec![0.0f32; d];
    for scene in scenes {
        env.reset(scene, &mut raw);
        loop {
            norm.apply(&raw, &mut x);
            let mean = tch::no_grad(|| {
                net.actor_mean(
                    &Tensor::from_slice(&x)
                        .view([1, d as i64])
                        .to_device(net.device()),
                )
                .to_device(tch::Device::Cpu)
            });
            let mut act = vec![0.0f32; a];
            mean.view([-1]).copy_data(&mut act, a);
            set.extend(&raw, &act);
            for v in &mut act {
                *v = v.clamp(-1.0, 1.0);
            }
            let info = env.step(&act, &mut raw);
            if info.terminated || info.truncated {
                break;
            }
        }
    }
    set
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;
    use crate::env::{PointReach, PointScene};
    use crate::net::NetSpec;
    use crate::normalize::RunningMeanStd;

    /// The expert of the point task: straight at the goal, full speed.
    fn expert(obs: &[f32]) -> [f32; 2] {
        let (dx, dy) = (obs[2], obs[3]);
        let k = 1.0 / dx.abs().max(dy.abs()).max(PointReach::STEP_SIZE);
        [(dx * k).clamp(-1.0, 1.0), (dy * k).clamp(-1.0, 1.0)]
    }

    fn expert_set(scenes: &[PointScene]) -> BcSet {
        let mut set = BcSet::default();
        let mut env = PointReach::default();
        let mut obs = [0.0f32; 4];
        for s in scenes {
            env.reset(s, &mut obs);
            loop {
                let a = expert(&obs);
                set.extend(&obs, &a);
                let info = env.step(&a, &mut obs);
                if info.terminated || info.truncated {
                    break;
                }
            }
        }
        set
    }

    #[test]
    fn cloning_reduces_the_imitation_loss_and_the_clone_reaches_goals() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let scenes: Vec<PointScene> = (0..64).map(|_| PointScene::random(&mut rng)).collect();
        let demos = expert_set(&scenes);
        let spec = NetSpec {
            obs_dim: 4,
            act_dim: 2,
            hidden: vec![64, 64],
        };
        let mut net = ActorCritic::new(spec, tch::Device::Cpu, 9);
        let mut rms = RunningMeanStd::new(4);
        rms.update(&demos.obs);
        let norm = ObsNormalizer::from_stats(&rms, 10.0);
        let held_out: Vec<PointScene> = (0..32).map(|_| PointScene::random(&mut rng)).collect();
        let before = crate::ppo::evaluate(&net, &norm, &PointReach::default(), &held_out, 1);
        let report = behaviour_clone(
            &mut net,
            &norm,
            &demos,
            &BcSet::default(),
            &BcConfig::default(),
            &mut rng,
        );
        assert_eq!(report.steps, BcConfig::default().steps);
        assert!(
            report.demo_loss_after < 0.25 * report.demo_loss_before,
            "{report:?}"
        );
        assert_eq!(imitation_loss(&net, &norm, &demos), report.demo_loss_after);
        let after = crate::ppo::evaluate(&net, &norm, &PointReach::default(), &held_out, 1);
        assert!(
            after.success_rate >= 0.9 && after.success_rate > before.success_rate,
            "before {before:?} after {after:?}"
        );
    }

    #[test]
    fn anchors_hold_the_policy_where_there_are_no_demonstrations() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let spec = NetSpec {
            obs_dim: 4,
            act_dim: 2,
            hidden: vec![32, 32],
        };
        let mut net = ActorCritic::new(spec, tch::Device::Cpu, 2);
        let norm = ObsNormalizer::from_stats(&RunningMeanStd::new(4), 10.0);
        let scenes: Vec<PointScene> = (0..16).map(|_| PointScene::random(&mut rng)).collect();
        let anchors = policy_pairs(&net, &norm, &PointReach::default(), &scenes);
        assert!(!anchors.is_empty());
        assert!(imitation_loss(&net, &norm, &anchors) < 1e-12);
        // Demonstrations on one corner only: with anchors the rest stays near the old policy.
        let demos = expert_set(&scenes[..2]);
        let report = behaviour_clone(
            &mut net,
            &norm,
            &demos,
            &anchors,
            &BcConfig::default(),
            &mut rng,
        );
        assert!(
            report.demo_loss_after < report.demo_loss_before,
            "{report:?}"
        );
        assert!(
            report.anchor_loss_after < 0.5 * report.demo_loss_before,
            "{report:?}"
        );
    }
}
