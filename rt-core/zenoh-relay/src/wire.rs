//! What one relay sends the other over Zenoh: a 36-byte header, then the payload.
//!
//! The header names the channel (which service), carries the payload's schema version and
//! length, the byte order, the sending relay's instance and a per-channel sequence number.
//! Service payloads are the `repr(C)` bytes of the iceoryx2 message ([`message_bytes`]) and
//! are validated again on arrival ([`message_from_bytes`]): a message from the network is
//! untrusted input, and one of another schema version is refused as at a local open.
//! Control messages ([`Hello`], [`PolicyAck`]) are JSON.

use serde::{Deserialize, Serialize};
use shm_schemas::services::{MessageBytesError, message_bytes, message_from_bytes};
use shm_schemas::{PolicyBlob, RetrainProgress, RetrainRequest, ShmMessage};

/// First bytes of every message.
pub const MAGIC: [u8; 4] = *b"FSZ1";
/// Version of this header layout.
pub const WIRE_VERSION: u16 = 1;
/// Written in native order; read back as anything else means the peer's byte order differs.
const BYTE_ORDER_MARK: u16 = 0x0102;
/// Header size (bytes).
pub const HEADER_LEN: usize = 36;
/// Version of the JSON control messages.
pub const CONTROL_VERSION: u32 = 1;

/// What a message carries. The discriminant is its byte on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
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

/// The fixed part of a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// What the payload is.
    pub channel: Channel,
    /// The payload's schema version.
    pub schema_version: u32,
    /// Random per relay process: tells a restarted peer from a repeat.
    pub sender_instance: u64,
    /// Per channel and sender, from 1.
    pub sequence: u64,
}

impl Header {
    /// A header of this build's schema version for `channel`.
    pub fn new(channel: Channel, sender_instance: u64, sequence: u64) -> Self {
        Self {
            channel,
            schema_version: channel.schema_version(),
            sender_instance,
            sequence,
        }
    }
}

/// Why received bytes are not a message of this build. Every variant names what was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// Fewer bytes than a header.
    #[error("message of {0} bytes is shorter than the {HEADER_LEN}-byte header")]
    TooShort(usize),
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
    #[error("header.payload_len says {said} bytes, {got} follow")]
    PayloadLen {
        /// The header's length.
        said: usize,
        /// Bytes after the header.
        got: usize,
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
    #[error("payload: {0}")]
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
            _ => "malformed",
        }
    }
}

