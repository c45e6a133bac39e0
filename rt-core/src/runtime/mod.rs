//! The real-time runtime of rt-core: the cycle thread (plan streaming, the safety shield,
//! controlled stops, the robot link) and the twin thread (scene sync, lookahead, verdicts,
//! plan approval), the lock-free hand-overs between them, and the real-time set-up of the
//! process.
//!
//! Data flow, one direction per channel (all single-producer/single-consumer, lock-free):
//!
//! ```text
//!  detections ──▶ TwinWorker ──scene──────────▶ Cycle ──servo──▶ RobotLink
//!  policies   ──▶ (lookahead, ──Box<Plan>──────▶ (shield,  ◀─state──
//!                  smoothing) ◀─retired plans── braking)
//!                             ◀─CycleReport───
//! ```
//!
//! The cycle is generic over a [`shield::ShieldModel`] (kinematics and clearance to the
//! live scene) and a [`link::RobotLink`]; the twin worker over a [`twin_thread::Lookahead`]
//! (the whole next episode in the twin with the current policy). [`toy`] holds small
//! stand-ins of both used by the tests and the bench.

pub mod alloc_count;
pub mod clock;
pub mod config;
pub mod cycle;
pub mod cycle_thread;
pub mod handoff;
pub mod histogram;
pub mod link;
pub mod plan;
pub mod rt_log;
pub mod rt_setup;
pub mod shield;
pub mod smoothing;
pub mod toy;
pub mod twin_adapter;
pub mod twin_thread;

/// Degrees of freedom of the xArm5 and a joint-space vector (rad, or rad/s, rad/s² by
/// context): the twin's definitions.
pub use crate::twin::{DOF, Joints};

/// The largest per-joint difference between two joint vectors, rad (no allocation: used in
/// the cycle too).
pub fn max_joint_gap_rad(a: &Joints, b: &Joints) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
