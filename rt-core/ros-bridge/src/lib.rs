//! The ROS 2 bridge: a non-real-time process (binary `ros-bridge`) that subscribes to the
//! runtime's iceoryx2 topics and republishes them over DDS (ros2-client), so a ROS 2 user sees
//! the arm, the scene and the lookahead verdict in RViz with no extra code:
//!
//! | ROS 2 topic | type | from |
//! |---|---|---|
//! | `/joint_states` | `sensor_msgs/JointState` | latest `RobotState`, at `rate_hz` (≥ 50 Hz) |
//! | `/tf` | `tf2_msgs/TFMessage` | link frames from the twin's forward kinematics |
//! | `/robot_description` | `std_msgs/String` (transient local) | `assets/xarm5.urdf` |
//! | `/foresight/scene_markers` | `visualization_msgs/MarkerArray` | goal and obstacle boxes (from `DetectionFrame`s), the TCP trail, and the last `TwinVerdict` as text |
//!
//! and serves one action, `/foresight/reach` (`foresight_msgs/action/Reach`, [`reach`]): a
//! goal on the table from any ROS 2 program (or `foresight reach`, [`reach_client`]), checked
//! against the workspace, handed to rt-core as an iceoryx2 `GoalRequest`, with feedback
//! and a result (reached, infeasible with the reason, stopped and why, cancelled). rt-core
//! takes it only with the goal source `action` (`foresight --ros --goal-source action`).
//!
//! The bridge never touches the cycle: it reads the same shared-memory samples as any other
//! subscriber, so a slow DDS peer cannot delay a control cycle.
//!
//! DDS discovery: by default the participant is restricted to the loopback interface
//! (`--ros-network 127.0.0.1`), which is right for a single machine and for tests; pass the
//! robot PC's address to reach other hosts. rustdds also announces itself to same-host peers
//! over unicast, so processes on one machine match even where `lo` has no MULTICAST flag.

#![forbid(unsafe_code)]

pub mod msgs;
pub mod reach;
pub mod reach_client;
pub mod reach_msgs;

use std::collections::VecDeque;
use std::net::IpAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::prelude::*;
use nalgebra::Vector3;
use recorder::ros_view::{link_transforms, scene_view};
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    dds::rustdds::DomainParticipantBuilder,
    qos::{Durability, History, WhenFull},
};
use serde::{Deserialize, Serialize};
use shm_schemas::{
    DetectionFrame, GoalRefusal, RetrainProgress, RetrainRequest, RobotState, TwinVerdict, services,
};

use msgs::{
    ColorRgba, Header, JointState, Marker, MarkerArray, Point, Pose, Quaternion, Time,
    Vector3 as RosVector3,
};
use twin::{DOF, LinkPoses, RobotModel};

/// A verdict in words, as the scene markers show it (the shared view's).
pub use recorder::ros_view::verdict_text;

/// Why the bridge could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum RosBridgeError {
    /// DDS participant, node, topic or publisher creation failed. (Text: the failures come
    /// from a dozen ros2_client and rustdds error types, several without `Error`.)
    #[error("ROS 2 / DDS set-up failed: {0}")]
    Dds(String),
    /// No `Reach` action server answered the client's goal in time.
    #[error(
        "ROS 2 / DDS set-up failed: no Reach action server answered within {0:?} (is `foresight --ros --goal-source action` running, on this DDS domain and network?)"
    )]
    NoReachServer(std::time::Duration),
    /// The iceoryx2 node could not be created.
    #[error("shared-memory set-up failed")]
    ShmNode(#[source] services::NodeCreateError),
    /// An iceoryx2 port could not be opened.
    #[error("shared-memory set-up failed")]
    Shm(#[from] shm_schemas::ShmOpenError),
}

/// Bridge settings.
#[derive(Debug, Clone)]
pub struct RosBridgeConfig {
    /// iceoryx2 service-name prefix of the run to bridge.
    pub prefix: String,
    /// DDS domain id (ROS_DOMAIN_ID).
    pub domain_id: u16,
    /// Interfaces DDS may use; empty = rustdds' default (all interfaces).
    pub networks: Vec<IpAddr>,
    /// `/joint_states` rate (Hz).
    pub rate_hz: f64,
    /// Fixed frame of every published pose.
    pub frame_id: String,
    /// URDF text for `/robot_description`.
    pub urdf: String,
    /// Node name.
    pub node_name: String,
    /// The `Reach` action's settings.
    pub reach: reach::ReachSettings,
}

/// What the bridge did (returned when it stops).
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
pub struct RosBridgeStats {
    /// `/joint_states` messages published.
    pub joint_states: u64,
    /// `/tf` messages published.
    pub tf_messages: u64,
    /// `/foresight/scene_markers` messages published.
    pub marker_arrays: u64,
    /// Shared-memory samples rejected by `validate()`.
    pub rejected_samples: u64,
    /// The `Reach` action's goals.
    pub reach: reach::ReachStats,
}

/// `geometry_msgs/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation (m).
    pub translation: RosVector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Pose of the child in the parent.
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}
impl ros2_client::Message for TfMessage {}

