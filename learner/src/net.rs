//! The Gaussian actor-critic: two separate tanh MLPs (actor mean, critic value) and a learned,
//! state-independent log standard deviation, as SB3's default `MlpPolicy` for PPO.
//!
//! All parameters live in **one flat tensor** (`theta`); layers are views into it. One
//! backward pass then yields one flat gradient, Adam and gradient-norm clipping are a handful
//! of tensor operations instead of a handful per layer, checkpoints are a single tensor, and
//! export to the `PolicyBlob` layout is a slice copy.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

use crate::random::randn;

/// `ln(2π) / 2`.
pub const HALF_LOG_2PI: f32 = 0.918_938_5;

/// Shapes of the actor-critic.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct NetSpec {
    /// Observation length.
    pub obs_dim: usize,
    /// Action length.
    pub act_dim: usize,
    /// Hidden layer widths (shared by actor and critic, separate weights).
    pub hidden: Vec<usize>,
}

/// Offset and shape of one weight matrix and its bias inside `theta`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerSlot {
    /// Offset of the row-major `[out, in]` weight.
    pub w_off: usize,
    /// Offset of the `[out]` bias.
    pub b_off: usize,
    /// Inputs.
    pub n_in: usize,
    /// Outputs.
    pub n_out: usize,
}

/// Where everything sits inside `theta`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Layout {
    /// Actor layers, input to output (the last one is linear, the others tanh).
    pub actor: Vec<LayerSlot>,
    /// Critic layers, input to output.
    pub critic: Vec<LayerSlot>,
    /// Offset of the `[act_dim]` log standard deviation.
    pub log_std_off: usize,
    /// Total parameter count.
    pub len: usize,
}

impl NetSpec {
    /// The parameter layout of this spec.
    pub fn layout(&self) -> Layout {
        let mut off = 0;
        let mut mlp = |out_dim: usize| {
            let mut dims = vec![self.obs_dim];
            dims.extend(&self.hidden);
            dims.push(out_dim);
            let mut v = Vec::new();
            for w in dims.windows(2) {
                let slot = LayerSlot {
                    w_off: off,
                    b_off: off + w[0] * w[1],
                    n_in: w[0],
                    n_out: w[1],
                };
                off += w[0] * w[1] + w[1];
                v.push(slot);
            }
            v
        };
        let actor = mlp(self.act_dim);
        let critic = mlp(1);
        let log_std_off = off;
        Layout {
            actor,
            critic,
            log_std_off,
            len: off + self.act_dim,
        }
    }
}

/// Why [`ActorCritic::from_flat`] could not build a network.
#[derive(Debug, thiserror::Error)]
pub enum NetFromFlatError {
    /// The parameter vector's length does not match the layout.
    #[error("parameter vector has {got} values, the network needs {expected}")]
    Length {
        /// Values given.
        got: usize,
        /// Values the layout needs.
        expected: usize,
    },
    /// torch could not create the parameter tensor.
    #[error("parameter tensor")]
    Tensor(#[from] tch::TchError),
}

/// The actor-critic's parameters and forward passes.
#[derive(Debug)]
pub struct ActorCritic {
    /// Shapes.
    pub spec: NetSpec,
    /// Parameter layout.
    pub layout: Layout,
    /// All parameters, `[layout.len]`, requires grad.
    pub theta: Tensor,
}

fn orthogonal(n_out: usize, n_in: usize, gain: f64, rng: &mut ChaCha8Rng) -> Tensor {
    // QR of a Gaussian matrix, sign-corrected (as torch.nn.init.orthogonal_). The Gaussian
    // comes from the seeded ChaCha stream, not torch's global generator, so initialisation
    // is reproducible even with other torch users in the process.
    let (rows, cols) = (n_out.max(n_in) as i64, n_out.min(n_in) as i64);
    let g: Vec<f32> = (0..rows * cols).map(|_| randn(rng)).collect();
    let a = Tensor::from_slice(&g).view([rows, cols]);
    let (q, r) = Tensor::linalg_qr(&a, "reduced");
    let d = r.diagonal(0, 0, 1).sign();
    let q = q * d.unsqueeze(0);
    let q = if n_out < n_in { q.tr() } else { q };
    q.contiguous() * gain
}

impl ActorCritic {
    /// A freshly initialised network (orthogonal weights with SB3's gains: √2 hidden, 0.01
    /// policy output, 1 value output; zero biases; log-std 0), drawn from `seed`.
    pub fn new(spec: NetSpec, device: Device, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let layout = spec.layout();
        let theta = Tensor::zeros([layout.len as i64], (Kind::Float, Device::Cpu));
        let mut put = |slot: &LayerSlot, gain: f64| {
            let w = orthogonal(slot.n_out, slot.n_in, gain, &mut rng).view([-1]);
            theta
                .narrow(0, slot.w_off as i64, (slot.n_in * slot.n_out) as i64)
                .copy_(&w);
        };
        for (layers, out_gain) in [(&layout.actor, 0.01), (&layout.critic, 1.0)] {
            for (i, slot) in layers.iter().enumerate() {
                let gain = if i + 1 == layers.len() {
                    out_gain
                } else {
                    2f64.sqrt()
                };
                put(slot, gain);
            }
        }
        let theta = theta.to_device(device).set_requires_grad(true);
        Self {
            spec,
            layout,
            theta,
        }
    }

