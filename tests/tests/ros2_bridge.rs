//! ROS 2 interop: the real `ros-bridge` process turns iceoryx2 `RobotState`,
//! `DetectionFrame` and `TwinVerdict` samples into `/joint_states` and
//! `/foresight/scene_markers`, and a ros2-client subscriber receives them over DDS.
//!
//! Everything runs inside a private network namespace (`unshare -n`) with `lo` up and
//! multicast enabled on it, so DDS discovery works and no packet leaves the namespace.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::{IpAddr, Ipv4Addr};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use foresight_tests::{
    ChildGuard, NetnsOutcome, asset, bin_path, run_in_private_netns, unique_prefix,
};
use iceoryx2::prelude::*;
use ros_bridge::msgs::{JointState, Marker, MarkerArray};
use ros_bridge::{ros_context, stream_qos};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use shm_schemas::{
    DetectedObject, DetectionFrame, EpisodeEnd, ObjectClass, RobotState, TwinVerdict, services,
};

const JOINTS: [f64; 5] = [0.1, -0.2, -0.3, 0.4, 0.5];

#[test]
fn bridge_publishes_joint_states_and_scene_markers_over_dds() {
    if run_in_private_netns("bridge_publishes_joint_states_and_scene_markers_over_dds")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let prefix = unique_prefix("ros2");

    // Shared-memory side: what rt-core and perception would publish.
    let (node, _cleanup) = services::create_node::<ipc::Service>("ros2-test").unwrap();
    let state_pub = services::open_publisher::<RobotState, _>(&node, &prefix).unwrap();
    let det_pub = services::open_publisher::<DetectionFrame, _>(&node, &prefix).unwrap();
    let verdict_pub = services::open_publisher::<TwinVerdict, _>(&node, &prefix).unwrap();

    let mut bridge = ChildGuard::spawn(
        "ros-bridge",
        Command::new(bin_path("ros-bridge"))
            .args(["--prefix", &prefix, "--rate-hz", "100", "--seconds", "60"])
            .args(["--urdf", asset("xarm5.urdf").to_str().unwrap()])
            .args(["--runtime", asset("runtime.toml").to_str().unwrap()])
            .args(["--task", asset("task.toml").to_str().unwrap()])
            .stdout(Stdio::piped()),
    );

    // ROS 2 side: an ordinary subscriber, loopback only.
    let ctx = ros_context(0, &[IpAddr::V4(Ipv4Addr::LOCALHOST)]).unwrap();
    let mut ros_node = ctx
        .new_node(
            NodeName::new("/test", "listener").unwrap(),
            NodeOptions::new(),
        )
        .unwrap();
    let qos = stream_qos();
    let js_topic = ros_node
        .create_topic(
            &Name::new("/", "joint_states").unwrap(),
            MessageTypeName::new("sensor_msgs", "JointState"),
            &qos,
        )
        .unwrap();
    let mk_topic = ros_node
        .create_topic(
            &Name::new("/foresight", "scene_markers").unwrap(),
            MessageTypeName::new("visualization_msgs", "MarkerArray"),
            &qos,
        )
        .unwrap();
    let js_sub = ros_node
        .create_subscription::<JointState>(&js_topic, None)
        .unwrap();
    let mk_sub = ros_node
        .create_subscription::<MarkerArray>(&mk_topic, None)
        .unwrap();

    let mut state = RobotState {
        joints_rad: JOINTS,
        link_ok: 1,
        ..Default::default()
    };
    let mut frame = DetectionFrame {
        sequence: 1,
        ..Default::default()
    };
    assert!(frame.push(DetectedObject::new(
        1,
        ObjectClass::Goal,
        0.9,
        [0.4, 0.2, 0.025],
        [0.05; 3]
    )));
    assert!(frame.push(DetectedObject::new(
        2,
        ObjectClass::Obstacle,
        0.8,
        [0.3, 0.0, 0.15],
        [0.06, 0.06, 0.3]
    )));
    frame.validate().unwrap();
    let mut verdict = TwinVerdict {
        verdict_id: 1,
        policy_id: 7,
        steps: 120,
        min_distance_m: 0.05,
        episode_end: EpisodeEnd::Success as u8,
        ..Default::default()
    };
    verdict.set_flags(true, true, true);
    verdict.validate().unwrap();

    let mut joint_states: Vec<(Instant, JointState)> = Vec::new();
    let mut markers: Option<MarkerArray> = None;
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut first_js: Option<Instant> = None;
    while Instant::now() < deadline {
        state.time_ns += 10_000_000;
        state.cycle_count += 1;
        state.validate().unwrap();
        state_pub.send_copy(state).unwrap();
        det_pub.send_copy(frame).unwrap();
        verdict_pub.send_copy(verdict).unwrap();
        while let Ok(Some((msg, _))) = js_sub.take() {
            first_js.get_or_insert_with(Instant::now);
            joint_states.push((Instant::now(), msg));
        }
        while let Ok(Some((msg, _))) = mk_sub.take() {
            if msg.markers.iter().any(|m| m.kind == Marker::CUBE) {
                markers = Some(msg);
            }
        }
        if let Some(t0) = first_js
            && t0.elapsed() > Duration::from_secs(2)
            && markers.is_some()
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }

    let t0 = first_js.expect("no /joint_states message arrived over DDS within 30 s");
    let last = joint_states.last().unwrap();
    assert_eq!(
        last.1.name,
        ["joint1", "joint2", "joint3", "joint4", "joint5"]
    );
    assert_eq!(last.1.position, JOINTS.to_vec());
    assert_eq!(last.1.header.frame_id, "link_base");
    // Rate over the 2 s window after the first message: the bridge runs at 100 Hz; the
    // issue asks for at least 50 Hz. Counted on arrival, so DDS delivery is included.
    let window = joint_states
        .iter()
        .filter(|(t, _)| t.duration_since(t0) <= Duration::from_secs(2))
        .count();
    assert!(
        window >= 100,
        "only {window} /joint_states in 2 s (< 50 Hz)"
    );

    let markers = markers.expect("no scene MarkerArray with boxes arrived");
    let cubes: Vec<&Marker> = markers
        .markers
        .iter()
        .filter(|m| m.kind == Marker::CUBE)
        .collect();
    let goal = cubes
        .iter()
        .find(|m| m.ns == "goal")
        .expect("goal cube marker");
    assert!((goal.pose.position.x - 0.4).abs() < 1e-6 && (goal.pose.position.y - 0.2).abs() < 1e-6);
    let obstacle = cubes
        .iter()
        .find(|m| m.ns == "obstacles")
        .expect("obstacle cube marker");
    assert!(
        (obstacle.scale.z - 0.3).abs() < 1e-6,
        "obstacle height carried into the marker"
    );
    assert!(
        markers
            .markers
            .iter()
            .any(|m| m.ns == "verdict" && m.text.contains("reaches goal")),
        "verdict text marker"
    );

    let status = bridge.interrupt_and_wait(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "bridge did not stop cleanly on SIGINT: {status:?}"
    );
}
