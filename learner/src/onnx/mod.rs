//! A policy taken elsewhere: `policy.onnx` and `policy.schema.json` from a [`PolicyBlob`]
//! (`learner export --onnx DIR`).
//!
//! The ONNX graph computes exactly what rt-core's `policy::MlpPolicy` computes from the same
//! blob, with the observation normaliser folded in, so a user feeds raw observations (SI
//! units, the layout of the `twin` crate's docs) and reads the clipped action:
//!
//! ```text
//! observation [batch, obs_dim] → Sub(mean) → Div(std) → Clip(±obs_clip)
//!   → (Gemm → Tanh|Relu) × hidden layers → Gemm (→ output activation)
//!   → Clip(±action_clip) → Mul(action_scale) → action [batch, act_dim]
//! ```
//!
//! Opset 13, IR version 7 (ONNX Runtime ≥ 1.8 runs it). The only numeric difference from
//! rt-core is `tanh`: the kernel's is within 4 ulp of the exact one ONNX Runtime uses.
//!
//! The schema file says what the graph expects and returns: the observation layout with
//! units, the action space, the limits, the policy's identity and every version, so that a
//! loader can refuse a policy whose contract it does not know (a mismatched policy loaded
//! blind has crashed real robots).

pub mod proto;

use std::path::{Path, PathBuf};

use shm_schemas::{
    ActionSpace, Activation, JOINT_ACT_DIM, JOINT_OBS_DIM, PAPER_OBS_DIM, POLICY_FORMAT_VERSION,
    PolicyBlob,
};

use crate::checkpoint::{CheckpointError, write_atomic};
use proto::{Dim, Msg};

/// Version of `policy.schema.json`'s layout.
pub const SCHEMA_VERSION: u32 = 1;
/// The ONNX opset the graph uses.
pub const OPSET: i64 = 13;
/// The ONNX IR version the model declares (the one of opset 13).
pub const IR_VERSION: i64 = 7;
/// The graph's input name.
pub const INPUT: &str = "observation";
/// The graph's output name.
pub const OUTPUT: &str = "action";
/// The file names written into the export folder.
pub const ONNX_FILE: &str = "policy.onnx";
/// See [`ONNX_FILE`].
pub const SCHEMA_FILE: &str = "policy.schema.json";

/// Values per extra box of the `nearest_boxes` observation (`twin` crate docs).
const PER_EXTRA_BOX: usize = 6;

/// Why an export could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum OnnxExportError {
    /// The blob's observation length matches no observation layout the `twin` crate has.
    #[error(
        "obs_dim {0} matches no known observation layout (17 for the paper's, 17 + 6·(k−1) for nearest_boxes with k = 2..=3 boxes)"
    )]
    UnknownObservation(usize),
    /// The blob's action space is not one this exporter knows, or its length is not the
    /// space's.
    #[error(
        "the policy's action space (action_space {space}, act_dim {act_dim}) is not one this exporter knows (action_space 0, act_dim 3: the Cartesian step [dx, dy, dz]; action_space 1, act_dim 5, obs_dim 29: the joint step)"
    )]
    UnknownActionSpace {
        /// `PolicyBlob::action_space`.
        space: u8,
        /// `PolicyBlob::act_dim`.
        act_dim: usize,
    },
    /// The export folder could not be made.
    #[error("cannot create the export folder {}", .path.display())]
    Folder {
        /// Folder.
        path: PathBuf,
        /// OS error.
        #[source]
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("writing the export")]
    Write(#[from] CheckpointError),
}

