//! Simulation rights by identity, not by address: a controller proves it is `xarm-sim`
//! started for this run before anything simulation-only is allowed to drive it.
//!
//! A loopback address says nothing about what answers behind it: `ssh -L 502:arm:502`,
//! `socat` or a container's port forward put a real xArm on 127.0.0.1. So the rights that
//! only a simulated arm may have — blind mode (`--no-lookahead`), resuming after a lost link
//! without the operator (`--auto-resume`), the synthetic camera and the bundled calibration —
//! are granted only to a controller that proves it holds the run's secret, and only on a
//! loopback address (both must hold).
//!
//! The choice:
//! - **The secret** ([`SimSecret`]): 32 bytes from the OS random source, drawn by the
//!   launcher for each run (or by whoever starts `xarm-sim` by hand), written as 64 hex digits.
//!   It travels in the environment variable [`SIM_SECRET_ENV`], never on a command line
//!   (`/proc/PID/cmdline` is readable by every user; `/proc/PID/environ` only by the
//!   process's own user and root). `xarm-sim` and `rt-core run` read it at start.
//! - **The challenge**: register 0xF0 ([`crate::codec::Register::SimIdentity`]), which the
//!   xArm SDK does not name, carrying a fresh 16-byte nonce ([`NONCE_LEN`]). `xarm-sim`
//!   with the secret answers HMAC-SHA256(secret, [`DOMAIN`] ‖ nonce) ([`PROOF_LEN`] bytes);
//!   `xarm-sim` without it answers as to any register it does not have (status bit 0x08,
//!   no data), and so, as far as the protocol lets us know, does a real controller — or it
//!   does not answer, or closes the connection. Anything but a proof that verifies is a
//!   refusal ([`SimIdentityError`]): the arm is treated as a real arm.
//! - **When**: the driver asks in [`crate::session::Session::open`] whenever
//!   [`crate::config::XArmConfig::sim_secret`] is set — right after the `GET_VERSION`
//!   handshake, before `GET_ERROR` and before anything that changes the controller — so
//!   at the first connection and at every reconnect, off the real-time cycle. rt-core sets
//!   it only when a simulation-only right is asked for; a plain run on any address sends no
//!   challenge.
//!
//! Trusted: every process of the user who runs Foresight (it can read the secret from the
//! environment of `xarm-sim` or `rt-core`), and that the real controller never gives
//! register 0xF0 a meaning that moves the arm.
//!
//! ```
//! use xarm::sim_identity::{NONCE_LEN, SimSecret};
//! let secret = SimSecret::generate().expect("OS random source");
//! let nonce = [7u8; NONCE_LEN];
//! let proof = secret.proof(&nonce);
//! assert!(secret.verify(&nonce, &proof));
//! let again = SimSecret::from_hex(&secret.to_hex()).expect("hex");
//! assert!(again.verify(&nonce, &proof));
//! assert!(!SimSecret::generate().expect("random").verify(&nonce, &proof));
//! ```

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use hmac::{Hmac, Mac};
use sha2::Sha256;

use crate::codec::{
    self, FrameError, MAX_FRAME_LEN, PROTOCOL_CONNECT, PROTOCOL_PRIVATE, Request, Response,
    STATUS_INVALID,
};

/// The environment variable that carries the run's secret to `xarm-sim` and `rt-core`
/// (64 hex digits).
pub const SIM_SECRET_ENV: &str = "FORESIGHT_SIM_SECRET";
/// Bytes of the secret.
pub const SECRET_LEN: usize = 32;
/// Bytes of the challenge's nonce (the request's payload, defined with the wire format).
pub const NONCE_LEN: usize = codec::SIM_NONCE_LEN;
/// Bytes of the proof (the reply's data): an HMAC-SHA256.
pub const PROOF_LEN: usize = 32;
/// What the proof is about, hashed before the nonce, so that the secret's HMAC means
/// nothing else.
pub const DOMAIN: &[u8] = b"foresight xarm-sim identity v1";

type HmacSha256 = Hmac<Sha256>;

/// The run's secret. Its `Debug` never shows it.
#[derive(Clone, PartialEq, Eq)]
pub struct SimSecret([u8; SECRET_LEN]);

impl std::fmt::Debug for SimSecret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SimSecret(..)")
    }
}

