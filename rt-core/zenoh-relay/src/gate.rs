//! The relays' front door: every TCP connection between the two relays starts with a mutual
//! challenge–response on the two hosts' keys, before Zenoh sees a byte of it.
//!
//! Zenoh's `usrpwd` checks only the side that connects, and only for the link credential,
//! which both hosts hold: whoever has the credential could listen where a relay dials and get
//! its session. And Zenoh's listener keeps a connection that has not finished its handshake
//! in one of a few places (8, for 5 s) and turns new ones away while they are full: a few
//! plain TCP sockets that never speak kept the real peer out. So neither relay lets Zenoh
//! touch the network:
//!
//! - the **listening** relay's Zenoh listens on a loopback port; its [`Door`] listens on the
//!   `--listen` address, runs the handshake as the listener and, once the connector has
//!   proved it holds the other host's key, joins the socket to that loopback port;
//! - the **connecting** relay's Zenoh connects to a loopback port of its [`Dialer`], which
//!   dials the `--peer` address, runs the handshake as the connector and, once the listener
//!   has proved it holds the other host's key, joins the two sockets. Zenoh's re-dialling
//!   (every 0.5–2 s) is unchanged: a refused or failed handshake closes Zenoh's connection
//!   like a refused dial.
//!
//! Zenoh's `usrpwd` still applies inside, and every message is still signed.
//!
//! **Protocol** (gate version 1). Each host already holds its own Ed25519 signing key and the
//! other host's public key ([`crate::keys`]); `L` is the link name and `SIG_X(m)` host X's
//! signature (verified with `verify_strict`) of `"foresight zenoh-relay gate v1\0" ‖ L ‖ "\0" ‖
//! m`:
//!
//! 1. connector → listener: `FSG1` ‖ `n_c` (32 random bytes);
//! 2. listener → connector: `FSG1` ‖ `n_l` (32 random bytes) ‖
//!    `SIG_listener("listener\0" ‖ n_c ‖ n_l)`;
//! 3. the connector verifies that signature with the other host's public key and hangs up if
//!    it does not verify, without proving anything itself; otherwise connector → listener:
//!    `SIG_connector("connector\0" ‖ n_l ‖ n_c)`;
//! 4. the listener verifies it with the other host's public key and hangs up if it does not
//!    verify; otherwise both sides carry Zenoh's bytes unchanged from here on.
//!
//! Each side signs a fresh nonce of the other's, so a recorded handshake is worth nothing;
//! the role inside each signature, and each side verifying only with the *other* host's key,
//! keep a proof from being reflected back. Keys of another `keygen`, or another
//! `--link-name`, fail both proofs; so does a holder of the link credential alone (the
//! credential is Zenoh's `usrpwd`, still checked inside).
//!
//! What it is not: a secure channel. The bytes after the handshake are neither encrypted nor
//! integrity-protected, so an active man in the middle who relays a whole handshake is not
//! stopped here (each message's own signature still decides what is accepted).
//!
//! **Pending connections.** A [`Door`] holds at most [`MAX_PENDING`] connections that have
//! not finished the handshake; each gets [`HANDSHAKE_TIMEOUT`] in all (not per byte), and a
//! new connection arriving while they are full closes the *oldest* pending one
//! (`pending_evicted`). A socket that never speaks therefore holds a place for at most
//! [`HANDSHAKE_TIMEOUT`] and is always the first to go, while a real peer's handshake takes
//! one round trip: idle sockets, however many, do not keep it out (only opening more than
//! [`MAX_PENDING`] new connections within that round trip would). At most [`MAX_TUNNELS`] proven
//! connections are kept (a new one closes the oldest: a peer that reconnects is never locked
//! out by its own stale connection). A [`Dialer`] carries at most [`MAX_TUNNELS`] of its
//! Zenoh's connections at once.

use shm_schemas::error_chain::error_chain;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ed25519_dalek::{Signature, Signer as _, SigningKey, VerifyingKey};