/// `std_msgs/String`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}
impl ros2_client::Message for StringMsg {}

fn now_stamp() -> Time {
    let ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    Time::from_unix_ns(ns)
}

fn dds(e: impl std::fmt::Debug) -> RosBridgeError {
    RosBridgeError::Dds(format!("{e:?}"))
}

/// Creates a ROS 2 context whose DDS participant uses only `networks` (all when empty).
///
/// # Errors
/// [`RosBridgeError::Dds`].
pub fn ros_context(domain_id: u16, networks: &[IpAddr]) -> Result<Context, RosBridgeError> {
    let mut builder = DomainParticipantBuilder::new(domain_id);
    if !networks.is_empty() {
        builder = builder.with_only_networks(networks.iter().copied());
    }
    let participant = builder.build().map_err(dds)?;
    Context::from_domain_participant(participant).map_err(dds)
}

/// QoS of the streaming topics (`/joint_states`, `/tf`, markers): reliable, volatile, keep
/// last 10 — what rviz2 and robot_state_publisher subscribe with.
pub fn stream_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

/// QoS of `/robot_description`: transient local, so late subscribers get it.
pub fn latched_qos() -> QosProfile {
    stream_qos()
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}

/// Names of the joints as in `assets/xarm5.urdf`.
pub const JOINT_NAMES: [&str; DOF] = ["joint1", "joint2", "joint3", "joint4", "joint5"];

struct Publishers {
    joint_states: Publisher<JointState>,
    tf: Publisher<TfMessage>,
    markers: Publisher<MarkerArray>,
    _description: Publisher<StringMsg>,
}

fn make_publishers(node: &mut Node, urdf: &str) -> Result<Publishers, RosBridgeError> {
    let qos = stream_qos();
    let topic = |node: &mut Node, name: &str, pkg: &str, ty: &str, qos: &QosProfile| {
        let (ns, base) = name.rsplit_once('/').unwrap_or(("/", name));
        let ns = if ns.is_empty() { "/" } else { ns };
        let name = Name::new(ns, base).map_err(dds)?;
        node.create_topic(&name, MessageTypeName::new(pkg, ty), qos)
            .map_err(dds)
    };
    let js_topic = topic(node, "/joint_states", "sensor_msgs", "JointState", &qos)?;
    let tf_topic = topic(node, "/tf", "tf2_msgs", "TFMessage", &qos)?;
    let mk_topic = topic(
        node,
        "/foresight/scene_markers",
        "visualization_msgs",
        "MarkerArray",
        &qos,
    )?;
    let latched = latched_qos();
    let rd_topic = topic(node, "/robot_description", "std_msgs", "String", &latched)?;
    let description = node.create_publisher(&rd_topic, None).map_err(dds)?;
    description
        .publish(StringMsg {
            data: urdf.to_owned(),
        })
        .map_err(dds)?;
    Ok(Publishers {
        joint_states: node.create_publisher(&js_topic, None).map_err(dds)?,
        tf: node.create_publisher(&tf_topic, None).map_err(dds)?,
        markers: node.create_publisher(&mk_topic, None).map_err(dds)?,
        _description: description,
    })
}

