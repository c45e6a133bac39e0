//! The actor-critic evaluated on host `f32` buffers, without tch: the batched forward pass
//! of the rollouts and evaluations, and the forward + backward pass of the PPO loss with
//! gradient-norm clipping and Adam for the update.
//!
//! Why: at the network sizes trained here (29 inputs, 64–256 hidden, 3 actions) a tch call
//! costs more in dispatch and autograd bookkeeping than in arithmetic; a rollout step made
//! ~10 tch calls per worker and a minibatch step ~150. Here a layer is one `sgemm`
//! (`matrixmultiply`, SIMD chosen at run time) plus a vectorised `tanh`, the backward pass is
//! written out by hand (it is short for a tanh MLP and a diagonal Gaussian), and a minibatch
//! is split by rows over the worker threads, whose gradients are summed in a fixed order.
//!
//! Semantics are those of [`super::loss::ppo_loss`] + [`crate::adam`] (tested against them:
//! same forward values, same gradient, same Adam step up to float rounding). Results are
//! bit-reproducible for a given number of threads (the row split and the summation order
//! are fixed).

use std::sync::{Arc, mpsc};

use policy::tanh;

use crate::net::{ActorCritic, HALF_LOG_2PI, LayerSlot, Layout, NetSpec};

/// `C[m,n] = A[m,k] · B[k,n] + beta · C` on strided slices; the strides address elements
/// of the slices (checked), e.g. `B = Wᵀ` of a row-major `W[n,k]` is `rsb = 1, csb = k`.
#[allow(clippy::too_many_arguments)]
fn gemm(
    (m, k, n): (usize, usize, usize),
    a: &[f32],
    (rsa, csa): (usize, usize),
    b: &[f32],
    (rsb, csb): (usize, usize),
    beta: f32,
    c: &mut [f32],
    (rsc, csc): (usize, usize),
) {
    if m == 0 || n == 0 {
        return;
    }
    let last = |rows: usize, cols: usize, rs: usize, cs: usize| {
        (rows.saturating_sub(1)) * rs + cols.saturating_sub(1) * cs
    };
    assert!(
        (k == 0 || (last(m, k, rsa, csa) < a.len() && last(k, n, rsb, csb) < b.len()))
            && last(m, n, rsc, csc) < c.len(),
        "gemm operand out of bounds"
    );
    // SAFETY: the assertion above checks that every element the product addresses
    // (row < m/k, column < k/n with the given strides) lies inside `a`, `b` and `c`; `c` is
    // borrowed mutably, so it does not alias `a` or `b`. All strides fit in isize because
    // they index inside slices.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            rsa as isize,
            csa as isize,
            b.as_ptr(),
            rsb as isize,
            csb as isize,
            beta,
            c.as_mut_ptr(),
            rsc as isize,
            csc as isize,
        );
    }
}

