//! Two real relay processes on loopback, iceoryx2 on both ends: what crosses, what is
//! re-sent after the other side restarts, and what is refused.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use shm_schemas::services::{self, loan_zeroed};
use shm_schemas::{
    EpisodeEnd, PolicyBlob, PolicyBlobBuilder, RetrainPhase, RetrainProgress, RetrainRequest,
    TwinVerdict,
};
use zenoh::Wait;
use zenoh_relay::status::RelayStatus;
use zenoh_relay::wire::{self, Channel};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn relay(side: &str, prefix: &str, link: &[String], status: &Path, name: &str) -> Proc {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_zenoh-relay"));
    cmd.args([side, "--prefix", prefix, "--link-name", name, "--status"])
        .arg(status)
        .args(link)
        .stdout(Stdio::null())
        .stderr(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(status.with_extension("log"))
                .unwrap(),
        );
    Proc(cmd.spawn().unwrap())
}

/// A name no other test of this process (tests run in parallel) or other process uses.
fn unique(tag: &str) -> String {
    static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    format!("zrt-{tag}-{}-{n}", std::process::id())
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(unique(tag));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One link under test: its name, port, both hosts' service prefixes and status files.
struct Link {
    dir: PathBuf,
    port: u16,
    name: String,
    pc: String,
    pl: String,
    ctl_status: PathBuf,
    lrn_status: PathBuf,
}

impl Link {
    fn new(tag: &str) -> Self {
        let dir = tmp_dir(tag);
        Self {
            port: free_port(),
            name: unique(tag),
            pc: unique("c"),
            pl: unique("lh"),
            ctl_status: dir.join("controller.json"),
            lrn_status: dir.join("learner.json"),
            dir,
        }
    }

    /// The robot side's relay, listening on loopback.
    fn controller(&self) -> Proc {
        let listen = ["--listen".into(), format!("tcp/127.0.0.1:{}", self.port)];
        relay(
            "controller",
            &self.pc,
            &listen,
            &self.ctl_status,
            &self.name,
        )
    }

    /// The learner side's relay, connecting to the controller's, with `extra` flags.
    fn learner(&self, extra: &[String]) -> Proc {
        let mut link = vec!["--peer".into(), format!("tcp/127.0.0.1:{}", self.port)];
        link.extend_from_slice(extra);
        relay("learner", &self.pl, &link, &self.lrn_status, &self.name)
    }

    fn wait_connected(&self) {
        wait_for(
            "the two relays to see each other",
            Duration::from_secs(20),
            || {
                status(&self.ctl_status)
                    .peer
                    .filter(|p| p.connected)
                    .map(|_| ())
            },
        );
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            std::fs::remove_dir_all(&self.dir).ok();
        }
    }
}

fn wait_for<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn status(path: &Path) -> RelayStatus {
    RelayStatus::read(path).unwrap_or_default()
}

fn request(id: u64) -> RetrainRequest {
    let mut r = RetrainRequest {
        request_id: id,
        request_time_ns: 1_000 + id,
        table_height_m: 0.0,
        goal_center_m: [0.3, 0.1, 0.02],
        goal_size_m: 0.04,
        verdict: TwinVerdict {
            episode_end: EpisodeEnd::Collision as u8,
            ..TwinVerdict::default()
        },
        ..RetrainRequest::default()
    };
    r.obstacle_count = 0;
    r
}

fn blob(id: u64) -> Box<PolicyBlob> {
    let mut b = PolicyBlob::new_boxed();
    PolicyBlobBuilder::random(id, 0x55, 17, &[32, 32], 3, id)
        .write_into(&mut b)
        .unwrap();
    b
}

