//! Makes a stock YOLOv8 ONNX export runnable by OpenCV 4.6's DNN module, by editing the
//! model's protobuf directly (a tiny reader/writer of the protobuf wire format, no codegen).
//!
//! The problem: the stock head multiplies the decoded boxes `[1, 4, N]` by a strides
//! constant of shape `[1, N]` (`dbox * self.strides`). OpenCV before 4.7 turns a `Mul` by a
//! constant into a `Scale` layer, which needs the constant to cover a contiguous run of the
//! input's axes starting at axis 1 — `[N]` against `[4, N]` does not — so `forward()` fails.
//!
//! The fix, for any stock export (any image size, class count or opset): such a `Mul` —
//! a constant of shape `[1, N]`, `N > 1`, whose output is the first input of the `Concat`
//! that produces a graph output — becomes an `Identity`, and the strides are returned as
//! [`PatchedModel::box_scale`]; the decoder multiplies the four box rows of the output by
//! them, which is exactly what the removed node computed.
//!
//! A second, smaller incompatibility: when several initializers are identical (e.g. the
//! all-zero biases of a model with random or untrained weights), the PyTorch exporter keeps
//! one and feeds the others through `Identity` nodes; OpenCV 4.6 cannot parse an `Identity`
//! of a constant. Such nodes are folded: the output becomes an initializer of its own (a
//! copy of the tensor under the output's name) and the node is dropped.
//!
//! A model needing neither rewrite is passed through untouched.

use std::collections::HashMap;

/// Why a model could not be read or patched.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OnnxPatchError {
    /// The bytes are not a well-formed protobuf message.
    #[error("not a valid ONNX protobuf: {0}")]
    Malformed(&'static str),
    /// The message has no graph.
    #[error("the ONNX model has no graph")]
    NoGraph,
    /// The strides constant is not stored as 32-bit floats.
    #[error(
        "the broadcast constant `{0}` is not a float32 tensor; this model cannot be run by OpenCV 4.6"
    )]
    UnsupportedConstant(String),
}

/// The result of [`patch_for_opencv`].
#[derive(Debug, Clone, PartialEq)]
pub struct PatchedModel {
    /// The (possibly rewritten) model bytes.
    pub onnx: Vec<u8>,
    /// Per-anchor factors the decoder must apply to the four box rows, when a strides
    /// `Mul` was removed.
    pub box_scale: Option<Vec<f32>>,
    /// Names of the strides nodes rewritten.
    pub rewritten_nodes: Vec<String>,
    /// `Identity` nodes of initializers folded into initializers.
    pub folded_identities: usize,
}

// ---- protobuf wire format ----

#[derive(Debug, Clone, Copy, PartialEq)]
enum Value<'a> {
    Varint(u64),
    Fixed64,
    Bytes(&'a [u8]),
    Fixed32(u32),
}

#[derive(Debug, Clone, Copy)]
struct Field<'a> {
    num: u32,
    value: Value<'a>,
    raw: &'a [u8],
}

fn read_varint(buf: &[u8], pos: &mut usize) -> Result<u64, OnnxPatchError> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *buf
            .get(*pos)
            .ok_or(OnnxPatchError::Malformed("truncated varint"))?;
        *pos += 1;
        v |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(OnnxPatchError::Malformed("varint too long"))
}

fn parse(buf: &[u8]) -> Result<Vec<Field<'_>>, OnnxPatchError> {
    let mut out = Vec::new();
    let mut pos = 0;
    while pos < buf.len() {
        let start = pos;
        let key = read_varint(buf, &mut pos)?;
        let num = u32::try_from(key >> 3)
            .map_err(|_| OnnxPatchError::Malformed("field number too large"))?;
        if num == 0 {
            return Err(OnnxPatchError::Malformed("field number 0"));
        }
        let value = match key & 7 {
            0 => Value::Varint(read_varint(buf, &mut pos)?),
            1 => {
                pos = pos
                    .checked_add(8)
                    .filter(|&p| p <= buf.len())
                    .ok_or(OnnxPatchError::Malformed("truncated fixed64"))?;
                Value::Fixed64
            }
            2 => {
                let len = usize::try_from(read_varint(buf, &mut pos)?)
                    .map_err(|_| OnnxPatchError::Malformed("length too large"))?;
                let end = pos
                    .checked_add(len)
                    .filter(|&e| e <= buf.len())
                    .ok_or(OnnxPatchError::Malformed("truncated bytes"))?;
                let b = &buf[pos..end];
                pos = end;
                Value::Bytes(b)
            }
            5 => {
                let b = buf
                    .get(pos..pos + 4)
                    .ok_or(OnnxPatchError::Malformed("truncated fixed32"))?;
                pos += 4;
                Value::Fixed32(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            _ => return Err(OnnxPatchError::Malformed("unsupported wire type")),
        };
        out.push(Field {
            num,
            value,
            raw: &buf[start..pos],
        });
    }
    Ok(out)
}

fn write_varint(out: &mut Vec<u8>, mut v: u64) {
    loop {
        let b = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            out.push(b);
            return;
        }
        out.push(b | 0x80);
    }
}

