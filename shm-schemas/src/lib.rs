//! The shared-memory contract of Foresight: every payload that crosses a process boundary
//! over iceoryx2, with its schema version, its service name and its validation — and the
//! scene file format that the twin, the simulated arm and the synthetic camera all read.
//!
//! Every payload is `#[repr(C)]`, fixed-size (no pointers, no heap), derives iceoryx2's
//! `ZeroCopySend` with an explicit versioned type name (`foresight::<Name>.v<N>`), has a
//! compile-time size check and a `validate()` that every consumer calls, so all reject the
//! same bad input the same way. Enums and flags are stored as `u8` and converted with
//! checked `TryFrom` (a `bool` or Rust enum in shared memory would make a bad byte UB).
//!
//! | payload | direction | service |
//! |---|---|---|
//! | [`DetectionFrame`] | perception → rt-core | [`services::DETECTIONS`] |
//! | [`PolicyBlob`] | learner → rt-core | [`services::POLICIES`] |
//! | [`RetrainRequest`] | rt-core → learner | [`services::RETRAIN_REQUESTS`] |
//! | [`RetrainProgress`] | learner → anyone | [`services::RETRAIN_PROGRESS`] |
//! | [`RobotState`] | rt-core → anyone | [`services::ROBOT_STATE`] |
//! | [`TwinVerdict`] | rt-core → anyone | [`services::TWIN_VERDICTS`] |
//! | [`GoalRequest`] | ros-bridge → rt-core | [`services::GOAL_REQUESTS`] |
//! | [`GoalRefusal`] | rt-core → ros-bridge | [`services::GOAL_REFUSALS`] |
//!
//! Beside the payloads: the scene-file format ([`scene_file`]), the one view of rt-core's
//! `runtime.toml` that other processes read too ([`runtime_view`]: `[intake]`, `[shield]`,
//! `[goal]` with their defaults), and [`error_chain`], how every process prints an error
//! with its causes.
//!
//! ```no_run
//! use iceoryx2::prelude::*;
//! use shm_schemas::{DetectedObject, DetectionFrame, ObjectClass, services};
//!
//! let (node, _) = services::create_node::<ipc::Service>("perception").unwrap();
//! let publisher = services::open_publisher::<DetectionFrame, _>(&node, "run42").unwrap();
//! let mut frame = DetectionFrame { sequence: 1, ..Default::default() };
//! frame.push(DetectedObject::new(1, ObjectClass::Goal, 0.9, [0.4, 0.2, 0.025], [0.05; 3]));
//! frame.validate().unwrap();
//! publisher.send_copy(frame).unwrap();
//! ```

pub mod checksum;
pub mod cli_bounds;
pub mod clock;
pub mod detection;
pub mod error;
pub mod error_chain;
pub mod goal_refusal;
pub mod goal_request;
pub mod policy_blob;
pub mod policy_builder;
pub mod process_ties;
pub mod retrain;
pub mod robot_state;
pub mod runtime_view;
pub mod scene_file;
pub mod services;
pub mod verdict;

pub use detection::{DetectedObject, DetectionFrame, MAX_DETECTIONS, ObjectClass};
pub use error::{SchemaError, flag_byte};
pub use goal_refusal::{GoalRefusal, GoalRefusalKind};
pub use goal_request::{GoalBoundError, GoalBounds, GoalCommand, GoalRequest, GoalRequestAgeError};
pub use policy_blob::{
    ACT_DIM, ActionSpace, Activation, JOINT_ACT_DIM, JOINT_OBS_DIM, LayerView, MAX_ACT,
    MAX_HIDDEN_LAYERS, MAX_HIDDEN_WIDTH, MAX_OBS, MAX_WEIGHTS, OBS_DIM, OBS_LAYOUT_CARTESIAN,
    OBS_LAYOUT_JOINT_V1, PAPER_OBS_DIM, POLICY_FORMAT_VERSION, PolicyBlob, required_weights,
};
pub use policy_builder::{PolicyBlobBuilder, PolicyBuildError};
pub use retrain::{
    BLOCKER_NONE, BLOCKER_SELF, BLOCKER_TABLE, InfeasibleKind, ObstacleBox, RetrainPhase,
    RetrainProgress, RetrainRequest,
};
pub use robot_state::{N_JOINTS, RobotState, StopReason};
pub use services::{ShmMessage, ShmOpenError, loan_zeroed, open_publisher, open_subscriber};
pub use verdict::{EpisodeEnd, Executor, PhaseCode, TwinVerdict};
