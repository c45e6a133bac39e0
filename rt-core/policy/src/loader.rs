//! [`PolicyLoader`]: the acceptance gate for [`PolicyBlob`]s. A blob becomes an
//! [`MlpPolicy`] only if it validates, has the expected dimensions and was trained for the
//! running task; every rejection is counted per [`PolicyRejectReason`]. It only takes blobs
//! in this process's private memory (`&Box<PolicyBlob>`), never a shared-memory sample.

use core::sync::atomic::{AtomicU64, Ordering};

use shm_schemas::{ActionSpace, PolicyBlob, SchemaError};

use super::mlp::MlpPolicy;
use shm_schemas::{ACT_DIM, OBS_DIM};

/// Why a policy blob was refused. `Copy`, no `String`: the caller counts and logs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
#[repr(u8)]
pub enum PolicyRejectReason {
    /// NaN or ±Inf in the weights, normalisation or scaling.
    #[error("non-finite number in the blob")]
    NonFinite = 0,
    /// Observation or action dimension differs from the running task's.
    #[error("observation/action dimensions do not match the task")]
    DimensionMismatch = 1,
    /// Trained for another task configuration.
    #[error("task-config hash does not match the running task")]
    TaskHashMismatch = 2,
    /// The checksum does not match the contents.
    #[error("bad checksum")]
    BadChecksum = 3,
    /// Layer sizes, counts or enum bytes are inconsistent or out of capacity.
    #[error("invalid layout (layer sizes, weight count or activation)")]
    LayoutInvalid = 4,
    /// A blob format this build does not read.
    #[error("unsupported blob format version")]
    VersionMismatch = 5,
    /// A finite value out of range (non-positive std or clip).
    #[error("normalisation or clipping value out of range")]
    OutOfRange = 6,
    /// An action-space byte this build does not know ([`ActionSpaceRefusal`] names it).
    #[error("unknown action space")]
    UnknownActionSpace = 7,
}

/// The action spaces this loader runs: every space this build knows. rt-core's lookahead
/// rolls a Cartesian-step policy out through the twin's per-step IK and a joint-step
/// policy toward the goal posture the twin chooses; both plans are approved the same way.
pub const RUNNABLE_SPACES: [ActionSpace; 2] = ActionSpace::ALL;

/// Why a blob's action space is refused, naming it: the words rt-core logs and returns
/// beside [`PolicyRejectReason::UnknownActionSpace`]. `Copy`, no `String`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ActionSpaceRefusal {
    /// A space byte this build does not know (a newer learner's space, or a corrupted byte).
    #[error(
        "the policy's action space byte {0} is unknown to this rt-core (it runs `cartesian_step` = 0 and `joint_step` = 1)"
    )]
    Unknown(u8),
}

impl ActionSpaceRefusal {
    /// The refusal of `blob`'s action space, `None` for a space this loader runs. Reads only
    /// the `action_space` byte (the full check is [`PolicyLoader::check`]).
    pub fn of(blob: &PolicyBlob) -> Option<Self> {
        match ActionSpace::try_from(blob.action_space) {
            Ok(space) if RUNNABLE_SPACES.contains(&space) => None,
            _ => Some(Self::Unknown(blob.action_space)),
        }
    }
}

impl PolicyRejectReason {
    /// Every reason, in discriminant order.
    pub const ALL: [PolicyRejectReason; 8] = [
        Self::NonFinite,
        Self::DimensionMismatch,
        Self::TaskHashMismatch,
        Self::BadChecksum,
        Self::LayoutInvalid,
        Self::VersionMismatch,
        Self::OutOfRange,
        Self::UnknownActionSpace,
    ];

    /// A short static name for logs and metrics.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::NonFinite => "non_finite",
            Self::DimensionMismatch => "dimension_mismatch",
            Self::TaskHashMismatch => "task_hash_mismatch",
            Self::BadChecksum => "bad_checksum",
            Self::LayoutInvalid => "layout_invalid",
            Self::VersionMismatch => "version_mismatch",
            Self::OutOfRange => "out_of_range",
            Self::UnknownActionSpace => "unknown_action_space",
        }
    }
}