    /// A network with the given flat parameters (length must match the spec's layout).
    ///
    /// # Errors
    /// [`NetFromFlatError::Length`] when the length does not match,
    /// [`NetFromFlatError::Tensor`] when torch cannot place the parameters on `device`.
    pub fn from_flat(
        spec: NetSpec,
        flat: &[f32],
        device: Device,
    ) -> Result<Self, NetFromFlatError> {
        let layout = spec.layout();
        if flat.len() != layout.len {
            return Err(NetFromFlatError::Length {
                got: flat.len(),
                expected: layout.len,
            });
        }
        let theta = Tensor::f_from_slice(flat)?
            .f_to_device(device)?
            .set_requires_grad(true);
        Ok(Self {
            spec,
            layout,
            theta,
        })
    }

    /// The parameters as a host vector.
    pub fn flat(&self) -> Vec<f32> {
        let t = self.theta.detach().to_device(Device::Cpu);
        let mut v = vec![0.0f32; self.layout.len];
        t.copy_data(&mut v, self.layout.len);
        v
    }

    /// The device the parameters live on.
    pub fn device(&self) -> Device {
        self.theta.device()
    }

    fn mlp(theta: &Tensor, layers: &[LayerSlot], x: &Tensor) -> Tensor {
        let mut h = x.shallow_clone();
        for (i, s) in layers.iter().enumerate() {
            let w = theta
                .narrow(0, s.w_off as i64, (s.n_in * s.n_out) as i64)
                .view([s.n_out as i64, s.n_in as i64]);
            let b = theta.narrow(0, s.b_off as i64, s.n_out as i64);
            h = h.linear(&w, Some(&b));
            if i + 1 < layers.len() {
                h = h.tanh();
            }
        }
        h
    }

    /// Action means `[n, act_dim]` of normalised observations `[n, obs_dim]`.
    pub fn actor_mean(&self, obs: &Tensor) -> Tensor {
        Self::mlp(&self.theta, &self.layout.actor, obs)
    }

    /// State values `[n]` of normalised observations `[n, obs_dim]`.
    pub fn value(&self, obs: &Tensor) -> Tensor {
        Self::mlp(&self.theta, &self.layout.critic, obs).squeeze_dim(1)
    }

    /// The log standard deviation `[act_dim]`.
    pub fn log_std(&self) -> Tensor {
        self.theta
            .narrow(0, self.layout.log_std_off as i64, self.spec.act_dim as i64)
    }

    /// Log-probabilities `[n]` of `actions` under the policy at `obs`, and the entropy `[]`
    /// of the (state-independent) Gaussian.
    pub fn log_prob_entropy(&self, obs: &Tensor, actions: &Tensor) -> (Tensor, Tensor) {
        let mean = self.actor_mean(obs);
        let log_std = self.log_std();
        gaussian_log_prob_entropy(&mean, &log_std, actions)
    }

