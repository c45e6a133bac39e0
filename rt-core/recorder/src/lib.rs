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
//! Each channel carries the QoS its publisher offered (`offered_qos_profiles`:
//! `/robot_description` transient local, so `ros2 bag play` latches the URDF; every other
//! topic volatile), and with [`RecorderConfig::bag_metadata`] (the launcher's run folders) the
//! file's folder is a rosbag2 bag ([`bag`]): `metadata.yaml` (rosbag2 metadata version 9, as
//! Jazzy writes it) beside the MCAP file, so `ros2 bag info runs/<id>`, `ros2 bag play
//! runs/<id>` and the `rosbags` Python reader open the folder.
//!
//! `assets/foxglove/foresight-layout.json` is a Foxglove layout for a run (Foxglove: Layouts
//! → Import): a 3D panel with the robot (`/robot_description`, `/tf`) and the scene markers,
//! plots of the verdicts (plan approved, safe, task reached) and of the separation (the
//! twin's smallest robot–obstacle distance, the referee's clearance), and the raw verdicts.
//!
//! The file is bounded ([`RecorderConfig::max_bytes`]: recording stops, once, with a
//! warning), written in whole chunks at least every [`RecorderConfig::flush_interval_s`] so a
//! killed process leaves a file readable up to its last chunk, and finished (summary and
//! footer) by [`Recorder::stop`] or when the handle is dropped ([`mcap_file`]).
//!
//! ```no_run
//! use recorder::{Recorder, RecorderConfig};
//! let urdf = std::fs::read_to_string("assets/xarm5.urdf").unwrap();
//! let mut cfg = RecorderConfig::new("runs/x/run.mcap".into(), "run42", urdf);
//! cfg.bag_metadata = true; // runs/x/ is a rosbag2 bag: metadata.yaml beside run.mcap
//! let rec = Recorder::start(cfg).unwrap();
//! // … the run …
//! let stats = rec.stop().unwrap();
//! println!("{} messages", stats.total());
//! ```

#![forbid(unsafe_code)]

pub mod bag;
pub mod cdr;
pub mod markers;
pub mod mcap_file;
pub mod msgs;
pub mod recorder;
pub mod ros_view;

pub use bag::{
    BagMetadata, BagMetadataWriteError, Durability, OfferedQos, RecordingState, RecordingStats,
};
pub use mcap_file::{McapFile, McapFileOptions};
pub use msgs::RefereeClearance;
pub use recorder::{
    DEFAULT_MAX_BYTES, Recorder, RecorderConfig, RecorderConfigError, RecorderStartError,
    RecorderStopError, topics,
};

#[cfg(test)]
mod tests {
    use crate::msgs::{RefereeClearanceMsg, RosMessage, TwinVerdictMsg};

    /// The Foxglove layout parses and every topic its panels name is recorded.
    #[test]
    fn the_foxglove_layout_shows_recorded_topics() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../assets/foxglove/foresight-layout.json"
        ))
        .unwrap();
        let layout: serde_json::Value = serde_json::from_str(&text).unwrap();
        let panels = layout["configById"].as_object().unwrap();
        let mut named = Vec::new();
        for panel in panels.values() {
            if let Some(topics) = panel["topics"].as_object() {
                named.extend(topics.keys().cloned());
            }
            for path in panel["paths"].as_array().into_iter().flatten() {
                let (topic, field) = path["value"].as_str().unwrap().split_once('.').unwrap();
                // The plotted field is in the topic's message definition.
                let definition = match topic {
                    crate::topics::VERDICTS => TwinVerdictMsg::definition(),
                    crate::topics::REFEREE => RefereeClearanceMsg::definition(),
                    other => panic!("no plot expected of {other}"),
                };
                assert!(
                    definition
                        .lines()
                        .any(|l| l.split_whitespace().nth(1) == Some(field)),
                    "{topic} has no field {field}"
                );
                named.push(topic.to_owned());
            }
            if let Some(topic) = panel["topicPath"].as_str() {
                named.push(topic.to_owned());
            }
        }
        for t in [
            crate::topics::ROBOT_DESCRIPTION,
            crate::topics::SCENE_MARKERS,
            crate::topics::VERDICTS,
            crate::topics::REFEREE,
        ] {
            assert!(named.iter().any(|n| n == t), "{t} not shown: {named:?}");
        }
        for n in &named {
            assert!(
                crate::topics::ALL.contains(&n.as_str()),
                "{n} is not recorded"
            );
        }
        // Every panel of the layout tree has a configuration.
        let tree = layout["layout"].to_string();
        for id in panels.keys() {
            assert!(tree.contains(&format!("\"{id}\"")), "{id} not placed");
        }
    }
}
