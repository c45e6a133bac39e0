//! Behaviour cloning: a warm start of the actor on (observation, action) pairs before PPO
//! fine-tunes it — the planner's demonstrations ([`crate::demonstrations`]) mixed with
//! *anchor* pairs, the base policy's own mean actions along its own episodes on scenes it
//! already solves, so that imitating the new way does not overwrite the old skill.
//!
//! The loss is the mean squared error between the actor's mean action (of the normalised
//! observation, as the rollout and the exported policy see it) and the target action. Only
//! the actor mean gets a gradient (the critic and the log-std are not in the graph). A
//! fresh [`Adam`] is used, so PPO's optimiser state is left as it was.
//!
//! An optional collision hinge ([`ClearanceHinge`], issue 31) adds
//! `weight · (relu(margin − d_next) / scale)²` per row, where `d_next = d + n·(μ·scale)` is
//! the clearance predicted after the actor's mean action `μ`: `d` is the distance between the
//! closest robot point and the closest obstacle point of the raw observation, `n` the unit
//! direction from the obstacle point to the robot point, `scale` the TCP displacement per
//! unit action. The shortfall is measured in steps (divided by `scale`), so that the weight
//! is on the scale of the imitation loss (action units squared). Its gradient with respect to
//! `μ` is `−2·weight·relu(margin − d_next)/scale · n` per row (divided by the rows), formed
//! by autograd with the imitation loss's.

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

/// The collision hinge of [`behaviour_clone`] (see the module docs): a penalty on mean
/// actions whose predicted clearance after the step falls below a margin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ClearanceHinge {
    /// Weight of the hinge (0: off).
    pub weight: f64,
    /// Clearance below which the hinge acts (m).
    pub margin_m: f64,
    /// TCP displacement per unit action (m).
    pub action_scale_m: f64,
    /// Index of the closest robot point (3 values, m) in the raw observation.
    pub robot_point_at: usize,
    /// Index of the closest obstacle point (3 values, m) in the raw observation.
    pub obstacle_point_at: usize,
}

impl ClearanceHinge {
    /// The rows' current clearance `d` and unit direction `n` (obstacle point → robot
    /// point) from the raw observations, as `[n, 4]` = `(d, nx, ny, nz)` on `dev`. Where the
    /// two points coincide (contact) the direction is 0: the row's hinge has no gradient.
    fn geometry(&self, set: &BcSet, obs_dim: usize, act_dim: usize, dev: tch::Device) -> Tensor {
        let n = set.len(obs_dim);
        let mut g = vec![0.0f32; n * 4];
        let (r, o) = (self.robot_point_at, self.obstacle_point_at);
        let fits = r + 3 <= obs_dim && o + 3 <= obs_dim && act_dim == 3;
        for (raw, out) in set.obs.chunks_exact(obs_dim).zip(g.chunks_exact_mut(4)) {
            if !fits {
                // No geometry in this observation: an infinite clearance, no hinge.
                out[0] = f32::INFINITY;
                continue;
            }
            let v: [f64; 3] =
                std::array::from_fn(|k| f64::from(raw[r + k]) - f64::from(raw[o + k]));
            let d = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            out[0] = d as f32;
            if d > 1e-9 {
                for k in 0..3 {
                    out[1 + k] = (v[k] / d) as f32;
                }
            }
        }
        Tensor::from_slice(&g).view([n as i64, 4]).to_device(dev)
    }

    /// The hinge's mean over the rows of `mean` (`[b, 3]`), with `geom` the rows'
    /// `Self::geometry` (`[b, 4]`): `weight · mean((relu(margin − d_next) / scale)²)`.
    pub fn loss(&self, mean: &Tensor, geom: &Tensor) -> Tensor {
        let d = geom.narrow(1, 0, 1);
        let n = geom.narrow(1, 1, 3);
        let d_next = d + (mean * n).sum_dim_intlist(1, true, Kind::Float) * self.action_scale_m;
        let short = (d_next.neg() + self.margin_m).relu() / self.action_scale_m;
        short.square().mean(Kind::Float) * self.weight
    }