#[test]
fn requests_progress_and_policies_cross_and_a_restarted_learner_side_gets_the_request_again() {
    let link = Link::new("cross");
    let (pc, pl) = (&link.pc, &link.pl);
    let (ctl_status, lrn_status) = (&link.ctl_status, &link.lrn_status);
    let _ctl = link.controller();
    let mut lrn = link.learner(&[]);

    let (node, _) = services::create_node::<ipc::Service>("relay-test").unwrap();
    // Controller host: rt-core's side.
    let req_pub = services::open_publisher::<RetrainRequest, _>(&node, pc).unwrap();
    let prog_sub = services::open_subscriber::<RetrainProgress, _>(&node, pc).unwrap();
    let pol_sub = services::open_subscriber::<PolicyBlob, _>(&node, pc).unwrap();
    // Learner host: the learner's side.
    let req_sub = services::open_subscriber::<RetrainRequest, _>(&node, pl).unwrap();
    let prog_pub = services::open_publisher::<RetrainProgress, _>(&node, pl).unwrap();
    let pol_pub = services::open_publisher::<PolicyBlob, _>(&node, pl).unwrap();

    link.wait_connected();

    // A request crosses, once.
    req_pub.send_copy(request(1)).unwrap();
    let got = wait_for(
        "the request on the learner host",
        Duration::from_secs(10),
        || req_sub.receive().unwrap().map(|s| *s.payload()),
    );
    assert_eq!(got, request(1));

    // Progress comes back; a policy comes back and is acknowledged.
    let p = RetrainProgress {
        request_id: 1,
        steps_done: 10,
        phase: RetrainPhase::Training as u8,
        ..RetrainProgress::default()
    };
    prog_pub.send_copy(p).unwrap();
    let back = wait_for(
        "progress on the controller",
        Duration::from_secs(10),
        || prog_sub.receive().unwrap().map(|s| *s.payload()),
    );
    assert_eq!(back, p);
    let b = blob(42);
    let mut s = loan_zeroed(&pol_pub).unwrap();
    s.payload_mut().copy_from(&b);
    s.send().unwrap();
    let checksum = wait_for(
        "the policy on the controller",
        Duration::from_secs(10),
        || {
            pol_sub
                .receive()
                .unwrap()
                .map(|s| (s.payload().policy_id, s.payload().checksum))
        },
    );
    assert_eq!(checksum, (42, b.checksum));
    wait_for(
        "the policy's acknowledgement",
        Duration::from_secs(10),
        || (status(lrn_status).received.get("policy_ack").copied() >= Some(1)).then_some(()),
    );

    // The learner host dies before answering request 2, and comes back: the controller
    // side sends request 2 again and the new learner side hands it on.
    drop(lrn);
    req_pub.send_copy(request(2)).unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        req_sub.receive().unwrap().is_none(),
        "nobody to carry it yet"
    );
    lrn = link.learner(&[]);
    let got = wait_for(
        "request 2 after the restart",
        Duration::from_secs(20),
        || {
            req_sub
                .receive()
                .unwrap()
                .map(|s| *s.payload())
                .filter(|r| r.request_id == 2)
        },
    );
    assert_eq!(got, request(2));
    // The final answer stops the re-sending.
    let done = RetrainProgress {
        request_id: 2,
        phase: RetrainPhase::Published as u8,
        published_policy_id: 43,
        wall_time_s: 3.5,
        success_rate: 1.0,
        ..RetrainProgress::default()
    };
    prog_pub.send_copy(done).unwrap();
    let st = wait_for("request 2 answered", Duration::from_secs(10), || {
        let st = status(ctl_status);
        st.requests
            .iter()
            .any(|r| r.request_id == 2 && r.answered_unix_s.is_some())
            .then_some(st)
    });
    let r2 = st.requests.iter().find(|r| r.request_id == 2).unwrap();
    assert!(r2.sends >= 2, "request 2 was re-sent: {r2:?}");
    assert_eq!(r2.remote_wall_time_s, Some(3.5));
    assert_eq!(r2.phase.as_deref(), Some("published"));
    // No more re-sends after the answer.
    let sends = r2.sends;
    std::thread::sleep(Duration::from_millis(2500));
    let r2 = status(ctl_status)
        .requests
        .into_iter()
        .find(|r| r.request_id == 2)
        .unwrap();
    assert_eq!(r2.sends, sends);
    // Each request reached the learner once.
    if let Some(s) = req_sub.receive().unwrap() {
        panic!("a repeat reached the learner: {:?}", s.payload().request_id);
    }
    drop(lrn);
}