/// A message: header + payload bytes.
pub fn encode(header: &Header, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
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
    debug_assert_eq!(out.len(), HEADER_LEN);
    out.extend_from_slice(payload);
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

/// Splits a message into its checked header and payload; `expected` is the channel of the
/// key it arrived on. The schema version is checked against this build's.
///
/// # Errors
/// [`WireError`] naming the header field.
pub fn decode(bytes: &[u8], expected: Channel) -> Result<(Header, &[u8]), WireError> {
    if bytes.len() < HEADER_LEN {
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
    let schema_version = le_u32(bytes, 12);
    if schema_version != channel.schema_version() {
        return Err(WireError::SchemaMismatch {
            channel,
            got: schema_version,
            expected: channel.schema_version(),
        });
    }
    let said = le_u32(bytes, 16) as usize;
    let payload = &bytes[HEADER_LEN..];
    if said != payload.len() {
        return Err(WireError::PayloadLen {
            said,
            got: payload.len(),
        });
    }
    let header = Header {
        channel,
        schema_version,
        sender_instance: le_u64(bytes, 20),
        sequence: le_u64(bytes, 28),
    };
    Ok((header, payload))
}

/// A service message for `channel`, with this build's schema version.
pub fn encode_message<T: ShmMessage>(
    channel: Channel,
    sender_instance: u64,
    sequence: u64,
    message: &T,
) -> Vec<u8> {
    encode(
        &Header::new(channel, sender_instance, sequence),
        message_bytes(message),
    )
}

/// A service message read from the network and validated.
///
/// # Errors
/// [`WireError`]: the header, the schema version, the length or a field of the payload.
pub fn decode_message<T: ShmMessage>(
    bytes: &[u8],
    channel: Channel,
) -> Result<(Header, Box<T>), WireError> {
    let (header, payload) = decode(bytes, channel)?;
    Ok((header, message_from_bytes::<T>(payload)?))
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

/// A JSON control message.
pub fn encode_control<T: Serialize>(
    channel: Channel,
    sender_instance: u64,
    sequence: u64,
    message: &T,
) -> Vec<u8> {
    let json = serde_json::to_vec(message).unwrap_or_default();
    encode(&Header::new(channel, sender_instance, sequence), &json)
}

/// A JSON control message read from the network.
///
/// # Errors
/// [`WireError`]: the header, or JSON that is not the message (the error names the field).
pub fn decode_control<T: for<'de> Deserialize<'de>>(
    bytes: &[u8],
    channel: Channel,
) -> Result<(Header, T), WireError> {
    let (header, payload) = decode(bytes, channel)?;
    let message = serde_json::from_slice(payload).map_err(|e| WireError::Control {
        channel,
        error: e.to_string(),
    })?;
    Ok((header, message))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use shm_schemas::{PolicyBlobBuilder, RetrainPhase, SchemaError};

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

    #[test]
    fn a_message_round_trips_with_its_header() {
        let bytes = encode_message(Channel::RetrainProgress, 0xabc, 42, &progress());
        assert_eq!(bytes.len(), HEADER_LEN + size_of::<RetrainProgress>());
        let (h, p) = decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress).unwrap();
        assert_eq!(
            h,
            Header {
                channel: Channel::RetrainProgress,
                schema_version: RetrainProgress::SCHEMA_VERSION,
                sender_instance: 0xabc,
                sequence: 42
            }
        );
        assert_eq!(*p, progress());
    }

    #[test]
    fn a_policy_blob_round_trips_and_a_flipped_weight_is_refused_by_its_checksum() {
        let builder = PolicyBlobBuilder::random(9, 0x77, 17, &[64, 64], 3, 1);
        let mut blob = PolicyBlob::new_boxed();
        builder.write_into(&mut blob).unwrap();
        let mut bytes = encode_message(Channel::Policy, 1, 1, &*blob);
        let (_, back) = decode_message::<PolicyBlob>(&bytes, Channel::Policy).unwrap();
        assert_eq!(back.policy_id, 9);
        assert_eq!(back.as_bytes(), blob.as_bytes());
        // One weight byte changed in flight.
        let at = HEADER_LEN + 360 + 8;
        bytes[at] ^= 0x40;
        let e = decode_message::<PolicyBlob>(&bytes, Channel::Policy).unwrap_err();
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
        let mut bytes = encode_message(Channel::RetrainProgress, 1, 1, &progress());
        bytes[12..16].copy_from_slice(&99u32.to_le_bytes());
        let e = decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress).unwrap_err();
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
        let good = encode_message(Channel::RetrainProgress, 1, 1, &progress());
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
                    b.push(0);
                    b
                },
                "header.payload_len",
            ),
            (
                {
                    let mut p = progress();
                    p.success_rate = 2.0;
                    encode_message(Channel::RetrainProgress, 1, 1, &p)
                },
                "success_rate",
            ),
            (
                {
                    let mut p = progress();
                    p.phase = 77;
                    encode_message(Channel::RetrainProgress, 1, 1, &p)
                },
                "phase",
            ),
        ];
        for (bytes, field) in cases {
            let e = decode_message::<RetrainProgress>(&bytes, Channel::RetrainProgress)
                .unwrap_err()
                .to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
        // The right header on the wrong key.
        let e = decode_message::<RetrainProgress>(&good, Channel::RetrainRequest).unwrap_err();
        assert!(matches!(e, WireError::WrongChannel { .. }), "{e:?}");
        // A payload of the wrong size for its type (a schema change that kept the version).
        let short = encode(&Header::new(Channel::RetrainProgress, 1, 1), &[0u8; 40]);
        let e = decode_message::<RetrainProgress>(&short, Channel::RetrainProgress).unwrap_err();
        assert!(e.to_string().contains("40 bytes"), "{e}");
    }

    #[test]
    fn control_messages_round_trip_and_unknown_fields_are_refused() {
        let hello = Hello {
            side: Side::Learner,
            host: "gpu-box".into(),
            pid: 12,
            relay_version: "0.1.0".into(),
            schema_versions: schema_versions(),
            task_hash: Some(0xfeed),
        };
        let bytes = encode_control(Channel::Hello, 5, 3, &hello);
        let (h, back): (Header, Hello) = decode_control(&bytes, Channel::Hello).unwrap();
        assert_eq!((h.sender_instance, h.sequence), (5, 3));
        assert_eq!(back, hello);
        let bad = encode(
            &Header::new(Channel::PolicyAck, 1, 1),
            br#"{"policy_id": 1, "checksum": 2, "extra": 3}"#,
        );
        let e = decode_control::<PolicyAck>(&bad, Channel::PolicyAck).unwrap_err();
        assert!(e.to_string().contains("extra"), "{e}");
    }
}
