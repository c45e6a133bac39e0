//! Foresight's real-time core: the xArm5 digital twin (kinematics, geometry, the task), and,
//! as they land, policy inference, the safety shield, smoothing, the xArm protocol and the
//! control cycle. The `rt-core` binary wires them into threads; the learner links this
//! library for its training environments, so training and lookahead share one task.

#![deny(clippy::unwrap_used)]
pub mod launcher;
pub mod policy;
pub mod ros_bridge;
pub mod runtime;
pub mod twin;
pub mod xarm;