/// Builds the `/joint_states` message of a robot state.
pub fn joint_state_msg(state: &RobotState, frame_id: &str) -> JointState {
    JointState {
        header: Header {
            stamp: now_stamp(),
            frame_id: frame_id.to_owned(),
        },
        name: JOINT_NAMES.iter().map(|s| (*s).to_owned()).collect(),
        position: state.joints_rad.to_vec(),
        velocity: state.joint_velocities_rad_s.to_vec(),
        effort: Vec::new(),
    }
}

/// Builds the `/tf` message: every link frame of the twin's FK, parented to `frame_id`
/// ([`recorder::ros_view::link_transforms`], as the recordings hold them).
pub fn tf_msg(model: &RobotModel, poses: &LinkPoses, frame_id: &str) -> TfMessage {
    let header = Header {
        stamp: now_stamp(),
        frame_id: frame_id.to_owned(),
    };
    let transforms = link_transforms(model, poses, frame_id)
        .into_iter()
        .map(|t| TransformStamped {
            header: header.clone(),
            child_frame_id: t.child_frame_id.to_owned(),
            transform: Transform {
                translation: vector3(t.translation_m),
                rotation: Quaternion {
                    x: t.rotation_xyzw[0],
                    y: t.rotation_xyzw[1],
                    z: t.rotation_xyzw[2],
                    w: t.rotation_xyzw[3],
                },
            },
        })
        .collect();
    TfMessage { transforms }
}