/// Time a connection has, in all, to finish the handshake.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(3);
/// Most connections a [`Door`] keeps before their handshake is done (the oldest goes first).
pub const MAX_PENDING: usize = 32;
/// Most proven connections a [`Door`] keeps, and most a [`Dialer`] carries at once: one per
/// Zenoh session the link allows ([`crate::link::MAX_SESSIONS`] is this value).
pub const MAX_TUNNELS: usize = 4;
/// How long a [`Dialer`] waits for the other host's TCP to answer.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);
/// First bytes of both handshake messages (gate version 1).
pub const GATE_MAGIC: [u8; 4] = *b"FSG1";
const NONCE_LEN: usize = 32;
const PROOF_LEN: usize = 64;
const HELLO_LEN: usize = GATE_MAGIC.len() + NONCE_LEN;
const ANSWER_LEN: usize = GATE_MAGIC.len() + NONCE_LEN + PROOF_LEN;
const DOMAIN: &[u8] = b"foresight zenoh-relay gate v1\0";
/// How often the accept loops look for new connections and for the stop flag.
const ACCEPT_POLL: Duration = Duration::from_millis(5);

/// Role names inside the signatures.
const LISTENER: &[u8] = b"listener";
const CONNECTOR: &[u8] = b"connector";

/// A host's keys, as both ends of the handshake use them: its own signing key and the other
/// host's public key, on one link.
#[derive(Clone)]
pub struct GateKey {
    own: SigningKey,
    peer: VerifyingKey,
    link_name: String,
}

impl std::fmt::Debug for GateKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GateKey")
            .field("own", &crate::keys::fingerprint(&self.own.verifying_key()))
            .field("peer", &crate::keys::fingerprint(&self.peer))
            .field("link_name", &self.link_name)
            .finish_non_exhaustive()
    }
}

impl GateKey {
    /// This host's key `own` and the other host's `peer`, on link `link_name`.
    pub fn new(own: SigningKey, peer: VerifyingKey, link_name: &str) -> Self {
        Self {
            own,
            peer,
            link_name: link_name.to_owned(),
        }
    }

    /// A host's keys as loaded from its folder.
    pub fn of(keys: &crate::keys::LinkKeys, link_name: &str) -> Self {
        Self::new(keys.signing.clone(), keys.peer, link_name)
    }

    fn signed(&self, role: &[u8], x: &[u8], y: &[u8]) -> Vec<u8> {
        let mut m = Vec::with_capacity(DOMAIN.len() + self.link_name.len() + 16 + 2 * NONCE_LEN);
        m.extend_from_slice(DOMAIN);
        m.extend_from_slice(self.link_name.as_bytes());
        m.push(0);
        m.extend_from_slice(role);
        m.push(0);
        m.extend_from_slice(x);
        m.extend_from_slice(y);
        m
    }

    fn prove(&self, role: &[u8], x: &[u8], y: &[u8]) -> [u8; PROOF_LEN] {
        self.own.sign(&self.signed(role, x, y)).to_bytes()
    }

    fn check(&self, role: &[u8], x: &[u8], y: &[u8], proof: &[u8]) -> bool {
        Signature::from_slice(proof).is_ok_and(|sig| {
            self.peer
                .verify_strict(&self.signed(role, x, y), &sig)
                .is_ok()
        })
    }
}

/// Why a handshake failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HandshakeError {
    /// The other side did not finish within [`HANDSHAKE_TIMEOUT`].
    #[error("no complete handshake within {} s", HANDSHAKE_TIMEOUT.as_secs())]
    Timeout,
    /// The first bytes are not the gate's: not a Foresight relay (or one of another version).
    #[error("not a Foresight relay's handshake (the first bytes are not \"FSG1\")")]
    NotARelay,
    /// The proof does not verify with the other host's public key.
    #[error(
        "its proof does not verify with the other host's public key (not that host, keys of another `zenoh-relay keygen`, or another --link-name)"
    )]
    BadProof,
    /// The other side closed the connection before the handshake was done.
    #[error("it closed the connection during the handshake")]
    Closed,
    /// The socket failed otherwise.
    #[error("socket: {0}")]
    Io(std::io::ErrorKind),
    /// The OS random source failed.
    #[error("random source")]
    Random(#[source] getrandom::Error),
}

