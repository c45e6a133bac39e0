//! The `sweep` binary's modes besides the static sweep (which lives in `main.rs`).

pub(crate) mod dynamic;
pub(crate) mod per_kind;
