//! Report packets streamed by the controller on ports 30000–30003, decoded into a `Copy`
//! [`ArmReport`], plus the encoders the simulator uses and a fixed-buffer stream framer.
//!
//! Every packet starts with its total size as a `u32` BE; all packets on one connection have
//! the same size (the client learns it from the first). Numbers after the size are `f32` LE
//! except the `u16`/`u32`/`u64` counters (BE). Decoders never panic: a wrong size, an
//! impossible state/mode or a non-finite joint is a [`ReportError`].

use thiserror::Error;

use super::codec::{WIRE_JOINTS, le_f32};

/// Port of the 250 Hz real-time report (804 B).
pub const PORT_REPORT_RT: u16 = 30000;
/// Port of the 5 Hz "normal" report (145 B).
pub const PORT_REPORT_NORMAL: u16 = 30001;
/// Port of the 5 Hz "rich" report (the SDK's default).
pub const PORT_REPORT_RICH: u16 = 30002;
/// Port of the 100 Hz "real" report (87 or 135 B).
pub const PORT_REPORT_REAL: u16 = 30003;

/// Size of the 30000 real-time packet.
pub const RT_LEN: usize = 804;
/// Size of the normal packet.
pub const NORMAL_LEN: usize = 145;
/// Size of the rich packet as the SDK 1.18.4 struct has it.
pub const RICH_LEN: usize = 587;
/// Minimum rich packet the SDK reads.
pub const RICH_MIN_LEN: usize = 245;
/// Size of the real packet with force/torque data.
pub const REAL_LEN: usize = 135;
/// Size of the real packet of older firmware.
pub const REAL_SHORT_LEN: usize = 87;
/// Largest packet the framer accepts.
pub const MAX_REPORT_LEN: usize = 1024;

/// Which report stream a packet came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReportKind {
    /// 30000, 250 Hz, 804 B.
    RealTime,
    /// 30001, 5 Hz, 145 B.
    Normal,
    /// 30002, 5 Hz, ≥ 245 B.
    Rich,
    /// 30003, 100 Hz, 87/135 B.
    Real,
}

impl ReportKind {
    /// The controller's port for this stream.
    pub fn port(self) -> u16 {
        match self {
            Self::RealTime => PORT_REPORT_RT,
            Self::Normal => PORT_REPORT_NORMAL,
            Self::Rich => PORT_REPORT_RICH,
            Self::Real => PORT_REPORT_REAL,
        }
    }

    /// Nominal rate of the stream (Hz).
    pub fn rate_hz(self) -> f64 {
        match self {
            Self::RealTime => 250.0,
            Self::Normal | Self::Rich => 5.0,
            Self::Real => 100.0,
        }
    }

    fn size_ok(self, n: usize) -> bool {
        match self {
            Self::RealTime => n == RT_LEN,
            Self::Normal => n == NORMAL_LEN,
            Self::Rich => (RICH_MIN_LEN..=MAX_REPORT_LEN).contains(&n),
            Self::Real => n == REAL_LEN || n == REAL_SHORT_LEN,
        }
    }
}

/// Why a report packet was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum ReportError {
    /// Fewer bytes than the size field (or than a size field).
    #[error("truncated report: {have} of {need} bytes")]
    Truncated {
        /// Bytes needed.
        need: usize,
        /// Bytes present.
        have: usize,
    },
    /// The size field is not a size this stream can have.
    #[error("report size {size} is invalid for this stream")]
    BadSize {
        /// The size field.
        size: u32,
    },
    /// A later packet's size differs from the first packet's.
    #[error("report size changed from {first} to {now}")]
    SizeChanged {
        /// Size learnt from the first packet.
        first: u32,
        /// This packet's size field.
        now: u32,
    },
    /// State nibble outside 0..=9 or mode nibble outside 0..=11.
    #[error("impossible state {state} / mode {mode}")]
    BadStateMode {
        /// State nibble.
        state: u8,
        /// Mode nibble.
        mode: u8,
    },
    /// A joint angle or pose value was NaN or infinite.
    #[error("non-finite joint or pose value")]
    NonFinite,
    /// Collision or teach sensitivity outside 0..=5.
    #[error("sensitivity byte out of range")]
    BadSensitivity,
}

