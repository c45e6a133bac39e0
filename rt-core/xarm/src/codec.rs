//! Allocation-free framing of the xArm controller's command channel (TCP port 502).
//!
//! A request is `tid:u16 BE | protocol:u16 BE | length:u16 BE | register:u8 | payload`,
//! with `length = 1 + payload`. A response echoes tid, protocol and register, then carries a
//! status byte and data: `length = 2 + data`. Floats and `i32`s inside payloads are
//! little-endian; `u16`s inside payloads are big-endian. Joint arrays are always 7 slots on the
//! wire; on the xArm5 slots 6 and 7 are zero.
//!
//! Everything here works on caller-provided byte slices: no allocation, no panics on any
//! input (the decoders are property-tested and fuzzed).

use thiserror::Error;

/// Protocol id used while connecting (the `GET_VERSION` handshake).
pub const PROTOCOL_CONNECT: u16 = 2;
/// Protocol id used after the handshake ("private protocol with heartbeat").
pub const PROTOCOL_PRIVATE: u16 = 3;
/// Protocol id of the SDK's optional raw heartbeat frame (no reply expected).
pub const PROTOCOL_HEARTBEAT: u16 = 1;
/// Protocol id of standard Modbus-TCP.
pub const PROTOCOL_MODBUS: u16 = 0;

/// Bytes before the length-counted part of a frame (tid, protocol, length).
pub const PREFIX_LEN: usize = 6;
/// Largest frame this codec accepts (prefix included). Longer length fields are rejected.
pub const MAX_FRAME_LEN: usize = 1024;
/// Joint slots on the wire.
pub const WIRE_JOINTS: usize = 7;
/// Axes of the xArm5.
pub const XARM5_AXES: usize = 5;
/// Length of the version string field in a `GET_VERSION` reply.
pub const VERSION_LEN: usize = 40;
/// Size of an encoded `MOVE_SERVOJ` / `MOVE_JOINT` request frame.
pub const SERVOJ_FRAME_LEN: usize = PREFIX_LEN + 1 + 40;

/// Status bit: the controller has an uncleared error.
pub const STATUS_ERROR: u8 = 0x40;
/// Status bit: the controller has an uncleared warning.
pub const STATUS_WARNING: u8 = 0x20;
/// Status bit: the robot cannot move (stopped, not enabled, error, ...).
pub const STATUS_NOT_READY: u8 = 0x10;
/// Status bit the SDK treats as "result invalid".
pub const STATUS_INVALID: u8 = 0x08;

/// A command register (the byte at frame offset 6). Total mapping from `u8`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Register {
    /// 0x01: version string.
    GetVersion,
    /// 0x02: robot serial numbers.
    GetRobotSn,
    /// 0x0B: enable/disable servos.
    MotionEnable,
    /// 0x0C: set state (0 start, 3 pause, 4 stop, 6 decelerate).
    SetState,
    /// 0x0D: get state.
    GetState,
    /// 0x0E: number of queued commands.
    GetCmdNum,
    /// 0x0F: error and warning codes.
    GetError,
    /// 0x10: clear the error.
    CleanError,
    /// 0x11: clear the warning.
    CleanWarn,
    /// 0x13: set mode.
    SetMode,
    /// 0x17: planned joint move.
    MoveJoint,
    /// 0x1D: servo_j streaming target.
    MoveServoJ,
    /// 0x1E: servo_cartesian streaming target.
    MoveServoCart,
    /// 0x1F: TCP jerk (mm/s³).
    SetTcpJerk,
    /// 0x20: TCP max acceleration (mm/s²).
    SetTcpMaxAcc,
    /// 0x21: joint jerk (rad/s³).
    SetJointJerk,
    /// 0x22: joint max acceleration (rad/s²).
    SetJointMaxAcc,
    /// 0x29: TCP pose.
    GetTcpPose,
    /// 0x2A: joint positions.
    GetJointPos,
    /// 0x5B: TCP pose, axis-angle orientation.
    GetTcpPoseAa,
    /// 0xF0: Foresight's own, not the xArm's: `xarm-sim` proves it holds the run's secret
    /// ([`crate::sim_identity`]). The SDK names no register 0xF0; a real controller answers
    /// it as it answers any register it does not have.
    SimIdentity,
    /// 0xFD: feedback check.
    FeedbackCheck,
    /// 0xFE: feedback type mask.
    SetFeedbackType,
    /// 0xFF: unsolicited feedback frame from the controller.
    Feedback,
    /// Any other register byte.
    Unknown(u8),
}

