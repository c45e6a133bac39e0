//! Scene intake over real iceoryx2 (issue 14, item 7): a second publisher on the detection
//! service — another process writing the scene rt-core acts on — is noticed by the real
//! `rt-core run`: every frame is refused while it is connected (nothing is planned, the
//! arm would stop), and planning resumes once it is gone.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::Duration;

use foresight_tests::rt_rig::{Rig, Seen, first_state_with_policy, straight_line_blob, task};
use foresight_tests::wait_for;
use iceoryx2::prelude::*;
use shm_schemas::services::{create_node, loan_zeroed, open_publisher};
use shm_schemas::{DetectedObject, DetectionFrame, ObjectClass};

#[test]
fn a_second_detection_publisher_is_refused_until_it_is_gone() {
    let task = task();
    let mut rig = Rig::start("rt_second_pub");
    rig.wait("the first robot state", Duration::from_secs(60), |s| {
        s.iter()
            .any(|(_, x)| matches!(x, Seen::State(_)))
            .then_some(())
    });

    // A second publisher joins (same user, same service) and writes its own scene: a goal
    // elsewhere, stamped now, with a sequence of its own.
    let (intruder_node, _) = create_node::<ipc::Service>("intruder").expect("node");
    let intruder =
        open_publisher::<DetectionFrame, _>(&intruder_node, &rig.prefix).expect("publisher");
    let mut frame = DetectionFrame {
        sequence: 1_000_000,
        capture_time_ns: shm_schemas::clock::monotonic_now_ns(),
        camera_id: 1,
        ..DetectionFrame::default()
    };
    assert!(frame.push(DetectedObject::new(
        1,
        ObjectClass::Goal,
        0.99,
        [0.30, -0.30, 0.025],
        [0.05; 3],
    )));
    let mut sample = loan_zeroed(&intruder).expect("loan");
    *sample.payload_mut() = frame;
    sample.send().expect("send");
    // rt-core has seen the second publisher: it refused a frame for it (waited for, not
    // slept on: a loaded machine may take seconds to get there).
    wait_for_log(
        &mut rig,
        "rt-core refusing frames for the second publisher",
        |log| log.contains("publishers on the detection service"),
    );

    // With two publishers connected, a policy that passes in a free scene gets no plan.
    rig.publish_policy(&straight_line_blob(1, &task, 0.0), false);
    wait_for_log(&mut rig, "rt-core taking policy 1", |log| {
        log.lines()
            .any(|l| l.contains("policy accepted") && l.contains("policy_id=1"))
    });
    // The policy is in: a lookahead on it would come now. A short window to see none come
    // (an absence cannot be waited for).
    std::thread::sleep(Duration::from_secs(1));
    rig.pump();
    assert!(
        first_state_with_policy(&rig.seen, 1).is_none(),
        "a plan ran while a second publisher wrote the scene"
    );
    assert!(
        !rig.seen
            .iter()
            .any(|(_, x)| matches!(x, Seen::Verdict(v) if v.policy_id == 1)),
        "the lookahead ran on a scene that cannot be trusted"
    );

    // The intruder leaves: the next frames are accepted and the policy drives the arm.
    drop(intruder);
    drop(intruder_node);
    rig.wait("policy 1 driving the arm", Duration::from_secs(60), |s| {
        first_state_with_policy(s, 1)
    });
    let log = rig.finish();
    assert!(
        log.contains("publishers on the detection service"),
        "the refusal names its reason:\n{log}"
    );
}

/// Waits (generously: a loaded machine is slow) until rt-core's log so far satisfies `done`,
/// keeping what rt-core publishes meanwhile (`Rig::pump`); panics naming `what`, with the
/// log, when it never does.
fn wait_for_log(rig: &mut Rig, what: &str, done: impl Fn(&str) -> bool) {
    let mut log = String::new();
    let seen = wait_for(Duration::from_secs(60), || {
        rig.pump();
        log = std::fs::read_to_string(&rig.log).unwrap_or_default();
        done(&log).then_some(())
    });
    assert!(seen.is_some(), "timed out waiting for {what}:\n{log}");
}
