//! [`PolicyBlob`]: a trained MLP policy, self-contained in one fixed-size payload
//! (learner → rt-core).
//!
//! # Network
//! `n_hidden` hidden layers of widths `hidden_sizes[..n_hidden]` with the hidden
//! `activation`, then a linear output layer of `act_dim` units followed by
//! `output_activation`. Evaluation (the deterministic mean action):
//!
//! ```text
//! x_i   = clamp((obs_i - obs_mean_i) / obs_std_i, -obs_clip, obs_clip)   i < obs_dim
//! h     = act(W_k h + b_k)                  for each hidden layer k
//! y     = out_act(W_out h + b_out)
//! a_j   = clamp(y_j, -action_clip, action_clip) * action_scale_j           j < act_dim
//! ```
//!
//! # Weight layout
//! `weights[..n_weights]` holds the layers in order (hidden layers first, output layer
//! last); each layer is its weight matrix `W` **row-major with shape `[out, in]`** (the
//! flattening of PyTorch's `nn.Linear.weight`) followed by its bias `b` of length `out`.
//! `n_weights` must equal `Σ (in·out + out)` over the layers.
//!
//! # Checksum
//! FNV-1a 64 ([`crate::checksum`]) over the little-endian bytes of every header field in
//! declaration order except `checksum` itself (all of `obs_mean`, `obs_std` and
//! `action_scale`, including unused slots) followed by `weights[..n_weights]`. Use
//! [`PolicyBlob::seal`] after the last write.
//!
//! # Writing in place
//! The blob is ~320 KB: write it straight into a loaned iceoryx2 sample with
//! [`PolicyBlob::init_zeroed`] on the sample's `MaybeUninit` payload and
//! [`crate::PolicyBlobBuilder::write_into`], never through a stack copy.

use core::mem::MaybeUninit;

use iceoryx2::prelude::ZeroCopySend;

use crate::checksum::Fnv1a64;
use crate::error::{SchemaError, count_within, finite_f32};

/// Largest observation dimension a blob can describe.
pub const MAX_OBS: usize = 32;
/// Length of the twin's observation vector: the largest observation a task can configure
/// (`[observation] kind = "nearest_boxes"` with 3 boxes: 17 + 2 × 6 values, see the `twin`
/// crate). A task's own observation is a prefix of it (`TaskConfig::obs_dim()`: 17 for the
/// paper's observation); a policy blob's `obs_dim` is the task's, the rest is ignored. Part
/// of the contract between the learner, which exports blobs, and the controller, which
/// evaluates them.
pub const OBS_DIM: usize = 29;
/// Observation length of the research system's (the paper's) observation.
pub const PAPER_OBS_DIM: usize = 17;
/// Action length of the reaching task: a Cartesian TCP step `[dx, dy, dz]`.
pub const ACT_DIM: usize = 3;
const _: () = assert!(OBS_DIM <= MAX_OBS && ACT_DIM <= MAX_ACT);
/// Action length of [`ActionSpace::JointStep`]: one step per joint of the xArm5.
pub const JOINT_ACT_DIM: usize = 5;
/// Observation length of [`ActionSpace::JointStep`] under [`OBS_LAYOUT_JOINT_V1`] (the
/// `twin` crate's joint-space table): the same buffer length as [`OBS_DIM`], whatever the
/// task's `[observation]`.
pub const JOINT_OBS_DIM: usize = 29;
const _: () = assert!(JOINT_OBS_DIM == OBS_DIM && JOINT_ACT_DIM <= MAX_ACT);
/// `PolicyBlob::obs_layout` of a Cartesian-step policy: the twin's Cartesian table, fixed by
/// `obs_dim` (17 for the paper's, 17 + 6·(k−1) for `nearest_boxes`). Zero: every blob
/// written before the field existed (it was reserved, zero) reads as this layout.
pub const OBS_LAYOUT_CARTESIAN: u32 = 0;
/// `PolicyBlob::obs_layout` of a joint-step policy: version 1 of the twin's joint-space
/// table ([`JOINT_OBS_DIM`] values: the goal posture and the joint error to it, the TCP, the
/// goal target, the nearest boxes; see the `twin` crate's docs).
pub const OBS_LAYOUT_JOINT_V1: u32 = 1;
/// Largest action dimension a blob can describe.
pub const MAX_ACT: usize = 8;
/// Most hidden layers.
pub const MAX_HIDDEN_LAYERS: usize = 4;
/// Widest hidden layer.
pub const MAX_HIDDEN_WIDTH: usize = 256;
/// Capacity of the weight array (f32 values): 80 Ki, enough for 17→256→256→3 (71 171)
/// and 32→256→256→8 (76 296).
pub const MAX_WEIGHTS: usize = 81_920;
/// The blob format this build reads and writes (`format_version`).
pub const POLICY_FORMAT_VERSION: u32 = 1;