impl From<u8> for Register {
    fn from(b: u8) -> Self {
        match b {
            0x01 => Self::GetVersion,
            0x02 => Self::GetRobotSn,
            0x0B => Self::MotionEnable,
            0x0C => Self::SetState,
            0x0D => Self::GetState,
            0x0E => Self::GetCmdNum,
            0x0F => Self::GetError,
            0x10 => Self::CleanError,
            0x11 => Self::CleanWarn,
            0x13 => Self::SetMode,
            0x17 => Self::MoveJoint,
            0x1D => Self::MoveServoJ,
            0x1E => Self::MoveServoCart,
            0x1F => Self::SetTcpJerk,
            0x20 => Self::SetTcpMaxAcc,
            0x21 => Self::SetJointJerk,
            0x22 => Self::SetJointMaxAcc,
            0x29 => Self::GetTcpPose,
            0x2A => Self::GetJointPos,
            0x5B => Self::GetTcpPoseAa,
            0xF0 => Self::SimIdentity,
            0xFD => Self::FeedbackCheck,
            0xFE => Self::SetFeedbackType,
            0xFF => Self::Feedback,
            other => Self::Unknown(other),
        }
    }
}

impl From<Register> for u8 {
    fn from(r: Register) -> u8 {
        match r {
            Register::GetVersion => 0x01,
            Register::GetRobotSn => 0x02,
            Register::MotionEnable => 0x0B,
            Register::SetState => 0x0C,
            Register::GetState => 0x0D,
            Register::GetCmdNum => 0x0E,
            Register::GetError => 0x0F,
            Register::CleanError => 0x10,
            Register::CleanWarn => 0x11,
            Register::SetMode => 0x13,
            Register::MoveJoint => 0x17,
            Register::MoveServoJ => 0x1D,
            Register::MoveServoCart => 0x1E,
            Register::SetTcpJerk => 0x1F,
            Register::SetTcpMaxAcc => 0x20,
            Register::SetJointJerk => 0x21,
            Register::SetJointMaxAcc => 0x22,
            Register::GetTcpPose => 0x29,
            Register::GetJointPos => 0x2A,
            Register::GetTcpPoseAa => 0x5B,
            Register::SimIdentity => 0xF0,
            Register::FeedbackCheck => 0xFD,
            Register::SetFeedbackType => 0xFE,
            Register::Feedback => 0xFF,
            Register::Unknown(b) => b,
        }
    }
}

/// A joint-space motion target as it goes on the wire (`MOVE_SERVOJ` / `MOVE_JOINT`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointTarget {
    /// J1..J7 (rad); slots past the axis count are zero.
    pub joints_rad: [f32; WIRE_JOINTS],
    /// Speed (rad/s); ignored by the controller for servo_j.
    pub speed_rad_s: f32,
    /// Acceleration (rad/s²); ignored by the controller for servo_j.
    pub acc_rad_s2: f32,
    /// Motion time (s); 0.
    pub mvtime_s: f32,
}

impl JointTarget {
    /// The SDK's fresh default joint speed: 20°/s.
    pub const DEFAULT_SPEED_RAD_S: f32 = 0.349_065_85;
    /// The SDK's fresh default joint acceleration: 500°/s².
    pub const DEFAULT_ACC_RAD_S2: f32 = 8.726_646;

    /// An xArm5 target: five joints, slots 6 and 7 zero, SDK default speed/acceleration.
    pub fn xarm5(q_rad: &[f64; XARM5_AXES]) -> Self {
        let mut joints_rad = [0.0f32; WIRE_JOINTS];
        for (slot, q) in joints_rad.iter_mut().zip(q_rad) {
            *slot = *q as f32;
        }
        Self {
            joints_rad,
            speed_rad_s: Self::DEFAULT_SPEED_RAD_S,
            acc_rad_s2: Self::DEFAULT_ACC_RAD_S2,
            mvtime_s: 0.0,
        }
    }
}

