//! `foresight_msgs/action/Reach`, as serde structs in ROS 2 IDL field order (the interface
//! package for ROS 2 programs is `rt-core/ros-bridge/foresight_msgs/`, `action/Reach.action`):
//!
//! ```text
//! # Goal: a target on the table, base (world) frame
//! float64 x_m
//! float64 y_m
//! float64 approach_height_m   # TCP height above the table over the target; 0 = the default
//! float64 deadline_s          # give up after this long (stopped); 0 = no deadline
//! ---
//! # Result
//! uint8 REACHED=1
//! uint8 INFEASIBLE=2
//! uint8 STOPPED=3
//! uint8 CANCELLED=4
//! uint8 PREEMPTED=5
//! uint8 REFUSED=6
//! uint8 outcome
//! string reason               # why (the infeasibility, the stop, the bound, the new goal)
//! float64 distance_m          # TCP to the target at the end (NaN when unknown)
//! ---
//! # Feedback
//! string phase                # the twin worker's phase (episode, dwell-at-goal, …) or cancelling
//! string executor             # policy, planner or unknown
//! float64 distance_m          # TCP to the target
//! string verdict              # the latest lookahead verdict in words
//! ```

use ros2_client::Message;
use serde::{Deserialize, Serialize};

/// The action's ROS 2 package.
pub const REACH_PACKAGE: &str = "foresight_msgs";
/// The action's type name.
pub const REACH_TYPE: &str = "Reach";
/// The action's namespace.
pub const REACH_NAMESPACE: &str = "/foresight";
/// The action's base name (`/foresight/reach`).
pub const REACH_NAME: &str = "reach";

/// The goal.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ReachGoal {
    /// Target x on the table, base frame, m.
    pub x_m: f64,
    /// Target y on the table, base frame, m.
    pub y_m: f64,
    /// TCP height above the table over the target, m; 0 = the task's default.
    pub approach_height_m: f64,
    /// Deadline from acceptance, s; 0 = none.
    pub deadline_s: f64,
}
impl Message for ReachGoal {}

/// How a goal ended (`ReachResult::outcome`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ReachOutcome {
    /// The TCP came within the task's tolerance of the target.
    Reached = 1,
    /// No safe way to the goal exists (the feasibility check's reason).
    Infeasible = 2,
    /// The arm stopped for good, or the deadline passed (the reason says which).
    Stopped = 3,
    /// Cancelled by the client; the arm is at rest.
    Cancelled = 4,
    /// Replaced by a newer goal (the reason names it).
    Preempted = 5,
    /// Not accepted: out of bounds (the reason names the bound), or the goal source is the
    /// camera.
    Refused = 6,
}

impl ReachOutcome {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Reached => "reached",
            Self::Infeasible => "infeasible",
            Self::Stopped => "stopped",
            Self::Cancelled => "cancelled",
            Self::Preempted => "preempted",
            Self::Refused => "refused",
        }
    }

    /// From the wire byte.
    pub fn from_wire(byte: u8) -> Option<Self> {
        Some(match byte {
            1 => Self::Reached,
            2 => Self::Infeasible,
            3 => Self::Stopped,
            4 => Self::Cancelled,
            5 => Self::Preempted,
            6 => Self::Refused,
            _ => return None,
        })
    }
}

/// The result.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReachResult {
    /// [`ReachOutcome`] as a byte (0 = unknown goal).
    pub outcome: u8,
    /// Why.
    pub reason: String,
    /// TCP to the target at the end, m (NaN when unknown).
    pub distance_m: f64,
}
impl Message for ReachResult {}

impl ReachResult {
    /// A result.
    pub fn new(outcome: ReachOutcome, reason: impl Into<String>, distance_m: f64) -> Self {
        Self {
            outcome: outcome as u8,
            reason: reason.into(),
            distance_m,
        }
    }

    /// The outcome, if known.
    pub fn outcome(&self) -> Option<ReachOutcome> {
        ReachOutcome::from_wire(self.outcome)
    }
}

/// The feedback.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReachFeedback {
    /// The worker's phase, or `waiting` / `cancelling`.
    pub phase: String,
    /// What moves the arm (`policy`, `planner`, `unknown`).
    pub executor: String,
    /// TCP to the target, m.
    pub distance_m: f64,
    /// The latest verdict in words.
    pub verdict: String,
}
impl Message for ReachFeedback {}