/// The policy id no blob may carry: rt-core's planner fallback reports its verified paths
/// as policy 0 ("none": not a learned policy), so a learned policy with that id would be
/// indistinguishable from it.
pub const RESERVED_POLICY_ID: u64 = 0;

/// Activation function. Stored as a `u8`; convert with `Activation::try_from(byte)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Activation {
    /// `f(x) = x` (valid only as the output activation).
    Identity = 0,
    /// `tanh(x)`.
    Tanh = 1,
    /// `max(x, 0)`.
    Relu = 2,
}

impl TryFrom<u8> for Activation {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            0 => Ok(Self::Identity),
            1 => Ok(Self::Tanh),
            2 => Ok(Self::Relu),
            _ => Err(SchemaError::BadEnum {
                field: "activation",
                value: u32::from(value),
            }),
        }
    }
}

/// The action space a policy's output lives in. Stored as a `u8` (`PolicyBlob::action_space`);
/// convert with `ActionSpace::try_from(byte)`. Each space has its observation layout, recorded
/// with its version in `PolicyBlob::obs_layout` ([`ActionSpace::obs_layout`]; the `twin`
/// crate's tables).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ActionSpace {
    /// The paper's: a Cartesian TCP step `[dx, dy, dz]` in `[-1, 1]`, times the task's
    /// `action.scale_m`; the twin's IK turns it into joints. Byte 0, so every blob written
    /// before the field existed (it was reserved, zero) reads as this space.
    CartesianStep = 0,
    /// Joint-space steps toward a goal posture the twin chose (issue 40 item 3): five
    /// per-joint steps in `[-1, 1]`, times the task's `action.joint_scale_rad`; the
    /// observation carries the goal posture and the joint error to it
    /// ([`OBS_LAYOUT_JOINT_V1`]). Byte 1.
    JointStep = 1,
}

impl ActionSpace {
    /// Every space this build knows, by byte.
    pub const ALL: [ActionSpace; 2] = [Self::CartesianStep, Self::JointStep];

    /// The space's name, as the export schema and the logs write it.
    pub fn name(self) -> &'static str {
        match self {
            Self::CartesianStep => "cartesian_step",
            Self::JointStep => "joint_step",
        }
    }

    /// The observation layout (and its version) a blob of this space carries in
    /// `PolicyBlob::obs_layout`.
    pub fn obs_layout(self) -> u32 {
        match self {
            Self::CartesianStep => OBS_LAYOUT_CARTESIAN,
            Self::JointStep => OBS_LAYOUT_JOINT_V1,
        }
    }

    /// The action length of the space ([`ACT_DIM`] or [`JOINT_ACT_DIM`]).
    pub fn act_dim(self) -> usize {
        match self {
            Self::CartesianStep => ACT_DIM,
            Self::JointStep => JOINT_ACT_DIM,
        }
    }
}

impl TryFrom<u8> for ActionSpace {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            0 => Ok(Self::CartesianStep),
            1 => Ok(Self::JointStep),
            _ => Err(SchemaError::BadEnum {
                field: "action_space",
                value: u32::from(value),
            }),
        }
    }
}

