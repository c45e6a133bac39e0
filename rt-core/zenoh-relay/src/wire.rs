//! What one relay sends the other over Zenoh: a 56-byte header, the payload, and an Ed25519
//! signature of both.
//!
//! The header names the channel (which service), carries the payload's schema version and
//! length, the byte order, the sending relay's instance, a sequence number and the request
//! the message is about ([`RequestRef`]: a progress message names the request it answers, a
//! policy the request it was trained for). Service payloads are the `repr(C)` bytes of the
//! iceoryx2 message ([`message_bytes`]) and are validated again on arrival
//! ([`message_from_bytes`]): a message from the network is untrusted input, and one of another
//! schema version is refused as at a local open. Control messages ([`Hello`], [`PolicyAck`])
//! are JSON.
//!
//! **Signature.** The last [`SIGNATURE_LEN`] bytes are the sender's Ed25519 signature
//! (`ed25519-dalek`, verified with `verify_strict`) of a domain string naming the wire
//! version and the link (`foresight zenoh-relay v2`, the link name), then header and payload:
//! channel, schema version, sender, sequence, the request it is bound to and every payload
//! byte are covered; a message of another link, or one changed in flight, is refused
//! ([`WireError::BadSignature`]). The receiver knows one public key, the other host's
//! ([`crate::keys`]).
//!
//! **Sequence.** Each relay numbers what it sends with one counter that never goes down:
//! the wall clock in ns, or one more than the last number it sent (kept across its restarts),
//! whichever is larger. The receiver accepts a message only above the last one it accepted on
//! that channel, and remembers that mark across its own restarts
//! ([`crate::keys::LinkState`]): a recorded message played back is refused (`replay`).
//!
//! **Size.** A message is never longer than [`max_message_len`] of its channel (a policy
//! blob's size + header + signature for a policy); a longer one is refused before it is
//! read (`oversize`).

use ed25519_dalek::{Signature, Signer as _, SigningKey, VerifyingKey};
use serde::{Deserialize, Serialize};
use shm_schemas::services::{MessageBytesError, message_bytes, message_from_bytes};
use shm_schemas::{PolicyBlob, RetrainProgress, RetrainRequest, ShmMessage};

/// First bytes of every message.
pub const MAGIC: [u8; 4] = *b"FSZ1";
/// Version of this header layout (2: request binding and signature).
pub const WIRE_VERSION: u16 = 2;
/// Written in native order; read back as anything else means the peer's byte order differs.
const BYTE_ORDER_MARK: u16 = 0x0102;
/// Header size (bytes).
pub const HEADER_LEN: usize = 56;
/// Ed25519 signature size (bytes), after the payload.
pub const SIGNATURE_LEN: usize = 64;
/// Version of the JSON control messages.
pub const CONTROL_VERSION: u32 = 2;
/// Longest JSON control message (bytes).
pub const MAX_CONTROL_LEN: usize = 1024;
/// What is signed before the header: the wire version's name.
const DOMAIN: &[u8] = b"foresight zenoh-relay v2\0";

/// What a message carries. The discriminant is its byte on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
pub enum Channel {
    /// [`RetrainRequest`], controller → learner host.
    RetrainRequest = 1,
    /// [`RetrainProgress`], learner host → controller.
    RetrainProgress = 2,
    /// [`PolicyBlob`], learner host → controller.
    Policy = 3,
    /// [`PolicyAck`], controller → learner host.
    PolicyAck = 4,
    /// [`Hello`], both ways, once a second.
    Hello = 5,
}

impl Channel {
    /// Every channel.
    pub const ALL: [Channel; 5] = [
        Self::RetrainRequest,
        Self::RetrainProgress,
        Self::Policy,
        Self::PolicyAck,
        Self::Hello,
    ];

