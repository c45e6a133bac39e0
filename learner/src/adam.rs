//! Adam on one flat parameter tensor, with its state (`m`, `v`, step count) in plain tensors
//! so that checkpoints can hold it. tch 0.26's `nn::Optimizer` wraps a C++ optimiser whose
//! state cannot be read or saved; this one can, and costs a handful of tensor operations per
//! step because the parameters are one tensor (see [`crate::net`]).

use tch::Tensor;

/// Adam (Kingma & Ba) with bias correction, no weight decay.
#[derive(Debug)]
pub struct Adam {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator epsilon (SB3's PPO uses 1e-5).
    pub eps: f64,
    /// First moment, shaped like the parameters.
    pub m: Tensor,
    /// Second moment, shaped like the parameters.
    pub v: Tensor,
    /// Steps taken.
    pub t: i64,
}

impl Adam {
    /// Fresh state for parameters shaped like `theta`.
    pub fn new(theta: &Tensor, lr: f64) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-5,
            m: theta.detach().zeros_like(),
            v: theta.detach().zeros_like(),
            t: 0,
        }
    }

    /// One update of `theta` (a leaf that requires grad) along `grad`.
    pub fn step(&mut self, theta: &Tensor, grad: &Tensor) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t as i32);
        let bc2 = 1.0 - self.beta2.powi(self.t as i32);
        tch::no_grad(|| {
            let _ = self.m.g_mul_scalar_(self.beta1);
            let _ = self.m.g_add_(&(grad * (1.0 - self.beta1)));
            let _ = self.v.g_mul_scalar_(self.beta2);
            let _ = self.v.g_add_(&(grad.square() * (1.0 - self.beta2)));
            let denom = (&self.v / bc2).sqrt() + self.eps;
            let upd = (&self.m / denom) * (self.lr / bc1);
            let mut th = theta.shallow_clone();
            let _ = th.g_sub_(&upd);
        });
    }
}

/// Scales `grad` in place so that its L2 norm is at most `max_norm`; returns the norm before.
pub fn clip_grad_norm(grad: &Tensor, max_norm: f64) -> f64 {
    let norm = grad.norm().double_value(&[]);
    if norm > max_norm && norm.is_finite() {
        let mut g = grad.shallow_clone();
        tch::no_grad(|| {
            let _ = g.g_mul_scalar_(max_norm / (norm + 1e-6));
        });
    }
    norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn first_adam_step_moves_each_parameter_by_lr_against_its_gradient_sign() {
        let theta = Tensor::from_slice(&[1.0f32, -2.0, 0.5]).set_requires_grad(true);
        let mut adam = Adam::new(&theta, 0.1);
        adam.eps = 1e-12;
        let g = Tensor::from_slice(&[3.0f32, -0.5, 0.0]);
        adam.step(&theta, &g);
        let v: Vec<f32> = Vec::try_from(theta.detach()).unwrap();
        assert!(
            (v[0] - 0.9).abs() < 1e-6 && (v[1] + 1.9).abs() < 1e-6 && v[2] == 0.5,
            "{v:?}"
        );
        assert_eq!(adam.t, 1);
    }

    #[test]
    fn adam_minimises_a_quadratic() {
        let mut theta = Tensor::from_slice(&[5.0f32, -3.0]).set_requires_grad(true);
        let mut adam = Adam::new(&theta, 0.05);
        for _ in 0..2000 {
            let loss = (&theta - Tensor::from_slice(&[1.0f32, 2.0]))
                .square()
                .sum(Kind::Float);
            theta.zero_grad();
            loss.backward();
            adam.step(&theta, &theta.grad());
        }
        let v: Vec<f32> = Vec::try_from(theta.detach()).unwrap();
        assert!(
            (v[0] - 1.0).abs() < 1e-2 && (v[1] - 2.0).abs() < 1e-2,
            "{v:?}"
        );
    }

    #[test]
    fn clipping_bounds_the_gradient_norm() {
        let g = Tensor::from_slice(&[3.0f32, 4.0]).to_device(Device::Cpu);
        let before = clip_grad_norm(&g, 0.5);
        assert!((before - 5.0).abs() < 1e-6);
        let after = g.norm().double_value(&[]);
        assert!((after - 0.5).abs() < 1e-4, "{after}");
        let small = Tensor::from_slice(&[0.1f32, 0.0]);
        clip_grad_norm(&small, 0.5);
        assert!((small.norm().double_value(&[]) - 0.1).abs() < 1e-7);
    }
}
