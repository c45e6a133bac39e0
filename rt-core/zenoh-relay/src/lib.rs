//! `zenoh-relay`: the learner's low-rate services between two hosts.
//!
//! iceoryx2 is shared memory and ends at the host. When the learner runs on another
//! machine (a GPU box on the LAN), one relay beside rt-core and one beside `learner serve`
//! carry [`shm_schemas::RetrainRequest`] (controller → learner host),
//! [`shm_schemas::RetrainProgress`] and [`shm_schemas::PolicyBlob`] (back) over Zenoh, and
//! nothing else: the real-time path never leaves the robot PC.
//!
//! - [`wire`]: the message format (header with schema version and the request it is about,
//!   payload validated again, an Ed25519 signature of both).
//! - [`keys`]: the link credential (Zenoh `usrpwd`) and each host's signing key;
//!   `zenoh-relay keygen`; the replay state.
//! - [`reliable`]: re-send until answered, drop repeats.
//! - [`gate`]: the front door of every connection between the relays (mutual
//!   challenge–response on the two hosts' keys; bounded, timed-out pending connections).
//! - [`link`]: where a relay listens and connects.
//! - [`relay`]: the loop.
//! - [`status`]: the status file the launcher's report reads.
//! - [`learner_host`]: `zenoh-relay learner-host`, the relay plus a supervised `learner serve`.
//!
//! **Trust.** A connection between the relays carries Zenoh only after *each* end proved to
//! the other that it holds its host's signing key ([`gate`]); inside, Zenoh accepts a session
//! only from a holder of the link credential, and the relay a message only when it is signed
//! by the other host's key, with a sequence above the last one accepted on its channel (kept
//! across restarts) and — for progress and policies — bound to the request in flight. There is no unauthenticated mode: without keys a relay refuses
//! to start, naming what is missing. What a relay must still trust: the other host itself
//! (a learner host with its key can send any *valid* policy; rt-core's lookahead and shield
//! still gate every motion), and whoever can read the keys folders. The link is not
//! encrypted (retrain requests describe the scene; nothing secret crosses).
//!
//! iceoryx2's own Zenoh tunnel (`iceoryx2-tunnel-zenoh`) exists only up to 0.8.1 on
//! crates.io while the workspace is on iceoryx2 0.10.0, so this small relay on the `zenoh`
//! crate stands in its place.

pub mod gate;
pub mod keys;
pub mod learner_host;
pub mod link;
pub mod relay;
pub mod reliable;
pub mod status;
pub mod wire;