#[inline(always)]
fn tanh_body(x: &mut [f32]) {
    for v in x {
        *v = tanh(*v);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn tanh_avx2(x: &mut [f32]) {
    tanh_body(x);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn tanh_avx512(x: &mut [f32]) {
    tanh_body(x);
}

/// `tanh` in place over a slice, with the AVX-512 (16 lanes) or AVX2 (8 lanes) build where
/// the CPU has it (no FMA contraction is used, so every build gives identical bits).
fn tanh_slice(x: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU supports AVX-512F (checked just above).
        unsafe { tanh_avx512(x) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { tanh_avx2(x) };
        return;
    }
    tanh_body(x);
}

/// Activations of one MLP for `n` rows: `outs[l]` is layer `l`'s output (`tanh` applied on
/// hidden layers), `[n, n_out]` row-major.
#[derive(Debug, Default, Clone)]
struct MlpActs {
    outs: Vec<Vec<f32>>,
}

/// Forward pass of one MLP over `n` rows of `x` (`[n, n_in]`), keeping every layer's output.
fn mlp_forward(theta: &[f32], layers: &[LayerSlot], x: &[f32], n: usize, acts: &mut MlpActs) {
    acts.outs.resize(layers.len(), Vec::new());
    for (l, s) in layers.iter().enumerate() {
        let (prev, rest) = acts.outs.split_at_mut(l);
        let input: &[f32] = if l == 0 { x } else { &prev[l - 1] };
        let y = &mut rest[0];
        y.resize(n * s.n_out, 0.0);
        let bias = &theta[s.b_off..s.b_off + s.n_out];
        for row in y.chunks_exact_mut(s.n_out) {
            row.copy_from_slice(bias);
        }
        let w = &theta[s.w_off..s.w_off + s.n_in * s.n_out];
        // y[n, out] += x[n, in] · Wᵀ, W row-major [out, in].
        gemm(
            (n, s.n_in, s.n_out),
            input,
            (s.n_in, 1),
            w,
            (1, s.n_in),
            1.0,
            y,
            (s.n_out, 1),
        );
        if l + 1 < layers.len() {
            tanh_slice(y);
        }
    }
}

/// Backward pass of one MLP: `d_out` (`[n, out]`, overwritten) is the loss gradient at the
/// output; adds the parameter gradients into `grad` (indexed like `theta`).
#[allow(clippy::too_many_arguments)]
fn mlp_backward(
    theta: &[f32],
    layers: &[LayerSlot],
    x: &[f32],
    n: usize,
    acts: &MlpActs,
    d_out: &mut Vec<f32>,
    scratch: &mut Vec<f32>,
    grad: &mut [f32],
) {
    for l in (0..layers.len()).rev() {
        let s = layers[l];
        let input: &[f32] = if l == 0 { x } else { &acts.outs[l - 1] };
        // dW[out, in] += d[n, out]ᵀ · input[n, in]
        gemm(
            (s.n_out, n, s.n_in),
            d_out,
            (1, s.n_out),
            input,
            (s.n_in, 1),
            1.0,
            &mut grad[s.w_off..s.w_off + s.n_in * s.n_out],
            (s.n_in, 1),
        );
        let db = &mut grad[s.b_off..s.b_off + s.n_out];
        for row in d_out.chunks_exact(s.n_out) {
            for (g, d) in db.iter_mut().zip(row) {
                *g += d;
            }
        }
        if l == 0 {
            break;
        }
        // d_in[n, in] = d[n, out] · W[out, in], then through the previous layer's tanh.
        scratch.resize(n * s.n_in, 0.0);
        gemm(
            (n, s.n_out, s.n_in),
            d_out,
            (s.n_out, 1),
            &theta[s.w_off..s.w_off + s.n_in * s.n_out],
            (s.n_in, 1),
            0.0,
            scratch,
            (s.n_in, 1),
        );
        for (d, h) in scratch.iter_mut().zip(input) {
            *d *= 1.0 - h * h;
        }
        std::mem::swap(d_out, scratch);
    }
}

/// A snapshot of the actor-critic's parameters on the host, for batched forward passes.
#[derive(Debug, Clone)]
pub(crate) struct HostNet {
    /// Shapes.
    pub(crate) spec: NetSpec,
    layout: Layout,
    theta: Vec<f32>,
}

/// Buffers of [`HostNet::forward`] (reused between calls, so a worker allocates once).
#[derive(Debug, Default, Clone)]
pub(crate) struct ForwardWork {
    actor: MlpActs,
    critic: MlpActs,
}

impl HostNet {
    /// A copy of `net`'s current parameters.
    pub(crate) fn of(net: &ActorCritic) -> Self {
        Self {
            spec: net.spec.clone(),
            layout: net.layout.clone(),
            theta: net.flat(),
        }
    }

    /// Action means (`[n * act_dim]`, into `mean`) and, when `value` is given, values
    /// (`[n]`) of `n` normalised observations `obs` (`[n * obs_dim]`).
    pub(crate) fn forward(
        &self,
        obs: &[f32],
        n: usize,
        work: &mut ForwardWork,
        mean: &mut [f32],
        value: Option<&mut [f32]>,
    ) {
        mlp_forward(&self.theta, &self.layout.actor, obs, n, &mut work.actor);
        if let Some(out) = work.actor.outs.last() {
            mean.copy_from_slice(out);
        }
        if let Some(v) = value {
            mlp_forward(&self.theta, &self.layout.critic, obs, n, &mut work.critic);
            if let Some(out) = work.critic.outs.last() {
                v.copy_from_slice(out);
            }
        }
    }
}

/// The rows of a minibatch one thread works on (advantages already normalised over the
/// whole minibatch).
#[derive(Debug, Default, Clone)]
pub(crate) struct Rows {
    pub(crate) n: usize,
    pub(crate) obs: Vec<f32>,
    pub(crate) actions: Vec<f32>,
    pub(crate) logp_old: Vec<f32>,
    pub(crate) adv: Vec<f32>,
    pub(crate) returns: Vec<f32>,
}

impl Rows {
    fn clear(&mut self) {
        self.n = 0;
        self.obs.clear();
        self.actions.clear();
        self.logp_old.clear();
        self.adv.clear();
        self.returns.clear();
    }
}

/// Sums of the loss pieces over some rows (divided by the minibatch size at the end).
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub(crate) struct LossSums {
    pub(crate) policy: f64,
    pub(crate) value: f64,
    pub(crate) approx_kl: f64,
    pub(crate) clipped: f64,
}

impl std::ops::AddAssign for LossSums {
    fn add_assign(&mut self, o: Self) {
        self.policy += o.policy;
        self.value += o.value;
        self.approx_kl += o.approx_kl;
        self.clipped += o.clipped;
    }
}

/// The loss settings of one update.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LossCfg {
    pub(crate) clip: f32,
    pub(crate) vf_coef: f32,
    pub(crate) ent_coef: f32,
}

/// One thread's share of a minibatch: its rows and buffers, and its gradient.
#[derive(Debug, Default, Clone)]
pub(crate) struct Shard {
    pub(crate) rows: Rows,
    actor: MlpActs,
    critic: MlpActs,
    d: Vec<f32>,
    scratch: Vec<f32>,
    pub(crate) grad: Vec<f32>,
}

impl Shard {
    /// Gradient (into `self.grad`, zeroed first) of the PPO loss over this shard's rows for a
    /// minibatch of `total` rows, without the entropy term (added once per minibatch).
    fn loss_grad(&mut self, net: &HostView<'_>, total: usize, cfg: LossCfg) -> LossSums {
        let (theta, layout, spec) = (net.theta, net.layout, net.spec);
        self.grad.clear();
        self.grad.resize(layout.len, 0.0);
        let n = self.rows.n;
        let mut sums = LossSums::default();
        if n == 0 {
            return sums;
        }
        let a = spec.act_dim;
        let inv_b = 1.0 / total as f32;
        let log_std = &theta[layout.log_std_off..layout.log_std_off + a];
        let inv_std: Vec<f32> = log_std.iter().map(|l| (-l).exp()).collect();
        let logp_const: f32 = log_std.iter().map(|l| -l - HALF_LOG_2PI).sum();

        // Actor: log-probabilities, surrogate, gradient at the means and at log_std.
        mlp_forward(theta, &layout.actor, &self.rows.obs, n, &mut self.actor);
        let mean = self.actor.outs.last().map_or(&[][..], Vec::as_slice);
        self.d.resize(n * a, 0.0);
        let mut d_log_std = vec![0.0f32; a];
        let lo = 1.0 - cfg.clip;
        let hi = 1.0 + cfg.clip;
        for i in 0..n {
            let row = i * a..(i + 1) * a;
            // a ≤ MAX_ACT_DIM (checked by HostUpdate::new).
            let mut z = [0.0f32; MAX_ACT_DIM];
            let zs = &mut z[..a];
            let mut lp = logp_const;
            for (j, ((zj, act), m)) in zs
                .iter_mut()
                .zip(&self.rows.actions[row.clone()])
                .zip(&mean[row.clone()])
                .enumerate()
            {
                *zj = (act - m) * inv_std[j];
                lp -= 0.5 * *zj * *zj;
            }
            let log_ratio = lp - self.rows.logp_old[i];
            let ratio = log_ratio.exp();
            let adv = self.rows.adv[i];
            let s1 = ratio * adv;
            let clamped = ratio.clamp(lo, hi);
            let s2 = clamped * adv;
            sums.policy -= f64::from(s1.min(s2));
            sums.approx_kl += f64::from((ratio - 1.0) - log_ratio);
            if (ratio - 1.0).abs() > cfg.clip {
                sums.clipped += 1.0;
            }
            // d(-mean(min(s1, s2)))/d logp: the unclipped branch carries r·A; the clipped one
            // only while the clamp is inactive (then s1 = s2 and both give r·A).
            let active = s1 < s2 || clamped == ratio;
            let g = if active { -ratio * adv * inv_b } else { 0.0 };
            for (j, zj) in zs.iter().enumerate() {
                // d logp/d mean_j = z_j / σ_j; d logp/d log_std_j = z_j² − 1.
                self.d[i * a + j] = g * zj * inv_std[j];
                d_log_std[j] += g * (zj * zj - 1.0);
            }
        }
        let mut d = std::mem::take(&mut self.d);
        mlp_backward(
            theta,
            &layout.actor,
            &self.rows.obs,
            n,
            &self.actor,
            &mut d,
            &mut self.scratch,
            &mut self.grad,
        );
        for (g, dl) in self.grad[layout.log_std_off..layout.log_std_off + a]
            .iter_mut()
            .zip(&d_log_std)
        {
            *g += dl;
        }

        sums.value = self.critic_grad(net, inv_b, cfg, &mut d);
        self.d = d;
        sums
    }

    /// The critic's part of [`Shard::loss_grad`]: the sum of squared errors of the values
    /// against the returns (returned), its gradient added into `self.grad`; `d` is scratch.
    fn critic_grad(
        &mut self,
        net: &HostView<'_>,
        inv_b: f32,
        cfg: LossCfg,
        d: &mut Vec<f32>,
    ) -> f64 {
        let (theta, layout, n) = (net.theta, net.layout, self.rows.n);
        mlp_forward(theta, &layout.critic, &self.rows.obs, n, &mut self.critic);
        let v = self.critic.outs.last().map_or(&[][..], Vec::as_slice);
        d.clear();
        d.resize(n, 0.0);
        let k = 2.0 * cfg.vf_coef * inv_b;
        let mut value = 0.0;
        for ((dv, vi), r) in d.iter_mut().zip(v).zip(&self.rows.returns) {
            let e = vi - r;
            value += f64::from(e * e);
            *dv = k * e;
        }
        mlp_backward(
            theta,
            &layout.critic,
            &self.rows.obs,
            n,
            &self.critic,
            d,
            &mut self.scratch,
            &mut self.grad,
        );
        value
    }
}

/// Borrowed parameters and shapes.
pub(crate) struct HostView<'a> {
    theta: &'a [f32],
    layout: &'a Layout,
    spec: &'a NetSpec,
}

/// Widest action space the host update handles (the twin has 3).
pub(crate) const MAX_ACT_DIM: usize = 16;

/// The PPO update on the host: parameters and Adam moments as `f32` vectors (copied from and
/// back to the tch tensors once per update), one [`Shard`] per thread.
pub(crate) struct HostUpdate {
    spec: NetSpec,
    layout: Layout,
    /// Shared with the gradient workers during [`Self::gradient`] only (each drops its
    /// handle before it answers), so [`Self::apply`] updates it in place.
    theta: Arc<Vec<f32>>,
    pub(crate) m: Vec<f32>,
    pub(crate) v: Vec<f32>,
    pub(crate) t: i64,
    grad: Vec<f32>,
    pub(crate) shards: Vec<Shard>,
    /// One thread per shard after the first, started at the first [`Self::gradient`] and
    /// kept until the update is dropped: a minibatch step costs two channel messages per
    /// worker instead of a thread start (which took ~30 % of the step on this VM).
    workers: Vec<GradWorker>,
}

/// One minibatch shard handed to a [`GradWorker`]: the shard moves to the worker and back
/// (its buffers are reused, nothing is copied).
struct GradJob {
    shard: Shard,
    theta: Arc<Vec<f32>>,
    total: usize,
    cfg: LossCfg,
}

/// A thread that computes [`Shard::loss_grad`] for the jobs it receives, in order.
struct GradWorker {
    jobs: Option<mpsc::Sender<GradJob>>,
    done: mpsc::Receiver<(Shard, LossSums)>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl GradWorker {
    fn start(layout: Layout, spec: NetSpec) -> std::io::Result<Self> {
        let (jobs, job_rx) = mpsc::channel::<GradJob>();
        let (done_tx, done) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("ppo-grad".into())
            .spawn(move || {
                for job in job_rx {
                    let GradJob {
                        mut shard,
                        theta,
                        total,
                        cfg,
                    } = job;
                    let view = HostView {
                        theta: &theta,
                        layout: &layout,
                        spec: &spec,
                    };
                    let sums = shard.loss_grad(&view, total, cfg);
                    // The parameters' handle goes before the answer, so the owner's
                    // `Arc::get_mut` in `apply` finds it unshared.
                    drop(theta);
                    if done_tx.send((shard, sums)).is_err() {
                        return;
                    }
                }
            })?;
        Ok(Self {
            jobs: Some(jobs),
            done,
            thread: Some(thread),
        })
    }

    /// The payload of the panic that ended the worker's thread (joins it).
    fn panic(&mut self) -> Box<dyn std::any::Any + Send> {
        match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Err(payload)) => payload,
            _ => Box::new("a PPO gradient worker thread ended without an answer"),
        }
    }
}