fn io_error(e: &std::io::Error) -> HandshakeError {
    match e.kind() {
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => HandshakeError::Timeout,
        std::io::ErrorKind::UnexpectedEof
        | std::io::ErrorKind::ConnectionReset
        | std::io::ErrorKind::ConnectionAborted
        | std::io::ErrorKind::BrokenPipe => HandshakeError::Closed,
        kind => HandshakeError::Io(kind),
    }
}

/// Reads exactly `buf.len()` bytes before `deadline` (a peer dribbling bytes gets no more
/// time than one that sends none).
fn read_by(s: &mut TcpStream, buf: &mut [u8], deadline: Instant) -> Result<(), HandshakeError> {
    let mut got = 0;
    while got < buf.len() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(HandshakeError::Timeout);
        }
        s.set_read_timeout(Some(left)).map_err(|e| io_error(&e))?;
        match s.read(&mut buf[got..]) {
            Ok(0) => return Err(HandshakeError::Closed),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_error(&e)),
        }
    }
    Ok(())
}

fn write_by(s: &mut TcpStream, bytes: &[u8], deadline: Instant) -> Result<(), HandshakeError> {
    let left = deadline.saturating_duration_since(Instant::now());
    if left.is_zero() {
        return Err(HandshakeError::Timeout);
    }
    s.set_write_timeout(Some(left)).map_err(|e| io_error(&e))?;
    s.write_all(bytes).map_err(|e| io_error(&e))
}

fn nonce() -> Result<[u8; NONCE_LEN], HandshakeError> {
    let mut n = [0u8; NONCE_LEN];
    getrandom::fill(&mut n).map_err(HandshakeError::Random)?;
    Ok(n)
}

/// The connector's half of the handshake on a connected socket: the listener must prove it
/// holds the other host's key first; only then does this side prove its own.
///
/// # Errors
/// [`HandshakeError`]: the listener's proof is wrong or missing, it is not a relay, or the
/// socket failed or timed out ([`HANDSHAKE_TIMEOUT`] in all).
pub fn connect_handshake(s: &mut TcpStream, key: &GateKey) -> Result<(), HandshakeError> {
    let deadline = Instant::now() + HANDSHAKE_TIMEOUT;
    let n_c = nonce()?;
    let mut hello = [0u8; HELLO_LEN];
    hello[..4].copy_from_slice(&GATE_MAGIC);
    hello[4..].copy_from_slice(&n_c);
    write_by(s, &hello, deadline)?;
    let mut answer = [0u8; ANSWER_LEN];
    read_by(s, &mut answer, deadline)?;
    if answer[..4] != GATE_MAGIC {
        return Err(HandshakeError::NotARelay);
    }
    let n_l = &answer[4..4 + NONCE_LEN];
    if !key.check(LISTENER, &n_c, n_l, &answer[4 + NONCE_LEN..]) {
        return Err(HandshakeError::BadProof);
    }
    write_by(s, &key.prove(CONNECTOR, n_l, &n_c), deadline)?;
    clear_timeouts(s);
    Ok(())
}

/// The listener's half of the handshake on an accepted socket: signs the connector's nonce,
/// then checks the connector's signature of its own.
///
/// # Errors
/// [`HandshakeError`]: not a relay's hello, a wrong proof, or the socket failed or timed out
/// ([`HANDSHAKE_TIMEOUT`] in all).
pub fn accept_handshake(s: &mut TcpStream, key: &GateKey) -> Result<(), HandshakeError> {
    let deadline = Instant::now() + HANDSHAKE_TIMEOUT;
    let mut hello = [0u8; HELLO_LEN];
    read_by(s, &mut hello, deadline)?;
    if hello[..4] != GATE_MAGIC {
        return Err(HandshakeError::NotARelay);
    }
    let n_c = &hello[4..];
    let n_l = nonce()?;
    let mut answer = [0u8; ANSWER_LEN];
    answer[..4].copy_from_slice(&GATE_MAGIC);
    answer[4..4 + NONCE_LEN].copy_from_slice(&n_l);
    answer[4 + NONCE_LEN..].copy_from_slice(&key.prove(LISTENER, n_c, &n_l));
    write_by(s, &answer, deadline)?;
    let mut proof = [0u8; PROOF_LEN];
    read_by(s, &mut proof, deadline)?;
    if !key.check(CONNECTOR, &n_l, n_c, &proof) {
        return Err(HandshakeError::BadProof);
    }
    clear_timeouts(s);
    Ok(())
}

