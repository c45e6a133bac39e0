//! Policy inference without allocation: [`PolicyLoader`] accepts or rejects a
//! [`shm_schemas::PolicyBlob`] (counted per [`PolicyRejectReason`]) and loads it into an
//! [`MlpPolicy`], whose [`MlpPolicy::act`] evaluates the deterministic mean action with no
//! allocation.
//!
//! The loader only takes a blob in this process's private memory (`&Box<PolicyBlob>`):
//! a sample received over iceoryx2 is copied out first ([`shm_schemas::PolicyBlob::to_boxed`]),
//! so a writer racing on the shared sample cannot change what was validated. A start
//! policy file is read with [`read_policy_file`], which reads at most one blob + 1 byte.
//!
//! Hot swap: allocate two policies with [`MlpPolicy::with_capacity`] at start-up, load the
//! incoming blob into the spare one off the cycle thread with
//! [`PolicyLoader::prepare_into`], then swap which one the cycle reads in one atomic step.
//! A rejected blob leaves the running policy untouched.

mod file;
mod kernel;
mod loader;
mod mlp;

pub use file::{POLICY_FILE_BYTES, PolicyFileError, read_policy_blob, read_policy_file};
/// The inference's `tanh` (within 4 ulp, branch-free), also the learner's host network's, so
/// that training and deployment evaluate hidden layers with the same bits.
pub use kernel::tanh;
pub use loader::{
    ActionSpaceRefusal, PolicyExpectation, PolicyLoader, PolicyRejectReason, RUNNABLE_SPACES,
    RejectCounters,
};
pub use mlp::{MlpPolicy, PolicyEvalError};

#[cfg(test)]
mod tests;
