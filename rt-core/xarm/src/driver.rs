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
//! On a lost connection the driver stops commanding; a helper thread re-opens the link with
//! exponential back-off (see [`crate::reconnect`]), so `read_state` never blocks, and after
//! the hand-over the driver resumes from the re-read joints: the next target must lie within
//! `max_resume_step_rad` of them (no jump). Every link, the first and each re-open, is
//! opened by [`crate::session::Session::open`].

use std::io::{ErrorKind, Read};
use std::time::{Duration, Instant};

use crate::codec::{
    self, FrameError, JointTarget, Register, Request, Response, SERVOJ_FRAME_LEN, STATUS_ERROR,
    STATUS_NOT_READY, VersionInfo,
};
use crate::codes::{ControllerError, ControllerWarning};
pub use crate::config::XArmConfig;
pub use crate::error::XArmError;
use crate::limits::check_xarm5_joints;
use crate::reconnect::Reconnector;
use crate::report::{self, ArmReport};
use crate::session::Session;
pub use crate::session::{CallReply, MAX_IN_FLIGHT};

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

/// Outcome of one checked reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ReplyEvent {
    Ok,
    NotReady,
    ErrorCode(u8, u8),
}

/// The report's controller state when stopped (by an error, or by a stop request).
const REPORT_STATE_STOPPED: u8 = 4;

