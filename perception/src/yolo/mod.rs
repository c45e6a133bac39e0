//! The YOLO detector: stock YOLOv8 / YOLO11 exports (`[1, 4 + C, N]`, NMS in our code) and
//! end-to-end NMS-free exports (`[1, N, 6]`), run by ONNX Runtime (default) or OpenCV DNN
//! ([`backend`]). Letterbox preprocessing at the model's own input size, decoding
//! ([`decode`](mod@decode)), class names from the model's metadata or a labels file ([`classes`]), and
//! the 3D measurement of each box from depth. A model that cannot run, or whose output fits
//! neither layout, is refused at load with the reason (a warm-up inference runs there).
//!
//! Settings live in `assets/perception/yolo.toml` ([`YoloFile`]): the model, an optional
//! labels file, and `[detector]` ([`YoloConfig`]: engine, threads, thresholds).

pub mod backend;
pub mod classes;
pub mod decode;

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Scalar, Size};
use opencv::dnn;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::Calibration;
use crate::color_detector::DetectError;
use crate::detection::Detection;
use crate::frame::Frame;
use crate::measure::{Blob, MeasureScratch, box_runs, measure_blob};
use crate::onnx_patch::{OnnxPatchError, model_info};

pub use backend::{BackendChoice, Engine, default_threads, ort_library_path};
pub use classes::{ClassMap, read_labels, resolve_classes};
pub use decode::{Letterbox, OutputLayout, RawBox, decode, decode_end_to_end, iou, nms};

/// Why a YOLO model could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum YoloLoadError {
    /// The model or labels file is missing or unreadable.
    #[error("cannot read {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The ONNX bytes could not be read or patched.
    #[error("cannot use model {path}")]
    Patch {
        /// The model.
        path: PathBuf,
        /// Why.
        source: OnnxPatchError,
    },
    /// The engine refused the model or could not run it, or its output fits no layout.
    #[error("{engine} cannot run model {path}: {message}")]
    Unrunnable {
        /// `ONNX Runtime` or `OpenCV DNN`.
        engine: &'static str,
        /// The model.
        path: PathBuf,
        /// The engine's message or a shape mismatch.
        message: String,
    },
    /// The ONNX Runtime library is missing, unloadable or too old.
    #[error("ONNX Runtime library {}: {message}", path.display())]
    OrtLibrary {
        /// The library looked at (empty when none is configured).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The class names are missing or malformed.
    #[error("labels of {path}: {message}")]
    Labels {
        /// The labels file, or the model when its metadata is at fault.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A setting is out of bounds (in the file `path`, when loaded from one).
    #[error(
        "invalid YOLO settings: {}{field} = {value} must be {allowed}",
        .path.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default()
    )]
    Setting {
        /// The settings file, if any.
        path: Option<PathBuf>,
        /// The setting (`[detector]` key).
        field: &'static str,
        /// Its value.
        value: f64,
        /// Its bounds.
        allowed: &'static str,
    },
    /// The settings file is not valid TOML for [`YoloFile`].
    #[error("invalid YOLO settings: {}", .path.display())]
    Toml {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: toml::de::Error,
    },
    /// The model's square input is outside 32..=4096 px.
    #[error("invalid YOLO settings: {}: input size {size_px} px is outside 32..=4096", .path.display())]
    ModelInputSize {
        /// The model.
        path: PathBuf,
        /// Its input size (px).
        size_px: i64,
    },
}

/// Detector settings (`[detector]` in `yolo.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct YoloConfig {
    /// `auto` (ONNX Runtime when its library loads, else OpenCV), `ort` or `opencv`.
    pub backend: BackendChoice,
    /// Inference threads; 0 = the cores this process may use. At most 64.
    pub threads: usize,
    /// Square network input (px), used only when the model's input size is dynamic; a model
    /// with a fixed input size (every stock export) runs at its own size.
    pub input_size_px: i32,
    /// Lowest class score kept, in [0, 1].
    pub confidence_threshold: f32,
    /// IoU above which a lower-scored box of the same class is suppressed, in [0, 1].
    pub nms_iou: f32,
    /// The ONNX Runtime shared library (else `ORT_DYLIB_PATH`, else the one `make setup`
    /// installed).
    pub ort_library: Option<PathBuf>,
}

