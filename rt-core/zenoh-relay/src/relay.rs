//! The relay loop: iceoryx2 on this host, Zenoh to the other.
//!
//! - **Controller side** (robot PC, beside rt-core): rt-core's retrain requests go out;
//!   the learner's progress and policies come in and are published to rt-core's services.
//! - **Learner side** (learner host, beside `learner serve`): requests come in and are
//!   published to the learner; its progress and policies go out.
//!
//! Everything that arrives is size-checked, its signature verified with the other host's
//! public key, decoded and validated again ([`crate::wire`]), and its sequence checked
//! against the last accepted one ([`crate::reliable::SequenceGuard`], remembered across
//! restarts in [`crate::keys::LinkState`]); what fails is counted by reason and logged (at
//! most once a second per reason), never forwarded. The delivery rules (re-send until
//! answered, drop repeats, bind answers to their request) are [`crate::reliable`]. Each side
//! says hello once a second; a peer silent for [`PEER_SILENCE`] counts as a link loss.
//!
//! **Verified before queued.** Zenoh's callback checks the size (unread), the header and the
//! signature, and that the sequence is above the last one queued or accepted on its channel,
//! *before* a message may take a place in its channel's bounded queue ([`queue_len`]); only
//! then is it queued, without blocking. So the queue holds nothing but fresh messages of the
//! other host: a flood of forged, garbage or replayed messages is refused and counted in the
//! callback (`bad_signature`, `malformed`, `replay`, …) and can neither take the 4 policy
//! places nor push a real policy out. A full queue (only the other host itself could fill it)
//! drops the message and counts it (`flood`). The loop takes at most a queue's length from
//! each channel per turn, so no channel starves another or the loop's own work (local
//! services, re-sends, hellos, the status file). Sends never block: Zenoh drops what its
//! queue cannot take, and the re-send rules send it again.
//!
//! **Connections.** The link is opened behind the relay's gate ([`crate::gate`]): both ends
//! prove their host keys to each other before Zenoh sees a connection, and pending
//! connections are bounded and timed out. What the gate refuses is counted in the status file's
//! `refused_connections`.
//!
//! Nothing of the real-time path crosses: no robot state, no detections, no verdicts.

use shm_schemas::error_chain::error_chain;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::ipc;
use shm_schemas::services::{self, loan_zeroed};
use shm_schemas::{
    PolicyBlob, RetrainPhase, RetrainProgress, RetrainRequest, ShmMessage, ShmOpenError,
};
use zenoh::Wait;

use crate::keys::{KeyError, LinkState, fingerprint};
use crate::link::{LinkArgs, LinkError};
use crate::reliable::{
    PolicyInbox, PolicyOutbox, ProgressAction, RequestAction, RequestInbox, RequestOutbox,
    SequenceGuard, is_final,
};
use crate::status::{AuthStatus, PeerStatus, RelayStatus, RequestStatus, host_name, unix_s};
use crate::wire::{
    self, Channel, Header, Hello, PolicyAck, RequestRef, Side, Signer, Verifier, WireError,
    control_payload, encode_control, encode_message, message_payload,
};

/// A peer not heard from for this long is "lost" (hellos come once a second).
pub const PEER_SILENCE: Duration = Duration::from_secs(3);
const HELLO_EVERY: Duration = Duration::from_secs(1);
const STATUS_EVERY: Duration = Duration::from_millis(250);
/// How often the replay marks of hellos, progress and acks are saved (policies and requests
/// save theirs before they are handed on).
const STATE_EVERY: Duration = Duration::from_secs(5);
/// How far above its last sent number a relay reserves sequence numbers in its state file
/// (one write per 10 s of sending at most).
pub const SEQUENCE_RESERVE_NS: u64 = 10_000_000_000;
/// How long the loop sleeps waiting for the network between polls of the local services.
const POLL: Duration = Duration::from_millis(1);