/// The observation layout of a blob's `obs_dim`: its kind and one entry per index.
///
/// # Errors
/// [`OnnxExportError::UnknownObservation`].
pub fn observation_layout(
    obs_dim: usize,
) -> Result<(&'static str, Vec<serde_json::Value>), OnnxExportError> {
    let extra = obs_dim.checked_sub(PAPER_OBS_DIM);
    let boxes = match extra {
        Some(e) if e % PER_EXTRA_BOX == 0 && e / PER_EXTRA_BOX <= 2 => 1 + e / PER_EXTRA_BOX,
        _ => return Err(OnnxExportError::UnknownObservation(obs_dim)),
    };
    let mut layout = Vec::with_capacity(obs_dim);
    let mut put = |name: String, unit: &str| {
        let index = layout.len();
        layout.push(serde_json::json!({"index": index, "name": name, "unit": unit}));
    };
    put("t (step index / max_steps)".into(), "1");
    for a in ["x", "y"] {
        put(format!("goal cube centre {a}"), "m");
    }
    for a in ["x", "y", "z"] {
        put(format!("tcp position {a}"), "m");
    }
    for a in ["x", "y", "z"] {
        put(format!("tcp velocity {a}"), "m/s");
    }
    put("nearest box height".into(), "m");
    put("nearest box width".into(), "m");
    for a in ["x", "y", "z"] {
        put(format!("closest robot point to the nearest box {a}"), "m");
    }
    for a in ["x", "y", "z"] {
        put(format!("closest point of the nearest box {a}"), "m");
    }
    for j in 2..=boxes {
        put(format!("box {j} height"), "m");
        put(format!("box {j} width"), "m");
        for a in ["x", "y", "z"] {
            put(format!("closest point of box {j} to the robot {a}"), "m");
        }
        put(format!("box {j} robot distance (capped at 1)"), "m");
    }
    let kind = if boxes == 1 { "paper" } else { "nearest_boxes" };
    Ok((kind, layout))
}

/// The joint-step space's observation layout (version 1, `OBS_LAYOUT_JOINT_V1`: the `twin`
/// crate's joint table), one entry per index.
pub fn joint_observation_layout() -> Vec<serde_json::Value> {
    let mut layout = Vec::with_capacity(JOINT_OBS_DIM);
    let mut put = |name: String, unit: &str| {
        let index = layout.len();
        layout.push(serde_json::json!({"index": index, "name": name, "unit": unit}));
    };
    put("t (step index / max_steps)".into(), "1");
    for j in 1..=JOINT_ACT_DIM {
        put(format!("joint {j} error (goal posture - joints)"), "rad");
    }
    for j in 1..=JOINT_ACT_DIM {
        put(format!("goal posture joint {j}"), "rad");
    }
    for a in ["x", "y", "z"] {
        put(format!("tcp position {a}"), "m");
    }
    for a in ["x", "y", "z"] {
        put(format!("goal target point {a}"), "m");
    }
    put("nearest box height".into(), "m");
    put("nearest box width".into(), "m");
    for a in ["x", "y", "z"] {
        put(format!("closest robot point to the nearest box {a}"), "m");
    }
    for a in ["x", "y", "z"] {
        put(format!("closest point of the nearest box {a}"), "m");
    }
    put("nearest box robot distance (capped at 1)".into(), "m");
    put("box 2 robot distance (capped at 1; 1 if none)".into(), "m");
    put("box 3 robot distance (capped at 1; 1 if none)".into(), "m");
    put(
        "table robot distance (links 2-5 and the tool, capped at 1)".into(),
        "m",
    );
    layout
}

/// The observation layout of `blob`: its space's (the joint table for a joint-step blob, the
/// Cartesian table of its `obs_dim` otherwise).
fn blob_observation_layout(
    blob: &PolicyBlob,
    space: ActionSpace,
) -> Result<(&'static str, Vec<serde_json::Value>), OnnxExportError> {
    match space {
        ActionSpace::CartesianStep => observation_layout(blob.obs_dim as usize),
        ActionSpace::JointStep => Ok(("joint_v1", joint_observation_layout())),
    }
}

/// The blob's action space, when this exporter knows it and the lengths are the space's.
fn action_space(blob: &PolicyBlob) -> Result<ActionSpace, OnnxExportError> {
    let unknown = OnnxExportError::UnknownActionSpace {
        space: blob.action_space,
        act_dim: blob.act_dim as usize,
    };
    match ActionSpace::try_from(blob.action_space) {
        Ok(space @ ActionSpace::CartesianStep) if blob.act_dim as usize == shm_schemas::ACT_DIM => {
            Ok(space)
        }
        Ok(space @ ActionSpace::JointStep)
            if blob.act_dim as usize == JOINT_ACT_DIM && blob.obs_dim as usize == JOINT_OBS_DIM =>
        {
            Ok(space)
        }
        _ => Err(unknown),
    }
}

