//! `XArmDriver`: our client of the xArm control box.
//!
//! Lifecycle: [`XArmDriver::connect`] (blocking: TCP to the command and report ports,
//! `GET_VERSION` with protocol id 2, then protocol id 3, like the official SDK) →
//! [`XArmDriver::start_servo_mode`] (blocking: clean error and warning, enable all, mode 1,
//! state 0, re-read the joints) → per cycle [`XArmDriver::read_state`] and
//! [`XArmDriver::send_servo`] (non-blocking, allocation-free) → [`XArmDriver::stop`] or
//! [`XArmDriver::emergency_stop`].
//!
//! Servo targets are pipelined: each `send_servo` checks the target against the SDK's
//! joint limits (out-of-range targets never reach the wire), writes one 47-byte frame without
//! blocking, and drains at most `reply_budget` replies that have arrived, checking each
//! (transaction id, protocol, register, status bits). An error bit makes the driver ask
//! `GET_ERROR` (pipelined too) and refuse further motion with the typed controller error.
//!
//! On a lost connection the driver stops commanding, retries with exponential back-off, and
//! after reconnecting re-reads the actual joints: the next target must lie within
//! `max_resume_step_rad` of them (no jump). By default the retry happens inside `read_state`
//! (blocking: fine for tools); the cycle calls [`XArmDriver::reconnect_off_cycle`] at start-up
//! so a helper thread does the blocking work and `read_state` stays non-blocking
//! (see [`super::reconnect`]).

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use super::codec::{
    self, FrameError, JointTarget, MAX_FRAME_LEN, PROTOCOL_CONNECT, PROTOCOL_PRIVATE, Register,
    Request, Response, SERVOJ_FRAME_LEN, STATUS_ERROR, STATUS_NOT_READY, VersionInfo,
};
use super::codes::{ControllerError, ControllerWarning};
use super::limits::{JointCheckError, check_xarm5_joints};
use super::reconnect::Reconnector;
use super::report::{self, ArmReport, ReportError, ReportFramer, ReportKind};

/// Most requests in flight (sent, not yet answered).
pub const MAX_IN_FLIGHT: usize = 64;

/// Driver settings.
#[derive(Debug, Clone, PartialEq)]
pub struct XArmConfig {
    /// Controller address (host or IP).
    pub host: String,
    /// Command port (502).
    pub command_port: u16,
    /// Report stream to follow.
    pub report_kind: ReportKind,
    /// Its port (30003 for `Real`, 30000 for `RealTime`).
    pub report_port: u16,
    /// TCP connect timeout.
    pub connect_timeout: Duration,
    /// Timeout of blocking calls and of pipelined replies.
    pub reply_timeout: Duration,
    /// Most replies checked per non-blocking call.
    pub reply_budget: usize,
    /// State older than this is stale (ns).
    pub stale_after_ns: u64,
    /// First reconnect delay (ns); doubles up to `backoff_max_ns`.
    pub backoff_initial_ns: u64,
    /// Longest reconnect delay (ns).
    pub backoff_max_ns: u64,
    /// After a reconnect, the first target may differ from the actual joints by this much.
    pub max_resume_step_rad: f64,
}

impl XArmConfig {
    /// Defaults for a controller at `host` on the real ports (502, report 30003).
    pub fn new(host: &str) -> Self {
        Self {
            host: host.to_string(),
            command_port: 502,
            report_kind: ReportKind::Real,
            report_port: report::PORT_REPORT_REAL,
            connect_timeout: Duration::from_secs(1),
            reply_timeout: Duration::from_secs(2),
            reply_budget: 16,
            stale_after_ns: 200_000_000,
            backoff_initial_ns: 100_000_000,
            backoff_max_ns: 5_000_000_000,
            max_resume_step_rad: 0.05,
        }
    }

    /// Parses `HOST[:PORT]` (default port 502; report port stays the default).
    pub fn from_addr(addr: &str) -> Self {
        match addr.rsplit_once(':') {
            Some((h, p)) if !h.contains(':') || h.starts_with('[') => match p.parse::<u16>() {
                Ok(port) => Self {
                    command_port: port,
                    ..Self::new(h.trim_start_matches('[').trim_end_matches(']'))
                },
                Err(_) => Self::new(addr),
            },
            _ => Self::new(addr),
        }
    }
}

