//! YOLOv8 ONNX detector through OpenCV's DNN module: letterbox preprocessing, decoding of the
//! `[1, 4 + classes, N]` output, confidence threshold, class-aware NMS, and a labels file
//! mapping model classes to goal / obstacle. Stock exports are made runnable on OpenCV 4.6 by
//! [`crate::onnx_patch`]; a model that still cannot run is refused at load with the reason.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Scalar, Size, Vector};
use opencv::dnn;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::Calibration;
use crate::color_detector::DetectError;
use crate::detection::{Detection, ObjectKind};
use crate::frame::Frame;
use crate::measure::{Blob, MeasureScratch, box_runs, measure_blob};
use crate::onnx_patch::{OnnxPatchError, patch_for_opencv};

/// Why a YOLO model could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum YoloLoadError {
    /// The model or labels file is missing or unreadable.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The ONNX bytes could not be read or patched.
    #[error("cannot use model {path}: {source}")]
    Patch {
        /// The model.
        path: PathBuf,
        /// Why.
        source: OnnxPatchError,
    },
    /// OpenCV refused the model or could not run it.
    #[error("OpenCV DNN cannot run model {path}: {message}")]
    Unrunnable {
        /// The model.
        path: PathBuf,
        /// OpenCV's message or a shape mismatch.
        message: String,
    },
    /// The labels file is malformed.
    #[error("labels file {path}: {message}")]
    Labels {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Bad settings.
    #[error("invalid YOLO settings: {0}")]
    Config(String),
}

/// Detector settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YoloConfig {
    /// Square network input size (px).
    pub input_size_px: i32,
    /// Lowest class score kept.
    pub confidence_threshold: f32,
    /// IoU above which a lower-scored box of the same class is suppressed.
    pub nms_iou: f32,
}

impl Default for YoloConfig {
    fn default() -> Self {
        Self {
            input_size_px: 640,
            confidence_threshold: 0.25,
            nms_iou: 0.45,
        }
    }
}

/// A decoded box in original image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawBox {
    /// Model class index.
    pub class: usize,
    /// Class score.
    pub score: f32,
    /// `[x0, y0, x1, y1]` (px).
    pub xyxy: [f32; 4],
}

/// Letterbox geometry: `network = original · scale + pad`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Scale factor.
    pub scale: f32,
    /// Horizontal padding (px).
    pub pad_x: f32,
    /// Vertical padding (px).
    pub pad_y: f32,
}

impl Letterbox {
    /// The letterbox of a `w × h` image into a `size × size` input (centred, as ultralytics).
    pub fn new(w: i32, h: i32, size: i32) -> Self {
        let scale = (size as f32 / w as f32).min(size as f32 / h as f32);
        let nw = (w as f32 * scale).round();
        let nh = (h as f32 * scale).round();
        Self {
            scale,
            pad_x: ((size as f32 - nw) / 2.0).floor(),
            pad_y: ((size as f32 - nh) / 2.0).floor(),
        }
    }
}

/// Decodes a `[1, 4 + C, N]` output (row-major `channels × n`): best class per anchor,
/// threshold, optional per-anchor box scale (see [`crate::onnx_patch`]), back to original
/// pixels through the letterbox.
pub fn decode(
    output: &[f32],
    channels: usize,
    n: usize,
    threshold: f32,
    box_scale: Option<&[f32]>,
    lb: Letterbox,
) -> Vec<RawBox> {
    let mut out = Vec::new();
    if channels <= 4 || output.len() < channels * n {
        return out;
    }
    for a in 0..n {
        let (mut best, mut score) = (0, f32::NEG_INFINITY);
        for c in 0..channels - 4 {
            let s = output[(4 + c) * n + a];
            if s > score {
                score = s;
                best = c;
            }
        }
        if score.is_nan() || score < threshold {
            continue;
        }
        let k = box_scale.and_then(|s| s.get(a).copied()).unwrap_or(1.0);
        let cx = output[a] * k;
        let cy = output[n + a] * k;
        let w = output[2 * n + a] * k;
        let h = output[3 * n + a] * k;
        let to_orig = |x: f32, pad: f32| (x - pad) / lb.scale;
        out.push(RawBox {
            class: best,
            score,
            xyxy: [
                to_orig(cx - w / 2.0, lb.pad_x),
                to_orig(cy - h / 2.0, lb.pad_y),
                to_orig(cx + w / 2.0, lb.pad_x),
                to_orig(cy + h / 2.0, lb.pad_y),
            ],
        });
    }
    out
}

