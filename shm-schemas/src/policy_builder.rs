//! [`PolicyBlobBuilder`]: assembles a [`PolicyBlob`] from plain weight matrices — for the
//! learner's export, for tests and for benches with a random policy. Allocates; it is not
//! meant for the real-time path.
//!
//! ```
//! use shm_schemas::{Activation, PolicyBlobBuilder};
//! // 2 → 3 (tanh) → 1, weights row-major [out, in].
//! let blob = PolicyBlobBuilder::new(7, 0xfeed)
//!     .activation(Activation::Tanh)
//!     .layer(2, 3, &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6], &[0.0, 0.0, 0.0])
//!     .layer(3, 1, &[1.0, -1.0, 0.5], &[0.1])
//!     .build()
//!     .unwrap();
//! assert!(blob.validate().is_ok());
//! assert_eq!((blob.obs_dim, blob.act_dim, blob.n_weights), (2, 1, 13));
//! ```

use crate::error::SchemaError;
use crate::policy_blob::{
    ActionSpace, Activation, MAX_ACT, MAX_HIDDEN_LAYERS, MAX_HIDDEN_WIDTH, MAX_OBS, MAX_WEIGHTS,
    POLICY_FORMAT_VERSION, PolicyBlob,
};

/// Why a [`PolicyBlobBuilder`] could not produce a blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PolicyBuildError {
    /// No layer was added.
    #[error("the network has no layers")]
    NoLayers,
    /// More hidden layers than [`MAX_HIDDEN_LAYERS`].
    #[error("{0} hidden layers exceed the maximum {MAX_HIDDEN_LAYERS}")]
    TooManyLayers(usize),
    /// A layer's input width differs from the previous layer's output width.
    #[error("layer {0}: input width does not match the previous layer's output")]
    DimensionChain(usize),
    /// A layer's weight or bias slice has the wrong length.
    #[error("layer {0}: weight or bias length does not match its dimensions")]
    LayerLength(usize),
    /// A dimension exceeds the blob's capacity (obs, hidden width, action or weights).
    #[error("a dimension exceeds the blob capacity ({0})")]
    Capacity(&'static str),
    /// The normalisation or action-scale vectors do not match the network's dimensions.
    #[error("normalisation/scaling vector length mismatch ({0})")]
    VectorLength(&'static str),
    /// The finished blob failed [`PolicyBlob::validate`] (e.g. NaN weights).
    #[error("the finished blob is invalid: {0}")]
    Invalid(SchemaError),
}

#[derive(Debug, Clone)]
struct Dense {
    in_dim: usize,
    out_dim: usize,
    weights: Vec<f32>,
    bias: Vec<f32>,
}

/// Builds a [`PolicyBlob`] from dense layers. Defaults: tanh hidden activation, identity
/// output, observation mean 0 / std 1 / clip 10, action scale 1 / clip 1.
#[derive(Debug, Clone)]
pub struct PolicyBlobBuilder {
    policy_id: u64,
    task_config_hash: u64,
    activation: Activation,
    output_activation: Activation,
    layers: Vec<Dense>,
    obs_mean: Option<Vec<f32>>,
    obs_std: Option<Vec<f32>>,
    obs_clip: f32,
    action_scale: Option<Vec<f32>>,
    action_clip: f32,
    action_space: ActionSpace,
}

impl PolicyBlobBuilder {
    /// An empty network for the given policy id and task-config hash.
    pub fn new(policy_id: u64, task_config_hash: u64) -> Self {
        Self {
            policy_id,
            task_config_hash,
            activation: Activation::Tanh,
            output_activation: Activation::Identity,
            layers: Vec::new(),
            obs_mean: None,
            obs_std: None,
            obs_clip: 10.0,
            action_scale: None,
            action_clip: 1.0,
            action_space: ActionSpace::CartesianStep,
        }
    }

    /// A network with deterministic pseudo-random weights (uniform in ±1/√in, biases
    /// ±0.1) from `seed`: for benches and tests.
    pub fn random(
        policy_id: u64,
        task_config_hash: u64,
        obs_dim: usize,
        hidden: &[usize],
        act_dim: usize,
        seed: u64,
    ) -> Self {
        let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
        let mut next = move || {
            // splitmix64
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            // uniform in [-1, 1)
            ((z >> 40) as f32 / (1u64 << 23) as f32) - 1.0
        };
        let mut b = Self::new(policy_id, task_config_hash);
        let mut in_dim = obs_dim;
        for &out_dim in hidden.iter().chain(core::iter::once(&act_dim)) {
            let scale = 1.0 / (in_dim.max(1) as f32).sqrt();
            let w: Vec<f32> = (0..in_dim * out_dim).map(|_| next() * scale).collect();
            let bias: Vec<f32> = (0..out_dim).map(|_| next() * 0.1).collect();
            b = b.layer(in_dim, out_dim, &w, &bias);
            in_dim = out_dim;
        }
        b
    }

    /// Hidden-layer activation.
    pub fn activation(mut self, activation: Activation) -> Self {
        self.activation = activation;
        self
    }

    /// The action space (default [`ActionSpace::CartesianStep`]); the blob records the
    /// space's observation layout with it ([`ActionSpace::obs_layout`]).
    pub fn action_space(mut self, space: ActionSpace) -> Self {
        self.action_space = space;
        self
    }

    /// Output activation.
    pub fn output_activation(mut self, activation: Activation) -> Self {
        self.output_activation = activation;
        self
    }

    /// Appends a dense layer: `weights` row-major `[out_dim, in_dim]` (PyTorch's
    /// `nn.Linear.weight` flattened), `bias` of length `out_dim`. The last layer added is
    /// the output layer.
    pub fn layer(mut self, in_dim: usize, out_dim: usize, weights: &[f32], bias: &[f32]) -> Self {
        self.layers.push(Dense {
            in_dim,
            out_dim,
            weights: weights.to_vec(),
            bias: bias.to_vec(),
        });
        self
    }

    /// Observation normalisation: `clamp((obs - mean) / std, -clip, clip)`.
    pub fn obs_normalization(mut self, mean: &[f32], std: &[f32], clip: f32) -> Self {
        self.obs_mean = Some(mean.to_vec());
        self.obs_std = Some(std.to_vec());
        self.obs_clip = clip;
        self
    }

    /// Action post-processing: `clamp(y, -clip, clip) * scale`.
    pub fn action_scaling(mut self, scale: &[f32], clip: f32) -> Self {
        self.action_scale = Some(scale.to_vec());
        self.action_clip = clip;
        self
    }

    fn check(&self) -> Result<(usize, usize, usize), PolicyBuildError> {
        let first = self.layers.first().ok_or(PolicyBuildError::NoLayers)?;
        let n_hidden = self.layers.len() - 1;
        if n_hidden > MAX_HIDDEN_LAYERS {
            return Err(PolicyBuildError::TooManyLayers(n_hidden));
        }
        let obs_dim = first.in_dim;
        let mut prev = obs_dim;
        let mut total = 0usize;
        for (i, l) in self.layers.iter().enumerate() {
            if l.in_dim != prev {
                return Err(PolicyBuildError::DimensionChain(i));
            }
            if l.weights.len() != l.in_dim * l.out_dim || l.bias.len() != l.out_dim {
                return Err(PolicyBuildError::LayerLength(i));
            }
            if i < n_hidden && (l.out_dim == 0 || l.out_dim > MAX_HIDDEN_WIDTH) {
                return Err(PolicyBuildError::Capacity("hidden width"));
            }
            total += l.weights.len() + l.bias.len();
            prev = l.out_dim;
        }
        let act_dim = prev;
        if obs_dim == 0 || obs_dim > MAX_OBS {
            return Err(PolicyBuildError::Capacity("obs_dim"));
        }
        if act_dim == 0 || act_dim > MAX_ACT {
            return Err(PolicyBuildError::Capacity("act_dim"));
        }
        if total > MAX_WEIGHTS {
            return Err(PolicyBuildError::Capacity("weights"));
        }
        if self.obs_mean.as_ref().is_some_and(|m| m.len() != obs_dim) {
            return Err(PolicyBuildError::VectorLength("obs_mean"));
        }
        if self.obs_std.as_ref().is_some_and(|s| s.len() != obs_dim) {
            return Err(PolicyBuildError::VectorLength("obs_std"));
        }
        if self
            .action_scale
            .as_ref()
            .is_some_and(|s| s.len() != act_dim)
        {
            return Err(PolicyBuildError::VectorLength("action_scale"));
        }
        Ok((obs_dim, act_dim, total))
    }

    /// Writes the whole blob into `blob` (every header field, every slot of the header
    /// arrays, the used weights), seals it and validates it. Pair with
    /// [`PolicyBlob::init_zeroed`] on a loaned sample to publish without a stack copy.
    ///
    /// # Errors
    /// [`PolicyBuildError`] for an inconsistent network or an invalid result.
    pub fn write_into(&self, blob: &mut PolicyBlob) -> Result<(), PolicyBuildError> {
        let (obs_dim, act_dim, total) = self.check()?;
        let n_hidden = self.layers.len() - 1;
        blob.format_version = POLICY_FORMAT_VERSION;
        blob.activation = self.activation as u8;
        blob.output_activation = self.output_activation as u8;
        blob.n_hidden = n_hidden as u8;
        blob.action_space = self.action_space as u8;
        blob.policy_id = self.policy_id;
        blob.task_config_hash = self.task_config_hash;
        blob.obs_dim = obs_dim as u32;
        blob.act_dim = act_dim as u32;
        blob.hidden_sizes = [0; MAX_HIDDEN_LAYERS];
        for (slot, l) in blob.hidden_sizes.iter_mut().zip(&self.layers[..n_hidden]) {
            *slot = l.out_dim as u32;
        }
        blob.n_weights = total as u32;
        blob.obs_clip = self.obs_clip;
        blob.action_clip = self.action_clip;
        blob.obs_layout = self.action_space.obs_layout();
        blob.obs_mean = [0.0; MAX_OBS];
        blob.obs_std = [1.0; MAX_OBS];
        blob.action_scale = [1.0; MAX_ACT];
        if let Some(m) = &self.obs_mean {
            blob.obs_mean[..obs_dim].copy_from_slice(m);
        }
        if let Some(s) = &self.obs_std {
            blob.obs_std[..obs_dim].copy_from_slice(s);
        }
        if let Some(s) = &self.action_scale {
            blob.action_scale[..act_dim].copy_from_slice(s);
        }
        let mut at = 0usize;
        for l in &self.layers {
            blob.weights[at..at + l.weights.len()].copy_from_slice(&l.weights);
            at += l.weights.len();
            blob.weights[at..at + l.bias.len()].copy_from_slice(&l.bias);
            at += l.bias.len();
        }
        blob.weights[at..].fill(0.0);
        blob.seal();
        blob.validate().map_err(PolicyBuildError::Invalid)
    }

    /// Builds the blob on the heap.
    ///
    /// # Errors
    /// As [`Self::write_into`].
    pub fn build(&self) -> Result<Box<PolicyBlob>, PolicyBuildError> {
        let mut blob = PolicyBlob::new_boxed();
        self.write_into(&mut blob)?;
        Ok(blob)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_is_per_layer_w_then_b() {
        let blob = PolicyBlobBuilder::new(1, 2)
            .layer(2, 2, &[1.0, 2.0, 3.0, 4.0], &[5.0, 6.0])
            .layer(2, 1, &[7.0, 8.0], &[9.0])
            .build()
            .unwrap();
        assert_eq!(
            &blob.weights[..9],
            &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
        );
        assert_eq!(blob.hidden(), &[2]);
        let out = blob.layer(1).unwrap();
        assert_eq!(
            (out.in_dim, out.out_dim, out.weights, out.bias),
            (2, 1, &[7.0, 8.0][..], &[9.0][..])
        );
    }

    #[test]
    fn rejects_broken_chains_and_lengths() {
        let e = PolicyBlobBuilder::new(1, 2)
            .layer(2, 3, &[0.0; 6], &[0.0; 3])
            .layer(2, 1, &[0.0; 2], &[0.0])
            .build()
            .unwrap_err();
        assert_eq!(e, PolicyBuildError::DimensionChain(1));
        let e = PolicyBlobBuilder::new(1, 2)
            .layer(2, 1, &[0.0; 3], &[0.0])
            .build()
            .unwrap_err();
        assert_eq!(e, PolicyBuildError::LayerLength(0));
        assert_eq!(
            PolicyBlobBuilder::new(1, 2).build().unwrap_err(),
            PolicyBuildError::NoLayers
        );
    }

    #[test]
    fn nan_weights_fail_validation() {
        let e = PolicyBlobBuilder::new(1, 2)
            .layer(1, 1, &[f32::NAN], &[0.0])
            .build()
            .unwrap_err();
        assert_eq!(
            e,
            PolicyBuildError::Invalid(SchemaError::NonFinite { field: "weights" })
        );
    }

    #[test]
    fn random_reference_network_fits() {
        let blob = PolicyBlobBuilder::random(3, 4, 17, &[256, 256], 3, 42)
            .build()
            .unwrap();
        assert_eq!(blob.n_weights, 71_171);
        assert!(blob.weights[..71_171].iter().all(|w| w.abs() <= 0.25));
        let again = PolicyBlobBuilder::random(3, 4, 17, &[256, 256], 3, 42)
            .build()
            .unwrap();
        assert_eq!(blob.checksum, again.checksum);
    }
}
