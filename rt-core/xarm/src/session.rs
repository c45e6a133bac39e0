//! [`Session`]: one live connection to the controller and the blocking steps every link
//! starts with (handshake, `GET_ERROR`, servo-mode entry, joint read), plus the non-blocking
//! pipeline primitives the driver streams through. The driver and the reconnect helper both
//! open links through [`Session::open`], so there is one way to (re)connect.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use crate::codec::{
    self, FrameError, MAX_FRAME_LEN, PROTOCOL_CONNECT, PROTOCOL_PRIVATE, Register, Request,
    Response, VersionInfo,
};
use crate::codes::{ControllerError, ControllerWarning};
use crate::config::XArmConfig;
use crate::error::XArmError;
use crate::report::ReportFramer;
use crate::sim_identity::{self, SimIdentityError, SimSecret};

/// Most requests in flight (sent, not yet answered).
pub const MAX_IN_FLIGHT: usize = 64;

#[derive(Debug, Clone, Copy)]
pub(crate) struct InFlight {
    pub(crate) tid: u16,
    pub(crate) register: u8,
    pub(crate) sent_ns: u64,
}

/// Fixed-capacity FIFO of requests in flight.
#[derive(Debug, Clone)]
pub(crate) struct InFlightQueue {
    pub(crate) items: [InFlight; MAX_IN_FLIGHT],
    pub(crate) head: usize,
    pub(crate) len: usize,
}

impl InFlightQueue {
    pub(crate) fn new() -> Self {
        Self {
            items: [InFlight {
                tid: 0,
                register: 0,
                sent_ns: 0,
            }; MAX_IN_FLIGHT],
            head: 0,
            len: 0,
        }
    }
    pub(crate) fn push(&mut self, f: InFlight) -> bool {
        if self.len == MAX_IN_FLIGHT {
            return false;
        }
        self.items[(self.head + self.len) % MAX_IN_FLIGHT] = f;
        self.len += 1;
        true
    }
    pub(crate) fn front(&self) -> Option<InFlight> {
        (self.len > 0).then(|| self.items[self.head])
    }
    pub(crate) fn pop(&mut self) {
        if self.len > 0 {
            self.head = (self.head + 1) % MAX_IN_FLIGHT;
            self.len -= 1;
        }
    }
    pub(crate) fn clear(&mut self) {
        self.len = 0;
    }
}

/// One live connection to the controller: the command and report sockets, transaction ids,
/// the protocol id, the receive buffers and the requests in flight, plus what the handshake
/// learned (version, error and warning). Shared by the driver (the cycle's non-blocking
/// pipeline) and the reconnect helper (the blocking re-open), so both open a link the same
/// way.
pub struct Session {
    pub(crate) cmd: TcpStream,
    pub(crate) report: TcpStream,
    pub(crate) rx: [u8; 4 * MAX_FRAME_LEN],
    pub(crate) rx_len: usize,
    pub(crate) framer: ReportFramer,
    pub(crate) tid: u16,
    pub(crate) protocol: u16,
    pub(crate) in_flight: InFlightQueue,
    /// Unsent tail of a partially written frame.
    pending: [u8; 64],
    pending_len: usize,
    pub(crate) error_query_in_flight: bool,
    /// The version string the handshake read.
    pub(crate) version: Option<VersionInfo>,
    /// The controller's error as last read with `GET_ERROR`.
    pub(crate) error: ControllerError,
    /// The controller's warning as last read with `GET_ERROR`.
    pub(crate) warning: ControllerWarning,
    /// A blocking reply carried the error bit since the owner last looked.
    error_flagged: bool,
}

fn resolve(host: &str, port: u16) -> Result<SocketAddr, XArmError> {
    (host, port)
        .to_socket_addrs()
        .map_err(|e| XArmError::Io(e.kind()))?
        .next()
        .ok_or(XArmError::Io(ErrorKind::NotFound))
}

