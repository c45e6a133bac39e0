//! Every payload through a real iceoryx2 publisher → subscriber, in one process.

use core::fmt::Debug;

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use shm_schemas::services::{self, ShmMessage, ShmOpenError};
use shm_schemas::*;

use crate::unique_prefix;

fn node(name: &str) -> Node<ipc::Service> {
    let (node, _cleanup) = services::create_node::<ipc::Service>(name).unwrap();
    node
}

/// Publishes `value` by copy and checks the subscriber receives an equal, valid payload.
fn round_trip<T: ShmMessage + PartialEq + Copy + Debug>(value: T) {
    let prefix = unique_prefix(T::SERVICE);
    let node = node("roundtrip");
    let publisher = open_publisher::<T, _>(&node, &prefix).unwrap();
    let subscriber = open_subscriber::<T, _>(&node, &prefix).unwrap();
    value.validate_message().unwrap();
    publisher.send_copy(value).unwrap();
    let sample = subscriber.receive().unwrap().expect("a sample");
    assert_eq!(*sample.payload(), value);
    sample.payload().validate_message().unwrap();
    assert!(subscriber.receive().unwrap().is_none());
}

pub fn detection_frame() -> DetectionFrame {
    let mut f = DetectionFrame {
        sequence: 42,
        capture_time_ns: 123_456_789,
        camera_id: 3,
        flags: DetectionFrame::FRAME_SETTLED,
        ..Default::default()
    };
    assert!(f.push(DetectedObject::new(
        1,
        ObjectClass::Goal,
        0.9,
        [0.4, 0.2, 0.025],
        [0.05; 3]
    )));
    assert!(f.push(DetectedObject::new(
        2,
        ObjectClass::Obstacle,
        0.75,
        [0.35, 0.0, 0.05],
        [0.06, 0.06, 0.1]
    )));
    f
}

pub fn verdict() -> TwinVerdict {
    let mut v = TwinVerdict {
        verdict_id: 7,
        scene_sequence: 42,
        policy_id: 99,
        computed_time_ns: 1_000,
        min_distance_m: 0.031,
        episode_return: 12.5,
        steps: 143,
        lookahead_compute_us: 2_100,
        episode_end: EpisodeEnd::Collision as u8,
        ..Default::default()
    };
    v.set_flags(false, false, false);
    v
}

pub fn retrain_request() -> RetrainRequest {
    let scene = shm_schemas::scene_file::SceneFile::from_toml_str(
        "[goal]\ncenter_m = [0.4, 0.2, 0.025]\nsize_m = 0.05\n\
         [[obstacle]]\ncenter_m = [0.35, 0.0, 0.15]\nsize_m = [0.06, 0.06, 0.3]\n",
        std::path::Path::new("<inline>"),
    )
    .unwrap();
    let mut r = RetrainRequest {
        request_id: 5,
        request_time_ns: 2_000,
        task_config_hash: 0xabc,
        failed_policy_id: 99,
        scene_sequence: 42,
        verdict: verdict(),
        ..Default::default()
    };
    r.set_scene(&scene);
    assert_eq!(r.scene().obstacles, scene.obstacles);
    assert_eq!(r.scene().goal, scene.goal);
    r
}

pub fn robot_state() -> RobotState {
    RobotState {
        time_ns: 5,
        cycle_count: 1000,
        missed_deadlines: 1,
        active_policy_id: 99,
        joints_rad: [0.1, -0.2, 0.3, -0.4, 0.5],
        joint_velocities_rad_s: [0.0, 0.01, 0.0, 0.0, -0.01],
        command_joints_rad: [0.1, -0.2, 0.3, -0.4, 0.5],
        tcp_m: [0.3, 0.0, 0.2],
        last_compute_us: 12.5,
        p99_compute_us: 30.0,
        arm_mode: 1,
        arm_state: 1,
        controlled_stop: 1,
        stop_reason: StopReason::ShieldViolation as u8,
        link_ok: 1,
        ..Default::default()
    }
}

pub fn retrain_progress() -> RetrainProgress {
    RetrainProgress {
        request_id: 5,
        steps_done: 200_000,
        published_policy_id: 100,
        mean_return: 30.0,
        success_rate: 0.95,
        wall_time_s: 41.0,
        phase: RetrainPhase::Published as u8,
        ..Default::default()
    }
}

#[test]
fn detection_frame_round_trips() {
    round_trip(detection_frame());
}

#[test]
fn goal_refusal_round_trips() {
    round_trip(GoalRefusal::by_age(
        41,
        GoalCommand::Reach as u8,
        &GoalRequestAgeError::TooOld {
            age_ns: 2_500_000_000,
        },
        7,
    ));
}

