//! The Zenoh side of a relay: where it listens, whom it connects to, and the keys.
//!
//! A relay is a Zenoh *peer* that listens only on the endpoints it is given (`--listen`) and
//! connects to the ones it is given (`--peer`, retried in the background every 0.5–2 s, also
//! after a lost connection). Zenoh itself never touches the network: it listens on a
//! loopback port behind the relay's [`crate::gate::Door`] and connects through a
//! [`crate::gate::Dialer`], so every connection between the relays starts with the gate's
//! mutual challenge–response on the two hosts' keys, and pending connections are bounded and
//! timed out there. There is no multicast scouting and no gossip (a scouted or gossiped
//! Zenoh locator would lead past the gate). Only TCP links are built into this binary.
//!
//! Keys are `foresight/<link name>/<channel>`; two robots on one LAN use two link names.
//!
//! Inside the gate, every session is also authenticated with Zenoh's `usrpwd` (the link
//! credential of [`crate::keys`]). The size of a message Zenoh reassembles is capped at the
//! largest valid relay message ([`crate::wire::MAX_MESSAGE_LEN`]) and the number of sessions
//! is small. There is no unauthenticated mode: without `--link-keys` a relay does not start.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use std::net::{SocketAddr, ToSocketAddrs};

use zenoh::Wait;
use zenoh::config::EndPoint;

use crate::gate::{Dialer, Door, GateEvents, GateKey};
use crate::keys::{KeyError, LinkKeys};
use crate::wire::{Channel, MAX_MESSAGE_LEN, Side};

/// Most Zenoh sessions a relay keeps (the other relay, and its reconnection): one per tunnel
/// the gate carries.
pub const MAX_SESSIONS: usize = crate::gate::MAX_TUNNELS;

/// Where a relay listens and connects (shared by `zenoh-relay` and `foresight`).
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct LinkArgs {
    /// A peer relay to connect to, `tcp/ADDR:PORT` (repeatable). Retried until it answers.
    #[arg(long = "peer", value_name = "tcp/ADDR:PORT")]
    pub peers: Vec<String>,
    /// Listen for the peer relay here, `tcp/ADDR:PORT` (repeatable; `tcp/0.0.0.0:7447` for
    /// every interface). Nothing is listened on unless given.
    #[arg(long = "listen", value_name = "tcp/ADDR:PORT")]
    pub listen: Vec<String>,
    /// The link's name: the middle of every Zenoh key (`foresight/<NAME>/…`). Relays only
    /// talk to relays of the same name (one name per robot on a shared LAN).
    #[arg(long, default_value = "foresight")]
    pub link_name: String,
    /// This host's keys folder, written by `zenoh-relay keygen --out DIR`: `DIR/robot-pc` on
    /// the robot PC, `DIR/learner-host` on the learner host. Required: the relays
    /// authenticate each other and sign every message.
    #[arg(long, value_name = "DIR")]
    pub link_keys: Option<PathBuf>,
}

/// Why the link settings are refused or the session could not be opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LinkError {
    /// Neither `--peer` nor `--listen`: nothing could ever connect.
    #[error(
        "no way to reach the other host: give --peer tcp/ADDR:PORT (the other relay's \
         address) or --listen tcp/ADDR:PORT (where the other relay connects)"
    )]
    Nowhere,
    /// An endpoint is not `tcp/ADDR:PORT`.
    #[error("{flag} {value}: {reason}")]
    Endpoint {
        /// `--peer` or `--listen`.
        flag: &'static str,
        /// As given.
        value: String,
        /// What is wrong.
        reason: String,
    },
    /// The link name is not usable in a key.
    #[error(
        "--link-name {0:?}: use 1–64 characters of letters, digits, `-` and `_` (it becomes part of the Zenoh keys)"
    )]
    LinkName(String),
    /// The keys are missing or unusable (the message names the file). (Text: this enum is
    /// `Clone + Eq`, and [`KeyError`] holds an `io::Error`.)
    #[error("{0}")]
    Keys(String),
    /// A `--listen` address cannot be listened on (taken, not this host's, unresolvable).
    #[error("--listen {value}: {error}")]
    Listen {
        /// As given.
        value: String,
        /// The system's words.
        error: String,
    },
    /// Zenoh refused the configuration or could not open. (Text: what was being set, with
    /// Zenoh's boxed error.)
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// Where the relay's own Zenoh listens and connects: loopback ports of the gate (see
/// [`LinkArgs::open`]), never the network.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ZenohEndpoints {
    /// Zenoh's listener behind the [`Door`]s (`tcp/127.0.0.1:PORT`), if the relay listens.
    pub listen: Vec<String>,
    /// The [`Dialer`]s' loopback ports, one per `--peer`.
    pub connect: Vec<String>,
}

