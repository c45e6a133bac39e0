//! Foresight's real-time process, `rt-core run`: two threads around a robot link.
//!
//! ```text
//!  detections ──▶ twin_thread ──scene──────────▶ cycle ──servo──▶ RobotLink (xArm / sim)
//!  policies   ──▶ (worker:      ──Box<Plan>─────▶ (control,  ◀─state──
//!                  lookahead,   ◀─retired plans── shield,
//!                  smoother,    ◀─CycleReport──── brake)
//!                  node)
//! ```
//!
//! - [`cycle`]: the real-time thread (control cycle, shield, brake, plan, the robot port and
//!   its xArm adapter, the thread itself). Start reading at [`cycle::Cycle::process`].
//! - [`twin_thread`]: the twin thread (worker, lookahead, smoother, its iceoryx2 node).
//!   Start reading at [`twin_thread::TwinWorker::step`].
//! - [`rt`]: the toolkit beneath both (hand-overs, log ring, clock, RT set-up, histograms,
//!   the counting allocator).
//! - [`config`]: `assets/runtime.toml`, validated at load.
//! - [`launch`]: `rt-core run`'s start-up (configuration, signals, simulation-only rights,
//!   the recorder, the link) around [`twin_thread::serve`], and its summary.
//! - [`operator_ack`]: the operator's acknowledgement channel (`rt-core ack`).
//!
//! The libraries it builds on are crates of their own: `twin` (model, kinematics, geometry,
//! the task), `policy` (allocation-free inference), `xarm` (the controller protocol and
//! driver) and `shm-schemas` (the contract with the other processes).

pub mod config;
pub mod cycle;
pub mod launch;
pub mod operator_ack;
pub mod rt;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
pub mod twin_thread;
