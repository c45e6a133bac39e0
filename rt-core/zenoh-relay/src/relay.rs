//! The relay loop: iceoryx2 on this host, Zenoh to the other.
//!
//! - **Controller side** (robot PC, beside rt-core): rt-core's retrain requests go out;
//!   the learner's progress and policies come in and are published to rt-core's services.
//! - **Learner side** (learner host, beside `learner serve`): requests come in and are
//!   published to the learner; its progress and policies go out.
//!
//! Everything that arrives is decoded and validated again ([`crate::wire`]); what fails is
//! counted by reason and logged (at most once a second per reason), never forwarded. The
//! delivery rules (re-send until answered, drop repeats) are [`crate::reliable`]. Each side
//! says hello once a second; a peer silent for [`PEER_SILENCE`] counts as a link loss.
//!
//! Nothing of the real-time path crosses: no robot state, no detections, no verdicts.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::ipc;
use shm_schemas::services::{self, loan_zeroed};
use shm_schemas::{PolicyBlob, RetrainPhase, RetrainProgress, RetrainRequest, ShmMessage};
use zenoh::Wait;

use crate::link::{LinkArgs, LinkError};
use crate::reliable::{
    PolicyInbox, PolicyOutbox, ProgressAction, RequestAction, RequestInbox, RequestOutbox, is_final,
};
use crate::status::{PeerStatus, RelayStatus, RequestStatus, host_name, unix_s};
use crate::wire::{
    self, Channel, Hello, PolicyAck, Side, WireError, decode_control, decode_message,
    encode_control, encode_message,
};

/// A peer not heard from for this long is "lost" (hellos come once a second).
pub const PEER_SILENCE: Duration = Duration::from_secs(3);
const HELLO_EVERY: Duration = Duration::from_secs(1);
const STATUS_EVERY: Duration = Duration::from_millis(250);
/// How long the loop sleeps waiting for the network between polls of the local services.
const POLL: Duration = Duration::from_millis(1);

/// One relay's settings.
#[derive(Debug, Clone)]
pub struct RelayConfig {
    /// Which end this is.
    pub side: Side,
    /// The iceoryx2 service prefix on this host.
    pub prefix: String,
    /// Where to listen and connect.
    pub link: LinkArgs,
    /// Where to keep the status file, if anywhere.
    pub status_path: Option<PathBuf>,
    /// Learner side: the hash of the task the local learner trains for (`--task`). Requests
    /// for another task are refused (rt-core would refuse the policies that came back) and
    /// the hash is announced in the hellos, so the robot side can say what is wrong.
    pub task_hash: Option<u64>,
}

/// Whether a request for task `requested` (0: not stated) may be served by a learner of
/// task `served` (`None`: not known here).
pub fn task_matches(served: Option<u64>, requested: u64) -> bool {
    requested == 0 || served.is_none_or(|h| h == requested)
}

/// Why the relay could not run.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    /// The Zenoh side.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The iceoryx2 side.
    #[error("iceoryx2: {0}")]
    Shm(String),
}

fn shm(e: impl std::fmt::Display) -> RelayError {
    RelayError::Shm(e.to_string())
}

/// The local services of one side.
enum Ports {
    Controller {
        requests: Subscriber<ipc::Service, RetrainRequest, ()>,
        progress: Publisher<ipc::Service, RetrainProgress, ()>,
        policies: Publisher<ipc::Service, PolicyBlob, ()>,
    },
    Learner {
        requests: Publisher<ipc::Service, RetrainRequest, ()>,
        progress: Subscriber<ipc::Service, RetrainProgress, ()>,
        policies: Subscriber<ipc::Service, PolicyBlob, ()>,
    },
}

/// Publishes a copy of `message` on a local service, written in place in shared memory.
fn publish_local<T: ShmMessage>(
    publisher: &Publisher<ipc::Service, T, ()>,
    message: &T,
) -> Result<(), String> {
    let mut sample = loan_zeroed(publisher).map_err(|e| format!("loan: {e:?}"))?;
    // SAFETY: both pointers are valid, aligned `T`s (one on the heap or stack, the other in
    // the loaned shared-memory sample) that cannot overlap; `T: ShmMessage` is plain data
    // (integers and floats), so a bytewise copy is a valid `T`. Copying through the pointer
    // avoids a stack temporary of a ~320 KB policy blob.
    unsafe {
        core::ptr::copy_nonoverlapping(message as *const T, sample.payload_mut() as *mut T, 1);
    }
    sample
        .send()
        .map(|_| ())
        .map_err(|e| format!("send: {e:?}"))
}