fn write_bytes_field(out: &mut Vec<u8>, num: u32, bytes: &[u8]) {
    write_varint(out, (u64::from(num) << 3) | 2);
    write_varint(out, bytes.len() as u64);
    out.extend_from_slice(bytes);
}

fn bytes_of<'a>(f: &Field<'a>) -> Option<&'a [u8]> {
    match f.value {
        Value::Bytes(b) => Some(b),
        _ => None,
    }
}

fn string_of(f: &Field<'_>) -> String {
    bytes_of(f)
        .map(|b| String::from_utf8_lossy(b).into_owned())
        .unwrap_or_default()
}

// ---- ONNX messages (only the fields used) ----

struct Tensor {
    dims: Vec<i64>,
    data_type: u64,
    floats: Option<Vec<f32>>,
}

fn parse_tensor(buf: &[u8]) -> Result<(String, Tensor), OnnxPatchError> {
    let mut name = String::new();
    let mut dims = Vec::new();
    let mut data_type = 0;
    let mut float_data = Vec::new();
    let mut raw = None;
    for f in parse(buf)? {
        match (f.num, f.value) {
            (1, Value::Varint(v)) => dims.push(v as i64),
            (1, Value::Bytes(b)) => {
                let mut p = 0;
                while p < b.len() {
                    dims.push(read_varint(b, &mut p)? as i64);
                }
            }
            (2, Value::Varint(v)) => data_type = v,
            (4, Value::Fixed32(v)) => float_data.push(f32::from_bits(v)),
            (4, Value::Bytes(b)) => {
                float_data.extend(
                    b.chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                );
            }
            (8, _) => name = string_of(&f),
            (9, Value::Bytes(b)) => raw = Some(b),
            _ => {}
        }
    }
    let floats = if data_type != 1 {
        None
    } else if let Some(r) = raw {
        Some(
            r.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    } else {
        Some(float_data)
    };
    Ok((
        name,
        Tensor {
            dims,
            data_type,
            floats,
        },
    ))
}

struct Node<'a> {
    raw_payload: &'a [u8],
    name: String,
    op_type: String,
    inputs: Vec<String>,
    outputs: Vec<String>,
    /// For `Constant` nodes: the `value` tensor.
    constant: Option<Tensor>,
}

fn parse_node(buf: &[u8]) -> Result<Node<'_>, OnnxPatchError> {
    let mut n = Node {
        raw_payload: buf,
        name: String::new(),
        op_type: String::new(),
        inputs: Vec::new(),
        outputs: Vec::new(),
        constant: None,
    };
    for f in parse(buf)? {
        match f.num {
            1 => n.inputs.push(string_of(&f)),
            2 => n.outputs.push(string_of(&f)),
            3 => n.name = string_of(&f),
            4 => n.op_type = string_of(&f),
            5 => {
                // AttributeProto: name = 1, t = 5.
                if let Some(b) = bytes_of(&f) {
                    let attr = parse(b)?;
                    let is_value = attr.iter().any(|a| a.num == 1 && string_of(a) == "value");
                    if is_value && let Some(t) = attr.iter().find(|a| a.num == 5).and_then(bytes_of)
                    {
                        n.constant = Some(parse_tensor(t)?.1);
                    }
                }
            }
            _ => {}
        }
    }
    Ok(n)
}

/// Rewrites the node as `Identity(input)`.
fn identity_node(node: &Node<'_>, keep_input: &str) -> Result<Vec<u8>, OnnxPatchError> {
    let mut out = Vec::with_capacity(node.raw_payload.len());
    let mut input_written = false;
    for f in parse(node.raw_payload)? {
        match f.num {
            1 => {
                if !input_written {
                    write_bytes_field(&mut out, 1, keep_input.as_bytes());
                    input_written = true;
                }
            }
            4 => write_bytes_field(&mut out, 4, b"Identity"),
            5 => {} // a Mul has no attributes we need
            _ => out.extend_from_slice(f.raw),
        }
    }
    Ok(out)
}