impl Drop for GradWorker {
    fn drop(&mut self) {
        self.jobs = None; // closes the channel: the thread's loop ends
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl std::fmt::Debug for HostUpdate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HostUpdate")
            .field("spec", &self.spec)
            .field("t", &self.t)
            .field("shards", &self.shards.len())
            .field("workers", &self.workers.len())
            .finish_non_exhaustive()
    }
}

/// Adam settings of one step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AdamCfg {
    pub(crate) lr: f64,
    pub(crate) beta1: f64,
    pub(crate) beta2: f64,
    pub(crate) eps: f64,
    pub(crate) max_grad_norm: f64,
}

/// What one minibatch step reports (means over the minibatch).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct StepReport {
    pub(crate) policy: f64,
    pub(crate) value: f64,
    pub(crate) entropy: f64,
    pub(crate) approx_kl: f64,
    pub(crate) clip_fraction: f64,
}

impl HostUpdate {
    /// State for `threads` shards from the flat parameters and Adam moments; `None` when the
    /// action space is wider than [`MAX_ACT_DIM`].
    pub(crate) fn new(
        spec: NetSpec,
        theta: Vec<f32>,
        m: Vec<f32>,
        v: Vec<f32>,
        t: i64,
        threads: usize,
    ) -> Option<Self> {
        if spec.act_dim > MAX_ACT_DIM {
            return None;
        }
        let layout = spec.layout();
        Some(Self {
            grad: vec![0.0; layout.len],
            spec,
            layout,
            theta: Arc::new(theta),
            m,
            v,
            t,
            shards: vec![Shard::default(); threads.max(1)],
            workers: Vec::new(),
        })
    }

