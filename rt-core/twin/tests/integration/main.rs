//! Integration tests of the digital twin (`twin`): kinematics, IK, geometry, the task,
//! scenes, URDF loading and determinism. The zero-allocation test of the per-step work
//! lives with the one counting allocator in rt-core's `alloc` tests; the `rt-core twin`
//! CLI's tests with the binary.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
mod determinism;
mod feasibility;
mod geometry;
mod ik;
mod joint_space;
mod kinematics;
mod robot_checks;
mod scenes;
mod task;
mod urdf;