#[test]
fn twin_verdict_round_trips() {
    round_trip(verdict());
}

/// Schema 5: a goal-taken verdict carries its blocker and link in the bytes that were
/// reserved, and its reason reads back from them.
#[test]
fn a_goal_taken_verdict_round_trips_its_reason() {
    let v = TwinVerdict {
        episode_end: EpisodeEnd::GoalTaken as u8,
        phase: PhaseCode::BackingOut as u8,
        taken_blocker: 2,
        taken_link: 6,
        min_distance_m: -0.045,
        ..verdict()
    };
    round_trip(v);
    assert_eq!(
        v.goal_taken_wire(),
        Some((InfeasibleKind::NoGoalPosture as u8, 2, 6, 0.045))
    );
    assert_eq!(verdict().goal_taken_wire(), None);
}

#[test]
fn retrain_request_round_trips() {
    round_trip(retrain_request());
}

#[test]
fn robot_state_round_trips() {
    round_trip(robot_state());
}

#[test]
fn retrain_progress_round_trips() {
    round_trip(retrain_progress());
}

#[test]
fn policy_blob_is_written_in_place_and_round_trips() {
    let prefix = unique_prefix("policy");
    let node = node("roundtrip_policy");
    let publisher = open_publisher::<PolicyBlob, _>(&node, &prefix).unwrap();
    let subscriber = open_subscriber::<PolicyBlob, _>(&node, &prefix).unwrap();
    let builder = PolicyBlobBuilder::random(77, 0xfeed, 17, &[256, 256], 3, 1);
    let expected = builder.build().unwrap();
    for _ in 0..3 {
        let mut sample = loan_zeroed(&publisher).unwrap();
        builder.write_into(sample.payload_mut()).unwrap();
        sample.send().unwrap();
        let received = subscriber.receive().unwrap().expect("a sample");
        received.payload().validate().unwrap();
        assert_eq!(received.payload(), &*expected);
        assert_eq!(received.payload().checksum, expected.checksum);
    }
}

#[test]
fn late_subscriber_gets_the_latest_policy_from_history() {
    let prefix = unique_prefix("policy_history");
    let node = node("history");
    let publisher = open_publisher::<PolicyBlob, _>(&node, &prefix).unwrap();
    for id in 1..=2 {
        let mut sample = loan_zeroed(&publisher).unwrap();
        PolicyBlobBuilder::random(id, 1, 17, &[64, 64], 3, id)
            .write_into(sample.payload_mut())
            .unwrap();
        sample.send().unwrap();
    }
    let subscriber = open_subscriber::<PolicyBlob, _>(&node, &prefix).unwrap();
    publisher.update_connections().unwrap();
    let sample = subscriber.receive().unwrap().expect("history sample");
    assert_eq!(sample.payload().policy_id, 2);
}

#[test]
fn a_different_schema_version_is_refused() {
    let prefix = unique_prefix("version");
    let node = node("version");
    // A "stale" process created the service with schema version 0.
    let _stale = services::open_service_with_version::<DetectionFrame, _>(&node, &prefix, 0)
        .expect("stale service created");
    assert_eq!(
        open_subscriber::<DetectionFrame, _>(&node, &prefix).err(),
        Some(ShmOpenError::SchemaMismatch(services::DETECTIONS))
    );
    assert_eq!(
        open_publisher::<DetectionFrame, _>(&node, &prefix).err(),
        Some(ShmOpenError::SchemaMismatch(services::DETECTIONS))
    );
}

#[test]
fn a_different_payload_type_on_the_same_name_is_refused() {
    #[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
    #[repr(C)]
    #[type_name("foresight::DetectionFrame.v0")]
    struct OldFrame {
        sequence: u64,
    }
    let prefix = unique_prefix("type");
    let node = node("type");
    let name = ServiceName::new(&services::service_name(&prefix, services::DETECTIONS)).unwrap();
    let verifier =
        services::schema_verifier(services::DETECTIONS, DetectionFrame::SCHEMA_VERSION).unwrap();
    let _old = node
        .service_builder(&name)
        .publish_subscribe::<OldFrame>()
        .open_or_create_with_attributes(&verifier)
        .unwrap();
    assert_eq!(
        open_subscriber::<DetectionFrame, _>(&node, &prefix).err(),
        Some(ShmOpenError::SchemaMismatch(services::DETECTIONS))
    );
}