/// A relay's gate: its doors (one per `--listen`) and dialers (one per `--peer`). Dropping
/// it closes them and every connection they carry.
#[derive(Default)]
pub struct Gate {
    /// One per `--listen`.
    pub doors: Vec<Door>,
    /// One per `--peer`.
    pub dialers: Vec<Dialer>,
}

/// `ADDR:PORT` of a checked `tcp/ADDR:PORT[?…][#…]` endpoint.
fn host_port(endpoint: &str) -> &str {
    let a = endpoint.strip_prefix("tcp/").unwrap_or(endpoint);
    a.split(['?', '#']).next().unwrap_or(a)
}

/// A loopback port free now (for Zenoh's listener behind the door).
fn free_loopback_port() -> Result<SocketAddr, LinkError> {
    std::net::TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], 0)))
        .and_then(|l| l.local_addr())
        .map_err(|e| LinkError::Zenoh(format!("no free loopback port for Zenoh: {e}")))
}

impl From<KeyError> for LinkError {
    fn from(e: KeyError) -> Self {
        Self::Keys(shm_schemas::error_chain::error_chain(&e).to_string())
    }
}

fn check_endpoint(flag: &'static str, value: &str) -> Result<(), LinkError> {
    let err = |reason: &str| LinkError::Endpoint {
        flag,
        value: value.to_owned(),
        reason: reason.to_owned(),
    };
    let Some(addr) = value.strip_prefix("tcp/") else {
        return Err(err(
            "only TCP endpoints are supported, written tcp/ADDR:PORT (e.g. tcp/192.168.1.20:7447)",
        ));
    };
    let port = addr
        .rsplit_once(':')
        .map(|(_, p)| p)
        .ok_or_else(|| err("missing the port (:PORT)"))?;
    if port.parse::<u16>().is_err() {
        return Err(err("the port is not a number in 0–65535"));
    }
    EndPoint::from_str(value).map_err(|e| err(&e.to_string()))?;
    Ok(())
}

impl LinkArgs {
    /// Checks the endpoints and the link name.
    ///
    /// # Errors
    /// [`LinkError`] naming the flag and value.
    pub fn validate(&self) -> Result<(), LinkError> {
        if self.peers.is_empty() && self.listen.is_empty() {
            return Err(LinkError::Nowhere);
        }
        for p in &self.peers {
            check_endpoint("--peer", p)?;
        }
        for l in &self.listen {
            check_endpoint("--listen", l)?;
        }
        let name_ok = !self.link_name.is_empty()
            && self.link_name.len() <= 64
            && self
                .link_name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
        if !name_ok {
            return Err(LinkError::LinkName(self.link_name.clone()));
        }
        if self.link_keys.is_none() {
            return Err(KeyError::NoFolder.into());
        }
        Ok(())
    }

    /// Validates the flags and loads `side`'s keys from `--link-keys`.
    ///
    /// # Errors
    /// [`LinkError`] naming the flag, or the missing or unusable key file.
    pub fn load_keys(&self, side: Side) -> Result<LinkKeys, LinkError> {
        self.validate()?;
        Ok(LinkKeys::load(self.link_keys.as_deref(), side)?)
    }

    /// The flags as a command line (for the launcher to pass on).
    pub fn to_args(&self) -> Vec<String> {
        let mut out = Vec::new();
        for p in &self.peers {
            out.extend(["--peer".to_owned(), p.clone()]);
        }
        for l in &self.listen {
            out.extend(["--listen".to_owned(), l.clone()]);
        }
        out.extend(["--link-name".to_owned(), self.link_name.clone()]);
        if let Some(k) = &self.link_keys {
            out.extend(["--link-keys".to_owned(), k.display().to_string()]);
        }
        out
    }

    /// The Zenoh key of a channel on this link.
    pub fn key(&self, channel: Channel) -> String {
        format!("foresight/{}/{}", self.link_name, channel.key_suffix())
    }