/// A borrowed view of one dense layer inside a blob.
#[derive(Debug, Clone, Copy)]
pub struct LayerView<'a> {
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Row-major `[out_dim, in_dim]`.
    pub weights: &'a [f32],
    /// Length `out_dim`.
    pub bias: &'a [f32],
}

/// A trained policy network with its normalisation, in one fixed-size payload.
/// See the [module docs](self) for the network, layout and checksum.
///
/// Deliberately neither `Clone` nor `Copy`: a ~320 KB value must not be copied through the
/// stack by accident; copy it with `*dst = ...` field by field or `copy_from`.
#[derive(Debug, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::PolicyBlob.v1")]
pub struct PolicyBlob {
    /// [`POLICY_FORMAT_VERSION`].
    pub format_version: u32,
    /// Hidden-layer [`Activation`] (Tanh or Relu) as a byte.
    pub activation: u8,
    /// Output [`Activation`] as a byte.
    pub output_activation: u8,
    /// Number of hidden layers (≤ [`MAX_HIDDEN_LAYERS`]).
    pub n_hidden: u8,
    /// The [`ActionSpace`] the network's output lives in, as a byte. A reader refuses a
    /// value it does not know, by name, rather than run the output as another space's.
    pub action_space: u8,
    /// Identifier of this policy (unique per export; never [`RESERVED_POLICY_ID`]).
    pub policy_id: u64,
    /// Hash of the task configuration the policy was trained for.
    pub task_config_hash: u64,
    /// FNV-1a 64 checksum (see the module docs).
    pub checksum: u64,
    /// Observation dimension (≤ [`MAX_OBS`]).
    pub obs_dim: u32,
    /// Action dimension (≤ [`MAX_ACT`]).
    pub act_dim: u32,
    /// Widths of the hidden layers; slots at and beyond `n_hidden` are 0.
    pub hidden_sizes: [u32; MAX_HIDDEN_LAYERS],
    /// Number of used entries of `weights`.
    pub n_weights: u32,
    /// Normalised observations are clipped to `±obs_clip` (> 0).
    pub obs_clip: f32,
    /// Network outputs are clipped to `±action_clip` (> 0) before scaling.
    pub action_clip: f32,
    /// The observation layout and its version ([`ActionSpace::obs_layout`] of
    /// `action_space`): [`OBS_LAYOUT_CARTESIAN`] (0, as every blob written before the field
    /// existed, when it was reserved and zero) or [`OBS_LAYOUT_JOINT_V1`].
    pub obs_layout: u32,
    /// Observation mean (first `obs_dim` used).
    pub obs_mean: [f32; MAX_OBS],
    /// Observation standard deviation, > 0 (first `obs_dim` used).
    pub obs_std: [f32; MAX_OBS],
    /// Per-action scale applied after clipping (first `act_dim` used).
    pub action_scale: [f32; MAX_ACT],
    /// The layers (see the module docs for the layout).
    pub weights: [f32; MAX_WEIGHTS],
}

const _: () = assert!(size_of::<PolicyBlob>() == 360 + 4 * MAX_WEIGHTS);
const _: () = assert!(size_of::<PolicyBlob>().is_multiple_of(align_of::<PolicyBlob>()));

/// Number of weight values a network with these dimensions needs.
pub fn required_weights(obs_dim: usize, hidden: &[usize], act_dim: usize) -> usize {
    let mut total = 0usize;
    let mut in_dim = obs_dim;
    for &h in hidden.iter().chain(core::iter::once(&act_dim)) {
        total = total.saturating_add(in_dim.saturating_mul(h).saturating_add(h));
        in_dim = h;
    }
    total
}

impl PolicyBlob {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = POLICY_FORMAT_VERSION;