    /// The last part of the Zenoh key (`foresight/<link>/<this>`).
    pub fn key_suffix(self) -> &'static str {
        match self {
            Self::RetrainRequest => "retrain_request",
            Self::RetrainProgress => "retrain_progress",
            Self::Policy => "policy",
            Self::PolicyAck => "policy_ack",
            Self::Hello => "hello",
        }
    }

    /// The schema version this build sends and accepts on the channel.
    pub fn schema_version(self) -> u32 {
        match self {
            Self::RetrainRequest => RetrainRequest::SCHEMA_VERSION,
            Self::RetrainProgress => RetrainProgress::SCHEMA_VERSION,
            Self::Policy => <PolicyBlob as ShmMessage>::SCHEMA_VERSION,
            Self::PolicyAck | Self::Hello => CONTROL_VERSION,
        }
    }

    fn from_byte(b: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|c| *c as u8 == b)
    }
}

/// The longest valid message on `channel`: header + the payload type's size (or
/// [`MAX_CONTROL_LEN`] for JSON) + signature. Zenoh is told the largest of them.
pub const fn max_message_len(channel: Channel) -> usize {
    let payload = match channel {
        Channel::RetrainRequest => size_of::<RetrainRequest>(),
        Channel::RetrainProgress => size_of::<RetrainProgress>(),
        Channel::Policy => size_of::<PolicyBlob>(),
        Channel::PolicyAck | Channel::Hello => MAX_CONTROL_LEN,
    };
    HEADER_LEN + payload + SIGNATURE_LEN
}

/// The longest valid message of any channel.
pub const MAX_MESSAGE_LEN: usize = max_message_len(Channel::Policy);

/// The retrain request a message is about: rt-core's `request_id` and `request_time_ns`
/// (both 0: none). Together they tell a request from an earlier one with the same id.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct RequestRef {
    /// `RetrainRequest::request_id`.
    pub request_id: u64,
    /// `RetrainRequest::request_time_ns`.
    pub request_time_ns: u64,
}

impl RequestRef {
    /// The identity of `r`.
    pub fn of(r: &RetrainRequest) -> Self {
        Self {
            request_id: r.request_id,
            request_time_ns: r.request_time_ns,
        }
    }
}

/// The fixed part of a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// What the payload is.
    pub channel: Channel,
    /// The payload's schema version.
    pub schema_version: u32,
    /// Random per relay process: tells a restarted peer from a repeat.
    pub sender_instance: u64,
    /// The sender's counter (never goes down, see the module docs).
    pub sequence: u64,
    /// The request the message is about (progress, policy; zero for the others).
    pub request: RequestRef,
}

impl Header {
    /// A header of this build's schema version for `channel`, bound to no request.
    pub fn new(channel: Channel, sender_instance: u64, sequence: u64) -> Self {
        Self {
            channel,
            schema_version: channel.schema_version(),
            sender_instance,
            sequence,
            request: RequestRef::default(),
        }
    }

    /// The same header bound to request `r`.
    #[must_use]
    pub fn bound_to(mut self, r: RequestRef) -> Self {
        self.request = r;
        self
    }
}

/// Signs what a relay sends, with its host's key, for one link.
#[derive(Clone)]
pub struct Signer {
    key: SigningKey,
    domain: Vec<u8>,
}

/// Verifies what a relay receives against the other host's public key, for one link.
#[derive(Clone)]
pub struct Verifier {
    key: VerifyingKey,
    domain: Vec<u8>,
}

fn domain(link_name: &str) -> Vec<u8> {
    let mut d = DOMAIN.to_vec();
    d.extend_from_slice(link_name.as_bytes());
    d.push(0);
    d
}

impl Signer {
    /// This host's key on link `link_name`.
    pub fn new(key: SigningKey, link_name: &str) -> Self {
        Self {
            key,
            domain: domain(link_name),
        }
    }

    /// The public key that verifies this signer.
    pub fn verifying_key(&self) -> VerifyingKey {
        self.key.verifying_key()
    }

    fn sign(&self, signed: &[u8]) -> Signature {
        let mut m = Vec::with_capacity(self.domain.len() + signed.len());
        m.extend_from_slice(&self.domain);
        m.extend_from_slice(signed);
        self.key.sign(&m)
    }
}

