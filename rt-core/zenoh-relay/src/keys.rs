//! The link's keys: who may open a Zenoh session to a relay, and who signed a message.
//!
//! Two layers, both from existing, reviewed code — nothing here invents cryptography:
//!
//! - **Session (Zenoh's `usrpwd` authentication).** Both relays hold one link credential
//!   (`link.credential`, a line `user:password` with a 256-bit random password). The relay that
//!   accepts a connection checks the connecting one with Zenoh's challenge–response (an HMAC of
//!   the password keyed by a per-connection nonce); a peer without the credential gets no
//!   session at all, so it can neither publish nor subscribe. Zenoh checks only the side that
//!   connects, and the traffic is not encrypted, which is why the second layer exists.
//! - **Messages (Ed25519, `ed25519-dalek`).** Each host has its own signing key; every message
//!   a relay sends is signed ([`crate::wire`]) and the other relay verifies it with the public
//!   key it was given. This authenticates each relay to the other whichever side listens
//!   (mutual), end to end: the robot side hands rt-core only policies signed by the learner
//!   host's key, and the learner host serves only requests signed by the robot PC's.
//!
//! Zenoh's TLS/mTLS would need X.509 certificates (a CA, two certificates, their renewal) and
//! the rustls stack in the build; the two layers above need one command (`zenoh-relay keygen
//! --out DIR`) and 32-byte keys, and the signatures cover what TLS would not: who produced a
//! policy, not only who carried it.
//!
//! `keygen` writes one folder per host; each holds only what its host needs:
//!
//! ```text
//! DIR/robot-pc/      link.credential  controller.key    learner-host.pub   (the robot PC)
//! DIR/learner-host/  link.credential  learner-host.key  controller.pub     (the GPU box)
//! ```
//!
//! Secret files are written `0600` and refused when group or others may read them. Each
//! relay keeps its replay state ([`LinkState`]) in its keys folder.
//!
//! Whoever can replace a file of the folder can replace the peer's public key (and so
//! choose who signs policies) or lower the replay marks, so every file a relay reads — the
//! folder itself, the secrets, the other host's `.pub` and `link-state.json` — must be owned
//! by the relay's own user (or root) and writable by no one else: a file another user owns,
//! or that group or others may write, is refused naming it ([`KeyError::ForeignOwner`],
//! [`KeyError::Writable`]).

use std::io::Write;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use ed25519_dalek::{SigningKey, VerifyingKey};
use serde::{Deserialize, Serialize};

use crate::wire::Side;

/// The credential file's name (also Zenoh's `usrpwd` dictionary file).
pub const CREDENTIAL_FILE: &str = "link.credential";
/// The replay state file's name, in the keys folder.
pub const STATE_FILE: &str = "link-state.json";
/// The user name in the credential.
pub const LINK_USER: &str = "foresight-link";

/// The folder `keygen` writes for a side.
pub fn side_folder(side: Side) -> &'static str {
    match side {
        Side::Controller => "robot-pc",
        Side::Learner => "learner-host",
    }
}

/// The key file stem of a side (`controller.key`, `learner-host.pub`).
fn key_stem(side: Side) -> &'static str {
    match side {
        Side::Controller => "controller",
        Side::Learner => "learner-host",
    }
}

fn other(side: Side) -> Side {
    match side {
        Side::Controller => Side::Learner,
        Side::Learner => Side::Controller,
    }
}

