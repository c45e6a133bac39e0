//! The PPO loss for one minibatch: clipped surrogate (with the approximate KL and the clip
//! fraction), per-minibatch advantage normalisation, value loss and entropy ([`ppo_loss`]).

use tch::{Kind, Tensor};

use crate::net::ActorCritic;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::net::NetSpec;
    use tch::Device;

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
}
