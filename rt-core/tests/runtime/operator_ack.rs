//! The operator's acknowledgement channel on the toy rig: it tells which stop is latched,
//! clears that stop and no other, and refuses a user that is not an operator.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Duration;

use crate::common::Rig;
use rt_core::cycle::StopReason;
use rt_core::operator_ack::{self, AckChannelError, AckOutcome, AckServer, LatchedStop};

fn socket(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!(
        "foresight-ack-test-{}-{name}.ack",
        std::process::id()
    ))
}

/// A rig whose lost link latched a protective stop, with the link back.
fn latched_rig() -> Rig {
    let (mut rig, conn) = crate::cycle::link_lost_while_following();
    conn.store(true, Ordering::Release);
    rig.run(1);
    assert!(rig.cycle.report().awaiting_ack);
    rig
}

/// Runs `request` on a thread of its own while the rig's cycle runs (the channel waits
/// for the cycle to take an acknowledgement).
fn while_cycling<T: Send + 'static>(
    rig: &mut Rig,
    request: impl FnOnce() -> T + Send + 'static,
) -> T {
    let h = std::thread::spawn(request);
    while !h.is_finished() {
        rig.run(1);
        std::thread::sleep(Duration::from_millis(1));
    }
    h.join().unwrap()
}

#[test]
fn the_channel_names_the_latched_stop_and_clears_only_that_one() {
    let mut rig = latched_rig();
    let path = socket("names");
    let server = AckServer::start(path.clone(), rig.cycle.control().clone(), vec![]).unwrap();
    let stop = operator_ack::query(&path).unwrap().expect("latched");
    assert_eq!(
        stop,
        LatchedStop {
            seq: 1,
            code: StopReason::LinkLost.code()
        }
    );
    assert!(stop.to_string().contains("lost link"), "{stop}");
    // Another stop's number, or the right number with another reason: refused.
    for wrong in [
        LatchedStop { seq: 2, ..stop },
        LatchedStop {
            code: StopReason::ArmError(0).code(),
            ..stop
        },
    ] {
        let p = path.clone();
        let out = while_cycling(&mut rig, move || operator_ack::acknowledge(&p, wrong)).unwrap();
        assert!(
            matches!(&out, AckOutcome::NotCleared(why) if why.contains("is latched")),
            "{out:?}"
        );
        assert!(rig.cycle.report().awaiting_ack);
    }
    let p = path.clone();
    let out = while_cycling(&mut rig, move || operator_ack::acknowledge(&p, stop)).unwrap();
    assert_eq!(out, AckOutcome::Cleared);
    assert!(!rig.cycle.report().awaiting_ack);
    assert_eq!(operator_ack::query(&path).unwrap(), None);
    drop(server);
    assert!(!path.exists(), "the socket outlived its server");
}

#[test]
fn a_user_that_is_not_an_operator_is_refused() {
    let mut rig = latched_rig();
    let path = socket("uid");
    // A server that accepts one user id that is not this process's.
    let me = xarm::owner::effective_uid();
    let _server =
        AckServer::start_allowing(path.clone(), rig.cycle.control().clone(), vec![me + 1]).unwrap();
    match operator_ack::query(&path) {
        Err(AckChannelError::Refused { why, .. }) => {
            assert!(why.contains(&format!("uid {me}")), "{why}");
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    let stop = LatchedStop {
        seq: 1,
        code: StopReason::LinkLost.code(),
    };
    let p = path.clone();
    let out = while_cycling(&mut rig, move || operator_ack::acknowledge(&p, stop)).unwrap();
    assert!(matches!(out, AckOutcome::NotCleared(_)), "{out:?}");
    assert!(
        rig.cycle.report().awaiting_ack,
        "a non-operator cleared the stop"
    );
}

#[test]
fn another_users_file_in_the_channels_place_is_refused_not_removed() {
    let rig = Rig::new();
    let path = socket("taken");
    std::fs::write(&path, "not a socket").unwrap();
    match AckServer::start(path.clone(), rig.cycle.control().clone(), vec![]) {
        Err(AckChannelError::PathTaken { why, .. }) => {
            assert!(why.contains("not a socket"), "{why}")
        }
        other => panic!("expected PathTaken, got {other:?}"),
    }
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "not a socket");
    let _ = std::fs::remove_file(&path);
}