fn activation_op(a: Activation) -> Option<&'static str> {
    match a {
        Activation::Identity => None,
        Activation::Tanh => Some("Tanh"),
        Activation::Relu => Some("Relu"),
    }
}

fn activation_name(a: Activation) -> &'static str {
    activation_op(a).map_or("identity", |op| match op {
        "Tanh" => "tanh",
        _ => "relu",
    })
}

/// The blob's network as an ONNX model (the bytes of `policy.onnx`).
///
/// # Errors
/// [`OnnxExportError`] for an observation or action layout this exporter does not know.
pub fn policy_onnx(blob: &PolicyBlob) -> Result<Vec<u8>, OnnxExportError> {
    let obs_dim = blob.obs_dim as usize;
    let act_dim = blob.act_dim as usize;
    blob_observation_layout(blob, action_space(blob)?)?;
    let mut inits = vec![
        proto::tensor("obs_mean", &[obs_dim as i64], &blob.obs_mean[..obs_dim]),
        proto::tensor("obs_std", &[obs_dim as i64], &blob.obs_std[..obs_dim]),
        proto::tensor("obs_clip_lo", &[], &[-blob.obs_clip]),
        proto::tensor("obs_clip_hi", &[], &[blob.obs_clip]),
        proto::tensor("action_clip_lo", &[], &[-blob.action_clip]),
        proto::tensor("action_clip_hi", &[], &[blob.action_clip]),
        proto::tensor(
            "action_scale",
            &[act_dim as i64],
            &blob.action_scale[..act_dim],
        ),
    ];
    let mut nodes = vec![
        proto::node("centre", "Sub", &[INPUT, "obs_mean"], &["centred"], &[]),
        proto::node("scale", "Div", &["centred", "obs_std"], &["scaled"], &[]),
        proto::node(
            "clip_obs",
            "Clip",
            &["scaled", "obs_clip_lo", "obs_clip_hi"],
            &["x0"],
            &[],
        ),
    ];
    let last = dense_layers(blob, "x0", &mut nodes, &mut inits);
    nodes.push(proto::node(
        "clip_action",
        "Clip",
        &[&last, "action_clip_lo", "action_clip_hi"],
        &["clipped"],
        &[],
    ));
    nodes.push(proto::node(
        "scale_action",
        "Mul",
        &["clipped", "action_scale"],
        &[OUTPUT],
        &[],
    ));
    Ok(model(blob, &graph(blob, &nodes, &inits)))
}

/// The network's layers from `input` on: a `Gemm` (weights `[out, in]`, `transB = 1`) and
/// its activation per layer, their weights as initialisers. Returns the last output's name.
fn dense_layers(
    blob: &PolicyBlob,
    input: &str,
    nodes: &mut Vec<Msg>,
    inits: &mut Vec<Msg>,
) -> String {
    // A validated blob's activations are known values.
    let hidden_act = Activation::try_from(blob.activation).unwrap_or(Activation::Tanh);
    let output_act = Activation::try_from(blob.output_activation).unwrap_or(Activation::Identity);
    let n_hidden = blob.n_hidden as usize;
    let mut input = input.to_owned();
    let mut in_dim = blob.obs_dim as usize;
    let mut offset = 0usize;
    for k in 0..=n_hidden {
        let out_dim = if k == n_hidden {
            blob.act_dim as usize
        } else {
            blob.hidden_sizes[k] as usize
        };
        let (w, b) = (format!("w{k}"), format!("b{k}"));
        let w_len = in_dim * out_dim;
        let weights = &blob.weights[offset..offset + w_len + out_dim];
        inits.push(proto::tensor(
            &w,
            &[out_dim as i64, in_dim as i64],
            &weights[..w_len],
        ));
        inits.push(proto::tensor(&b, &[out_dim as i64], &weights[w_len..]));
        offset += w_len + out_dim;
        let pre = format!("z{k}");
        nodes.push(proto::node(
            &format!("dense{k}"),
            "Gemm",
            &[&input, &w, &b],
            &[&pre],
            &[proto::int_attribute("transB", 1)],
        ));
        let act = if k == n_hidden {
            output_act
        } else {
            hidden_act
        };
        input = match activation_op(act) {
            Some(op) => {
                let post = format!("h{k}");
                nodes.push(proto::node(&format!("act{k}"), op, &[&pre], &[&post], &[]));
                post
            }
            None => pre,
        };
        in_dim = out_dim;
    }
    input
}