impl From<SchemaError> for PolicyRejectReason {
    fn from(e: SchemaError) -> Self {
        match e {
            SchemaError::NonFinite { .. } => Self::NonFinite,
            SchemaError::ChecksumMismatch { .. } => Self::BadChecksum,
            SchemaError::VersionMismatch { .. } => Self::VersionMismatch,
            SchemaError::OutOfRange { .. } => Self::OutOfRange,
            SchemaError::BadEnum {
                field: "action_space",
                ..
            } => Self::UnknownActionSpace,
            SchemaError::CountOverCapacity { .. }
            | SchemaError::BadEnum { .. }
            | SchemaError::LayoutInvalid { .. } => Self::LayoutInvalid,
        }
    }
}

/// Lock-free counters of accepted and rejected blobs, one per reason. Shareable between
/// threads (`&self` methods, relaxed atomics).
#[derive(Debug, Default)]
pub struct RejectCounters {
    rejected: [AtomicU64; PolicyRejectReason::ALL.len()],
    accepted: AtomicU64,
}

impl RejectCounters {
    /// Counts one rejection.
    pub fn record(&self, reason: PolicyRejectReason) {
        self.rejected[reason as usize].fetch_add(1, Ordering::Relaxed);
    }

    /// Rejections for `reason` so far.
    pub fn count(&self, reason: PolicyRejectReason) -> u64 {
        self.rejected[reason as usize].load(Ordering::Relaxed)
    }

    /// All rejections so far.
    pub fn total_rejected(&self) -> u64 {
        self.rejected
            .iter()
            .map(|c| c.load(Ordering::Relaxed))
            .sum()
    }

    /// Accepted blobs so far.
    pub fn accepted(&self) -> u64 {
        self.accepted.load(Ordering::Relaxed)
    }
}

/// What the running task expects of a policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PolicyExpectation {
    /// `TaskConfig::hash()` of the running task.
    pub task_config_hash: u64,
    /// Observation dimension.
    pub obs_dim: usize,
    /// Action dimension.
    pub act_dim: usize,
}

impl PolicyExpectation {
    /// The given task hash with the twin's full observation ([`OBS_DIM`], the default
    /// task's `nearest_boxes` observation with 3 boxes) and [`ACT_DIM`].
    pub const fn for_task(task_config_hash: u64) -> Self {
        Self::for_task_obs(task_config_hash, OBS_DIM)
    }

    /// The given task hash and observation length (the task's `TaskConfig::obs_dim()`, ≤
    /// [`OBS_DIM`]; 17 for the paper's observation), and [`ACT_DIM`].
    pub const fn for_task_obs(task_config_hash: u64, obs_dim: usize) -> Self {
        Self {
            task_config_hash,
            obs_dim,
            act_dim: ACT_DIM,
        }
    }
}

/// Validates blobs and turns accepted ones into [`MlpPolicy`]s, counting rejections.
///
/// # Private copies only
/// Every method takes the blob as `&Box<PolicyBlob>`, not `&PolicyBlob`, on purpose. A
/// sample in iceoryx2 shared memory can be written by another process at any moment, so a
/// blob validated in place could change between its check and its load (a clip bound
/// made negative or NaN after the check would reach `clamp` at evaluation). A `Box` is
/// this process's own heap memory — safe code cannot make one over shared memory — and
/// the shared borrow excludes writers while the loader runs, so what is checked is exactly
/// what is loaded. Copy a sample out first with [`PolicyBlob::to_boxed`] (or
/// [`PolicyBlob::copy_from`] into a box kept for reuse); passing the sample's payload
/// does not compile:
///
/// ```compile_fail,E0308
/// use policy::{PolicyExpectation, PolicyLoader};
/// use shm_schemas::{OBS_DIM, PolicyBlob, PolicyBlobBuilder};
///
/// let loader = PolicyLoader::new(PolicyExpectation::for_task(0xabc));
/// let blob = PolicyBlobBuilder::random(1, 0xabc, OBS_DIM, &[8], 3, 7).build().unwrap();
/// let shared: &PolicyBlob = &blob; // what `Sample::payload()` hands out
/// let _ = loader.check(shared); // expected `&Box<PolicyBlob>`: copy it first
/// ```
///
/// ```
/// use policy::{MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
/// use shm_schemas::{OBS_DIM, PolicyBlobBuilder};
///
/// let loader = PolicyLoader::new(PolicyExpectation::for_task(0xabc));
/// let blob = PolicyBlobBuilder::random(1, 0xabc, OBS_DIM, &[64, 64], 3, 7).build().unwrap();
/// let policy = loader.prepare(&blob).unwrap();
/// assert_eq!(policy.policy_id(), 1);
///
/// let other_task = PolicyBlobBuilder::random(2, 0xdef, OBS_DIM, &[64, 64], 3, 7).build().unwrap();
/// let mut spare = MlpPolicy::with_capacity(); // allocate once, reuse for every swap
/// assert_eq!(loader.prepare_into(&other_task, &mut spare), Err(PolicyRejectReason::TaskHashMismatch));
/// assert_eq!(loader.counters().count(PolicyRejectReason::TaskHashMismatch), 1);
/// ```
#[derive(Debug)]
pub struct PolicyLoader {
    expected: PolicyExpectation,
    counters: RejectCounters,
}

