//! The few ONNX protobuf messages a policy export needs, encoded by hand (protobuf's wire
//! format: varints and length-delimited fields). Field numbers are those of `onnx.proto`
//! (ONNX 1.x); nothing here decodes. The encoder is small enough to read against the spec,
//! and it keeps a code generator and a `protoc` out of the build.

/// Protobuf wire types.
const VARINT: u32 = 0;
const FIXED32: u32 = 5;
const LEN: u32 = 2;

/// One message being encoded: its bytes.
#[derive(Debug, Default, Clone)]
pub struct Msg(Vec<u8>);

impl Msg {
    /// An empty message.
    pub fn new() -> Self {
        Self::default()
    }

    fn varint(&mut self, mut v: u64) {
        loop {
            let byte = (v & 0x7f) as u8;
            v >>= 7;
            if v == 0 {
                self.0.push(byte);
                return;
            }
            self.0.push(byte | 0x80);
        }
    }

    fn key(&mut self, field: u32, wire: u32) {
        self.varint(u64::from(field << 3 | wire));
    }

    /// An `int64`/`int32`/enum field (negative values as 10-byte two's complement).
    pub fn int(mut self, field: u32, v: i64) -> Self {
        self.key(field, VARINT);
        self.varint(v as u64);
        self
    }

    /// A `float` field.
    pub fn float(mut self, field: u32, v: f32) -> Self {
        self.key(field, FIXED32);
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `bytes` field.
    pub fn bytes(mut self, field: u32, v: &[u8]) -> Self {
        self.key(field, LEN);
        self.varint(v.len() as u64);
        self.0.extend_from_slice(v);
        self
    }

    /// A `string` field.
    pub fn string(self, field: u32, v: &str) -> Self {
        self.bytes(field, v.as_bytes())
    }

    /// An embedded message field.
    pub fn msg(self, field: u32, m: &Msg) -> Self {
        self.bytes(field, &m.0)
    }

    /// The encoded bytes.
    pub fn into_bytes(self) -> Vec<u8> {
        self.0
    }
}

/// `TensorProto.DataType.FLOAT`.
pub const FLOAT: i64 = 1;

/// `TensorProto` of `f32` values with `dims`, stored as little-endian `raw_data`.
pub fn tensor(name: &str, dims: &[i64], values: &[f32]) -> Msg {
    let mut m = Msg::new();
    for &d in dims {
        m = m.int(1, d); // dims
    }
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    m.int(2, FLOAT) // data_type
        .string(8, name) // name
        .bytes(9, &raw) // raw_data
}

/// `AttributeProto` holding one `int` (`type = INT`).
pub fn int_attribute(name: &str, v: i64) -> Msg {
    Msg::new().string(1, name).int(3, v).int(20, 2)
}

/// `NodeProto`: `op_type` from `inputs` to `outputs`, with attributes.
pub fn node(name: &str, op_type: &str, inputs: &[&str], outputs: &[&str], attrs: &[Msg]) -> Msg {
    let mut m = Msg::new();
    for i in inputs {
        m = m.string(1, i);
    }
    for o in outputs {
        m = m.string(2, o);
    }
    m = m.string(3, name).string(4, op_type);
    for a in attrs {
        m = m.msg(5, a);
    }
    m
}

/// One dimension of a shape: a fixed size or a named (free) one.
#[derive(Debug, Clone, Copy)]
pub enum Dim<'a> {
    /// `dim_value`.
    Fixed(i64),
    /// `dim_param`.
    Named(&'a str),
}

/// `ValueInfoProto` of a `float` tensor with `dims`.
pub fn float_value_info(name: &str, dims: &[Dim<'_>], doc: &str) -> Msg {
    let mut shape = Msg::new();
    for d in dims {
        let dim = match d {
            Dim::Fixed(v) => Msg::new().int(1, *v),
            Dim::Named(p) => Msg::new().string(2, p),
        };
        shape = shape.msg(1, &dim);
    }
    let tensor_type = Msg::new().int(1, FLOAT).msg(2, &shape);
    let type_proto = Msg::new().msg(1, &tensor_type);
    Msg::new()
        .string(1, name)
        .msg(2, &type_proto)
        .string(3, doc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_and_keys_follow_the_wire_format() {
        // The protobuf spec's own example: field 1, varint 150 → 08 96 01.
        assert_eq!(Msg::new().int(1, 150).into_bytes(), [0x08, 0x96, 0x01]);
        // A string: field 2, "testing" → 12 07 74 65 73 74 69 6e 67.
        assert_eq!(
            Msg::new().string(2, "testing").into_bytes(),
            [0x12, 0x07, 0x74, 0x65, 0x73, 0x74, 0x69, 0x6e, 0x67]
        );
        // A float: field 2, wire type 5, little-endian.
        assert_eq!(
            Msg::new().float(2, 1.0).into_bytes(),
            [0x15, 0x00, 0x00, 0x80, 0x3f]
        );
        // -1 as int64: ten bytes.
        assert_eq!(Msg::new().int(1, -1).into_bytes().len(), 11);
    }
}
