//! The simulated controller (fed arbitrary frames by the `sim_controller` target).

#[path = "../../src/xarm/sim/controller.rs"]
pub mod controller;