/// Why keys could not be made or loaded. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// No `--link-keys` folder was given.
    #[error(
        "--link-keys DIR is missing: the two relays authenticate each other and every message is \
         signed, there is no unauthenticated mode. Make the keys once with `zenoh-relay keygen \
         --out link-keys`, then give link-keys/robot-pc on the robot PC and link-keys/learner-host \
         on the learner host"
    )]
    NoFolder,
    /// A file the side needs is not there.
    #[error(
        "{path}: missing ({what}). Is {dir} the {folder} folder written by `zenoh-relay keygen`?"
    )]
    Missing {
        /// The file.
        path: PathBuf,
        /// What it is.
        what: &'static str,
        /// The folder given.
        dir: PathBuf,
        /// The folder keygen writes for this side.
        folder: &'static str,
    },
    /// A secret file others may read.
    #[error("{path}: a secret readable by group or others (mode {mode:o}); run chmod 600 on it")]
    Permissions {
        /// The file.
        path: PathBuf,
        /// Its mode bits.
        mode: u32,
    },
    /// A file or the folder belongs to another user (neither this process's user nor
    /// root): that user could replace the keys or the replay marks.
    #[error(
        "{path}: owned by uid {owner}, not by this user (uid {me}) or root; another user could \
         replace the link's keys or replay marks. Take it over (chown) or make new keys"
    )]
    ForeignOwner {
        /// The file or folder.
        path: PathBuf,
        /// Its owner.
        owner: u32,
        /// This process's effective uid.
        me: u32,
    },
    /// A file or the folder group or others may write.
    #[error("{path}: writable by group or others (mode {mode:o}); run chmod go-w on it")]
    Writable {
        /// The file or folder.
        path: PathBuf,
        /// Its mode bits.
        mode: u32,
    },
    /// A file's content is not what it should be.
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// `keygen` would overwrite keys.
    #[error("{0}: already exists; keygen does not overwrite keys (choose another --out)")]
    Exists(PathBuf),
    /// The operating system's random source failed.
    #[error("random source")]
    Random(#[source] getrandom::Error),
    /// Reading or writing a file.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        error: std::io::Error,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> KeyError + '_ {
    move |error| KeyError::Io {
        path: path.to_owned(),
        error,
    }
}

fn random_32() -> Result<[u8; 32], KeyError> {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b).map_err(KeyError::Random)?;
    Ok(b)
}

fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

fn unhex_32(path: &Path, text: &str) -> Result<[u8; 32], KeyError> {
    let t = text.trim();
    let bad = |reason: &str| KeyError::Format {
        path: path.to_owned(),
        reason: reason.to_owned(),
    };
    if t.len() != 64 || !t.bytes().all(|c| c.is_ascii_hexdigit()) {
        return Err(bad("expected 64 hexadecimal characters (32 bytes)"));
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&t[2 * i..2 * i + 2], 16)
            .map_err(|_| bad("expected 64 hexadecimal characters (32 bytes)"))?;
    }
    Ok(out)
}

/// A short printable name of a public key (its first 8 bytes in hex).
pub fn fingerprint(key: &VerifyingKey) -> String {
    format!("ed25519:{}", hex(&key.as_bytes()[..8]))
}

fn write_new(path: &Path, text: &str, secret: bool) -> Result<(), KeyError> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(if secret { 0o600 } else { 0o644 })
        .open(path)
        .map_err(|e| {
            if e.kind() == std::io::ErrorKind::AlreadyExists {
                KeyError::Exists(path.to_owned())
            } else {
                KeyError::Io {
                    path: path.to_owned(),
                    error: e,
                }
            }
        })?;
    f.write_all(text.as_bytes()).map_err(io(path))?;
    f.sync_all().map_err(io(path))
}

/// What `keygen` wrote.
#[derive(Debug, Clone)]
pub struct Generated {
    /// The robot PC's folder.
    pub robot_pc: PathBuf,
    /// The learner host's folder.
    pub learner_host: PathBuf,
    /// The robot PC's public key.
    pub controller_key: String,
    /// The learner host's public key.
    pub learner_key: String,
}