/// Rate limit for repeated warnings: one line per reason per second.
#[derive(Default)]
struct WarnLimit(std::collections::HashMap<&'static str, Instant>);

impl WarnLimit {
    fn allow(&mut self, key: &'static str, now: Instant) -> bool {
        match self.0.get(key) {
            Some(t) if now.duration_since(*t) < Duration::from_secs(1) => false,
            _ => {
                self.0.insert(key, now);
                true
            }
        }
    }
}

/// The running relay.
struct Relay {
    cfg: RelayConfig,
    instance: u64,
    seq: u64,
    session: zenoh::Session,
    ports: Ports,
    status: RelayStatus,
    status_dirty: bool,
    peer_last_seen: Option<Instant>,
    peer_lost_at: Option<Instant>,
    down_before_s: f64,
    request_out: RequestOutbox,
    request_in: RequestInbox,
    policy_out: PolicyOutbox,
    policy_in: PolicyInbox,
    /// The learner side's latest policy (re-sent until acknowledged).
    latest_policy: Option<Box<PolicyBlob>>,
    /// The controller side's last forwarded progress (exact repeats are dropped).
    last_progress: Option<RetrainProgress>,
    /// Controller side: the task hash the learner host announced.
    peer_task_hash: Option<u64>,
    warn: WarnLimit,
}

/// A random-enough instance id: tells a restarted relay from a repeat of an old message.
fn new_instance_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.finish().max(1)
}

/// Runs a relay until `stop` is set.
///
/// # Errors
/// [`RelayError`] when the link or the local services cannot be opened; failures while
/// running are counted and logged.
pub fn run(cfg: RelayConfig, stop: &AtomicBool) -> Result<RelayStatus, RelayError> {
    cfg.link.validate()?;
    let node_name = match cfg.side {
        Side::Controller => "zenoh-relay-controller",
        Side::Learner => "zenoh-relay-learner",
    };
    let (node, _) = services::create_node::<ipc::Service>(node_name).map_err(shm)?;
    let p = cfg.prefix.as_str();
    let ports = match cfg.side {
        Side::Controller => Ports::Controller {
            requests: services::open_subscriber(&node, p).map_err(shm)?,
            progress: services::open_publisher(&node, p).map_err(shm)?,
            policies: services::open_publisher(&node, p).map_err(shm)?,
        },
        Side::Learner => Ports::Learner {
            requests: services::open_publisher(&node, p).map_err(shm)?,
            progress: services::open_subscriber(&node, p).map_err(shm)?,
            policies: services::open_subscriber(&node, p).map_err(shm)?,
        },
    };
    let session = cfg.link.open()?;
    let (tx, rx) = mpsc::channel::<(Channel, Vec<u8>)>();
    let incoming: &[Channel] = match cfg.side {
        Side::Controller => &[Channel::RetrainProgress, Channel::Policy, Channel::Hello],
        Side::Learner => &[Channel::RetrainRequest, Channel::PolicyAck, Channel::Hello],
    };
    let mut subscribers = Vec::new();
    for &channel in incoming {
        let tx = tx.clone();
        let sub = session
            .declare_subscriber(cfg.link.key(channel))
            .callback(move |sample| {
                let _ = tx.send((channel, sample.payload().to_bytes().into_owned()));
            })
            .wait()
            .map_err(|e| LinkError::Zenoh(format!("subscribing {channel:?}: {e}")))?;
        subscribers.push(sub);
    }
    let status = RelayStatus {
        side: Some(cfg.side),
        host: host_name(),
        link_name: cfg.link.link_name.clone(),
        prefix: cfg.prefix.clone(),
        peers: cfg.link.peers.clone(),
        listen: cfg.link.listen.clone(),
        started_unix_s: unix_s(),
        ..RelayStatus::default()
    };
    tracing::info!(
        side = ?cfg.side,
        prefix = %cfg.prefix,
        peers = ?cfg.link.peers,
        listen = ?cfg.link.listen,
        scout = cfg.link.scout,
        link = %cfg.link.link_name,
        "relay up"
    );
    let mut relay = Relay {
        cfg,
        instance: new_instance_id(),
        seq: 0,
        session,
        ports,
        status,
        status_dirty: true,
        peer_last_seen: None,
        peer_lost_at: None,
        down_before_s: 0.0,
        request_out: RequestOutbox::new(),
        request_in: RequestInbox::default(),
        policy_out: PolicyOutbox::default(),
        policy_in: PolicyInbox::default(),
        latest_policy: None,
        last_progress: None,
        peer_task_hash: None,
        warn: WarnLimit::default(),
    };
    let mut next_hello = Instant::now();
    let mut next_status = Instant::now();
    let mut next_connections = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        match rx.recv_timeout(POLL) {
            Ok((channel, bytes)) => relay.on_remote(channel, &bytes),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        while let Ok((channel, bytes)) = rx.try_recv() {
            relay.on_remote(channel, &bytes);
        }
        relay.poll_local();
        let now = Instant::now();
        relay.resend_due(now);
        relay.watch_peer(now);
        if now >= next_hello {
            relay.send_hello();
            next_hello = now + HELLO_EVERY;
        }
        if now >= next_connections {
            relay.update_connections();
            next_connections = now + Duration::from_secs(1);
        }
        if relay.status_dirty && now >= next_status {
            relay.write_status();
            next_status = now + STATUS_EVERY;
        }
    }
    relay.write_status();
    drop(subscribers);
    let status = relay.status.clone();
    let _ = relay.session.close().wait();
    tracing::info!("relay stopped");
    Ok(status)
}