    /// Zeroes `slot` in place (no stack copy of the ~320 KB payload) and returns it as an
    /// initialised blob. All-zero is a valid bit pattern: every field is an integer, a
    /// float or an array of them. A zeroed blob does not validate until written and sealed.
    pub fn init_zeroed(slot: &mut MaybeUninit<PolicyBlob>) -> &mut PolicyBlob {
        // SAFETY: `PolicyBlob` is `repr(C)` and consists only of `u8`/`u32`/`u64`/`f32`
        // fields and arrays thereof, for which the all-zero bit pattern is a valid value;
        // after `write_bytes` every byte of the slot is initialised.
        unsafe {
            core::ptr::write_bytes(slot.as_mut_ptr(), 0, 1);
            slot.assume_init_mut()
        }
    }

    /// A zeroed blob on the heap (allocated directly, never on the stack).
    pub fn new_boxed() -> Box<PolicyBlob> {
        let mut slot = Box::<PolicyBlob>::new_uninit();
        Self::init_zeroed(&mut slot);
        // SAFETY: `init_zeroed` initialised every byte with a valid value.
        unsafe { slot.assume_init() }
    }

    /// The blob's bytes: the blob-file format (`*.blob`), native-endian, exactly
    /// `size_of::<PolicyBlob>()` bytes. The checksum and the schema version inside make a
    /// file from another build or architecture fail [`PolicyBlob::from_bytes`].
    pub fn as_bytes(&self) -> &[u8] {
        // SAFETY: `PolicyBlob` is `repr(C)`, made only of integers and floats with no
        // padding (its size is asserted above), so every byte is initialised; the slice
        // borrows `self` for its lifetime.
        unsafe {
            core::slice::from_raw_parts(
                (self as *const PolicyBlob).cast::<u8>(),
                size_of::<PolicyBlob>(),
            )
        }
    }

