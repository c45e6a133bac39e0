//! [`MlpPolicy`]: a [`PolicyBlob`]'s network copied into buffers allocated once, evaluated
//! without allocation (the deterministic mean action).

use shm_schemas::{
    ActionSpace, Activation, JOINT_ACT_DIM, MAX_ACT, MAX_HIDDEN_LAYERS, MAX_HIDDEN_WIDTH, MAX_OBS,
    MAX_WEIGHTS, PolicyBlob,
};

use super::kernel::{COLUMN_BLOCK, Simd, columns, rows, tanh};
use shm_schemas::{ACT_DIM, OBS_DIM};

/// Widest vector any layer reads or writes.
const MAX_WIDTH: usize = {
    let mut w = MAX_HIDDEN_WIDTH;
    if MAX_OBS > w {
        w = MAX_OBS;
    }
    if MAX_ACT > w {
        w = MAX_ACT;
    }
    w
};

/// Most dense layers (hidden + output).
const MAX_LAYERS: usize = MAX_HIDDEN_LAYERS + 1;

/// Layers at least this wide are stored transposed for the column kernel; narrower ones
/// (the action head) stay row-major.
const COLUMN_MIN_OUT: usize = 16;

/// Capacity of the policy's weight buffer: the blob capacity plus the worst-case padding
/// of transposed layers (each input row padded to a multiple of [`COLUMN_BLOCK`]).
const BUFFER_CAPACITY: usize = MAX_WEIGHTS + MAX_LAYERS * MAX_WIDTH * COLUMN_BLOCK;

/// One dense layer's place in the weight buffer.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct DenseSpec {
    in_dim: usize,
    out_dim: usize,
    /// Start of the layer's weights in the buffer; the bias (`out_dim` values) follows them.
    offset: usize,
    /// 0: weights row-major `[out, in]`; otherwise transposed, `wt[j * stride + o]`.
    stride: usize,
}

impl DenseSpec {
    fn weights_len(&self) -> usize {
        if self.stride == 0 {
            self.in_dim * self.out_dim
        } else {
            self.in_dim * self.stride
        }
    }
}

/// Why [`MlpPolicy::evaluate`] refused its arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PolicyEvalError {
    /// No network is loaded.
    #[error("no policy loaded")]
    Empty,
    /// `obs` or `out` has a length other than the policy's dimensions.
    #[error("observation/action length does not match the policy")]
    DimensionMismatch,
}

/// A multilayer perceptron ready for the real-time path.
///
/// All memory is allocated by [`MlpPolicy::with_capacity`] (one weight buffer sized to the
/// blob format's [`MAX_WEIGHTS`] plus layout padding, fixed arrays for everything else); loading another blob
/// into it (`MlpPolicy::load_from`, used by [`super::PolicyLoader::prepare_into`]) and
/// evaluating it ([`MlpPolicy::act`]) never allocate. Scratch vectors live on the stack
/// (2 × 1 KB), so `act` takes `&self` and a policy can be shared read-only between threads.
///
/// # Performance
/// Wide layers are stored transposed and evaluated 32–64 outputs at a time in registers
/// (vectorised; an AVX2 build is picked at construction when the CPU has it), the narrow
/// action head as row dot products with eight lane accumulators, and `tanh` is a fast,
/// vectorisable 4-ulp version. The summation order is fixed, so results are bit-identical across runs
/// and kernel builds. See `benches/policy.rs` for figures.
#[derive(Debug, Clone)]
pub struct MlpPolicy {
    policy_id: u64,
    task_config_hash: u64,
    action_space: ActionSpace,
    obs_dim: usize,
    act_dim: usize,
    n_layers: usize,
    layers: [DenseSpec; MAX_LAYERS],
    activation: Activation,
    output_activation: Activation,
    obs_mean: [f32; MAX_OBS],
    obs_std: [f32; MAX_OBS],
    obs_clip: f32,
    action_scale: [f32; MAX_ACT],
    action_clip: f32,
    weights: Box<[f32]>,
    simd: Simd,
}

impl MlpPolicy {
    /// An empty policy holding buffers for the largest network a blob can describe (the
    /// only allocation this type makes). [`Self::is_loaded`] is `false` until
    /// `Self::load_from`.
    pub fn with_capacity() -> Self {
        Self {
            policy_id: 0,
            task_config_hash: 0,
            action_space: ActionSpace::CartesianStep,
            obs_dim: 0,
            act_dim: 0,
            n_layers: 0,
            layers: [DenseSpec::default(); MAX_LAYERS],
            activation: Activation::Tanh,
            output_activation: Activation::Identity,
            obs_mean: [0.0; MAX_OBS],
            obs_std: [1.0; MAX_OBS],
            obs_clip: 0.0,
            action_scale: [0.0; MAX_ACT],
            action_clip: 0.0,
            weights: vec![0.0; BUFFER_CAPACITY].into_boxed_slice(),
            simd: Simd::detect(),
        }
    }