/// `zenoh-relay keygen --out DIR`: a link credential and one signing key per host, in one
/// folder per host. Never overwrites a file.
///
/// # Errors
/// [`KeyError`] naming the file (or the random source).
pub fn generate(out: &Path) -> Result<Generated, KeyError> {
    let password = hex(&random_32()?);
    let credential = format!("{LINK_USER}:{password}\n");
    let controller = SigningKey::from_bytes(&random_32()?);
    let learner = SigningKey::from_bytes(&random_32()?);
    let mut dirs = Vec::new();
    for (side, own, peer) in [
        (Side::Controller, &controller, &learner),
        (Side::Learner, &learner, &controller),
    ] {
        let dir = out.join(side_folder(side));
        std::fs::create_dir_all(&dir).map_err(io(&dir))?;
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).map_err(io(&dir))?;
        write_new(&dir.join(CREDENTIAL_FILE), &credential, true)?;
        write_new(
            &dir.join(format!("{}.key", key_stem(side))),
            &format!("{}\n", hex(own.as_bytes())),
            true,
        )?;
        write_new(
            &dir.join(format!("{}.pub", key_stem(other(side)))),
            &format!("{}\n", hex(peer.verifying_key().as_bytes())),
            false,
        )?;
        dirs.push(dir);
    }
    Ok(Generated {
        learner_host: dirs.pop().unwrap_or_default(),
        robot_pc: dirs.pop().unwrap_or_default(),
        controller_key: fingerprint(&controller.verifying_key()),
        learner_key: fingerprint(&learner.verifying_key()),
    })
}

/// One relay's keys, loaded from its folder.
#[derive(Clone)]
pub struct LinkKeys {
    /// The folder (absolute).
    pub dir: PathBuf,
    /// This relay's side.
    pub side: Side,
    /// This host's signing key.
    pub signing: SigningKey,
    /// The other host's public key.
    pub peer: VerifyingKey,
    /// Zenoh `usrpwd` user.
    pub user: String,
    /// Zenoh `usrpwd` password.
    pub password: String,
    /// The credential file (absolute): Zenoh's dictionary of accepted users.
    pub credential_file: PathBuf,
}

impl std::fmt::Debug for LinkKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinkKeys")
            .field("dir", &self.dir)
            .field("side", &self.side)
            .field("own", &fingerprint(&self.signing.verifying_key()))
            .field("peer", &fingerprint(&self.peer))
            .field("user", &self.user)
            .finish_non_exhaustive()
    }
}

/// This process's effective uid: the user a file of the keys folder must belong to.
fn effective_uid() -> u32 {
    // SAFETY: geteuid(2) takes no argument, touches no memory of ours and cannot fail.
    unsafe { libc::geteuid() }
}

/// Refuses `path` (described by `meta`) when a user other than `me` or root owns it, or
/// when group or others may write it.
fn check_trusted(path: &Path, meta: &std::fs::Metadata, me: u32) -> Result<(), KeyError> {
    let owner = meta.uid();
    if owner != me && owner != 0 {
        return Err(KeyError::ForeignOwner {
            path: path.to_owned(),
            owner,
            me,
        });
    }
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o022 != 0 {
        return Err(KeyError::Writable {
            path: path.to_owned(),
            mode,
        });
    }
    Ok(())
}

fn read_file(
    dir: &Path,
    name: &str,
    what: &'static str,
    side: Side,
    secret: bool,
    me: u32,
) -> Result<(PathBuf, String), KeyError> {
    let path = dir.join(name);
    let meta = match std::fs::metadata(&path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(KeyError::Missing {
                path,
                what,
                dir: dir.to_owned(),
                folder: side_folder(side),
            });
        }
        Err(e) => return Err(KeyError::Io { path, error: e }),
    };
    check_trusted(&path, &meta, me)?;
    let mode = meta.permissions().mode() & 0o777;
    if secret && mode & 0o077 != 0 {
        return Err(KeyError::Permissions { path, mode });
    }
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    Ok((path, text))
}

impl LinkKeys {
    /// This side's keys from `dir` (the folder `keygen` wrote for it).
    ///
    /// # Errors
    /// [`KeyError`] naming the missing, unreadable, world-readable or malformed file, or the
    /// file or folder another user owns or may write.
    pub fn load(dir: Option<&Path>, side: Side) -> Result<Self, KeyError> {
        Self::load_for(dir, side, effective_uid())
    }

