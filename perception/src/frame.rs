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
    #[error("bad colour image")]
    BadColour(#[source] ImageDefect),
    /// The depth image was of the wrong type or size.
    #[error("bad depth image")]
    BadDepth(#[source] ImageDefect),
    /// A depth image file is of the wrong type.
    #[error("bad depth image: {}", .path.display())]
    BadDepthFile {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        #[source]
        defect: ImageDefect,
    },
    /// OpenCV failed.
    #[error("OpenCV")]
    OpenCv(#[from] opencv::Error),
}

/// What is wrong with a colour or depth image.
#[derive(Debug, thiserror::Error)]
pub enum ImageDefect {
    /// No pixels.
    #[error("the image is empty")]
    Empty,
    /// Not stored in one block.
    #[error("the image is not stored contiguously")]
    NotContiguous,
    /// The wrong pixel type.
    #[error("expected {expected}, got OpenCV type {got}")]
    WrongType {
        /// What the image must be.
        expected: &'static str,
        /// The OpenCV type it is.
        got: i32,
    },
    /// The wrong size for what it goes with.
    #[error("{what} is {width}x{height} but {other} {other_width}x{other_height}")]
    Size {
        /// The image (`depth`, `the image`).
        what: &'static str,
        /// Its columns.
        width: i32,
        /// Its rows.
        height: i32,
        /// What it must match (`colour is`, `the calibration is for`).
        other: &'static str,
        /// Columns it must have.
        other_width: i32,
        /// Rows it must have.
        other_height: i32,
    },
    /// A `sensor_msgs/Image` encoding not handled (as received from the topic).
    #[error("unsupported encoding {0:?}")]
    Encoding(String),
    /// A `sensor_msgs/Image` that does not fit its own header.
    #[error(transparent)]
    Message(#[from] ImageMsgConvertError),
}

/// Why a `sensor_msgs/Image` could not be copied into a `Mat`; each message names the field.
#[derive(Debug, thiserror::Error)]
pub enum ImageMsgConvertError {
    /// `is_bigendian` is set on a multi-byte encoding.
    #[error("is_bigendian = {is_bigendian}: big-endian {encoding} images are not supported")]
    BigEndian {
        /// The flag as received.
        is_bigendian: u8,
        /// The encoding.
        encoding: String,
    },
    /// `width` or `height` is 0.
    #[error("empty image (0 rows or columns): width = {width}, height = {height}")]
    Empty {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
    },
    /// `step` is shorter than a row or `data` shorter than the image.
    #[error(
        "{width}x{height} {encoding} image needs {row_bytes} bytes per row, got step {step} and {data_len} bytes"
    )]
    TooShort {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
        /// The encoding.
        encoding: String,
        /// Bytes one row needs.
        row_bytes: usize,
        /// `step` as received.
        step: u32,
        /// `data.len()` as received.
        data_len: usize,
    },
    /// OpenCV could not allocate or expose the `Mat`.
    #[error("OpenCV could not make the image")]
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
            return Err(FrameError::BadColour(ImageDefect::Empty));
        }
        if self.bgr.typ() != CV_8UC3 {
            return Err(FrameError::BadColour(ImageDefect::WrongType {
                expected: "8-bit BGR (CV_8UC3)",
                got: self.bgr.typ(),
            }));
        }
        if !self.bgr.is_continuous() {
            return Err(FrameError::BadColour(ImageDefect::NotContiguous));
        }
        if let Some(d) = &self.depth_m {
            if d.typ() != CV_32FC1 || !d.is_continuous() {
                return Err(FrameError::BadDepth(ImageDefect::WrongType {
                    expected: "contiguous CV_32FC1 metres",
                    got: d.typ(),
                }));
            }
            if d.rows() != self.bgr.rows() || d.cols() != self.bgr.cols() {
                return Err(FrameError::BadDepth(ImageDefect::Size {
                    what: "depth",
                    width: d.cols(),
                    height: d.rows(),
                    other: "colour is",
                    other_width: self.bgr.cols(),
                    other_height: self.bgr.rows(),
                }));
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
        got => Err(FrameError::BadDepthFile {
            path: path.to_path_buf(),
            defect: ImageDefect::WrongType {
                expected: "a 1-channel 32-bit float (m) or 16-bit (mm) image",
                got,
            },
        }),
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
