//! The operator's acknowledgement channel on the toy rig: it tells which stop is latched,
//! clears that stop and no other, and refuses a user that is not an operator.

use std::io::Write;
use std::os::unix::fs::PermissionsExt;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Duration;

use crate::common::Rig;
use rt_core::cycle::StopReason;
use rt_core::operator_ack::{self, AckChannelError, AckOutcome, AckServer, LatchedStop};

/// A test's private folder, removed with everything in it when the test ends (pass or fail):
/// `make test` left one folder per test and run in the temp folder before.
struct ScratchFolder(PathBuf);

impl Drop for ScratchFolder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The channel's socket for test `name`, in a private folder of this test's own (the
/// channel opens only in a folder writable by its user alone, issue 41 item 4). Keep the
/// folder guard alive for as long as the socket is used.
fn socket(name: &str) -> (ScratchFolder, PathBuf) {
    let folder =
        std::env::temp_dir().join(format!("foresight-ack-test-{}-{name}", std::process::id()));
    xarm::owner::prepare_lock_folder(&folder).unwrap();
    let path = folder.join(format!("{name}.ack"));
    (ScratchFolder(folder), path)
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
    let (_folder, path) = socket("names");
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
    let (_folder, path) = socket("uid");
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
    let (_folder, path) = socket("taken");
    xarm::owner::prepare_lock_folder(path.parent().unwrap()).unwrap();
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

/// Issue 41 item 4: a file in the channel's place is named with the way to remove it
/// (before, the error said "remove it" without saying how or as whom), and the channel
/// does not open in a folder others may write in, sticky or not (before, it opened in the
/// world-writable lock folder, where anyone could plant `<lock>.ack` first).
#[test]
fn a_planted_file_is_named_with_its_removal_and_a_shared_folder_is_refused() {
    let rig = Rig::new();
    let (_folder, path) = socket("planted");
    let folder = path.parent().unwrap().to_path_buf();
    xarm::owner::prepare_lock_folder(&folder).unwrap();
    std::fs::write(&path, "planted").unwrap();
    let e = AckServer::start(path.clone(), rig.cycle.control().clone(), vec![]).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("rm -f -- '{}'", path.display())),
        "the error does not say how to remove it: {msg}"
    );
    std::fs::remove_file(&path).unwrap();
    std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o1777)).unwrap();
    match AckServer::start(path.clone(), rig.cycle.control().clone(), vec![]) {
        Err(AckChannelError::Folder(e)) => assert!(e.to_string().contains("rm -r"), "{e}"),
        other => panic!("a channel opened in a folder others may write in: {other:?}"),
    }
    let _ = std::fs::remove_dir_all(&folder);
}

/// Issue 41 item 4: a client sending its request a byte at a time neither blocks an
/// operator's acknowledgement nor keeps its connection past one request deadline. Before,
/// the channel served one connection at a time with a timeout per read: the trickle held
/// it (for minutes), the acknowledgement got no answer and the stop stayed latched.
#[test]
fn a_trickling_client_does_not_block_an_acknowledgement() {
    let mut rig = latched_rig();
    let (_folder, path) = socket("trickle");
    let _server = AckServer::start(path.clone(), rig.cycle.control().clone(), vec![]).unwrap();
    // Far more bytes than fit in one request deadline at this pace.
    const TRICKLE_BYTES: usize = 200;
    let p = path.clone();
    let (started_tx, started_rx) = std::sync::mpsc::channel();
    let trickler = std::thread::spawn(move || {
        let mut s = std::os::unix::net::UnixStream::connect(&p).unwrap();
        let mut sent = 0;
        while sent < TRICKLE_BYTES {
            if s.write_all(b"s").is_err() {
                break;
            }
            sent += 1;
            if sent == 1 {
                let _ = started_tx.send(());
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        sent
    });
    started_rx.recv().unwrap();
    let p = path.clone();
    let stop = while_cycling(&mut rig, move || operator_ack::query(&p))
        .expect("the channel answered no query beside a trickling client")
        .expect("latched");
    let p = path.clone();
    let out = while_cycling(&mut rig, move || operator_ack::acknowledge(&p, stop)).unwrap();
    assert_eq!(out, AckOutcome::Cleared);
    assert!(!rig.cycle.report().awaiting_ack);
    let sent = trickler.join().unwrap();
    assert!(
        sent < TRICKLE_BYTES,
        "the trickling client kept its connection for all {sent} bytes: no deadline per request"
    );
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}
