//! The cycle thread's side of the runtime (real-time: no allocation, no shared lock, no
//! blocking I/O, no formatting after start-up):
//!
//! - [`control`]: the control cycle itself (`new → start → process → stop`), re-exported here;
//! - [`shield`]: the one check every command passes, and [`twin_model`], the twin's geometry
//!   as the shield's model;
//! - [`brake`]: the allocation-free controlled stop;
//! - [`separation`]: speed and separation monitoring (ISO/TS 15066), the playback scale;
//! - [`plan`]: an approved plan as the cycle streams it;
//! - [`link`]: the robot port ([`link::RobotLink`]) with the in-process arm and the dry-run
//!   wrapper, and [`xarm_link`], its adapter to the xArm driver;
//! - [`thread`]: the cycle thread (real-time set-up, allocation counting, the loop).

pub mod brake;
pub mod control;
pub mod link;
pub mod plan;
pub mod separation;
pub mod shield;
pub mod thread;
pub mod twin_model;
pub mod xarm_link;

pub use control::*;