#[test]
fn service_names_are_prefixed() {
    assert_eq!(
        services::service_name("run7", services::POLICIES),
        "run7/foresight/policies"
    );
    assert_eq!(
        services::service_name("run7/", services::POLICIES),
        "run7/foresight/policies"
    );
    assert_eq!(
        services::service_name("", services::ROBOT_STATE),
        "foresight/robot_state"
    );
}

/// A process that dies holding ports leaves its shared memory behind; the next
/// `create_node` must clean it so a restart is never blocked. The test re-runs itself as
/// the crashing child (it takes every publisher slot of a service, then aborts).
#[test]
fn ports_of_a_crashed_process_do_not_block_a_restart() {
    const CHILD_ENV: &str = "FORESIGHT_SHM_CRASH_PREFIX";
    if let Ok(prefix) = std::env::var(CHILD_ENV) {
        let node = node("crashing_child");
        let first = open_publisher::<RobotState, _>(&node, &prefix).unwrap();
        let second = open_publisher::<RobotState, _>(&node, &prefix).unwrap();
        // Every slot is taken: a third publisher is refused while this process lives.
        assert!(matches!(
            open_publisher::<RobotState, _>(&node, &prefix),
            Err(ShmOpenError::Publisher { .. })
        ));
        first.send_copy(robot_state()).unwrap();
        let _keep = (first, second);
        std::process::abort();
    }
    let prefix = unique_prefix("crash");
    let status = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "roundtrip::ports_of_a_crashed_process_do_not_block_a_restart",
            "--nocapture",
        ])
        .env(CHILD_ENV, &prefix)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(!status.success(), "the child must have crashed");
    // Turn iceoryx2's own automatic cleanup off, so the explicit pass of `create_node`
    // is what is tested.
    let mut config = Config::global_config().clone();
    config.global.node.cleanup_dead_nodes_on_creation = false;
    config.global.service.cleanup_dead_nodes_on_open = false;
    let (node, _cleanup) =
        services::create_node_with_config::<ipc::Service>("restarted", &config).unwrap();
    // No assertion on the cleanup counts: the other tests of this binary create nodes in
    // parallel with iceoryx2's own cleanup on, and may remove the dead child first (then
    // this pass counts a failed cleanup of a node that is already gone). What matters is
    // below: every publisher slot the dead child held is free again.
    let first = open_publisher::<RobotState, _>(&node, &prefix).unwrap();
    let second = open_publisher::<RobotState, _>(&node, &prefix).unwrap();
    let subscriber = open_subscriber::<RobotState, _>(&node, &prefix).unwrap();
    second.send_copy(robot_state()).unwrap();
    assert!(subscriber.receive().unwrap().is_some());
    drop(first);
}

/// Four processes' worth of nodes open the same services at the same instant (what the
/// launcher's start-up does). With iceoryx2's creation timeout cut to 1 ms, every opener that
/// finds a creation in progress gets `HangsInCreation` or a create/open ping-pong at once:
/// the helpers must ride those out and every port must open, round after round.
#[test]
fn concurrent_openers_of_the_same_services_all_succeed() {
    const OPENERS: usize = 4;
    const ROUNDS: usize = 15;
    let mut config = Config::global_config().clone();
    config.global.creation_timeout = core::time::Duration::from_millis(1);
    for round in 0..ROUNDS {
        let prefix = unique_prefix(&format!("concurrent{round}"));
        let barrier = std::sync::Barrier::new(OPENERS);
        let failures: Vec<String> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..OPENERS)
                .map(|i| {
                    let (prefix, barrier, config) = (&prefix, &barrier, &config);
                    scope.spawn(move || -> Result<(), ShmOpenError> {
                        let (node, _) = services::create_node_with_config::<ipc::Service>(
                            &format!("opener{i}"),
                            config,
                        )
                        .expect("node");
                        barrier.wait();
                        let _d = open_subscriber::<DetectionFrame, _>(&node, prefix)?;
                        let _p = open_subscriber::<PolicyBlob, _>(&node, prefix)?;
                        let _r = open_subscriber::<RetrainRequest, _>(&node, prefix)?;
                        let _g = open_subscriber::<RetrainProgress, _>(&node, prefix)?;
                        let _s = open_subscriber::<RobotState, _>(&node, prefix)?;
                        let _v = open_subscriber::<TwinVerdict, _>(&node, prefix)?;
                        Ok(())
                    })
                })
                .collect();
            workers
                .into_iter()
                .filter_map(|w| w.join().expect("opener thread").err())
                .map(|e| e.to_string())
                .collect()
        });
        assert!(failures.is_empty(), "round {round}: {failures:?}");
    }
}