impl Verifier {
    /// The other host's public key on link `link_name`.
    pub fn new(key: VerifyingKey, link_name: &str) -> Self {
        Self {
            key,
            domain: domain(link_name),
        }
    }

    fn verify(&self, signed: &[u8], signature: &[u8]) -> bool {
        let Ok(sig) = Signature::from_slice(signature) else {
            return false;
        };
        let mut m = Vec::with_capacity(self.domain.len() + signed.len());
        m.extend_from_slice(&self.domain);
        m.extend_from_slice(signed);
        self.key.verify_strict(&m, &sig).is_ok()
    }
}

/// Why received bytes are not a message of this build. Every variant names what was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// Fewer bytes than a header and a signature.
    #[error(
        "message of {0} bytes is shorter than the {HEADER_LEN}-byte header and the {SIGNATURE_LEN}-byte signature"
    )]
    TooShort(usize),
    /// Longer than any valid message of its channel: not read.
    #[error(
        "message of {got} bytes on {channel:?} is longer than the largest valid one ({max} bytes); dropped unread"
    )]
    Oversize {
        /// The channel (from the key).
        channel: Channel,
        /// Its length.
        got: usize,
        /// The limit.
        max: usize,
    },
    /// Not a Foresight relay message.
    #[error("header.magic is {0:?}, not \"FSZ1\": not a Foresight relay message")]
    Magic([u8; 4]),
    /// Another header layout.
    #[error("header.wire_version is {got}, this relay speaks {WIRE_VERSION}")]
    WireVersion {
        /// What arrived.
        got: u16,
    },
    /// The sender's byte order differs (payloads are native-endian `repr(C)`).
    #[error("header.byte_order: the peer's byte order differs from this host's")]
    ByteOrder,
    /// A channel byte this build does not know.
    #[error("header.channel {0} is unknown")]
    UnknownChannel(u8),
    /// The message arrived on the key of another channel.
    #[error("header.channel is {got:?} on the key of {expected:?}")]
    WrongChannel {
        /// The header's channel.
        got: Channel,
        /// The key's channel.
        expected: Channel,
    },
    /// The payload length in the header does not match the bytes that follow.
    #[error("header.payload_len says {said} bytes, {got} follow before the signature")]
    PayloadLen {
        /// The header's length.
        said: usize,
        /// Bytes after the header.
        got: usize,
    },
    /// Reserved header bytes are not zero.
    #[error("header.reserved is not zero")]
    Reserved,
    /// The signature is not the other host's over this header and payload (a sender without
    /// the key, a message changed in flight, or one of another link).
    #[error(
        "signature of {channel:?} (sequence {sequence}) does not verify with the other host's public key: not sent by it, changed in flight, or meant for another link"
    )]
    BadSignature {
        /// The channel.
        channel: Channel,
        /// The header's sequence.
        sequence: u64,
    },
    /// The peer was built against another schema of the payload: refused, as a local open
    /// of the iceoryx2 service would be.
    #[error(
        "header.schema_version of {channel:?} is {got}, this build has {expected}: the peer runs another build; refused"
    )]
    SchemaMismatch {
        /// The channel.
        channel: Channel,
        /// The peer's version.
        got: u32,
        /// This build's.
        expected: u32,
    },
    /// The payload is not a valid message (length, a field out of range, a bad checksum).
    #[error("payload")]
    Payload(#[from] MessageBytesError),
    /// A control message's JSON is malformed.
    #[error("payload of {channel:?}: {error}")]
    Control {
        /// The channel.
        channel: Channel,
        /// serde_json's message (names the field).
        error: String,
    },
}

impl WireError {
    /// A short, stable name for counting rejections by kind.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::SchemaMismatch { .. } => "schema_mismatch",
            Self::Payload(_) | Self::Control { .. } => "invalid_payload",
            Self::Oversize { .. } => "oversize",
            Self::BadSignature { .. } => "bad_signature",
            _ => "malformed",
        }
    }
}