/// How many received messages of `channel` may wait for the loop (each already verified:
/// signed by the other host, fresh); more are dropped and counted (`flood`). The loop takes at
/// most this many per channel per turn.
pub const fn queue_len(channel: Channel) -> usize {
    match channel {
        Channel::Policy => 4,
        Channel::RetrainRequest | Channel::PolicyAck | Channel::Hello => 16,
        Channel::RetrainProgress => 64,
    }
}

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
    /// The iceoryx2 node could not be created.
    #[error("iceoryx2")]
    ShmNode(#[source] services::NodeCreateError),
    /// An iceoryx2 port could not be opened.
    #[error("iceoryx2")]
    Shm(#[from] ShmOpenError),
    /// The replay state file cannot be read or written (the message names it).
    #[error("replay state")]
    State(#[source] KeyError),
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

/// Refusals noted by Zenoh's callbacks (size, full queue), collected by the loop.
#[derive(Default)]
struct CallbackRefusals {
    counts: BTreeMap<&'static str, u64>,
    last: Option<String>,
}

fn note(refusals: &Mutex<CallbackRefusals>, kind: &'static str, text: String) {
    let mut r = refusals.lock().unwrap_or_else(PoisonError::into_inner);
    *r.counts.entry(kind).or_default() += 1;
    r.last = Some(text);
}

impl CallbackRefusals {
    fn take(refusals: &Mutex<Self>) -> Self {
        std::mem::take(&mut *refusals.lock().unwrap_or_else(PoisonError::into_inner))
    }
}

/// A message the callback verified: the other host's signature over this header and
/// payload, a sequence above any queued or accepted before on its channel.
struct Verified {
    header: Header,
    payload: Vec<u8>,
}

fn replay_text(channel: Channel, sequence: u64, last: u64) -> String {
    format!(
        "{channel:?} refused: sequence {sequence} is not above the last accepted ({last}): a replayed or old message"
    )
}

/// Zenoh's callback for `channel`: size (unread), header, signature and sequence, then the
/// bounded queue; never blocks.
fn admit(
    bytes: &[u8],
    channel: Channel,
    verifier: &Verifier,
    admitted: &Mutex<u64>,
    queue: &mpsc::SyncSender<Verified>,
    refusals: &Mutex<CallbackRefusals>,
) -> bool {
    let (header, payload) = match wire::decode(bytes, channel, verifier) {
        Ok(v) => v,
        Err(e) => {
            note(
                refusals,
                e.kind(),
                format!("{channel:?} refused: {}", error_chain(&e)),
            );
            return false;
        }
    };
    let mut last = admitted.lock().unwrap_or_else(PoisonError::into_inner);
    if header.sequence <= *last {
        note(
            refusals,
            "replay",
            replay_text(channel, header.sequence, *last),
        );
        return false;
    }
    let m = Verified {
        header,
        payload: payload.to_vec(),
    };
    match queue.try_send(m) {
        Ok(()) => {
            *last = header.sequence;
            true
        }
        Err(mpsc::TrySendError::Full(_)) => {
            note(
                refusals,
                "flood",
                format!(
                    "{channel:?} dropped: {} verified messages already wait (a flood)",
                    queue_len(channel)
                ),
            );
            false
        }
        Err(mpsc::TrySendError::Disconnected(_)) => false,
    }
}

/// The incoming side of the link: a bounded queue of verified messages per channel, filled
/// by Zenoh's callbacks.
struct Inbox {
    queues: Vec<(Channel, mpsc::Receiver<Verified>)>,
    doorbell: mpsc::Receiver<()>,
    refusals: Arc<Mutex<CallbackRefusals>>,
    /// Connections the gate refused.
    gate: Arc<Mutex<CallbackRefusals>>,
}

/// The running relay.
struct Relay {
    cfg: RelayConfig,
    instance: u64,
    /// The last sequence sent (see [`crate::wire`]: never goes down).
    seq: u64,
    signer: Signer,
    guard: SequenceGuard,
    state: LinkState,
    state_path: PathBuf,
    state_dirty: bool,
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
    /// The learner side's latest policy and the request it answers (re-sent until
    /// acknowledged).
    latest_policy: Option<(Box<PolicyBlob>, RequestRef)>,
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
    let keys = cfg.link.load_keys(cfg.side)?;
    let peer_fp = fingerprint(&keys.peer);
    let state_path = keys.state_path();
    let state = LinkState::load(&state_path, &peer_fp).map_err(RelayError::State)?;
    // Written at once: a relay that could not remember what it accepted does not start.
    state.write(&state_path).map_err(RelayError::State)?;
    let node_name = match cfg.side {
        Side::Controller => "zenoh-relay-controller",
        Side::Learner => "zenoh-relay-learner",
    };
    let (node, _) =
        services::create_node::<ipc::Service>(node_name).map_err(RelayError::ShmNode)?;
    let p = cfg.prefix.as_str();
    let ports = match cfg.side {
        Side::Controller => Ports::Controller {
            requests: services::open_subscriber(&node, p).map_err(RelayError::Shm)?,
            progress: services::open_publisher(&node, p).map_err(RelayError::Shm)?,
            policies: services::open_publisher(&node, p).map_err(RelayError::Shm)?,
        },
        Side::Learner => Ports::Learner {
            requests: services::open_publisher(&node, p).map_err(RelayError::Shm)?,
            progress: services::open_subscriber(&node, p).map_err(RelayError::Shm)?,
            policies: services::open_subscriber(&node, p).map_err(RelayError::Shm)?,
        },
    };
    let gate_refusals = Arc::new(Mutex::new(CallbackRefusals::default()));
    let events: crate::gate::GateEvents = {
        let g = Arc::clone(&gate_refusals);
        Arc::new(move |kind, text| note(&g, kind, text))
    };
    let (session, gate) = cfg.link.open(&keys, &events)?;
    let verifier = Verifier::new(keys.peer, &cfg.link.link_name);
    let incoming: &[Channel] = match cfg.side {
        Side::Controller => &[Channel::RetrainProgress, Channel::Policy, Channel::Hello],
        Side::Learner => &[Channel::RetrainRequest, Channel::PolicyAck, Channel::Hello],
    };
    let (bell_tx, doorbell) = mpsc::sync_channel::<()>(1);
    let refusals = Arc::new(Mutex::new(CallbackRefusals::default()));
    let mut queues = Vec::new();
    let mut subscribers = Vec::new();
    for &channel in incoming {
        let (tx, rx) = mpsc::sync_channel::<Verified>(queue_len(channel));
        let bell = bell_tx.clone();
        let refused = Arc::clone(&refusals);
        let verifier = verifier.clone();
        // The last sequence queued on this channel, from the last accepted (across restarts).
        let admitted = Mutex::new(
            state
                .seen
                .get(channel.key_suffix())
                .copied()
                .unwrap_or_default(),
        );
        let sub = session
            .declare_subscriber(cfg.link.key(channel))
            // Not this session's own publications (hellos go both ways on one key).
            .allowed_origin(zenoh::sample::Locality::Remote)
            .callback(move |sample| {
                // The size first (unread), then verified, then a bounded queue; never blocks.
                if let Err(e) = wire::check_size(sample.payload().len(), channel) {
                    note(&refused, e.kind(), format!("{channel:?} refused: {e}"));
                    return;
                }
                let bytes = sample.payload().to_bytes();
                if admit(&bytes, channel, &verifier, &admitted, &tx, &refused) {
                    let _ = bell.try_send(());
                }
            })
            .wait()
            .map_err(|e| LinkError::Zenoh(format!("subscribing {channel:?}: {e}")))?;
        subscribers.push(sub);
        queues.push((channel, rx));
    }
    drop(bell_tx);
    let inbox = Inbox {
        queues,
        doorbell,
        refusals,
        gate: gate_refusals,
    };
    let status = RelayStatus {
        side: Some(cfg.side),
        host: host_name(),
        link_name: cfg.link.link_name.clone(),
        prefix: cfg.prefix.clone(),
        peers: cfg.link.peers.clone(),
        listen: cfg.link.listen.clone(),
        started_unix_s: unix_s(),
        auth: Some(AuthStatus {
            keys_dir: keys.dir.display().to_string(),
            own_key: fingerprint(&keys.signing.verifying_key()),
            peer_key: peer_fp.clone(),
            user: keys.user.clone(),
        }),
        ..RelayStatus::default()
    };
    tracing::info!(
        side = ?cfg.side,
        prefix = %cfg.prefix,
        peers = ?cfg.link.peers,
        listen = ?cfg.link.listen,
        link = %cfg.link.link_name,
        own_key = %fingerprint(&keys.signing.verifying_key()),
        peer_key = %peer_fp,
        "relay up"
    );
    let signer = Signer::new(keys.signing.clone(), &cfg.link.link_name);
    let mut relay = Relay {
        instance: new_instance_id(),
        // Above every number an earlier run of this relay may have used.
        seq: state.sent,
        signer,
        guard: SequenceGuard::from_marks(&state.seen),
        state,
        state_path,
        state_dirty: false,
        cfg,
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
    let mut next_state = Instant::now();
    let mut next_connections = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        match inbox.doorbell.recv_timeout(POLL) {
            Ok(()) | Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        relay.take_remote(&inbox);
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
        if relay.state_dirty && now >= next_state {
            relay.save_state();
            next_state = now + STATE_EVERY;
        }
    }
    relay.take_remote(&inbox);
    relay.save_state();
    relay.write_status();
    drop(subscribers);
    let status = relay.status.clone();
    let _ = relay.session.close().wait();
    drop(gate);
    tracing::info!("relay stopped");
    Ok(status)
}

impl Relay {
    /// The next sequence: the wall clock in ns, or one above the last sent, whichever is
    /// larger. It never goes down for this key, across restarts too: the state file holds
    /// a reservation [`SEQUENCE_RESERVE_NS`] above the last number sent, written before a
    /// number beyond it is used, and a restarted relay starts above the reservation.
    fn next_seq(&mut self) -> u64 {
        let now_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
        self.seq = now_ns.max(self.seq.saturating_add(1));
        if self.seq > self.state.sent {
            self.state.sent = self.seq.saturating_add(SEQUENCE_RESERVE_NS);
            self.state_dirty = true;
            self.save_state();
        }
        self.seq
    }

    /// Writes the replay state when it changed; false when it could not be written.
    fn save_state(&mut self) -> bool {
        if !self.state_dirty {
            return true;
        }
        self.state.seen = self.guard.marks();
        match self.state.write(&self.state_path) {
            Ok(()) => {
                self.state_dirty = false;
                true
            }
            Err(e) => {
                if self.warn.allow("state", Instant::now()) {
                    tracing::error!("{}", error_chain(&e));
                }
                false
            }
        }
    }

    /// Takes what Zenoh's callbacks queued: at most a queue's length per channel, so one
    /// channel's flood does not hold up another or the loop. Folds the callbacks' refusals
    /// into the status.
    fn take_remote(&mut self, inbox: &Inbox) {
        for (channel, rx) in &inbox.queues {
            for _ in 0..queue_len(*channel) {
                match rx.try_recv() {
                    Ok(m) => self.on_remote(*channel, &m),
                    Err(_) => break,
                }
            }
        }
        let now = Instant::now();
        let taken = CallbackRefusals::take(&inbox.refusals);
        if let Some(text) = taken.last {
            for (kind, n) in taken.counts {
                *self.status.rejected.entry(kind.to_owned()).or_default() += n;
                if self.warn.allow(kind, now) {
                    tracing::warn!("{text} ({n} this turn)");
                }
            }
            self.status.last_rejection = Some(text);
            self.status_dirty = true;
        }
        let refused = CallbackRefusals::take(&inbox.gate);
        if let Some(text) = refused.last {
            for (kind, n) in refused.counts {
                *self
                    .status
                    .refused_connections
                    .entry(kind.to_owned())
                    .or_default() += n;
                if self.warn.allow(kind, now) {
                    tracing::warn!("gate: {text} ({n} this turn)");
                }
            }
            self.status.last_connection_refusal = Some(text);
            self.status_dirty = true;
        }
    }

    /// Sends without blocking: what Zenoh's queue cannot take is dropped there (requests and
    /// policies are re-sent until answered, a lost ack brings the policy again).
    fn put(&mut self, channel: Channel, bytes: Vec<u8>) {
        let key = self.cfg.link.key(channel);
        let res = self
            .session
            .put(key, bytes)
            .congestion_control(zenoh::qos::CongestionControl::Drop)
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
        self.refuse(e.kind(), format!("{channel:?} refused: {}", error_chain(e)));
    }

    /// Counts a refusal by `kind` and keeps its words for the status file.
    fn refuse(&mut self, kind: &'static str, text: String) {
        RelayStatus::count(&mut self.status.rejected, kind);
        if self.warn.allow(kind, Instant::now()) {
            tracing::warn!("{text}");
        }
        self.status.last_rejection = Some(text);
        self.status_dirty = true;
    }

    /// A message whose sequence is not above the last accepted on its channel is refused
    /// (`replay`).
    fn fresh(&mut self, h: &Header) -> bool {
        match self.guard.accept(h.channel, h.sequence) {
            Ok(()) => {
                self.state_dirty = true;
                true
            }
            Err(last) => {
                self.refuse("replay", replay_text(h.channel, h.sequence, last));
                false
            }
        }
    }

    /// Persists the replay state before a policy or a request is handed on; refused
    /// (`state_not_saved`) if it cannot be, so a restart can never accept it again.
    fn saved_before_forwarding(&mut self, channel: Channel) -> bool {
        if self.save_state() {
            return true;
        }
        self.refuse(
            "state_not_saved",
            format!(
                "{channel:?} not handed on: the replay state {} could not be written",
                self.state_path.display()
            ),
        );
        false
    }

    fn accepted(&mut self, channel: Channel) {
        RelayStatus::count(&mut self.status.received, channel.key_suffix());
        self.status_dirty = true;
    }

    /// A message from the other host (size, signature and sequence already checked by the
    /// callback): payload, sequence against the persisted marks, then the channel's rules.
    fn on_remote(&mut self, channel: Channel, m: &Verified) {
        let (h, payload) = (m.header, m.payload.as_slice());
        let res = match channel {
            Channel::Hello => control_payload::<Hello>(payload, channel).map(|m| {
                // Zenoh does not hand a session its own publications (`Locality::Remote`);
                // the instance check is a second guard.
                let ok = h.sender_instance != self.instance && self.fresh(&h);
                if ok {
                    self.on_hello(&m);
                }
                ok
            }),
            Channel::RetrainRequest => message_payload::<RetrainRequest>(payload).map(|r| {
                let ok = self.fresh(&h);
                if ok {
                    self.on_request(h.sender_instance, &r);
                }
                ok
            }),
            Channel::RetrainProgress => message_payload::<RetrainProgress>(payload).map(|p| {
                let ok = self.fresh(&h);
                if ok {
                    self.on_progress(&p, h.request);
                }
                ok
            }),
            Channel::Policy => message_payload::<PolicyBlob>(payload).map(|b| {
                let ok = self.fresh(&h);
                if ok {
                    self.on_policy(&b, h.request);
                }
                ok
            }),
            Channel::PolicyAck => control_payload::<PolicyAck>(payload, channel).map(|a| {
                let ok = self.fresh(&h);
                if ok && self.policy_out.on_ack(a.policy_id, a.checksum) {
                    tracing::info!(
                        policy_id = a.policy_id,
                        "policy acknowledged by the controller"
                    );
                }
                ok
            }),
        };
        match res {
            Ok(true) => self.accepted(channel),
            Ok(false) => {}
            Err(e) => self.reject(channel, &e),
        }
    }

    fn on_hello(&mut self, hello: &Hello) {
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

    /// Learner side: a request from the controller (signature and sequence checked).
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
        if !self.saved_before_forwarding(Channel::RetrainRequest) {
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
                self.send_progress(&p);
                self.status.duplicates_dropped += 1;
            }
            RequestAction::Drop => self.status.duplicates_dropped += 1,
        }
    }

    /// Controller side: progress from the learner host, bound by it to request `bound`.
    /// Only progress bound to the request in flight is forwarded: a late or replayed answer
    /// to another request cannot end this one.
    fn on_progress(&mut self, p: &RetrainProgress, bound: RequestRef) {
        let now = Instant::now();
        match self.request_out.on_progress(p, bound, now) {
            ProgressAction::Stale => {
                self.status.stale_dropped += 1;
                self.status_dirty = true;
                tracing::debug!(
                    request = p.request_id,
                    bound_time_ns = bound.request_time_ns,
                    "progress for another request than the one in flight: dropped"
                );
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
                                Ok(RetrainPhase::Infeasible) => "infeasible",
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

    /// Controller side: a policy from the learner host (signature, blob and sequence
    /// checked), bound by it to request `bound`. It is handed to rt-core only when it is for
    /// the request in flight, and only after the replay state is saved.
    fn on_policy(&mut self, blob: &PolicyBlob, bound: RequestRef) {
        let (id, checksum) = (blob.policy_id, blob.checksum);
        let current = self.request_out.current().map(RequestRef::of);
        if current != Some(bound) {
            // A genuine policy for a superseded (or unknown) request: acknowledged so the
            // learner host stops sending it, never handed on.
            self.status.stale_dropped += 1;
            self.status_dirty = true;
            if self.warn.allow("stale_policy", Instant::now()) {
                tracing::info!(
                    policy_id = id,
                    for_request = bound.request_id,
                    current = ?current.map(|c| c.request_id),
                    "policy for another request than the one in flight: not handed to rt-core"
                );
            }
        } else if self.policy_in.is_new(id, checksum) {
            if !self.saved_before_forwarding(Channel::Policy) {
                // Not acknowledged: sent again, and refused again until the state is saved.
                return;
            }
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
        let bytes = encode_control(
            &Header::new(Channel::PolicyAck, self.instance, seq),
            &ack,
            &self.signer,
        );
        self.put(Channel::PolicyAck, bytes);
    }

    /// Learner side: one progress message to the controller, bound to its request.
    fn send_progress(&mut self, p: &RetrainProgress) {
        let seq = self.next_seq();
        let header = Header::new(Channel::RetrainProgress, self.instance, seq)
            .bound_to(self.request_in.binding(p.request_id));
        let bytes = encode_message(&header, p, &self.signer);
        self.put(Channel::RetrainProgress, bytes);
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
            self.send_progress(&p);
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
                    self.latest_policy = Some((b, self.request_in.current()));
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
        let header =
            Header::new(Channel::RetrainRequest, self.instance, seq).bound_to(RequestRef::of(r));
        let bytes = encode_message(&header, r, &self.signer);
        self.put(Channel::RetrainRequest, bytes);
        if let Some(s) = self.status.requests.last_mut()
            && s.request_id == r.request_id
        {
            s.sends += 1;
        }
    }

    fn send_policy(&mut self) {
        let seq = self.next_seq();
        let Some((b, bound)) = self.latest_policy.as_ref() else {
            return;
        };
        let header = Header::new(Channel::Policy, self.instance, seq).bound_to(*bound);
        let bytes = encode_message(&header, &**b, &self.signer);
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
        let bytes = encode_control(
            &Header::new(Channel::Hello, self.instance, seq),
            &hello,
            &self.signer,
        );
        // Hellos are not counted as traffic.
        let _ = self
            .session
            .put(self.cfg.link.key(Channel::Hello), bytes)
            .congestion_control(zenoh::qos::CongestionControl::Drop)
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