impl Relay {
    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn put(&mut self, channel: Channel, bytes: Vec<u8>) {
        let key = self.cfg.link.key(channel);
        let res = self
            .session
            .put(key, bytes)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait();
        match res {
            Ok(()) => {
                RelayStatus::count(&mut self.status.sent, channel.key_suffix());
                self.status_dirty = true;
            }
            Err(e) => {
                if self.warn.allow("put", Instant::now()) {
                    tracing::warn!("sending {channel:?}: {e}");
                }
            }
        }
    }

    fn reject(&mut self, channel: Channel, e: &WireError) {
        RelayStatus::count(&mut self.status.rejected, e.kind());
        let text = format!("{channel:?} refused: {e}");
        if self.warn.allow(e.kind(), Instant::now()) {
            tracing::warn!("{text}");
        }
        self.status.last_rejection = Some(text);
        self.status_dirty = true;
    }

    fn accepted(&mut self, channel: Channel) {
        RelayStatus::count(&mut self.status.received, channel.key_suffix());
        self.status_dirty = true;
    }

    /// A message from the other host.
    fn on_remote(&mut self, channel: Channel, bytes: &[u8]) {
        let res = match channel {
            Channel::Hello => match decode_control::<Hello>(bytes, channel) {
                // Zenoh hands a session its own publications too.
                Ok((h, _)) if h.sender_instance == self.instance => return,
                Ok((h, m)) => {
                    self.on_hello(h.sender_instance, &m);
                    Ok(())
                }
                Err(e) => Err(e),
            },
            Channel::RetrainRequest => decode_message::<RetrainRequest>(bytes, channel)
                .map(|(h, r)| self.on_request(h.sender_instance, &r)),
            Channel::RetrainProgress => {
                decode_message::<RetrainProgress>(bytes, channel).map(|(_, p)| self.on_progress(&p))
            }
            Channel::Policy => {
                decode_message::<PolicyBlob>(bytes, channel).map(|(_, b)| self.on_policy(&b))
            }
            Channel::PolicyAck => decode_control::<PolicyAck>(bytes, channel).map(|(_, a)| {
                if self.policy_out.on_ack(a.policy_id, a.checksum) {
                    tracing::info!(
                        policy_id = a.policy_id,
                        "policy acknowledged by the controller"
                    );
                }
            }),
        };
        match res {
            Ok(()) => self.accepted(channel),
            Err(e) => self.reject(channel, &e),
        }
    }