impl Default for YoloConfig {
    fn default() -> Self {
        Self {
            backend: BackendChoice::Auto,
            threads: 0,
            input_size_px: 640,
            confidence_threshold: 0.25,
            nms_iou: 0.45,
            ort_library: None,
        }
    }
}

impl YoloConfig {
    /// Checks every bound; the error names the field.
    ///
    /// # Errors
    /// [`YoloLoadError::Setting`].
    pub fn validate(&self) -> Result<(), YoloLoadError> {
        let s = self.input_size_px;
        if !(32..=4096).contains(&s) || s % 32 != 0 {
            return Err(YoloLoadError::Setting {
                path: None,
                field: "input_size_px",
                value: f64::from(s),
                allowed: "a multiple of 32 in 32..=4096",
            });
        }
        for (name, v) in [
            ("confidence_threshold", self.confidence_threshold),
            ("nms_iou", self.nms_iou),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(YoloLoadError::Setting {
                    path: None,
                    field: name,
                    // The value as written (an f32 widened would print its binary tail).
                    value: v.to_string().parse().unwrap_or(f64::NAN),
                    allowed: "in [0, 1]",
                });
            }
        }
        if self.threads > 64 {
            return Err(YoloLoadError::Setting {
                path: None,
                field: "threads",
                value: self.threads as f64,
                allowed: "in 0..=64 (0: the cores given)",
            });
        }
        Ok(())
    }
}

/// `assets/perception/yolo.toml`: which model, its labels, and the detector settings. Paths
/// are relative to the file's folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YoloFile {
    /// The ONNX model.
    pub model: PathBuf,
    /// A labels file (optional when the model names its classes `goal` / `obstacle`).
    #[serde(default)]
    pub labels: Option<PathBuf>,
    /// The model OpenCV DNN runs instead of `model` (with `backend = "opencv"`, and when
    /// `auto` falls back to it): OpenCV 4.6 cannot run an int8 (QDQ) model, so a file naming
    /// one gives here the fp32 export it was quantized from. Absent: `model` on both engines.
    #[serde(default)]
    pub opencv_model: Option<PathBuf>,
    /// Detector settings.
    #[serde(default)]
    pub detector: YoloConfig,
}