fn clear_timeouts(s: &TcpStream) {
    let _ = s.set_read_timeout(None);
    let _ = s.set_write_timeout(None);
}

/// Where the gate reports a refused or closed connection: a short stable kind
/// (`connector_unauthenticated`, `handshake_timeout`, `pending_evicted`,
/// `listener_unauthenticated`, `listener_no_handshake`) and a sentence.
pub type GateEvents = Arc<dyn Fn(&'static str, String) + Send + Sync>;

/// Sockets by id, oldest first, bounded: adding one beyond the bound closes the oldest.
#[derive(Default)]
struct Table(Mutex<VecDeque<(u64, TcpStream)>>);

impl Table {
    /// Adds `s`; returns the evicted oldest socket's id, if the table was full.
    fn add(&self, id: u64, s: TcpStream, max: usize) -> Option<u64> {
        let mut t = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let evicted = if t.len() >= max {
            t.pop_front().map(|(old, sock)| {
                let _ = sock.shutdown(Shutdown::Both);
                old
            })
        } else {
            None
        };
        t.push_back((id, s));
        evicted
    }

    /// Removes `id`; false when it was not there (evicted, or never added).
    fn remove(&self, id: u64) -> bool {
        let mut t = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        match t.iter().position(|(i, _)| *i == id) {
            Some(at) => {
                t.remove(at);
                true
            }
            None => false,
        }
    }

    fn len(&self) -> usize {
        self.0.lock().unwrap_or_else(PoisonError::into_inner).len()
    }

    fn close_all(&self) {
        let mut t = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        for (_, s) in t.drain(..) {
            let _ = s.shutdown(Shutdown::Both);
        }
    }
}

/// Carries bytes both ways until either side closes, then closes both.
fn pipe(a: TcpStream, b: TcpStream) {
    let _ = a.set_nodelay(true);
    let _ = b.set_nodelay(true);
    let (Ok(mut a2), Ok(mut b2)) = (a.try_clone(), b.try_clone()) else {
        let _ = a.shutdown(Shutdown::Both);
        let _ = b.shutdown(Shutdown::Both);
        return;
    };
    let back = std::thread::Builder::new()
        .name("gate-pipe".into())
        .spawn(move || {
            let _ = std::io::copy(&mut b2, &mut a2);
            let _ = a2.shutdown(Shutdown::Both);
            let _ = b2.shutdown(Shutdown::Both);
        });
    let (mut a, mut b) = (a, b);
    let _ = std::io::copy(&mut a, &mut b);
    let _ = a.shutdown(Shutdown::Both);
    let _ = b.shutdown(Shutdown::Both);
    if let Ok(t) = back {
        let _ = t.join();
    }
}

/// Accepts without blocking, until `stop`; hands each connection to `on_accept`.
fn accept_loop(
    listener: &TcpListener,
    stop: &AtomicBool,
    mut on_accept: impl FnMut(TcpStream, SocketAddr),
) {
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((s, from)) => {
                if s.set_nonblocking(false).is_ok() {
                    on_accept(s, from);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(ACCEPT_POLL);
            }
            Err(e) => {
                tracing::debug!("gate accept: {e}");
                std::thread::sleep(ACCEPT_POLL);
            }
        }
    }
}