/// A signed message: header + payload + signature.
pub fn encode(header: &Header, payload: &[u8], signer: &Signer) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len() + SIGNATURE_LEN);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&WIRE_VERSION.to_le_bytes());
    out.extend_from_slice(&BYTE_ORDER_MARK.to_ne_bytes());
    out.push(header.channel as u8);
    out.extend_from_slice(&[0; 3]);
    out.extend_from_slice(&header.schema_version.to_le_bytes());
    let len = u32::try_from(payload.len()).unwrap_or(u32::MAX);
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(&header.sender_instance.to_le_bytes());
    out.extend_from_slice(&header.sequence.to_le_bytes());
    out.extend_from_slice(&header.request.request_id.to_le_bytes());
    out.extend_from_slice(&header.request.request_time_ns.to_le_bytes());
    out.extend_from_slice(&[0; 4]);
    debug_assert_eq!(out.len(), HEADER_LEN);
    out.extend_from_slice(payload);
    let sig = signer.sign(&out);
    out.extend_from_slice(&sig.to_bytes());
    out
}

fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn le_u32(b: &[u8], at: usize) -> u32 {
    let mut a = [0; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}
fn le_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// Refuses, without reading it, a message longer than any valid one of `channel`.
///
/// # Errors
/// [`WireError::Oversize`].
pub fn check_size(len: usize, channel: Channel) -> Result<(), WireError> {
    let max = max_message_len(channel);
    if len > max {
        return Err(WireError::Oversize {
            channel,
            got: len,
            max,
        });
    }
    Ok(())
}

/// Splits a message into its checked header and payload; `expected` is the channel of the
/// key it arrived on. The size is checked first, then the header's framing, then the
/// signature (with `verifier`), then the schema version against this build's.
///
/// # Errors
/// [`WireError`] naming the header field (or the signature).
pub fn decode<'a>(
    bytes: &'a [u8],
    expected: Channel,
    verifier: &Verifier,
) -> Result<(Header, &'a [u8]), WireError> {
    check_size(bytes.len(), expected)?;
    if bytes.len() < HEADER_LEN + SIGNATURE_LEN {
        return Err(WireError::TooShort(bytes.len()));
    }
    let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if magic != MAGIC {
        return Err(WireError::Magic(magic));
    }
    let version = le_u16(bytes, 4);
    if version != WIRE_VERSION {
        return Err(WireError::WireVersion { got: version });
    }
    if u16::from_ne_bytes([bytes[6], bytes[7]]) != BYTE_ORDER_MARK {
        return Err(WireError::ByteOrder);
    }
    let channel = Channel::from_byte(bytes[8]).ok_or(WireError::UnknownChannel(bytes[8]))?;
    if channel != expected {
        return Err(WireError::WrongChannel {
            got: channel,
            expected,
        });
    }
    let said = le_u32(bytes, 16) as usize;
    let body_len = bytes.len() - HEADER_LEN - SIGNATURE_LEN;
    if said != body_len {
        return Err(WireError::PayloadLen {
            said,
            got: body_len,
        });
    }
    let sequence = le_u64(bytes, 28);
    let (signed, signature) = bytes.split_at(HEADER_LEN + body_len);
    if !verifier.verify(signed, signature) {
        return Err(WireError::BadSignature { channel, sequence });
    }
    if bytes[9..12] != [0; 3] || bytes[52..56] != [0; 4] {
        return Err(WireError::Reserved);
    }
    let schema_version = le_u32(bytes, 12);
    if schema_version != channel.schema_version() {
        return Err(WireError::SchemaMismatch {
            channel,
            got: schema_version,
            expected: channel.schema_version(),
        });
    }
    let header = Header {
        channel,
        schema_version,
        sender_instance: le_u64(bytes, 20),
        sequence,
        request: RequestRef {
            request_id: le_u64(bytes, 36),
            request_time_ns: le_u64(bytes, 44),
        },
    };
    Ok((header, &signed[HEADER_LEN..]))
}