    /// [`LinkKeys::load`] for a process running as `me`.
    fn load_for(dir: Option<&Path>, side: Side, me: u32) -> Result<Self, KeyError> {
        let dir = dir.ok_or(KeyError::NoFolder)?;
        let dir = std::fs::canonicalize(dir).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                KeyError::Missing {
                    path: dir.to_owned(),
                    what: "the keys folder",
                    dir: dir.to_owned(),
                    folder: side_folder(side),
                }
            } else {
                KeyError::Io {
                    path: dir.to_owned(),
                    error: e,
                }
            }
        })?;
        let meta = std::fs::metadata(&dir).map_err(io(&dir))?;
        check_trusted(&dir, &meta, me)?;
        let (credential_file, text) = read_file(
            &dir,
            CREDENTIAL_FILE,
            "the link credential shared by both hosts",
            side,
            true,
            me,
        )?;
        let line = text.lines().map(str::trim).find(|l| !l.is_empty());
        let (user, password) = line
            .and_then(|l| l.split_once(':'))
            .map(|(u, p)| (u.trim().to_owned(), p.trim().to_owned()))
            .filter(|(u, p)| !u.is_empty() && p.len() >= 32)
            .ok_or_else(|| KeyError::Format {
                path: credential_file.clone(),
                reason:
                    "expected one line `user:password` with a password of at least 32 characters"
                        .into(),
            })?;
        let own_name = format!("{}.key", key_stem(side));
        let (own_path, own) =
            read_file(&dir, &own_name, "this host's signing key", side, true, me)?;
        let signing = SigningKey::from_bytes(&unhex_32(&own_path, &own)?);
        let peer_name = format!("{}.pub", key_stem(other(side)));
        let (peer_path, peer) = read_file(
            &dir,
            &peer_name,
            "the other host's public key",
            side,
            false,
            me,
        )?;
        let peer = VerifyingKey::from_bytes(&unhex_32(&peer_path, &peer)?).map_err(|e| {
            KeyError::Format {
                path: peer_path.clone(),
                reason: format!("not an Ed25519 public key: {e}"),
            }
        })?;
        if peer.is_weak() {
            return Err(KeyError::Format {
                path: peer_path,
                reason: "a weak (small-order) Ed25519 public key".into(),
            });
        }
        Ok(Self {
            dir,
            side,
            signing,
            peer,
            user,
            password,
            credential_file,
        })
    }

    /// Where this relay keeps its replay state.
    pub fn state_path(&self) -> PathBuf {
        self.dir.join(STATE_FILE)
    }
}

/// What a relay must remember across a restart so that a recorded message cannot be played
/// back to it: the highest sequence accepted from the peer's key per channel, and a bound
/// above every sequence it sent itself (its next messages are numbered above it even if the
/// clock went back). Written atomically (a temporary, fsync, rename, fsync of the folder).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LinkState {
    /// The peer key the `seen` marks belong to (new keys start afresh).
    pub peer_key: String,
    /// Highest sequence accepted per channel (`policy`, `retrain_progress`, …).
    pub seen: std::collections::BTreeMap<String, u64>,
    /// A bound above every sequence this relay sent (reserved before use).
    pub sent: u64,
}

impl LinkState {
    /// Reads the state for `peer_key`; a missing file, or one of other keys, is a fresh state.
    ///
    /// # Errors
    /// An unreadable or malformed file (refused rather than silently forgotten), or one
    /// another user owns or group or others may write (who could lower its marks).
    pub fn load(path: &Path, peer_key: &str) -> Result<Self, KeyError> {
        Self::load_for(path, peer_key, effective_uid())
    }

