//! Every run as an MCAP file that `ros2 bag info`, `ros2 bag play` and Foxglove open.
//!
//! A [`Recorder`] subscribes to a run's iceoryx2 services on its own normal thread (never the
//! cycle's: it reads the same shared-memory samples as any other subscriber, so a slow disk
//! cannot delay a control cycle) and writes ROS 2 messages, CDR-encoded ([`cdr`]) with their
//! full `ros2msg` definitions as schemas ([`msgs`]):
//!
//! | topic | type | from |
//! |---|---|---|
//! | `/joint_states`, `/joint_commands` | `sensor_msgs/JointState` | `RobotState` (measured, commanded), ≤ `state_rate_hz` |
//! | `/tf` | `tf2_msgs/TFMessage` | the twin's FK of the measured joints |
//! | `/robot_description` | `std_msgs/String` | the URDF, once at the start |
//! | `/foresight/scene_markers` | `visualization_msgs/MarkerArray` | goal and boxes seen, the commanded TCP path since the last approved plan, the verdict ([`markers`]) |
//! | `/foresight/detections` | `foresight_msgs/Detections` | `DetectionFrame` |
//! | `/foresight/verdicts` | `foresight_msgs/TwinVerdict` | `TwinVerdict` |
//! | `/foresight/retrain_requests`, `/foresight/retrain_progress` | `foresight_msgs/…` | the learner's services |
//! | `/foresight/robot_status` | `foresight_msgs/RobotStatus` | `RobotState` (stop reason, controller codes) |
//! | `/foresight/referee` | `foresight_msgs/RefereeClearance` | handed in by the owner ([`Recorder::referee`]) |
//!
//! The file is bounded ([`RecorderConfig::max_bytes`]: recording stops, once, with a
//! warning), written in whole chunks at least every [`RecorderConfig::flush_interval_s`] so a
//! killed process leaves a file readable up to its last chunk, and finished (summary and
//! footer) by [`Recorder::stop`] or when the handle is dropped ([`mcap_file`]).
//!
//! ```no_run
//! use recorder::{Recorder, RecorderConfig};
//! let urdf = std::fs::read_to_string("assets/xarm5.urdf").unwrap();
//! let rec = Recorder::start(RecorderConfig::new("runs/x/run.mcap".into(), "run42", urdf)).unwrap();
//! // … the run …
//! let stats = rec.stop().unwrap();
//! println!("{} messages", stats.total());
//! ```

#![forbid(unsafe_code)]

pub mod cdr;
pub mod markers;
pub mod mcap_file;
pub mod msgs;
pub mod recorder;

pub use mcap_file::{McapFile, McapFileOptions, RecordingStats};
pub use msgs::RefereeClearance;
pub use recorder::{
    DEFAULT_MAX_BYTES, Recorder, RecorderConfig, RecorderConfigError, RecorderStartError,
    RecorderStopError, topics,
};