    fn on_hello(&mut self, _instance: u64, hello: &Hello) {
        let now = Instant::now();
        let expected_side = match self.cfg.side {
            Side::Controller => Side::Learner,
            Side::Learner => Side::Controller,
        };
        if hello.side != expected_side {
            if self.warn.allow("side", now) {
                tracing::warn!(
                    "a {:?} relay on {} uses link {:?} too: two relays of one side on one link",
                    hello.side,
                    hello.host,
                    self.cfg.link.link_name
                );
            }
            return;
        }
        if hello.schema_versions != wire::schema_versions() && self.warn.allow("schema", now) {
            tracing::error!(
                "the relay on {} speaks schema versions {:?} (request, progress, policy), this one {:?}: its messages will be refused; build both hosts from the same source",
                hello.host,
                hello.schema_versions,
                wire::schema_versions()
            );
        }
        if let Some(lost) = self.peer_lost_at.take() {
            let down = now.duration_since(lost).as_secs_f64();
            self.down_before_s += down;
            tracing::info!(host = %hello.host, down_s = down, "link to the other host back");
        } else if self.peer_last_seen.is_none() {
            tracing::info!(host = %hello.host, pid = hello.pid, version = %hello.relay_version, "other host connected");
        }
        self.peer_last_seen = Some(now);
        self.peer_task_hash = hello.task_hash;
        self.check_peer_task();
        self.status.peer = Some(PeerStatus {
            host: hello.host.clone(),
            pid: hello.pid,
            relay_version: hello.relay_version.clone(),
            connected: true,
            last_seen_unix_s: unix_s(),
        });
        self.status.link_down_s = self.down_before_s;
    }

    /// Learner side: a request from the controller.
    fn on_request(&mut self, instance: u64, r: &RetrainRequest) {
        if !task_matches(self.cfg.task_hash, r.task_config_hash) {
            let text = format!(
                "retrain request {} refused: it is for task hash {:#018x}, the learner here trains for {:#018x} (use the robot's assets/task.toml on both hosts)",
                r.request_id,
                r.task_config_hash,
                self.cfg.task_hash.unwrap_or_default()
            );
            RelayStatus::count(&mut self.status.rejected, "task_mismatch");
            if self.warn.allow("task_mismatch", Instant::now()) {
                tracing::error!("{text}");
            }
            self.status.last_rejection = Some(text);
            self.status_dirty = true;
            return;
        }
        match self.request_in.on_request(instance, r) {
            RequestAction::Forward => {
                tracing::info!(
                    request = r.request_id,
                    "retrain request from the controller"
                );
                if let Ports::Learner { requests, .. } = &self.ports
                    && let Err(e) = publish_local(requests, r)
                {
                    tracing::error!("publishing the retrain request locally: {e}");
                }
            }
            RequestAction::Reanswer(p) => {
                let seq = self.next_seq();
                let bytes = encode_message(Channel::RetrainProgress, self.instance, seq, &p);
                self.put(Channel::RetrainProgress, bytes);
                self.status.duplicates_dropped += 1;
            }
            RequestAction::Drop => self.status.duplicates_dropped += 1,
        }
    }

    /// Controller side: progress from the learner host.
    fn on_progress(&mut self, p: &RetrainProgress) {
        let now = Instant::now();
        match self.request_out.on_progress(p, now) {
            ProgressAction::Stale => {
                self.status.duplicates_dropped += 1;
                return;
            }
            ProgressAction::Forward { answered } => {
                let t = unix_s();
                if let Some(r) = self.status.requests.last_mut()
                    && r.request_id == p.request_id
                {
                    r.first_progress_unix_s.get_or_insert(t);
                    if answered && r.answered_unix_s.is_none() {
                        r.answered_unix_s = Some(t);
                        r.remote_wall_time_s = Some(p.wall_time_s);
                        r.phase = Some(
                            match p.phase() {
                                Ok(RetrainPhase::Published) => "published",
                                _ => "budget_exhausted",
                            }
                            .to_owned(),
                        );
                        r.policy_id = Some(p.published_policy_id);
                        tracing::info!(
                            request = p.request_id,
                            remote_wall_s = p.wall_time_s,
                            "retraining answered by the learner host"
                        );
                    }
                }
            }
        }
        if self.last_progress.as_ref() == Some(p) {
            self.status.duplicates_dropped += 1;
            return;
        }
        self.last_progress = Some(*p);
        if let Ports::Controller { progress, .. } = &self.ports
            && let Err(e) = publish_local(progress, p)
        {
            tracing::warn!("publishing retrain progress locally: {e}");
        }
    }