/// Why a secret could not be made or read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SimSecretError {
    /// Not 64 characters.
    #[error(
        "{SIM_SECRET_ENV} must be {} hexadecimal digits (a {SECRET_LEN}-byte secret), not {len} \
         characters",
        2 * SECRET_LEN
    )]
    BadLength {
        /// Characters given.
        len: usize,
    },
    /// A character that is not a hex digit.
    #[error("{SIM_SECRET_ENV} holds a character that is not a hexadecimal digit")]
    NotHex,
    /// The variable is not valid Unicode.
    #[error("{SIM_SECRET_ENV} is not valid Unicode")]
    NotUnicode,
    /// The OS random source failed.
    #[error("the OS random source failed; no secret was drawn")]
    Random,
}

impl SimSecret {
    /// A fresh secret from the OS random source.
    ///
    /// # Errors
    /// [`SimSecretError::Random`].
    pub fn generate() -> Result<Self, SimSecretError> {
        let mut b = [0u8; SECRET_LEN];
        getrandom::fill(&mut b).map_err(|_| SimSecretError::Random)?;
        Ok(Self(b))
    }

    /// From its 64 hex digits (either case; surrounding white space ignored).
    ///
    /// # Errors
    /// [`SimSecretError::BadLength`], [`SimSecretError::NotHex`].
    pub fn from_hex(text: &str) -> Result<Self, SimSecretError> {
        let t = text.trim().as_bytes();
        if t.len() != 2 * SECRET_LEN {
            return Err(SimSecretError::BadLength {
                len: text.trim().chars().count(),
            });
        }
        let digit = |c: u8| match c {
            b'0'..=b'9' => Ok(c - b'0'),
            b'a'..=b'f' => Ok(c - b'a' + 10),
            b'A'..=b'F' => Ok(c - b'A' + 10),
            _ => Err(SimSecretError::NotHex),
        };
        let mut b = [0u8; SECRET_LEN];
        for (o, pair) in b.iter_mut().zip(t.chunks_exact(2)) {
            *o = digit(pair[0])? << 4 | digit(pair[1])?;
        }
        Ok(Self(b))
    }

    /// Its 64 lower-case hex digits (for [`SIM_SECRET_ENV`]).
    pub fn to_hex(&self) -> String {
        self.0.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// The secret in [`SIM_SECRET_ENV`]; `None` when it is not set or empty.
    ///
    /// # Errors
    /// [`SimSecretError`] when it is set but is not 64 hex digits.
    pub fn from_env() -> Result<Option<Self>, SimSecretError> {
        match std::env::var(SIM_SECRET_ENV) {
            Ok(v) if v.trim().is_empty() => Ok(None),
            Ok(v) => Self::from_hex(&v).map(Some),
            Err(std::env::VarError::NotPresent) => Ok(None),
            Err(std::env::VarError::NotUnicode(_)) => Err(SimSecretError::NotUnicode),
        }
    }

    fn mac(&self, nonce: &[u8; NONCE_LEN]) -> HmacSha256 {
        // An HMAC takes a key of any length: `new_from_slice` cannot fail here.
        let mut mac = <HmacSha256 as Mac>::new_from_slice(&self.0)
            .unwrap_or_else(|_| unreachable!("HMAC accepts any key length"));
        mac.update(DOMAIN);
        mac.update(nonce);
        mac
    }

    /// The proof `xarm-sim` answers the challenge `nonce` with.
    pub fn proof(&self, nonce: &[u8; NONCE_LEN]) -> [u8; PROOF_LEN] {
        self.mac(nonce).finalize().into_bytes().into()
    }

    /// Whether `proof` answers `nonce` under this secret (compared in constant time).
    pub fn verify(&self, nonce: &[u8; NONCE_LEN], proof: &[u8]) -> bool {
        proof.len() == PROOF_LEN && self.mac(nonce).verify_slice(proof).is_ok()
    }
}

/// A fresh challenge nonce from the OS random source.
///
/// # Errors
/// [`SimIdentityError::Random`].
pub fn fresh_nonce() -> Result<[u8; NONCE_LEN], SimIdentityError> {
    let mut n = [0u8; NONCE_LEN];
    getrandom::fill(&mut n).map_err(|_| SimIdentityError::Random)?;
    Ok(n)
}

/// Why a controller has not proven it is this run's `xarm-sim`: it is then a real arm.
/// Small and `Copy` (it travels inside [`crate::error::XArmError`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SimIdentityError {
    /// It answered the challenge as a register it does not have.
    #[error(
        "it answered the identity challenge (register 0xF0) as a register it does not have \
         (status 0x{status:02x}), as a real xArm or an xarm-sim without the run's secret does"
    )]
    Unsupported {
        /// The reply's status byte.
        status: u8,
    },
    /// Its answer carries no proof.
    #[error("its answer to the identity challenge carries no proof ({len} data bytes)")]
    NoProof {
        /// Data bytes of the reply.
        len: usize,
    },
    /// A proof that does not verify under the run's secret.
    #[error(
        "its proof does not match this run's secret (not xarm-sim, or an xarm-sim started \
         with another secret)"
    )]
    WrongProof,
    /// No answer within the reply timeout.
    #[error("it did not answer the identity challenge within the reply timeout")]
    NoAnswer,
    /// It closed the connection.
    #[error("it closed the connection at the identity challenge")]
    Closed,
    /// A malformed or mismatched reply.
    #[error("its answer to the identity challenge is not a valid reply: {0}")]
    BadReply(FrameError),
    /// A socket error.
    #[error("socket error at the identity challenge: {0:?}")]
    Io(ErrorKind),
    /// The command port could not be reached to ask ([`ask`]).
    #[error("its command port could not be reached to ask its identity ({0:?})")]
    Unreachable(ErrorKind),
    /// No nonce could be drawn.
    #[error("the OS random source failed; no challenge was sent")]
    Random,
}

