//! [`ArmLock`]: one owner per arm. Whoever moves the arm (`rt-core run`, `rt-core xarm probe
//! --servo-test`) first takes an exclusive `flock` on a file named after the controller's
//! resolved command address, *before* it connects; a second owner is refused with the
//! holder's pid, since when it holds the arm and its command line.
//!
//! The lock is the kernel's (`flock(2)` through [`File::try_lock`]): it belongs to the open
//! file, so it dies with the process whatever the way out (a crash, `kill -9`), and a stale
//! lock cannot exist. The file itself stays; only the lock on it counts.
//!
//! Where: `$FORESIGHT_LOCK_DIR` if set, else `/tmp/foresight-arm-locks` (one folder for the
//! whole machine, sticky and writable by all like `/tmp`, so two users cannot both drive one
//! arm). Name: `xarm-<ip>-<port>.lock` from the first address the name resolves to (the one
//! the driver connects to), so `localhost` and `127.0.0.1` are the same arm. The lock cannot
//! see a process on *another* machine driving the same controller.
//!
//! The holder writes one fixed-size record (pid, since, address, command line) at offset 0
//! in a single write, closed by an end line that repeats the pid; a reader that catches a
//! half-written record sees the two pids differ and reads again.
//!
//! ```no_run
//! use xarm::config::XArmConfig;
//! use xarm::owner::ArmLock;
//! let lock = ArmLock::acquire(&XArmConfig::from_addr("192.168.1.195"))?;
//! // ... connect and move; the lock is released when `lock` is dropped or the process ends.
//! # Ok::<(), xarm::owner::ArmLockError>(())
//! ```

use std::fmt;
use std::fs::{File, OpenOptions, TryLockError};
use std::io::ErrorKind;
use std::net::{SocketAddr, ToSocketAddrs};
use std::os::unix::fs::{DirBuilderExt, FileExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::config::XArmConfig;

/// Environment variable naming the lock folder (default [`DEFAULT_LOCK_DIR`]).
pub const LOCK_DIR_ENV: &str = "FORESIGHT_LOCK_DIR";

/// The machine-wide lock folder.
pub const DEFAULT_LOCK_DIR: &str = "/tmp/foresight-arm-locks";

/// Size of the holder record (bytes); the command line is cut to fit.
const RECORD_LEN: usize = 1024;

/// First line of a record.
const MAGIC: &str = "foresight-arm-lock v1";

/// Who holds an arm's lock, as written in the lock file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LockHolder {
    /// Process id.
    pub pid: u32,
    /// When it took the lock (seconds since the Unix epoch).
    pub since_unix_s: u64,
    /// The controller address it resolved.
    pub addr: String,
    /// Its command line (arguments joined by spaces, possibly cut).
    pub command_line: String,
}

impl fmt::Display for LockHolder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "pid {} (holding the arm since {}; `{}`)",
            self.pid,
            utc_text(self.since_unix_s),
            self.command_line
        )
    }
}

/// Why the arm's lock was not taken.
#[derive(Debug, thiserror::Error)]
pub enum ArmLockError {
    /// The controller's name does not resolve (the lock is named after its address).
    #[error("cannot resolve the controller address {addr} to name its lock: {kind}")]
    Resolve {
        /// `host:port` as given.
        addr: String,
        /// Why.
        kind: ErrorKind,
    },
    /// The lock folder or file cannot be made or opened.
    #[error("cannot open the arm's lock file {}: {kind}", .path.display())]
    Io {
        /// The file (or folder).
        path: PathBuf,
        /// Why.
        kind: ErrorKind,
    },
    /// Another process holds the arm.
    #[error(
        "the xArm at {addr} is already commanded by {}: one process drives an arm at a \
         time; stop that one first (lock {})",
        .holder.as_ref().map_or_else(|| "another process (its record is unreadable)".to_owned(), ToString::to_string),
        .path.display()
    )]
    Held {
        /// The controller's resolved address.
        addr: SocketAddr,
        /// The lock file.
        path: PathBuf,
        /// Who holds it, when its record could be read.
        holder: Option<LockHolder>,
    },
}

/// The exclusive right to command one arm; released when dropped or when the process ends
/// (however it ends).
#[derive(Debug)]
pub struct ArmLock {
    // Held only for its lock (closing it releases the lock).
    _file: File,
    path: PathBuf,
    holder: LockHolder,
}

impl ArmLock {
    /// Takes the lock of the controller at `cfg.host:cfg.command_port` in the lock folder
    /// (`$FORESIGHT_LOCK_DIR` or [`DEFAULT_LOCK_DIR`]). Does not connect to the controller
    /// (the name is resolved, nothing is sent) and does not block.
    ///
    /// # Errors
    /// [`ArmLockError::Held`] naming the holder when another process has it; the others
    /// when the name does not resolve or the file cannot be opened.
    pub fn acquire(cfg: &XArmConfig) -> Result<Self, ArmLockError> {
        let dir = std::env::var_os(LOCK_DIR_ENV)
            .map_or_else(|| PathBuf::from(DEFAULT_LOCK_DIR), PathBuf::from);
        Self::acquire_in(&dir, cfg)
    }

