//! Policy inference without allocation: [`PolicyLoader`] accepts or rejects a
//! [`shm_schemas::PolicyBlob`] (counted per [`PolicyRejectReason`]) and loads it into an
//! [`MlpPolicy`], whose [`MlpPolicy::act`] evaluates the deterministic mean action with no
//! allocation.
//!
//! Hot swap: allocate two policies with [`MlpPolicy::with_capacity`] at start-up, load the
//! incoming blob into the spare one off the cycle thread with
//! [`PolicyLoader::prepare_into`], then swap which one the cycle reads in one atomic step.
//! A rejected blob leaves the running policy untouched.

mod kernel;
mod loader;
mod mlp;

pub use loader::{PolicyExpectation, PolicyLoader, PolicyRejectReason, RejectCounters};
pub use mlp::{MlpPolicy, PolicyEvalError};

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests;
