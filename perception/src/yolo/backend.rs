//! The two inference engines a YOLO model can run on, behind one call: a float NCHW blob
//! in, the model's output tensor (as the stock model defines it) and its shape out.
//!
//! - **ONNX Runtime** (`ort`, the default when its library loads): the shared library is
//!   loaded at run time (`load-dynamic`) from, in order, the `ort_library` setting /
//!   `--ort-library`, `ORT_DYLIB_PATH`, and the path `make setup` baked in at build time
//!   (`FORESIGHT_ORT_DYLIB`: the PyPI `onnxruntime` wheel's `libonnxruntime.so`). A missing
//!   or too-old library (older than 1.22, the C API this build asks for) is a clear error, never
//!   a panic. One library per process: a second, different path is refused.
//! - **OpenCV DNN** (4.6 on Debian 12): the model is patched at load by
//!   [`crate::onnx_patch`] so stock exports run; the removed strides are applied again here,
//!   so both engines return the same tensor.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use opencv::core::{Mat, Scalar, Vector};
use opencv::dnn;
use opencv::prelude::*;
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};

use crate::color_detector::DetectError;
use crate::onnx_patch::patch_for_opencv;

use super::YoloLoadError;

/// Which engine runs the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// ONNX Runtime when its library loads, else OpenCV DNN (with a warning).
    #[default]
    Auto,
    /// ONNX Runtime; an error when its library cannot be loaded.
    Ort,
    /// OpenCV DNN.
    #[value(name = "opencv")]
    #[serde(rename = "opencv")]
    OpenCv,
}

/// Where the ONNX Runtime library is looked for, in order: `explicit` (the setting or the
/// flag), `ORT_DYLIB_PATH`, the path baked in at build time by `make setup`.
///
/// # Errors
/// [`YoloLoadError::OrtLibrary`] when none is set or the file is missing.
pub fn ort_library_path(explicit: Option<&Path>) -> Result<PathBuf, YoloLoadError> {
    let candidate = explicit
        .map(Path::to_path_buf)
        .or_else(|| {
            std::env::var_os("ORT_DYLIB_PATH")
                .filter(|v| !v.is_empty())
                .map(PathBuf::from)
        })
        .or_else(|| {
            option_env!("FORESIGHT_ORT_DYLIB")
                .filter(|s| !s.is_empty())
                .map(PathBuf::from)
        });
    let Some(path) = candidate else {
        return Err(YoloLoadError::OrtLibrary {
            path: PathBuf::new(),
            message: "no ONNX Runtime library configured: run `make setup` (installs the onnxruntime wheel) and rebuild, or set ORT_DYLIB_PATH / --ort-library".into(),
        });
    };
    std::fs::canonicalize(&path).map_err(|e| YoloLoadError::OrtLibrary {
        path: path.clone(),
        message: format!("cannot open the library: {e}"),
    })
}

/// The process's one ONNX Runtime: the library it came from and its environment.
static ORT: Mutex<Option<(PathBuf, ort::environment::Environment)>> = Mutex::new(None);

/// Loads the ONNX Runtime library at `path` once per process (or reuses it).
fn ort_environment(path: &Path) -> Result<ort::environment::Environment, YoloLoadError> {
    let mut slot = ORT
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((loaded, env)) = slot.as_ref() {
        if loaded == path {
            return Ok(env.clone());
        }
        return Err(YoloLoadError::OrtLibrary {
            path: path.to_path_buf(),
            message: format!(
                "ONNX Runtime is already loaded from {} in this process; one library per process",
                loaded.display()
            ),
        });
    }
    let lib_err = |message: String| YoloLoadError::OrtLibrary {
        path: path.to_path_buf(),
        message,
    };
    let env = ort::init_from(path)
        .map_err(|e| lib_err(e.to_string()))?
        .with_name("foresight-perception")
        .with_telemetry(false)
        .build()
        .map_err(|e| lib_err(e.to_string()))?;
    *slot = Some((path.to_path_buf(), env.clone()));
    Ok(env)
}

/// The threads an engine gets when the setting is 0: the cores this process may run on.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZero::get)
}

/// A model ready to run on one engine.
pub enum Engine {
    /// ONNX Runtime.
    Ort {
        /// The session.
        session: Box<Session>,
        /// Name of the image input.
        input_name: String,
        /// The library it runs on.
        library: PathBuf,
    },
    /// OpenCV DNN.
    OpenCv {
        /// The network.
        net: Box<dnn::Net>,
        /// Per-anchor strides removed by the patch, applied again to the box rows.
        box_scale: Option<Vec<f32>>,
        /// Nodes the patch rewrote (for logs).
        rewritten_nodes: Vec<String>,
    },
}

