//! rt-core's xArm protocol modules, compiled on their own for fuzzing (see `xarm.rs`).
#![allow(missing_docs, dead_code)]

pub mod xarm;
