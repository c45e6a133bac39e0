//! Single-process round trip of the policy path over real iceoryx2 shared memory: a
//! learner-side publisher writes `PolicyBlob`s in place into loaned samples, an rt-core-side
//! subscriber accepts them through `PolicyLoader` into a pre-allocated spare policy and
//! evaluates it; a corrupted blob is rejected and counted while the running policy stays.
//! Detections travel the same way. (The two-process test is the runtime's.)

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use iceoryx2::prelude::*;
use policy::{MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
use shm_schemas::services::{self, create_node};
use shm_schemas::{
    DetectedObject, DetectionFrame, ObjectClass, PolicyBlob, PolicyBlobBuilder, loan_zeroed,
    open_publisher, open_subscriber,
};
use twin::{ACT_DIM, OBS_DIM};

fn prefix(test: &str) -> String {
    format!("foresight-tests/{test}/{}", std::process::id())
}

#[test]
fn policies_published_in_place_are_accepted_or_rejected_by_the_loader() {
    const TASK: u64 = 0x7a5c;
    let prefix = prefix("policy");
    let (learner, _) = create_node::<ipc::Service>("learner").unwrap();
    let (rt, _) = create_node::<ipc::Service>("rt_core").unwrap();
    let publisher = open_publisher::<PolicyBlob, _>(&learner, &prefix).unwrap();
    let subscriber = open_subscriber::<PolicyBlob, _>(&rt, &prefix).unwrap();

    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let mut running = MlpPolicy::with_capacity();
    let mut spare = MlpPolicy::with_capacity();
    let obs = [0.2f32; OBS_DIM];

    // 1: a good policy, written straight into shared memory.
    let builder = PolicyBlobBuilder::random(1, TASK, OBS_DIM, &[256, 256], ACT_DIM, 11);
    let mut sample = loan_zeroed(&publisher).unwrap();
    builder.write_into(sample.payload_mut()).unwrap();
    sample.send().unwrap();
    let received = subscriber.receive().unwrap().expect("policy 1");
    loader
        .prepare_into(&received.payload().to_boxed(), &mut spare)
        .unwrap();
    drop(received);
    std::mem::swap(&mut running, &mut spare);
    assert_eq!(running.policy_id(), 1);
    let reference = builder.build().unwrap();
    let local = PolicyLoader::new(PolicyExpectation::for_task(TASK))
        .prepare(&reference)
        .unwrap();
    let action = running.act(&obs);
    assert_eq!(action, local.act(&obs), "shared memory changed the network");

    // 2: a blob corrupted after sealing (a torn write) is rejected; policy 1 keeps running.
    let mut sample = loan_zeroed(&publisher).unwrap();
    PolicyBlobBuilder::random(2, TASK, OBS_DIM, &[64, 64], ACT_DIM, 12)
        .write_into(sample.payload_mut())
        .unwrap();
    sample.payload_mut().weights[5] += 0.25;
    sample.send().unwrap();
    let received = subscriber.receive().unwrap().expect("policy 2");
    assert_eq!(
        loader.prepare_into(&received.payload().to_boxed(), &mut spare),
        Err(PolicyRejectReason::BadChecksum)
    );
    assert_eq!(running.policy_id(), 1);
    assert_eq!(running.act(&obs), action);

    // 3: a policy for another task is rejected too.
    let mut sample = loan_zeroed(&publisher).unwrap();
    PolicyBlobBuilder::random(3, TASK + 1, OBS_DIM, &[64, 64], ACT_DIM, 13)
        .write_into(sample.payload_mut())
        .unwrap();
    sample.send().unwrap();
    let received = subscriber.receive().unwrap().expect("policy 3");
    assert_eq!(
        loader.prepare_into(&received.payload().to_boxed(), &mut spare),
        Err(PolicyRejectReason::TaskHashMismatch)
    );
    assert_eq!(loader.counters().total_rejected(), 2);
    assert_eq!(loader.counters().accepted(), 1);
}

#[test]
fn detections_round_trip_and_validate() {
    let prefix = prefix("detections");
    let (perception, _) = create_node::<ipc::Service>("perception").unwrap();
    let (rt, _) = create_node::<ipc::Service>("rt_core").unwrap();
    let publisher = open_publisher::<DetectionFrame, _>(&perception, &prefix).unwrap();
    let subscriber = open_subscriber::<DetectionFrame, _>(&rt, &prefix).unwrap();
    for sequence in 1..=5u64 {
        let mut frame = DetectionFrame {
            sequence,
            capture_time_ns: sequence * 33_000_000,
            camera_id: 1,
            flags: DetectionFrame::FRAME_SETTLED,
            ..Default::default()
        };
        frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.9,
            [0.4, 0.2, 0.025],
            [0.05; 3],
        ));
        frame.push(DetectedObject::new(
            2,
            ObjectClass::Obstacle,
            0.8,
            [0.35, 0.0, 0.05 * sequence as f32],
            [0.06, 0.06, 0.1 * sequence as f32],
        ));
        publisher.send_copy(frame).unwrap();
        let got = subscriber.receive().unwrap().expect("frame");
        got.payload().validate().unwrap();
        assert_eq!(*got.payload(), frame);
        assert_eq!(
            got.payload().objects()[1].class(),
            Ok(ObjectClass::Obstacle)
        );
    }
    assert_eq!(services::DETECTIONS, "foresight/detections");
}