/// A copy of a serialized `TensorProto` under another name.
fn renamed_tensor(raw: &[u8], name: &str) -> Result<Vec<u8>, OnnxPatchError> {
    let mut out = Vec::with_capacity(raw.len() + name.len());
    for f in parse(raw)? {
        if f.num != 8 {
            out.extend_from_slice(f.raw);
        }
    }
    write_bytes_field(&mut out, 8, name.as_bytes());
    Ok(out)
}

/// The parts of a `GraphProto` the rewrites look at.
struct Graph<'a> {
    /// All fields, in order (rebuilding copies the untouched ones verbatim).
    fields: Vec<Field<'a>>,
    /// The nodes, in order.
    nodes: Vec<Node<'a>>,
    /// Initializers and `Constant` node outputs, by name.
    constants: HashMap<String, Tensor>,
    /// Serialized initializers, by name.
    initializer_bytes: HashMap<String, &'a [u8]>,
    /// Names of the graph outputs.
    outputs: Vec<String>,
}

fn parse_graph(graph: &[u8]) -> Result<Graph<'_>, OnnxPatchError> {
    let mut g = Graph {
        fields: parse(graph)?,
        nodes: Vec::new(),
        constants: HashMap::new(),
        initializer_bytes: HashMap::new(),
        outputs: Vec::new(),
    };
    for f in &g.fields {
        match f.num {
            1 => g.nodes.push(parse_node(
                bytes_of(f).ok_or(OnnxPatchError::Malformed("node is not a message"))?,
            )?),
            5 => {
                let raw =
                    bytes_of(f).ok_or(OnnxPatchError::Malformed("initializer is not a message"))?;
                let (name, t) = parse_tensor(raw)?;
                g.initializer_bytes.insert(name.clone(), raw);
                g.constants.insert(name, t);
            }
            12 => {
                // ValueInfoProto: name = 1
                if let Some(b) = bytes_of(f)
                    && let Some(nf) = parse(b)?.iter().find(|x| x.num == 1)
                {
                    g.outputs.push(string_of(nf));
                }
            }
            _ => {}
        }
    }
    for n in &mut g.nodes {
        if n.op_type == "Constant"
            && let (Some(t), Some(o)) = (n.constant.take(), n.outputs.first())
        {
            g.constants.insert(o.clone(), t);
        }
    }
    Ok(g)
}

/// The strides `Mul`s turned into `Identity`s.
#[derive(Default)]
struct StrideRewrite {
    /// Node index → its replacement `NodeProto` bytes.
    replace: Vec<(usize, Vec<u8>)>,
    /// The strides the decoder applies instead.
    box_scale: Option<Vec<f32>>,
    /// Names of the rewritten nodes.
    rewritten: Vec<String>,
}

/// Index of the `[1, N]` (`N > 1`) constant input of node `n` whose other input is not a
/// constant, when `n` is a two-input `Mul` feeding the `Concat` of a graph output.
fn stride_mul_constant(g: &Graph<'_>, n: &Node<'_>) -> Option<usize> {
    if n.op_type != "Mul" || n.inputs.len() != 2 || n.outputs.len() != 1 {
        return None;
    }
    let ci = (0..2).find(|&k| {
        g.constants
            .get(&n.inputs[k])
            .is_some_and(|t| t.dims.len() == 2 && t.dims[0] == 1 && t.dims[1] > 1)
    })?;
    if g.constants.contains_key(&n.inputs[1 - ci]) {
        return None;
    }
    let out = &n.outputs[0];
    let feeds_output_concat = g.nodes.iter().any(|c| {
        c.op_type == "Concat"
            && c.inputs.first() == Some(out)
            && c.outputs.iter().any(|o| g.outputs.contains(o))
    });
    feeds_output_concat.then_some(ci)
}

fn rewrite_stride_muls(g: &Graph<'_>) -> Result<StrideRewrite, OnnxPatchError> {
    let mut r = StrideRewrite::default();
    for (i, n) in g.nodes.iter().enumerate() {
        let Some(ci) = stride_mul_constant(g, n) else {
            continue;
        };
        let t = &g.constants[&n.inputs[ci]];
        let floats = t
            .floats
            .clone()
            .filter(|f| f.len() as i64 == t.dims[1])
            .ok_or_else(|| {
                OnnxPatchError::UnsupportedConstant(format!(
                    "{} (data type {})",
                    n.inputs[ci], t.data_type
                ))
            })?;
        r.replace.push((i, identity_node(n, &n.inputs[1 - ci])?));
        r.rewritten.push(if n.name.is_empty() {
            n.outputs[0].clone()
        } else {
            n.name.clone()
        });
        r.box_scale = Some(floats);
    }
    Ok(r)
}