/// Intersection over union of two `xyxy` boxes.
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: &[f32; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union <= 0.0 { 0.0 } else { inter / union }
}

/// Class-aware non-maximum suppression: highest score first; a box is dropped when it
/// overlaps an already kept box *of the same class* by more than `iou_threshold`.
pub fn nms(mut boxes: Vec<RawBox>, iou_threshold: f32) -> Vec<RawBox> {
    boxes.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<RawBox> = Vec::new();
    for b in boxes {
        if kept
            .iter()
            .all(|k| k.class != b.class || iou(&k.xyxy, &b.xyxy) <= iou_threshold)
        {
            kept.push(b);
        }
    }
    kept
}

/// Reads a labels file: one class per line in model order, `name` or `name: kind` with kind
/// `goal`, `obstacle` or `ignore`; a bare name must itself be `goal` or `obstacle`. Blank
/// lines and `#` comments are skipped.
///
/// # Errors
/// [`YoloLoadError::Io`] / [`YoloLoadError::Labels`].
pub fn read_labels(path: &Path) -> Result<Vec<(String, Option<ObjectKind>)>, YoloLoadError> {
    let text = std::fs::read_to_string(path).map_err(|source| YoloLoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |message: String| YoloLoadError::Labels {
        path: path.to_path_buf(),
        message,
    };
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let (name, kind) = match line.split_once(':') {
            Some((n, k)) => (n.trim(), k.trim()),
            None => (line, line),
        };
        let kind = if kind.eq_ignore_ascii_case("ignore") {
            None
        } else {
            Some(ObjectKind::parse(kind).ok_or_else(|| {
                bad(format!(
                    "line {}: class {name:?} needs a kind: write `{name}: goal`, `{name}: obstacle` or `{name}: ignore`",
                    i + 1
                ))
            })?)
        };
        out.push((name.to_string(), kind));
    }
    if out.is_empty() {
        return Err(bad("no classes".into()));
    }
    Ok(out)
}

/// The YOLOv8 detector.
pub struct YoloDetector {
    net: dnn::Net,
    config: YoloConfig,
    labels: Vec<(String, Option<ObjectKind>)>,
    box_scale: Option<Vec<f32>>,
    /// Nodes the loader rewrote (for logs).
    pub rewritten_nodes: Vec<String>,
    padded: Mat,
    resized: Mat,
    blob: Mat,
    scratch: MeasureScratch,
}

