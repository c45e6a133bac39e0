//! `xarm-sim`'s library side: a simulated xArm5 control box that speaks the controller
//! protocol on the command and report ports, integrates servo targets within the joint
//! limits and 180°/s, and checks the arm against a ground-truth scene with an independent
//! referee (its own kinematics, link shapes and distance code, not the twin's: a contact
//! with a box, the table or itself raises error 31 and stops the arm, like the real
//! controller; the smallest clearance of the run goes into the summary). Boxes with paths
//! move: every physics tick places them where their paths put them, time counted from the
//! moment their scene came into force ([`world`]); a box that walks into the arm at rest
//! raises error 31 too (a real xArm's collision detection trips when a stopped arm is
//! pushed), and the summary counts contacts while moving and at rest apart. In
//! servo mode it raises the controller's protective faults: a `servo_j` target that would
//! move a joint or the TCP too fast in one servo period is refused with error 24 (joint
//! speed) or 60 (linear speed) and stops the arm ([`controller::ProtectiveLimits`]).
//!
//! [`controller::Controller`] is the pure state machine; [`server::SimServer`] binds the
//! sockets and runs the threads; [`world::World`] is the ground truth, judged by
//! [`referee::Referee`].

#![forbid(unsafe_code)]

pub mod controller;
/// The referee, a crate of its own (`xarm-referee`) shared with the launcher and the sweep.
pub use xarm_referee as referee;
pub mod server;
pub mod world;

pub use controller::{Controller, ProtectiveFault, ProtectiveLimits, ServoStreamStats};
pub use server::{SimError, SimOptions, SimPorts, SimServer, SimSummary};
