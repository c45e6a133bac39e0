//! Two real relay processes on loopback, iceoryx2 on both ends: what crosses, what is
//! re-sent after the other side restarts, and what is refused — a peer without the link
//! credential, one without the learner host's key, replayed and late messages, a flood.
//! Every loop is bounded by a deadline.
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
use zenoh_relay::keys::LinkKeys;
use zenoh_relay::status::RelayStatus;
use zenoh_relay::wire::{self, Channel, Header, RequestRef, Side, Signer};

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

fn relay(
    side: &str,
    prefix: &str,
    link: &[String],
    status: &Path,
    name: &str,
    keys: &Path,
) -> Proc {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_zenoh-relay"));
    cmd.args([side, "--prefix", prefix, "--link-name", name, "--status"])
        .arg(status)
        .arg("--link-keys")
        .arg(keys)
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

/// Who a third Zenoh peer is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Third {
    /// Neither the link credential nor a host key: Zenoh straight to the relay's address.
    Stranger,
    /// The link credential (Zenoh's `usrpwd`) but no host key: Zenoh straight to the address.
    CredentialOnly,
    /// Through the gate with the learner host's key, and the credential: what a process on
    /// the learner host (or a stream injected into the link) could send.
    LearnerHost,
}

/// One link under test: its name, port, both hosts' service prefixes, status files and
/// keys (made with `keygen`, as a user would).
struct Link {
    dir: PathBuf,
    port: u16,
    name: String,
    pc: String,
    pl: String,
    ctl_status: PathBuf,
    lrn_status: PathBuf,
    ctl_keys: PathBuf,
    lrn_keys: PathBuf,
}

impl Link {
    fn new(tag: &str) -> Self {
        let dir = tmp_dir(tag);
        let out = Command::new(env!("CARGO_BIN_EXE_zenoh-relay"))
            .arg("keygen")
            .arg("--out")
            .arg(dir.join("keys"))
            .output()
            .unwrap();
        assert!(out.status.success(), "keygen: {out:?}");
        Self {
            port: free_port(),
            name: unique(tag),
            pc: unique("c"),
            pl: unique("lh"),
            ctl_status: dir.join("controller.json"),
            lrn_status: dir.join("learner.json"),
            ctl_keys: dir.join("keys/robot-pc"),
            lrn_keys: dir.join("keys/learner-host"),
            dir,
        }
    }

    /// The learner host's keys (a test acting as the learner host signs with them).
    fn learner_keys(&self) -> LinkKeys {
        LinkKeys::load(Some(&self.lrn_keys), Side::Learner).unwrap()
    }

    /// Where a third peer that passes the gate as the learner host (with its key) reaches
    /// the controller relay: a gate dialer's loopback port (kept for the rest of the test
    /// process; tests are short).
    fn through_gate(&self) -> String {
        let dialer = zenoh_relay::gate::Dialer::open(
            format!("127.0.0.1:{}", self.port),
            zenoh_relay::gate::GateKey::of(&self.learner_keys(), &self.name),
            std::sync::Arc::new(|_, _| {}),
        )
        .unwrap();
        let local = dialer.local_addr();
        std::mem::forget(dialer);
        format!("tcp/{local}")
    }

    /// A Zenoh session of a third peer connecting to the controller relay.
    fn third_peer(&self, who: Third) -> zenoh::Session {
        let mut config = zenoh::Config::default();
        let endpoint = match who {
            Third::LearnerHost => self.through_gate(),
            Third::Stranger | Third::CredentialOnly => format!("tcp/127.0.0.1:{}", self.port),
        };
        config
            .insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
            .unwrap();
        config.insert_json5("listen/endpoints", "[]").unwrap();
        config
            .insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        if who != Third::Stranger {
            let k = self.learner_keys();
            zenoh_relay::link::set_usrpwd(&mut config, &k.user, &k.password, &k.credential_file)
                .unwrap();
        }
        zenoh::open(config).wait().unwrap()
    }