/// A signed service message.
pub fn encode_message<T: ShmMessage>(header: &Header, message: &T, signer: &Signer) -> Vec<u8> {
    encode(header, message_bytes(message), signer)
}

/// A service message read from the network, its signature verified and its payload
/// validated.
///
/// # Errors
/// [`WireError`]: the size, the header, the signature, the schema version, the length or a
/// field of the payload.
pub fn decode_message<T: ShmMessage>(
    bytes: &[u8],
    channel: Channel,
    verifier: &Verifier,
) -> Result<(Header, Box<T>), WireError> {
    let (header, payload) = decode(bytes, channel, verifier)?;
    Ok((header, message_payload::<T>(payload)?))
}

/// The payload of a service message that [`decode`] checked, validated.
///
/// # Errors
/// [`WireError::Payload`]: its length or a field.
pub fn message_payload<T: ShmMessage>(payload: &[u8]) -> Result<Box<T>, WireError> {
    Ok(message_from_bytes::<T>(payload)?)
}

/// Which end of the link a relay is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Side {
    /// On the robot PC, beside rt-core.
    Controller,
    /// On the learner host, beside `learner serve`.
    Learner,
}

/// Sent once a second by each relay: who and where it is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hello {
    /// The sender's end.
    pub side: Side,
    /// The sender's host name.
    pub host: String,
    /// The sender's process id.
    pub pid: u32,
    /// The relay's version (the workspace version).
    pub relay_version: String,
    /// Schema versions the sender speaks: retrain request, retrain progress, policy blob.
    pub schema_versions: [u32; 3],
    /// On the learner host: the hash of the task it trains for (requests carry the robot's).
    #[serde(default)]
    pub task_hash: Option<u64>,
}

/// "This policy arrived": stops the learner host's relay re-sending it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyAck {
    /// `PolicyBlob::policy_id` received.
    pub policy_id: u64,
    /// Its checksum.
    pub checksum: u64,
}

/// This build's schema versions, as [`Hello::schema_versions`] carries them.
pub fn schema_versions() -> [u32; 3] {
    [
        Channel::RetrainRequest.schema_version(),
        Channel::RetrainProgress.schema_version(),
        Channel::Policy.schema_version(),
    ]
}

/// A signed JSON control message.
pub fn encode_control<T: Serialize>(header: &Header, message: &T, signer: &Signer) -> Vec<u8> {
    let json = serde_json::to_vec(message).unwrap_or_default();
    encode(header, &json, signer)
}

/// A JSON control message read from the network, its signature verified.
///
/// # Errors
/// [`WireError`]: the size, the header, the signature, or JSON that is not the message (the
/// error names the field).
pub fn decode_control<T: for<'de> Deserialize<'de>>(
    bytes: &[u8],
    channel: Channel,
    verifier: &Verifier,
) -> Result<(Header, T), WireError> {
    let (header, payload) = decode(bytes, channel, verifier)?;
    Ok((header, control_payload(payload, channel)?))
}