/// The xArm5 driver.
pub struct XArmDriver {
    cfg: XArmConfig,
    conn: Option<Session>,
    version: Option<VersionInfo>,
    state: Option<DriverState>,
    prev_q: Option<([f64; 5], u64)>,
    error: ControllerError,
    warning: ControllerWarning,
    error_bit_seen: bool,
    /// The last report said "stopped" (state 4) without carrying a code (the 30001/30003
    /// reports have none) while no error is known: `GET_ERROR` is asked, rate-limited by
    /// `error_poll_ns`, so a controller that stops while nothing is sent is still named by
    /// its error. Without it the code was learnt only from a reply's error bit, i.e. only
    /// when a command happened to be in flight when the error was raised.
    stopped_unexplained: bool,
    not_ready_seen: bool,
    resume_from: Option<[f64; 5]>,
    reconnects: u32,
    servo_mode_wanted: bool,
    stats: DriverStats,
    servo_frame: [u8; SERVOJ_FRAME_LEN],
    origin: Instant,
    /// When `GET_ERROR` was last asked while an error stands (ns).
    last_error_poll_ns: u64,
    /// An acknowledgement is under way until the reply to its last request (this
    /// transaction id): error codes read meanwhile (reports, `GET_ERROR` replies) predate
    /// the `CLEAN_ERROR` and are ignored.
    acknowledging: Option<u16>,
    /// Re-opens a lost link off the caller's thread: the one reconnect path.
    reconnector: Reconnector,
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
        let session = Session::open(&cfg)?;
        let reconnector = Reconnector::spawn(cfg.clone()).map_err(|e| XArmError::Io(e.kind()))?;
        let mut d = Self {
            version: session.version(),
            error: session.error,
            warning: session.warning,
            error_bit_seen: session.error != ControllerError::None,
            stopped_unexplained: false,
            conn: Some(session),
            cfg,
            state: None,
            prev_q: None,
            not_ready_seen: false,
            resume_from: None,
            reconnects: 0,
            servo_mode_wanted: false,
            stats: DriverStats::default(),
            servo_frame: [0; SERVOJ_FRAME_LEN],
            origin: Instant::now(),
            last_error_poll_ns: 0,
            acknowledging: None,
            reconnector,
        };
        d.wait_for_first_report()?;
        Ok(d)
    }

    fn mono_ns(&self) -> u64 {
        self.origin.elapsed().as_nanos() as u64
    }

    /// Waits for the first report (the controller streams at ≥ 5 Hz).
    fn wait_for_first_report(&mut self) -> Result<(), XArmError> {
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

    /// The settings.
    pub fn config(&self) -> &XArmConfig {
        &self.cfg
    }

    /// Counters of the command channel.
    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    /// Error and warning last known to the driver.
    pub fn error_warning(&self) -> (ControllerError, ControllerWarning) {
        (self.error, self.warning)
    }

    /// Whether the reconnect helper is inside a connection attempt now, and how many
    /// attempts it has made.
    pub fn reconnect_progress(&self) -> Option<(bool, u32)> {
        Some((self.reconnector.busy(), self.reconnector.attempts()))
    }

    /// One blocking request/response (setup and tools, not the cycle). Waits for replies
    /// in flight first.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn call(&mut self, req: &Request) -> Result<CallReply, XArmError> {
        self.blocking(|s, timeout| s.call(req, timeout))
    }

    /// Runs one blocking step of the session on an empty pipeline (replies in flight are
    /// drained and checked first). A link failure loses the connection (the reconnect
    /// helper takes over); an error bit seen in a reply is remembered, so the code is read.
    fn blocking<T>(
        &mut self,
        step: impl FnOnce(&mut Session, Duration) -> Result<T, XArmError>,
    ) -> Result<T, XArmError> {
        let timeout = self.cfg.reply_timeout;
        let deadline = Instant::now() + timeout;
        while self.conn.as_ref().is_some_and(|c| c.in_flight.len > 0) {
            let now = self.mono_ns();
            self.drain_replies(now, usize::MAX)?;
            if Instant::now() > deadline {
                return Err(self.lose(XArmError::Timeout));
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        let session = self.conn.as_mut().ok_or(XArmError::Disconnected)?;
        let result = step(session, timeout);
        if session.take_error_flag() {
            self.error_bit_seen = true;
        }
        match result {
            Err(
                e @ (XArmError::Disconnected
                | XArmError::Io(_)
                | XArmError::Timeout
                | XArmError::Frame(_)),
            ) => Err(self.lose(e)),
            other => other,
        }
    }

    /// Records the error and warning the session has just read with `GET_ERROR`.
    fn take_session_error(&mut self) {
        if let Some(s) = self.conn.as_ref() {
            self.error = s.error;
            self.warning = s.warning;
            self.error_bit_seen = self.error != ControllerError::None;
        }
    }

    /// Reads `GET_ERROR` (blocking) and records it.
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn refresh_error(&mut self) -> Result<(ControllerError, ControllerWarning), XArmError> {
        let read = self.blocking(Session::refresh_error)?;
        self.take_session_error();
        Ok(read)
    }

    /// `GET_STATE` (blocking).
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn get_state(&mut self) -> Result<u8, XArmError> {
        self.blocking(Session::get_state)
    }

    /// `GET_JOINT_POS` (blocking): the five joints (rad).
    ///
    /// # Errors
    /// [`XArmError`], [`FrameError::NonFinite`] inside.
    pub fn get_joints(&mut self) -> Result<[f64; 5], XArmError> {
        self.blocking(Session::get_joints)
    }

    /// `GET_TCP_POSE` (blocking): x, y, z (mm), roll, pitch, yaw (rad).
    ///
    /// # Errors
    /// [`XArmError`].
    pub fn get_tcp_pose(&mut self) -> Result<[f32; 6], XArmError> {
        self.blocking(Session::get_tcp_pose)
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
        let result = self.blocking(Session::enter_servo_mode);
        if matches!(
            result,
            Ok(_) | Err(XArmError::Controller(_) | XArmError::NotReady { .. })
        ) {
            // The step read GET_ERROR before deciding.
            self.take_session_error();
        }
        let q = result?;
        self.servo_mode_wanted = true;
        self.not_ready_seen = false;
        self.resume_from = None;
        Ok(q)
    }

    /// An operator acknowledged a protective stop: clears the error and the warning and
    /// re-enables servo mode (enable all, mode 1, state 0), pipelined without blocking. The
    /// next target must lie within `max_resume_step_rad` of the last reported joints. If the
    /// error persists, the replies' error bit brings it back. Never called by the driver or
    /// the runtime on their own.
    ///
    /// # Errors
    /// [`XArmError::Disconnected`] without a link, [`XArmError::Backlog`] with a full
    /// pipeline, link errors.
    pub fn acknowledge(&mut self, now_ns: u64) -> Result<(), XArmError> {
        if self.conn.is_none() {
            return Err(XArmError::Disconnected);
        }
        self.drain_replies(now_ns, usize::MAX)?;
        let requests = [
            Request::CleanError,
            Request::CleanWarn,
            Request::MotionEnable {
                servo_id: 8,
                enable: true,
            },
            Request::SetMode {
                mode: 1,
                detection: Some(0),
            },
            Request::SetState(0),
            // Last: the authoritative answer whether the error is gone (reports and replies
            // read before it may still carry the old code and are ignored).
            Request::GetError,
        ];
        let conn = self.conn.as_mut().ok_or(XArmError::Disconnected)?;
        if conn.error_query_in_flight {
            return Err(XArmError::Backlog);
        }
        if conn.in_flight.len + requests.len() > MAX_IN_FLIGHT {
            return Err(XArmError::Backlog);
        }
        for r in &requests {
            if let Err(e) = conn.send_request(r, now_ns) {
                return Err(self.lose(e));
            }
        }
        conn.error_query_in_flight = true;
        self.acknowledging = Some(conn.last_tid());
        self.error = ControllerError::None;
        self.warning = ControllerWarning::None;
        self.error_bit_seen = false;
        self.stopped_unexplained = false;
        self.not_ready_seen = false;
        self.servo_mode_wanted = true;
        self.resume_from = self.state.map(|s| s.report.joints5_rad());
        Ok(())
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
            // The helper logs, closes the dead sockets and reconnects.
            self.reconnector.request(
                why,
                self.servo_mode_wanted && self.cfg.resume_after_reconnect,
                Some(dead),
            );
        }
        self.state = None;
        self.prev_q = None;
        why
    }

    /// Installs the connection the helper re-opened, if it has one; never blocks.
    fn try_reconnect(&mut self) -> Result<(), XArmError> {
        let Some(new) = self.reconnector.take() else {
            self.reconnector.request(
                XArmError::Disconnected,
                self.servo_mode_wanted && self.cfg.resume_after_reconnect,
                None,
            );
            return Err(XArmError::Disconnected);
        };
        self.version = new.session.version();
        self.error = new.session.error;
        self.warning = new.session.warning;
        self.conn = Some(new.session);
        self.error_bit_seen = self.error != ControllerError::None;
        self.stopped_unexplained = false;
        self.not_ready_seen = false;
        self.state = None;
        self.prev_q = None;
        self.resume_from = Some(new.q_rad);
        // Without automatic resumption the new link is not in servo mode: motion waits for
        // an operator's acknowledgement.
        self.servo_mode_wanted = self.servo_mode_wanted && self.cfg.resume_after_reconnect;
        self.reconnects += 1;
        Ok(())
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
        if self.acknowledging == Some(expect.tid) {
            self.acknowledging = None;
        }
        let event = if expect.register == u8::from(Register::GetError) {
            conn.error_query_in_flight = false;
            let (e, w) = r.err_warn()?;
            ReplyEvent::ErrorCode(e, w)
        } else if r.status & STATUS_ERROR != 0 {
            self.stats.error_replies += 1;
            // During an acknowledgement the replies still carry the bit of the error
            // being cleared.
            self.error_bit_seen |= self.acknowledging.is_none();
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
                Ok(Some(ReplyEvent::ErrorCode(..))) if self.acknowledging.is_some() => {}
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
        // An error bit with an unknown code: ask for it (pipelined). A known error is
        // re-read every `error_poll_ns` until it reads cleared (the operator may clear it on
        // the controller; the 30003 report carries no code).
        let poll_due = (self.error != ControllerError::None || self.stopped_unexplained)
            && now_ns.saturating_sub(self.last_error_poll_ns) >= self.cfg.error_poll_ns;
        if ((self.error_bit_seen && self.error == ControllerError::None) || poll_due)
            && let Some(c) = self.conn.as_mut()
            && !c.error_query_in_flight
            && c.send_request(&Request::GetError, now_ns).is_ok()
        {
            c.error_query_in_flight = true;
            self.last_error_poll_ns = now_ns;
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
            if let Some(e) = r.error_code
                && self.acknowledging.is_none()
            {
                self.error = ControllerError::from(e);
                self.error_bit_seen = e != 0;
            }
            self.stopped_unexplained = r.error_code.is_none()
                && r.state == REPORT_STATE_STOPPED
                && self.acknowledging.is_none()
                && self.error == ControllerError::None;
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
    /// is down this is where the connection the reconnect helper re-opened is taken over
    /// (never blocks).
    ///
    /// # Errors
    /// [`XArmError::Disconnected`] while down, [`XArmError::NoState`] when stale,
    /// [`XArmError::Controller`] when the controller reports an error (the state is still
    /// readable through [`XArmDriver::last_state`]).
    pub fn read_state(&mut self, now_ns: u64) -> Result<DriverState, XArmError> {
        if self.conn.is_none() {
            self.try_reconnect()?;
        }
        self.drain_replies(now_ns, self.cfg.reply_budget)?;
        self.drain_reports(now_ns)?;
        let mut s = self.state.ok_or(XArmError::NoState)?;
        // The codes as known now (an acknowledgement may have cleared them since the
        // last report was decoded).
        s.error = self.error;
        s.warning = self.warning;
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