    /// [`ArmLock::acquire`] in the folder `dir`.
    ///
    /// # Errors
    /// As [`ArmLock::acquire`].
    pub fn acquire_in(dir: &Path, cfg: &XArmConfig) -> Result<Self, ArmLockError> {
        let addr = resolve(cfg)?;
        let path = dir.join(lock_file_name(addr));
        make_dir(dir)?;
        let file = open(&path)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let holder = read_holder(&file);
                return Err(ArmLockError::Held { addr, path, holder });
            }
            Err(TryLockError::Error(e)) => {
                return Err(ArmLockError::Io {
                    path,
                    kind: e.kind(),
                });
            }
        }
        let holder = LockHolder {
            pid: std::process::id(),
            since_unix_s: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
            addr: addr.to_string(),
            command_line: std::env::args().collect::<Vec<_>>().join(" "),
        };
        // A read-only file (made by another user without write access for us) still locks;
        // its record then names the earlier holder, which the log line below corrects.
        if let Err(e) = write_record(&file, &holder) {
            tracing::warn!(path = %path.display(), error = %e, "could not write the arm lock's holder record");
        }
        tracing::info!(path = %path.display(), %addr, "arm lock taken: this process owns the arm");
        Ok(Self {
            _file: file,
            path,
            holder,
        })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// This process's record in it.
    pub fn holder(&self) -> &LockHolder {
        &self.holder
    }
}

fn resolve(cfg: &XArmConfig) -> Result<SocketAddr, ArmLockError> {
    let err = |kind| ArmLockError::Resolve {
        addr: format!("{}:{}", cfg.host, cfg.command_port),
        kind,
    };
    (cfg.host.as_str(), cfg.command_port)
        .to_socket_addrs()
        .map_err(|e| err(e.kind()))?
        .next()
        .ok_or_else(|| err(ErrorKind::NotFound))
}

/// `xarm-<ip>-<port>.lock`, the IPv6 colons as underscores.
fn lock_file_name(addr: SocketAddr) -> String {
    format!("xarm-{}-{}.lock", addr.ip(), addr.port()).replace(':', "_")
}

fn make_dir(dir: &Path) -> Result<(), ArmLockError> {
    if dir.is_dir() {
        return Ok(());
    }
    let io = |e: std::io::Error| ArmLockError::Io {
        path: dir.to_path_buf(),
        kind: e.kind(),
    };
    match std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o1777)
        .create(dir)
    {
        Ok(()) => {
            // Sticky and writable by all, like /tmp (the mode above is cut by the umask).
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o1777));
            Ok(())
        }
        Err(_) if dir.is_dir() => Ok(()),
        Err(e) => Err(io(e)),
    }
}

fn open(path: &Path) -> Result<File, ArmLockError> {
    let opts = |write: bool| {
        let mut o = OpenOptions::new();
        o.read(true)
            .write(write)
            .create(write)
            .truncate(false)
            .mode(0o666)
            // Never follow a link planted in a shared folder.
            .custom_flags(libc::O_NOFOLLOW);
        o
    };
    let io = |e: std::io::Error| ArmLockError::Io {
        path: path.to_path_buf(),
        kind: e.kind(),
    };
    match opts(true).open(path) {
        Ok(f) => {
            // Writable by the next user too (the mode above is cut by the umask).
            let _ = f.set_permissions(std::fs::Permissions::from_mode(0o666));
            Ok(f)
        }
        // Another user's file we may not write: a read-only descriptor locks as well.
        Err(e) if e.kind() == ErrorKind::PermissionDenied => opts(false).open(path).map_err(io),
        Err(e) => Err(io(e)),
    }
}

fn record_text(h: &LockHolder) -> [u8; RECORD_LEN] {
    let clean = |s: &str| s.replace(['\n', '\r'], " ");
    let head = format!(
        "{MAGIC}\npid={}\nsince_unix_s={}\naddr={}\ncmd=",
        h.pid,
        h.since_unix_s,
        clean(&h.addr)
    );
    let tail = format!("\nend pid={}\n", h.pid);
    let mut cmd = clean(&h.command_line);
    let room = RECORD_LEN.saturating_sub(head.len() + tail.len());
    if cmd.len() > room {
        let mut cut = room.saturating_sub(3);
        while !cmd.is_char_boundary(cut) {
            cut -= 1;
        }
        cmd.truncate(cut);
        cmd.push_str("...");
    }
    let text = format!("{head}{cmd}{tail}");
    let mut out = [b'\n'; RECORD_LEN];
    let n = text.len().min(RECORD_LEN);
    out[..n].copy_from_slice(&text.as_bytes()[..n]);
    out
}