    /// The blob's bytes, writable: for reading a blob file straight into a private blob
    /// (e.g. `policy::read_policy_file`) without an intermediate buffer. Any bytes written
    /// leave a well-formed `PolicyBlob` (every bit pattern is a valid value of its
    /// integer and float fields); whether it is a *valid* policy is for
    /// [`PolicyBlob::validate`] to say.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as in `as_bytes`, the blob is `repr(C)` integers and floats with no
        // padding, so its `size_of` bytes are initialised; every bit pattern written through
        // the slice is a valid value of those fields; the slice borrows `self` exclusively
        // for its lifetime.
        unsafe {
            core::slice::from_raw_parts_mut(
                (self as *mut PolicyBlob).cast::<u8>(),
                size_of::<PolicyBlob>(),
            )
        }
    }

    /// Parses blob-file bytes and validates the result (layout, finite numbers, checksum).
    ///
    /// # Errors
    /// [`SchemaError::LayoutInvalid`] for a wrong length, else the first error of
    /// [`PolicyBlob::validate`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Box<PolicyBlob>, SchemaError> {
        if bytes.len() != size_of::<PolicyBlob>() {
            return Err(SchemaError::LayoutInvalid {
                field: "blob file length",
            });
        }
        let mut blob = PolicyBlob::new_boxed();
        // SAFETY: the destination is a live, exclusively borrowed `PolicyBlob` of exactly
        // `bytes.len()` bytes; every bit pattern is a valid value of its integer/float fields.
        unsafe {
            core::ptr::copy_nonoverlapping(
                bytes.as_ptr(),
                (&mut *blob as *mut PolicyBlob).cast::<u8>(),
                bytes.len(),
            );
        }
        blob.validate()?;
        Ok(blob)
    }

    /// Copies every field of `other` into `self` in place (no stack temporary).
    pub fn copy_from(&mut self, other: &PolicyBlob) {
        self.format_version = other.format_version;
        self.activation = other.activation;
        self.output_activation = other.output_activation;
        self.n_hidden = other.n_hidden;
        self.action_space = other.action_space;
        self.policy_id = other.policy_id;
        self.task_config_hash = other.task_config_hash;
        self.checksum = other.checksum;
        self.obs_dim = other.obs_dim;
        self.act_dim = other.act_dim;
        self.hidden_sizes = other.hidden_sizes;
        self.n_weights = other.n_weights;
        self.obs_clip = other.obs_clip;
        self.action_clip = other.action_clip;
        self.obs_layout = other.obs_layout;
        self.obs_mean = other.obs_mean;
        self.obs_std = other.obs_std;
        self.action_scale = other.action_scale;
        self.weights.copy_from_slice(&other.weights);
    }

    /// A heap copy of `self`.
    pub fn to_boxed(&self) -> Box<PolicyBlob> {
        let mut b = Self::new_boxed();
        b.copy_from(self);
        b
    }

    /// Hidden-layer widths in use (`hidden_sizes[..n_hidden]`, clamped to capacity).
    pub fn hidden(&self) -> &[u32] {
        &self.hidden_sizes[..usize::from(self.n_hidden).min(MAX_HIDDEN_LAYERS)]
    }

    /// Number of dense layers (hidden + output).
    pub fn n_layers(&self) -> usize {
        self.hidden().len() + 1
    }

    /// The weight count the header's dimensions require.
    pub fn required_weights(&self) -> usize {
        let mut total = 0usize;
        let mut in_dim = self.obs_dim as usize;
        for out in self.hidden().iter().chain(core::iter::once(&self.act_dim)) {
            let out = *out as usize;
            total = total.saturating_add(in_dim.saturating_mul(out).saturating_add(out));
            in_dim = out;
        }
        total
    }

    /// Layer `index` (0 = first hidden, `n_layers() - 1` = output), or `None` when out of
    /// range or the layout does not fit the weight array. Allocation-free.
    pub fn layer(&self, index: usize) -> Option<LayerView<'_>> {
        if index >= self.n_layers() {
            return None;
        }
        let dims = |i: usize| -> usize {
            if i == 0 {
                self.obs_dim as usize
            } else if i <= self.hidden().len() {
                self.hidden()[i - 1] as usize
            } else {
                self.act_dim as usize
            }
        };
        let mut offset = 0usize;
        for i in 0..index {
            offset += dims(i) * dims(i + 1) + dims(i + 1);
        }
        let (in_dim, out_dim) = (dims(index), dims(index + 1));
        let w_end = offset + in_dim * out_dim;
        let b_end = w_end + out_dim;
        if b_end > MAX_WEIGHTS {
            return None;
        }
        Some(LayerView {
            in_dim,
            out_dim,
            weights: &self.weights[offset..w_end],
            bias: &self.weights[w_end..b_end],
        })
    }

    /// The FNV-1a 64 checksum over the header (minus `checksum`) and the used weights.
    pub fn compute_checksum(&self) -> u64 {
        let mut h = Fnv1a64::new();
        h.write_u32(self.format_version);
        h.write(&[
            self.activation,
            self.output_activation,
            self.n_hidden,
            self.action_space,
        ]);
        h.write_u64(self.policy_id);
        h.write_u64(self.task_config_hash);
        h.write_u32(self.obs_dim);
        h.write_u32(self.act_dim);
        for s in self.hidden_sizes {
            h.write_u32(s);
        }
        h.write_u32(self.n_weights);
        h.write_f32s(&[self.obs_clip, self.action_clip]);
        h.write_u32(self.obs_layout);
        h.write_f32s(&self.obs_mean);
        h.write_f32s(&self.obs_std);
        h.write_f32s(&self.action_scale);
        h.write_f32s(&self.weights[..(self.n_weights as usize).min(MAX_WEIGHTS)]);
        h.finish()
    }

    /// Stores [`Self::compute_checksum`] in `checksum`. Call after the last write.
    pub fn seal(&mut self) {
        self.checksum = self.compute_checksum();
    }

    /// Checks, in this order: format version; `policy_id` not [`RESERVED_POLICY_ID`];
    /// activation bytes; dimensions and layer
    /// sizes within capacity and consistent with `n_weights`; the checksum; every used
    /// number finite; `obs_std > 0`, `obs_clip > 0`, `action_clip > 0`.
    ///
    /// The clips are the bounds `[-clip, clip]` of `clamp` at evaluation: a negative clip
    /// (min > max) is [`SchemaError::OutOfRange`], a NaN or infinite one
    /// [`SchemaError::NonFinite`], each naming the field (`obs_clip` or `action_clip`).
    /// A consumer must run this on its own copy of the blob, not on a shared-memory sample
    /// that another process can still write (see `policy::PolicyLoader`).
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        if self.format_version != POLICY_FORMAT_VERSION {
            return Err(SchemaError::VersionMismatch {
                expected: POLICY_FORMAT_VERSION,
                found: self.format_version,
            });
        }
        // Issue 41 item 5: a learner's blob with id 0 would be taken for the planner's
        // verified path in rt-core's verdicts, logs and acknowledgements.
        if self.policy_id == RESERVED_POLICY_ID {
            return Err(SchemaError::OutOfRange { field: "policy_id" });
        }
        match Activation::try_from(self.activation)? {
            Activation::Tanh | Activation::Relu => {}
            Activation::Identity => {
                return Err(SchemaError::OutOfRange {
                    field: "activation",
                });
            }
        }
        // A space this build does not know is refused by name: its output would otherwise be
        // run as a Cartesian step (issue 40 item 3). Each space has its own observation
        // layout: a blob claiming another is refused rather than fed the wrong values.
        let space = ActionSpace::try_from(self.action_space)?;
        if self.obs_layout != space.obs_layout() {
            return Err(SchemaError::BadEnum {
                field: "obs_layout",
                value: self.obs_layout,
            });
        }
        if space == ActionSpace::JointStep
            && (self.obs_dim as usize != JOINT_OBS_DIM || self.act_dim as usize != JOINT_ACT_DIM)
        {
            return Err(SchemaError::LayoutInvalid {
                field: "joint_step obs_dim/act_dim",
            });
        }
        Activation::try_from(self.output_activation).map_err(|_| SchemaError::BadEnum {
            field: "output_activation",
            value: u32::from(self.output_activation),
        })?;
        count_within("n_hidden", u32::from(self.n_hidden), MAX_HIDDEN_LAYERS)?;
        count_within("obs_dim", self.obs_dim, MAX_OBS)?;
        count_within("act_dim", self.act_dim, MAX_ACT)?;
        if self.obs_dim == 0 {
            return Err(SchemaError::LayoutInvalid { field: "obs_dim" });
        }
        if self.act_dim == 0 {
            return Err(SchemaError::LayoutInvalid { field: "act_dim" });
        }
        for (i, &width) in self.hidden_sizes.iter().enumerate() {
            if i < usize::from(self.n_hidden) {
                if width == 0 {
                    return Err(SchemaError::LayoutInvalid {
                        field: "hidden_sizes",
                    });
                }
                count_within("hidden_sizes", width, MAX_HIDDEN_WIDTH)?;
            } else if width != 0 {
                return Err(SchemaError::LayoutInvalid {
                    field: "hidden_sizes",
                });
            }
        }
        count_within("n_weights", self.n_weights, MAX_WEIGHTS)?;
        if self.n_weights as usize != self.required_weights() {
            return Err(SchemaError::LayoutInvalid { field: "n_weights" });
        }
        let computed = self.compute_checksum();
        if computed != self.checksum {
            return Err(SchemaError::ChecksumMismatch {
                stored: self.checksum,
                computed,
            });
        }
        let obs = self.obs_dim as usize;
        let act = self.act_dim as usize;
        finite_f32("obs_clip", &[self.obs_clip])?;
        finite_f32("action_clip", &[self.action_clip])?;
        finite_f32("obs_mean", &self.obs_mean[..obs])?;
        finite_f32("obs_std", &self.obs_std[..obs])?;
        finite_f32("action_scale", &self.action_scale[..act])?;
        finite_f32("weights", &self.weights[..self.n_weights as usize])?;
        if self.obs_std[..obs].iter().any(|s| *s <= 0.0) {
            return Err(SchemaError::OutOfRange { field: "obs_std" });
        }
        if self.obs_clip <= 0.0 {
            return Err(SchemaError::OutOfRange { field: "obs_clip" });
        }
        if self.action_clip <= 0.0 {
            return Err(SchemaError::OutOfRange {
                field: "action_clip",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 41 item 5: a blob with the planner's id 0 is refused (before: accepted).
    #[test]
    fn a_blob_with_the_reserved_policy_id_is_refused() {
        let blob = crate::PolicyBlobBuilder::random(7, 42, 17, &[16], 3, 1)
            .build()
            .unwrap();
        assert_eq!(blob.validate(), Ok(()));
        let mut zero = PolicyBlob::new_boxed();
        zero.copy_from(&blob);
        zero.policy_id = RESERVED_POLICY_ID;
        zero.seal();
        assert_eq!(
            zero.validate(),
            Err(SchemaError::OutOfRange { field: "policy_id" })
        );
    }

    #[test]
    fn blob_file_bytes_round_trip_and_bad_files_are_rejected() {
        let blob = crate::PolicyBlobBuilder::random(7, 42, 17, &[16, 16], 3, 1)
            .build()
            .unwrap();
        let bytes = blob.as_bytes().to_vec();
        let back = PolicyBlob::from_bytes(&bytes).unwrap();
        assert_eq!(back.as_bytes(), blob.as_bytes());
        assert_eq!(
            PolicyBlob::from_bytes(&bytes[..bytes.len() - 1]).unwrap_err(),
            SchemaError::LayoutInvalid {
                field: "blob file length"
            }
        );
        let mut flipped = bytes.clone();
        let last_weight = size_of::<PolicyBlob>() - 4 * (MAX_WEIGHTS - back.n_weights as usize) - 2;
        flipped[last_weight] ^= 0x40;
        assert!(
            PolicyBlob::from_bytes(&flipped).is_err(),
            "a flipped weight byte is caught"
        );
    }

    #[test]
    fn required_weights_of_the_reference_network() {
        assert_eq!(required_weights(17, &[256, 256], 3), 71_171);
        assert_eq!(required_weights(32, &[256, 256], 8), 76_296);
        assert_eq!(required_weights(2, &[], 1), 3);
    }

    #[test]
    fn clip_bounds_with_min_above_max_or_non_finite_are_rejected_naming_the_field() {
        type Field = fn(&mut PolicyBlob) -> &mut f32;
        let fields: [(&str, Field); 2] = [
            ("obs_clip", |b| &mut b.obs_clip),
            ("action_clip", |b| &mut b.action_clip),
        ];
        for (field, slot) in fields {
            for (value, want) in [
                (-1.0, SchemaError::OutOfRange { field }),
                (-0.0, SchemaError::OutOfRange { field }),
                (0.0, SchemaError::OutOfRange { field }),
                (f32::NAN, SchemaError::NonFinite { field }),
                (f32::INFINITY, SchemaError::NonFinite { field }),
                (f32::NEG_INFINITY, SchemaError::NonFinite { field }),
            ] {
                let mut blob = crate::PolicyBlobBuilder::random(7, 42, 17, &[16], 3, 1)
                    .build()
                    .unwrap();
                *slot(&mut blob) = value;
                blob.seal();
                assert_eq!(blob.validate(), Err(want), "{field} = {value}");
                assert!(want.to_string().contains(field));
            }
        }
    }

    #[test]
    fn bytes_written_through_as_bytes_mut_round_trip() {
        let blob = crate::PolicyBlobBuilder::random(7, 42, 17, &[16, 16], 3, 1)
            .build()
            .unwrap();
        let mut copy = PolicyBlob::new_boxed();
        copy.as_bytes_mut().copy_from_slice(blob.as_bytes());
        assert_eq!(copy.validate(), Ok(()));
        assert_eq!(*copy, *blob);
    }

    #[test]
    fn zeroed_blob_is_rejected() {
        let blob = PolicyBlob::new_boxed();
        assert_eq!(
            blob.validate(),
            Err(SchemaError::VersionMismatch {
                expected: 1,
                found: 0
            })
        );
    }
}