impl YoloDetector {
    /// Loads a model and its labels, patches it for OpenCV 4.6 if needed, and runs one
    /// warm-up inference so a model OpenCV cannot run is refused here, with the reason.
    ///
    /// # Errors
    /// [`YoloLoadError`].
    pub fn load(model: &Path, labels: &Path, config: YoloConfig) -> Result<Self, YoloLoadError> {
        if config.input_size_px < 32
            || config.input_size_px % 32 != 0
            || config.input_size_px > 4096
        {
            return Err(YoloLoadError::Config(format!(
                "input_size_px = {} must be a multiple of 32 in 32..=4096",
                config.input_size_px
            )));
        }
        if !(0.0..=1.0).contains(&config.confidence_threshold)
            || !(0.0..=1.0).contains(&config.nms_iou)
        {
            return Err(YoloLoadError::Config(
                "confidence_threshold and nms_iou must be in [0, 1]".into(),
            ));
        }
        let bytes = std::fs::read(model).map_err(|source| YoloLoadError::Io {
            path: model.to_path_buf(),
            source,
        })?;
        let labels = read_labels(labels)?;
        let patched = patch_for_opencv(&bytes).map_err(|source| YoloLoadError::Patch {
            path: model.to_path_buf(),
            source,
        })?;
        let unrunnable = |message: String| YoloLoadError::Unrunnable {
            path: model.to_path_buf(),
            message,
        };
        let buf: Vector<u8> = Vector::from_slice(&patched.onnx);
        let mut net = dnn::read_net_from_onnx_buffer(&buf).map_err(|e| unrunnable(e.message))?;
        net.set_preferable_backend(dnn::DNN_BACKEND_OPENCV)
            .map_err(|e| unrunnable(e.message))?;
        net.set_preferable_target(dnn::DNN_TARGET_CPU)
            .map_err(|e| unrunnable(e.message))?;
        let mut det = Self {
            net,
            config,
            labels,
            box_scale: patched.box_scale,
            rewritten_nodes: patched.rewritten_nodes,
            padded: Mat::default(),
            resized: Mat::default(),
            blob: Mat::default(),
            scratch: MeasureScratch::default(),
        };
        let probe = Mat::new_rows_cols_with_default(
            config.input_size_px,
            config.input_size_px,
            opencv::core::CV_8UC3,
            Scalar::all(114.0),
        )
        .map_err(|e| unrunnable(e.message))?;
        let (channels, n, _) = det.infer(&probe).map_err(|e| unrunnable(e.to_string()))?;
        if channels != 4 + det.labels.len() {
            return Err(unrunnable(format!(
                "the output has {channels} channels per anchor, but the labels file names {} classes (expected 4 + classes)",
                det.labels.len()
            )));
        }
        if let Some(s) = &det.box_scale
            && s.len() != n
        {
            return Err(unrunnable(format!(
                "strides constant has {} entries for {n} anchors",
                s.len()
            )));
        }
        Ok(det)
    }

    /// Runs the network on a BGR image; returns (channels, anchors, letterbox) with the
    /// output left in `self.blob`.
    fn infer(&mut self, bgr: &Mat) -> Result<(usize, usize, Letterbox), DetectError> {
        let s = self.config.input_size_px;
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
        let input = dnn::blob_from_image(
            &self.padded,
            1.0 / 255.0,
            Size::new(s, s),
            Scalar::default(),
            true,
            false,
            opencv::core::CV_32F,
        )?;
        self.net.set_input(&input, "", 1.0, Scalar::default())?;
        self.blob = self.net.forward_single("")?;
        let sizes = self.blob.mat_size();
        let dims: Vec<i32> = sizes.iter().copied().collect();
        match dims.as_slice() {
            [1, c, n] if *c > 4 && *n > 0 => Ok((*c as usize, *n as usize, lb)),
            other => Err(DetectError::Model(format!(
                "expected an output of shape [1, 4 + classes, N], got {other:?}"
            ))),
        }
    }