    /// Controller side: a policy from the learner host (already validated).
    fn on_policy(&mut self, blob: &PolicyBlob) {
        let (id, checksum) = (blob.policy_id, blob.checksum);
        if self.policy_in.is_new(id, checksum) {
            let Ports::Controller { policies, .. } = &self.ports else {
                return;
            };
            if let Err(e) = publish_local(policies, blob) {
                // Not acknowledged: the learner host sends it again.
                tracing::error!("publishing the policy locally: {e}");
                return;
            }
            self.policy_in.delivered(id, checksum);
            tracing::info!(
                policy_id = id,
                "policy from the learner host handed to rt-core"
            );
            let t = unix_s();
            if let Some(r) = self
                .status
                .requests
                .iter_mut()
                .rev()
                .find(|r| r.policy_id == Some(id) || r.policy_id.is_none())
            {
                r.policy_received_unix_s.get_or_insert(t);
            }
        } else {
            self.status.duplicates_dropped += 1;
        }
        let seq = self.next_seq();
        let ack = PolicyAck {
            policy_id: id,
            checksum,
        };
        let bytes = encode_control(Channel::PolicyAck, self.instance, seq, &ack);
        self.put(Channel::PolicyAck, bytes);
    }

    /// Takes what the local processes published and sends it over.
    fn poll_local(&mut self) {
        let now = Instant::now();
        match &self.ports {
            Ports::Controller { requests, .. } => {
                let mut latest: Option<RetrainRequest> = None;
                loop {
                    match requests.receive() {
                        Ok(Some(s)) => {
                            let r = *s.payload();
                            match r.validate() {
                                Ok(()) => latest = Some(r),
                                Err(e) => tracing::warn!("local retrain request refused: {e}"),
                            }
                        }
                        Ok(None) => break,
                        Err(e) => {
                            tracing::warn!("receiving retrain requests: {e:?}");
                            break;
                        }
                    }
                }
                if let Some(r) = latest {
                    let same = self.request_out.current().is_some_and(|c| {
                        (c.request_id, c.request_time_ns) == (r.request_id, r.request_time_ns)
                    });
                    if !same {
                        if let Some(prev) = self.status.requests.last_mut()
                            && prev.answered_unix_s.is_none()
                        {
                            prev.superseded = true;
                        }
                        self.request_out.submit(r, now);
                        self.status.requests.push(RequestStatus {
                            request_id: r.request_id,
                            submitted_unix_s: unix_s(),
                            ..RequestStatus::default()
                        });
                        tracing::info!(
                            request = r.request_id,
                            "retrain request sent to the learner host"
                        );
                        self.send_request(&r);
                        self.check_peer_task();
                    }
                }
            }
            Ports::Learner {
                progress, policies, ..
            } => {
                let mut out: Vec<RetrainProgress> = Vec::new();
                while let Ok(Some(s)) = progress.receive() {
                    out.push(*s.payload());
                }
                let mut newest: Option<Box<PolicyBlob>> = None;
                while let Ok(Some(s)) = policies.receive() {
                    let mut b = PolicyBlob::new_boxed();
                    b.copy_from(s.payload());
                    newest = Some(b);
                }
                self.send_learner_output(out, newest, now);
            }
        }
    }

    /// Learner side: the learner's progress and newest policy go to the controller.
    fn send_learner_output(
        &mut self,
        progress: Vec<RetrainProgress>,
        newest: Option<Box<PolicyBlob>>,
        now: Instant,
    ) {
        for p in progress {
            if let Err(e) = p.validate() {
                tracing::warn!("local retrain progress refused: {e}");
                continue;
            }
            self.request_in.on_local_progress(&p);
            let seq = self.next_seq();
            let bytes = encode_message(Channel::RetrainProgress, self.instance, seq, &p);
            self.put(Channel::RetrainProgress, bytes);
            if is_final(&p) {
                tracing::info!(
                    request = p.request_id,
                    wall_s = p.wall_time_s,
                    "retraining answered"
                );
            }
        }
        if let Some(b) = newest {
            match b.validate() {
                Ok(()) => {
                    self.policy_out.submit(b.policy_id, b.checksum, now);
                    tracing::info!(policy_id = b.policy_id, "policy sent to the controller");
                    self.latest_policy = Some(b);
                    self.send_policy();
                }
                Err(e) => tracing::warn!("local policy refused: {e}"),
            }
        }
    }