impl Session {
    fn connect(cfg: &XArmConfig) -> Result<Self, XArmError> {
        let cmd = TcpStream::connect_timeout(
            &resolve(&cfg.host, cfg.command_port)?,
            cfg.connect_timeout,
        )?;
        cmd.set_nodelay(true)?;
        let report =
            TcpStream::connect_timeout(&resolve(&cfg.host, cfg.report_port)?, cfg.connect_timeout)?;
        report.set_nodelay(true)?;
        report.set_nonblocking(true)?;
        Ok(Self {
            cmd,
            report,
            rx: [0; 4 * MAX_FRAME_LEN],
            rx_len: 0,
            framer: ReportFramer::new(),
            tid: 0,
            protocol: PROTOCOL_CONNECT,
            in_flight: InFlightQueue::new(),
            pending: [0; 64],
            pending_len: 0,
            error_query_in_flight: false,
            version: None,
            error: ControllerError::None,
            warning: ControllerWarning::None,
            error_flagged: false,
        })
    }

    /// The transaction id of the last request written.
    pub(crate) fn last_tid(&self) -> u16 {
        self.tid
    }

    pub(crate) fn next_tid(&mut self) -> u16 {
        self.tid = if self.tid == u16::MAX {
            1
        } else {
            self.tid + 1
        };
        self.tid
    }