    /// Runs the network on a ready `[1, 3, S, S]` float blob and returns the output as the
    /// stock model defines it (`[1, 4 + C, N]`, channels-major), with the strides removed
    /// by the loader applied again — to compare against the original model's output.
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn forward_blob(&mut self, blob: &Mat) -> Result<(usize, usize, Vec<f32>), DetectError> {
        self.net.set_input(blob, "", 1.0, Scalar::default())?;
        let out = self.net.forward_single("")?;
        let dims: Vec<i32> = out.mat_size().iter().copied().collect();
        let [1, c, n] = dims[..] else {
            return Err(DetectError::Model(format!(
                "unexpected output shape {dims:?}"
            )));
        };
        let (c, n) = (c as usize, n as usize);
        let mut v = out.data_typed::<f32>()?.to_vec();
        if let Some(s) = &self.box_scale {
            for row in 0..4 {
                for a in 0..n {
                    v[row * n + a] *= s[a];
                }
            }
        }
        Ok((c, n, v))
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
        let (channels, n, lb) = self.infer(&frame.bgr)?;
        let out = self.blob.data_typed::<f32>()?;
        let boxes = nms(
            decode(
                out,
                channels,
                n,
                self.config.confidence_threshold,
                self.box_scale.as_deref(),
                lb,
            ),
            self.config.nms_iou,
        );
        let (w, h) = (frame.bgr.cols(), frame.bgr.rows());
        let depth: Option<&[f32]> = match &frame.depth_m {
            Some(d) => Some(d.data_typed::<f32>()?),
            None => None,
        };
        let mut dets = Vec::new();
        for b in boxes {
            let Some(kind) = self.labels.get(b.class).and_then(|l| l.1) else {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_of_720p_into_640() {
        let lb = Letterbox::new(1280, 720, 640);
        assert_eq!(lb.scale, 0.5);
        assert_eq!(lb.pad_x, 0.0);
        assert_eq!(lb.pad_y, 140.0);
    }

    #[test]
    fn decode_thresholds_scales_and_unletterboxes() {
        // 2 classes, 3 anchors; channels-major.
        let n = 3;
        let mut out = vec![0.0f32; 6 * n];
        let set = |out: &mut Vec<f32>, a: usize, b: [f32; 4], s: [f32; 2]| {
            for (c, v) in b.iter().chain(s.iter()).enumerate() {
                out[c * n + a] = *v;
            }
        };
        set(&mut out, 0, [10.0, 20.0, 4.0, 2.0], [0.9, 0.1]);
        set(&mut out, 1, [50.0, 50.0, 10.0, 10.0], [0.1, 0.2]);
        set(&mut out, 2, [30.0, 40.0, 2.0, 2.0], [0.3, 0.6]);
        let lb = Letterbox {
            scale: 0.5,
            pad_x: 0.0,
            pad_y: 140.0,
        };
        let boxes = decode(&out, 6, n, 0.25, Some(&[8.0, 8.0, 16.0]), lb);
        assert_eq!(boxes.len(), 2);
        assert_eq!(boxes[0].class, 0);
        // anchor 0: cx 80, cy 160, w 32, h 16 in network px → original: x (64..96)/0.5, y (152-140..168-140)/0.5
        assert_eq!(boxes[0].xyxy, [128.0, 24.0, 192.0, 56.0]);
        assert_eq!(boxes[1].class, 1);
        assert_eq!(boxes[1].score, 0.6);
        assert_eq!(boxes[1].xyxy, [928.0, 968.0, 992.0, 1032.0]);
    }

    #[test]
    fn nms_is_class_aware() {
        let b = |class, score, x: f32| RawBox {
            class,
            score,
            xyxy: [x, 0.0, x + 10.0, 10.0],
        };
        let kept = nms(
            vec![
                b(0, 0.5, 1.0),
                b(0, 0.9, 0.0),
                b(1, 0.8, 0.0),
                b(0, 0.7, 50.0),
            ],
            0.45,
        );
        assert_eq!(kept.len(), 3);
        assert_eq!(kept[0].score, 0.9);
        assert!(kept.iter().any(|k| k.class == 1));
        assert!(
            !kept.iter().any(|k| k.score == 0.5),
            "overlapping same-class box survived"
        );
        assert!((iou(&[0.0, 0.0, 10.0, 10.0], &[5.0, 0.0, 15.0, 10.0]) - 1.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn labels_map_classes_and_reject_unknown_kinds() {
        let dir = std::env::temp_dir().join(format!("foresight-labels-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("l.txt");
        std::fs::write(
            &p,
            "# classes\ngoal\ncube: goal\nbox: obstacle\nhand: ignore\n",
        )
        .unwrap();
        let l = read_labels(&p).unwrap();
        assert_eq!(l.len(), 4);
        assert_eq!(l[1], ("cube".to_string(), Some(ObjectKind::Goal)));
        assert_eq!(l[3].1, None);
        std::fs::write(&p, "person\n").unwrap();
        assert!(
            read_labels(&p)
                .unwrap_err()
                .to_string()
                .contains("needs a kind")
        );
        assert!(
            read_labels(&dir.join("missing.txt"))
                .unwrap_err()
                .to_string()
                .contains("cannot read")
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