    fn key(&self, c: Channel) -> String {
        format!("foresight/{}/{}", self.name, c.key_suffix())
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
            &self.ctl_keys,
        )
    }

    /// The learner side's relay, connecting to the controller's, with `extra` flags.
    fn learner(&self, extra: &[String]) -> Proc {
        let mut link = vec!["--peer".into(), format!("tcp/127.0.0.1:{}", self.port)];
        link.extend_from_slice(extra);
        relay(
            "learner",
            &self.pl,
            &link,
            &self.lrn_status,
            &self.name,
            &self.lrn_keys,
        )
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

/// The status file's count of connections refused by the gate for `reason` (read from the
/// file's JSON, as the launcher reads it).
fn refused_connections(path: &Path, reason: &str) -> u64 {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v["refused_connections"][reason].as_u64())
        .unwrap_or(0)
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

/// A sequence above anything sent so far (the relays use the wall clock in ns too).
fn now_seq() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

/// Waits until the third peer's session sees the controller relay (or `timeout`).
fn peers_after(session: &zenoh::Session, timeout: Duration) -> usize {
    let deadline = Instant::now() + timeout;
    loop {
        let n = session.info().peers_zid().wait().count();
        if n > 0 || Instant::now() >= deadline {
            return n;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
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

    // A mismatched peer with the credential and the learner host's key (another build, a
    // bug there), straight on Zenoh.
    let session = link.third_peer(Third::LearnerHost);
    assert_eq!(peers_after(&session, Duration::from_secs(20)), 1);
    let signer = Signer::new(link.learner_keys().signing, name);
    let key = |c: Channel| link.key(c);
    let _ = port;
    let progress = RetrainProgress {
        request_id: 1,
        phase: RetrainPhase::Training as u8,
        ..RetrainProgress::default()
    };
    let mut other_schema_header = Header::new(Channel::RetrainProgress, 9, now_seq());
    other_schema_header.schema_version = RetrainProgress::SCHEMA_VERSION + 1;
    let other_schema = wire::encode_message(&other_schema_header, &progress, &signer);
    let mut raw = shm_schemas::services::message_bytes(&*blob(7)).to_vec();
    raw[360 + 8] ^= 1;
    let bad_policy = wire::encode(&Header::new(Channel::Policy, 9, now_seq()), &raw, &signer);
    let garbage = b"hello, this is not a relay message at all, not even signed: nothing".to_vec();
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
                last.contains("shorter than")
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

/// Controller relay alone, rt-core's side on iceoryx2, and a request in flight.
struct RobotSide {
    _node: Node<ipc::Service>,
    req_pub: iceoryx2::port::publisher::Publisher<ipc::Service, RetrainRequest, ()>,
    prog_sub: iceoryx2::port::subscriber::Subscriber<ipc::Service, RetrainProgress, ()>,
    pol_sub: iceoryx2::port::subscriber::Subscriber<ipc::Service, PolicyBlob, ()>,
}

impl RobotSide {
    fn open(link: &Link, tag: &str) -> Self {
        let (node, _) = services::create_node::<ipc::Service>(tag).unwrap();
        Self {
            req_pub: services::open_publisher::<RetrainRequest, _>(&node, &link.pc).unwrap(),
            prog_sub: services::open_subscriber::<RetrainProgress, _>(&node, &link.pc).unwrap(),
            pol_sub: services::open_subscriber::<PolicyBlob, _>(&node, &link.pc).unwrap(),
            _node: node,
        }
    }

    /// rt-core asks for `r` (again until the controller relay has it in flight: a relay that
    /// just started may not be connected yet; it drops the repeats).
    fn request(&self, link: &Link, r: RetrainRequest) {
        wait_for_every(
            "the request in the relay's status",
            Duration::from_millis(200),
            || {
                self.req_pub.send_copy(r).unwrap();
                status(&link.ctl_status)
                    .requests
                    .iter()
                    .any(|s| s.request_id == r.request_id)
                    .then_some(())
            },
        );
    }
}

fn signed_policy(signer: &Signer, id: u64, bound: RequestRef, seq: u64) -> Vec<u8> {
    wire::encode_message(
        &Header::new(Channel::Policy, 77, seq).bound_to(bound),
        &*blob(id),
        signer,
    )
}

fn infeasible(request_id: u64) -> RetrainProgress {
    RetrainProgress {
        request_id,
        phase: RetrainPhase::Infeasible as u8,
        infeasible_kind: shm_schemas::InfeasibleKind::OutOfReach as u8,
        infeasible_by_m: 0.2,
        ..RetrainProgress::default()
    }
}

/// Puts `messages` every 100 ms until `done` says so (or 20 s).
fn put_until<T>(
    session: &zenoh::Session,
    messages: &[(String, Vec<u8>)],
    what: &str,
    mut done: impl FnMut() -> Option<T>,
) -> T {
    wait_for_every(what, Duration::from_millis(100), || {
        for (k, m) in messages {
            session.put(k, m.clone()).wait().unwrap();
        }
        done()
    })
}

fn wait_for_every<T>(what: &str, every: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(every);
    }
}

#[test]
fn a_third_peer_without_the_credential_gets_no_session_and_one_without_the_key_is_refused() {
    let link = Link::new("stranger");
    let _ctl = link.controller();
    let rt = RobotSide::open(&link, "relay-test-stranger");
    let r = request(1);
    rt.request(&link, r);
    let bound = RequestRef::of(&r);
    // A stranger's key, signing a false "infeasible" for the request in flight and a policy
    // for it.
    let stranger = Signer::new(
        ed25519_dalek::SigningKey::from_bytes(&[0x5a; 32]),
        &link.name,
    );
    let forged = |seq: u64| {
        vec![
            (
                link.key(Channel::RetrainProgress),
                wire::encode_message(
                    &Header::new(Channel::RetrainProgress, 66, seq).bound_to(bound),
                    &infeasible(1),
                    &stranger,
                ),
            ),
            (
                link.key(Channel::Policy),
                signed_policy(&stranger, 5, bound, seq),
            ),
        ]
    };

    // 1. No credential, no key, and 1b. the link credential alone: the gate refuses the
    //    connection (no host key), so there is no session; nothing they put arrives.
    for who in [Third::Stranger, Third::CredentialOnly] {
        let outsider = link.third_peer(who);
        assert_eq!(
            peers_after(&outsider, Duration::from_secs(3)),
            0,
            "{who:?} got a session"
        );
        for _ in 0..10 {
            for (k, m) in forged(now_seq()) {
                outsider.put(k, m).wait().unwrap();
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let st = status(&link.ctl_status);
        assert!(st.rejected.is_empty(), "{st:?}");
        assert!(st.received.is_empty(), "{st:?}");
        let _ = outsider.close().wait();
    }
    wait_for("the gate's refusals", Duration::from_secs(10), || {
        (refused_connections(&link.ctl_status, "connector_unauthenticated")
            + refused_connections(&link.ctl_status, "handshake_timeout")
            >= 2)
            .then_some(())
    });

    // 2. Through the gate (the learner host's key) but the messages signed by another key (a
    //    stream injected into the link): every message refused and counted.
    let insider = link.third_peer(Third::LearnerHost);
    assert_eq!(peers_after(&insider, Duration::from_secs(20)), 1);
    let st = put_until(
        &insider,
        &forged(now_seq()),
        "the refusals of the forged messages",
        || {
            let st = status(&link.ctl_status);
            (st.rejected.get("bad_signature") >= Some(&2)).then_some(st)
        },
    );
    let last = st.last_rejection.clone().unwrap();
    assert!(
        last.contains("signature") && last.contains("other host's public key"),
        "{last}"
    );
    assert!(!st.received.contains_key("policy"), "{st:?}");
    assert!(!st.received.contains_key("retrain_progress"), "{st:?}");
    assert!(
        st.requests[0].answered_unix_s.is_none(),
        "a forged infeasible ended the request: {st:?}"
    );
    assert!(
        rt.prog_sub.receive().unwrap().is_none(),
        "forged progress forwarded"
    );
    assert!(
        rt.pol_sub.receive().unwrap().is_none(),
        "forged policy forwarded"
    );
    let _ = insider.close().wait();
}

#[test]
fn a_replayed_or_older_policy_is_refused_also_after_the_robot_side_restarts() {
    let link = Link::new("replay");
    let mut ctl = link.controller();
    let rt = RobotSide::open(&link, "relay-test-replay");
    let r = request(1);
    rt.request(&link, r);
    let bound = RequestRef::of(&r);
    // The test is the learner host here: its key, its credential.
    let signer = Signer::new(link.learner_keys().signing, &link.name);
    let peer = link.third_peer(Third::LearnerHost);
    assert_eq!(peers_after(&peer, Duration::from_secs(20)), 1);
    let seq = now_seq();
    let recorded = signed_policy(&signer, 42, bound, seq);
    let older = signed_policy(&signer, 43, bound, seq - 1);
    let pk = link.key(Channel::Policy);

    // The genuine policy reaches rt-core's side once.
    let got = put_until(
        &peer,
        &[(pk.clone(), recorded.clone())],
        "the genuine policy on rt-core's side",
        || rt.pol_sub.receive().unwrap().map(|s| s.payload().policy_id),
    );
    assert_eq!(got, 42);
    // Played back, and an older one (signed, never seen): refused as replays.
    let st = put_until(
        &peer,
        &[(pk.clone(), recorded.clone()), (pk.clone(), older.clone())],
        "the replays refused",
        || {
            let st = status(&link.ctl_status);
            (st.rejected.get("replay") >= Some(&2)).then_some(st)
        },
    );
    assert!(st.last_rejection.unwrap().contains("replayed or old"));
    assert!(
        rt.pol_sub.receive().unwrap().is_none(),
        "a replay reached rt-core"
    );
    let _ = peer.close().wait();

    // The robot side restarts (its policy inbox is empty again); the same request is in
    // flight again. The replay is still refused: the mark was saved.
    drop(ctl);
    std::fs::remove_file(&link.ctl_status).unwrap();
    ctl = link.controller();
    rt.request(&link, r);
    let peer = link.third_peer(Third::LearnerHost);
    assert_eq!(peers_after(&peer, Duration::from_secs(20)), 1);
    put_until(
        &peer,
        &[(pk.clone(), recorded.clone())],
        "the replay refused after the restart",
        || (status(&link.ctl_status).rejected.get("replay") >= Some(&1)).then_some(()),
    );
    assert!(
        rt.pol_sub.receive().unwrap().is_none(),
        "a replay reached rt-core after a restart"
    );
    // A new policy (a new sequence) still gets through.
    let fresh = signed_policy(&signer, 44, bound, now_seq());
    let got = put_until(
        &peer,
        &[(pk, fresh)],
        "a new policy after the restart",
        || rt.pol_sub.receive().unwrap().map(|s| s.payload().policy_id),
    );
    assert_eq!(got, 44);
    let _ = peer.close().wait();
    drop(ctl);
}

#[test]
fn a_late_infeasible_answer_to_an_earlier_request_cannot_end_the_request_in_flight() {
    let link = Link::new("late");
    let _ctl = link.controller();
    let rt = RobotSide::open(&link, "relay-test-late");
    // An earlier rt-core asked request 1 at time 1001; this one asks request 1 at 5000.
    let earlier = request(1);
    let mut r = request(1);
    r.request_time_ns = 5_000;
    rt.request(&link, r);
    let signer = Signer::new(link.learner_keys().signing, &link.name);
    let peer = link.third_peer(Third::LearnerHost);
    assert_eq!(peers_after(&peer, Duration::from_secs(20)), 1);
    let key = link.key(Channel::RetrainProgress);
    let late = wire::encode_message(
        &Header::new(Channel::RetrainProgress, 77, now_seq()).bound_to(RequestRef::of(&earlier)),
        &infeasible(1),
        &signer,
    );
    let st = put_until(
        &peer,
        &[(key.clone(), late)],
        "the late answer dropped",
        || {
            let st = status(&link.ctl_status);
            (st.stale_dropped >= 1).then_some(st)
        },
    );
    assert!(st.requests[0].answered_unix_s.is_none(), "{st:?}");
    assert!(
        rt.prog_sub.receive().unwrap().is_none(),
        "the late answer was forwarded"
    );
    // The request in flight is still re-sent (not lost), and its own answer ends it.
    wait_for("a re-send", Duration::from_secs(10), || {
        (status(&link.ctl_status).requests[0].sends >= 2).then_some(())
    });
    let own = wire::encode_message(
        &Header::new(Channel::RetrainProgress, 77, now_seq()).bound_to(RequestRef::of(&r)),
        &infeasible(1),
        &signer,
    );
    let got = put_until(&peer, &[(key, own)], "the answer forwarded", || {
        rt.prog_sub.receive().unwrap().map(|s| *s.payload())
    });
    assert_eq!(got, infeasible(1));
    wait_for("the request answered", Duration::from_secs(10), || {
        (status(&link.ctl_status).requests[0].phase.as_deref() == Some("infeasible")).then_some(())
    });
    let _ = peer.close().wait();
}

#[test]
fn a_flood_is_dropped_and_counted_and_a_real_policy_still_gets_through() {
    let link = Link::new("flood");
    let _ctl = link.controller();
    let _lrn = link.learner(&[]);
    let rt = RobotSide::open(&link, "relay-test-flood");
    let (node, _) = services::create_node::<ipc::Service>("relay-test-flood-l").unwrap();
    let req_sub = services::open_subscriber::<RetrainRequest, _>(&node, &link.pl).unwrap();
    let pol_pub = services::open_publisher::<PolicyBlob, _>(&node, &link.pl).unwrap();
    link.wait_connected();
    rt.request(&link, request(1));
    wait_for(
        "the request on the learner host",
        Duration::from_secs(20),
        || req_sub.receive().unwrap().map(|_| ()),
    );

    // A peer through the gate whose messages are not signed by the learner host's key floods:
    // small forged progress as fast as it can, oversize messages on the policy key, garbage
    // hellos.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flooder = {
        let stop = std::sync::Arc::clone(&stop);
        let session = link.third_peer(Third::LearnerHost);
        assert_eq!(peers_after(&session, Duration::from_secs(20)), 1);
        let (pk, polk, hk) = (
            link.key(Channel::RetrainProgress),
            link.key(Channel::Policy),
            link.key(Channel::Hello),
        );
        let stranger = Signer::new(
            ed25519_dalek::SigningKey::from_bytes(&[0x33; 32]),
            &link.name,
        );
        std::thread::spawn(move || {
            let oversize = vec![0u8; wire::MAX_MESSAGE_LEN + 1];
            let deadline = Instant::now() + Duration::from_secs(30);
            let mut n = 0u64;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) && Instant::now() < deadline {
                let m = wire::encode_message(
                    &Header::new(Channel::RetrainProgress, 3, now_seq()),
                    &infeasible(1),
                    &stranger,
                );
                for _ in 0..200 {
                    session.put(&pk, m.clone()).wait().unwrap();
                }
                if n.is_multiple_of(20) {
                    session.put(&polk, oversize.clone()).wait().unwrap();
                    session.put(&hk, vec![1u8; 200]).wait().unwrap();
                }
                n += 1;
            }
            let _ = session.close().wait();
        })
    };
    // Forged messages are refused before they may wait in a queue (`bad_signature`, not
    // `flood`).
    wait_for("the flood to be counted", Duration::from_secs(20), || {
        let st = status(&link.ctl_status);
        (st.rejected.get("bad_signature") >= Some(&1) && st.rejected.get("oversize") >= Some(&1))
            .then_some(())
    });
    // During the flood, the learner host publishes a policy: it reaches rt-core.
    let b = blob(42);
    let mut s = loan_zeroed(&pol_pub).unwrap();
    s.payload_mut().copy_from(&b);
    s.send().unwrap();
    let got = wait_for(
        "the real policy during the flood",
        Duration::from_secs(20),
        || rt.pol_sub.receive().unwrap().map(|s| s.payload().policy_id),
    );
    assert_eq!(got, 42);
    // The relay kept up with its own work: the learner host is still connected.
    let st = status(&link.ctl_status);
    assert!(st.peer.as_ref().is_some_and(|p| p.connected), "{st:?}");
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    flooder.join().unwrap();
    let st = status(&link.ctl_status);
    println!(
        "flood: refused {:?}, received {:?}",
        st.rejected, st.received
    );
    assert!(!st.received.contains_key("retrain_progress"), "{st:?}");
    assert!(
        !st.rejected.contains_key("flood"),
        "a forged message took a queue place: {st:?}"
    );
    assert!(
        rt.prog_sub.receive().unwrap().is_none(),
        "forged progress forwarded"
    );
    assert!(st.requests[0].answered_unix_s.is_none(), "{st:?}");
}

// ---- Issue 30 item 6: link availability. ----

/// A Zenoh session listening on the address the learner relay dials, holding the link
/// credential (`keys`' `usrpwd`) but not the robot PC's key: a holder of the credential
/// standing in for the robot PC.
fn rogue_listener(port: u16, keys: &LinkKeys) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    zenoh_relay::link::set_usrpwd(
        &mut config,
        &keys.user,
        &keys.password,
        &keys.credential_file,
    )
    .unwrap();
    config
        .insert_json5("listen/endpoints", &format!("[\"tcp/127.0.0.1:{port}\"]"))
        .unwrap();
    config.insert_json5("connect/endpoints", "[]").unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(config).wait().unwrap()
}

#[test]
fn a_flood_of_forged_policies_does_not_keep_the_real_policy_out() {
    let link = Link::new("polflood");
    let _ctl = link.controller();
    let _lrn = link.learner(&[]);
    let rt = RobotSide::open(&link, "relay-test-polflood");
    let (node, _) = services::create_node::<ipc::Service>("relay-test-polflood-l").unwrap();
    let req_sub = services::open_subscriber::<RetrainRequest, _>(&node, &link.pl).unwrap();
    let pol_pub = services::open_publisher::<PolicyBlob, _>(&node, &link.pl).unwrap();
    link.wait_connected();
    let r = request(1);
    rt.request(&link, r);
    wait_for(
        "the request on the learner host",
        Duration::from_secs(20),
        || req_sub.receive().unwrap().map(|_| ()),
    );

    // A peer that got through the gate (as the learner host; a stream injected into the link
    // could do the same) floods the policy key: full-size policies for the request in flight
    // signed by a stranger, and short garbage, from three threads, as fast as Zenoh takes
    // them. Before the fix each took one of the 4 policy places before its signature was
    // looked at.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sent = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let session = std::sync::Arc::new(link.third_peer(Third::LearnerHost));
    assert_eq!(peers_after(&session, Duration::from_secs(20)), 1);
    let stranger = Signer::new(
        ed25519_dalek::SigningKey::from_bytes(&[0x44; 32]),
        &link.name,
    );
    let forged = signed_policy(&stranger, 666, RequestRef::of(&r), now_seq());
    let garbage = vec![0x5au8; 200];
    let flooders: Vec<_> = [forged, garbage.clone(), garbage]
        .into_iter()
        .map(|m| {
            let (stop, sent, session) = (
                std::sync::Arc::clone(&stop),
                std::sync::Arc::clone(&sent),
                std::sync::Arc::clone(&session),
            );
            let key = link.key(Channel::Policy);
            std::thread::spawn(move || {
                let deadline = Instant::now() + Duration::from_secs(60);
                while !stop.load(std::sync::atomic::Ordering::Relaxed) && Instant::now() < deadline
                {
                    session
                        .put(&key, m.clone())
                        .congestion_control(zenoh::qos::CongestionControl::Block)
                        .wait()
                        .unwrap();
                    sent.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            })
        })
        .collect();
    wait_for(
        "the forged policies refused",
        Duration::from_secs(20),
        || {
            let st = status(&link.ctl_status);
            (st.rejected.get("bad_signature") >= Some(&1)
                && st.rejected.get("malformed") >= Some(&1))
            .then_some(())
        },
    );
    let flood_start = Instant::now();
    // During the flood the learner host publishes its policy: it reaches rt-core.
    let b = blob(42);
    let mut s = loan_zeroed(&pol_pub).unwrap();
    s.payload_mut().copy_from(&b);
    s.send().unwrap();
    let got = wait_for(
        "the real policy during a flood of forged ones",
        Duration::from_secs(20),
        || rt.pol_sub.receive().unwrap().map(|s| s.payload().policy_id),
    );
    let flood_s = flood_start.elapsed().as_secs_f64();
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for f in flooders {
        f.join().unwrap();
    }
    let st = status(&link.ctl_status);
    println!(
        "policy flood: {} forged or garbage policies put; the real one arrived {flood_s:.1} s after it was published; refused {:?}, received {:?}",
        sent.load(std::sync::atomic::Ordering::Relaxed),
        st.rejected,
        st.received
    );
    assert_eq!(got, 42, "a forged policy reached rt-core");
    if let Some(s) = rt.pol_sub.receive().unwrap() {
        panic!("another policy reached rt-core: {}", s.payload().policy_id);
    }
    // Nothing forged took one of the policy queue's places: no message (the real policy's
    // sends included) was turned away for a full queue.
    assert!(
        !st.rejected.contains_key("flood"),
        "forged or garbage policies took the policy queue's places and turned real messages away: {:?}",
        st.rejected
    );
}

#[test]
fn idle_plain_tcp_connections_to_the_listener_do_not_keep_the_real_peer_out() {
    const IDLE: usize = 40;
    let link = Link::new("idle");
    let _ctl = link.controller();
    wait_for("the relay's status file", Duration::from_secs(20), || {
        link.ctl_status.exists().then_some(())
    });
    // Plain TCP sockets that never speak, each opened again as soon as the listener closes it.
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], link.port));
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (opened_tx, opened_rx) = std::sync::mpsc::channel::<()>();
    let holder = {
        let stop = std::sync::Arc::clone(&stop);
        std::thread::spawn(move || {
            let open = || {
                let s = std::net::TcpStream::connect(addr).unwrap();
                s.set_nonblocking(true).unwrap();
                s
            };
            let mut sockets: Vec<_> = (0..IDLE).map(|_| open()).collect();
            opened_tx.send(()).unwrap();
            let mut closed_by_listener = 0u64;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                for s in &mut sockets {
                    let mut b = [0u8; 64];
                    match std::io::Read::read(s, &mut b) {
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                        _ => {
                            closed_by_listener += 1;
                            *s = open();
                        }
                    }
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            closed_by_listener
        })
    };
    opened_rx.recv_timeout(Duration::from_secs(20)).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let started = Instant::now();
    let _lrn = link.learner(&[]);
    let connected = Instant::now() + Duration::from_secs(20);
    let mut seen = false;
    while !seen && Instant::now() < connected {
        seen = status(&link.ctl_status).peer.is_some_and(|p| p.connected);
        std::thread::sleep(Duration::from_millis(10));
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let closed = holder.join().unwrap();
    println!(
        "{IDLE} idle TCP connections held open: the real peer {} after {:.1} s; the listener closed {closed} idle connections",
        if seen {
            "connected"
        } else {
            "had not connected"
        },
        started.elapsed().as_secs_f64()
    );
    assert!(
        seen,
        "{IDLE} idle plain TCP connections kept the real peer out for 20 s"
    );
}

#[test]
fn a_peer_with_the_wrong_key_is_refused_on_both_sides() {
    // 1. The connecting side: a holder of the link credential, without the robot PC's key,
    //    listens where the learner relay dials. The learner relay must not open a session
    //    with it (it would hand it the retrain requests' answers and take its traffic).
    let link = Link::new("wrongkey");
    let rogue = rogue_listener(link.port, &link.learner_keys());
    let lrn = link.learner(&[]);
    let n = peers_after(&rogue, Duration::from_secs(10));
    assert_eq!(
        n, 0,
        "the learner relay opened a session with a listener that does not hold the robot PC's key"
    );
    wait_for(
        "the learner relay's refusal of the listener",
        Duration::from_secs(20),
        || {
            (refused_connections(&link.lrn_status, "listener_unauthenticated")
                + refused_connections(&link.lrn_status, "listener_no_handshake")
                >= 1)
                .then_some(())
        },
    );
    drop(lrn);
    let _ = rogue.close().wait();

    // 2. Both real relays, but the learner host's folder is of another `keygen`: each side
    //    refuses the other, and neither sees a peer.
    let other = link.dir.join("other-keys");
    let out = Command::new(env!("CARGO_BIN_EXE_zenoh-relay"))
        .arg("keygen")
        .arg("--out")
        .arg(&other)
        .output()
        .unwrap();
    assert!(out.status.success(), "keygen: {out:?}");
    std::fs::remove_file(&link.lrn_status).ok();
    let _ctl = link.controller();
    let wrong_status = link.dir.join("wrong-learner.json");
    let _wrong = relay(
        "learner",
        &link.pl,
        &["--peer".into(), format!("tcp/127.0.0.1:{}", link.port)],
        &wrong_status,
        &link.name,
        &other.join("learner-host"),
    );
    let (ctl, lrn) = wait_for("both sides' refusals", Duration::from_secs(20), || {
        let (c, l) = (status(&link.ctl_status), status(&wrong_status));
        (refused_connections(&link.ctl_status, "connector_unauthenticated") >= 1
            && refused_connections(&wrong_status, "listener_unauthenticated") >= 1)
            .then_some((c, l))
    });
    println!(
        "wrong keys: the controller refused {:?}; the learner refused {:?}",
        ctl.last_connection_refusal, lrn.last_connection_refusal
    );
    assert!(ctl.peer.is_none(), "{ctl:?}");
    assert!(lrn.peer.is_none(), "{lrn:?}");
}
