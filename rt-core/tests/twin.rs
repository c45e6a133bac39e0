//! Integration tests of the digital twin (`rt_core::twin`): kinematics, IK, geometry, the
//! task, scenes, determinism, zero allocation per step and the CLI. One test binary, so
//! the counting global allocator of `alloc` is global only here.

#[path = "twin/alloc.rs"]
mod alloc;
#[path = "twin/cli.rs"]
mod cli;
#[path = "twin/common.rs"]
mod common;
#[path = "twin/determinism.rs"]
mod determinism;
#[path = "twin/geometry.rs"]
mod geometry;
#[path = "twin/ik.rs"]
mod ik;
#[path = "twin/kinematics.rs"]
mod kinematics;
#[path = "twin/no_alloc.rs"]
mod no_alloc;
#[path = "twin/scenes.rs"]
mod scenes;
#[path = "twin/task.rs"]
mod task;
#[path = "twin/urdf.rs"]
mod urdf;