/// A request the driver sends (and the simulator parses).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// `GET_VERSION`.
    GetVersion,
    /// `GET_ROBOT_SN`.
    GetRobotSn,
    /// `MOTION_EN`: servo id 1..7, 8 = all.
    MotionEnable {
        /// Servo id (8 = all).
        servo_id: u8,
        /// Enable (true) or disable.
        enable: bool,
    },
    /// `SET_STATE`.
    SetState(u8),
    /// `GET_STATE`.
    GetState,
    /// `GET_CMDNUM`.
    GetCmdNum,
    /// `GET_ERROR`.
    GetError,
    /// `CLEAN_ERR`.
    CleanError,
    /// `CLEAN_WAR`.
    CleanWarn,
    /// `SET_MODE` (firmware ≥ 1.10: mode and detection parameter).
    SetMode {
        /// Mode (1 = servo).
        mode: u8,
        /// Detection parameter (the SDK sends 0); `None` for the old 1-byte form.
        detection: Option<u8>,
    },
    /// `MOVE_JOINT`.
    MoveJoint(JointTarget),
    /// `MOVE_SERVOJ`.
    ServoJ(JointTarget),
    /// `MOVE_SERVO_CART`: pose (mm, rad), speed, acc, tool-frame flag.
    ServoCart {
        /// x, y, z (mm), roll, pitch, yaw (rad).
        pose: [f32; 6],
        /// Speed (mm/s).
        speed_mm_s: f32,
        /// Acceleration (mm/s²).
        acc_mm_s2: f32,
        /// Tool-frame coordinates (sent as an f32 1.0/0.0).
        tool_frame: bool,
    },
    /// `SET_TCP_JERK` (mm/s³).
    SetTcpJerk(f32),
    /// `SET_TCP_MAXACC` (mm/s²).
    SetTcpMaxAcc(f32),
    /// `SET_JOINT_JERK` (rad/s³).
    SetJointJerk(f32),
    /// `SET_JOINT_MAXACC` (rad/s²).
    SetJointMaxAcc(f32),
    /// `GET_TCP_POSE`.
    GetTcpPose,
    /// `GET_JOINT_POS`; `Some(n)` is the `get_joint_states` variant (n = 1..3).
    GetJointPos(Option<u8>),
    /// `GET_TCP_POSE_AA`.
    GetTcpPoseAa,
    /// `SET_FEEDBACK_TYPE` bitmask.
    SetFeedbackType(u8),
    /// `FEEDBACK_CHECK`.
    FeedbackCheck,
    /// Foresight's identity challenge (register 0xF0, [`crate::sim_identity`]): a fresh
    /// nonce; `xarm-sim` answers with its proof, a real controller as to any unknown register.
    SimIdentity([u8; SIM_NONCE_LEN]),
}

/// Bytes of the identity challenge's nonce ([`Request::SimIdentity`]'s payload; the wire's
/// side of [`crate::sim_identity::NONCE_LEN`]).
pub const SIM_NONCE_LEN: usize = 16;

/// Why a frame could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum EncodeError {
    /// The output buffer is too small for the frame.
    #[error("output buffer of {have} bytes cannot hold a {need}-byte frame")]
    BufferTooSmall {
        /// Bytes needed.
        need: usize,
        /// Bytes available.
        have: usize,
    },
}

/// Why bytes from the wire are not a valid frame (or not the frame we expected).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum FrameError {
    /// Fewer bytes than the frame needs.
    #[error("truncated frame: {have} of {need} bytes")]
    Truncated {
        /// Bytes needed.
        need: usize,
        /// Bytes present.
        have: usize,
    },
    /// The length field is below the minimum for this kind of frame.
    #[error("length field {length} too small")]
    LengthTooSmall {
        /// The length field.
        length: u16,
    },
    /// The length field exceeds [`MAX_FRAME_LEN`].
    #[error("length field {length} exceeds the maximum frame size")]
    LengthTooLarge {
        /// The length field.
        length: u16,
    },
    /// A register this codec does not know.
    #[error("unknown register 0x{0:02x}")]
    UnknownRegister(u8),
    /// The payload length does not fit the register.
    #[error("register 0x{register:02x}: payload of {len} bytes is invalid")]
    BadPayload {
        /// The register.
        register: u8,
        /// Payload length.
        len: usize,
    },
    /// A reply's transaction id does not match the request.
    #[error("transaction id {got} where {want} was expected")]
    TransactionMismatch {
        /// Expected.
        want: u16,
        /// Received.
        got: u16,
    },
    /// A reply's protocol id does not match the request (SDK code 6).
    #[error("protocol id {got} where {want} was expected")]
    ProtocolMismatch {
        /// Expected.
        want: u16,
        /// Received.
        got: u16,
    },
    /// A reply's register does not match the request (SDK code 7).
    #[error("register 0x{got:02x} where 0x{want:02x} was expected")]
    RegisterMismatch {
        /// Expected.
        want: u8,
        /// Received.
        got: u8,
    },
    /// A float in the data was NaN or infinite.
    #[error("non-finite number in the data")]
    NonFinite,
    /// The version string is not `<axis>,<type>,<sn>,<boxsn>,v<maj>.<min>.<rev>`.
    #[error("unparsable version string")]
    BadVersion,
}

/// The fixed prefix of every frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    /// Transaction id.
    pub tid: u16,
    /// Protocol id.
    pub protocol: u16,
    /// Length field (bytes after the prefix).
    pub length: u16,
}

