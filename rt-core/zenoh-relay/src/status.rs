//! What a relay saw, as a JSON file rewritten atomically while it runs (`--status FILE`):
//! the other host, link losses and their length, each retrain request's timings, counts of
//! messages sent, received, re-sent, dropped as repeats and rejected. The launcher reads the
//! controller side's file into the run report ("retrained on gpu-box in 4.2 s, …").

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::wire::Side;

/// Seconds since the Unix epoch (the launcher's run timeline uses the same clock).
pub fn unix_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The other relay, as its hellos describe it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PeerStatus {
    /// Its host name.
    pub host: String,
    /// Its process id.
    pub pid: u32,
    /// Its version.
    pub relay_version: String,
    /// Whether a hello arrived within the last [`crate::relay::PEER_SILENCE`].
    pub connected: bool,
    /// When its last hello arrived (Unix s).
    pub last_seen_unix_s: f64,
}

/// The link's authentication, as this relay uses it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AuthStatus {
    /// The keys folder.
    pub keys_dir: String,
    /// This host's public key (fingerprint).
    pub own_key: String,
    /// The other host's public key: the only signer accepted.
    pub peer_key: String,
    /// The Zenoh `usrpwd` user of the link credential.
    pub user: String,
}

/// One retrain request as the controller's relay carried it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RequestStatus {
    /// `RetrainRequest::request_id`.
    pub request_id: u64,
    /// When rt-core's request reached the relay (Unix s).
    pub submitted_unix_s: f64,
    /// Times sent over the link (1 + re-sends).
    pub sends: u64,
    /// When the learner host's first progress for it arrived (Unix s).
    pub first_progress_unix_s: Option<f64>,
    /// When its final answer arrived (Unix s).
    pub answered_unix_s: Option<f64>,
    /// The final phase (`published`, `budget_exhausted`, `infeasible`).
    pub phase: Option<String>,
    /// The learner's own wall time for it (s), from the final progress.
    pub remote_wall_time_s: Option<f64>,
    /// The policy published for it.
    pub policy_id: Option<u64>,
    /// When that policy reached rt-core's side (Unix s).
    pub policy_received_unix_s: Option<f64>,
    /// Superseded by a newer request before its answer.
    pub superseded: bool,
}

/// The status file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RelayStatus {
    /// This relay's end (`controller` or `learner`).
    pub side: Option<Side>,
    /// This host's name.
    pub host: String,
    /// The link name.
    pub link_name: String,
    /// The iceoryx2 service prefix on this host.
    pub prefix: String,
    /// `--peer` endpoints.
    pub peers: Vec<String>,
    /// `--listen` endpoints.
    pub listen: Vec<String>,
    /// When the relay started (Unix s).
    pub started_unix_s: f64,
    /// The other relay.
    pub peer: Option<PeerStatus>,
    /// How often the other relay fell silent after having been heard.
    pub link_losses: u64,
    /// Total time it was silent after having been heard (s), the current silence included.
    pub link_down_s: f64,
    /// Messages sent over the link, by channel.
    pub sent: BTreeMap<String, u64>,
    /// Messages received and accepted, by channel.
    pub received: BTreeMap<String, u64>,
    /// Messages refused, by reason: `bad_signature` (not signed by the other host's key),
    /// `replay` (a sequence not above the last accepted), `oversize`, `flood` (dropped
    /// because the channel's queue was full), `schema_mismatch`, `invalid_payload`,
    /// `malformed`, `task_mismatch`, `state_not_saved`.
    pub rejected: BTreeMap<String, u64>,
    /// The last refusal, in words.
    pub last_rejection: Option<String>,
    /// Connections the gate ([`crate::gate`]) refused or closed, by reason:
    /// `connector_unauthenticated` (a connection to a `--listen` address whose proof did not
    /// verify with the other host's public key, that is not a relay, or that hung up during
    /// the handshake), `handshake_timeout` (one that did not finish the handshake in
    /// time: a socket that never spoke), `pending_evicted` (the oldest unfinished one, closed
    /// for a newer one while the door was full), `listener_unauthenticated` (a `--peer` whose
    /// proof did not verify with the other host's public key, or that is not a relay),
    /// `listener_no_handshake` (a `--peer` that did not finish the handshake in time or hung
    /// up during it).
    pub refused_connections: BTreeMap<String, u64>,
    /// The last connection refusal, in words.
    pub last_connection_refusal: Option<String>,
    /// Re-sends of unanswered requests / unacknowledged policies.
    pub resends: u64,
    /// Repeats dropped (requests, policies, progress).
    pub duplicates_dropped: u64,
    /// Genuine but late messages dropped: progress or a policy bound to another request than
    /// the one in flight (an older one, or an earlier rt-core's with the same id).
    pub stale_dropped: u64,
    /// Who this relay trusts (keys by fingerprint).
    pub auth: Option<AuthStatus>,
    /// Retrain requests (controller side; newest last).
    pub requests: Vec<RequestStatus>,
    /// The learner host trains for another task than the robot's (its policies would be
    /// refused by rt-core, so it refuses the requests): what differs, in words.
    pub task_mismatch: Option<String>,
}

impl RelayStatus {
    /// Writes the file atomically (a temporary beside it, then a rename).
    ///
    /// # Errors
    /// The file system's.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let json = serde_json::to_vec_pretty(self).map_err(std::io::Error::other)?;
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, json)?;
        std::fs::rename(&tmp, path)
    }

    /// Reads a status file.
    ///
    /// # Errors
    /// Missing file or malformed JSON (the message says which).
    pub fn read(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Counts a channel's message in `sent` or `received`.
    pub fn count(map: &mut BTreeMap<String, u64>, key: &str) {
        *map.entry(key.to_owned()).or_default() += 1;
    }
}

/// The host name of this machine (`/proc/sys/kernel/hostname`, else `HOSTNAME`, else
/// `unknown`).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_owned())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_file_round_trips_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("zrelay-status-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("relay.json");
        let mut s = RelayStatus {
            side: Some(Side::Controller),
            host: "robot-pc".into(),
            link_losses: 1,
            link_down_s: 5.2,
            ..RelayStatus::default()
        };
        RelayStatus::count(&mut s.sent, "retrain_request");
        RelayStatus::count(&mut s.sent, "retrain_request");
        s.requests.push(RequestStatus {
            request_id: 1,
            sends: 2,
            remote_wall_time_s: Some(3.5),
            ..RequestStatus::default()
        });
        s.write(&path).unwrap();
        assert_eq!(RelayStatus::read(&path).unwrap(), s);
        assert!(!path.with_extension("json.tmp").exists());
        std::fs::write(&path, "{\"link_losses\": \"x\"}").unwrap();
        let e = RelayStatus::read(&path).unwrap_err();
        assert!(
            e.contains("relay.json") && e.contains("invalid type"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