/// One decoded report: what every stream shares plus the fields some streams add.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmReport {
    /// Stream the packet came from.
    pub kind: ReportKind,
    /// Controller state (1 moving, 2 sleeping/ready, 3 paused, 4 stopped, 5 reset).
    pub state: u8,
    /// Mode (1 = servo).
    pub mode: u8,
    /// Queued commands.
    pub cmdnum: u16,
    /// Actual joint angles J1..J7 (rad).
    pub joints_rad: [f32; WIRE_JOINTS],
    /// Actual TCP pose: x, y, z (mm), roll, pitch, yaw (rad).
    pub tcp_pose: [f32; 6],
    /// Joint torques (N·m, or currents), real/normal/rich only.
    pub torques: [f32; WIRE_JOINTS],
    /// Target joint angles (rad), real-time stream only.
    pub target_joints_rad: [f32; WIRE_JOINTS],
    /// Controller timestamp (µs), real-time stream only.
    pub timestamp_us: u64,
    /// Error code, normal/rich only.
    pub error_code: Option<u8>,
    /// Warning code, normal/rich only.
    pub warn_code: Option<u8>,
    /// Enable bits (bit i = joint i+1), normal/rich only.
    pub enable_bits: Option<u8>,
    /// Brake-released bits, normal/rich only.
    pub brake_bits: Option<u8>,
}

impl ArmReport {
    /// An empty report of `kind` (state 4, mode 0, zeros).
    pub fn empty(kind: ReportKind) -> Self {
        Self {
            kind,
            state: 4,
            mode: 0,
            cmdnum: 0,
            joints_rad: [0.0; WIRE_JOINTS],
            tcp_pose: [0.0; 6],
            torques: [0.0; WIRE_JOINTS],
            target_joints_rad: [0.0; WIRE_JOINTS],
            timestamp_us: 0,
            error_code: None,
            warn_code: None,
            enable_bits: None,
            brake_bits: None,
        }
    }

    /// The five xArm5 joints as `f64` (rad).
    pub fn joints5_rad(&self) -> [f64; 5] {
        let mut q = [0.0; 5];
        for (o, j) in q.iter_mut().zip(self.joints_rad) {
            *o = f64::from(j);
        }
        q
    }
}

fn be32(b: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn read_floats<const N: usize>(b: &[u8], at: usize, finite: bool) -> Result<[f32; N], ReportError> {
    let mut out = [0.0f32; N];
    for (i, v) in out.iter_mut().enumerate() {
        *v = le_f32(b, at + 4 * i);
        if finite && !v.is_finite() {
            return Err(ReportError::NonFinite);
        }
    }
    Ok(out)
}

fn write_floats(out: &mut [u8], at: usize, v: &[f32]) {
    for (i, x) in v.iter().enumerate() {
        out[at + 4 * i..at + 4 * i + 4].copy_from_slice(&x.to_le_bytes());
    }
}

fn state_mode(byte: u8) -> Result<(u8, u8), ReportError> {
    let (state, mode) = (byte & 0x0F, byte >> 4);
    if state > 9 || mode > 11 {
        return Err(ReportError::BadStateMode { state, mode });
    }
    Ok((state, mode))
}

/// Decodes one whole packet of stream `kind`.
///
/// # Errors
/// [`ReportError`] for truncated packets, sizes the stream cannot have, impossible
/// state/mode, non-finite joints or pose, bad sensitivities.
pub fn decode(kind: ReportKind, packet: &[u8]) -> Result<ArmReport, ReportError> {
    if packet.len() < 4 {
        return Err(ReportError::Truncated {
            need: 4,
            have: packet.len(),
        });
    }
    let size = be32(packet, 0);
    if !kind.size_ok(size as usize) {
        return Err(ReportError::BadSize { size });
    }
    let size = size as usize;
    if packet.len() < size {
        return Err(ReportError::Truncated {
            need: size,
            have: packet.len(),
        });
    }
    let p = &packet[..size];
    let mut r = ArmReport::empty(kind);
    if kind == ReportKind::RealTime {
        r.timestamp_us = u64::from_be_bytes([p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11]]);
        (r.state, r.mode) = state_mode(p[12])?;
        r.cmdnum = u16::from_be_bytes([p[13], p[14]]);
        r.target_joints_rad = read_floats(p, 32, true)?;
        r.joints_rad = read_floats(p, 116, true)?;
        r.tcp_pose = read_floats(p, 472, true)?;
        return Ok(r);
    }
    (r.state, r.mode) = state_mode(p[4])?;
    r.cmdnum = u16::from_be_bytes([p[5], p[6]]);
    r.joints_rad = read_floats(p, 7, true)?;
    r.tcp_pose = read_floats(p, 35, true)?;
    r.torques = read_floats(p, 59, false)?;
    if matches!(kind, ReportKind::Normal | ReportKind::Rich) {
        r.brake_bits = Some(p[87]);
        r.enable_bits = Some(p[88]);
        r.error_code = Some(p[89]);
        r.warn_code = Some(p[90]);
        if p[131] > 5 || p[132] > 5 {
            return Err(ReportError::BadSensitivity);
        }
    }
    Ok(r)
}