impl FrameHeader {
    /// Total frame size (prefix + length).
    pub fn frame_len(&self) -> usize {
        PREFIX_LEN + self.length as usize
    }
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

/// Reads a little-endian `f32` at `at`; the caller guarantees `at + 4 <= b.len()`.
pub(crate) fn le_f32(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn put_f32(out: &mut [u8], at: usize, v: f32) {
    out[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// Looks at the start of a byte stream: `Ok(None)` if fewer than a whole frame's bytes are
/// buffered yet, `Ok(Some(len))` with the size of the first frame, or an error if the length
/// field is impossible (`min_length` is 1 for requests, 2 for responses).
///
/// # Errors
/// [`FrameError::LengthTooSmall`] / [`FrameError::LengthTooLarge`].
pub fn frame_len(buf: &[u8], min_length: u16) -> Result<Option<usize>, FrameError> {
    if buf.len() < PREFIX_LEN {
        return Ok(None);
    }
    let length = be16(buf, 4);
    if length < min_length {
        return Err(FrameError::LengthTooSmall { length });
    }
    let total = PREFIX_LEN + length as usize;
    if total > MAX_FRAME_LEN {
        return Err(FrameError::LengthTooLarge { length });
    }
    Ok((buf.len() >= total).then_some(total))
}

fn header(frame: &[u8], min_length: u16) -> Result<FrameHeader, FrameError> {
    match frame_len(frame, min_length)? {
        Some(_) => Ok(FrameHeader {
            tid: be16(frame, 0),
            protocol: be16(frame, 2),
            length: be16(frame, 4),
        }),
        None => {
            let need = if frame.len() < PREFIX_LEN {
                PREFIX_LEN + min_length as usize
            } else {
                PREFIX_LEN + be16(frame, 4) as usize
            };
            Err(FrameError::Truncated {
                need,
                have: frame.len(),
            })
        }
    }
}

/// A response frame, borrowed from the receive buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Response<'a> {
    /// Prefix fields.
    pub header: FrameHeader,
    /// Register byte as sent.
    pub register: u8,
    /// Status byte (see `STATUS_*`).
    pub status: u8,
    /// Data bytes after the status byte.
    pub data: &'a [u8],
}

impl<'a> Response<'a> {
    /// Parses one whole response frame (exactly the bytes [`frame_len`] reported; trailing
    /// bytes are ignored).
    ///
    /// # Errors
    /// [`FrameError`] for truncated frames and impossible length fields.
    pub fn parse(frame: &'a [u8]) -> Result<Self, FrameError> {
        let header = header(frame, 2)?;
        let end = header.frame_len();
        Ok(Self {
            header,
            register: frame[6],
            status: frame[7],
            data: &frame[8..end],
        })
    }

    /// Checks that this frame answers request (`tid`, `protocol`, `register`), in the SDK's
    /// order: transaction id, then protocol id, then register.
    ///
    /// # Errors
    /// The first mismatch.
    pub fn check(&self, tid: u16, protocol: u16, register: u8) -> Result<(), FrameError> {
        if self.header.tid != tid {
            return Err(FrameError::TransactionMismatch {
                want: tid,
                got: self.header.tid,
            });
        }
        if self.header.protocol != protocol {
            return Err(FrameError::ProtocolMismatch {
                want: protocol,
                got: self.header.protocol,
            });
        }
        if self.register != register {
            return Err(FrameError::RegisterMismatch {
                want: register,
                got: self.register,
            });
        }
        Ok(())
    }

    fn need(&self, n: usize) -> Result<&'a [u8], FrameError> {
        if self.data.len() < n {
            return Err(FrameError::BadPayload {
                register: self.register,
                len: self.data.len(),
            });
        }
        Ok(&self.data[..n])
    }

    /// `GET_STATE` data: the state byte.
    ///
    /// # Errors
    /// [`FrameError::BadPayload`] if the data is empty.
    pub fn state(&self) -> Result<u8, FrameError> {
        Ok(self.need(1)?[0])
    }

    /// `GET_ERROR` data: (error code, warning code).
    ///
    /// # Errors
    /// [`FrameError::BadPayload`] if shorter than 2 bytes.
    pub fn err_warn(&self) -> Result<(u8, u8), FrameError> {
        let d = self.need(2)?;
        Ok((d[0], d[1]))
    }

    /// `GET_CMDNUM` data.
    ///
    /// # Errors
    /// [`FrameError::BadPayload`] if shorter than 2 bytes.
    pub fn cmdnum(&self) -> Result<u16, FrameError> {
        let d = self.need(2)?;
        Ok(u16::from_be_bytes([d[0], d[1]]))
    }

    /// `GET_JOINT_POS` data: the first 7 floats (rad), all finite.
    ///
    /// # Errors
    /// [`FrameError::BadPayload`] if shorter than 28 bytes, [`FrameError::NonFinite`].
    pub fn joints(&self) -> Result<[f32; WIRE_JOINTS], FrameError> {
        floats::<WIRE_JOINTS>(self.need(4 * WIRE_JOINTS)?)
    }

    /// `GET_TCP_POSE` data: x, y, z (mm), roll, pitch, yaw (rad), all finite.
    ///
    /// # Errors
    /// [`FrameError::BadPayload`] if shorter than 24 bytes, [`FrameError::NonFinite`].
    pub fn tcp_pose(&self) -> Result<[f32; 6], FrameError> {
        floats::<6>(self.need(24)?)
    }

    /// `GET_VERSION` data, parsed.
    ///
    /// # Errors
    /// [`FrameError::BadVersion`] if it does not look like a version string.
    pub fn version(&self) -> Result<VersionInfo, FrameError> {
        VersionInfo::parse(self.data)
    }
}

fn floats<const N: usize>(d: &[u8]) -> Result<[f32; N], FrameError> {
    let mut out = [0.0f32; N];
    for (i, v) in out.iter_mut().enumerate() {
        *v = le_f32(d, 4 * i);
        if !v.is_finite() {
            return Err(FrameError::NonFinite);
        }
    }
    Ok(out)
}

/// Robot type of an xArm5 in the `GET_VERSION` string (the SDK's `XARM5_X4`).
pub const XARM5_ROBOT_TYPE: u8 = 5;

/// What a `GET_VERSION` reply says, parsed without allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VersionInfo {
    /// Axis count (5 on the xArm5).
    pub axis: u8,
    /// Robot type (5 = xArm5).
    pub robot_type: u8,
    /// Firmware major, minor, revision.
    pub firmware: [u16; 3],
    /// The raw string, NUL-padded.
    pub raw: [u8; VERSION_LEN],
    /// Bytes of `raw` before the first NUL.
    pub raw_len: u8,
}

impl VersionInfo {
    /// Parses `<axis>,<type>,<sn>,<boxsn>,v<maj>.<min>.<rev>` (NUL-padded).
    ///
    /// # Errors
    /// [`FrameError::BadVersion`].
    pub fn parse(data: &[u8]) -> Result<Self, FrameError> {
        let n = data.iter().position(|b| *b == 0).unwrap_or(data.len());
        let text = &data[..n.min(VERSION_LEN)];
        let s = core::str::from_utf8(text).map_err(|_| FrameError::BadVersion)?;
        let mut parts = s.split(',');
        let num = |p: Option<&str>| -> Result<u8, FrameError> {
            p.and_then(|x| x.trim().parse::<u8>().ok())
                .ok_or(FrameError::BadVersion)
        };
        let axis = num(parts.next())?;
        let robot_type = num(parts.next())?;
        let _sn = parts.next().ok_or(FrameError::BadVersion)?;
        let _box_sn = parts.next().ok_or(FrameError::BadVersion)?;
        let ver = parts.next().ok_or(FrameError::BadVersion)?;
        let ver = ver.trim().strip_prefix('v').ok_or(FrameError::BadVersion)?;
        let mut firmware = [0u16; 3];
        let mut it = ver.split('.');
        for f in firmware.iter_mut() {
            *f = it
                .next()
                .and_then(|x| x.parse::<u16>().ok())
                .ok_or(FrameError::BadVersion)?;
        }
        let mut raw = [0u8; VERSION_LEN];
        raw[..text.len()].copy_from_slice(text);
        Ok(Self {
            axis,
            robot_type,
            firmware,
            raw,
            raw_len: text.len() as u8,
        })
    }