/// `Identity` nodes of initializers: their indices, and the initializers that replace
/// them (copies under the outputs' names).
fn fold_identity_initializers(g: &Graph<'_>) -> Result<(Vec<usize>, Vec<Vec<u8>>), OnnxPatchError> {
    let mut dropped = Vec::new();
    let mut new_initializers = Vec::new();
    for (i, n) in g.nodes.iter().enumerate() {
        if n.op_type == "Identity"
            && n.inputs.len() == 1
            && n.outputs.len() == 1
            && let Some(raw) = g.initializer_bytes.get(&n.inputs[0])
        {
            new_initializers.push(renamed_tensor(raw, &n.outputs[0])?);
            dropped.push(i);
        }
    }
    Ok((dropped, new_initializers))
}

/// The graph with nodes replaced or dropped and initializers appended.
fn rebuild_graph(
    g: &Graph<'_>,
    size_hint: usize,
    replace: &[(usize, Vec<u8>)],
    dropped: &[usize],
    new_initializers: &[Vec<u8>],
) -> Vec<u8> {
    let mut new_graph = Vec::with_capacity(size_hint);
    let mut node_idx = 0;
    for f in &g.fields {
        if f.num == 1 {
            if dropped.contains(&node_idx) {
                // folded into an initializer below
            } else if let Some((_, bytes)) = replace.iter().find(|(i, _)| *i == node_idx) {
                write_bytes_field(&mut new_graph, 1, bytes);
            } else {
                new_graph.extend_from_slice(f.raw);
            }
            node_idx += 1;
        } else {
            new_graph.extend_from_slice(f.raw);
        }
    }
    for t in new_initializers {
        write_bytes_field(&mut new_graph, 5, t);
    }
    new_graph
}

/// Applies the rewrite described in the module docs.
///
/// # Errors
/// [`OnnxPatchError`] for bytes that are not an ONNX model, or a strides constant stored
/// in a type other than float32.
pub fn patch_for_opencv(model: &[u8]) -> Result<PatchedModel, OnnxPatchError> {
    let fields = parse(model)?;
    let graph_field = fields
        .iter()
        .find(|f| f.num == 7)
        .ok_or(OnnxPatchError::NoGraph)?;
    let graph = bytes_of(graph_field).ok_or(OnnxPatchError::NoGraph)?;
    let g = parse_graph(graph)?;
    let strides = rewrite_stride_muls(&g)?;
    let (dropped, new_initializers) = fold_identity_initializers(&g)?;
    let folded_identities = dropped.len();
    if strides.replace.is_empty() && dropped.is_empty() {
        return Ok(PatchedModel {
            onnx: model.to_vec(),
            box_scale: None,
            rewritten_nodes: strides.rewritten,
            folded_identities,
        });
    }
    let new_graph = rebuild_graph(
        &g,
        graph.len(),
        &strides.replace,
        &dropped,
        &new_initializers,
    );
    let mut new_model = Vec::with_capacity(model.len());
    for f in &fields {
        if f.num == 7 {
            write_bytes_field(&mut new_model, 7, &new_graph);
        } else {
            new_model.extend_from_slice(f.raw);
        }
    }
    Ok(PatchedModel {
        onnx: new_model,
        box_scale: strides.box_scale,
        rewritten_nodes: strides.rewritten,
        folded_identities,
    })
}

/// What a loader needs to know about a model before running it, read from the protobuf
/// (the same for every backend): the first graph input's shape and the free-form metadata
/// (`metadata_props`; Ultralytics writes `names`, `imgsz`, `stride`, `task`, `args`, …).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelInfo {
    /// Name of the first graph input that is not an initializer.
    pub input_name: String,
    /// Its dimensions; `None` for a symbolic (dynamic) dimension.
    pub input_dims: Vec<Option<i64>>,
    /// `metadata_props` as (key, value) pairs, in file order.
    pub metadata: Vec<(String, String)>,
}

