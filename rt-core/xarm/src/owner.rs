//! [`ArmLock`]: one owner per arm. Whoever moves the arm (`rt-core run`, `rt-core xarm probe
//! --servo-test`) first takes an exclusive `flock` on a file named after the controller's
//! resolved command address, *before* it connects; a second owner is refused with the
//! holder's pid, since when it holds the arm and its command line.
//!
//! The lock is the kernel's (`flock(2)` through [`File::try_lock`]): it belongs to the open
//! file, so it dies with the process whatever the way out (a crash, `kill -9`), and a stale
//! lock cannot exist. The file itself stays; only the lock on it counts.
//!
//! Where: `$FORESIGHT_LOCK_DIR` if set, else the folder `foresight` in the machine's own
//! lock folder, `/run/lock/foresight` (`/tmp/foresight` where there is no `/run/lock`). The
//! lock folder is private (issue 41 item 4): made at start by rt-core's user with mode 0755
//! and checked before every use to be owned by that user and writable by nobody else, so no
//! other user can plant a file, a socket or a link where the lock or the operator's
//! acknowledgement channel (`<lock>.ack`) belongs. Operators of another account reach the
//! channel through the folder's search permission; the channel decides by their user id.
//! Every folder above it must be a real folder (no symbolic link), owned by root or by this
//! user, and sticky if others may write to it (`/run/lock` and `/tmp` are). Otherwise the
//! lock is refused ([`ArmLockError::InsecureFolder`], naming the folder and why). Two users
//! of one machine still cannot both drive one arm: the second finds the lock folder owned
//! by the first and is refused, naming it. A file another user put in the lock's place is
//! named with the way to remove it ([`ArmLockError::Planted`]).
//!
//! Name: the *canonical* controller address ([`canonical_addr`]), so every spelling of one
//! arm is one lock: the name is resolved (trailing dots and case ignored) to the first
//! address (the one the driver connects to), an IPv4-mapped IPv6 address is the IPv4 one
//! (`::ffff:127.0.0.1` is `127.0.0.1`), and every loopback address (127.0.0.0/8, `::1`) is
//! `127.0.0.1` (a simulator listening on all addresses answers on each of them).
//!
//! Limits: the lock is this machine's. It cannot see a process on *another* machine driving
//! the same controller, nor one in another container or network namespace with its own
//! `/run/lock` and `/tmp` (share the folder into every container that may drive the arm, or
//! point `FORESIGHT_LOCK_DIR` at a shared one), nor one that reaches the controller through
//! another address of it (a second network interface, a NAT). On NFS `flock` is emulated
//! with POSIX locks on the server (Linux ≥ 2.6.12) and is only as good as the server's lock
//! manager: keep the lock folder on a local file system.
//!
//! The file is [`LOCK_FILE_MODE`] (0600): no other user may open it, so none can take (or
//! hold) the lock with a read-only descriptor and refuse rt-core the arm. Who holds it is
//! still named to other users from the kernel's lock table ([`owner_of`]).
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
use std::net::{IpAddr, Ipv4Addr, SocketAddr, ToSocketAddrs};
use std::os::unix::fs::{DirBuilderExt, FileExt, MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::config::XArmConfig;

/// Environment variable naming the lock folder (default: the first of [`DEFAULT_LOCK_DIRS`]
/// that exists).
pub const LOCK_DIR_ENV: &str = "FORESIGHT_LOCK_DIR";

/// The lock file's mode: readable and writable by its creator only (issue 41 item 4). A
/// file others could open (0644 before) let any user take a read-only descriptor's `flock`
/// on it and refuse rt-core the arm. The file lies in a private folder
/// ([`LOCK_FOLDER_MODE`]), so another user's rt-core never needs to open it: it is refused
/// at the folder, naming its owner.
pub const LOCK_FILE_MODE: u32 = 0o600;

/// The lock folder's mode when rt-core makes it: writable by its owner only; others may
/// pass through it to the acknowledgement channel's socket.
pub const LOCK_FOLDER_MODE: u32 = 0o755;

/// The machine-wide lock folders, in order of preference: the first that exists holds the
/// private lock folder [`LOCK_SUBDIR`].
pub const DEFAULT_LOCK_DIRS: [&str; 2] = ["/run/lock", "/tmp"];

/// The private lock folder's name in the machine-wide one.
pub const LOCK_SUBDIR: &str = "foresight";

/// Prefix of the lock files' names.
const LOCK_FILE_PREFIX: &str = "foresight-xarm-";

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
    /// The lock folder (or one above it) could let another user remove, replace or plant
    /// a file where the lock or the acknowledgement channel belongs.
    #[error(
        "refusing the lock folder {}: {why}; the lock folder must be this user's own and \
         writable by it alone (rt-core makes it, mode 755, when it is missing), every folder \
         above it owned by root or by this user and not writable by others unless sticky \
         (like /tmp); if nothing of another user runs from it, remove it (as its owner or \
         root: `rm -r -- '{}'`) or set FORESIGHT_LOCK_DIR to a folder of your own",
        .path.display(), .path.display()
    )]
    InsecureFolder {
        /// The folder.
        path: PathBuf,
        /// Why.
        why: InsecureFolderWhy,
    },
    /// Something that is not this user's lock file lies in its place: a symbolic link, or
    /// a file of another user.
    #[error(
        "{} lies where the arm's lock file {} belongs: rt-core does not use it; if no \
         rt-core of that user runs, remove it (as its owner or root: `rm -f -- '{}'`) and \
         start again",
        .what, .path.display(), .path.display()
    )]
    Planted {
        /// The lock file's path.
        path: PathBuf,
        /// What lies there ("a file of uid 1001", "a symbolic link").
        what: String,
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

/// Why a lock folder is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum InsecureFolderWhy {
    /// A symbolic link (it could be pointed elsewhere).
    #[error("it is a symbolic link")]
    SymbolicLink,
    /// Not a folder.
    #[error("it is not a folder")]
    NotAFolder,
    /// Owned by another user (who may remove anything in it).
    #[error("it is owned by another user (uid {owner_uid})")]
    OtherOwner {
        /// The owner.
        owner_uid: u32,
    },
    /// Writable by others without the sticky bit (anyone may remove the lock file).
    #[error("it is writable by others without the sticky bit (mode {mode:o})")]
    WritableNotSticky {
        /// The folder's permission bits.
        mode: u32,
    },
    /// The lock file is not a regular file.
    #[error("the lock file is not a regular file")]
    NotAFile,
    /// The lock folder itself is writable by its group or by others (sticky or not): they
    /// could plant a file where the lock or the acknowledgement channel belongs.
    #[error("it is writable by others than its owner (mode {mode:o})")]
    NotPrivate {
        /// The folder's permission bits.
        mode: u32,
    },
}