    /// Whether the controller says it is an xArm5: robot type [`XARM5_ROBOT_TYPE`]
    /// (the SDK's `XARM5_X4`, its only xArm5 type) with [`XARM5_AXES`] axes. Any other arm
    /// (an xArm6/7 would get J6/J7 = 0 from us) is refused at the handshake.
    pub fn is_xarm5(&self) -> bool {
        usize::from(self.axis) == XARM5_AXES && self.robot_type == XARM5_ROBOT_TYPE
    }

    /// The version string as text.
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(&self.raw[..self.raw_len as usize]).unwrap_or("")
    }
}

fn write_prefix(out: &mut [u8], tid: u16, protocol: u16, length: u16) {
    out[0..2].copy_from_slice(&tid.to_be_bytes());
    out[2..4].copy_from_slice(&protocol.to_be_bytes());
    out[4..6].copy_from_slice(&length.to_be_bytes());
}

fn put_joint_target(out: &mut [u8], t: &JointTarget) {
    for (i, q) in t.joints_rad.iter().enumerate() {
        put_f32(out, 7 + 4 * i, *q);
    }
    put_f32(out, 35, t.speed_rad_s);
    put_f32(out, 39, t.acc_rad_s2);
    put_f32(out, 43, t.mvtime_s);
}

impl Request {
    /// The register this request goes to.
    pub fn register(&self) -> Register {
        match self {
            Self::GetVersion => Register::GetVersion,
            Self::GetRobotSn => Register::GetRobotSn,
            Self::MotionEnable { .. } => Register::MotionEnable,
            Self::SetState(_) => Register::SetState,
            Self::GetState => Register::GetState,
            Self::GetCmdNum => Register::GetCmdNum,
            Self::GetError => Register::GetError,
            Self::CleanError => Register::CleanError,
            Self::CleanWarn => Register::CleanWarn,
            Self::SetMode { .. } => Register::SetMode,
            Self::MoveJoint(_) => Register::MoveJoint,
            Self::ServoJ(_) => Register::MoveServoJ,
            Self::ServoCart { .. } => Register::MoveServoCart,
            Self::SetTcpJerk(_) => Register::SetTcpJerk,
            Self::SetTcpMaxAcc(_) => Register::SetTcpMaxAcc,
            Self::SetJointJerk(_) => Register::SetJointJerk,
            Self::SetJointMaxAcc(_) => Register::SetJointMaxAcc,
            Self::GetTcpPose => Register::GetTcpPose,
            Self::GetJointPos(_) => Register::GetJointPos,
            Self::GetTcpPoseAa => Register::GetTcpPoseAa,
            Self::SetFeedbackType(_) => Register::SetFeedbackType,
            Self::FeedbackCheck => Register::FeedbackCheck,
            Self::SimIdentity(_) => Register::SimIdentity,
        }
    }