#[allow(
    clippy::borrowed_box,
    reason = "`&Box<PolicyBlob>` admits only private memory, never a shared-memory sample"
)]
impl PolicyLoader {
    /// A loader for the given expectation, with zeroed counters.
    pub fn new(expected: PolicyExpectation) -> Self {
        Self {
            expected,
            counters: RejectCounters::default(),
        }
    }

    /// The expectation blobs are checked against.
    pub fn expected(&self) -> PolicyExpectation {
        self.expected
    }

    /// The counters.
    pub fn counters(&self) -> &RejectCounters {
        &self.counters
    }

    /// Checks a blob without building anything: [`PolicyBlob::validate`] (format, layout,
    /// checksum, finite values, ranges; an unknown action space), then dimensions (the
    /// expectation's for a Cartesian-step blob; a joint-step blob's are its layout's), then
    /// task hash. Counts the
    /// outcome. No allocation. `blob` is a private copy (see [the type docs](Self)).
    ///
    /// # Errors
    /// The [`PolicyRejectReason`].
    pub fn check(&self, blob: &Box<PolicyBlob>) -> Result<(), PolicyRejectReason> {
        let result = Self::check_against(blob, self.expected);
        match result {
            Ok(()) => {
                self.counters.accepted.fetch_add(1, Ordering::Relaxed);
            }
            Err(reason) => self.counters.record(reason),
        }
        result
    }

    fn check_against(
        blob: &PolicyBlob,
        expected: PolicyExpectation,
    ) -> Result<(), PolicyRejectReason> {
        blob.validate()?;
        if ActionSpaceRefusal::of(blob).is_some() {
            return Err(PolicyRejectReason::UnknownActionSpace);
        }
        // The Cartesian step observes the task's observation; the joint step its own layout
        // (its lengths already checked by `validate`).
        let dims_match = match ActionSpace::try_from(blob.action_space) {
            Ok(ActionSpace::JointStep) => true,
            _ => {
                blob.obs_dim as usize == expected.obs_dim
                    && blob.act_dim as usize == expected.act_dim
            }
        };
        if !dims_match {
            return Err(PolicyRejectReason::DimensionMismatch);
        }
        if blob.task_config_hash != expected.task_config_hash {
            return Err(PolicyRejectReason::TaskHashMismatch);
        }
        Ok(())
    }

    /// Checks a blob and builds a new policy from it (allocates the policy's buffers once).
    /// `blob` is a private copy (see [the type docs](Self)).
    ///
    /// # Errors
    /// The [`PolicyRejectReason`] (counted).
    pub fn prepare(&self, blob: &Box<PolicyBlob>) -> Result<MlpPolicy, PolicyRejectReason> {
        self.check(blob)?;
        let mut policy = MlpPolicy::with_capacity();
        policy.load_from(blob);
        Ok(policy)
    }

    /// Checks a blob and loads it into an existing policy's buffers — no allocation, for
    /// double-buffered hot swaps. On rejection `target` is left unchanged. `blob` is a
    /// private copy (see [the type docs](Self)).
    ///
    /// # Errors
    /// The [`PolicyRejectReason`] (counted).
    pub fn prepare_into(
        &self,
        blob: &Box<PolicyBlob>,
        target: &mut MlpPolicy,
    ) -> Result<(), PolicyRejectReason> {
        self.check(blob)?;
        target.load_from(blob);
        Ok(())
    }
}