    /// Splits the minibatch rows `idx` of the rollout (`obs`, … as flat row-major vectors)
    /// over the shards; advantages are normalised over the minibatch (zero mean, unit
    /// sample std, as [`super::loss::normalize_advantages`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn load(
        &mut self,
        obs: &[f32],
        actions: &[f32],
        logp: &[f32],
        adv: &[f32],
        returns: &[f32],
        idx: &[i64],
    ) {
        let (d, a) = (self.spec.obs_dim, self.spec.act_dim);
        let b = idx.len();
        let (mean, inv) = if b >= 2 {
            let mean = idx.iter().map(|&i| f64::from(adv[i as usize])).sum::<f64>() / b as f64;
            let var = idx
                .iter()
                .map(|&i| (f64::from(adv[i as usize]) - mean).powi(2))
                .sum::<f64>()
                / (b - 1) as f64;
            (mean as f32, (1.0 / (var.sqrt() + 1e-8)) as f32)
        } else {
            (0.0, 1.0)
        };
        let per = b.div_ceil(self.shards.len());
        for (k, shard) in self.shards.iter_mut().enumerate() {
            let r = &mut shard.rows;
            r.clear();
            let part = idx.get(k * per..((k + 1) * per).min(b)).unwrap_or(&[]);
            for &i in part {
                let i = i as usize;
                r.obs.extend_from_slice(&obs[i * d..(i + 1) * d]);
                r.actions.extend_from_slice(&actions[i * a..(i + 1) * a]);
                r.logp_old.push(logp[i]);
                r.adv.push((adv[i] - mean) * inv);
                r.returns.push(returns[i]);
            }
            r.n = part.len();
        }
    }

    /// The gradient of the loss over the loaded minibatch (shards 1.. on the worker threads
    /// when there are several), into `self.grad`; returns the loss pieces.
    pub(crate) fn gradient(&mut self, cfg: LossCfg) -> StepReport {
        let total: usize = self.shards.iter().map(|s| s.rows.n).sum();
        let mut sums = LossSums::default();
        if self.shards.len() > 1 && self.workers.is_empty() {
            self.workers = (1..self.shards.len())
                .map_while(|_| GradWorker::start(self.layout.clone(), self.spec.clone()).ok())
                .collect();
        }
        // Shards 1.. go to the workers (those that could not be started, if any, are done
        // here after shard 0); the answers are taken back in shard order.
        let mut sent = Vec::with_capacity(self.workers.len());
        for (k, w) in self.workers.iter().enumerate() {
            let Some(tx) = w.jobs.as_ref() else {
                continue; // closed only in `drop`: the shard stays here
            };
            let job = GradJob {
                shard: std::mem::take(&mut self.shards[k + 1]),
                theta: Arc::clone(&self.theta),
                total,
                cfg,
            };
            match tx.send(job) {
                Ok(()) => sent.push(k),
                Err(mpsc::SendError(job)) => self.shards[k + 1] = job.shard,
            }
        }
        let view = HostView {
            theta: &self.theta,
            layout: &self.layout,
            spec: &self.spec,
        };
        for (k, shard) in self.shards.iter_mut().enumerate() {
            if k == 0 || !sent.contains(&(k - 1)) {
                sums += shard.loss_grad(&view, total, cfg);
            }
        }
        for k in sent {
            let (shard, part) = match self.workers[k].done.recv() {
                Ok(answer) => answer,
                // The worker stopped without answering: it panicked (a bug, as it would be
                // here); its shard went with it, so the panic goes on in this thread.
                Err(mpsc::RecvError) => std::panic::resume_unwind(self.workers[k].panic()),
            };
            self.shards[k + 1] = shard;
            sums += part;
        }
        // Sum of the shards' gradients in shard order (fixed, so reproducible).
        self.grad.copy_from_slice(&self.shards[0].grad);
        for sh in &self.shards[1..] {
            for (g, x) in self.grad.iter_mut().zip(&sh.grad) {
                *g += x;
            }
        }
        // Entropy bonus: d(−c·Σ(log_std + ½ + ½ln2π))/d log_std = −c.
        let a = self.spec.act_dim;
        let ls = self.layout.log_std_off;
        for g in &mut self.grad[ls..ls + a] {
            *g -= cfg.ent_coef;
        }
        let entropy: f64 = self.theta[ls..ls + a]
            .iter()
            .map(|l| f64::from(*l) + 0.5 + f64::from(HALF_LOG_2PI))
            .sum();
        let nb = total.max(1) as f64;
        StepReport {
            policy: sums.policy / nb,
            value: sums.value / nb,
            entropy,
            approx_kl: sums.approx_kl / nb,
            clip_fraction: sums.clipped / nb,
        }
    }

    /// The current parameters.
    pub(crate) fn theta(&self) -> &[f32] {
        &self.theta
    }

    /// The current gradient (after [`Self::gradient`]).
    #[cfg(test)]
    pub(crate) fn grad(&self) -> &[f32] {
        &self.grad
    }

    /// Clips the gradient's norm to `max_grad_norm` and takes one Adam step (as
    /// [`crate::adam::clip_grad_norm`] then [`crate::adam::Adam::step`]).
    pub(crate) fn apply(&mut self, c: AdamCfg) {
        let norm = self
            .grad
            .iter()
            .map(|g| f64::from(*g) * f64::from(*g))
            .sum::<f64>()
            .sqrt();
        if norm > c.max_grad_norm && norm.is_finite() {
            let k = (c.max_grad_norm / (norm + 1e-6)) as f32;
            self.grad.iter_mut().for_each(|g| *g *= k);
        }
        self.t += 1;
        let bc1 = 1.0 - c.beta1.powi(self.t as i32);
        let bc2 = 1.0 - c.beta2.powi(self.t as i32);
        let (b1, b2) = (c.beta1 as f32, c.beta2 as f32);
        let (ob1, ob2) = ((1.0 - c.beta1) as f32, (1.0 - c.beta2) as f32);
        let inv_bc2 = (1.0 / bc2) as f32;
        let step = (c.lr / bc1) as f32;
        let eps = c.eps as f32;
        for (((th, m), v), g) in Arc::make_mut(&mut self.theta)
            .iter_mut()
            .zip(&mut self.m)
            .zip(&mut self.v)
            .zip(&self.grad)
        {
            *m = *m * b1 + g * ob1;
            *v = *v * b2 + g * g * ob2;
            let denom = (*v * inv_bc2).sqrt() + eps;
            *th -= (*m / denom) * step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adam::{Adam, clip_grad_norm};
    use crate::net::ActorCritic;
    use crate::ppo::loss::ppo_loss;
    use crate::random::randn;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use tch::{Device, Tensor};

    fn spec() -> NetSpec {
        NetSpec {
            obs_dim: 29,
            act_dim: 3,
            hidden: vec![128, 128],
        }
    }

    fn randv(rng: &mut ChaCha8Rng, n: usize, scale: f32) -> Vec<f32> {
        (0..n).map(|_| randn(rng) * scale).collect()
    }

    /// A network with non-trivial output layers and log-std (the init's 0.01 gain and zero
    /// log-std would hide errors in those gradients).
    fn net(seed: u64) -> ActorCritic {
        let s = spec();
        let base = ActorCritic::new(s.clone(), Device::Cpu, seed);
        let mut flat = base.flat();
        let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
        for x in &mut flat {
            *x += randn(&mut rng) * 0.05;
        }
        let l = s.layout();
        for j in 0..s.act_dim {
            flat[l.log_std_off + j] = -0.5 + 0.3 * j as f32;
        }
        ActorCritic::from_flat(s, &flat, Device::Cpu).unwrap()
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn fast_tanh_is_within_4_ulp_in_every_build() {
        let mut xs: Vec<f32> = (0..64_000).map(|i| -12.0 + i as f32 * 0.000_375).collect();
        let exact: Vec<f32> = xs.iter().map(|x| f64::from(*x).tanh() as f32).collect();
        let mut portable = xs.clone();
        tanh_body(&mut portable);
        #[cfg(target_arch = "x86_64")]
        for (feature, build) in [
            ("avx2", tanh_avx2 as unsafe fn(&mut [f32])),
            ("avx512f", tanh_avx512),
        ] {
            if std::arch::is_x86_feature_detected!("avx2")
                && (feature == "avx2" || std::arch::is_x86_feature_detected!("avx512f"))
            {
                let mut v = xs.clone();
                // SAFETY: the CPU has the build's feature (checked just above).
                unsafe { build(&mut v) };
                assert_eq!(v, portable, "the {feature} build differs");
            }
        }
        tanh_slice(&mut xs);
        assert_eq!(xs, portable, "builds differ");
        for (g, e) in xs.iter().zip(&exact) {
            let ulp = (i64::from(g.to_bits() as i32) - i64::from(e.to_bits() as i32)).abs();
            assert!(ulp <= 4, "tanh {g} vs {e}");
        }
    }

    #[test]
    fn host_forward_matches_the_tch_forward() {
        let net = net(3);
        let host = HostNet::of(&net);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut work = ForwardWork::default();
        for n in [1usize, 7, 32, 257] {
            let obs = randv(&mut rng, n * 29, 2.0);
            let (mean_t, val_t) = super::super::rollout::forward(&net, &obs, n, true);
            let mut mean = vec![0.0; n * 3];
            let mut val = vec![0.0; n];
            host.forward(&obs, n, &mut work, &mut mean, Some(&mut val));
            assert!(max_abs_diff(&mean, &mean_t) <= 1e-5, "means, n = {n}");
            assert!(max_abs_diff(&val, &val_t) <= 1e-5, "values, n = {n}");
        }
    }

    struct Data {
        obs: Vec<f32>,
        act: Vec<f32>,
        logp_old: Vec<f32>,
        adv: Vec<f32>,
        ret: Vec<f32>,
    }

    /// `n` rows whose old log-probabilities are the current ones shifted by ±0.4, so that
    /// some ratios fall outside the clip range on both sides.
    fn data(net: &ActorCritic, n: usize, seed: u64) -> Data {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let obs = randv(&mut rng, n * 29, 1.5);
        let act = randv(&mut rng, n * 3, 0.8);
        let lp = tch::no_grad(|| {
            net.log_prob_entropy(
                &Tensor::from_slice(&obs).view([n as i64, 29]),
                &Tensor::from_slice(&act).view([n as i64, 3]),
            )
            .0
        });
        let lp: Vec<f32> = Vec::try_from(lp).unwrap();
        let logp_old = lp.iter().map(|l| l + randn(&mut rng) * 0.4).collect();
        Data {
            obs,
            act,
            logp_old,
            adv: randv(&mut rng, n, 2.0).iter().map(|a| a + 0.3).collect(),
            ret: randv(&mut rng, n, 1.0),
        }
    }

    fn tch_grad(net: &ActorCritic, d: &Data, n: usize, cfg: LossCfg) -> (Vec<f32>, f64, f64) {
        let p = ppo_loss(
            net,
            &Tensor::from_slice(&d.obs).view([n as i64, 29]),
            &Tensor::from_slice(&d.act).view([n as i64, 3]),
            &Tensor::from_slice(&d.logp_old),
            &Tensor::from_slice(&d.adv),
            &Tensor::from_slice(&d.ret),
            f64::from(cfg.clip),
        );
        let loss =
            &p.policy + &p.value * f64::from(cfg.vf_coef) - &p.entropy * f64::from(cfg.ent_coef);
        let mut theta = net.theta.shallow_clone();
        theta.zero_grad();
        loss.backward();
        let g: Vec<f32> = Vec::try_from(net.theta.grad().detach()).unwrap();
        (
            g,
            p.policy.double_value(&[]),
            p.clip_fraction.double_value(&[]),
        )
    }

    fn host_update(net: &ActorCritic, d: &Data, n: usize, threads: usize) -> HostUpdate {
        let len = net.layout.len;
        let mut h = HostUpdate::new(
            spec(),
            net.flat(),
            vec![0.0; len],
            vec![0.0; len],
            0,
            threads,
        )
        .unwrap();
        let idx: Vec<i64> = (0..n as i64).collect();
        h.load(&d.obs, &d.act, &d.logp_old, &d.adv, &d.ret, &idx);
        h
    }

    #[test]
    fn host_gradient_matches_tch_autograd_of_the_ppo_loss() {
        let cfg = LossCfg {
            clip: 0.2,
            vf_coef: 0.5,
            ent_coef: 0.01,
        };
        let n = 301;
        let net = net(5);
        let d = data(&net, n, 6);
        let (g_t, policy_t, cf_t) = tch_grad(&net, &d, n, cfg);
        for threads in [1, 2, 3] {
            let mut h = host_update(&net, &d, n, threads);
            let r = h.gradient(cfg);
            let scale = g_t.iter().map(|g| g.abs()).fold(0.0, f32::max);
            let err = max_abs_diff(h.grad(), &g_t);
            assert!(
                err <= 1e-4 * scale,
                "threads {threads}: max |Δgrad| {err} (max |grad| {scale})"
            );
            assert!((r.policy - policy_t).abs() < 1e-5, "{r:?} vs {policy_t}");
            assert!((r.clip_fraction - cf_t).abs() < 1e-6, "{r:?} vs {cf_t}");
            assert!(
                r.clip_fraction > 0.2,
                "the data must exercise clipping: {r:?}"
            );
        }
    }

    #[test]
    fn host_step_matches_grad_clipping_and_adam_on_tensors() {
        let cfg = LossCfg {
            clip: 0.2,
            vf_coef: 0.5,
            ent_coef: 0.0,
        };
        let n = 128;
        let net = net(7);
        let d = data(&net, n, 8);
        let mut adam = Adam::new(&net.theta, 3e-4);
        let mut h = host_update(&net, &d, n, 2);
        let adam_cfg = AdamCfg {
            lr: adam.lr,
            beta1: adam.beta1,
            beta2: adam.beta2,
            eps: adam.eps,
            max_grad_norm: 0.5,
        };
        for _ in 0..3 {
            let (g, _, _) = tch_grad(&net, &d, n, cfg);
            let grad = Tensor::from_slice(&g);
            clip_grad_norm(&grad, 0.5);
            adam.step(&net.theta, &grad);
            h.gradient(cfg);
            h.apply(adam_cfg);
        }
        let err = max_abs_diff(h.theta(), &net.flat());
        assert!(err < 1e-6, "parameters differ by {err}");
        let m: Vec<f32> = Vec::try_from(adam.m.shallow_clone()).unwrap();
        assert!(max_abs_diff(&h.m, &m) < 1e-7);
        assert_eq!(h.t, adam.t);
    }

    #[test]
    fn host_update_is_bit_reproducible_for_a_thread_count() {
        let cfg = LossCfg {
            clip: 0.2,
            vf_coef: 0.5,
            ent_coef: 0.0,
        };
        let net = net(9);
        let d = data(&net, 200, 10);
        let run = || {
            let mut h = host_update(&net, &d, 200, 2);
            h.gradient(cfg);
            h.grad().to_vec()
        };
        assert!(run() == run());
    }
}