/// The `GraphProto`: nodes, initialisers, the input and the output.
fn graph(blob: &PolicyBlob, nodes: &[Msg], inits: &[Msg]) -> Msg {
    let mut graph = Msg::new().string(2, "foresight_policy");
    for n in nodes {
        graph = graph.msg(1, n);
    }
    for t in inits {
        graph = graph.msg(5, t);
    }
    graph
        .string(
            10,
            "Foresight policy: raw observation in (SI units), clipped action out; see policy.schema.json",
        )
        .msg(
            11,
            &proto::float_value_info(
                INPUT,
                &[Dim::Named("batch"), Dim::Fixed(i64::from(blob.obs_dim))],
                "raw observation (SI units), layout in policy.schema.json",
            ),
        )
        .msg(
            12,
            &proto::float_value_info(
                OUTPUT,
                &[Dim::Named("batch"), Dim::Fixed(i64::from(blob.act_dim))],
                "action in [-action_clip, action_clip] × action_scale",
            ),
        )
}

/// The `ModelProto` around `graph`: versions, producer, opset and the policy's identity.
fn model(blob: &PolicyBlob, graph: &Msg) -> Vec<u8> {
    let opset = Msg::new().string(1, "").int(2, OPSET);
    let meta = |k: &str, v: String| Msg::new().string(1, k).string(2, &v);
    Msg::new()
        .int(1, IR_VERSION)
        .string(2, "foresight-learner")
        .string(3, env!("CARGO_PKG_VERSION"))
        .int(5, i64::from(POLICY_FORMAT_VERSION))
        .msg(7, graph)
        .msg(8, &opset)
        .msg(14, &meta("policy_id", blob.policy_id.to_string()))
        .msg(
            14,
            &meta(
                "task_config_hash",
                format!("{:#018x}", blob.task_config_hash),
            ),
        )
        .msg(14, &meta("schema", SCHEMA_FILE.into()))
        .into_bytes()
}

/// The task's action scales a schema states (`action.scale_m`, `action.joint_scale_rad`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActionScales {
    /// The Cartesian step's scale (m).
    pub scale_m: f64,
    /// The joint step's per-joint scale (rad), joint 1 first.
    pub joint_scale_rad: [f64; JOINT_ACT_DIM],
}

/// The schema's `action` entry of `space`.
fn action_entry(
    blob: &PolicyBlob,
    space: ActionSpace,
    scales: Option<ActionScales>,
) -> serde_json::Value {
    let act_dim = blob.act_dim as usize;
    let mut entry = serde_json::json!({
        "space": space.name(),
        "dim": act_dim,
        "limits": [-blob.action_clip, blob.action_clip],
        "scale": &blob.action_scale[..act_dim],
    });
    let (names, unit, scale_key, scale): (Vec<String>, &str, &str, serde_json::Value) = match space
    {
        ActionSpace::CartesianStep => (
            ["dx", "dy", "dz"].map(String::from).to_vec(),
            "a fraction of action.scale_m: the TCP displacement asked for one step is action × action.scale_m (m); IK turns it into joints",
            "action_scale_m",
            serde_json::json!(scales.map(|s| s.scale_m)),
        ),
        ActionSpace::JointStep => (
            (1..=JOINT_ACT_DIM).map(|j| format!("dq{j}")).collect(),
            "a fraction of action.joint_scale_rad: joint i is asked to move by action[i] × action.joint_scale_rad[i] (rad) in one step, toward the goal posture the observation carries",
            "joint_scale_rad",
            serde_json::json!(scales.map(|s| s.joint_scale_rad)),
        ),
    };
    entry["names"] = serde_json::json!(names);
    entry["unit"] = serde_json::json!(unit);
    entry[scale_key] = scale;
    entry
}

