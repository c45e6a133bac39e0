//! The operator's acknowledgement channel: the one way a latched protective stop is
//! cleared in `rt-core run` (not real-time; a thread of its own).
//!
//! - **Where.** A Unix stream socket beside the arm's lock file (`<lock>.ack`, see
//!   [`socket_path`]), made by the rt-core that holds the lock; `rt-core ack --robot HOST`
//!   finds it from the same address. The folder is the private lock folder
//!   (`xarm::owner::prepare_lock_folder`: made at start, this user's, writable by it alone),
//!   so no other user can plant anything in the socket's place; a file there that is not
//!   this user's socket is named, with how to remove it, and the channel does not open.
//! - **Who.** The kernel gives the peer's user id (`SO_PEERCRED`) right after `accept`:
//!   accepted from rt-core's own user, root and `[operator] ack_uids`; anything else is
//!   refused and closed at once, before a byte is read, and logged. A signal (the SIGUSR1 of
//!   earlier versions) clears nothing: any process of the same user can send one, and it
//!   names no stop.
//! - **Nobody blocks it** (issue 41 item 4). Each accepted connection is served on a
//!   thread of its own, up to [`MAX_CONNECTIONS`] at once (more are refused at once), and
//!   has one deadline for its whole request ([`REQUEST_TIMEOUT`]), not one per read: a
//!   client trickling a byte at a time is cut at the deadline, and meanwhile an operator's
//!   acknowledgement is served beside it.
//! - **What.** An acknowledgement names the stop it clears: its number (the cycle counts
//!   latches) and its reason. The channel first tells what is latched (`status`), the
//!   operator confirms that stop, and the cycle clears it only if it is still the one
//!   latched: a late or scripted acknowledgement cannot clear a newer stop.
//!
//! Protocol, one line each way per request (ASCII, ≤ [`MAX_LINE`] bytes):
//! `status` → `latched <seq> <code>` or `none`; `ack <seq> <code>` → `cleared <seq>`,
//! `refused <why>` or `dropped <why>`.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::os::unix::io::AsRawFd;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use crate::cycle::control::{CycleControl, StopReason};

/// Longest request or reply line, bytes.
pub const MAX_LINE: usize = 256;

/// How long a connection may take to send its whole request.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);

/// Connections served at once; one more is refused at once.
pub const MAX_CONNECTIONS: usize = 8;

/// How long the channel waits for the cycle to take an acknowledgement.
const CLEAR_WAIT: Duration = Duration::from_secs(2);

/// Why the channel could not be opened or used.
#[derive(Debug, thiserror::Error)]
pub enum AckChannelError {
    /// rt-core refused this user: not one of its operators.
    #[error("{path}: {why}")]
    Refused {
        /// The socket's path.
        path: PathBuf,
        /// rt-core's reason.
        why: String,
    },
    /// Something that is not this user's socket lies where the channel belongs.
    #[error(
        "{path}: {why}; the acknowledgement channel cannot open there: if no rt-core of \
         that user runs, remove it (as its owner or root: `rm -f -- '{path}'`) and start \
         again, or point FORESIGHT_LOCK_DIR elsewhere"
    )]
    PathTaken {
        /// The socket's path.
        path: PathBuf,
        /// What lies there.
        why: String,
    },
    /// The folder of the socket is not a private lock folder (or cannot be made).
    #[error("acknowledgement channel")]
    Folder(#[from] xarm::owner::ArmLockError),
    /// A socket call failed.
    #[error("{path}")]
    Io {
        /// The socket's path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The peer sent something that is not the protocol.
    #[error("{path}: unexpected reply {reply:?}")]
    Protocol {
        /// The socket's path.
        path: PathBuf,
        /// What came.
        reply: String,
    },
}

/// The acknowledgement channel's socket for the arm whose lock file is `lock_path`.
pub fn socket_path(lock_path: &Path) -> PathBuf {
    let mut s = lock_path.as_os_str().to_owned();
    s.push(".ack");
    PathBuf::from(s)
}

/// A stop the cycle has latched, as the channel names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LatchedStop {
    /// The latch's number in this run (1 for the first).
    pub seq: u64,
    /// [`StopReason::code`].
    pub code: u8,
}