/// Simulator-side extras that go into the normal/rich packets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RichExtras {
    /// Robot type (5 = xArm5).
    pub robot_type: u8,
    /// Axis count.
    pub axis: u8,
    /// Firmware version text, e.g. `v2.6.0` (up to 30 bytes).
    pub version: [u8; 30],
    /// Report counter.
    pub counter: u32,
    /// Collision sensitivity 0..=5.
    pub collision_sensitivity: u8,
}

impl Default for RichExtras {
    fn default() -> Self {
        let mut version = [0u8; 30];
        version[..6].copy_from_slice(b"v2.6.0");
        Self {
            robot_type: 5,
            axis: 5,
            version,
            counter: 0,
            collision_sensitivity: 3,
        }
    }
}

fn encode_head(r: &ArmReport, size: usize, out: &mut [u8]) {
    out[..size].fill(0);
    out[0..4].copy_from_slice(&(size as u32).to_be_bytes());
    out[4] = (r.state & 0x0F) | (r.mode << 4);
    out[5..7].copy_from_slice(&r.cmdnum.to_be_bytes());
    write_floats(out, 7, &r.joints_rad);
    write_floats(out, 35, &r.tcp_pose);
    write_floats(out, 59, &r.torques);
}

/// Encodes a 135-byte "real" (30003) packet.
pub fn encode_real(r: &ArmReport, out: &mut [u8; REAL_LEN]) {
    encode_head(r, REAL_LEN, out);
}

/// Encodes an 804-byte real-time (30000) packet (fields beyond the documented ones are 0).
pub fn encode_rt(r: &ArmReport, out: &mut [u8; RT_LEN]) {
    out.fill(0);
    out[0..4].copy_from_slice(&(RT_LEN as u32).to_be_bytes());
    out[4..12].copy_from_slice(&r.timestamp_us.to_be_bytes());
    out[12] = (r.state & 0x0F) | (r.mode << 4);
    out[13..15].copy_from_slice(&r.cmdnum.to_be_bytes());
    write_floats(out, 32, &r.target_joints_rad);
    write_floats(out, 116, &r.joints_rad);
    write_floats(out, 424, &r.tcp_pose);
    write_floats(out, 472, &r.tcp_pose);
}

fn encode_normal_part(r: &ArmReport, x: &RichExtras, size: usize, out: &mut [u8]) {
    encode_head(r, size, out);
    out[87] = r.brake_bits.unwrap_or(0);
    out[88] = r.enable_bits.unwrap_or(0);
    out[89] = r.error_code.unwrap_or(0);
    out[90] = r.warn_code.unwrap_or(0);
    out[131] = x.collision_sensitivity.min(5);
    out[132] = 1;
    write_floats(out, 133, &[0.0, 0.0, -1.0]);
}