impl Engine {
    /// An ONNX Runtime session for `bytes` with `threads` intra-op threads (0: all cores
    /// given). Threads do not spin between runs: the detector shares the machine with the
    /// controller.
    ///
    /// # Errors
    /// [`YoloLoadError::OrtLibrary`] / [`YoloLoadError::Unrunnable`].
    pub fn ort(
        model: &Path,
        bytes: &[u8],
        input_name: &str,
        library: &Path,
        threads: usize,
    ) -> Result<Self, YoloLoadError> {
        let env = ort_environment(library)?;
        let unrunnable = |message: String| YoloLoadError::Unrunnable {
            engine: "ONNX Runtime",
            path: model.to_path_buf(),
            message,
        };
        let threads = if threads == 0 {
            default_threads()
        } else {
            threads
        };
        let session = Session::builder(&env)
            .and_then(|b| Ok(b.with_optimization_level(GraphOptimizationLevel::All)?))
            .and_then(|b| Ok(b.with_intra_threads(threads)?))
            .and_then(|b| Ok(b.with_inter_threads(1)?))
            .and_then(|b| Ok(b.with_intra_op_spinning(false)?))
            .and_then(|mut b| b.commit_from_memory(bytes))
            .map_err(|e| unrunnable(e.to_string()))?;
        let input_name = if input_name.is_empty() {
            session
                .inputs()
                .first()
                .map(|i| i.name().to_string())
                .ok_or_else(|| unrunnable("the model has no input".into()))?
        } else {
            input_name.to_string()
        };
        Ok(Self::Ort {
            session: Box::new(session),
            input_name,
            library: library.to_path_buf(),
        })
    }

    /// An OpenCV DNN network for `bytes`, patched for OpenCV 4.6 when needed.
    ///
    /// # Errors
    /// [`YoloLoadError::Patch`] / [`YoloLoadError::Unrunnable`].
    pub fn opencv(model: &Path, bytes: &[u8]) -> Result<Self, YoloLoadError> {
        let patched = patch_for_opencv(bytes).map_err(|source| YoloLoadError::Patch {
            path: model.to_path_buf(),
            source,
        })?;
        let unrunnable = |message: String| YoloLoadError::Unrunnable {
            engine: "OpenCV DNN",
            path: model.to_path_buf(),
            message,
        };
        let buf: Vector<u8> = Vector::from_slice(&patched.onnx);
        let mut net = dnn::read_net_from_onnx_buffer(&buf).map_err(|e| unrunnable(e.message))?;
        net.set_preferable_backend(dnn::DNN_BACKEND_OPENCV)
            .map_err(|e| unrunnable(e.message))?;
        net.set_preferable_target(dnn::DNN_TARGET_CPU)
            .map_err(|e| unrunnable(e.message))?;
        Ok(Self::OpenCv {
            net: Box::new(net),
            box_scale: patched.box_scale,
            rewritten_nodes: patched.rewritten_nodes,
        })
    }

    /// `ort` or `opencv`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Ort { .. } => "ort",
            Self::OpenCv { .. } => "opencv",
        }
    }

    /// Runs the model on a `[1, 3, S, S]` float blob; writes its first output into `out`
    /// (as the stock model defines it) and returns its shape.
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn run(&mut self, blob: &Mat, out: &mut Vec<f32>) -> Result<Vec<i64>, DetectError> {
        match self {
            Self::Ort {
                session,
                input_name,
                ..
            } => {
                let dims: Vec<usize> = blob.mat_size().iter().map(|&d| d as usize).collect();
                let data = blob.data_typed::<f32>()?;
                let model = DetectError::Ort;
                let input = TensorRef::from_array_view((dims, data)).map_err(model)?;
                let outputs = session
                    .run(ort::inputs![input_name.as_str() => input])
                    .map_err(model)?;
                let (shape, values) = outputs[0].try_extract_tensor::<f32>().map_err(model)?;
                out.clear();
                out.extend_from_slice(values);
                Ok(shape.to_vec())
            }
            Self::OpenCv { net, box_scale, .. } => {
                net.set_input(blob, "", 1.0, Scalar::default())?;
                let res = net.forward_single("")?;
                let dims: Vec<i64> = res.mat_size().iter().map(|&d| i64::from(d)).collect();
                out.clear();
                out.extend_from_slice(res.data_typed::<f32>()?);
                if let (Some(s), [1, c, n]) = (box_scale.as_deref(), dims.as_slice()) {
                    let (c, n) = (*c as usize, *n as usize);
                    if c >= 4 && s.len() == n {
                        for row in 0..4 {
                            for (v, k) in out[row * n..(row + 1) * n].iter_mut().zip(s) {
                                *v *= k;
                            }
                        }
                    }
                }
                Ok(dims)
            }
        }
    }
}
