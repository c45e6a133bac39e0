//! A small CDR serializer: the encoding ROS 2 puts on the wire (XCDR1, little-endian) and
//! `ros2 bag` stores in MCAP files with `message_encoding = "cdr"`.
//!
//! A message is the 4-byte encapsulation header `00 01 00 00` (CDR, little-endian) followed
//! by its fields in declaration order. Each primitive is aligned to its own size (1, 2, 4 or
//! 8 bytes), counted from the end of the encapsulation header; a `string` is a `u32` length
//! that counts the terminating NUL, the bytes, then the NUL; a sequence (`T[]`) is a `u32`
//! element count then the elements; a fixed array (`T[N]`) is its elements alone.
//!
//! ```
//! use recorder::cdr::CdrWriter;
//! let mut w = CdrWriter::new();
//! w.u8(1);
//! w.f64(0.5); // aligned to 8: seven padding bytes after the u8
//! w.string("hi");
//! assert_eq!(w.as_bytes().len(), 4 + 1 + 7 + 8 + 4 + 3);
//! ```

/// The encapsulation header of a little-endian plain-CDR payload.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Writes one CDR message into a growable buffer (reused between messages with
/// [`CdrWriter::reset`]).
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// A writer holding only the encapsulation header.
    pub fn new() -> Self {
        let mut buf = Vec::with_capacity(256);
        buf.extend_from_slice(&CDR_LE_HEADER);
        Self { buf }
    }

    /// Empties the writer for the next message (keeps its capacity).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.buf.extend_from_slice(&CDR_LE_HEADER);
    }

    /// The message so far, header included.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Pads with zeros so that the next field starts at a multiple of `n` bytes from the end
    /// of the encapsulation header.
    fn align(&mut self, n: usize) {
        let offset = self.buf.len() - CDR_LE_HEADER.len();
        let pad = (n - offset % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// `bool` (one byte, 0 or 1).
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// `uint8` / `byte`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `uint64`.
    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `float32`.
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `string`: length with the NUL, the bytes, the NUL. A string longer than `u32::MAX`
    /// bytes cannot occur here (every string the recorder writes is bounded, the URDF the
    /// longest); it would be cut to fit.
    pub fn string(&mut self, s: &str) {
        let bytes = &s.as_bytes()[..s.len().min(u32::MAX as usize - 1)];
        self.u32(bytes.len() as u32 + 1);
        self.buf.extend_from_slice(bytes);
        self.buf.push(0);
    }

    /// The element count of a sequence (`T[]`); the caller writes the elements after it.
    pub fn sequence_len(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// `float64[]`.
    pub fn f64_sequence(&mut self, v: &[f64]) {
        self.sequence_len(v.len());
        for x in v {
            self.f64(*x);
        }
    }

    /// `float32[N]` (a fixed array: no count).
    pub fn f32_array(&mut self, v: &[f32]) {
        for x in v {
            self.f32(*x);
        }
    }

    /// `float64[N]` (a fixed array: no count).
    pub fn f64_array(&mut self, v: &[f64]) {
        for x in v {
            self.f64(*x);
        }
    }

    /// `string[]`.
    pub fn string_sequence<S: AsRef<str>>(&mut self, v: &[S]) {
        self.sequence_len(v.len());
        for s in v {
            self.string(s.as_ref());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `sensor_msgs/JointState` with one joint, byte for byte as a ROS 2 (Fast DDS /
    /// Cyclone) publisher puts it on the wire: stamp 1.5 s, frame "w", name ["j"],
    /// position [0.5], velocity [], effort [].
    #[test]
    fn a_joint_state_encodes_to_the_known_ros2_bytes() {
        let mut w = CdrWriter::new();
        w.i32(1); // stamp.sec
        w.u32(500_000_000); // stamp.nanosec
        w.string("w"); // frame_id
        w.string_sequence(&["j"]);
        w.f64_sequence(&[0.5]);
        w.f64_sequence(&[]);
        w.f64_sequence(&[]);
        let expected: Vec<u8> = [
            &[0x00, 0x01, 0x00, 0x00][..], // encapsulation: CDR little-endian
            &[1, 0, 0, 0],                 // sec = 1
            &[0x00, 0x65, 0xcd, 0x1d],     // nanosec = 500_000_000
            &[2, 0, 0, 0, b'w', 0],        // "w": length 2 with the NUL
            &[0, 0],                       // pad to 4
            &[1, 0, 0, 0],                 // name: 1 element
            &[2, 0, 0, 0, b'j', 0],        // "j"
            &[0, 0],                       // pad to 4
            &[1, 0, 0, 0],                 // position: 1 element (offset 28)
            &0.5f64.to_le_bytes(),         // 0.5 at offset 32: already 8-aligned
            &[0, 0, 0, 0],                 // velocity: 0 elements
            &[0, 0, 0, 0],                 // effort: 0 elements
        ]
        .concat();
        assert_eq!(w.as_bytes(), expected.as_slice());
    }

    #[test]
    fn alignment_counts_from_the_end_of_the_encapsulation_header() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.u64(1);
        // 4 header + 1 byte + 7 padding + 8.
        assert_eq!(w.as_bytes().len(), 20);
        assert_eq!(&w.as_bytes()[4..12], &[7, 0, 0, 0, 0, 0, 0, 0]);
        w.bool(true);
        w.f32(2.0);
        assert_eq!(&w.as_bytes()[20..28], &[1, 0, 0, 0, 0, 0, 0, 0x40]);
        w.reset();
        assert_eq!(w.as_bytes(), &CDR_LE_HEADER);
    }
}