impl std::fmt::Display for LatchedStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "stop #{} ({}, code {})",
            self.seq,
            StopReason::describe_code(self.code),
            self.code
        )
    }
}

/// The server side, started by `rt-core run` on an xArm link.
#[derive(Debug)]
pub struct AckServer {
    path: PathBuf,
}

impl AckServer {
    /// Binds the channel at `path` and serves it on a thread of its own until the process
    /// ends. A stale socket of this user's at `path` (a crashed run's) is replaced: the
    /// caller holds the arm's lock, so no live rt-core serves it. Anything else there is
    /// refused.
    ///
    /// # Errors
    /// [`AckChannelError`] when the socket cannot be made.
    pub fn start(
        path: PathBuf,
        control: Arc<CycleControl>,
        extra_uids: Vec<u32>,
    ) -> Result<Self, AckChannelError> {
        let me = xarm::owner::effective_uid();
        let allowed = [me, 0].into_iter().chain(extra_uids).collect();
        Self::start_allowing(path, control, allowed)
    }

    /// [`AckServer::start`] accepting exactly the user ids `allowed` (tests of the
    /// refusal; `start` adds rt-core's own user and root to the configured ones).
    ///
    /// # Errors
    /// As [`AckServer::start`].
    pub fn start_allowing(
        path: PathBuf,
        control: Arc<CycleControl>,
        allowed: Vec<u32>,
    ) -> Result<Self, AckChannelError> {
        let io = |source| AckChannelError::Io {
            path: path.clone(),
            source,
        };
        let me = xarm::owner::effective_uid();
        if let Some(folder) = path.parent() {
            xarm::owner::prepare_lock_folder(folder)?;
        }
        match std::fs::symlink_metadata(&path) {
            Ok(m) if m.file_type().is_socket() && m.uid() == me => {
                std::fs::remove_file(&path).map_err(io)?;
            }
            Ok(m) => {
                return Err(AckChannelError::PathTaken {
                    path: path.clone(),
                    why: format!(
                        "a {} owned by uid {} lies there",
                        if m.file_type().is_socket() {
                            "socket"
                        } else {
                            "file that is not a socket"
                        },
                        m.uid()
                    ),
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io(e)),
        }
        let listener = UnixListener::bind(&path).map_err(io)?;
        // Anyone may connect; the peer's user id decides (operators may be other accounts).
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o666)).map_err(io)?;
        let thread_path: Arc<Path> = Arc::from(path.as_path());
        let allowed: Arc<[u32]> = Arc::from(allowed);
        std::thread::Builder::new()
            .name("operator-ack".into())
            .spawn(move || {
                let busy = Arc::new(AtomicUsize::new(0));
                for conn in listener.incoming() {
                    match conn {
                        Ok(stream) => admit(stream, &control, &allowed, &thread_path, &busy),
                        Err(e) => tracing::warn!("acknowledgement channel: accept: {e}"),
                    }
                }
            })
            .map_err(io)?;
        tracing::info!(
            path = %path.display(),
            "operator acknowledgement channel open (`rt-core ack --robot HOST`)"
        );
        Ok(Self { path })
    }

    /// The socket's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for AckServer {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The peer's process and user ids, from the kernel.
fn peer_credentials(stream: &UnixStream) -> std::io::Result<(i32, u32)> {
    let mut cred = libc::ucred {
        pid: 0,
        uid: 0,
        gid: 0,
    };
    let mut len = std::mem::size_of::<libc::ucred>() as libc::socklen_t;
    // SAFETY: the descriptor is the open socket `stream` owns; `cred` and `len` are valid,
    // writable and `len` is `cred`'s size, so the kernel writes at most that many bytes.
    let rc = unsafe {
        libc::getsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            (&raw mut cred).cast(),
            &raw mut len,
        )
    };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok((cred.pid, cred.uid))
}

/// Reads one line of at most [`MAX_LINE`] bytes (the client's side: one reply).
fn read_line(stream: &UnixStream) -> std::io::Result<String> {
    let mut line = String::new();
    BufReader::new(stream.take(MAX_LINE as u64)).read_line(&mut line)?;
    Ok(line.trim().to_owned())
}

