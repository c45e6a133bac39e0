//! [`XArmError`]: why an operation on the controller failed. Small and `Copy`, so it
//! travels through the real-time cycle.

use std::io::ErrorKind;

use crate::codec::FrameError;
use crate::codes::ControllerError;
use crate::limits::JointCheckError;
use crate::report::ReportError;
use crate::sim_identity::SimIdentityError;

/// Why a driver operation failed. Small and `Copy`: it travels through the cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum XArmError {
    /// A socket operation failed.
    #[error("socket error: {0:?}")]
    Io(ErrorKind),
    /// `GET_VERSION` names another arm than an xArm5 (type 5, 5 axes): nothing is driven.
    #[error(
        "the controller reports robot type {robot_type} with {axis} axes, not an xArm5 \
         (type 5, 5 axes): refusing to drive it with the xArm5 model"
    )]
    NotXArm5 {
        /// Axis count the controller reports.
        axis: u8,
        /// Robot type the controller reports.
        robot_type: u8,
    },
    /// A simulation-only right was asked for ([`crate::config::XArmConfig::sim_secret`]) and
    /// the controller did not prove it is this run's `xarm-sim`: it is a real arm, and
    /// nothing but `GET_VERSION` and the challenge was sent to it.
    #[error("the controller did not prove it is this run's xarm-sim: {0}")]
    NotSimulator(SimIdentityError),
    /// No reply within the timeout.
    #[error("no reply within the timeout")]
    Timeout,
    /// The connection is lost (reconnecting with back-off).
    #[error("connection to the controller lost")]
    Disconnected,
    /// A malformed or unexpected frame from the controller.
    #[error("bad frame from the controller: {0}")]
    Frame(FrameError),
    /// A malformed report packet.
    #[error("bad report from the controller: {0}")]
    Report(ReportError),
    /// The controller reports an error code; motion is refused until it is cleared.
    #[error("controller error: {0}")]
    Controller(ControllerError),
    /// A reply carried the error bit; the code is being read (`GET_ERROR` in flight).
    #[error("controller flagged an error; reading its code")]
    ErrorPending,
    /// The controller cannot move (status bit 4: stopped, not enabled, wrong mode).
    #[error("controller not ready to move (state {state}, mode {mode})")]
    NotReady {
        /// Last known state.
        state: u8,
        /// Last known mode.
        mode: u8,
    },
    /// The target is outside the joint limits (nothing was sent).
    #[error("target refused: {0}")]
    JointLimit(JointCheckError),
    /// Too many requests in flight or the socket buffer is full (nothing was sent).
    #[error("command pipeline full")]
    Backlog,
    /// After a reconnect the target is too far from the actual joints.
    #[error("target of joint {} jumps away from the re-read joint state", .joint + 1)]
    ResumeJump {
        /// 0-based joint.
        joint: u8,
    },
    /// No report yet, or the last one is stale.
    #[error("no fresh state from the report stream")]
    NoState,
}

impl From<FrameError> for XArmError {
    fn from(e: FrameError) -> Self {
        Self::Frame(e)
    }
}

impl From<std::io::Error> for XArmError {
    fn from(e: std::io::Error) -> Self {
        match e.kind() {
            ErrorKind::WouldBlock | ErrorKind::TimedOut => Self::Timeout,
            ErrorKind::UnexpectedEof
            | ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::BrokenPipe => Self::Disconnected,
            k => Self::Io(k),
        }
    }
}