    /// [`LinkState::load`] for a process running as `me`.
    fn load_for(path: &Path, peer_key: &str, me: u32) -> Result<Self, KeyError> {
        match std::fs::metadata(path) {
            Ok(meta) => check_trusted(path, &meta, me)?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io(path)(e)),
        }
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Self {
                    peer_key: peer_key.to_owned(),
                    ..Self::default()
                });
            }
            Err(e) => return Err(io(path)(e)),
        };
        let st: Self = serde_json::from_str(&text).map_err(|e| KeyError::Format {
            path: path.to_owned(),
            reason: format!("{e} (delete it only if you also made new keys)"),
        })?;
        if st.peer_key != peer_key {
            return Ok(Self {
                peer_key: peer_key.to_owned(),
                ..Self::default()
            });
        }
        Ok(st)
    }

    /// Writes the state atomically.
    ///
    /// # Errors
    /// The file system's, naming the file.
    pub fn write(&self, path: &Path) -> Result<(), KeyError> {
        let json = serde_json::to_vec_pretty(self).map_err(|e| KeyError::Format {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let tmp = path.with_extension("json.tmp");
        {
            let mut f = std::fs::OpenOptions::new()
                .write(true)
                .create(true)
                .truncate(true)
                .mode(0o600)
                .open(&tmp)
                .map_err(io(&tmp))?;
            f.write_all(&json).map_err(io(&tmp))?;
            f.sync_all().map_err(io(&tmp))?;
        }
        std::fs::rename(&tmp, path).map_err(io(path))?;
        if let Some(dir) = path.parent()
            && let Ok(d) = std::fs::File::open(dir)
        {
            d.sync_all().map_err(io(dir))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("zrelay-keys-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn keygen_writes_one_folder_per_host_that_loads_as_a_matching_pair() {
        let d = tmp("pair");
        let g = generate(&d).unwrap();
        let c = LinkKeys::load(Some(&g.robot_pc), Side::Controller).unwrap();
        let l = LinkKeys::load(Some(&g.learner_host), Side::Learner).unwrap();
        assert_eq!(c.peer, l.signing.verifying_key());
        assert_eq!(l.peer, c.signing.verifying_key());
        assert_eq!((c.user.as_str(), &c.password), (LINK_USER, &l.password));
        assert_eq!(c.password.len(), 64);
        // Each host gets only its own secret.
        assert!(!g.robot_pc.join("learner-host.key").exists());
        assert!(!g.learner_host.join("controller.key").exists());
        let mode = std::fs::metadata(g.robot_pc.join("controller.key"))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o600);
        // Never overwrites.
        assert!(matches!(generate(&d), Err(KeyError::Exists(_))));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn missing_wrong_or_exposed_keys_are_refused_naming_the_file() {
        let d = tmp("bad");
        let e = LinkKeys::load(None, Side::Controller).unwrap_err();
        assert!(e.to_string().contains("--link-keys") && e.to_string().contains("keygen"));
        let e = LinkKeys::load(Some(&d), Side::Controller).unwrap_err();
        assert!(e.to_string().contains("keys folder"), "{e}");
        let g = generate(&d).unwrap();
        // The other host's folder.
        let e = LinkKeys::load(Some(&g.learner_host), Side::Controller)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("controller.key") && e.contains("robot-pc"),
            "{e}"
        );
        // A secret others may read.
        let key = g.robot_pc.join("controller.key");
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = LinkKeys::load(Some(&g.robot_pc), Side::Controller)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("controller.key") && e.contains("chmod 600"),
            "{e}"
        );
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
        // A truncated public key.
        std::fs::write(g.robot_pc.join("learner-host.pub"), "abcd\n").unwrap();
        let e = LinkKeys::load(Some(&g.robot_pc), Side::Controller)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("learner-host.pub") && e.contains("64 hex"),
            "{e}"
        );
        // No credential.
        std::fs::remove_file(g.robot_pc.join(CREDENTIAL_FILE)).unwrap();
        let e = LinkKeys::load(Some(&g.robot_pc), Side::Controller)
            .unwrap_err()
            .to_string();
        assert!(e.contains(CREDENTIAL_FILE) && e.contains("missing"), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }

    /// Issue 41 item 5: the keys folder, the other host's `.pub` and `link-state.json` are
    /// checked as the secrets are: one that group or others may write, or that another user
    /// owns, is refused naming it (before, only the secrets' read bits were checked).
    #[test]
    fn a_keys_folder_pub_or_state_file_others_may_write_or_own_is_refused_naming_it() {
        let d = tmp("trust");
        let g = generate(&d).unwrap();
        let me = effective_uid();
        let dir = std::fs::canonicalize(&g.robot_pc).unwrap();
        let public = dir.join("learner-host.pub");
        let state = dir.join(STATE_FILE);
        LinkState::default().write(&state).unwrap();
        LinkKeys::load_for(Some(&dir), Side::Controller, me).unwrap();
        LinkState::load_for(&state, "ed25519:aa", me).unwrap();
        let chmod = |p: &Path, mode: u32| {
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
        };
        let keys_err = |me: u32| {
            LinkKeys::load_for(Some(&dir), Side::Controller, me)
                .unwrap_err()
                .to_string()
        };
        let state_err = |me: u32| {
            LinkState::load_for(&state, "ed25519:aa", me)
                .unwrap_err()
                .to_string()
        };
        let named = |e: &str, p: &Path, what: &str| {
            assert!(
                e.starts_with(&format!("{}:", p.display())) && e.contains(what),
                "{e}"
            );
        };
        // Writable by group or others.
        for mode in [0o770, 0o703] {
            chmod(&dir, mode);
            named(&keys_err(me), &dir, "chmod go-w");
        }
        chmod(&dir, 0o700);
        for mode in [0o664, 0o646] {
            chmod(&public, mode);
            named(&keys_err(me), &public, "chmod go-w");
        }
        chmod(&public, 0o644);
        chmod(&state, 0o620);
        named(&state_err(me), &state, "chmod go-w");
        chmod(&state, 0o600);
        // Owned by another user.
        if me == 0 {
            for p in [&dir, &public] {
                std::os::unix::fs::chown(p, Some(65_534), None).unwrap();
                named(&keys_err(me), p, "owned by uid 65534");
                std::os::unix::fs::chown(p, Some(0), None).unwrap();
            }
            std::os::unix::fs::chown(&state, Some(65_534), None).unwrap();
            named(&state_err(me), &state, "owned by uid 65534");
            std::os::unix::fs::chown(&state, Some(0), None).unwrap();
        } else {
            // Without root no file can be given away: run as another user instead.
            named(&keys_err(me + 1), &dir, &format!("owned by uid {me}"));
            named(&state_err(me + 1), &state, &format!("owned by uid {me}"));
        }
        LinkKeys::load_for(Some(&dir), Side::Controller, me).unwrap();
        LinkState::load_for(&state, "ed25519:aa", me).unwrap();
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn the_replay_state_round_trips_and_new_keys_start_afresh() {
        let d = tmp("state");
        std::fs::create_dir_all(&d).unwrap();
        let path = d.join(STATE_FILE);
        let mut st = LinkState::load(&path, "ed25519:aa").unwrap();
        assert_eq!(st.sent, 0);
        st.seen.insert("policy".into(), 42);
        st.sent = 7;
        st.write(&path).unwrap();
        assert_eq!(LinkState::load(&path, "ed25519:aa").unwrap(), st);
        assert!(!path.with_extension("json.tmp").exists());
        assert!(
            LinkState::load(&path, "ed25519:bb")
                .unwrap()
                .seen
                .is_empty()
        );
        std::fs::write(&path, "{\"seen\": 3}").unwrap();
        let e = LinkState::load(&path, "ed25519:aa")
            .unwrap_err()
            .to_string();
        assert!(e.contains(STATE_FILE), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }
}