fn write_record(file: &File, h: &LockHolder) -> std::io::Result<()> {
    let rec = record_text(h);
    if file.metadata()?.len() != RECORD_LEN as u64 {
        file.set_len(RECORD_LEN as u64)?;
    }
    // One write of the whole record (a reader checks its two pids agree).
    file.write_all_at(&rec, 0)?;
    Ok(())
}

/// Parses a record; `None` when it is incomplete or torn (the two pids differ).
fn parse_record(bytes: &[u8]) -> Option<LockHolder> {
    let text = std::str::from_utf8(bytes).ok()?;
    let mut lines = text.lines();
    if lines.next()? != MAGIC {
        return None;
    }
    let mut field = |key: &str| -> Option<String> {
        lines
            .next()?
            .strip_prefix(key)
            .and_then(|r| r.strip_prefix('='))
            .map(str::to_owned)
    };
    let pid: u32 = field("pid")?.parse().ok()?;
    let since_unix_s = field("since_unix_s")?.parse().ok()?;
    let addr = field("addr")?;
    let command_line = field("cmd")?;
    let end: u32 = lines.next()?.strip_prefix("end pid=")?.parse().ok()?;
    (end == pid).then_some(LockHolder {
        pid,
        since_unix_s,
        addr,
        command_line,
    })
}

/// The holder's record, read again a few times while it is torn or names a process that
/// no longer runs (a new holder is writing its own).
fn read_holder(file: &File) -> Option<LockHolder> {
    let mut last = None;
    for _ in 0..20 {
        let mut buf = [0u8; RECORD_LEN];
        let n = file.read_at(&mut buf, 0).unwrap_or(0);
        if let Some(h) = parse_record(&buf[..n]) {
            if Path::new(&format!("/proc/{}", h.pid)).exists() {
                return Some(h);
            }
            last = Some(h);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    last
}

/// `YYYY-MM-DD HH:MM:SS UTC` for seconds since the epoch.
fn utc_text(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let secs = unix_s % 86_400;
    // Civil from days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02} UTC",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn dir(test: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("xarm-lock-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn a_second_owner_is_refused_with_the_holder_named_until_the_first_lets_go() {
        let d = dir("second");
        let cfg = XArmConfig::from_addr("127.0.0.1:5020");
        let first = ArmLock::acquire_in(&d, &cfg).unwrap();
        assert_eq!(first.path(), d.join("xarm-127.0.0.1-5020.lock"));
        // `localhost` is the same arm; flock conflicts between two opens in one process too.
        let e = ArmLock::acquire_in(&d, &XArmConfig::from_addr("localhost:5020")).unwrap_err();
        let ArmLockError::Held { holder, addr, .. } = &e else {
            panic!("{e}");
        };
        assert_eq!(addr.port(), 5020);
        let holder = holder.as_ref().expect("the record is read");
        assert_eq!(holder.pid, std::process::id());
        assert_eq!(holder, first.holder());
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("pid {}", std::process::id())) && msg.contains("UTC"),
            "{msg}"
        );
        // Another port is another arm.
        let other = ArmLock::acquire_in(&d, &XArmConfig::from_addr("127.0.0.1:5021")).unwrap();
        drop(first);
        let again = ArmLock::acquire_in(&d, &cfg).unwrap();
        drop((again, other));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn records_round_trip_and_torn_ones_are_refused() {
        let h = LockHolder {
            pid: 42,
            since_unix_s: 1_700_000_000,
            addr: "127.0.0.1:502".into(),
            command_line: "rt-core run --link xarm\n--robot x".into(),
        };
        let rec = record_text(&h);
        let back = parse_record(&rec).unwrap();
        assert_eq!(back.command_line, "rt-core run --link xarm --robot x");
        assert_eq!((back.pid, back.since_unix_s), (42, 1_700_000_000));
        // The head of a new record over the tail of an old one.
        let other = record_text(&LockHolder {
            pid: 7,
            ..h.clone()
        });
        let mut torn = rec;
        torn[..40].copy_from_slice(&other[..40]);
        assert_eq!(parse_record(&torn), None);
        assert_eq!(parse_record(&rec[..40]), None);
        let long = LockHolder {
            command_line: "é".repeat(2000),
            ..h
        };
        assert!(
            parse_record(&record_text(&long))
                .unwrap()
                .command_line
                .ends_with("...")
        );
        assert_eq!(utc_text(1_700_000_000), "2023-11-14 22:13:20 UTC");
        assert_eq!(utc_text(0), "1970-01-01 00:00:00 UTC");
    }
}