/// The JSON payload of a control message that [`decode`] checked.
///
/// # Errors
/// [`WireError::Control`] naming the field.
pub fn control_payload<T: for<'de> Deserialize<'de>>(
    payload: &[u8],
    channel: Channel,
) -> Result<T, WireError> {
    serde_json::from_slice(payload).map_err(|e| WireError::Control {
        channel,
        error: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::error_chain::error_chain;
    use shm_schemas::{PolicyBlobBuilder, RetrainPhase, SchemaError};

    fn keys() -> (Signer, Verifier) {
        let k = SigningKey::from_bytes(&[7; 32]);
        let v = Verifier::new(k.verifying_key(), "foresight");
        (Signer::new(k, "foresight"), v)
    }

    fn progress() -> RetrainProgress {
        RetrainProgress {
            request_id: 7,
            steps_done: 1000,
            success_rate: 0.5,
            wall_time_s: 1.5,
            phase: RetrainPhase::Training as u8,
            ..RetrainProgress::default()
        }
    }

    fn bound(seq: u64) -> Header {
        Header::new(Channel::RetrainProgress, 0xabc, seq).bound_to(RequestRef {
            request_id: 7,
            request_time_ns: 99,
        })
    }

    #[test]
    fn a_message_round_trips_with_its_header_and_request_binding() {
        let (s, v) = keys();
        let bytes = encode_message(&bound(42), &progress(), &s);
        assert_eq!(
            bytes.len(),
            HEADER_LEN + size_of::<RetrainProgress>() + SIGNATURE_LEN
        );
        let (h, p) =
            decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress, &v).unwrap();
        assert_eq!(h, bound(42));
        assert_eq!(h.request.request_time_ns, 99);
        assert_eq!(*p, progress());
    }

    #[test]
    fn a_message_signed_by_another_key_for_another_link_or_changed_in_flight_is_refused() {
        let (s, v) = keys();
        let good = encode_message(&bound(1), &progress(), &s);
        // A stranger's key.
        let stranger = Signer::new(SigningKey::from_bytes(&[9; 32]), "foresight");
        let forged = encode_message(&bound(1), &progress(), &stranger);
        // The right key, another link.
        let other_link = Signer::new(SigningKey::from_bytes(&[7; 32]), "robot-2");
        let replayed_elsewhere = encode_message(&bound(1), &progress(), &other_link);
        // Each signed header field and a payload byte changed after signing.
        let mut tampered = Vec::new();
        for at in [20, 28, 36, 44, HEADER_LEN + 8] {
            let mut b = good.clone();
            b[at] ^= 1;
            tampered.push(b);
        }
        // The signature itself.
        let mut b = good.clone();
        let n = b.len();
        b[n - 1] ^= 1;
        tampered.push(b);
        for bytes in [forged, replayed_elsewhere].into_iter().chain(tampered) {
            let e = decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress, &v)
                .unwrap_err();
            assert!(matches!(e, WireError::BadSignature { .. }), "{e:?}");
            assert_eq!(e.kind(), "bad_signature");
            assert!(e.to_string().contains("signature"), "{e}");
        }
        assert!(decode_message::<RetrainProgress>(&good, Channel::RetrainProgress, &v).is_ok());
    }

    #[test]
    fn a_message_longer_than_the_largest_valid_one_is_refused_unread() {
        let (s, v) = keys();
        assert_eq!(
            MAX_MESSAGE_LEN,
            HEADER_LEN + size_of::<PolicyBlob>() + SIGNATURE_LEN
        );
        let big = encode(&Header::new(Channel::Hello, 1, 1), &[b' '; 2000], &s);
        let e = decode_control::<Hello>(&big, Channel::Hello, &v).unwrap_err();
        assert!(matches!(e, WireError::Oversize { .. }), "{e:?}");
        assert_eq!(e.kind(), "oversize");
        let e = decode(&vec![0u8; MAX_MESSAGE_LEN + 1], Channel::Policy, &v).unwrap_err();
        assert_eq!(e.kind(), "oversize");
    }

    #[test]
    fn a_policy_blob_round_trips_and_a_flipped_weight_is_refused() {
        let (s, v) = keys();
        let builder = PolicyBlobBuilder::random(9, 0x77, 17, &[64, 64], 3, 1);
        let mut blob = PolicyBlob::new_boxed();
        builder.write_into(&mut blob).unwrap();
        let bytes = encode_message(&Header::new(Channel::Policy, 1, 1), &*blob, &s);
        assert!(bytes.len() <= MAX_MESSAGE_LEN);
        let (_, back) = decode_message::<PolicyBlob>(&bytes, Channel::Policy, &v).unwrap();
        assert_eq!(back.policy_id, 9);
        assert_eq!(back.as_bytes(), blob.as_bytes());
        // One weight byte changed by the signer (a bug on the learner host): the checksum.
        let mut raw = message_bytes(&*blob).to_vec();
        raw[360 + 8] ^= 0x40;
        let bytes = encode(&Header::new(Channel::Policy, 1, 2), &raw, &s);
        let e = decode_message::<PolicyBlob>(&bytes, Channel::Policy, &v).unwrap_err();
        assert!(
            matches!(
                e,
                WireError::Payload(MessageBytesError::Invalid {
                    error: SchemaError::ChecksumMismatch { .. },
                    ..
                })
            ),
            "{e:?}"
        );
    }

    #[test]
    fn another_schema_version_is_refused_naming_the_channel_and_both_versions() {
        let (s, v) = keys();
        let mut h = bound(1);
        h.schema_version = 99;
        let bytes = encode_message(&h, &progress(), &s);
        let e =
            decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress, &v).unwrap_err();
        assert_eq!(
            e,
            WireError::SchemaMismatch {
                channel: Channel::RetrainProgress,
                got: 99,
                expected: RetrainProgress::SCHEMA_VERSION
            }
        );
        assert_eq!(e.kind(), "schema_mismatch");
        assert!(e.to_string().contains("schema_version"), "{e}");
    }

    #[test]
    fn malformed_headers_and_payloads_are_refused_naming_the_field() {
        let (s, v) = keys();
        let good = encode_message(&bound(1), &progress(), &s);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (good[..10].to_vec(), "shorter than"),
            (
                {
                    let mut b = good.clone();
                    b[0] = b'X';
                    b
                },
                "header.magic",
            ),
            (
                {
                    let mut b = good.clone();
                    b[4] = 9;
                    b
                },
                "header.wire_version",
            ),
            (
                {
                    let mut b = good.clone();
                    b.swap(6, 7);
                    b
                },
                "header.byte_order",
            ),
            (
                {
                    let mut b = good.clone();
                    b[8] = 200;
                    b
                },
                "header.channel 200",
            ),
            (
                {
                    let mut b = good.clone();
                    b[16] ^= 1;
                    b
                },
                "header.payload_len",
            ),
            (
                {
                    let mut p = progress();
                    p.success_rate = 2.0;
                    encode_message(&bound(1), &p, &s)
                },
                "success_rate",
            ),
            (
                {
                    let mut p = progress();
                    p.phase = 77;
                    encode_message(&bound(1), &p, &s)
                },
                "phase",
            ),
        ];
        for (bytes, field) in cases {
            let e = error_chain(
                &decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress, &v)
                    .unwrap_err(),
            )
            .to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
        // The right header on the wrong key.
        let e = decode_message::<RetrainProgress>(&good, Channel::RetrainRequest, &v).unwrap_err();
        assert!(matches!(e, WireError::WrongChannel { .. }), "{e:?}");
        // A payload of the wrong size for its type (a schema change that kept the version).
        let short = encode(&bound(1), &[0u8; 40], &s);
        let e =
            decode_message::<RetrainProgress>(&short, Channel::RetrainProgress, &v).unwrap_err();
        assert!(error_chain(&e).to_string().contains("40 bytes"), "{e}");
    }

    #[test]
    fn control_messages_round_trip_and_unknown_fields_are_refused() {
        let (s, v) = keys();
        let hello = Hello {
            side: Side::Learner,
            host: "gpu-box".into(),
            pid: 12,
            relay_version: "0.1.0".into(),
            schema_versions: schema_versions(),
            task_hash: Some(0xfeed),
        };
        let bytes = encode_control(&Header::new(Channel::Hello, 5, 3), &hello, &s);
        let (h, back): (Header, Hello) = decode_control(&bytes, Channel::Hello, &v).unwrap();
        assert_eq!((h.sender_instance, h.sequence), (5, 3));
        assert_eq!(back, hello);
        let bad = encode(
            &Header::new(Channel::PolicyAck, 1, 1),
            br#"{"policy_id": 1, "checksum": 2, "extra": 3}"#,
            &s,
        );
        let e = decode_control::<PolicyAck>(&bad, Channel::PolicyAck, &v).unwrap_err();
        assert!(e.to_string().contains("extra"), "{e}");
    }
}