/// The exclusive right to command one arm; released when dropped or when the process ends
/// (however it ends).
#[derive(Debug)]
pub struct ArmLock {
    // Held only for its lock (released explicitly on drop, see `Drop`).
    file: File,
    path: PathBuf,
    holder: LockHolder,
}

/// Releases the lock explicitly (`flock(LOCK_UN)`) before the file is closed. Closing alone
/// is not enough: the lock belongs to the open file description, and a child forked by any
/// thread of this process between its `fork` and its `exec` (std opens with `O_CLOEXEC`, so
/// only that window) holds a duplicate of the descriptor, which keeps the lock alive after
/// the owner let go. An explicit unlock releases it through every duplicate at once.
///
/// No Foresight process forks while it holds the lock: `rt-core` spawns no child, and the
/// launcher, which spawns `rt-core` and the other processes, never takes the lock itself.
/// A crash (no `Drop`) still releases the lock when the process's descriptors close, except
/// for a duplicate held by a child still between `fork` and `exec`, which that `exec`
/// closes an instant later.
impl Drop for ArmLock {
    fn drop(&mut self) {
        let _ = self.file.unlock();
    }
}

impl ArmLock {
    /// Takes the lock of the controller at `cfg.host:cfg.command_port` in the lock folder
    /// ([`lock_dir`]). Does not connect to the controller (the name is resolved, nothing is
    /// sent) and does not block.
    ///
    /// # Errors
    /// [`ArmLockError::Held`] naming the holder when another process has it;
    /// [`ArmLockError::InsecureFolder`]; the others when the name does not resolve or the
    /// file cannot be opened.
    pub fn acquire(cfg: &XArmConfig) -> Result<Self, ArmLockError> {
        Self::acquire_in(&lock_dir(), cfg)
    }