    /// Writes the unsent tail of an earlier frame; true when nothing is left.
    pub(crate) fn flush_pending(&mut self) -> Result<bool, XArmError> {
        while self.pending_len > 0 {
            match self.cmd.write(&self.pending[..self.pending_len]) {
                Ok(0) => return Err(XArmError::Disconnected),
                Ok(n) => {
                    self.pending.copy_within(n..self.pending_len, 0);
                    self.pending_len -= n;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(false),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(true)
    }

    /// Non-blocking write of one whole frame (the tail is kept if the socket takes part).
    pub(crate) fn write_frame(
        &mut self,
        frame: &[u8],
        register: u8,
        now_ns: u64,
    ) -> Result<(), XArmError> {
        if !self.flush_pending()? || self.in_flight.len == MAX_IN_FLIGHT {
            return Err(XArmError::Backlog);
        }
        let mut written = 0;
        while written < frame.len() {
            match self.cmd.write(&frame[written..]) {
                Ok(0) => return Err(XArmError::Disconnected),
                Ok(n) => written += n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    if written == 0 {
                        return Err(XArmError::Backlog);
                    }
                    let rest = &frame[written..];
                    self.pending[..rest.len()].copy_from_slice(rest);
                    self.pending_len = rest.len();
                    break;
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
        let tid = u16::from_be_bytes([frame[0], frame[1]]);
        self.in_flight.push(InFlight {
            tid,
            register,
            sent_ns: now_ns,
        });
        Ok(())
    }

    pub(crate) fn send_request(&mut self, req: &Request, now_ns: u64) -> Result<(), XArmError> {
        let mut buf = [0u8; 64];
        let tid = self.next_tid();
        let n = req
            .encode(tid, self.protocol, &mut buf)
            .map_err(|_| XArmError::Frame(FrameError::LengthTooLarge { length: 0 }))?;
        self.write_frame(&buf[..n], u8::from(req.register()), now_ns)
    }

    /// Reads what the command socket has (non-blocking). Ok(false) on EOF.
    pub(crate) fn fill_rx(&mut self) -> Result<(), XArmError> {
        if self.rx_len == self.rx.len() {
            return Ok(());
        }
        match self.cmd.read(&mut self.rx[self.rx_len..]) {
            Ok(0) => Err(XArmError::Disconnected),
            Ok(n) => {
                self.rx_len += n;
                Ok(())
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) => Ok(()),
            Err(e) => Err(e.into()),
        }
    }

    /// Opens a session like the SDK (blocking): TCP to the command and report ports,
    /// `GET_VERSION` with protocol id 2 (transaction id 1), then protocol id 3, and
    /// `GET_ERROR`. Clears nothing and moves nothing. A controller whose version string does
    /// not name an xArm5 (type 5, 5 axes) is refused before anything else is sent. With
    /// [`XArmConfig::sim_secret`] set, the controller must then prove it is `xarm-sim`
    /// holding that secret ([`Self::prove_sim_identity`]) before anything else is sent.
    ///
    /// # Errors
    /// [`XArmError::NotXArm5`] for another arm; [`XArmError::NotSimulator`] for a controller
    /// that does not prove it is `xarm-sim` when that is asked; [`XArmError`] for
    /// unreachable ports, timeouts and malformed replies.
    pub fn open(cfg: &XArmConfig) -> Result<Self, XArmError> {
        let mut s = Self::connect(cfg)?;
        let r = s.call(&Request::GetVersion, cfg.reply_timeout)?;
        let v = VersionInfo::parse(&r.data[..r.len]).map_err(XArmError::Frame)?;
        if !v.is_xarm5() {
            tracing::error!(
                version = v.as_str(),
                "not an xArm5: refusing the controller"
            );
            return Err(XArmError::NotXArm5 {
                axis: v.axis,
                robot_type: v.robot_type,
            });
        }
        tracing::info!(version = v.as_str(), "xArm connected");
        s.version = Some(v);
        s.protocol = PROTOCOL_PRIVATE;
        if let Some(secret) = &cfg.sim_secret {
            if let Err(e) = s.prove_sim_identity(secret, cfg.reply_timeout) {
                tracing::error!(
                    host = cfg.host,
                    port = cfg.command_port,
                    "not xarm-sim: {e}; it is a real arm, refused for simulation-only use"
                );
                return Err(XArmError::NotSimulator(e));
            }
            tracing::info!(
                host = cfg.host,
                port = cfg.command_port,
                "the controller proved it is this run's xarm-sim"
            );
        }
        s.refresh_error(cfg.reply_timeout)?;
        Ok(s)
    }

    /// Asks the controller to prove it is `xarm-sim` holding `secret` (blocking): one
    /// challenge on register 0xF0 with a fresh nonce, answered by HMAC-SHA256 of the secret
    /// ([`crate::sim_identity`]). Sends nothing else; changes nothing on the controller.
    ///
    /// # Errors
    /// [`SimIdentityError`]: anything but a proof that verifies (an unknown-register reply,
    /// no answer within `timeout`, a closed connection, a wrong proof).
    pub fn prove_sim_identity(
        &mut self,
        secret: &SimSecret,
        timeout: Duration,
    ) -> Result<(), SimIdentityError> {
        let nonce = sim_identity::fresh_nonce()?;
        match self.call(&Request::SimIdentity(nonce), timeout) {
            Ok(r) => sim_identity::check_reply(secret, &nonce, r.status, &r.data[..r.len]),
            Err(XArmError::Timeout) => Err(SimIdentityError::NoAnswer),
            Err(XArmError::Disconnected) => Err(SimIdentityError::Closed),
            Err(XArmError::Frame(e)) => Err(SimIdentityError::BadReply(e)),
            Err(XArmError::Io(k)) => Err(SimIdentityError::Io(k)),
            Err(_) => Err(SimIdentityError::NoAnswer),
        }
    }

    /// The version string the handshake read.
    pub fn version(&self) -> Option<VersionInfo> {
        self.version
    }

    /// One blocking request/response on an empty pipeline (the caller drains replies in
    /// flight first). The socket is back in non-blocking mode afterwards.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn call(&mut self, req: &Request, timeout: Duration) -> Result<CallReply, XArmError> {
        let res = self.call_inner(req, Instant::now() + timeout);
        let _ = self.cmd.set_nonblocking(true);
        if res
            .as_ref()
            .is_ok_and(|r| r.status & codec::STATUS_ERROR != 0)
        {
            self.error_flagged = true;
        }
        res
    }

    /// Whether a blocking reply carried the error bit since the last look (clears it).
    pub fn take_error_flag(&mut self) -> bool {
        std::mem::take(&mut self.error_flagged)
    }

    fn call_inner(&mut self, req: &Request, deadline: Instant) -> Result<CallReply, XArmError> {
        let mut buf = [0u8; 64];
        let tid = self.next_tid();
        let protocol = self.protocol;
        let n = req
            .encode(tid, protocol, &mut buf)
            .map_err(|_| XArmError::Frame(FrameError::LengthTooLarge { length: 0 }))?;
        self.cmd.set_nonblocking(false)?;
        self.cmd.write_all(&buf[..n])?;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(XArmError::Timeout);
            }
            self.cmd.set_read_timeout(Some(left))?;
            if let Some(len) = codec::frame_len(&self.rx[..self.rx_len], 2)? {
                let frame = &self.rx[..len];
                let r = Response::parse(frame)?;
                if r.header.tid != tid {
                    // A stale reply: ignore it like the SDK does.
                    self.rx.copy_within(len..self.rx_len, 0);
                    self.rx_len -= len;
                    continue;
                }
                r.check(tid, protocol, u8::from(req.register()))?;
                let mut out = CallReply {
                    status: r.status,
                    data: [0; 128],
                    len: r.data.len().min(128),
                };
                out.data[..out.len].copy_from_slice(&r.data[..out.len]);
                self.rx.copy_within(len..self.rx_len, 0);
                self.rx_len -= len;
                return Ok(out);
            }
            match self.cmd.read(&mut self.rx[self.rx_len..]) {
                Ok(0) => return Err(XArmError::Disconnected),
                Ok(n) => self.rx_len += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Reads `GET_ERROR` (blocking) and records it.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn refresh_error(
        &mut self,
        timeout: Duration,
    ) -> Result<(ControllerError, ControllerWarning), XArmError> {
        let r = self.call(&Request::GetError, timeout)?;
        if r.len < 2 {
            return Err(XArmError::Frame(FrameError::BadPayload {
                register: 0x0F,
                len: r.len,
            }));
        }
        self.error = ControllerError::from(r.data[0]);
        self.warning = ControllerWarning::from(r.data[1]);
        Ok((self.error, self.warning))
    }

    /// `GET_STATE` (blocking).
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn get_state(&mut self, timeout: Duration) -> Result<u8, XArmError> {
        let r = self.call(&Request::GetState, timeout)?;
        if r.len < 1 {
            return Err(XArmError::Frame(FrameError::BadPayload {
                register: 0x0D,
                len: 0,
            }));
        }
        Ok(r.data[0])
    }

    /// `GET_JOINT_POS` (blocking): the five joints (rad).
    ///
    /// # Errors
    /// [`XArmError`], [`FrameError::NonFinite`] inside.
    pub fn get_joints(&mut self, timeout: Duration) -> Result<[f64; 5], XArmError> {
        let r = self.call(&Request::GetJointPos(None), timeout)?;
        let q7 = r.response_view(Register::GetJointPos).joints()?;
        let mut q = [0.0; 5];
        for (o, v) in q.iter_mut().zip(q7) {
            *o = f64::from(v);
        }
        Ok(q)
    }

    /// `GET_TCP_POSE` (blocking): x, y, z (mm), roll, pitch, yaw (rad).
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn get_tcp_pose(&mut self, timeout: Duration) -> Result<[f32; 6], XArmError> {
        let r = self.call(&Request::GetTcpPose, timeout)?;
        Ok(r.response_view(Register::GetTcpPose).tcp_pose()?)
    }

    /// Enable all servos, mode 1, state 0 (each state change followed by `GET_STATE`, as
    /// the SDK does), without clearing errors first; then re-reads the joints, where
    /// streaming must start.
    ///
    /// # Errors
    /// [`XArmError::Controller`] if the controller has an error, [`XArmError::NotReady`] if
    /// it does not leave the stopped state.
    pub fn enter_servo_mode(&mut self, timeout: Duration) -> Result<[f64; 5], XArmError> {
        self.call(
            &Request::MotionEnable {
                servo_id: 8,
                enable: true,
            },
            timeout,
        )?;
        self.get_state(timeout)?;
        self.call(
            &Request::SetMode {
                mode: 1,
                detection: Some(0),
            },
            timeout,
        )?;
        self.call(&Request::SetState(0), timeout)?;
        let state = self.get_state(timeout)?;
        let (err, _) = self.refresh_error(timeout)?;
        if err != ControllerError::None {
            return Err(XArmError::Controller(err));
        }
        if matches!(state, 3..=5) {
            return Err(XArmError::NotReady { state, mode: 1 });
        }
        self.get_joints(timeout)
    }
}

/// A reply to a blocking call, copied out of the receive buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CallReply {
    /// Status byte.
    pub status: u8,
    /// Data bytes (first 128).
    pub data: [u8; 128],
    /// Valid bytes of `data`.
    pub len: usize,
}

impl CallReply {
    pub(crate) fn response_view(&self, register: Register) -> Response<'_> {
        Response {
            header: codec::FrameHeader {
                tid: 0,
                protocol: 0,
                length: (self.len + 2) as u16,
            },
            register: u8::from(register),
            status: self.status,
            data: &self.data[..self.len],
        }
    }
}