/// Checks a reply to the challenge `nonce`: its status byte and data.
///
/// # Errors
/// [`SimIdentityError::Unsupported`] (status bit 0x08), [`SimIdentityError::NoProof`],
/// [`SimIdentityError::WrongProof`].
pub fn check_reply(
    secret: &SimSecret,
    nonce: &[u8; NONCE_LEN],
    status: u8,
    data: &[u8],
) -> Result<(), SimIdentityError> {
    if status & STATUS_INVALID != 0 {
        return Err(SimIdentityError::Unsupported { status });
    }
    if data.len() < PROOF_LEN {
        return Err(SimIdentityError::NoProof { len: data.len() });
    }
    if !secret.verify(nonce, &data[..PROOF_LEN]) {
        return Err(SimIdentityError::WrongProof);
    }
    Ok(())
}

/// Where [`ask`] puts its question: a controller's command port and the timeouts to use.
/// Made from an [`crate::config::XArmConfig`] (`From<&XArmConfig>`, in `config.rs`), so
/// that this module, which the settings name for [`SimSecret`], does not name them back.
#[derive(Debug, Clone, Copy)]
pub struct CommandEndpoint<'a> {
    /// Controller address (host or IP).
    pub host: &'a str,
    /// Command port.
    pub command_port: u16,
    /// TCP connect timeout.
    pub connect_timeout: Duration,
    /// Timeout of each reply.
    pub reply_timeout: Duration,
}

/// Asks the controller of `cfg` (command port only; no report stream, no lock) whether it
/// is `xarm-sim` holding `secret`, as the SDK opens a session: `GET_VERSION` with protocol
/// id 2, then the challenge with protocol id 3. Sends nothing else, changes nothing on the
/// controller and closes the connection. For a launcher that must decide before it starts
/// anything; rt-core asks again in [`crate::session::Session::open`] before it drives.
///
/// # Errors
/// [`SimIdentityError`]: anything but a proof that verifies within `cfg.reply_timeout`
/// per reply (`cfg.connect_timeout` to connect).
pub fn ask<'a>(
    cfg: impl Into<CommandEndpoint<'a>>,
    secret: &SimSecret,
) -> Result<(), SimIdentityError> {
    let cfg = cfg.into();
    let addr = (cfg.host, cfg.command_port)
        .to_socket_addrs()
        .map_err(|e| SimIdentityError::Unreachable(e.kind()))?
        .next()
        .ok_or(SimIdentityError::Unreachable(ErrorKind::NotFound))?;
    let mut stream = TcpStream::connect_timeout(&addr, cfg.connect_timeout)
        .map_err(|e| SimIdentityError::Unreachable(e.kind()))?;
    let _ = stream.set_nodelay(true);
    let mut rx = Exchange {
        stream: &mut stream,
        buf: [0; MAX_FRAME_LEN],
        len: 0,
        timeout: cfg.reply_timeout,
    };
    let (_, data_len) = rx.call(1, PROTOCOL_CONNECT, &Request::GetVersion)?;
    codec::VersionInfo::parse(&rx.buf[8..8 + data_len]).map_err(SimIdentityError::BadReply)?;
    let nonce = fresh_nonce()?;
    let (status, data_len) = rx.call(2, PROTOCOL_PRIVATE, &Request::SimIdentity(nonce))?;
    check_reply(secret, &nonce, status, &rx.buf[8..8 + data_len])
}