impl YoloFile {
    /// Reads and validates the file; relative paths are resolved against its folder.
    ///
    /// # Errors
    /// [`YoloLoadError::Io`] / [`YoloLoadError::Toml`] / [`YoloLoadError::Setting`] naming the
    /// file (and the field).
    pub fn load(path: &Path) -> Result<Self, YoloLoadError> {
        let text = std::fs::read_to_string(path).map_err(|source| YoloLoadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut f: Self = toml::from_str(&text).map_err(|source| YoloLoadError::Toml {
            path: path.to_path_buf(),
            source,
        })?;
        f.detector.validate().map_err(|e| match e {
            YoloLoadError::Setting {
                field,
                value,
                allowed,
                ..
            } => YoloLoadError::Setting {
                path: Some(path.to_path_buf()),
                field,
                value,
                allowed,
            },
            e => e,
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        f.model = dir.join(&f.model);
        f.labels = f.labels.map(|l| dir.join(l));
        f.opencv_model = f.opencv_model.map(|m| dir.join(m));
        f.detector.ort_library = f.detector.ort_library.map(|l| dir.join(l));
        Ok(f)
    }
}

/// The YOLO detector with its reusable buffers.
pub struct YoloDetector {
    engine: Engine,
    config: YoloConfig,
    classes: ClassMap,
    layout: OutputLayout,
    /// The output shape seen at load; every later run must give the same.
    output_dims: Vec<i64>,
    input_px: i32,
    /// Nodes the OpenCV loader rewrote (empty on ONNX Runtime; for logs).
    pub rewritten_nodes: Vec<String>,
    /// Why `auto` fell back to OpenCV (for logs), if it did.
    pub fallback_reason: Option<String>,
    /// The model file the engine runs (`model`, or the OpenCV model on OpenCV DNN).
    model_path: PathBuf,
    padded: Mat,
    resized: Mat,
    output: Vec<f32>,
    scratch: MeasureScratch,
}

impl YoloDetector {
    /// Loads a model: class names from its metadata or `labels`, input size from its input
    /// shape, the engine per `config.backend`; runs one warm-up inference and identifies the
    /// output layout, so a model that cannot run is refused here, with the reason.
    ///
    /// # Errors
    /// [`YoloLoadError`].
    pub fn load(
        model: &Path,
        labels: Option<&Path>,
        config: YoloConfig,
    ) -> Result<Self, YoloLoadError> {
        Self::load_with_opencv_model(model, None, labels, config)
    }

    /// [`YoloDetector::load`] with another model for OpenCV DNN (`opencv_model` in
    /// `yolo.toml`): `model` runs on ONNX Runtime, `opencv_model` (when given) on OpenCV DNN
    /// — chosen with `backend = "opencv"` or by the `auto` fallback. Class names, input size
    /// and layout are read from the model that runs.
    ///
    /// # Errors
    /// [`YoloLoadError`].
    pub fn load_with_opencv_model(
        model: &Path,
        opencv_model: Option<&Path>,
        labels: Option<&Path>,
        config: YoloConfig,
    ) -> Result<Self, YoloLoadError> {
        config.validate()?;
        let read = |path: &Path| {
            let bytes = std::fs::read(path).map_err(|source| YoloLoadError::Io {
                path: path.to_path_buf(),
                source,
            })?;
            let info = model_info(&bytes).map_err(|source| YoloLoadError::Patch {
                path: path.to_path_buf(),
                source,
            })?;
            Ok::<_, YoloLoadError>((bytes, info))
        };
        let (bytes, info) = read(model)?;
        // OpenCV DNN's model, read only when OpenCV DNN runs.
        let on_opencv = |fallback_reason: Option<String>| match opencv_model {
            Some(cv) if cv != model => read(cv).and_then(|(b, i)| {
                Ok((
                    Engine::opencv(cv, &b)?,
                    cv.to_path_buf(),
                    i,
                    fallback_reason,
                ))
            }),
            _ => Ok((
                Engine::opencv(model, &bytes)?,
                model.to_path_buf(),
                info.clone(),
                fallback_reason,
            )),
        };
        let (engine, model_path, info, fallback_reason) = match config.backend {
            BackendChoice::OpenCv => on_opencv(None)?,
            BackendChoice::Ort => {
                let lib = ort_library_path(config.ort_library.as_deref())?;
                let e = Engine::ort(model, &bytes, &info.input_name, &lib, config.threads)?;
                (e, model.to_path_buf(), info, None)
            }
            BackendChoice::Auto => {
                match ort_library_path(config.ort_library.as_deref()).and_then(|lib| {
                    Engine::ort(model, &bytes, &info.input_name, &lib, config.threads)
                }) {
                    Ok(e) => (e, model.to_path_buf(), info, None),
                    Err(e @ YoloLoadError::OrtLibrary { .. }) => on_opencv(Some(e.to_string()))?,
                    Err(e) => return Err(e),
                }
            }
        };
        let model = model_path.as_path();
        let classes = resolve_classes(model, info.metadata("names"), labels)?;
        let input_px = match info.square_input_px() {
            Some(s) if (32..=4096).contains(&s) => s as i32,
            Some(s) => {
                return Err(YoloLoadError::ModelInputSize {
                    path: model.to_path_buf(),
                    size_px: s,
                });
            }
            None => config.input_size_px,
        };
        // Ultralytics states an NMS-free head as `end2end: True` or `'nms': True` in `args`.
        let end_to_end = info
            .metadata("end2end")
            .map(|v| v.eq_ignore_ascii_case("true"))
            .or_else(|| {
                info.metadata("args")
                    .map(|a| a.replace(' ', "").contains("'nms':True"))
                    .filter(|&nms| nms)
            });
        let rewritten_nodes = match &engine {
            Engine::OpenCv {
                rewritten_nodes, ..
            } => rewritten_nodes.clone(),
            Engine::Ort { .. } => Vec::new(),
        };
        let mut det = Self {
            engine,
            config,
            classes,
            layout: OutputLayout::EndToEnd { rows: 0 },
            output_dims: Vec::new(),
            input_px,
            rewritten_nodes,
            fallback_reason,
            model_path: model.to_path_buf(),
            padded: Mat::default(),
            resized: Mat::default(),
            output: Vec::new(),
            scratch: MeasureScratch::default(),
        };
        let engine_name = match det.engine {
            Engine::Ort { .. } => "ONNX Runtime",
            Engine::OpenCv { .. } => "OpenCV DNN",
        };
        let unrunnable = |message: String| YoloLoadError::Unrunnable {
            engine: engine_name,
            path: model.to_path_buf(),
            message,
        };
        let probe = Mat::new_rows_cols_with_default(
            input_px,
            input_px,
            opencv::core::CV_8UC3,
            Scalar::all(114.0),
        )
        .map_err(|e| unrunnable(e.message))?;
        let (dims, _) = det.infer(&probe).map_err(|e| unrunnable(e.to_string()))?;
        det.output_dims.clone_from(&dims);
        det.layout = OutputLayout::identify(&dims, det.classes.len(), end_to_end).map_err(|m| {
            unrunnable(format!(
                "{m}; the class names give {} classes",
                det.classes.len()
            ))
        })?;
        if let (
            Engine::OpenCv {
                box_scale: Some(s), ..
            },
            OutputLayout::Anchors { anchors, .. },
        ) = (&det.engine, det.layout)
            && s.len() != anchors
        {
            return Err(unrunnable(format!(
                "strides constant has {} entries for {anchors} anchors",
                s.len()
            )));
        }
        Ok(det)
    }

    /// The engine that runs the model: `ort` or `opencv`.
    pub fn backend_name(&self) -> &'static str {
        self.engine.name()
    }

    /// The model file the engine runs: the loaded model, or the OpenCV model on OpenCV DNN.
    pub fn model_path(&self) -> &Path {
        &self.model_path
    }

    /// The network's square input size (px).
    pub fn input_px(&self) -> i32 {
        self.input_px
    }

    /// The output layout found at load.
    pub fn layout(&self) -> OutputLayout {
        self.layout
    }

    /// The model's classes and what each is for the twin.
    pub fn classes(&self) -> &ClassMap {
        &self.classes
    }

    /// Letterboxes a BGR image into the network's input blob `[1, 3, S, S]` (RGB, 0..1).
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn letterbox_blob(&mut self, bgr: &Mat) -> Result<(Mat, Letterbox), DetectError> {
        let s = self.input_px;
        let lb = Letterbox::new(bgr.cols(), bgr.rows(), s);
        let nw = (bgr.cols() as f32 * lb.scale).round() as i32;
        let nh = (bgr.rows() as f32 * lb.scale).round() as i32;
        opencv::imgproc::resize(
            bgr,
            &mut self.resized,
            Size::new(nw, nh),
            0.0,
            0.0,
            opencv::imgproc::INTER_LINEAR,
        )?;
        let (px, py) = (lb.pad_x as i32, lb.pad_y as i32);
        opencv::core::copy_make_border(
            &self.resized,
            &mut self.padded,
            py,
            s - nh - py,
            px,
            s - nw - px,
            opencv::core::BORDER_CONSTANT,
            Scalar::all(114.0),
        )?;
        let blob = dnn::blob_from_image(
            &self.padded,
            1.0 / 255.0,
            Size::new(s, s),
            Scalar::default(),
            true,
            false,
            opencv::core::CV_32F,
        )?;
        Ok((blob, lb))
    }

    /// Runs the network on a BGR image; the output is left in `self.output`.
    fn infer(&mut self, bgr: &Mat) -> Result<(Vec<i64>, Letterbox), DetectError> {
        let (blob, lb) = self.letterbox_blob(bgr)?;
        let dims = self.engine.run(&blob, &mut self.output)?;
        Ok((dims, lb))
    }

    /// Runs the network on a ready `[1, 3, S, S]` float blob and returns the output as the
    /// stock model defines it (shape, values) — to compare against the original model's
    /// output.
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn forward_blob(&mut self, blob: &Mat) -> Result<(Vec<i64>, Vec<f32>), DetectError> {
        let mut out = Vec::new();
        let dims = self.engine.run(blob, &mut out)?;
        Ok((dims, out))
    }

    /// The boxes of one image in its own pixels, after threshold and (for the anchors
    /// layout) class-aware NMS.
    ///
    /// # Errors
    /// [`DetectError`], also when the output's shape differs from the one seen at load.
    pub fn boxes(&mut self, bgr: &Mat) -> Result<Vec<RawBox>, DetectError> {
        let (dims, lb) = self.infer(bgr)?;
        if dims != self.output_dims || self.output.len() < self.layout.len() {
            return Err(DetectError::OutputShape {
                got: dims,
                expected: self.output_dims.clone(),
            });
        }
        let threshold = self.config.confidence_threshold;
        Ok(match self.layout {
            OutputLayout::Anchors { channels, anchors } => nms(
                decode(&self.output, channels, anchors, threshold, None, lb),
                self.config.nms_iou,
            ),
            OutputLayout::EndToEnd { rows } => {
                decode_end_to_end(&self.output, rows, self.classes.len(), threshold, lb)
            }
        })
    }

    /// Detects objects; with a calibration and depth, measures each box's 3D extent.
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn detect(
        &mut self,
        frame: &Frame,
        calibration: Option<&Calibration>,
    ) -> Result<Vec<Detection>, DetectError> {
        frame.validate()?;
        let boxes = self.boxes(&frame.bgr)?;
        let (w, h) = (frame.bgr.cols(), frame.bgr.rows());
        let depth: Option<&[f32]> = match &frame.depth_m {
            Some(d) => Some(d.data_typed::<f32>()?),
            None => None,
        };
        let mut dets = Vec::new();
        for b in boxes {
            let Some(kind) = self.classes.get(b.class).and_then(|l| l.1) else {
                continue;
            };
            let x0 = (b.xyxy[0].round() as i32).clamp(0, w - 1);
            let y0 = (b.xyxy[1].round() as i32).clamp(0, h - 1);
            let x1 = (b.xyxy[2].round() as i32).clamp(x0 + 1, w);
            let y1 = (b.xyxy[3].round() as i32).clamp(y0 + 1, h);
            let bbox = [x0, y0, x1 - x0, y1 - y0];
            let mut det = Detection {
                kind,
                confidence: b.score.clamp(0.0, 1.0),
                bbox_px: bbox,
                position_m: [0.0; 3],
                size_m: [0.0; 3],
            };
            if let (Some(cal), Some(depth)) = (calibration, depth) {
                let runs = box_runs(bbox);
                let blob = Blob {
                    bbox_px: bbox,
                    runs: &runs,
                };
                if let Some(m) = measure_blob(
                    &blob,
                    depth,
                    w as usize,
                    &cal.model,
                    cal.file.workspace.table_height_m,
                    &mut self.scratch,
                ) {
                    det.position_m = m.position_m;
                    det.size_m = m.size_m;
                }
            } else if let Some(cal) = calibration {
                let mid = cal.pixel_to_table_m(f64::from(x0 + x1) / 2.0, f64::from(y1 - 1));
                det.position_m = [mid[0], mid[1], cal.file.workspace.table_height_m];
            }
            dets.push(det);
        }
        Ok(dets)
    }
}