/// Why a driver operation failed. Small and `Copy`: it travels through the cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum XArmError {
    /// A socket operation failed.
    #[error("socket error: {0:?}")]
    Io(ErrorKind),
    /// No reply within the timeout.
    #[error("no reply within the timeout")]
    Timeout,
    /// The connection is lost (reconnecting with back-off).
    #[error("connection to the controller lost")]
    Disconnected,
    /// A malformed or unexpected frame from the controller.
    #[error("bad frame from the controller: {0}")]
    Frame(FrameError),
    /// A malformed report packet.
    #[error("bad report from the controller: {0}")]
    Report(ReportError),
    /// The controller reports an error code; motion is refused until it is cleared.
    #[error("controller error: {0}")]
    Controller(ControllerError),
    /// A reply carried the error bit; the code is being read (`GET_ERROR` in flight).
    #[error("controller flagged an error; reading its code")]
    ErrorPending,
    /// The controller cannot move (status bit 4: stopped, not enabled, wrong mode).
    #[error("controller not ready to move (state {state}, mode {mode})")]
    NotReady {
        /// Last known state.
        state: u8,
        /// Last known mode.
        mode: u8,
    },
    /// The target is outside the joint limits (nothing was sent).
    #[error("target refused: {0}")]
    JointLimit(JointCheckError),
    /// Too many requests in flight or the socket buffer is full (nothing was sent).
    #[error("command pipeline full")]
    Backlog,
    /// After a reconnect the target is too far from the actual joints.
    #[error("target of joint {} jumps away from the re-read joint state", .joint + 1)]
    ResumeJump {
        /// 0-based joint.
        joint: u8,
    },
    /// No report yet, or the last one is stale.
    #[error("no fresh state from the report stream")]
    NoState,
}

impl From<FrameError> for XArmError {
    fn from(e: FrameError) -> Self {
        Self::Frame(e)
    }
}

impl From<std::io::Error> for XArmError {
    fn from(e: std::io::Error) -> Self {
        match e.kind() {
            ErrorKind::WouldBlock | ErrorKind::TimedOut => Self::Timeout,
            ErrorKind::UnexpectedEof
            | ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::BrokenPipe => Self::Disconnected,
            k => Self::Io(k),
        }
    }
}

/// The driver's view of the arm after [`XArmDriver::read_state`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverState {
    /// When the last report arrived (caller's clock, ns).
    pub stamp_ns: u64,
    /// The last report.
    pub report: ArmReport,
    /// Joint velocities estimated from the last two reports (rad/s).
    pub dq_rad_s: [f64; 5],
    /// Controller error known to the driver.
    pub error: ControllerError,
    /// Controller warning known to the driver.
    pub warning: ControllerWarning,
    /// Reconnections so far (a change means: re-plan from `report.joints_rad`).
    pub reconnects: u32,
}

/// Counters of the pipelined command channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DriverStats {
    /// Servo frames written.
    pub servo_sent: u64,
    /// Replies checked.
    pub replies: u64,
    /// Replies with the not-ready bit on a motion command.
    pub not_ready_replies: u64,
    /// Replies with the error bit.
    pub error_replies: u64,
    /// Highest number of requests in flight.
    pub max_in_flight: usize,
    /// Round trip of the last reply (send → drained), ns.
    pub last_rtt_ns: u64,
    /// Reports decoded.
    pub reports: u64,
}

#[derive(Debug, Clone, Copy)]
struct InFlight {
    tid: u16,
    register: u8,
    sent_ns: u64,
}

/// Fixed-capacity FIFO of requests in flight.
#[derive(Debug, Clone)]
struct InFlightQueue {
    items: [InFlight; MAX_IN_FLIGHT],
    head: usize,
    len: usize,
}