    /// Whether the hinge is on (a positive weight).
    fn on(&self) -> bool {
        self.weight > 0.0
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
    /// The collision hinge (`None` or a weight of 0: off).
    pub hinge: Option<ClearanceHinge>,
}

impl Default for BcConfig {
    /// 300 steps of 256 rows, lr 1e-3, half demonstrations, clip 1, no hinge.
    fn default() -> Self {
        Self {
            steps: 300,
            batch: 256,
            lr: 1e-3,
            demo_share: 0.5,
            max_grad_norm: 1.0,
            hinge: None,
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
    /// The collision hinge on the demonstrations before (0 without one).
    pub hinge_loss_before: f64,
    /// The collision hinge on the demonstrations after (0 without one).
    pub hinge_loss_after: f64,
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

/// The training loss of the rows `idx` of `(x, y)`: the imitation loss, plus the hinge
/// (with the rows' geometry) when there is one.
fn rows_loss(
    net: &ActorCritic,
    x: &Tensor,
    y: &Tensor,
    idx: &Tensor,
    hinge: Option<(&ClearanceHinge, &Tensor)>,
) -> Tensor {
    let mean = net.actor_mean(&x.index_select(0, idx));
    let imitation = (&mean - y.index_select(0, idx)).square().mean(Kind::Float);
    match hinge {
        Some((h, g)) => imitation + h.loss(&mean, &g.index_select(0, idx)),
        None => imitation,
    }
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
    let a = net.spec.act_dim;
    let dev = net.device();
    let hinge = cfg.hinge.filter(ClearanceHinge::on);
    let geom = hinge.map(|h| {
        (
            h,
            h.geometry(demos, d, a, dev),
            anchor.as_ref().map(|_| h.geometry(anchors, d, a, dev)),
        )
    });
    let hinge_of = |net: &ActorCritic| {
        geom.as_ref().map_or(0.0, |(h, g, _)| {
            tch::no_grad(|| h.loss(&net.actor_mean(&dx), g).double_value(&[]))
        })
    };
    report.demo_loss_before = loss_of(net, &dx, &dy);
    report.hinge_loss_before = hinge_of(net);
    if let Some((ax, ay)) = &anchor {
        report.anchor_loss_before = loss_of(net, ax, ay);
    }
    let (batch, n_demo) = batch_split(cfg, anchor.is_some());
    let n_anchor = batch - n_demo;
    let pick = |rng: &mut ChaCha8Rng, n: usize, of: usize| pick_rows(rng, n, of, dev);
    let mut adam = Adam::new(&net.theta, cfg.lr);
    for _ in 0..cfg.steps {
        let i = pick(rng, n_demo, report.demo_pairs);
        let mut loss = rows_loss(net, &dx, &dy, &i, geom.as_ref().map(|(h, g, _)| (h, g)))
            * (n_demo as f64 / batch as f64);
        if let Some((ax, ay)) = &anchor
            && n_anchor > 0
        {
            let j = pick(rng, n_anchor, report.anchor_pairs);
            let ag = geom
                .as_ref()
                .and_then(|(h, _, ag)| ag.as_ref().map(|g| (h, g)));
            loss += rows_loss(net, ax, ay, &j, ag) * (n_anchor as f64 / batch as f64);
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
    report.hinge_loss_after = hinge_of(net);
    if let Some((ax, ay)) = &anchor {
        report.anchor_loss_after = loss_of(net, ax, ay);
    }
    report
}

/// A minibatch's size and its demonstration rows: all of them without anchors, else
/// [`BcConfig::demo_share`] of it (at least one row).
fn batch_split(cfg: &BcConfig, with_anchors: bool) -> (usize, usize) {
    let batch = cfg.batch.max(1);
    let n_demo = if with_anchors {
        ((batch as f64 * cfg.demo_share.clamp(0.0, 1.0)).round() as usize).clamp(1, batch)
    } else {
        batch
    };
    (batch, n_demo)
}

/// `n` row indices drawn uniformly from `0..of` with `rng`, as a tensor on `dev`.
fn pick_rows(rng: &mut ChaCha8Rng, n: usize, of: usize, dev: tch::Device) -> Tensor {
    let idx: Vec<i64> = (0..n).map(|_| rng.random_range(0..of) as i64).collect();
    Tensor::from_slice(&idx).to_device(dev)
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

    fn hinge() -> ClearanceHinge {
        ClearanceHinge {
            weight: 0.7,
            margin_m: 0.03,
            action_scale_m: 0.015,
            robot_point_at: 0,
            obstacle_point_at: 3,
        }
    }

    /// One row's geometry: robot point at `obstacle + d·n`.
    fn geom_of(h: &ClearanceHinge, d_m: f32, n: [f32; 3]) -> Tensor {
        let mut set = BcSet::default();
        let o = [0.4f32, -0.1, 0.3];
        let obs: Vec<f32> = (0..3).map(|k| o[k] + d_m * n[k]).chain(o).collect();
        set.extend(&obs, &[0.0; 3]);
        h.geometry(&set, 6, 3, tch::Device::Cpu)
    }

    fn hinge_at(h: &ClearanceHinge, g: &Tensor, mu: [f64; 3]) -> (f64, [f64; 3]) {
        let mean = Tensor::from_slice(&mu.map(|v| v as f32))
            .view([1, 3])
            .set_requires_grad(true);
        let loss = h.loss(&mean, g);
        loss.backward();
        let mut grad = [0.0f32; 3];
        mean.grad().view([-1]).copy_data(&mut grad, 3);
        (loss.double_value(&[]), grad.map(f64::from))
    }

    #[test]
    fn the_hinge_gradient_matches_a_finite_difference_and_pushes_away_from_the_obstacle() {
        let h = hinge();
        let n = [1.0f32 / 3.0, 2.0 / 3.0, 2.0 / 3.0];
        let g = geom_of(&h, 0.02, n);
        let mu = [0.3, -0.5, 0.1];
        let (loss, grad) = hinge_at(&h, &g, mu);
        // d_next = 0.02 + 0.015·(n·μ) = 0.02 − 0.015/6 = 0.0175 m: 5/6 of a step short of
        // the margin.
        let short = 5.0 / 6.0;
        assert!((loss - 0.7 * short * short).abs() < 1e-4, "{loss}");
        let eps = 1e-2;
        for k in 0..3 {
            let (mut up, mut down) = (mu, mu);
            up[k] += eps;
            down[k] -= eps;
            let fd = (hinge_at(&h, &g, up).0 - hinge_at(&h, &g, down).0) / (2.0 * eps);
            assert!(
                (grad[k] - fd).abs() < 1e-3,
                "component {k}: {grad:?} vs {fd}"
            );
            // The analytic form: −2·weight·short/scale·n.
            let analytic = -2.0 * 0.7 * short * f64::from(n[k]);
            assert!((grad[k] - analytic).abs() < 1e-3, "{grad:?} vs {analytic}");
            // Descending the gradient moves the action away from the obstacle (along n).
            assert!(grad[k] < 0.0, "{grad:?}");
        }
    }

    #[test]
    fn the_hinge_is_zero_with_no_gradient_at_or_beyond_the_margin_and_in_contact() {
        let h = hinge();
        let n = [0.0f32, 0.0, 1.0];
        // 5 cm now, 1 step toward the box: 3.5 cm after, beyond the 3 cm margin.
        let (loss, grad) = hinge_at(&h, &geom_of(&h, 0.05, n), [0.0, 0.0, -1.0]);
        assert_eq!(loss, 0.0);
        assert_eq!(grad, [0.0; 3]);
        // Exactly at the margin after the step.
        let (loss, grad) = hinge_at(&h, &geom_of(&h, 0.045, n), [0.0, 0.0, -1.0]);
        assert!(loss < 1e-9, "{loss}");
        assert!(grad.iter().all(|v| v.abs() < 1e-4), "{grad:?}");
        // Moving away from a box 2 cm off clears the margin too.
        let (loss, grad) = hinge_at(&h, &geom_of(&h, 0.02, n), [0.0, 0.0, 1.0]);
        assert_eq!(loss, 0.0);
        assert_eq!(grad, [0.0; 3]);
        // Points that coincide (contact) have no direction: no gradient.
        let (_, grad) = hinge_at(&h, &geom_of(&h, 0.0, n), [0.2, 0.2, 0.2]);
        assert_eq!(grad, [0.0; 3]);
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