    /// The Zenoh configuration: peer mode, listening and connecting only on the gate's
    /// loopback endpoints `inner`, no multicast scouting and no gossip, no shared memory
    /// transport, `usrpwd` authentication with `keys`' credential, and bounded sessions and
    /// message sizes.
    ///
    /// # Errors
    /// [`LinkError`] (the settings are validated first).
    pub fn zenoh_config(
        &self,
        keys: &LinkKeys,
        inner: &ZenohEndpoints,
    ) -> Result<zenoh::Config, LinkError> {
        self.validate()?;
        let mut c = zenoh::Config::default();
        let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let set = |c: &mut zenoh::Config, k: &str, v: &str| {
            c.insert_json5(k, v)
                .map_err(|e| LinkError::Zenoh(format!("config {k} = {v}: {e}")))
        };
        set(&mut c, "mode", "\"peer\"")?;
        set(&mut c, "listen/endpoints", &json(&inner.listen))?;
        set(&mut c, "connect/endpoints", &json(&inner.connect))?;
        // Found peers would be dialled at their Zenoh locators, past the gate.
        set(&mut c, "scouting/multicast/enabled", "false")?;
        set(&mut c, "scouting/gossip/enabled", "false")?;
        // The lease (10 s by default) decides when a silent peer is dropped; a dropped link
        // to a `--peer` is re-dialled every 0.5–2 s.
        set(
            &mut c,
            "connect/retry",
            "{period_init_ms: 500, period_max_ms: 2000, period_increase_factor: 2}",
        )?;
        set_usrpwd(&mut c, &keys.user, &keys.password, &keys.credential_file)?;
        // Bounds: Zenoh reassembles nothing larger than the largest valid message (rounded
        // up to whole 64 KiB batches) and keeps few sessions. Only the gate's proven
        // connections reach its listener; its own pending bounds stay as a second guard.
        let max_message = MAX_MESSAGE_LEN.div_ceil(65_536) * 65_536;
        set(
            &mut c,
            "transport/link/rx/max_message_size",
            &max_message.to_string(),
        )?;
        set(
            &mut c,
            "transport/unicast/max_sessions",
            &MAX_SESSIONS.to_string(),
        )?;
        set(&mut c, "transport/unicast/accept_pending", "8")?;
        set(&mut c, "transport/unicast/accept_timeout", "5000")?;
        Ok(c)
    }

    /// Opens the gate and the Zenoh session behind it: a [`Dialer`] per `--peer` (Zenoh
    /// connects to it), Zenoh listening on a loopback port, then a [`Door`] per `--listen`
    /// in front of that port. Returns at once when the peer is not reachable yet (Zenoh
    /// dials again in the background). Connections the gate refuses are reported to
    /// `events`.
    ///
    /// # Errors
    /// [`LinkError`]: bad settings, a `--listen` address that cannot be listened on, or
    /// Zenoh could not open.
    pub fn open(
        &self,
        keys: &LinkKeys,
        events: &GateEvents,
    ) -> Result<(zenoh::Session, Gate), LinkError> {
        self.validate()?;
        let key = GateKey::of(keys, &self.link_name);
        let mut gate = Gate::default();
        let mut inner = ZenohEndpoints::default();
        for p in &self.peers {
            let d = Dialer::open(host_port(p).to_owned(), key.clone(), events.clone())
                .map_err(|e| LinkError::Zenoh(format!("a loopback port for --peer {p}: {e}")))?;
            inner.connect.push(format!("tcp/{}", d.local_addr()));
            gate.dialers.push(d);
        }
        let mut listen = Vec::new();
        for l in &self.listen {
            let err = |error: String| LinkError::Listen {
                value: l.clone(),
                error,
            };
            let addr = host_port(l)
                .to_socket_addrs()
                .map_err(|e| err(e.to_string()))?
                .next()
                .ok_or_else(|| err("resolves to no address".into()))?;
            listen.push((l, addr));
        }
        let backend = if listen.is_empty() {
            None
        } else {
            let b = free_loopback_port()?;
            inner.listen.push(format!("tcp/{b}"));
            Some(b)
        };
        let config = self.zenoh_config(keys, &inner)?;
        let session = zenoh::open(config)
            .wait()
            .map_err(|e| LinkError::Zenoh(e.to_string()))?;
        if let Some(backend) = backend {
            for (l, addr) in listen {
                let door = Door::open(addr, backend, key.clone(), events.clone()).map_err(|e| {
                    LinkError::Listen {
                        value: l.clone(),
                        error: e.to_string(),
                    }
                })?;
                gate.doors.push(door);
            }
        }
        Ok((session, gate))
    }
}