    /// A shallow copy (shares storage) detached from the graph, for read-only use on another
    /// thread.
    pub fn detached(&self) -> Self {
        Self {
            spec: self.spec.clone(),
            layout: self.layout.clone(),
            theta: self.theta.detach(),
        }
    }
}

/// Diagonal-Gaussian log-probability `[n]` (summed over action dimensions) and entropy `[]`.
pub fn gaussian_log_prob_entropy(
    mean: &Tensor,
    log_std: &Tensor,
    actions: &Tensor,
) -> (Tensor, Tensor) {
    let z = (actions - mean) * (-log_std).exp();
    let logp = (z.square() * -0.5 - log_std - f64::from(HALF_LOG_2PI)).sum_dim_intlist(
        [-1i64].as_slice(),
        false,
        Kind::Float,
    );
    let ent = (log_std + 0.5 + f64::from(HALF_LOG_2PI)).sum(Kind::Float);
    (logp, ent)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> NetSpec {
        NetSpec {
            obs_dim: 5,
            act_dim: 3,
            hidden: vec![8, 6],
        }
    }

    #[test]
    fn layout_covers_every_parameter_once() {
        let l = spec().layout();
        // actor: 5*8+8 + 8*6+6 + 6*3+3; critic: 5*8+8 + 8*6+6 + 6*1+1; log_std 3
        assert_eq!(l.len, 48 + 54 + 21 + 48 + 54 + 7 + 3);
        assert_eq!(l.actor[0].w_off, 0);
        assert_eq!(l.critic[0].w_off, 48 + 54 + 21);
        assert_eq!(l.log_std_off, l.len - 3);
    }

    #[test]
    fn init_is_orthogonal_and_seeded() {
        let a = ActorCritic::new(spec(), Device::Cpu, 3);
        let b = ActorCritic::new(spec(), Device::Cpu, 3);
        assert!(a.flat() == b.flat());
        assert!(a.flat() != ActorCritic::new(spec(), Device::Cpu, 4).flat());
        let s = a.layout.critic[1];
        let w = a.theta.detach().narrow(0, s.w_off as i64, 48).view([6, 8]);
        // rows orthonormal times sqrt(2)
        let g = w.matmul(&w.tr()) / 2.0;
        let err = (g - Tensor::eye(6, (Kind::Float, Device::Cpu)))
            .abs()
            .max()
            .double_value(&[]);
        assert!(err < 1e-4, "{err}");
        let ls = a.log_std().detach();
        assert_eq!(ls.abs().sum(Kind::Float).double_value(&[]), 0.0);
    }

    #[test]
    fn from_flat_checks_the_length() {
        let n = spec().layout().len;
        let e = ActorCritic::from_flat(spec(), &vec![0.0; n - 1], Device::Cpu).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "parameter vector has {} values, the network needs {n}",
                n - 1
            )
        );
        let net = ActorCritic::from_flat(spec(), &vec![0.5; n], Device::Cpu).unwrap();
        assert_eq!(net.flat(), vec![0.5; n]);
    }

    #[test]
    fn gaussian_log_prob_matches_closed_form() {
        let mean = Tensor::from_slice(&[0.5f32, -1.0]).view([1, 2]);
        let log_std = Tensor::from_slice(&[0.0f32, (0.5f32).ln()]);
        let act = Tensor::from_slice(&[1.5f32, -1.0]).view([1, 2]);
        let (lp, ent) = gaussian_log_prob_entropy(&mean, &log_std, &act);
        // dim 0: z = 1, std 1 → -0.5 - 0 - c; dim 1: z = 0, std 0.5 → -ln 0.5 - c
        let c = f64::from(HALF_LOG_2PI);
        let want = -0.5 - c + (-(0.5f64.ln()) - c);
        assert!((lp.double_value(&[0]) - want).abs() < 1e-5);
        let want_ent = (0.5 + c) * 2.0 + 0.5f64.ln();
        assert!((ent.double_value(&[]) - want_ent).abs() < 1e-5);
    }
}
