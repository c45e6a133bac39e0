//! Annotated images: detection boxes with class, world position and size drawn on the
//! colour image (what `perception detect` writes next to its JSON).

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Point, Rect, Scalar, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use crate::detection::{Detection, ObjectKind};

/// Draws `detections` on a copy of `bgr`.
///
/// # Errors
/// OpenCV errors.
pub fn annotate(bgr: &Mat, detections: &[Detection]) -> Result<Mat, opencv::Error> {
    let mut out = bgr.try_clone()?;
    for d in detections {
        let colour = match d.kind {
            ObjectKind::Goal => Scalar::new(0.0, 255.0, 0.0, 0.0),
            ObjectKind::Obstacle => Scalar::new(0.0, 0.0, 255.0, 0.0),
        };
        let [x, y, w, h] = d.bbox_px;
        imgproc::rectangle(
            &mut out,
            Rect::new(x, y, w, h),
            colour,
            2,
            imgproc::LINE_8,
            0,
        )?;
        let lines = [
            format!("{} {:.2}", d.kind.name(), d.confidence),
            format!(
                "at ({:.3}, {:.3}, {:.3}) m",
                d.position_m[0], d.position_m[1], d.position_m[2]
            ),
            format!(
                "size {:.3} x {:.3} x {:.3} m",
                d.size_m[0], d.size_m[1], d.size_m[2]
            ),
        ];
        for (i, text) in lines.iter().enumerate() {
            let org = Point::new(x, (y - 6 - 16 * (2 - i as i32)).max(12));
            imgproc::put_text(
                &mut out,
                text,
                org,
                imgproc::FONT_HERSHEY_SIMPLEX,
                0.45,
                Scalar::all(0.0),
                3,
                imgproc::LINE_AA,
                false,
            )?;
            imgproc::put_text(
                &mut out,
                text,
                org,
                imgproc::FONT_HERSHEY_SIMPLEX,
                0.45,
                colour,
                1,
                imgproc::LINE_AA,
                false,
            )?;
        }
    }
    Ok(out)
}

/// Why [`write_image`] failed; each message names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageWriteError {
    /// The encoder for the extension refused the image.
    #[error("cannot write {path}: the encoder refused")]
    Refused {
        /// The file.
        path: PathBuf,
    },
    /// OpenCV failed (unknown extension, unwritable folder, …).
    #[error("cannot write {path}: {}", source.message)]
    OpenCv {
        /// The file.
        path: PathBuf,
        /// OpenCV's error.
        source: opencv::Error,
    },
}

/// Writes an image (format from the extension).
///
/// # Errors
/// [`ImageWriteError`].
pub fn write_image(path: &Path, image: &Mat) -> Result<(), ImageWriteError> {
    match opencv::imgcodecs::imwrite(path, image, &Vector::new()) {
        Ok(true) => Ok(()),
        Ok(false) => Err(ImageWriteError::Refused {
            path: path.to_path_buf(),
        }),
        Err(source) => Err(ImageWriteError::OpenCv {
            path: path.to_path_buf(),
            source,
        }),
    }
}
