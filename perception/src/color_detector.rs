//! The classical colour detector, the default of the demo: per-class HSV thresholds
//! (configurable in TOML), depth-edge splitting, connected components, and 3D measurement of
//! each blob with the calibration.
//!
//! Per frame: BGR→HSV once (inside the image region where the workspace and anything
//! standing on it can appear, when a calibration is given), then per class `inRange`, removal
//! of mask pixels on depth discontinuities (so two objects that touch in the image but not in
//! space become two blobs), connected components over runs ([`crate::runs`]), and
//! [`measure_blob`] on every blob large enough. All buffers are kept between frames.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Rect, Scalar};
use opencv::imgproc;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::Calibration;
use crate::detection::{Detection, ObjectKind};
use crate::frame::{Frame, FrameError, ImageDefect};
use crate::measure::{Blob, MeasureScratch, measure_blob};
use crate::runs::{DepthCut, RunLabeller};

/// One colour class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourClass {
    /// A name for logs.
    pub name: String,
    /// What objects of this colour are.
    pub kind: ObjectKind,
    /// Lower HSV bound (OpenCV scale: H 0..180, S, V 0..255), inclusive.
    pub hsv_min: [u8; 3],
    /// Upper HSV bound, inclusive.
    pub hsv_max: [u8; 3],
}

/// The colour detector's configuration (TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourDetectorConfig {
    /// Smallest blob kept (px).
    pub min_area_px: u32,
    /// Neighbouring mask pixels whose depths differ by more than this are split (m).
    pub depth_edge_m: f32,
    /// Tallest object expected (m): bounds the image region searched when calibrated.
    pub max_object_height_m: f64,
    /// The classes.
    #[serde(rename = "class")]
    pub classes: Vec<ColourClass>,
}

impl Default for ColourDetectorConfig {
    fn default() -> Self {
        Self {
            min_area_px: 150,
            depth_edge_m: 0.03,
            max_object_height_m: 0.45,
            classes: vec![
                ColourClass {
                    name: "green goal cube".into(),
                    kind: ObjectKind::Goal,
                    hsv_min: [45, 100, 40],
                    hsv_max: [80, 255, 255],
                },
                ColourClass {
                    name: "blue obstacle box".into(),
                    kind: ObjectKind::Obstacle,
                    hsv_min: [95, 100, 40],
                    hsv_max: [125, 255, 255],
                },
            ],
        }
    }
}

/// Why [`ColourDetectorConfig::validate`] rejected a configuration; each message names the
/// field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ColourDetectorConfigError {
    /// `classes` is empty.
    #[error("at least one [[class]] is needed")]
    NoClasses,
    /// `min_area_px` is 0.
    #[error("min_area_px must be > 0")]
    MinArea,
    /// `depth_edge_m` is not a positive number.
    #[error("depth_edge_m = {0} must be > 0")]
    DepthEdge(f32),
    /// `max_object_height_m` is not a positive number.
    #[error("max_object_height_m = {0} must be > 0")]
    MaxObjectHeight(f64),
    /// A class's hue bound exceeds OpenCV's 0..=180.
    #[error(
        "class {class:?}: hue is 0..=180 in OpenCV's scale (hsv_min {hsv_min:?}, hsv_max {hsv_max:?})"
    )]
    Hue {
        /// The class's name.
        class: String,
        /// Its lower bound.
        hsv_min: [u8; 3],
        /// Its upper bound.
        hsv_max: [u8; 3],
    },
    /// A class's lower bound exceeds its upper bound.
    #[error("class {class:?}: hsv_min {hsv_min:?} exceeds hsv_max {hsv_max:?}")]
    Range {
        /// The class's name.
        class: String,
        /// Its lower bound.
        hsv_min: [u8; 3],
        /// Its upper bound.
        hsv_max: [u8; 3],
    },
}

/// Why a detector configuration file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum DetectorConfigError {
    /// The file could not be read.
    #[error("cannot read detector config {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Malformed TOML.
    #[error("invalid detector config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// Bad values.
    #[error("invalid detector config {path}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The first bad value.
        source: ColourDetectorConfigError,
    },
}