    /// Payload size in bytes (after the register byte).
    pub fn payload_len(&self) -> usize {
        match self {
            Self::MotionEnable { .. } => 2,
            Self::SetState(_) | Self::SetFeedbackType(_) => 1,
            Self::SetMode { detection, .. } => 1 + usize::from(detection.is_some()),
            Self::MoveJoint(_) | Self::ServoJ(_) => 40,
            Self::ServoCart { .. } => 36,
            Self::SetTcpJerk(_)
            | Self::SetTcpMaxAcc(_)
            | Self::SetJointJerk(_)
            | Self::SetJointMaxAcc(_) => 4,
            Self::GetJointPos(n) => usize::from(n.is_some()),
            Self::SimIdentity(_) => SIM_NONCE_LEN,
            _ => 0,
        }
    }

    /// Encodes the whole frame into `out` and returns its length.
    ///
    /// # Errors
    /// [`EncodeError::BufferTooSmall`].
    ///
    /// # Performance
    /// No allocation; a servo_j frame is 47 bytes.
    pub fn encode(&self, tid: u16, protocol: u16, out: &mut [u8]) -> Result<usize, EncodeError> {
        let n = self.payload_len();
        let total = PREFIX_LEN + 1 + n;
        if out.len() < total {
            return Err(EncodeError::BufferTooSmall {
                need: total,
                have: out.len(),
            });
        }
        write_prefix(out, tid, protocol, (1 + n) as u16);
        out[6] = u8::from(self.register());
        match self {
            Self::MotionEnable { servo_id, enable } => {
                out[7] = *servo_id;
                out[8] = u8::from(*enable);
            }
            Self::SetState(s) | Self::SetFeedbackType(s) => out[7] = *s,
            Self::SetMode { mode, detection } => {
                out[7] = *mode;
                if let Some(d) = detection {
                    out[8] = *d;
                }
            }
            Self::MoveJoint(t) | Self::ServoJ(t) => put_joint_target(out, t),
            Self::ServoCart {
                pose,
                speed_mm_s,
                acc_mm_s2,
                tool_frame,
            } => {
                for (i, v) in pose.iter().enumerate() {
                    put_f32(out, 7 + 4 * i, *v);
                }
                put_f32(out, 31, *speed_mm_s);
                put_f32(out, 35, *acc_mm_s2);
                put_f32(out, 39, if *tool_frame { 1.0 } else { 0.0 });
            }
            Self::SetTcpJerk(v)
            | Self::SetTcpMaxAcc(v)
            | Self::SetJointJerk(v)
            | Self::SetJointMaxAcc(v) => put_f32(out, 7, *v),
            Self::GetJointPos(Some(k)) => out[7] = *k,
            Self::SimIdentity(nonce) => out[7..7 + nonce.len()].copy_from_slice(nonce),
            _ => {}
        }
        Ok(total)
    }