/// Encodes a 145-byte normal (30001) packet.
pub fn encode_normal(r: &ArmReport, x: &RichExtras, out: &mut [u8; NORMAL_LEN]) {
    encode_normal_part(r, x, NORMAL_LEN, out);
}

/// Encodes a 587-byte rich (30002) packet: the normal part, robot type and axis, master/slave
/// ids, firmware text, motion limits, the counter; `is_simulation_robot` is 0 so the SDK talks
/// to us like to an arm. Everything else is 0.
pub fn encode_rich(r: &ArmReport, x: &RichExtras, out: &mut [u8; RICH_LEN]) {
    encode_normal_part(r, x, RICH_LEN, out);
    out[145] = x.robot_type;
    out[146] = x.axis;
    out[147] = 0xAA;
    out[148] = 0x55;
    out[151..181].copy_from_slice(&x.version);
    write_floats(out, 181, &[10_000.0, 1.0, 50_000.0, 1.0, 1_000.0]);
    write_floats(
        out,
        201,
        &[1_000.0, 0.01, 20.0, 0.0001, core::f32::consts::PI],
    );
    write_floats(out, 221, &[0.0, 0.0]);
    out[284..288].copy_from_slice(&x.counter.to_be_bytes());
    out[314] = 0;
}

/// A fixed-buffer framer for one report connection: read bytes into [`ReportFramer::spare`],
/// [`ReportFramer::commit`] them, then take packets with [`ReportFramer::next_packet`].
/// The packet size is learnt from the first packet; later packets must match it.
#[derive(Debug, Clone)]
pub struct ReportFramer {
    buf: [u8; 2 * MAX_REPORT_LEN],
    start: usize,
    end: usize,
    size: Option<u32>,
}

impl Default for ReportFramer {
    fn default() -> Self {
        Self::new()
    }
}

impl ReportFramer {
    /// An empty framer.
    pub fn new() -> Self {
        Self {
            buf: [0; 2 * MAX_REPORT_LEN],
            start: 0,
            end: 0,
            size: None,
        }
    }

    /// Forgets buffered bytes and the learnt size (for a new connection).
    pub fn reset(&mut self) {
        self.start = 0;
        self.end = 0;
        self.size = None;
    }

    /// The free tail of the buffer to read into (compacts first).
    pub fn spare(&mut self) -> &mut [u8] {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        &mut self.buf[self.end..]
    }

    /// Marks `n` bytes of [`ReportFramer::spare`] as filled.
    pub fn commit(&mut self, n: usize) {
        self.end = (self.end + n).min(self.buf.len());
    }