/// The listening side's front door on one address (see the module docs).
pub struct Door {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    pending: Arc<Table>,
    tunnels: Arc<Table>,
}

impl Door {
    /// Listens on `listen`; a connection that proves it holds the other host's key of `key`
    /// is joined to `backend` (the local Zenoh's loopback listener). Refusals go to `events`.
    ///
    /// # Errors
    /// The address cannot be listened on (in use, not this host's).
    pub fn open(
        listen: SocketAddr,
        backend: SocketAddr,
        key: GateKey,
        events: GateEvents,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(listen)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let pending = Arc::new(Table::default());
        let tunnels = Arc::new(Table::default());
        let thread = {
            let (stop, pending, tunnels) = (
                Arc::clone(&stop),
                Arc::clone(&pending),
                Arc::clone(&tunnels),
            );
            let next = AtomicU64::new(0);
            std::thread::Builder::new()
                .name("gate-door".into())
                .spawn(move || {
                    accept_loop(&listener, &stop, |s, from| {
                        let id = next.fetch_add(1, Ordering::Relaxed);
                        let Ok(clone) = s.try_clone() else { return };
                        if let Some(old) = pending.add(id, clone, MAX_PENDING) {
                            events(
                                "pending_evicted",
                                format!(
                                    "{MAX_PENDING} connections to {addr} had not finished the handshake: the oldest (#{old}) was closed for the one from {from}"
                                ),
                            );
                        }
                        let ctx = Arrival {
                            id,
                            from,
                            backend,
                            key: key.clone(),
                            events: Arc::clone(&events),
                            pending: Arc::clone(&pending),
                            tunnels: Arc::clone(&tunnels),
                            stop: Arc::clone(&stop),
                        };
                        if std::thread::Builder::new()
                            .name("gate-handshake".into())
                            .spawn(move || ctx.run(s))
                            .is_err()
                        {
                            pending.remove(id);
                        }
                    });
                    pending.close_all();
                    tunnels.close_all();
                })?
        };
        Ok(Self {
            addr,
            stop,
            thread: Some(thread),
            pending,
            tunnels,
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Connections waiting for their handshake now.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Proven connections carried now.
    pub fn tunnels(&self) -> usize {
        self.tunnels.len()
    }
}

impl Drop for Door {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// One connection at a [`Door`], in its own thread.
struct Arrival {
    id: u64,
    from: SocketAddr,
    backend: SocketAddr,
    key: GateKey,
    events: GateEvents,
    pending: Arc<Table>,
    tunnels: Arc<Table>,
    stop: Arc<AtomicBool>,
}

impl Arrival {
    fn run(self, mut s: TcpStream) {
        let res = accept_handshake(&mut s, &self.key);
        // Not pending any more: evicted (already reported) or shutting down.
        if !self.pending.remove(self.id) || self.stop.load(Ordering::Relaxed) {
            let _ = s.shutdown(Shutdown::Both);
            return;
        }
        if let Err(e) = res {
            let kind = if e == HandshakeError::Timeout {
                "handshake_timeout"
            } else {
                "connector_unauthenticated"
            };
            (self.events)(
                kind,
                format!("connection from {} refused: {}", self.from, error_chain(&e)),
            );
            let _ = s.shutdown(Shutdown::Both);
            return;
        }
        let inner = match TcpStream::connect_timeout(&self.backend, CONNECT_TIMEOUT) {
            Ok(i) => i,
            Err(e) => {
                tracing::warn!("gate: the local Zenoh at {} refused: {e}", self.backend);
                let _ = s.shutdown(Shutdown::Both);
                return;
            }
        };
        tracing::debug!(from = %self.from, "gate: the connector proved the other host's key");
        if let Ok(clone) = s.try_clone()
            && let Some(old) = self.tunnels.add(self.id, clone, MAX_TUNNELS)
        {
            tracing::info!("gate: {MAX_TUNNELS} proven connections: the oldest (#{old}) closed");
        }
        pipe(s, inner);
        self.tunnels.remove(self.id);
    }
}

/// The connecting side's way out to one `--peer` address (see the module docs).
pub struct Dialer {
    local: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Dialer {
    /// Listens on a free loopback port for the local Zenoh; each of its connections is
    /// carried to `remote` (`ADDR:PORT`, resolved at each dial) once the listener there has
    /// proved it holds the other host's key of `key`. Refusals go to `events`.
    ///
    /// # Errors
    /// No loopback port could be listened on.
    pub fn open(remote: String, key: GateKey, events: GateEvents) -> std::io::Result<Self> {
        let listener = TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], 0)))?;
        listener.set_nonblocking(true)?;
        let local = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let active = Arc::new(AtomicU64::new(0));
        let thread = {
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("gate-dialer".into())
                .spawn(move || {
                    accept_loop(&listener, &stop, |s, _| {
                        if active.load(Ordering::Relaxed) >= MAX_TUNNELS as u64 {
                            let _ = s.shutdown(Shutdown::Both);
                            return;
                        }
                        active.fetch_add(1, Ordering::Relaxed);
                        let (remote, key, events, active) = (
                            remote.clone(),
                            key.clone(),
                            Arc::clone(&events),
                            Arc::clone(&active),
                        );
                        let spawned =
                            std::thread::Builder::new()
                                .name("gate-dial".into())
                                .spawn(move || {
                                    dial(s, &remote, &key, &events);
                                    active.fetch_sub(1, Ordering::Relaxed);
                                });
                        if spawned.is_err() {
                            tracing::warn!("gate: no thread for a dial");
                        }
                    });
                })?
        };
        Ok(Self {
            local,
            stop,
            thread: Some(thread),
        })
    }

    /// The loopback address the local Zenoh connects to.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }
}

impl Drop for Dialer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Dials `remote`, proves nothing until its listener has, then carries `local` (the local
/// Zenoh's connection) there.
fn dial(local: TcpStream, remote: &str, key: &GateKey, events: &GateEvents) {
    let addrs: Vec<SocketAddr> = match remote.to_socket_addrs() {
        Ok(a) => a.collect(),
        Err(e) => {
            tracing::debug!("gate: resolving {remote}: {e}");
            let _ = local.shutdown(Shutdown::Both);
            return;
        }
    };
    // Not reachable (yet): Zenoh dials again, as it would after a refused connection.
    let Some(mut out) = addrs
        .iter()
        .find_map(|a| TcpStream::connect_timeout(a, CONNECT_TIMEOUT).ok())
    else {
        let _ = local.shutdown(Shutdown::Both);
        return;
    };
    if let Err(e) = connect_handshake(&mut out, key) {
        let kind = match e {
            HandshakeError::BadProof | HandshakeError::NotARelay => "listener_unauthenticated",
            _ => "listener_no_handshake",
        };
        events(
            kind,
            format!("the listener at {remote} was refused: {}", error_chain(&e)),
        );
        let _ = out.shutdown(Shutdown::Both);
        let _ = local.shutdown(Shutdown::Both);
        return;
    }
    tracing::debug!(%remote, "gate: the listener proved the other host's key");
    pipe(local, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair() -> (TcpStream, TcpStream) {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let (a, _) = l.accept().unwrap();
        (c, a)
    }

    fn both(
        connector: GateKey,
        listener: GateKey,
    ) -> (Result<(), HandshakeError>, Result<(), HandshakeError>) {
        let (mut c, mut a) = pair();
        let t = std::thread::spawn(move || accept_handshake(&mut a, &listener));
        let rc = connect_handshake(&mut c, &connector);
        drop(c);
        (rc, t.join().unwrap())
    }

    /// The two hosts' keys, each side's view: (robot PC, learner host).
    fn hosts(link: &str) -> (GateKey, GateKey) {
        let (c, l) = (
            SigningKey::from_bytes(&[1; 32]),
            SigningKey::from_bytes(&[2; 32]),
        );
        (
            GateKey::new(c.clone(), l.verifying_key(), link),
            GateKey::new(l, c.verifying_key(), link),
        )
    }

    #[test]
    fn both_ends_prove_their_host_key_and_either_refuses_a_wrong_one() {
        let (robot, learner) = hosts("foresight");
        assert_eq!(both(robot.clone(), learner.clone()), (Ok(()), Ok(())));
        assert_eq!(both(learner.clone(), robot.clone()), (Ok(()), Ok(())));
        // The connector expects another listener key (another keygen's folder): it refuses
        // the listener and proves nothing; the listener sees it hang up.
        let stranger = SigningKey::from_bytes(&[3; 32]);
        let other = GateKey::new(robot.own.clone(), stranger.verifying_key(), "foresight");
        let (c, a) = both(other, learner.clone());
        assert_eq!(c, Err(HandshakeError::BadProof));
        assert_eq!(a, Err(HandshakeError::Closed));
        // Another link name: the same.
        let (robot2, _) = hosts("robot-2");
        let (c, _) = both(robot2, learner);
        assert_eq!(c, Err(HandshakeError::BadProof));
    }

    #[test]
    fn a_listener_refuses_a_connector_with_a_wrong_proof_or_none() {
        let (robot, learner) = hosts("foresight");
        // A connector that skips the listener's proof and signs with a stranger's key.
        let stranger = GateKey::new(
            SigningKey::from_bytes(&[3; 32]),
            learner.own.verifying_key(),
            "foresight",
        );
        let (mut c, mut a) = pair();
        let kl = learner.clone();
        let t = std::thread::spawn(move || accept_handshake(&mut a, &kl));
        let n_c = [9u8; NONCE_LEN];
        let mut hello = GATE_MAGIC.to_vec();
        hello.extend_from_slice(&n_c);
        c.write_all(&hello).unwrap();
        let mut answer = [0u8; ANSWER_LEN];
        c.read_exact(&mut answer).unwrap();
        assert!(robot.check(LISTENER, &n_c, &answer[4..36], &answer[36..]));
        c.write_all(&stranger.prove(CONNECTOR, &answer[4..36], &n_c))
            .unwrap();
        assert_eq!(t.join().unwrap(), Err(HandshakeError::BadProof));
        // The listener's own proof reflected back as the connector's: refused.
        let (mut c, mut a) = pair();
        let kl = learner.clone();
        let t = std::thread::spawn(move || accept_handshake(&mut a, &kl));
        c.write_all(&hello).unwrap();
        c.read_exact(&mut answer).unwrap();
        c.write_all(&answer[36..]).unwrap();
        assert_eq!(t.join().unwrap(), Err(HandshakeError::BadProof));
        // Not a relay (Zenoh's own first bytes, say).
        let (mut c, mut a) = pair();
        let t = std::thread::spawn(move || accept_handshake(&mut a, &learner));
        c.write_all(&[0u8; HELLO_LEN]).unwrap();
        assert_eq!(t.join().unwrap(), Err(HandshakeError::NotARelay));
    }

    #[test]
    fn a_silent_or_dribbling_connector_gets_the_handshake_timeout_in_all() {
        let (_, k) = hosts("foresight");
        let (mut c, mut a) = pair();
        let t = std::thread::spawn(move || accept_handshake(&mut a, &k));
        // One byte a second: each read would succeed, the deadline is for the whole.
        for _ in 0..5 {
            if c.write_all(b"F").is_err() {
                break;
            }
            std::thread::sleep(Duration::from_secs(1));
        }
        assert_eq!(t.join().unwrap(), Err(HandshakeError::Timeout));
    }

    #[test]
    fn a_full_door_closes_the_oldest_pending_connection() {
        let t = Table::default();
        let (a, _a) = pair();
        let (b, _b) = pair();
        let (c, _c) = pair();
        assert_eq!(t.add(1, a, 2), None);
        assert_eq!(t.add(2, b, 2), None);
        assert_eq!(t.add(3, c, 2), Some(1));
        assert!(!t.remove(1), "evicted");
        assert!(t.remove(3));
        assert_eq!(t.len(), 1);
    }
}