    /// Parses one whole request frame (as the controller does). Returns the prefix and the
    /// request.
    ///
    /// # Errors
    /// [`FrameError`] for truncated frames, impossible lengths, unknown registers and payloads
    /// of the wrong size.
    pub fn decode(frame: &[u8]) -> Result<(FrameHeader, Self), FrameError> {
        let h = header(frame, 1)?;
        let reg = frame[6];
        let p = &frame[7..h.frame_len()];
        let bad = || FrameError::BadPayload {
            register: reg,
            len: p.len(),
        };
        let exact = |n: usize| if p.len() == n { Ok(()) } else { Err(bad()) };
        let at_least = |n: usize| if p.len() >= n { Ok(()) } else { Err(bad()) };
        let joint_target = || {
            at_least(40)?;
            Ok::<_, FrameError>(joint_target_at(p))
        };
        let first_f32 = || {
            at_least(4)?;
            Ok::<_, FrameError>(le_f32(p, 0))
        };
        let req = match Register::from(reg) {
            Register::GetVersion => Self::GetVersion,
            Register::GetRobotSn => Self::GetRobotSn,
            Register::MotionEnable => {
                exact(2)?;
                Self::MotionEnable {
                    servo_id: p[0],
                    enable: p[1] != 0,
                }
            }
            Register::SetState => {
                at_least(1)?;
                Self::SetState(p[0])
            }
            Register::GetState => Self::GetState,
            Register::GetCmdNum => Self::GetCmdNum,
            Register::GetError => Self::GetError,
            Register::CleanError => Self::CleanError,
            Register::CleanWarn => Self::CleanWarn,
            Register::SetMode => {
                at_least(1)?;
                Self::SetMode {
                    mode: p[0],
                    detection: p.get(1).copied(),
                }
            }
            Register::MoveJoint => Self::MoveJoint(joint_target()?),
            Register::MoveServoJ => Self::ServoJ(joint_target()?),
            Register::MoveServoCart => {
                at_least(36)?;
                Self::servo_cart_at(p)
            }
            Register::SetTcpJerk => Self::SetTcpJerk(first_f32()?),
            Register::SetTcpMaxAcc => Self::SetTcpMaxAcc(first_f32()?),
            Register::SetJointJerk => Self::SetJointJerk(first_f32()?),
            Register::SetJointMaxAcc => Self::SetJointMaxAcc(first_f32()?),
            Register::GetTcpPose => Self::GetTcpPose,
            Register::GetJointPos => Self::GetJointPos(p.first().copied()),
            Register::GetTcpPoseAa => Self::GetTcpPoseAa,
            Register::SetFeedbackType => {
                at_least(1)?;
                Self::SetFeedbackType(p[0])
            }
            Register::FeedbackCheck => Self::FeedbackCheck,
            Register::SimIdentity => {
                exact(SIM_NONCE_LEN)?;
                let mut nonce = [0u8; SIM_NONCE_LEN];
                nonce.copy_from_slice(p);
                Self::SimIdentity(nonce)
            }
            Register::Feedback | Register::Unknown(_) => {
                return Err(FrameError::UnknownRegister(reg));
            }
        };
        Ok((h, req))
    }

    /// A Cartesian servo request from a payload of at least 36 bytes: the pose (6 × f32),
    /// speed, acceleration and the tool-frame flag.
    fn servo_cart_at(p: &[u8]) -> Self {
        let mut pose = [0.0f32; 6];
        for (i, v) in pose.iter_mut().enumerate() {
            *v = le_f32(p, 4 * i);
        }
        Self::ServoCart {
            pose,
            speed_mm_s: le_f32(p, 24),
            acc_mm_s2: le_f32(p, 28),
            tool_frame: le_f32(p, 32) != 0.0,
        }
    }
}

/// A joint target from a payload of at least 40 bytes: the joints (7 × f32), speed,
/// acceleration and move time.
fn joint_target_at(p: &[u8]) -> JointTarget {
    let mut joints_rad = [0.0f32; WIRE_JOINTS];
    for (i, q) in joints_rad.iter_mut().enumerate() {
        *q = le_f32(p, 4 * i);
    }
    JointTarget {
        joints_rad,
        speed_rad_s: le_f32(p, 28),
        acc_rad_s2: le_f32(p, 32),
        mvtime_s: le_f32(p, 36),
    }
}

/// Encodes a response frame (the simulator's side): echoes `tid`, `protocol`, `register`,
/// then `status` and `data`. Returns the frame length.
///
/// # Errors
/// [`EncodeError::BufferTooSmall`].
pub fn encode_response(
    tid: u16,
    protocol: u16,
    register: u8,
    status: u8,
    data: &[u8],
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let total = PREFIX_LEN + 2 + data.len();
    if out.len() < total || total > MAX_FRAME_LEN {
        return Err(EncodeError::BufferTooSmall {
            need: total,
            have: out.len().min(MAX_FRAME_LEN),
        });
    }
    write_prefix(out, tid, protocol, (2 + data.len()) as u16);
    out[6] = register;
    out[7] = status;
    out[8..total].copy_from_slice(data);
    Ok(total)
}