    /// [`ArmLock::acquire`] in the folder `dir`.
    ///
    /// # Errors
    /// As [`ArmLock::acquire`].
    pub fn acquire_in(dir: &Path, cfg: &XArmConfig) -> Result<Self, ArmLockError> {
        let addr = canonical_addr(&cfg.host, cfg.command_port)?;
        let path = dir.join(lock_file_name(addr));
        prepare_lock_folder(dir)?;
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
        // The file locked must still be the one the path names (not removed or replaced
        // between the open and the lock).
        let same = std::fs::symlink_metadata(&path)
            .ok()
            .zip(file.metadata().ok())
            .is_some_and(|(p, f)| p.dev() == f.dev() && p.ino() == f.ino());
        if !same {
            return Err(ArmLockError::Io {
                path,
                kind: ErrorKind::NotFound,
            });
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
        Ok(Self { file, path, holder })
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

/// Why the owner of an arm could not be named.
#[derive(Debug, thiserror::Error)]
pub enum ArmOwnerError {
    /// The controller's name does not resolve.
    #[error(transparent)]
    Lock(#[from] ArmLockError),
    /// No process holds the arm's lock.
    #[error("no process owns the xArm at {addr} (its lock {} is free)", .path.display())]
    NotHeld {
        /// The controller's canonical address.
        addr: SocketAddr,
        /// The lock file.
        path: PathBuf,
    },
    /// The lock is held, but the holder cannot be named for sure (no readable record that
    /// the kernel's lock table confirms).
    #[error(
        "the xArm at {addr} is owned, but its owner cannot be named for sure (lock {}; \
         the kernel's lock table does not confirm the record)",
        .path.display()
    )]
    Unconfirmed {
        /// The controller's canonical address.
        addr: SocketAddr,
        /// The lock file.
        path: PathBuf,
    },
}

/// The process that owns the arm at `cfg` now, from the lock folder ([`lock_dir`]): the
/// lock must be held, and its holder is the pid the kernel's lock table (`/proc/locks`)
/// gives for the lock file (the record's pid must agree when it is readable). For the
/// operator's acknowledgement, which must reach that process and no other.
///
/// # Errors
/// [`ArmOwnerError`].
pub fn owner_of(cfg: &XArmConfig) -> Result<LockHolder, ArmOwnerError> {
    owner_in(&lock_dir(), cfg)
}

/// [`owner_of`] in the folder `dir`.
///
/// # Errors
/// As [`owner_of`].
pub fn owner_in(dir: &Path, cfg: &XArmConfig) -> Result<LockHolder, ArmOwnerError> {
    let addr = canonical_addr(&cfg.host, cfg.command_port)?;
    let path = dir.join(lock_file_name(addr));
    let not_held = || ArmOwnerError::NotHeld {
        addr,
        path: path.clone(),
    };
    let file = match OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(&path)
    {
        Ok(f) => f,
        Err(e) if e.kind() == ErrorKind::NotFound => return Err(not_held()),
        // Another user's lock (0600, issue 41 item 4): the kernel's lock table names the
        // holder without opening the file.
        Err(e) if e.kind() == ErrorKind::PermissionDenied => {
            let meta = std::fs::symlink_metadata(&path).map_err(|e| ArmLockError::Io {
                path: path.clone(),
                kind: e.kind(),
            })?;
            let table =
                std::fs::read_to_string("/proc/locks").map_err(|_| ArmOwnerError::Unconfirmed {
                    addr,
                    path: path.clone(),
                })?;
            return match flock_holder(&table, meta.ino()) {
                Some(pid) => Ok(LockHolder {
                    pid,
                    since_unix_s: 0,
                    addr: addr.to_string(),
                    command_line: String::new(),
                }),
                None => Err(not_held()),
            };
        }
        Err(e) => {
            return Err(ArmLockError::Io {
                path,
                kind: e.kind(),
            }
            .into());
        }
    };
    match file.try_lock_shared() {
        Ok(()) => return Err(not_held()),
        Err(TryLockError::WouldBlock) => {}
        Err(TryLockError::Error(e)) => {
            return Err(ArmLockError::Io {
                path,
                kind: e.kind(),
            }
            .into());
        }
    }
    let unconfirmed = || ArmOwnerError::Unconfirmed {
        addr,
        path: path.clone(),
    };
    let ino = file.metadata().map_err(|_| unconfirmed())?.ino();
    let table = std::fs::read_to_string("/proc/locks").map_err(|_| unconfirmed())?;
    let pid = flock_holder(&table, ino).ok_or_else(unconfirmed)?;
    match read_holder(&file) {
        Some(h) if h.pid == pid => Ok(h),
        Some(_) => Err(unconfirmed()),
        None => Ok(LockHolder {
            pid,
            since_unix_s: 0,
            addr: addr.to_string(),
            command_line: String::new(),
        }),
    }
}

/// The pid holding an exclusive `flock` on inode `ino` in a `/proc/locks` table.
fn flock_holder(table: &str, ino: u64) -> Option<u32> {
    table.lines().find_map(|line| {
        // `1: FLOCK  ADVISORY  WRITE 1234 08:01:5678 0 EOF`; waiters read `1: -> FLOCK …`.
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            [_, "FLOCK", _, "WRITE", pid, dev, ..]
                if dev.rsplit(':').next()?.parse::<u64>().ok()? == ino =>
            {
                pid.parse().ok()
            }
            _ => None,
        }
    })
}

/// The lock folder: `$FORESIGHT_LOCK_DIR` if set, else [`LOCK_SUBDIR`] in the first of
/// [`DEFAULT_LOCK_DIRS`] that exists.
pub fn lock_dir() -> PathBuf {
    if let Some(d) = std::env::var_os(LOCK_DIR_ENV) {
        return PathBuf::from(d);
    }
    DEFAULT_LOCK_DIRS
        .iter()
        .map(PathBuf::from)
        .find(|d| d.is_dir())
        .unwrap_or_else(|| PathBuf::from("/tmp"))
        .join(LOCK_SUBDIR)
}

/// Makes the lock folder `dir` when it is missing ([`LOCK_FOLDER_MODE`]) and checks it
/// ([`check_lock_folder`]): what rt-core does before it puts its lock or its
/// acknowledgement channel there.
///
/// # Errors
/// As [`check_lock_folder`]; [`ArmLockError::Io`] when it cannot be made.
pub fn prepare_lock_folder(dir: &Path) -> Result<(), ArmLockError> {
    make_dir(dir)?;
    check_lock_folder(dir)
}

/// The canonical address of the controller at `host:port`, the key of its lock: the name
/// (trailing dots and case ignored) resolved to its first address, an IPv4-mapped IPv6
/// address as IPv4, every loopback address as `127.0.0.1`. Resolves the name; sends nothing.
///
/// # Errors
/// [`ArmLockError::Resolve`] when the name does not resolve.
pub fn canonical_addr(host: &str, port: u16) -> Result<SocketAddr, ArmLockError> {
    canonical_addr_with(host, port, |h, p| {
        (h, p).to_socket_addrs().map(Iterator::collect)
    })
}

/// [`canonical_addr`] with the name resolution injected (`resolve(host, port)`, called with
/// the cleaned name; an IP literal is not resolved), for tests.
///
/// # Errors
/// As [`canonical_addr`].
pub fn canonical_addr_with<R>(host: &str, port: u16, resolve: R) -> Result<SocketAddr, ArmLockError>
where
    R: FnOnce(&str, u16) -> std::io::Result<Vec<SocketAddr>>,
{
    let err = |kind| ArmLockError::Resolve {
        addr: format!("{host}:{port}"),
        kind,
    };
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    let bare = bare.split('%').next().unwrap_or(bare);
    let first = match bare.parse::<IpAddr>() {
        Ok(ip) => ip,
        Err(_) => {
            let name = host.trim_end_matches('.').to_ascii_lowercase();
            if name.is_empty() {
                return Err(err(ErrorKind::InvalidInput));
            }
            resolve(&name, port)
                .map_err(|e| err(e.kind()))?
                .first()
                .map(SocketAddr::ip)
                .ok_or_else(|| err(ErrorKind::NotFound))?
        }
    };
    let ip = match first.to_canonical() {
        ip if ip.is_loopback() => IpAddr::V4(Ipv4Addr::LOCALHOST),
        ip => ip,
    };
    Ok(SocketAddr::new(ip, port))
}

/// The path of the lock file of the controller at `cfg.host:cfg.command_port` in the
/// lock folder ([`lock_dir`]), whoever holds it. The operator's acknowledgement channel
/// lies beside it (`rt-core`'s `operator_ack`).
///
/// # Errors
/// When the name does not resolve.
pub fn lock_path(cfg: &XArmConfig) -> Result<PathBuf, ArmLockError> {
    let addr = canonical_addr(&cfg.host, cfg.command_port)?;
    Ok(lock_dir().join(lock_file_name(addr)))
}

/// `foresight-xarm-<ip>-<port>.lock`, the IPv6 colons as underscores.
fn lock_file_name(addr: SocketAddr) -> String {
    format!("{LOCK_FILE_PREFIX}{}-{}.lock", addr.ip(), addr.port()).replace(':', "_")
}

/// The effective user id of this process.
pub fn effective_uid() -> u32 {
    // SAFETY: geteuid(2) takes no argument, touches no memory of ours and cannot fail.
    unsafe { libc::geteuid() }
}

/// Checks that `dir` and every folder above it cannot be used by another user to remove,
/// replace or plant a lock file: each is a real folder (not a symbolic link), owned by root
/// or by this user, and sticky when others may write to it; and `dir` itself is this
/// user's and writable by it alone (issue 41 item 4).
///
/// # Errors
/// [`ArmLockError::InsecureFolder`] naming the first folder that fails and why;
/// [`ArmLockError::Io`] when one cannot be read.
pub fn check_lock_folder(dir: &Path) -> Result<(), ArmLockError> {
    check_lock_folder_as(dir, effective_uid())
}

/// [`check_lock_folder`] as the user `uid`.
fn check_lock_folder_as(dir: &Path, uid: u32) -> Result<(), ArmLockError> {
    let abs = if dir.is_absolute() {
        dir.to_path_buf()
    } else {
        std::env::current_dir()
            .map_err(|e| ArmLockError::Io {
                path: dir.to_path_buf(),
                kind: e.kind(),
            })?
            .join(dir)
    };
    for (depth, folder) in abs.ancestors().enumerate() {
        let meta = std::fs::symlink_metadata(folder).map_err(|e| ArmLockError::Io {
            path: folder.to_path_buf(),
            kind: e.kind(),
        })?;
        let insecure = |why| ArmLockError::InsecureFolder {
            path: folder.to_path_buf(),
            why,
        };
        if meta.file_type().is_symlink() {
            return Err(insecure(InsecureFolderWhy::SymbolicLink));
        }
        if !meta.is_dir() {
            return Err(insecure(InsecureFolderWhy::NotAFolder));
        }
        if meta.uid() != 0 && meta.uid() != uid {
            return Err(insecure(InsecureFolderWhy::OtherOwner {
                owner_uid: meta.uid(),
            }));
        }
        let mode = meta.mode() & 0o7777;
        if mode & 0o022 != 0 && mode & 0o1000 == 0 {
            return Err(insecure(InsecureFolderWhy::WritableNotSticky { mode }));
        }
        // The lock folder itself: this user's, and nobody else may write in it.
        if depth == 0 {
            if meta.uid() != uid {
                return Err(insecure(InsecureFolderWhy::OtherOwner {
                    owner_uid: meta.uid(),
                }));
            }
            if mode & 0o022 != 0 {
                return Err(insecure(InsecureFolderWhy::NotPrivate { mode }));
            }
        }
    }
    Ok(())
}

/// Makes a missing lock folder ([`LOCK_FOLDER_MODE`], owned by this user; the check that
/// follows decides whether it may be used).
fn make_dir(dir: &Path) -> Result<(), ArmLockError> {
    if std::fs::symlink_metadata(dir).is_ok() {
        return Ok(());
    }
    let io = |e: std::io::Error| ArmLockError::Io {
        path: dir.to_path_buf(),
        kind: e.kind(),
    };
    match std::fs::DirBuilder::new()
        .recursive(true)
        .mode(LOCK_FOLDER_MODE)
        .create(dir)
    {
        Ok(()) => {
            // The mode above is cut by the umask; writable by its owner only in any case.
            let _ =
                std::fs::set_permissions(dir, std::fs::Permissions::from_mode(LOCK_FOLDER_MODE));
            Ok(())
        }
        Err(_) if dir.is_dir() => Ok(()),
        Err(e) => Err(io(e)),
    }
}

fn open(path: &Path) -> Result<File, ArmLockError> {
    let mut opts = OpenOptions::new();
    opts.read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(LOCK_FILE_MODE)
        // Never follow a link planted under the name (one made after the check below).
        // (O_NONBLOCK: a FIFO planted under the name must not block the open.)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    let io = |e: std::io::Error| ArmLockError::Io {
        path: path.to_path_buf(),
        kind: e.kind(),
    };
    let me = effective_uid();
    // A link or another user's file in the lock's place is named, never used (root could
    // open it, and a lock on another user's file is one they can take from us).
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => return Err(planted(path, "a symbolic link")),
        Ok(m) if m.uid() != me => {
            return Err(planted(path, &format!("a file of uid {}", m.uid())));
        }
        _ => {}
    }
    let file = opts.open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if meta.uid() != me {
        return Err(planted(path, &format!("a file of uid {}", meta.uid())));
    }
    // The mode above is cut by the umask; a file of ours from a version that made it
    // readable by others (0644, 0666) is narrowed too.
    if meta.mode() & 0o777 != LOCK_FILE_MODE {
        let _ = file.set_permissions(std::fs::Permissions::from_mode(LOCK_FILE_MODE));
    }
    // A FIFO or a device planted under the name is no lock file.
    if !meta.is_file() {
        return Err(ArmLockError::InsecureFolder {
            path: path.to_path_buf(),
            why: InsecureFolderWhy::NotAFile,
        });
    }
    Ok(file)
}