    /// Copies a blob's network into this policy's buffers. No allocation.
    ///
    /// `blob` must be the loader's private copy that has just passed
    /// [`PolicyBlob::validate`] ([`super::PolicyLoader`] guarantees both: it takes only
    /// `&Box<PolicyBlob>`), never a shared-memory sample another process can still write.
    /// A blob whose activation bytes are invalid leaves the policy unloaded; out-of-range
    /// clip values cannot make evaluation panic (see [`clip`]).
    pub(crate) fn load_from(&mut self, blob: &PolicyBlob) {
        self.n_layers = 0;
        let (Ok(activation), Ok(output_activation), Ok(action_space)) = (
            Activation::try_from(blob.activation),
            Activation::try_from(blob.output_activation),
            ActionSpace::try_from(blob.action_space),
        ) else {
            return;
        };
        let mut offset = 0usize;
        let mut n_layers = 0usize;
        for i in 0..blob.n_layers().min(MAX_LAYERS) {
            let Some(layer) = blob.layer(i) else {
                return;
            };
            let (n_in, n_out) = (layer.in_dim, layer.out_dim);
            let stride = if n_out >= COLUMN_MIN_OUT {
                n_out.div_ceil(COLUMN_BLOCK) * COLUMN_BLOCK
            } else {
                0
            };
            let spec = DenseSpec {
                in_dim: n_in,
                out_dim: n_out,
                offset,
                stride,
            };
            let w_end = offset + spec.weights_len();
            let b_end = w_end + n_out;
            if b_end > self.weights.len() || n_in > MAX_WIDTH || n_out > MAX_WIDTH {
                return;
            }
            let dst = &mut self.weights[offset..w_end];
            if stride == 0 {
                dst.copy_from_slice(layer.weights);
            } else {
                dst.fill(0.0);
                for (o, row) in layer.weights.chunks_exact(n_in.max(1)).enumerate() {
                    for (j, w) in row.iter().enumerate() {
                        dst[j * stride + o] = *w;
                    }
                }
            }
            self.weights[w_end..b_end].copy_from_slice(layer.bias);
            self.layers[i] = spec;
            offset = b_end;
            n_layers += 1;
        }
        if n_layers != blob.n_layers() {
            return;
        }
        self.policy_id = blob.policy_id;
        self.task_config_hash = blob.task_config_hash;
        self.action_space = action_space;
        self.obs_dim = blob.obs_dim as usize;
        self.act_dim = blob.act_dim as usize;
        self.activation = activation;
        self.output_activation = output_activation;
        self.obs_mean = blob.obs_mean;
        self.obs_std = blob.obs_std;
        self.obs_clip = blob.obs_clip;
        self.action_scale = blob.action_scale;
        self.action_clip = blob.action_clip;
        self.n_layers = n_layers;
    }

    /// Whether a network is loaded.
    pub fn is_loaded(&self) -> bool {
        self.n_layers > 0
    }

    /// The loaded policy's id (0 when empty).
    pub fn policy_id(&self) -> u64 {
        if self.is_loaded() { self.policy_id } else { 0 }
    }

    /// The task-config hash the loaded policy was trained for.
    pub fn task_config_hash(&self) -> u64 {
        self.task_config_hash
    }

    /// The action space the policy's output lives in ([`Self::act`] for the Cartesian step,
    /// [`Self::act_joint`] for the joint step).
    pub fn action_space(&self) -> ActionSpace {
        self.action_space
    }

    /// Observation dimension (0 when empty).
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Action dimension (0 when empty).
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// The deterministic mean action for a twin observation. No allocation, no panic.
    ///
    /// For a policy prepared for the task's dimensions (the first `obs_dim` of the twin's
    /// [`OBS_DIM`] values → [`ACT_DIM`], which [`super::PolicyLoader::prepare`] with
    /// [`super::PolicyExpectation::for_task`] guarantees). Any other policy — or an empty one — yields the zero action (no
    /// motion); use [`Self::evaluate`] to see the error.
    pub fn act(&self, obs: &[f32; OBS_DIM]) -> [f32; ACT_DIM] {
        let mut out = [0.0; ACT_DIM];
        // The task's observation is a prefix of the twin's vector (`OBS_DIM` is the largest
        // a task can configure); a policy longer than the vector is refused by `evaluate`.
        let used = obs.get(..self.obs_dim).unwrap_or(obs.as_slice());
        if self.evaluate(used, &mut out).is_err() {
            out = [0.0; ACT_DIM];
        }
        out
    }