fn vector3(v: [f64; 3]) -> RosVector3 {
    RosVector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

/// Builds the scene marker array ([`recorder::ros_view::scene_view`], the picture the
/// recordings hold, with the TCP trail as the `tcp_trail` line): a DELETEALL, then goal and
/// obstacles from the latest detections, the TCP trail, and the verdict as text above the goal.
pub fn scene_markers(
    detections: Option<&DetectionFrame>,
    tcp_trail_m: &VecDeque<[f64; 3]>,
    verdict: Option<&TwinVerdict>,
    frame_id: &str,
) -> MarkerArray {
    let header = Header {
        stamp: now_stamp(),
        frame_id: frame_id.to_owned(),
    };
    let view = scene_view(
        detections,
        "tcp_trail",
        tcp_trail_m.iter().copied(),
        verdict,
    );
    MarkerArray {
        markers: view
            .into_iter()
            .map(|m| Marker {
                header: header.clone(),
                ns: m.ns.to_owned(),
                id: m.id,
                kind: m.shape.ros_type(),
                action: m.action.ros_action(),
                pose: Pose {
                    position: Point {
                        x: m.position_m[0],
                        y: m.position_m[1],
                        z: m.position_m[2],
                    },
                    orientation: Quaternion::default(),
                },
                scale: vector3(m.scale_m),
                color: ColorRgba {
                    r: m.rgba[0],
                    g: m.rgba[1],
                    b: m.rgba[2],
                    a: m.rgba[3],
                },
                points: m
                    .points_m
                    .into_iter()
                    .map(|p| Point {
                        x: p[0],
                        y: p[1],
                        z: p[2],
                    })
                    .collect(),
                text: m.text,
                ..Marker::default()
            })
            .collect(),
    }
}

/// Runs the bridge until `stop` is set. Publishes `/joint_states` and `/tf` at `rate_hz`
/// once a robot state has arrived, and the scene markers at 5 Hz.
///
/// # Errors
/// [`RosBridgeError`] when DDS or shared memory cannot be set up.
pub fn run(
    cfg: &RosBridgeConfig,
    model: &RobotModel,
    stop: &Arc<AtomicBool>,
) -> Result<RosBridgeStats, RosBridgeError> {
    let context = ros_context(cfg.domain_id, &cfg.networks)?;
    let mut node = context
        .new_node(
            NodeName::new("/foresight", &cfg.node_name).map_err(dds)?,
            NodeOptions::new().enable_rosout(false),
        )
        .map_err(dds)?;
    let publishers = make_publishers(&mut node, &cfg.urdf)?;

    let shm = RosBridgeError::Shm;
    let (shm_node, _cleanup) =
        services::create_node::<ipc::Service>("ros-bridge").map_err(RosBridgeError::ShmNode)?;
    let state_sub =
        services::open_subscriber::<RobotState, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let det_sub =
        services::open_subscriber::<DetectionFrame, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let verdict_sub =
        services::open_subscriber::<TwinVerdict, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let retrain_req_sub =
        services::open_subscriber::<RetrainRequest, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let retrain_prog_sub =
        services::open_subscriber::<RetrainProgress, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let refusal_sub =
        services::open_subscriber::<GoalRefusal, _>(&shm_node, &cfg.prefix).map_err(shm)?;
    let mut reach = reach::ReachServer::new(&mut node, &shm_node, &cfg.prefix, cfg.reach)?;
    let mut retrain_requests: Vec<RetrainRequest> = Vec::new();
    let mut retrain_progress: Vec<RetrainProgress> = Vec::new();
    let mut goal_refusals: Vec<GoalRefusal> = Vec::new();

    let mut stats = RosBridgeStats::default();
    let mut latest_state: Option<RobotState> = None;
    let mut latest_det: Option<DetectionFrame> = None;
    let mut latest_verdict: Option<TwinVerdict> = None;
    let mut trail: VecDeque<[f64; 3]> = VecDeque::with_capacity(512);
    let period = Duration::from_secs_f64(1.0 / cfg.rate_hz.max(1.0));
    let marker_period = Duration::from_millis(200);
    let mut next = Instant::now();
    let mut next_markers = Instant::now();

    while !stop.load(Ordering::Relaxed) {
        let mut fresh_state = false;
        while let Ok(Some(s)) = state_sub.receive() {
            if s.validate().is_ok() {
                latest_state = Some(*s);
                fresh_state = true;
            } else {
                stats.rejected_samples += 1;
            }
        }
        retrain_requests.clear();
        while let Ok(Some(s)) = retrain_req_sub.receive() {
            let r = *s;
            drop(s);
            if r.validate().is_ok() {
                retrain_requests.push(r);
            } else {
                stats.rejected_samples += 1;
            }
        }
        retrain_progress.clear();
        while let Ok(Some(s)) = retrain_prog_sub.receive() {
            if s.validate().is_ok() {
                retrain_progress.push(*s);
            } else {
                stats.rejected_samples += 1;
            }
        }
        goal_refusals.clear();
        while let Ok(Some(s)) = refusal_sub.receive() {
            if s.validate().is_ok() {
                goal_refusals.push(*s);
            } else {
                stats.rejected_samples += 1;
            }
        }
        while let Ok(Some(s)) = det_sub.receive() {
            if s.validate().is_ok() {
                latest_det = Some(*s);
            } else {
                stats.rejected_samples += 1;
            }
        }
        while let Ok(Some(s)) = verdict_sub.receive() {
            if s.validate().is_ok() {
                latest_verdict = Some(*s);
            } else {
                stats.rejected_samples += 1;
            }
        }
        if let Some(state) = &latest_state {
            let poses = model.fk(&state.joints_rad);
            if publishers
                .joint_states
                .publish(joint_state_msg(state, &cfg.frame_id))
                .is_ok()
            {
                stats.joint_states += 1;
            }
            if publishers
                .tf
                .publish(tf_msg(model, &poses, &cfg.frame_id))
                .is_ok()
            {
                stats.tf_messages += 1;
            }
            let tcp = poses.tcp_m();
            let moved = trail
                .back()
                .is_none_or(|p| (Vector3::from(*p) - tcp).norm() > 0.002);
            if moved {
                if trail.len() == trail.capacity() {
                    trail.pop_front();
                }
                trail.push_back([tcp.x, tcp.y, tcp.z]);
            }
        }
        reach.poll(&reach::ReachInputs {
            state: latest_state.as_ref().map(|s| (s, fresh_state)),
            verdict: latest_verdict.as_ref(),
            retrain_requests: &retrain_requests,
            retrain_progress: &retrain_progress,
            goal_refusals: &goal_refusals,
        });
        let now = Instant::now();
        if now >= next_markers {
            let msg = scene_markers(
                latest_det.as_ref(),
                &trail,
                latest_verdict.as_ref(),
                &cfg.frame_id,
            );
            if publishers.markers.publish(msg).is_ok() {
                stats.marker_arrays += 1;
            }
            next_markers = now + marker_period;
        }
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    reach.shut_down();
    stats.reach = reach.stats();
    Ok(stats)
}