fn planted(path: &Path, what: &str) -> ArmLockError {
    ArmLockError::Planted {
        path: path.to_path_buf(),
        what: what.to_owned(),
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
        assert_eq!(first.path(), d.join("foresight-xarm-127.0.0.1-5020.lock"));
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

    /// Issue 30 item 7, narrowed by issue 41 item 4: the lock file is its creator's alone
    /// (0600; 0644 before, which let any user `flock` a read-only descriptor of it and
    /// refuse rt-core the arm), also when an older version left it open to others (0666,
    /// 0644); the lock still works for a second owner (refused while held, granted after).
    #[test]
    fn the_lock_file_is_readable_and_writable_by_its_creator_only() {
        let d = dir("mode");
        let cfg = XArmConfig::from_addr("127.0.0.1:5030");
        let first = ArmLock::acquire_in(&d, &cfg).unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().mode() & 0o777;
        assert_eq!(mode(first.path()), 0o600, "{}", first.path().display());
        let path = first.path().to_path_buf();
        drop(first);
        // A file left 0666 by an older version is narrowed by its owner's next lock.
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o666)).unwrap();
        let again = ArmLock::acquire_in(&d, &cfg).unwrap();
        assert_eq!(mode(&path), 0o600);
        assert!(ArmLock::acquire_in(&d, &cfg).is_err());
        drop(again);
        std::fs::remove_dir_all(&d).ok();
    }

    /// Issue 30 item 8: `make test` once found the lock still held after its owner was
    /// dropped, because a parallel test forked a child that held a duplicate of the lock's
    /// descriptor until its `exec`. A duplicate made here stands for that child, without
    /// any timing: the lock must be free as soon as the owner is dropped.
    #[test]
    fn a_duplicate_descriptor_in_a_forked_child_does_not_keep_the_lock_after_the_owner_lets_go() {
        let d = dir("duplicate");
        let cfg = XArmConfig::from_addr("127.0.0.1:5022");
        let first = ArmLock::acquire_in(&d, &cfg).unwrap();
        // What a child between fork and exec holds: another descriptor of the same open file.
        let child_copy = first.file.try_clone().unwrap();
        drop(first);
        let again = ArmLock::acquire_in(&d, &cfg);
        assert!(again.is_ok(), "{:?}", again.err());
        drop((again, child_copy));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn every_spelling_of_one_controller_is_one_lock() {
        let no_dns = |_: &str, _: u16| -> std::io::Result<Vec<SocketAddr>> {
            panic!("an IP literal is not resolved")
        };
        let key = |host: &str| canonical_addr_with(host, 502, no_dns).unwrap();
        let arm: SocketAddr = "192.168.1.195:502".parse().unwrap();
        for spelling in [
            "192.168.1.195",
            "::ffff:192.168.1.195",
            "[::ffff:192.168.1.195]",
            "::ffff:c0a8:1c3",
        ] {
            assert_eq!(key(spelling), arm, "{spelling}");
        }
        let lo: SocketAddr = "127.0.0.1:502".parse().unwrap();
        for spelling in ["127.0.0.1", "127.0.0.2", "::1", "[::1]", "::ffff:127.0.0.1"] {
            assert_eq!(key(spelling), lo, "{spelling}");
        }
        // Names: trailing dots and case do not matter, the first address counts, and a
        // mapped or loopback answer is canonical too.
        let named = |host: &str, answer: &str| {
            let answer: SocketAddr = answer.parse().unwrap();
            canonical_addr_with(host, 502, move |name, _| {
                assert_eq!(name, "xarm.lab", "the name as resolved");
                Ok(vec![answer, "10.9.9.9:502".parse().unwrap()])
            })
            .unwrap()
        };
        assert_eq!(named("XArm.Lab.", "192.168.1.195:502"), arm);
        assert_eq!(named("xarm.lab", "[::ffff:192.168.1.195]:502"), arm);
        assert_eq!(named("xarm.lab..", "[::1]:502"), lo);
        assert!(matches!(
            canonical_addr_with("xarm.lab", 502, |_, _| Ok(vec![])),
            Err(ArmLockError::Resolve { .. })
        ));
        assert!(matches!(
            canonical_addr_with(".", 502, no_dns),
            Err(ArmLockError::Resolve { .. })
        ));
        // And the real locks: an IPv4-mapped spelling and a trailing dot are refused as the
        // arm already held.
        let d = dir("spelling");
        let first = ArmLock::acquire_in(&d, &XArmConfig::from_addr("127.0.0.1:5020")).unwrap();
        for other in ["[::ffff:127.0.0.1]:5020", "[::1]:5020", "localhost.:5020"] {
            let e = ArmLock::acquire_in(&d, &XArmConfig::from_addr(other)).unwrap_err();
            assert!(matches!(e, ArmLockError::Held { .. }), "{other}: {e}");
        }
        drop(first);
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn a_lock_folder_others_could_empty_is_refused() {
        use std::os::unix::fs::symlink;
        let cfg = XArmConfig::from_addr("127.0.0.1:5030");
        let set_mode = |d: &Path, mode: u32| {
            std::fs::set_permissions(d, std::fs::Permissions::from_mode(mode)).unwrap();
        };
        // World-writable without the sticky bit: anyone could remove the lock file.
        let open = dir("open");
        std::fs::create_dir_all(&open).unwrap();
        set_mode(&open, 0o777);
        let e = ArmLock::acquire_in(&open, &cfg).unwrap_err();
        assert!(
            matches!(
                e,
                ArmLockError::InsecureFolder {
                    why: InsecureFolderWhy::WritableNotSticky { mode: 0o777 },
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("sticky"), "{e}");
        // A folder above the lock folder counts too.
        let inner = open.join("inner");
        std::fs::create_dir_all(&inner).unwrap();
        assert!(matches!(
            ArmLock::acquire_in(&inner, &cfg),
            Err(ArmLockError::InsecureFolder { ref path, .. }) if *path == open
        ));
        // Sticky (like /tmp): accepted above the lock folder (issue 41 item 4: the lock
        // folder itself is private, see the next test).
        set_mode(&open, 0o1777);
        drop(ArmLock::acquire_in(&inner, &cfg).unwrap());
        // A symbolic link to a good folder: refused.
        let link = dir("link");
        symlink(&open, &link).unwrap();
        assert!(matches!(
            ArmLock::acquire_in(&link, &cfg),
            Err(ArmLockError::InsecureFolder {
                why: InsecureFolderWhy::SymbolicLink,
                ..
            })
        ));
        // Owned by another user (who may remove anything in it, sticky or not).
        let theirs = dir("theirs");
        std::fs::create_dir_all(&theirs).unwrap();
        set_mode(&theirs, 0o1777);
        let me = effective_uid();
        let as_uid = if me == 0 {
            std::os::unix::fs::chown(&theirs, Some(65_534), None).unwrap();
            0
        } else {
            me + 1
        };
        let owner = std::fs::metadata(&theirs).unwrap().uid();
        assert!(matches!(
            check_lock_folder_as(&theirs, as_uid),
            Err(ArmLockError::InsecureFolder {
                why: InsecureFolderWhy::OtherOwner { owner_uid },
                ..
            }) if owner_uid == owner
        ));
        // A FIFO planted under the lock file's name: refused, without blocking.
        let fifo_dir = dir("fifo");
        std::fs::create_dir_all(&fifo_dir).unwrap();
        let name = lock_file_name(canonical_addr("127.0.0.1", 5030).unwrap());
        let made = std::process::Command::new("mkfifo")
            .arg(fifo_dir.join(name))
            .status()
            .is_ok_and(|s| s.success());
        if made {
            assert!(matches!(
                ArmLock::acquire_in(&fifo_dir, &cfg),
                Err(ArmLockError::InsecureFolder {
                    why: InsecureFolderWhy::NotAFile,
                    ..
                })
            ));
        }
        for d in [&open, &link, &theirs, &fifo_dir] {
            let _ = std::fs::remove_file(d);
            let _ = std::fs::remove_dir_all(d);
        }
    }

    /// Issue 41 item 4: the lock folder is made private (0755, this user's) and a folder
    /// others may write in is refused as the lock folder, sticky or not: another user
    /// could plant a file where the lock or the acknowledgement channel belongs (before,
    /// a missing folder was made 1777 and a sticky one was used as it was).
    #[test]
    fn the_lock_folder_is_made_private_and_a_shared_one_is_refused() {
        let cfg = XArmConfig::from_addr("127.0.0.1:5031");
        let d = dir("private").join("locks");
        let lock = ArmLock::acquire_in(&d, &cfg).unwrap();
        let meta = std::fs::metadata(&d).unwrap();
        assert_eq!(meta.mode() & 0o7777, LOCK_FOLDER_MODE, "{}", d.display());
        assert_eq!(meta.uid(), effective_uid());
        drop(lock);
        for shared in [0o1777, 0o1775, 0o775] {
            std::fs::set_permissions(&d, std::fs::Permissions::from_mode(shared)).unwrap();
            let e = ArmLock::acquire_in(&d, &cfg).unwrap_err();
            assert!(
                matches!(
                    e,
                    ArmLockError::InsecureFolder {
                        why: InsecureFolderWhy::NotPrivate { .. }
                            | InsecureFolderWhy::WritableNotSticky { .. },
                        ref path,
                    } if *path == d
                ),
                "mode {shared:o}: {e}"
            );
            if shared & 0o1000 != 0 {
                assert!(
                    matches!(
                        e,
                        ArmLockError::InsecureFolder {
                            why: InsecureFolderWhy::NotPrivate { .. },
                            ..
                        }
                    ),
                    "a sticky shared folder: {e}"
                );
            }
            assert!(e.to_string().contains("rm -r"), "{e}");
        }
        // The default folder is the private one inside the machine's.
        if std::env::var_os(LOCK_DIR_ENV).is_none() {
            assert_eq!(lock_dir().file_name().unwrap(), LOCK_SUBDIR);
        }
        std::fs::remove_dir_all(d.parent().unwrap()).ok();
    }

    /// Issue 41 item 4: a link, or a file of another user, in the lock file's place is
    /// named with the way to remove it, never locked (before, root locked another user's
    /// file, which that user could lock in turn and so refuse rt-core the arm).
    #[test]
    fn a_foreign_file_in_the_locks_place_is_named_with_the_way_to_remove_it() {
        let d = dir("planted");
        make_dir(&d).unwrap();
        let cfg = XArmConfig::from_addr("127.0.0.1:5032");
        let path = d.join(lock_file_name(canonical_addr("127.0.0.1", 5032).unwrap()));
        std::os::unix::fs::symlink("/dev/null", &path).unwrap();
        let e = ArmLock::acquire_in(&d, &cfg).unwrap_err();
        assert!(matches!(e, ArmLockError::Planted { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("symbolic link")
                && msg.contains(&format!("rm -f -- '{}'", path.display())),
            "{msg}"
        );
        std::fs::remove_file(&path).unwrap();
        // Another user's file (root can make one here; others cannot, which is the point).
        if effective_uid() == 0 {
            std::fs::write(&path, b"").unwrap();
            std::os::unix::fs::chown(&path, Some(65_534), None).unwrap();
            let e = ArmLock::acquire_in(&d, &cfg).unwrap_err();
            let msg = e.to_string();
            assert!(
                matches!(e, ArmLockError::Planted { .. }) && msg.contains("uid 65534"),
                "{msg}"
            );
            assert!(msg.contains("rm -f --"), "{msg}");
        }
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn the_owner_is_the_pid_the_kernel_names_for_the_lock() {
        let d = dir("owner");
        let cfg = XArmConfig::from_addr("127.0.0.1:5040");
        assert!(matches!(
            owner_in(&d, &cfg),
            Err(ArmOwnerError::NotHeld { .. })
        ));
        let lock = ArmLock::acquire_in(&d, &cfg).unwrap();
        let owner = owner_in(&d, &XArmConfig::from_addr("[::ffff:127.0.0.1]:5040")).unwrap();
        assert_eq!(owner.pid, std::process::id());
        assert_eq!(&owner, lock.holder());
        drop(lock);
        assert!(matches!(
            owner_in(&d, &cfg),
            Err(ArmOwnerError::NotHeld { .. })
        ));
        let table = "1: FLOCK  ADVISORY  WRITE 77 00:2a:991 0 EOF\n\
                     2: -> FLOCK  ADVISORY  WRITE 78 00:2a:992 0 EOF\n\
                     3: POSIX  ADVISORY  WRITE 79 00:2a:993 0 EOF\n";
        assert_eq!(flock_holder(table, 991), Some(77));
        assert_eq!(flock_holder(table, 992), None);
        assert_eq!(flock_holder(table, 993), None);
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