/// One blocking request and its reply on a bare command connection ([`ask`]).
struct Exchange<'a> {
    stream: &'a mut TcpStream,
    buf: [u8; MAX_FRAME_LEN],
    len: usize,
    timeout: Duration,
}

impl Exchange<'_> {
    /// Sends `req`, reads its reply into the front of `buf`; returns the status byte and
    /// the number of data bytes (from `buf[8]`).
    fn call(
        &mut self,
        tid: u16,
        protocol: u16,
        req: &Request,
    ) -> Result<(u8, usize), SimIdentityError> {
        let io = |e: std::io::Error| match e.kind() {
            ErrorKind::WouldBlock | ErrorKind::TimedOut => SimIdentityError::NoAnswer,
            ErrorKind::UnexpectedEof
            | ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::BrokenPipe => SimIdentityError::Closed,
            k => SimIdentityError::Io(k),
        };
        let mut frame = [0u8; 64];
        let n = req
            .encode(tid, protocol, &mut frame)
            .map_err(|_| SimIdentityError::BadReply(FrameError::LengthTooLarge { length: 0 }))?;
        self.stream.write_all(&frame[..n]).map_err(io)?;
        self.len = 0;
        let deadline = Instant::now() + self.timeout;
        loop {
            if let Some(len) =
                codec::frame_len(&self.buf[..self.len], 2).map_err(SimIdentityError::BadReply)?
            {
                let r = Response::parse(&self.buf[..len]).map_err(SimIdentityError::BadReply)?;
                r.check(tid, protocol, u8::from(req.register()))
                    .map_err(SimIdentityError::BadReply)?;
                return Ok((r.status, r.data.len()));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(SimIdentityError::NoAnswer);
            }
            self.stream.set_read_timeout(Some(left)).map_err(io)?;
            match self.stream.read(&mut self.buf[self.len..]) {
                Ok(0) => return Err(SimIdentityError::Closed),
                Ok(k) => self.len += k,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(io(e)),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_round_trips_and_bad_text_is_refused() {
        let s = SimSecret::generate().unwrap();
        let hex = s.to_hex();
        assert_eq!(hex.len(), 64);
        assert_eq!(SimSecret::from_hex(&hex).unwrap(), s);
        assert_eq!(
            SimSecret::from_hex(&format!(" {} \n", hex.to_uppercase())).unwrap(),
            s
        );
        assert_eq!(
            SimSecret::from_hex("abc"),
            Err(SimSecretError::BadLength { len: 3 })
        );
        let mut bad = hex.clone();
        bad.replace_range(0..1, "g");
        assert_eq!(SimSecret::from_hex(&bad), Err(SimSecretError::NotHex));
        assert_eq!(format!("{s:?}"), "SimSecret(..)");
        assert!(!format!("{s:?}").contains(&hex[..8]));
    }

    #[test]
    fn only_the_right_secret_and_nonce_verify() {
        let s = SimSecret::from_hex(&"11".repeat(32)).unwrap();
        let other = SimSecret::from_hex(&"22".repeat(32)).unwrap();
        let n = [3u8; NONCE_LEN];
        let p = s.proof(&n);
        assert!(s.verify(&n, &p));
        assert!(!other.verify(&n, &p));
        assert!(!s.verify(&[4u8; NONCE_LEN], &p));
        assert!(!s.verify(&n, &p[..31]));
        assert_eq!(check_reply(&s, &n, 0, &p), Ok(()));
        assert_eq!(check_reply(&s, &n, 0x10, &p), Ok(()));
        assert_eq!(
            check_reply(&s, &n, STATUS_INVALID, &p),
            Err(SimIdentityError::Unsupported { status: 0x08 })
        );
        assert_eq!(
            check_reply(&s, &n, 0, &[]),
            Err(SimIdentityError::NoProof { len: 0 })
        );
        assert_eq!(
            check_reply(&other, &n, 0, &p),
            Err(SimIdentityError::WrongProof)
        );
        // Fixed vector: HMAC-SHA256 over DOMAIN ‖ nonce, so both sides agree byte for byte.
        let fixed = SimSecret::from_hex(&"00".repeat(32)).unwrap();
        let mut m = <HmacSha256 as Mac>::new_from_slice(&[0u8; 32]).unwrap();
        m.update(b"foresight xarm-sim identity v1");
        m.update(&[0u8; NONCE_LEN]);
        let want: [u8; 32] = m.finalize().into_bytes().into();
        assert_eq!(fixed.proof(&[0u8; NONCE_LEN]), want);
    }
}