impl ColourDetectorConfig {
    /// Checks the values.
    ///
    /// # Errors
    /// [`ColourDetectorConfigError`] naming the first bad value.
    pub fn validate(&self) -> Result<(), ColourDetectorConfigError> {
        if self.classes.is_empty() {
            return Err(ColourDetectorConfigError::NoClasses);
        }
        if self.min_area_px == 0 {
            return Err(ColourDetectorConfigError::MinArea);
        }
        if !(self.depth_edge_m.is_finite() && self.depth_edge_m > 0.0) {
            return Err(ColourDetectorConfigError::DepthEdge(self.depth_edge_m));
        }
        if !(self.max_object_height_m.is_finite() && self.max_object_height_m > 0.0) {
            return Err(ColourDetectorConfigError::MaxObjectHeight(
                self.max_object_height_m,
            ));
        }
        for c in &self.classes {
            let (class, hsv_min, hsv_max) = (c.name.clone(), c.hsv_min, c.hsv_max);
            if hsv_min[0] > 180 || hsv_max[0] > 180 {
                return Err(ColourDetectorConfigError::Hue {
                    class,
                    hsv_min,
                    hsv_max,
                });
            }
            if (0..3).any(|i| hsv_min[i] > hsv_max[i]) {
                return Err(ColourDetectorConfigError::Range {
                    class,
                    hsv_min,
                    hsv_max,
                });
            }
        }
        Ok(())
    }