/// Reads one request line of at most [`MAX_LINE`] bytes, all of it before `deadline`: each
/// read waits only for the time left, so a client sending a byte at a time is cut at the
/// deadline, not kept as long as each byte comes within a timeout.
#[allow(
    clippy::disallowed_methods,
    reason = "the channel's own threads, off the cycle: the deadline is wall time"
)]
fn read_request(mut stream: &UnixStream, deadline: Instant) -> std::io::Result<String> {
    let mut buf = [0u8; MAX_LINE];
    let mut n = 0;
    while n < MAX_LINE && !buf[..n].contains(&b'\n') {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::ErrorKind::TimedOut.into());
        }
        stream.set_read_timeout(Some(left))?;
        match stream.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    let line = buf[..n].split(|b| *b == b'\n').next().unwrap_or_default();
    Ok(String::from_utf8_lossy(line).trim().to_owned())
}

/// One connection just accepted: a peer that is not an operator (or whose user id is not
/// known) is refused and closed at once, before anything is read from it; an operator's is
/// served on a thread of its own, at most [`MAX_CONNECTIONS`] at once.
#[allow(
    clippy::disallowed_methods,
    reason = "the channel's own thread, off the cycle: the request's deadline is wall time"
)]
fn admit(
    mut stream: UnixStream,
    control: &Arc<CycleControl>,
    allowed: &Arc<[u32]>,
    path: &Arc<Path>,
    busy: &Arc<AtomicUsize>,
) {
    let deadline = Instant::now() + REQUEST_TIMEOUT;
    // A refusal is one short line into an empty socket buffer: it never waits long.
    let _ = stream.set_write_timeout(Some(Duration::from_millis(100)));
    let (pid, uid) = match peer_credentials(&stream) {
        Ok(c) => c,
        Err(e) => {
            tracing::warn!("acknowledgement channel: peer credentials unknown ({e}): refused");
            let _ = writeln!(stream, "refused the peer's user id is unknown");
            return;
        }
    };
    if !allowed.contains(&uid) {
        tracing::warn!(
            uid,
            pid,
            "acknowledgement channel: refused a peer that is not an operator ([operator] ack_uids)"
        );
        let _ = writeln!(
            stream,
            "refused uid {uid} is not an operator of this rt-core ([operator] ack_uids in its runtime.toml)"
        );
        return;
    }
    if busy.fetch_add(1, Ordering::AcqRel) >= MAX_CONNECTIONS {
        busy.fetch_sub(1, Ordering::AcqRel);
        tracing::warn!(
            uid,
            pid,
            "acknowledgement channel: {MAX_CONNECTIONS} connections served already: refused"
        );
        let _ = writeln!(
            stream,
            "refused busy ({MAX_CONNECTIONS} connections served now): try again"
        );
        return;
    }
    let (control, path, slot) = (control.clone(), path.clone(), busy.clone());
    let spawned = std::thread::Builder::new()
        .name("operator-ack-conn".into())
        .spawn(move || {
            serve_one(stream, &control, uid, pid, &path, deadline);
            slot.fetch_sub(1, Ordering::AcqRel);
        });
    if let Err(e) = spawned {
        busy.fetch_sub(1, Ordering::AcqRel);
        tracing::warn!("acknowledgement channel: cannot serve a connection ({e})");
    }
}

fn serve_one(
    mut stream: UnixStream,
    control: &CycleControl,
    uid: u32,
    pid: i32,
    path: &Path,
    deadline: Instant,
) {
    let _ = stream.set_write_timeout(Some(REQUEST_TIMEOUT));
    let request = match read_request(&stream, deadline) {
        Ok(l) => l,
        Err(e) => {
            tracing::warn!(
                uid,
                pid,
                "acknowledgement channel: no request in time ({e})"
            );
            return;
        }
    };
    let reply = answer(&request, control, uid, pid, path);
    let _ = writeln!(stream, "{reply}");
}