    /// The next whole packet, `Ok(None)` if more bytes are needed.
    ///
    /// # Errors
    /// [`ReportError::BadSize`] for a size field below 8 or above [`MAX_REPORT_LEN`],
    /// [`ReportError::SizeChanged`] when it differs from the first packet's. After an error the
    /// stream is out of step: reconnect (and [`ReportFramer::reset`]).
    pub fn next_packet(&mut self) -> Result<Option<&[u8]>, ReportError> {
        let avail = &self.buf[self.start..self.end];
        if avail.len() < 4 {
            return Ok(None);
        }
        let size = be32(avail, 0);
        match self.size {
            None => {
                if !(8..=MAX_REPORT_LEN as u32).contains(&size) {
                    return Err(ReportError::BadSize { size });
                }
                self.size = Some(size);
            }
            Some(first) if first != size => {
                return Err(ReportError::SizeChanged { first, now: size });
            }
            Some(_) => {}
        }
        let n = size as usize;
        if avail.len() < n {
            return Ok(None);
        }
        let at = self.start;
        self.start += n;
        Ok(Some(&self.buf[at..at + n]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(kind: ReportKind) -> ArmReport {
        let mut r = ArmReport::empty(kind);
        r.state = 2;
        r.mode = 1;
        r.cmdnum = 3;
        r.joints_rad = [0.1, -0.2, -0.3, 0.4, 0.5, 0.0, 0.0];
        r.tcp_pose = [200.0, 0.0, 100.0, 3.0, 0.0, 0.0];
        r
    }

    #[test]
    fn real_round_trips_and_short_packets_are_accepted() {
        let r = sample(ReportKind::Real);
        let mut buf = [0u8; REAL_LEN];
        encode_real(&r, &mut buf);
        assert_eq!(decode(ReportKind::Real, &buf).unwrap(), r);
        let mut short = [0u8; REAL_SHORT_LEN];
        short.copy_from_slice(&buf[..REAL_SHORT_LEN]);
        short[0..4].copy_from_slice(&(REAL_SHORT_LEN as u32).to_be_bytes());
        assert_eq!(
            decode(ReportKind::Real, &short).unwrap().joints_rad,
            r.joints_rad
        );
    }

    #[test]
    fn rt_and_rich_round_trip() {
        let mut r = sample(ReportKind::RealTime);
        r.timestamp_us = 123_456_789;
        r.target_joints_rad = [0.2; 7];
        let mut buf = [0u8; RT_LEN];
        encode_rt(&r, &mut buf);
        assert_eq!(decode(ReportKind::RealTime, &buf).unwrap(), r);

        let mut r = sample(ReportKind::Rich);
        r.error_code = Some(31);
        r.warn_code = Some(0);
        r.enable_bits = Some(0x1F);
        r.brake_bits = Some(0x1F);
        let mut buf = [0u8; RICH_LEN];
        encode_rich(&r, &RichExtras::default(), &mut buf);
        assert_eq!(decode(ReportKind::Rich, &buf).unwrap(), r);
        assert_eq!((buf[145], buf[146], buf[314]), (5, 5, 0));
    }

    #[test]
    fn garbage_is_a_typed_error() {
        let mut buf = [0u8; REAL_LEN];
        encode_real(&sample(ReportKind::Real), &mut buf);
        assert_eq!(
            decode(ReportKind::Real, &buf[..50]),
            Err(ReportError::Truncated {
                need: 135,
                have: 50
            })
        );
        assert_eq!(
            decode(ReportKind::RealTime, &buf),
            Err(ReportError::BadSize { size: 135 })
        );
        let mut bad = buf;
        bad[4] = 0xCF;
        assert!(matches!(
            decode(ReportKind::Real, &bad),
            Err(ReportError::BadStateMode { .. })
        ));
        let mut nan = buf;
        nan[7..11].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(decode(ReportKind::Real, &nan), Err(ReportError::NonFinite));
        assert!(decode(ReportKind::Real, &[1, 2]).is_err());
    }

    #[test]
    fn framer_splits_a_stream_and_rejects_size_changes() {
        let mut a = [0u8; REAL_LEN];
        encode_real(&sample(ReportKind::Real), &mut a);
        let mut f = ReportFramer::new();
        let stream: Vec<u8> = a.iter().chain(a.iter()).copied().collect();
        // Feed in odd-sized chunks.
        let mut got = 0;
        for chunk in stream.chunks(50) {
            f.spare()[..chunk.len()].copy_from_slice(chunk);
            f.commit(chunk.len());
            while let Some(p) = f.next_packet().unwrap() {
                assert_eq!(p, a.as_slice());
                got += 1;
            }
        }
        assert_eq!(got, 2);
        let mut b = a;
        b[0..4].copy_from_slice(&87u32.to_be_bytes());
        f.spare()[..REAL_LEN].copy_from_slice(&b);
        f.commit(REAL_LEN);
        assert_eq!(
            f.next_packet(),
            Err(ReportError::SizeChanged {
                first: 135,
                now: 87
            })
        );
        let mut g = ReportFramer::new();
        g.spare()[..4].copy_from_slice(&[0xff, 0xff, 0xff, 0xff]);
        g.commit(4);
        assert!(matches!(g.next_packet(), Err(ReportError::BadSize { .. })));
    }
}