    /// Loads and validates a TOML file.
    ///
    /// # Errors
    /// [`DetectorConfigError`].
    pub fn load(path: &Path) -> Result<Self, DetectorConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| DetectorConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let c: Self = toml::from_str(&text).map_err(|e| DetectorConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        c.validate()
            .map_err(|source| DetectorConfigError::Invalid {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(c)
    }
}

/// Why detection failed on a frame.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    /// The frame was unusable.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// OpenCV failed.
    #[error("OpenCV")]
    OpenCv(#[from] opencv::Error),
    /// ONNX Runtime could not run the model.
    #[error("model: ONNX Runtime")]
    Ort(#[source] ort::Error),
    /// The model's output changed shape since it was loaded.
    #[error("model: output shape {got:?} differs from the one seen at load ({expected:?})")]
    OutputShape {
        /// The shape now.
        got: Vec<i64>,
        /// The shape at load.
        expected: Vec<i64>,
    },
}

/// The colour detector with its reusable buffers.
pub struct ColourDetector {
    config: ColourDetectorConfig,
    hsv: Mat,
    mask: Mat,
    labeller: RunLabeller,
    scratch: MeasureScratch,
}

impl ColourDetector {
    /// A detector with a validated configuration.
    ///
    /// # Errors
    /// [`ColourDetectorConfigError`] naming the first bad value.
    pub fn new(config: ColourDetectorConfig) -> Result<Self, ColourDetectorConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            hsv: Mat::default(),
            mask: Mat::default(),
            labeller: RunLabeller::default(),
            scratch: MeasureScratch::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ColourDetectorConfig {
        &self.config
    }

    /// The image region searched: with a calibration, the bounding box of the workspace at
    /// table height and at `max_object_height_m` above it (plus a margin); else everything.
    pub fn search_region(
        &self,
        width_px: i32,
        height_px: i32,
        calibration: Option<&Calibration>,
    ) -> Rect {
        let full = Rect::new(0, 0, width_px, height_px);
        let Some(cal) = calibration else { return full };
        let ws = cal.file.workspace;
        let (mut u0, mut v0, mut u1, mut v1) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for c in ws.corners_xy_m() {
            for z in [
                ws.table_height_m,
                ws.table_height_m + self.config.max_object_height_m,
            ] {
                let Some((p, _)) = cal.model.project([c[0], c[1], z]) else {
                    return full;
                };
                u0 = u0.min(p[0]);
                v0 = v0.min(p[1]);
                u1 = u1.max(p[0]);
                v1 = v1.max(p[1]);
            }
        }
        let margin = 8.0;
        let x0 = ((u0 - margin).floor().max(0.0) as i32).min(width_px - 1);
        let y0 = ((v0 - margin).floor().max(0.0) as i32).min(height_px - 1);
        let x1 = ((u1 + margin).ceil() as i32).clamp(x0 + 1, width_px);
        let y1 = ((v1 + margin).ceil() as i32).clamp(y0 + 1, height_px);
        Rect::new(x0, y0, x1 - x0, y1 - y0)
    }

    /// Detects objects in `frame`. With a calibration and depth, every detection carries its
    /// position and size in the twin's frame; with a calibration but no depth, the table
    /// point under the blob (through the homography) and the footprint width; without a
    /// calibration, zeros.
    ///
    /// # Errors
    /// [`DetectError`] for a bad frame or an OpenCV failure.
    pub fn detect(
        &mut self,
        frame: &Frame,
        calibration: Option<&Calibration>,
    ) -> Result<Vec<Detection>, DetectError> {
        frame.validate()?;
        let (w, h) = (frame.bgr.cols(), frame.bgr.rows());
        if let Some(cal) = calibration {
            check_calibrated_size(cal, w, h)?;
        }
        let roi = self.search_region(w, h, calibration);
        let view = Mat::roi(&frame.bgr, roi)?;
        imgproc::cvt_color(&view, &mut self.hsv, imgproc::COLOR_BGR2HSV, 0)?;
        let depth: Option<&[f32]> = match &frame.depth_m {
            Some(d) => Some(d.data_typed::<f32>()?),
            None => None,
        };
        let mut out = Vec::new();
        for ci in 0..self.config.classes.len() {
            let class = &self.config.classes[ci];
            let (lo, hi) = (hsv_scalar(class.hsv_min), hsv_scalar(class.hsv_max));
            let kind = class.kind;
            opencv::core::in_range(&self.hsv, &lo, &hi, &mut self.mask)?;
            let rw = roi.width as usize;
            let rh = roi.height as usize;
            let cut = depth.map(|d| DepthCut {
                depth_m: d,
                width_px: w as usize,
                edge_m: self.config.depth_edge_m,
            });
            let mask = self.mask.data_typed_mut::<u8>()?;
            self.labeller
                .label(mask, rw, rh, (roi.x, roi.y), cut.as_ref());
            for comp in self.labeller.components() {
                if comp.area < self.config.min_area_px {
                    continue;
                }
                let bbox = comp.bbox_px;
                let blob = Blob {
                    bbox_px: bbox,
                    runs: self.labeller.runs_of(comp),
                };
                let det = match (calibration, depth) {
                    (Some(cal), Some(depth)) => {
                        let Some(m) = measure_blob(
                            &blob,
                            depth,
                            w as usize,
                            &cal.model,
                            cal.file.workspace.table_height_m,
                            &mut self.scratch,
                        ) else {
                            continue;
                        };
                        Detection {
                            kind,
                            confidence: m.valid_fraction.clamp(0.0, 1.0),
                            bbox_px: bbox,
                            position_m: m.position_m,
                            size_m: m.size_m,
                        }
                    }
                    (Some(cal), None) => table_footprint(kind, bbox, cal),
                    (None, _) => Detection {
                        kind,
                        confidence: 1.0,
                        bbox_px: bbox,
                        position_m: [0.0; 3],
                        size_m: [0.0; 3],
                    },
                };
                out.push(det);
            }
        }
        Ok(out)
    }
}

/// Refuses an image of another size than the one `cal` was made for.
fn check_calibrated_size(cal: &Calibration, w: i32, h: i32) -> Result<(), DetectError> {
    let k = cal.file.intrinsics;
    if k.width_px as i32 != w || k.height_px as i32 != h {
        return Err(FrameError::BadColour(ImageDefect::Size {
            what: "the image",
            width: w,
            height: h,
            other: "the calibration is for",
            other_width: k.width_px as i32,
            other_height: k.height_px as i32,
        })
        .into());
    }
    Ok(())
}

/// An HSV triple as OpenCV's `Scalar` (fourth channel 0).
fn hsv_scalar(hsv: [u8; 3]) -> Scalar {
    Scalar::new(f64::from(hsv[0]), f64::from(hsv[1]), f64::from(hsv[2]), 0.0)
}

/// Without depth: the table point under the middle of the blob's bottom edge, and the
/// bottom edge's width on the table as a square footprint (height unknown: 0).
fn table_footprint(kind: ObjectKind, bbox: [i32; 4], cal: &Calibration) -> Detection {
    let [x, y, w, h] = bbox.map(f64::from);
    let bottom = y + h - 1.0;
    let left = cal.pixel_to_table_m(x, bottom);
    let right = cal.pixel_to_table_m(x + w - 1.0, bottom);
    let mid = cal.pixel_to_table_m(x + w / 2.0, bottom);
    let width = ((left[0] - right[0]).powi(2) + (left[1] - right[1]).powi(2)).sqrt();
    Detection {
        kind,
        confidence: 0.5,
        bbox_px: bbox,
        position_m: [mid[0], mid[1], cal.file.workspace.table_height_m],
        size_m: [width, width, 0.0],
    }
}