/// The reply to one request.
fn answer(request: &str, control: &CycleControl, uid: u32, pid: i32, path: &Path) -> String {
    let latched = control
        .latched()
        .map(|(seq, code)| LatchedStop { seq, code });
    let mut words = request.split_ascii_whitespace();
    match (words.next(), words.next(), words.next(), words.next()) {
        (Some("status"), None, None, None) => match latched {
            Some(l) => format!("latched {} {}", l.seq, l.code),
            None => "none".into(),
        },
        (Some("ack"), Some(seq), Some(code), None) => {
            let (Ok(seq), Ok(code)) = (seq.parse::<u64>(), code.parse::<u8>()) else {
                return "refused `ack` takes a stop's number and its reason code".into();
            };
            let named = LatchedStop { seq, code };
            let Some(now) = latched else {
                tracing::warn!(uid, pid, %named, "acknowledgement refused: no stop is latched");
                return format!("refused no stop is latched (the acknowledgement named {named})");
            };
            if now != named {
                tracing::warn!(uid, pid, %named, latched = %now,
                    "acknowledgement refused: it names another stop than the one latched");
                return format!("refused it names {named}, but {now} is latched");
            }
            tracing::warn!(uid, pid, stop = %now, channel = %path.display(),
                "operator acknowledgement: clearing the controller's error and re-enabling motion");
            control.acknowledge(seq);
            wait_cleared(control, now)
        }
        _ => "refused unknown request (`status` or `ack <seq> <code>`)".into(),
    }
}

/// Waits until the cycle has taken the acknowledgement of `stop`.
#[allow(
    clippy::disallowed_methods,
    reason = "the channel's own thread, off the cycle: it waits for the cycle's next periods"
)]
fn wait_cleared(control: &CycleControl, stop: LatchedStop) -> String {
    let t0 = Instant::now();
    while t0.elapsed() < CLEAR_WAIT {
        std::thread::sleep(Duration::from_millis(10));
        if control.latched() != Some((stop.seq, stop.code)) {
            return format!("cleared {}", stop.seq);
        }
    }
    "dropped the cycle did not take it (the link is down, or the arm is still stopping or \
     not measured at rest): acknowledge again once the arm is at rest on a live link"
        .into()
}

/// What the client got for an acknowledgement.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AckOutcome {
    /// The stop was cleared.
    Cleared,
    /// Refused or dropped, with rt-core's reason.
    NotCleared(String),
}

fn request(path: &Path, line: &str) -> Result<String, AckChannelError> {
    let io = |source| AckChannelError::Io {
        path: path.to_owned(),
        source,
    };
    let mut stream = UnixStream::connect(path).map_err(io)?;
    stream
        .set_read_timeout(Some(REQUEST_TIMEOUT + CLEAR_WAIT + Duration::from_secs(1)))
        .map_err(io)?;
    match writeln!(stream, "{line}") {
        // Refused and closed before the request was read: the refusal is still there.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
        r => r.map_err(io)?,
    }
    read_line(&stream).map_err(io)
}

/// Asks the channel at `path` which stop is latched (`None`: none is).
///
/// # Errors
/// [`AckChannelError`] when the channel cannot be reached or answers out of protocol
/// (including a refusal of this user).
pub fn query(path: &Path) -> Result<Option<LatchedStop>, AckChannelError> {
    let reply = request(path, "status")?;
    if let Some(why) = reply.strip_prefix("refused ") {
        return Err(AckChannelError::Refused {
            path: path.to_owned(),
            why: why.to_owned(),
        });
    }
    let bad = || AckChannelError::Protocol {
        path: path.to_owned(),
        reply: reply.clone(),
    };
    let mut w = reply.split_ascii_whitespace();
    match (w.next(), w.next(), w.next()) {
        (Some("none"), None, None) => Ok(None),
        (Some("latched"), Some(seq), Some(code)) => Ok(Some(LatchedStop {
            seq: seq.parse().map_err(|_| bad())?,
            code: code.parse().map_err(|_| bad())?,
        })),
        _ => Err(bad()),
    }
}

/// Acknowledges `stop` over the channel at `path`.
///
/// # Errors
/// [`AckChannelError`] when the channel cannot be reached or answers out of protocol.
pub fn acknowledge(path: &Path, stop: LatchedStop) -> Result<AckOutcome, AckChannelError> {
    let reply = request(path, &format!("ack {} {}", stop.seq, stop.code))?;
    match reply.split_once(' ') {
        Some(("cleared", _)) => Ok(AckOutcome::Cleared),
        Some(("refused" | "dropped", why)) => Ok(AckOutcome::NotCleared(why.to_owned())),
        _ => Err(AckChannelError::Protocol {
            path: path.to_owned(),
            reply,
        }),
    }
}