impl InFlightQueue {
    fn new() -> Self {
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
    fn push(&mut self, f: InFlight) -> bool {
        if self.len == MAX_IN_FLIGHT {
            return false;
        }
        self.items[(self.head + self.len) % MAX_IN_FLIGHT] = f;
        self.len += 1;
        true
    }
    fn front(&self) -> Option<InFlight> {
        (self.len > 0).then(|| self.items[self.head])
    }
    fn pop(&mut self) {
        if self.len > 0 {
            self.head = (self.head + 1) % MAX_IN_FLIGHT;
            self.len -= 1;
        }
    }
    fn clear(&mut self) {
        self.len = 0;
    }
}

pub(super) struct Conn {
    cmd: TcpStream,
    report: TcpStream,
    rx: [u8; 4 * MAX_FRAME_LEN],
    rx_len: usize,
    framer: ReportFramer,
    tid: u16,
    protocol: u16,
    in_flight: InFlightQueue,
    /// Unsent tail of a partially written frame.
    pending: [u8; 64],
    pending_len: usize,
    error_query_in_flight: bool,
}

fn resolve(host: &str, port: u16) -> Result<SocketAddr, XArmError> {
    (host, port)
        .to_socket_addrs()
        .map_err(|e| XArmError::Io(e.kind()))?
        .next()
        .ok_or(XArmError::Io(ErrorKind::NotFound))
}

impl Conn {
    fn open(cfg: &XArmConfig) -> Result<Self, XArmError> {
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
        })
    }

    fn next_tid(&mut self) -> u16 {
        self.tid = if self.tid == u16::MAX {
            1
        } else {
            self.tid + 1
        };
        self.tid
    }

    /// Writes the unsent tail of an earlier frame; true when nothing is left.
    fn flush_pending(&mut self) -> Result<bool, XArmError> {
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
    fn write_frame(&mut self, frame: &[u8], register: u8, now_ns: u64) -> Result<(), XArmError> {
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

    fn send_request(&mut self, req: &Request, now_ns: u64) -> Result<(), XArmError> {
        let mut buf = [0u8; 64];
        let tid = self.next_tid();
        let n = req
            .encode(tid, self.protocol, &mut buf)
            .map_err(|_| XArmError::Frame(FrameError::LengthTooLarge { length: 0 }))?;
        self.write_frame(&buf[..n], u8::from(req.register()), now_ns)
    }

    /// Reads what the command socket has (non-blocking). Ok(false) on EOF.
    fn fill_rx(&mut self) -> Result<(), XArmError> {
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
}

/// Outcome of one checked reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ReplyEvent {
    Ok,
    NotReady,
    ErrorCode(u8, u8),
}

/// The xArm5 driver.
pub struct XArmDriver {
    cfg: XArmConfig,
    conn: Option<Conn>,
    version: Option<VersionInfo>,
    state: Option<DriverState>,
    prev_q: Option<([f64; 5], u64)>,
    error: ControllerError,
    warning: ControllerWarning,
    error_bit_seen: bool,
    not_ready_seen: bool,
    resume_from: Option<[f64; 5]>,
    reconnects: u32,
    next_attempt_ns: u64,
    backoff_ns: u64,
    servo_mode_wanted: bool,
    stats: DriverStats,
    servo_frame: [u8; SERVOJ_FRAME_LEN],
    origin: Instant,
    /// Reconnects off the cycle when set ([`XArmDriver::reconnect_off_cycle`]).
    reconnector: Option<Reconnector>,
}

impl std::fmt::Debug for XArmDriver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("XArmDriver")
            .field("cfg", &self.cfg)
            .field("connected", &self.conn.is_some())
            .field("error", &self.error)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl XArmDriver {
    /// Connects like the SDK: command port, report port, `GET_VERSION` with protocol id 2
    /// (transaction id 1), then protocol id 3; reads the error/warning codes and waits for
    /// the first report. Does not clear errors or move anything.
    ///
    /// # Errors
    /// [`XArmError`] for unreachable ports, timeouts and malformed replies.
    pub fn connect(cfg: XArmConfig) -> Result<Self, XArmError> {
        let mut d = Self {
            backoff_ns: cfg.backoff_initial_ns,
            cfg,
            conn: None,
            version: None,
            state: None,
            prev_q: None,
            error: ControllerError::None,
            warning: ControllerWarning::None,
            error_bit_seen: false,
            not_ready_seen: false,
            resume_from: None,
            reconnects: 0,
            next_attempt_ns: 0,
            servo_mode_wanted: false,
            stats: DriverStats::default(),
            servo_frame: [0; SERVOJ_FRAME_LEN],
            origin: Instant::now(),
            reconnector: None,
        };
        d.handshake()?;
        Ok(d)
    }

    fn mono_ns(&self) -> u64 {
        self.origin.elapsed().as_nanos() as u64
    }

    fn handshake(&mut self) -> Result<(), XArmError> {
        self.conn = Some(Conn::open(&self.cfg)?);
        let r = self.call(&Request::GetVersion)?;
        let v = VersionInfo::parse(&r.data[..r.len]).map_err(XArmError::Frame)?;
        tracing::info!(version = v.as_str(), "xArm connected");
        self.version = Some(v);
        if let Some(c) = self.conn.as_mut() {
            c.protocol = PROTOCOL_PRIVATE;
        }
        self.refresh_error()?;
        // Wait for the first report (the controller streams at ≥ 5 Hz).
        let deadline = Instant::now() + self.cfg.reply_timeout;
        loop {
            let now = self.mono_ns();
            match self.read_state(now) {
                Ok(_) => return Ok(()),
                Err(XArmError::NoState) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(2));
                }
                Err(XArmError::NoState) => return Err(XArmError::Timeout),
                Err(XArmError::Controller(_)) => return Ok(()),
                Err(e) => return Err(e),
            }
        }
    }

    /// The parsed version string.
    pub fn version(&self) -> Option<VersionInfo> {
        self.version
    }

    /// Counters of the command channel.
    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    /// Error and warning last known to the driver.
    pub fn error_warning(&self) -> (ControllerError, ControllerWarning) {
        (self.error, self.warning)
    }

    /// Whether the command connection is up.
    pub fn is_connected(&self) -> bool {
        self.conn.is_some()
    }

    /// From now on a lost link is re-opened by a helper thread (start-up: spawns it), so
    /// [`XArmDriver::read_state`] never blocks: it answers `Disconnected` until the helper
    /// hands the new connection over, then resumes exactly like an inline reconnect (joints
    /// re-read, the next target within `max_resume_step_rad` of them).
    ///
    /// # Errors
    /// The thread could not be spawned.
    pub fn reconnect_off_cycle(&mut self) -> std::io::Result<()> {
        if self.reconnector.is_none() {
            self.reconnector = Some(Reconnector::spawn(self.cfg.clone())?);
        }
        Ok(())
    }

    /// With [`XArmDriver::reconnect_off_cycle`]: whether the helper is inside a connection
    /// attempt now, and how many attempts it has made.
    pub fn reconnect_progress(&self) -> Option<(bool, u32)> {
        self.reconnector.as_ref().map(|r| (r.busy(), r.attempts()))
    }

    /// The connection, leaving the driver disconnected (the reconnect helper hands it to
    /// the cycle's driver).
    pub(super) fn take_conn(&mut self) -> Option<Conn> {
        self.conn.take()
    }

    /// One blocking request/response (setup and tools, not the cycle). Waits for replies
    /// in flight first.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn call(&mut self, req: &Request) -> Result<CallReply, XArmError> {
        let timeout = self.cfg.reply_timeout;
        let deadline = Instant::now() + timeout;
        // Drain the pipeline.
        while self.conn.as_ref().is_some_and(|c| c.in_flight.len > 0) {
            let now = self.mono_ns();
            self.drain_replies(now, usize::MAX)?;
            if Instant::now() > deadline {
                return Err(self.lose(XArmError::Timeout));
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        let res = self.call_inner(req, deadline);
        if let Some(c) = self.conn.as_mut() {
            let _ = c.cmd.set_nonblocking(true);
        }
        match res {
            Err(
                e @ (XArmError::Disconnected
                | XArmError::Io(_)
                | XArmError::Timeout
                | XArmError::Frame(_)),
            ) => Err(self.lose(e)),
            other => other,
        }
    }

    fn call_inner(&mut self, req: &Request, deadline: Instant) -> Result<CallReply, XArmError> {
        let conn = self.conn.as_mut().ok_or(XArmError::Disconnected)?;
        let mut buf = [0u8; 64];
        let tid = conn.next_tid();
        let protocol = conn.protocol;
        let n = req
            .encode(tid, protocol, &mut buf)
            .map_err(|_| XArmError::Frame(FrameError::LengthTooLarge { length: 0 }))?;
        conn.cmd.set_nonblocking(false)?;
        conn.cmd.write_all(&buf[..n])?;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                conn.cmd.set_nonblocking(true)?;
                return Err(XArmError::Timeout);
            }
            conn.cmd.set_read_timeout(Some(left))?;
            if let Some(len) = codec::frame_len(&conn.rx[..conn.rx_len], 2)? {
                let frame = &conn.rx[..len];
                let r = Response::parse(frame)?;
                if r.header.tid != tid {
                    // A stale reply: ignore it like the SDK does.
                    conn.rx.copy_within(len..conn.rx_len, 0);
                    conn.rx_len -= len;
                    continue;
                }
                r.check(tid, protocol, u8::from(req.register()))?;
                let mut out = CallReply {
                    status: r.status,
                    data: [0; 128],
                    len: r.data.len().min(128),
                };
                out.data[..out.len].copy_from_slice(&r.data[..out.len]);
                conn.rx.copy_within(len..conn.rx_len, 0);
                conn.rx_len -= len;
                conn.cmd.set_nonblocking(true)?;
                if out.status & STATUS_ERROR != 0 {
                    self.error_bit_seen = true;
                }
                return Ok(out);
            }
            let n = conn.cmd.read(&mut conn.rx[conn.rx_len..]);
            match n {
                Ok(0) => return Err(XArmError::Disconnected),
                Ok(n) => conn.rx_len += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Reads `GET_ERROR` (blocking) and records it.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn refresh_error(&mut self) -> Result<(ControllerError, ControllerWarning), XArmError> {
        let r = self.call(&Request::GetError)?;
        if r.len < 2 {
            return Err(XArmError::Frame(FrameError::BadPayload {
                register: 0x0F,
                len: r.len,
            }));
        }
        self.error = ControllerError::from(r.data[0]);
        self.warning = ControllerWarning::from(r.data[1]);
        self.error_bit_seen = r.data[0] != 0;
        Ok((self.error, self.warning))
    }

    /// `GET_STATE` (blocking).
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn get_state(&mut self) -> Result<u8, XArmError> {
        let r = self.call(&Request::GetState)?;
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
    pub fn get_joints(&mut self) -> Result<[f64; 5], XArmError> {
        let r = self.call(&Request::GetJointPos(None))?;
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
    pub fn get_tcp_pose(&mut self) -> Result<[f32; 6], XArmError> {
        let r = self.call(&Request::GetTcpPose)?;
        Ok(r.response_view(Register::GetTcpPose).tcp_pose()?)
    }

    /// The SDK's servo preparation: clean error, clean warning, enable all servos, mode 1,
    /// state 0 (each followed by `GET_STATE` as the SDK does), then re-reads the joints so
    /// streaming starts from where the arm is.
    ///
    /// # Errors
    /// [`XArmError::Controller`] if an error survives cleaning, others for I/O.
    pub fn start_servo_mode(&mut self) -> Result<[f64; 5], XArmError> {
        self.call(&Request::CleanError)?;
        self.get_state()?;
        self.call(&Request::CleanWarn)?;
        self.enter_servo_mode()
    }

    /// Enable all servos, mode 1, state 0 (each state change followed by `GET_STATE`), without
    /// clearing errors first; then re-reads the joints.
    ///
    /// # Errors
    /// [`XArmError::Controller`] if the controller has an error, [`XArmError::NotReady`] if
    /// it does not leave the stopped state.
    pub fn enter_servo_mode(&mut self) -> Result<[f64; 5], XArmError> {
        self.call(&Request::MotionEnable {
            servo_id: 8,
            enable: true,
        })?;
        self.get_state()?;
        self.call(&Request::SetMode {
            mode: 1,
            detection: Some(0),
        })?;
        self.call(&Request::SetState(0))?;
        let state = self.get_state()?;
        let (err, _) = self.refresh_error()?;
        if err != ControllerError::None {
            return Err(XArmError::Controller(err));
        }
        if matches!(state, 3..=5) {
            return Err(XArmError::NotReady { state, mode: 1 });
        }
        self.servo_mode_wanted = true;
        self.not_ready_seen = false;
        let q = self.get_joints()?;
        self.resume_from = None;
        Ok(q)
    }

    /// Asks the controller to stop (`SET_STATE(4)`) without blocking; motion stops at once
    /// on the controller side. Further targets are refused until `start_servo_mode`.
    pub fn stop(&mut self, now_ns: u64) {
        self.servo_mode_wanted = false;
        if let Some(c) = self.conn.as_mut() {
            let _ = c.send_request(&Request::SetState(4), now_ns);
        }
    }

    /// The SDK's `emergency_stop()`: `SET_STATE(4)` then `GET_STATE`, repeated every 0.1 s
    /// until the state reads 4 (up to 3 s). Blocking.
    ///
    /// # Errors
    /// [`XArmError`] if the controller cannot be reached or never reports state 4.
    pub fn emergency_stop(&mut self) -> Result<(), XArmError> {
        self.servo_mode_wanted = false;
        let deadline = Instant::now() + Duration::from_secs(3);
        loop {
            self.call(&Request::SetState(4))?;
            if self.get_state()? == 4 {
                return Ok(());
            }
            if Instant::now() > deadline {
                return Err(XArmError::Timeout);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn lose(&mut self, why: XArmError) -> XArmError {
        if let Some(dead) = self.conn.take() {
            if let Some(r) = self.reconnector.as_mut() {
                // The helper logs, closes the dead sockets and reconnects.
                r.request(why, self.servo_mode_wanted, Some(dead));
            } else {
                drop(dead);
                tracing::warn!("xArm link lost: {why}");
            }
            self.next_attempt_ns = 0;
            self.backoff_ns = self.cfg.backoff_initial_ns;
        }
        self.state = None;
        self.prev_q = None;
        why
    }

    fn try_reconnect(&mut self, now_ns: u64) -> Result<(), XArmError> {
        if let Some(r) = self.reconnector.as_mut() {
            let Some(new) = r.take() else {
                r.request(XArmError::Disconnected, self.servo_mode_wanted, None);
                return Err(XArmError::Disconnected);
            };
            self.conn = Some(new.conn);
            self.version = new.version;
            self.error = new.error;
            self.warning = new.warning;
            self.error_bit_seen = new.error != ControllerError::None;
            self.not_ready_seen = false;
            self.state = None;
            self.prev_q = None;
            self.resume_from = Some(new.q_rad);
            self.reconnects += 1;
            return Ok(());
        }
        if now_ns < self.next_attempt_ns {
            return Err(XArmError::Disconnected);
        }
        let resume = self.servo_mode_wanted;
        let result = self.handshake().and_then(|()| {
            if self.error != ControllerError::None {
                return Err(XArmError::Controller(self.error));
            }
            if resume {
                self.enter_servo_mode()?;
            }
            self.get_joints()
        });
        match result {
            Ok(q) => {
                self.reconnects += 1;
                if let Some(st) = self.state.as_mut() {
                    st.reconnects = self.reconnects;
                }
                self.resume_from = Some(q);
                self.backoff_ns = self.cfg.backoff_initial_ns;
                tracing::info!(reconnects = self.reconnects, "xArm link re-established");
                Ok(())
            }
            Err(e) => {
                self.conn = None;
                self.next_attempt_ns = now_ns.saturating_add(self.backoff_ns);
                self.backoff_ns = (self.backoff_ns.saturating_mul(2)).min(self.cfg.backoff_max_ns);
                Err(match e {
                    XArmError::Controller(c) => XArmError::Controller(c),
                    _ => XArmError::Disconnected,
                })
            }
        }
    }

    fn handle_reply(&mut self, now_ns: u64) -> Result<Option<ReplyEvent>, XArmError> {
        let Some(conn) = self.conn.as_mut() else {
            return Err(XArmError::Disconnected);
        };
        let Some(len) = codec::frame_len(&conn.rx[..conn.rx_len], 2)? else {
            return Ok(None);
        };
        let r = Response::parse(&conn.rx[..len])?;
        if r.register == u8::from(Register::Feedback) {
            conn.rx.copy_within(len..conn.rx_len, 0);
            conn.rx_len -= len;
            return Ok(Some(ReplyEvent::Ok));
        }
        let Some(expect) = conn.in_flight.front() else {
            return Err(XArmError::Frame(FrameError::TransactionMismatch {
                want: 0,
                got: r.header.tid,
            }));
        };
        r.check(expect.tid, conn.protocol, expect.register)?;
        let event = if expect.register == u8::from(Register::GetError) {
            conn.error_query_in_flight = false;
            let (e, w) = r.err_warn()?;
            ReplyEvent::ErrorCode(e, w)
        } else if r.status & STATUS_ERROR != 0 {
            self.stats.error_replies += 1;
            self.error_bit_seen = true;
            ReplyEvent::Ok
        } else if r.status & STATUS_NOT_READY != 0
            && expect.register == u8::from(Register::MoveServoJ)
        {
            self.stats.not_ready_replies += 1;
            ReplyEvent::NotReady
        } else {
            ReplyEvent::Ok
        };
        self.stats.replies += 1;
        self.stats.last_rtt_ns = now_ns.saturating_sub(expect.sent_ns);
        conn.in_flight.pop();
        conn.rx.copy_within(len..conn.rx_len, 0);
        conn.rx_len -= len;
        Ok(Some(event))
    }

    /// Checks up to `budget` replies that have arrived. Never blocks.
    fn drain_replies(&mut self, now_ns: u64, budget: usize) -> Result<(), XArmError> {
        let Some(conn) = self.conn.as_mut() else {
            return Err(XArmError::Disconnected);
        };
        if let Err(e) = conn
            .fill_rx()
            .and_then(|()| conn.flush_pending().map(|_| ()))
        {
            return Err(self.lose(e));
        }
        for _ in 0..budget {
            match self.handle_reply(now_ns) {
                Ok(None) => break,
                Ok(Some(ReplyEvent::Ok)) => {}
                Ok(Some(ReplyEvent::NotReady)) => self.not_ready_seen = true,
                Ok(Some(ReplyEvent::ErrorCode(e, w))) => {
                    self.error = ControllerError::from(e);
                    self.warning = ControllerWarning::from(w);
                    self.error_bit_seen = e != 0;
                }
                Err(e) => return Err(self.lose(e)),
            }
        }
        let timeout_ns = self.cfg.reply_timeout.as_nanos() as u64;
        if let Some(c) = self.conn.as_ref()
            && let Some(oldest) = c.in_flight.front()
            && now_ns.saturating_sub(oldest.sent_ns) > timeout_ns
        {
            return Err(self.lose(XArmError::Timeout));
        }
        // An error bit with an unknown code: ask for it (pipelined).
        if self.error_bit_seen
            && self.error == ControllerError::None
            && let Some(c) = self.conn.as_mut()
            && !c.error_query_in_flight
            && c.send_request(&Request::GetError, now_ns).is_ok()
        {
            c.error_query_in_flight = true;
        }
        Ok(())
    }

    fn drain_reports(&mut self, now_ns: u64) -> Result<(), XArmError> {
        let kind = self.cfg.report_kind;
        let Some(conn) = self.conn.as_mut() else {
            return Err(XArmError::Disconnected);
        };
        let mut latest: Option<ArmReport> = None;
        // Bounded: at most 8 reads per call.
        for _ in 0..8 {
            let spare = conn.framer.spare();
            if spare.is_empty() {
                break;
            }
            match conn.report.read(spare) {
                Ok(0) => return Err(self.lose(XArmError::Disconnected)),
                Ok(n) => conn.framer.commit(n),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(self.lose(e.into())),
            }
            loop {
                match conn.framer.next_packet() {
                    Ok(Some(p)) => match report::decode(kind, p) {
                        Ok(r) => latest = Some(r),
                        Err(e) => return Err(self.lose(XArmError::Report(e))),
                    },
                    Ok(None) => break,
                    Err(e) => return Err(self.lose(XArmError::Report(e))),
                }
            }
        }
        if let Some(r) = latest {
            self.stats.reports += 1;
            let q = r.joints5_rad();
            let mut dq = [0.0; 5];
            if let Some((pq, pt)) = self.prev_q
                && now_ns > pt
            {
                let dt = (now_ns - pt) as f64 * 1e-9;
                for i in 0..5 {
                    dq[i] = (q[i] - pq[i]) / dt;
                }
            }
            self.prev_q = Some((q, now_ns));
            if let Some(e) = r.error_code {
                self.error = ControllerError::from(e);
                self.error_bit_seen = e != 0;
            }
            if let Some(w) = r.warn_code {
                self.warning = ControllerWarning::from(w);
            }
            self.state = Some(DriverState {
                stamp_ns: now_ns,
                report: r,
                dq_rad_s: dq,
                error: self.error,
                warning: self.warning,
                reconnects: self.reconnects,
            });
        }
        Ok(())
    }

    /// The latest state from the report stream (non-blocking, bounded work). While the link
    /// is down this is where reconnection happens, with back-off: inline by default (an
    /// attempt blocks for at most the connect and reply timeouts), or by taking over the
    /// connection the helper of [`XArmDriver::reconnect_off_cycle`] re-opened (never blocks).
    ///
    /// # Errors
    /// [`XArmError::Disconnected`] while down, [`XArmError::NoState`] when stale,
    /// [`XArmError::Controller`] when the controller reports an error (the state is still
    /// readable through [`XArmDriver::last_state`]).
    pub fn read_state(&mut self, now_ns: u64) -> Result<DriverState, XArmError> {
        if self.conn.is_none() {
            self.try_reconnect(now_ns)?;
        }
        self.drain_replies(now_ns, self.cfg.reply_budget)?;
        self.drain_reports(now_ns)?;
        let s = self.state.ok_or(XArmError::NoState)?;
        if now_ns.saturating_sub(s.stamp_ns) > self.cfg.stale_after_ns {
            return Err(XArmError::NoState);
        }
        if self.error != ControllerError::None {
            return Err(XArmError::Controller(self.error));
        }
        Ok(s)
    }

    /// The last state read, even if stale or with an error.
    pub fn last_state(&self) -> Option<DriverState> {
        self.state
    }

    /// Streams one servo_j target (rad) without blocking.
    ///
    /// # Errors
    /// [`XArmError::JointLimit`] (nothing sent), [`XArmError::Controller`] while the
    /// controller has an error ([`XArmError::ErrorPending`] until its code is read), [`XArmError::NotReady`] when the controller refused an earlier
    /// target (reported once), [`XArmError::ResumeJump`] after a reconnect,
    /// [`XArmError::Backlog`], [`XArmError::Disconnected`].
    ///
    /// # Performance
    /// No allocation: one 47-byte encode into a fixed buffer, one `write`, a bounded drain.
    pub fn send_servo(&mut self, now_ns: u64, q_rad: &[f64; 5]) -> Result<(), XArmError> {
        check_xarm5_joints(q_rad).map_err(XArmError::JointLimit)?;
        if self.conn.is_none() {
            return Err(XArmError::Disconnected);
        }
        self.drain_replies(now_ns, self.cfg.reply_budget)?;
        if self.error != ControllerError::None {
            return Err(XArmError::Controller(self.error));
        }
        if self.error_bit_seen {
            return Err(XArmError::ErrorPending);
        }
        if self.not_ready_seen {
            self.not_ready_seen = false;
            let (state, mode) = self
                .state
                .map_or((0, 0), |s| (s.report.state, s.report.mode));
            return Err(XArmError::NotReady { state, mode });
        }
        if let Some(q0) = self.resume_from {
            for (i, (a, b)) in q_rad.iter().zip(q0).enumerate() {
                if (a - b).abs() > self.cfg.max_resume_step_rad {
                    return Err(XArmError::ResumeJump { joint: i as u8 });
                }
            }
        }
        let conn = self.conn.as_mut().ok_or(XArmError::Disconnected)?;
        let tid = conn.next_tid();
        codec::encode_servo_j(tid, &JointTarget::xarm5(q_rad), &mut self.servo_frame);
        let frame = self.servo_frame;
        match conn.write_frame(&frame, u8::from(Register::MoveServoJ), now_ns) {
            Ok(()) => {}
            Err(XArmError::Backlog) => return Err(XArmError::Backlog),
            Err(e) => return Err(self.lose(e)),
        }
        self.resume_from = None;
        self.stats.servo_sent += 1;
        self.stats.max_in_flight = self.stats.max_in_flight.max(conn.in_flight.len);
        Ok(())
    }

    /// Requests in flight (sent, not yet answered).
    pub fn in_flight(&self) -> usize {
        self.conn.as_ref().map_or(0, |c| c.in_flight.len)
    }

    /// Waits (blocking, up to the reply timeout) until every request in flight is answered
    /// and checked.
    ///
    /// # Errors
    /// [`XArmError::Timeout`] and link errors.
    pub fn flush(&mut self) -> Result<(), XArmError> {
        let deadline = Instant::now() + self.cfg.reply_timeout;
        while self.in_flight() > 0 {
            let now = self.mono_ns();
            self.drain_replies(now, usize::MAX)?;
            if Instant::now() > deadline {
                return Err(self.lose(XArmError::Timeout));
            }
            std::thread::sleep(Duration::from_micros(100));
        }
        Ok(())
    }

    /// Drops the connection (as if it had been lost); the next `read_state` reconnects.
    pub fn disconnect(&mut self) {
        self.lose(XArmError::Disconnected);
        if let Some(c) = self.conn.as_mut() {
            c.in_flight.clear();
        }
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
    fn response_view(&self, register: Register) -> Response<'_> {
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
