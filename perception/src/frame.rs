//! A camera frame as the detectors see it: colour (BGR, 8 bit), optional depth (metres,
//! 32-bit float, NaN/0 where unknown), sequence number and capture time; plus image and
//! depth file I/O with clear errors for corrupt or mismatched inputs.

use std::path::{Path, PathBuf};

use opencv::core::{CV_8UC3, CV_16UC1, CV_32FC1, Mat};
use opencv::prelude::*;

use crate::synthetic::RenderedFrame;

/// Why a frame was rejected.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The file could not be read or decoded.
    #[error("cannot read image {path}: {message}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The colour image was empty or of the wrong type.
    #[error("bad colour image: {0}")]
    BadColour(String),
    /// The depth image was of the wrong type or size.
    #[error("bad depth image: {0}")]
    BadDepth(String),
    /// OpenCV failed.
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
}

/// One camera frame.
#[derive(Debug)]
pub struct Frame {
    /// Increases by one per captured frame of a source.
    pub sequence: u64,
    /// Capture time, `CLOCK_MONOTONIC` (ns).
    pub capture_time_ns: u64,
    /// Colour, `CV_8UC3`, B-G-R.
    pub bgr: Mat,
    /// Depth along the optical axis (m), `CV_32FC1`, same size as `bgr`.
    pub depth_m: Option<Mat>,
}

impl Frame {
    /// Checks types and sizes.
    ///
    /// # Errors
    /// [`FrameError::BadColour`] / [`FrameError::BadDepth`].
    pub fn validate(&self) -> Result<(), FrameError> {
        if self.bgr.empty() {
            return Err(FrameError::BadColour("the image is empty".into()));
        }
        if self.bgr.typ() != CV_8UC3 {
            return Err(FrameError::BadColour(format!(
                "expected 8-bit BGR (CV_8UC3), got OpenCV type {}",
                self.bgr.typ()
            )));
        }
        if !self.bgr.is_continuous() {
            return Err(FrameError::BadColour(
                "the image is not stored contiguously".into(),
            ));
        }
        if let Some(d) = &self.depth_m {
            if d.typ() != CV_32FC1 || !d.is_continuous() {
                return Err(FrameError::BadDepth(format!(
                    "expected contiguous CV_32FC1 metres, got type {}",
                    d.typ()
                )));
            }
            if d.rows() != self.bgr.rows() || d.cols() != self.bgr.cols() {
                return Err(FrameError::BadDepth(format!(
                    "depth is {}x{} but colour is {}x{}",
                    d.cols(),
                    d.rows(),
                    self.bgr.cols(),
                    self.bgr.rows()
                )));
            }
        }
        Ok(())
    }

    /// Wraps a synthetic render (copies the pixels).
    ///
    /// # Errors
    /// OpenCV allocation errors.
    pub fn from_rendered(
        r: &RenderedFrame,
        sequence: u64,
        capture_time_ns: u64,
    ) -> Result<Self, FrameError> {
        let (w, h) = (r.width_px as i32, r.height_px as i32);
        let bgr =
            Mat::new_rows_cols_with_bytes::<opencv::core::Vec3b>(h, w, &r.bgr)?.try_clone()?;
        let depth = Mat::new_rows_cols_with_data::<f32>(h, w, &r.depth_m)?.try_clone()?;
        Ok(Self {
            sequence,
            capture_time_ns,
            bgr,
            depth_m: Some(depth),
        })
    }
}

/// Reads a colour image (any format OpenCV decodes).
///
/// # Errors
/// [`FrameError::Read`] for a missing, unreadable or corrupt file.
pub fn read_colour(path: &Path) -> Result<Mat, FrameError> {
    let read = |message: String| FrameError::Read {
        path: path.to_path_buf(),
        message,
    };
    if !path.is_file() {
        return Err(read("no such file".into()));
    }
    let m = opencv::imgcodecs::imread(path, opencv::imgcodecs::IMREAD_COLOR)
        .map_err(|e| read(e.to_string()))?;
    if m.empty() {
        return Err(read(
            "not a decodable image (corrupt or unsupported format)".into(),
        ));
    }
    Ok(m)
}

/// Reads a depth image: 32-bit float TIFF in metres, or 16-bit PNG/TIFF in millimetres
/// (0 = unknown). Returns `CV_32FC1` metres with NaN where unknown.
///
/// # Errors
/// [`FrameError::Read`] / [`FrameError::BadDepth`].
pub fn read_depth(path: &Path) -> Result<Mat, FrameError> {
    let read = |message: String| FrameError::Read {
        path: path.to_path_buf(),
        message,
    };
    if !path.is_file() {
        return Err(read("no such file".into()));
    }
    let m = opencv::imgcodecs::imread(path, opencv::imgcodecs::IMREAD_UNCHANGED)
        .map_err(|e| read(e.to_string()))?;
    if m.empty() {
        return Err(read(
            "not a decodable depth image (corrupt or unsupported format)".into(),
        ));
    }
    match m.typ() {
        t if t == CV_32FC1 => Ok(m),
        t if t == CV_16UC1 => {
            let mut out = Mat::default();
            m.convert_to(&mut out, CV_32FC1, 1e-3, 0.0)?;
            let data = out.data_typed_mut::<f32>()?;
            for d in data.iter_mut() {
                if *d <= 0.0 {
                    *d = f32::NAN;
                }
            }
            Ok(out)
        }
        t => Err(FrameError::BadDepth(format!(
            "{}: expected a 1-channel 32-bit float (m) or 16-bit (mm) image, got OpenCV type {t}",
            path.display()
        ))),
    }
}

/// Writes a depth image as 32-bit float TIFF (metres).
///
/// # Errors
/// OpenCV errors, or when the encoder refuses the file.
pub fn write_depth(path: &Path, depth_m: &Mat) -> Result<(), FrameError> {
    let ok = opencv::imgcodecs::imwrite(path, depth_m, &opencv::core::Vector::new())?;
    if !ok {
        return Err(FrameError::Read {
            path: path.to_path_buf(),
            message: "the encoder refused to write it".into(),
        });
    }
    Ok(())
}