impl ModelInfo {
    /// The metadata value of `key`.
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The square input size of an NCHW image input `[1, 3, S, S]` with static H = W.
    pub fn square_input_px(&self) -> Option<i64> {
        match self.input_dims.as_slice() {
            [_, Some(3), Some(h), Some(w)] if h == w && *h > 0 => Some(*h),
            _ => None,
        }
    }
}

/// Reads [`ModelInfo`] from ONNX bytes.
///
/// # Errors
/// [`OnnxPatchError`] for bytes that are not an ONNX model.
pub fn model_info(model: &[u8]) -> Result<ModelInfo, OnnxPatchError> {
    let fields = parse(model)?;
    let mut info = ModelInfo::default();
    for f in &fields {
        // ModelProto.metadata_props = 14: StringStringEntryProto { key = 1, value = 2 }
        if f.num == 14
            && let Some(b) = bytes_of(f)
        {
            let kv = parse(b)?;
            let get = |n: u32| kv.iter().find(|x| x.num == n).map(string_of);
            if let Some(k) = get(1) {
                info.metadata.push((k, get(2).unwrap_or_default()));
            }
        }
    }
    let graph = fields
        .iter()
        .find(|f| f.num == 7)
        .and_then(bytes_of)
        .ok_or(OnnxPatchError::NoGraph)?;
    let gf = parse(graph)?;
    let initializers: Vec<String> = gf
        .iter()
        .filter(|f| f.num == 5)
        .filter_map(bytes_of)
        .filter_map(|b| parse(b).ok()?.iter().find(|x| x.num == 8).map(string_of))
        .collect();
    // GraphProto.input = 11: ValueInfoProto { name = 1, type = 2 }
    for f in gf.iter().filter(|f| f.num == 11) {
        let Some(vi) = bytes_of(f) else { continue };
        let vf = parse(vi)?;
        let name = vf
            .iter()
            .find(|x| x.num == 1)
            .map(string_of)
            .unwrap_or_default();
        if initializers.contains(&name) {
            continue;
        }
        info.input_name = name;
        // TypeProto.tensor_type = 1 → Tensor { elem_type = 1, shape = 2 }
        // → TensorShapeProto { dim = 1 } → Dimension { dim_value = 1, dim_param = 2 }
        let shape = vf
            .iter()
            .find(|x| x.num == 2)
            .and_then(bytes_of)
            .map(parse)
            .transpose()?
            .and_then(|t| t.iter().find(|x| x.num == 1).and_then(bytes_of))
            .map(parse)
            .transpose()?
            .and_then(|t| t.iter().find(|x| x.num == 2).and_then(bytes_of));
        if let Some(shape) = shape {
            for d in parse(shape)?.iter().filter(|x| x.num == 1) {
                let dim = bytes_of(d).map(parse).transpose()?.unwrap_or_default();
                info.input_dims
                    .push(dim.iter().find_map(|x| match (x.num, x.value) {
                        (1, Value::Varint(v)) => Some(v as i64),
                        _ => None,
                    }));
            }
        }
        break;
    }
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(inputs: &[&str], output: &str, op: &str) -> Vec<u8> {
        let mut n = Vec::new();
        for i in inputs {
            write_bytes_field(&mut n, 1, i.as_bytes());
        }
        write_bytes_field(&mut n, 2, output.as_bytes());
        write_bytes_field(&mut n, 3, format!("{op}_{output}").as_bytes());
        write_bytes_field(&mut n, 4, op.as_bytes());
        n
    }

    fn tensor(name: &str, dims: &[i64], data: &[f32]) -> Vec<u8> {
        let mut t = Vec::new();
        let mut packed = Vec::new();
        for d in dims {
            write_varint(&mut packed, *d as u64);
        }
        write_bytes_field(&mut t, 1, &packed);
        write_varint(&mut t, 2 << 3);
        write_varint(&mut t, 1);
        write_bytes_field(&mut t, 8, name.as_bytes());
        let raw: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        write_bytes_field(&mut t, 9, &raw);
        t
    }

    fn model(with_strides: bool) -> Vec<u8> {
        let mut g = Vec::new();
        if with_strides {
            write_bytes_field(&mut g, 1, &node(&["boxes", "strides"], "dbox", "Mul"));
        } else {
            write_bytes_field(&mut g, 1, &node(&["boxes"], "dbox", "Identity"));
        }
        write_bytes_field(&mut g, 1, &node(&["dbox", "cls"], "output0", "Concat"));
        write_bytes_field(&mut g, 5, &tensor("strides", &[1, 3], &[8.0, 16.0, 32.0]));
        let mut vi = Vec::new();
        write_bytes_field(&mut vi, 1, b"output0");
        write_bytes_field(&mut g, 12, &vi);
        let mut m = Vec::new();
        write_varint(&mut m, 1 << 3);
        write_varint(&mut m, 7); // ir_version
        write_bytes_field(&mut m, 7, &g);
        m
    }

    #[test]
    fn the_strides_mul_becomes_identity_and_its_constant_the_box_scale() {
        let p = patch_for_opencv(&model(true)).unwrap();
        assert_eq!(p.box_scale.as_deref(), Some(&[8.0f32, 16.0, 32.0][..]));
        assert_eq!(p.rewritten_nodes, vec!["Mul_dbox".to_string()]);
        // The rewritten model parses, has an Identity with one input, and nothing else changed.
        let f = parse(&p.onnx).unwrap();
        let g = parse(bytes_of(f.iter().find(|f| f.num == 7).unwrap()).unwrap()).unwrap();
        let n = parse_node(bytes_of(&g[0]).unwrap()).unwrap();
        assert_eq!(n.op_type, "Identity");
        assert_eq!(n.inputs, vec!["boxes".to_string()]);
        assert_eq!(n.outputs, vec!["dbox".to_string()]);
        assert_eq!(
            g[1].raw,
            parse(bytes_of(&parse(&model(true)).unwrap()[1]).unwrap()).unwrap()[1].raw
        );
        // Patching again finds nothing more to do.
        let again = patch_for_opencv(&p.onnx).unwrap();
        assert!(again.box_scale.is_none());
        assert_eq!(again.onnx, p.onnx);
    }

    #[test]
    fn identities_of_initializers_become_initializers() {
        let mut g = Vec::new();
        write_bytes_field(&mut g, 1, &node(&["bias_a"], "bias_b", "Identity"));
        write_bytes_field(&mut g, 1, &node(&["x", "bias_b"], "y", "Add"));
        write_bytes_field(&mut g, 5, &tensor("bias_a", &[1, 2], &[0.5, 0.25]));
        let mut m = Vec::new();
        write_bytes_field(&mut m, 7, &g);
        let p = patch_for_opencv(&m).unwrap();
        assert_eq!(p.folded_identities, 1);
        let f = parse(&p.onnx).unwrap();
        let g = parse(bytes_of(&f[0]).unwrap()).unwrap();
        let nodes: Vec<Node<'_>> = g
            .iter()
            .filter(|f| f.num == 1)
            .map(|f| parse_node(bytes_of(f).unwrap()).unwrap())
            .collect();
        assert_eq!(nodes.len(), 1);
        assert_eq!(nodes[0].op_type, "Add");
        let inits: Vec<(String, Tensor)> = g
            .iter()
            .filter(|f| f.num == 5)
            .map(|f| parse_tensor(bytes_of(f).unwrap()).unwrap())
            .collect();
        assert_eq!(inits.len(), 2);
        assert_eq!(inits[1].0, "bias_b");
        assert_eq!(inits[1].1.dims, vec![1, 2]);
        assert_eq!(inits[1].1.floats.as_deref(), Some(&[0.5f32, 0.25][..]));
    }

    #[test]
    fn random_and_truncated_bytes_never_panic() {
        let good = model(true);
        for cut in 0..good.len() {
            let _ = patch_for_opencv(&good[..cut]);
        }
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for len in 0..2000 {
            let bytes: Vec<u8> = (0..len % 97)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state as u8
                })
                .collect();
            let _ = patch_for_opencv(&bytes);
            let mut spliced = good.clone();
            let at = len % good.len();
            spliced.splice(at..at, bytes);
            let _ = patch_for_opencv(&spliced);
        }
    }

    #[test]
    fn models_without_the_broadcast_pass_through_and_garbage_is_refused() {
        let m = model(false);
        let p = patch_for_opencv(&m).unwrap();
        assert_eq!(p.onnx, m);
        assert!(p.box_scale.is_none());
        assert!(matches!(
            patch_for_opencv(b"\x0a\xff\xff"),
            Err(OnnxPatchError::Malformed(_))
        ));
        assert_eq!(
            patch_for_opencv(&[0x08, 0x07]),
            Err(OnnxPatchError::NoGraph)
        );
        let mut big = Vec::new();
        write_varint(&mut big, u64::MAX);
        assert!(read_varint(&big, &mut 0).is_ok());
    }
}