/// The contents of `policy.schema.json` for `blob`; `scales` are the task's action scales
/// when the task that trained the policy is known (its hash matches).
///
/// # Errors
/// [`OnnxExportError`] for an observation or action layout this exporter does not know.
pub fn policy_schema(
    blob: &PolicyBlob,
    scales: Option<ActionScales>,
) -> Result<serde_json::Value, OnnxExportError> {
    let obs_dim = blob.obs_dim as usize;
    let act_dim = blob.act_dim as usize;
    let space = action_space(blob)?;
    let (kind, layout) = blob_observation_layout(blob, space)?;
    let hidden: Vec<u32> = blob.hidden_sizes[..blob.n_hidden as usize].to_vec();
    let act = |b: u8| Activation::try_from(b).map_or("unknown", activation_name);
    let mut schema = serde_json::json!({
        "schema_version": SCHEMA_VERSION,
        "policy": {
            "policy_id": blob.policy_id,
            "task_config_hash": format!("{:#018x}", blob.task_config_hash),
            "blob_format_version": POLICY_FORMAT_VERSION,
            "producer": format!("foresight-learner {}", env!("CARGO_PKG_VERSION")),
        },
        "onnx": {
            "file": ONNX_FILE,
            "opset": OPSET,
            "ir_version": IR_VERSION,
            "input": {"name": INPUT, "shape": ["batch", obs_dim], "dtype": "float32"},
            "output": {"name": OUTPUT, "shape": ["batch", act_dim], "dtype": "float32"},
            "normaliser": "folded in: (observation - mean) / std, clipped to ±obs_clip",
        },
        "observation": {
            "kind": kind,
            "dim": obs_dim,
            "units": "raw SI units as the twin computes them (the graph normalises)",
            "layout": layout,
            "obs_clip": blob.obs_clip,
        },
        "action": action_entry(blob, space, scales),
        "network": {
            "hidden": hidden,
            "activation": act(blob.activation),
            "output_activation": act(blob.output_activation),
        },
    });
    // The joint table is versioned (`PolicyBlob::obs_layout`); the Cartesian one is fixed by
    // its length, and its schema stays as it was written before the joint step existed.
    if space == ActionSpace::JointStep {
        schema["observation"]["layout_version"] = serde_json::json!(blob.obs_layout);
    }
    Ok(schema)
}

/// Writes `policy.onnx` and `policy.schema.json` into `dir` (made if missing), each
/// atomically; returns their paths.
///
/// # Errors
/// [`OnnxExportError`].
pub fn write_export(
    dir: &Path,
    blob: &PolicyBlob,
    scales: Option<ActionScales>,
) -> Result<(PathBuf, PathBuf), OnnxExportError> {
    let onnx = policy_onnx(blob)?;
    let schema = policy_schema(blob, scales)?;
    std::fs::create_dir_all(dir).map_err(|source| OnnxExportError::Folder {
        path: dir.to_path_buf(),
        source,
    })?;
    let (onnx_path, schema_path) = (dir.join(ONNX_FILE), dir.join(SCHEMA_FILE));
    write_atomic(&onnx_path, &onnx)?;
    let mut text = serde_json::to_string_pretty(&schema).unwrap_or_default();
    text.push('\n');
    write_atomic(&schema_path, text.as_bytes())?;
    Ok((onnx_path, schema_path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_observation_layouts_are_the_twins() {
        assert_eq!(observation_layout(17).unwrap().0, "paper");
        let (kind, layout) = observation_layout(29).unwrap();
        assert_eq!((kind, layout.len()), ("nearest_boxes", 29));
        assert_eq!(layout[28]["name"], "box 3 robot distance (capped at 1)");
        for bad in [0, 16, 18, 35] {
            let e = observation_layout(bad).unwrap_err();
            assert!(e.to_string().contains(&format!("obs_dim {bad}")), "{e}");
        }
    }
}
