//! The taped workspace rectangle on the table, in the twin's frame: the reference that
//! calibration ties the image to.

use serde::{Deserialize, Serialize};

/// An axis-aligned rectangle on the table top, marked with tape (its outer edge is the
/// rectangle's boundary; the tape lies inside it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkspaceRect {
    /// Corner with the smallest x and y (m, robot base frame).
    pub min_xy_m: [f64; 2],
    /// Extent along x and y (m).
    pub size_m: [f64; 2],
    /// Height of the table top (m).
    pub table_height_m: f64,
}

impl WorkspaceRect {
    /// The four corners (x, y) in the order calibration uses: `(xmin, ymin)`, `(xmin, ymax)`,
    /// `(xmax, ymax)`, `(xmax, ymin)`. For a camera in front of the robot looking back at it
    /// these are the image's top-left, top-right, bottom-right and bottom-left corners.
    pub fn corners_xy_m(&self) -> [[f64; 2]; 4] {
        let [x0, y0] = self.min_xy_m;
        let [x1, y1] = [x0 + self.size_m[0], y0 + self.size_m[1]];
        [[x0, y0], [x0, y1], [x1, y1], [x1, y0]]
    }

    /// Checks the numbers.
    ///
    /// # Errors
    /// [`WorkspaceValidateError`] naming the first bad value.
    pub fn validate(&self) -> Result<(), WorkspaceValidateError> {
        if self
            .min_xy_m
            .iter()
            .any(|v| !v.is_finite() || v.abs() > 3.0)
        {
            return Err(WorkspaceValidateError::MinXy(self.min_xy_m));
        }
        if self
            .size_m
            .iter()
            .any(|v| !(v.is_finite() && *v > 0.01 && *v < 3.0))
        {
            return Err(WorkspaceValidateError::Size(self.size_m));
        }
        if !(self.table_height_m.is_finite() && self.table_height_m.abs() < 3.0) {
            return Err(WorkspaceValidateError::TableHeight(self.table_height_m));
        }
        Ok(())
    }
}

/// Why [`WorkspaceRect::validate`] rejected a rectangle; each message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorkspaceValidateError {
    /// `min_xy_m` is not finite or lies more than 3 m from the base.
    #[error("workspace.min_xy_m = {0:?} must be finite and within ±3 m")]
    MinXy([f64; 2]),
    /// A side of `size_m` is outside (0.01, 3) m.
    #[error("workspace.size_m = {0:?}: each side must be in (0.01, 3) m")]
    Size([f64; 2]),
    /// `table_height_m` is not finite or beyond ±3 m.
    #[error("workspace.table_height_m = {0} must be finite and within ±3 m")]
    TableHeight(f64),
}