/// Sets Zenoh's `usrpwd` authentication: this relay opens sessions as `user`/`password` and
/// accepts only the users of `dictionary` (the credential file itself, `user:password`).
///
/// # Errors
/// [`LinkError::Zenoh`] when Zenoh refuses the values.
pub fn set_usrpwd(
    c: &mut zenoh::Config,
    user: &str,
    password: &str,
    dictionary: &Path,
) -> Result<(), LinkError> {
    let v = serde_json::json!({
        "user": user,
        "password": password,
        "dictionary_file": dictionary.display().to_string(),
    });
    c.insert_json5("transport/auth/usrpwd", &v.to_string())
        .map_err(|e| LinkError::Zenoh(format!("config transport/auth/usrpwd: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(peers: &[&str], listen: &[&str]) -> LinkArgs {
        LinkArgs {
            peers: peers.iter().map(|s| (*s).to_owned()).collect(),
            listen: listen.iter().map(|s| (*s).to_owned()).collect(),
            link_name: "foresight".into(),
            link_keys: Some("keys".into()),
        }
    }

    fn test_keys(tag: &str) -> (PathBuf, LinkKeys) {
        let d = std::env::temp_dir().join(format!("zrelay-link-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let g = crate::keys::generate(&d).unwrap();
        let k = LinkKeys::load(Some(&g.robot_pc), Side::Controller).unwrap();
        (d, k)
    }

    #[test]
    fn endpoints_must_be_tcp_addr_port_and_something_must_be_given() {
        assert_eq!(link(&[], &[]).validate(), Err(LinkError::Nowhere));
        assert!(link(&["tcp/10.0.0.2:7447"], &[]).validate().is_ok());
        assert!(link(&[], &["tcp/0.0.0.0:7447"]).validate().is_ok());
        assert!(link(&["tcp/[::1]:7447"], &[]).validate().is_ok());
        for (bad, why) in [
            ("udp/10.0.0.2:7447", "only TCP"),
            ("10.0.0.2:7447", "only TCP"),
            ("tcp/10.0.0.2", "port"),
            ("tcp/10.0.0.2:99999", "port"),
        ] {
            let e = link(&[bad], &[]).validate().unwrap_err().to_string();
            assert!(
                e.contains("--peer") && e.contains(bad) && e.contains(why),
                "{e}"
            );
        }
        let mut l = link(&["tcp/10.0.0.2:7447"], &[]);
        l.link_name = "robot 1".into();
        assert!(matches!(l.validate(), Err(LinkError::LinkName(_))));
        // No keys: refused, saying how to make them.
        let mut l = link(&["tcp/10.0.0.2:7447"], &[]);
        l.link_keys = None;
        let e = l.validate().unwrap_err().to_string();
        assert!(
            e.contains("--link-keys") && e.contains("zenoh-relay keygen"),
            "{e}"
        );
    }

    #[test]
    fn the_zenoh_config_listens_and_connects_only_where_told_and_does_not_scout() {
        let (dir, keys) = test_keys("cfg");
        let inner = ZenohEndpoints {
            listen: vec!["tcp/127.0.0.1:40001".into()],
            connect: vec!["tcp/127.0.0.1:40002".into()],
        };
        let c = link(&["tcp/10.0.0.2:7447"], &["tcp/10.0.0.1:7447"])
            .zenoh_config(&keys, &inner)
            .unwrap();
        let get = |c: &zenoh::Config, k: &str| -> serde_json::Value {
            serde_json::from_str(&c.get_json(k).unwrap()).unwrap()
        };
        assert_eq!(get(&c, "mode"), "peer");
        // Zenoh only on the gate's loopback ports; nothing found by scouting or gossip.
        assert_eq!(
            get(&c, "listen/endpoints"),
            serde_json::json!(["tcp/127.0.0.1:40001"])
        );
        assert_eq!(
            get(&c, "connect/endpoints"),
            serde_json::json!(["tcp/127.0.0.1:40002"])
        );
        assert_eq!(get(&c, "scouting/multicast/enabled"), false);
        assert_eq!(get(&c, "scouting/gossip/enabled"), false);
        assert_eq!(host_port("tcp/[::1]:7447"), "[::1]:7447");
        assert_eq!(host_port("tcp/10.0.0.2:7447#iface=eth0"), "10.0.0.2:7447");
        // Authenticated and bounded.
        assert_eq!(get(&c, "transport/auth/usrpwd/user"), keys.user.as_str());
        assert_eq!(
            get(&c, "transport/auth/usrpwd/dictionary_file"),
            keys.credential_file.display().to_string()
        );
        let max = get(&c, "transport/link/rx/max_message_size")
            .as_u64()
            .unwrap();
        assert!(
            max as usize >= MAX_MESSAGE_LEN && max < 2 * MAX_MESSAGE_LEN as u64,
            "{max}"
        );
        assert_eq!(get(&c, "transport/unicast/max_sessions"), MAX_SESSIONS);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn flags_round_trip_through_the_command_line() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            link: LinkArgs,
        }
        let mut l = link(
            &["tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"],
            &["tcp/0.0.0.0:7447"],
        );
        l.link_name = "arm-2".into();
        let argv = std::iter::once("x".to_owned()).chain(l.to_args());
        assert_eq!(Cli::parse_from(argv).link, l);
        assert_eq!(l.key(Channel::Policy), "foresight/arm-2/policy");
    }
}