    /// The deterministic mean joint-step action of a joint-step policy for a twin observation
    /// of the joint-space layout (`shm_schemas::JOINT_OBS_DIM` values). No allocation, no
    /// panic; any other policy — or an empty one — yields the zero action (no motion).
    pub fn act_joint(&self, obs: &[f32; OBS_DIM]) -> [f32; JOINT_ACT_DIM] {
        let mut out = [0.0; JOINT_ACT_DIM];
        let used = obs.get(..self.obs_dim).unwrap_or(obs.as_slice());
        if self.action_space != ActionSpace::JointStep || self.evaluate(used, &mut out).is_err() {
            out = [0.0; JOINT_ACT_DIM];
        }
        out
    }

    /// Evaluates the network on `obs` (length `obs_dim`) into `out` (length `act_dim`).
    /// No allocation.
    ///
    /// # Errors
    /// [`PolicyEvalError`] when empty or the lengths differ from the policy's.
    pub fn evaluate(&self, obs: &[f32], out: &mut [f32]) -> Result<(), PolicyEvalError> {
        if !self.is_loaded() {
            return Err(PolicyEvalError::Empty);
        }
        if obs.len() != self.obs_dim || out.len() != self.act_dim {
            return Err(PolicyEvalError::DimensionMismatch);
        }
        let mut a = [0.0f32; MAX_WIDTH];
        let mut b = [0.0f32; MAX_WIDTH];
        let clip_obs = self.obs_clip;
        for (i, x) in a[..self.obs_dim].iter_mut().enumerate() {
            *x = clip((obs[i] - self.obs_mean[i]) / self.obs_std[i], clip_obs);
        }
        let (mut src, mut dst) = (&mut a, &mut b);
        for (k, layer) in self.layers[..self.n_layers].iter().enumerate() {
            let w_end = layer.offset + layer.weights_len();
            let w = &self.weights[layer.offset..w_end];
            let bias = &self.weights[w_end..w_end + layer.out_dim];
            let x = &src[..layer.in_dim];
            let act = if k + 1 == self.n_layers {
                self.output_activation
            } else {
                self.activation
            };
            let y = &mut dst[..layer.out_dim];
            if layer.stride == 0 {
                rows(w, x, bias, y);
            } else {
                columns(self.simd, w, layer.stride, x, bias, y);
            }
            match act {
                Activation::Identity => {}
                Activation::Tanh => y.iter_mut().for_each(|v| *v = tanh(*v)),
                Activation::Relu => y.iter_mut().for_each(|v| *v = v.max(0.0)),
            }
            core::mem::swap(&mut src, &mut dst);
        }
        let c = self.action_clip;
        for (j, o) in out.iter_mut().enumerate() {
            *o = clip(src[j], c) * self.action_scale[j];
        }
        Ok(())
    }
}

/// `x` limited to `[-c, c]`: the same as `x.clamp(-c, c)` for every `c` that validation
/// admits (finite and positive; a NaN `x` stays NaN), but never panics. `f32::clamp`
/// panics when its bounds are inverted or NaN, which a validated blob excludes; this keeps
/// evaluation panic-free even if a policy ever held other values (with a negative `c`
/// every result is `±c`, with a NaN `c` nothing is clipped).
#[inline(always)]
fn clip(x: f32, c: f32) -> f32 {
    if x > c {
        c
    } else if x < -c {
        -c
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::PolicyBlobBuilder;

    #[test]
    fn clip_matches_clamp_for_valid_bounds() {
        for c in [1e-6f32, 0.5, 1.0, 10.0, f32::MAX] {
            for x in [
                -f32::INFINITY,
                -20.0,
                -1.0,
                -0.0,
                0.0,
                0.25,
                1.0,
                3.0,
                f32::INFINITY,
            ] {
                assert_eq!(clip(x, c).to_bits(), x.clamp(-c, c).to_bits(), "{x} {c}");
            }
            assert!(clip(f32::NAN, c).is_nan());
        }
    }

    #[test]
    fn evaluation_never_panics_on_inverted_or_nan_clip_bounds() {
        // Loaded past the loader (no validation), as a blob changed after its check would
        // have been: `f32::clamp(-c, c)` panics for each of these.
        let obs = [0.5f32; OBS_DIM];
        for bad in [-1.0f32, f32::NAN, -f32::INFINITY] {
            let mut blob = PolicyBlobBuilder::random(4, 1, OBS_DIM, &[16], ACT_DIM, 5)
                .build()
                .unwrap();
            blob.obs_clip = bad;
            blob.action_clip = bad;
            let mut p = MlpPolicy::with_capacity();
            p.load_from(&blob);
            assert!(p.is_loaded());
            let _ = p.act(&obs);
        }
    }

    #[test]
    fn empty_policy_yields_zero_action_and_an_error() {
        let p = MlpPolicy::with_capacity();
        assert!(!p.is_loaded());
        assert_eq!(p.act(&[1.0; OBS_DIM]), [0.0; ACT_DIM]);
        let mut out = [0.0; ACT_DIM];
        assert_eq!(
            p.evaluate(&[1.0; OBS_DIM], &mut out),
            Err(PolicyEvalError::Empty)
        );
    }
}