/// Encodes an xArm5 servo_j frame straight into a fixed buffer (the hot path of the driver).
pub fn encode_servo_j(tid: u16, target: &JointTarget, out: &mut [u8; SERVOJ_FRAME_LEN]) {
    write_prefix(out, tid, PROTOCOL_PRIVATE, 41);
    out[6] = 0x1D;
    put_joint_target(out, target);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        let s: String = s.split_whitespace().collect();
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    #[test]
    fn servo_j_matches_the_captured_sdk_frame() {
        let t = JointTarget::xarm5(&[0.1, -0.2, -0.3, 0.4, 0.5]);
        let mut out = [0u8; SERVOJ_FRAME_LEN];
        encode_servo_j(0x0102, &t, &mut out);
        let want = hex(
            "0102 0003 0029 1d cdcccc3d cdcc4cbe 9a9999be cdcccc3e 0000003f 00000000 00000000 \
             c2b8b23e 58a00b41 00000000",
        );
        assert_eq!(out.as_slice(), want.as_slice());
        let mut generic = [0u8; 64];
        let n = Request::ServoJ(t).encode(0x0102, 3, &mut generic).unwrap();
        assert_eq!(&generic[..n], want.as_slice());
    }

    #[test]
    fn small_requests_match_captures() {
        let cases: [(Request, &str); 6] = [
            (Request::GetVersion, "0001 0002 0001 01"),
            (
                Request::MotionEnable {
                    servo_id: 8,
                    enable: true,
                },
                "0001 0002 0003 0b 08 01",
            ),
            (
                Request::SetMode {
                    mode: 1,
                    detection: Some(0),
                },
                "0001 0002 0003 13 01 00",
            ),
            (Request::SetState(4), "0001 0002 0002 0c 04"),
            (Request::SetTcpJerk(1000.0), "0001 0002 0005 1f 00 00 7a 44"),
            (Request::GetJointPos(None), "0001 0002 0001 2a"),
        ];
        for (req, want) in cases {
            let mut out = [0u8; 64];
            let n = req.encode(1, 2, &mut out).unwrap();
            assert_eq!(&out[..n], hex(want).as_slice(), "{req:?}");
            let (h, back) = Request::decode(&out[..n]).unwrap();
            assert_eq!((h.tid, h.protocol), (1, 2));
            assert_eq!(back, req);
        }
    }

    #[test]
    fn responses_parse_and_check_in_sdk_order() {
        let f = hex("0007 0003 0003 0d 00 02");
        let r = Response::parse(&f).unwrap();
        assert_eq!(r.state().unwrap(), 2);
        assert!(r.check(7, 3, 0x0d).is_ok());
        assert_eq!(
            r.check(8, 2, 0x0c),
            Err(FrameError::TransactionMismatch { want: 8, got: 7 })
        );
        assert_eq!(
            r.check(7, 2, 0x0c),
            Err(FrameError::ProtocolMismatch { want: 2, got: 3 })
        );
        assert_eq!(
            r.check(7, 3, 0x0c),
            Err(FrameError::RegisterMismatch {
                want: 0x0c,
                got: 0x0d
            })
        );
        assert!(matches!(r.joints(), Err(FrameError::BadPayload { .. })));
    }

    #[test]
    fn version_string_parses() {
        let mut data = [0u8; 40];
        let s = b"5,5,XF1302,AC1302,v2.6.0";
        data[..s.len()].copy_from_slice(s);
        let v = VersionInfo::parse(&data).unwrap();
        assert_eq!((v.axis, v.robot_type, v.firmware), (5, 5, [2, 6, 0]));
        assert_eq!(v.as_str(), "5,5,XF1302,AC1302,v2.6.0");
        assert!(v.is_xarm5());
        for other in [
            "6,6,XI1202,AC1302,v1.12.10",
            "7,7,X,A,v2.0.0",
            "5,6,X,A,v2.0.0",
        ] {
            assert!(
                !VersionInfo::parse(other.as_bytes()).unwrap().is_xarm5(),
                "{other}"
            );
        }
        assert_eq!(VersionInfo::parse(b"5,5,x"), Err(FrameError::BadVersion));
        assert_eq!(VersionInfo::parse(b""), Err(FrameError::BadVersion));
    }

    #[test]
    fn bad_frames_are_typed_errors() {
        assert_eq!(frame_len(&[0, 1, 0, 3], 2), Ok(None));
        assert_eq!(
            frame_len(&hex("0001 0003 0001 0d"), 2),
            Err(FrameError::LengthTooSmall { length: 1 })
        );
        assert_eq!(
            frame_len(&hex("0001 0003 ffff"), 2),
            Err(FrameError::LengthTooLarge { length: 0xffff })
        );
        assert!(matches!(
            Response::parse(&hex("0001 0003 0005 0d 00")),
            Err(FrameError::Truncated { need: 11, have: 8 })
        ));
        assert_eq!(
            Request::decode(&hex("0001 0003 0001 77")),
            Err(FrameError::UnknownRegister(0x77))
        );
        assert!(matches!(
            Request::decode(&hex("0001 0003 0005 1d 00 00 00 00")),
            Err(FrameError::BadPayload {
                register: 0x1d,
                len: 4
            })
        ));
        let nan = hex(
            "0001 0003 001e 2a 00 0000c07f 00000000 00000000 00000000 00000000 00000000 00000000",
        );
        assert_eq!(
            Response::parse(&nan).unwrap().joints(),
            Err(FrameError::NonFinite)
        );
    }

    #[test]
    fn register_mapping_is_total_and_round_trips() {
        for b in 0..=255u8 {
            assert_eq!(u8::from(Register::from(b)), b);
        }
        assert_eq!(Register::from(0x77), Register::Unknown(0x77));
    }
}