#[test]
fn messages_of_another_schema_or_malformed_ones_are_refused_counted_and_not_forwarded() {
    let link = Link::new("refuse");
    let (pc, ctl_status, port, name) = (&link.pc, &link.ctl_status, link.port, &link.name);
    let _ctl = link.controller();
    let (node, _) = services::create_node::<ipc::Service>("relay-test-refuse").unwrap();
    let prog_sub = services::open_subscriber::<RetrainProgress, _>(&node, pc).unwrap();
    let pol_sub = services::open_subscriber::<PolicyBlob, _>(&node, pc).unwrap();
    wait_for("the relay's status file", Duration::from_secs(20), || {
        ctl_status.exists().then_some(())
    });

    // A hostile or mismatched peer, straight on Zenoh.
    let mut config = zenoh::Config::default();
    config
        .insert_json5("connect/endpoints", &format!("[\"tcp/127.0.0.1:{port}\"]"))
        .unwrap();
    config.insert_json5("listen/endpoints", "[]").unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let session = zenoh::open(config).wait().unwrap();
    let key = |c: Channel| format!("foresight/{name}/{}", c.key_suffix());
    let progress = RetrainProgress {
        request_id: 1,
        phase: RetrainPhase::Training as u8,
        ..RetrainProgress::default()
    };
    let mut other_schema = wire::encode_message(Channel::RetrainProgress, 9, 1, &progress);
    other_schema[12..16].copy_from_slice(&(RetrainProgress::SCHEMA_VERSION + 1).to_le_bytes());
    let mut bad_policy = wire::encode_message(Channel::Policy, 9, 2, &*blob(7));
    let n = bad_policy.len();
    bad_policy[wire::HEADER_LEN + 360 + 8] ^= 1;
    let _ = n;
    let garbage = b"hello, this is not a relay message at all".to_vec();
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        session
            .put(key(Channel::RetrainProgress), other_schema.clone())
            .wait()
            .unwrap();
        session
            .put(key(Channel::Policy), bad_policy.clone())
            .wait()
            .unwrap();
        session
            .put(key(Channel::Hello), garbage.clone())
            .wait()
            .unwrap();
        std::thread::sleep(Duration::from_millis(200));
        let st = status(ctl_status);
        if st.rejected.get("schema_mismatch") >= Some(&1)
            && st.rejected.get("invalid_payload") >= Some(&1)
            && st.rejected.get("malformed") >= Some(&1)
        {
            assert!(!st.received.contains_key("retrain_progress"));
            assert!(!st.received.contains_key("policy"));
            let last = st.last_rejection.unwrap();
            assert!(
                last.contains("magic")
                    || last.contains("schema_version")
                    || last.contains("checksum"),
                "{last}"
            );
            break;
        }
        assert!(Instant::now() < deadline, "rejections not counted: {st:?}");
    }
    assert!(
        prog_sub.receive().unwrap().is_none(),
        "a refused progress was forwarded"
    );
    assert!(
        pol_sub.receive().unwrap().is_none(),
        "a refused policy was forwarded"
    );
    let _ = session.close().wait();
}

#[test]
fn a_learner_host_of_another_task_refuses_the_request_and_the_robot_side_says_why() {
    let link = Link::new("task");
    let (pc, pl) = (&link.pc, &link.pl);
    let (ctl_status, lrn_status) = (&link.ctl_status, &link.lrn_status);
    let task = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/task.toml");
    let served = twin::TaskConfig::load(&task).unwrap().hash();
    let _ctl = link.controller();
    let _lrn = link.learner(&["--task".into(), task.display().to_string()]);
    let (node, _) = services::create_node::<ipc::Service>("relay-test-task").unwrap();
    let req_pub = services::open_publisher::<RetrainRequest, _>(&node, pc).unwrap();
    let req_sub = services::open_subscriber::<RetrainRequest, _>(&node, pl).unwrap();
    link.wait_connected();
    let mut wrong = request(1);
    wrong.task_config_hash = served ^ 1;
    req_pub.send_copy(wrong).unwrap();
    let st = wait_for(
        "the refusal on the learner host",
        Duration::from_secs(10),
        || {
            let st = status(lrn_status);
            st.rejected.contains_key("task_mismatch").then_some(st)
        },
    );
    assert!(st.last_rejection.unwrap().contains("task hash"));
    let ctl = wait_for("the robot side's note", Duration::from_secs(10), || {
        status(ctl_status).task_mismatch
    });
    assert!(ctl.contains(&format!("{served:#018x}")), "{ctl}");
    assert!(
        req_sub.receive().unwrap().is_none(),
        "a request of another task was forwarded"
    );
    // The robot's own task is served.
    let mut right = request(2);
    right.task_config_hash = served;
    req_pub.send_copy(right).unwrap();
    let got = wait_for(
        "the request of the served task",
        Duration::from_secs(10),
        || req_sub.receive().unwrap().map(|s| *s.payload()),
    );
    assert_eq!(got.request_id, 2);
}