    /// Controller side: notes (once) a learner host that trains for another task than the
    /// requests'.
    fn check_peer_task(&mut self) {
        let Some(requested) = self.request_out.current().map(|r| r.task_config_hash) else {
            return;
        };
        if task_matches(self.peer_task_hash, requested) || self.status.task_mismatch.is_some() {
            return;
        }
        let text = format!(
            "the learner host trains for task hash {:#018x}, this robot's task is {:#018x}: it refuses the requests (start it with the robot's assets/task.toml)",
            self.peer_task_hash.unwrap_or_default(),
            requested
        );
        tracing::error!("{text}");
        self.status.task_mismatch = Some(text);
        self.status_dirty = true;
    }

    fn send_request(&mut self, r: &RetrainRequest) {
        let seq = self.next_seq();
        let bytes = encode_message(Channel::RetrainRequest, self.instance, seq, r);
        self.put(Channel::RetrainRequest, bytes);
        if let Some(s) = self.status.requests.last_mut()
            && s.request_id == r.request_id
        {
            s.sends += 1;
        }
    }

    fn send_policy(&mut self) {
        let seq = self.next_seq();
        let Some(b) = self.latest_policy.as_deref() else {
            return;
        };
        let bytes = encode_message(Channel::Policy, self.instance, seq, b);
        self.put(Channel::Policy, bytes);
    }

    fn resend_due(&mut self, now: Instant) {
        if let Some(r) = self.request_out.due(now) {
            tracing::info!(
                request = r.request_id,
                "no answer yet: retrain request sent again"
            );
            self.status.resends += 1;
            self.send_request(&r);
        }
        if self.policy_out.due(now) {
            self.status.resends += 1;
            self.send_policy();
        }
    }

    fn watch_peer(&mut self, now: Instant) {
        let Some(seen) = self.peer_last_seen else {
            return;
        };
        if self.peer_lost_at.is_none() && now.duration_since(seen) >= PEER_SILENCE {
            self.peer_lost_at = Some(seen);
            self.status.link_losses += 1;
            if let Some(p) = self.status.peer.as_mut() {
                p.connected = false;
            }
            tracing::warn!(
                "no hello from the other host for {} s: link lost (messages are re-sent when it is back)",
                PEER_SILENCE.as_secs()
            );
            self.status_dirty = true;
        }
        if let Some(lost) = self.peer_lost_at {
            self.status.link_down_s = self.down_before_s + now.duration_since(lost).as_secs_f64();
        }
    }

    fn send_hello(&mut self) {
        let hello = Hello {
            side: self.cfg.side,
            host: self.status.host.clone(),
            pid: std::process::id(),
            relay_version: env!("CARGO_PKG_VERSION").to_owned(),
            schema_versions: wire::schema_versions(),
            task_hash: self.cfg.task_hash,
        };
        let seq = self.next_seq();
        let bytes = encode_control(Channel::Hello, self.instance, seq, &hello);
        // Hellos are not counted as traffic.
        let _ = self
            .session
            .put(self.cfg.link.key(Channel::Hello), bytes)
            .wait();
    }

    fn update_connections(&self) {
        let res = match &self.ports {
            Ports::Controller {
                progress, policies, ..
            } => progress
                .update_connections()
                .and_then(|()| policies.update_connections()),
            Ports::Learner { requests, .. } => requests.update_connections(),
        };
        if let Err(e) = res {
            tracing::debug!("update connections: {e:?}");
        }
    }

    fn write_status(&mut self) {
        self.status_dirty = false;
        if let Some(path) = &self.cfg.status_path
            && let Err(e) = self.status.write(path)
            && self.warn.allow("status", Instant::now())
        {
            tracing::warn!("writing {}: {e}", path.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_is_served_only_for_the_task_the_learner_trains_for() {
        assert!(task_matches(Some(7), 7));
        assert!(!task_matches(Some(7), 8));
        assert!(
            task_matches(None, 8),
            "task unknown here: rt-core checks the policy"
        );
        assert!(task_matches(Some(7), 0), "a request that states no task");
    }
}
