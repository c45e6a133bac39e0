//! Pinhole camera geometry: intrinsics, the camera pose in the twin's frame, projection of
//! world points to pixels and back-projection of a pixel with its depth to a world point.
//!
//! Conventions (OpenCV's): the camera frame has x right, y down, z forward (the optical axis);
//! integer pixel coordinates are pixel *centres*; depth is the z coordinate in the camera
//! frame (what the ZED and most RGB-D cameras publish), not the ray length. The world is the
//! twin's frame: the robot base, z up, metres.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics of an undistorted (rectified) image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Focal length along x (px).
    pub fx_px: f64,
    /// Focal length along y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// Image width (px).
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
}

/// Why [`Intrinsics::validate`] rejected a camera; each message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IntrinsicsValidateError {
    /// `fx_px` or `fy_px` is not a finite focal length above 1 px.
    #[error("intrinsics.{field} = {value} must be a finite focal length > 1 px")]
    FocalLength {
        /// `"fx_px"` or `"fy_px"`.
        field: &'static str,
        /// The value given.
        value: f64,
    },
    /// `width_px` or `height_px` is outside 16..16384.
    #[error("intrinsics image size {width_px}x{height_px} must be within 16..16384 px")]
    ImageSize {
        /// The width given.
        width_px: u32,
        /// The height given.
        height_px: u32,
    },
    /// `cx_px` or `cy_px` lies outside the image.
    #[error("intrinsics.{field} = {value} must lie inside the image {extent} {limit_px}")]
    PrincipalPoint {
        /// `"cx_px"` or `"cy_px"`.
        field: &'static str,
        /// The value given.
        value: f64,
        /// `"width"` or `"height"`.
        extent: &'static str,
        /// The image width or height (px).
        limit_px: f64,
    },
}

impl Intrinsics {
    /// Checks that the numbers describe a usable camera.
    ///
    /// # Errors
    /// [`IntrinsicsValidateError`] naming the first bad value.
    pub fn validate(&self) -> Result<(), IntrinsicsValidateError> {
        for (field, value) in [("fx_px", self.fx_px), ("fy_px", self.fy_px)] {
            if !(value.is_finite() && value > 1.0) {
                return Err(IntrinsicsValidateError::FocalLength { field, value });
            }
        }
        if self.width_px < 16
            || self.height_px < 16
            || self.width_px > 16384
            || self.height_px > 16384
        {
            return Err(IntrinsicsValidateError::ImageSize {
                width_px: self.width_px,
                height_px: self.height_px,
            });
        }
        let (w, h) = (f64::from(self.width_px), f64::from(self.height_px));
        for (field, value, extent, limit_px) in [
            ("cx_px", self.cx_px, "width", w),
            ("cy_px", self.cy_px, "height", h),
        ] {
            if !(value.is_finite() && value > 0.0 && value < limit_px) {
                return Err(IntrinsicsValidateError::PrincipalPoint {
                    field,
                    value,
                    extent,
                    limit_px,
                });
            }
        }
        Ok(())
    }

    /// The 3×3 camera matrix `K`.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx_px, 0.0, self.cx_px, 0.0, self.fy_px, self.cy_px, 0.0, 0.0, 1.0,
        )
    }
}

/// Where the camera is: `x_cam = rotation · x_world + translation_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// World-to-camera rotation.
    pub rotation: Rotation3<f64>,
    /// World origin expressed in the camera frame (m).
    pub translation_m: Vector3<f64>,
}

/// Why [`CameraPose::look_at`] found no pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "cannot look from eye_m = {eye_m:?} at target_m = {target_m:?}: degenerate or vertical view"
)]
pub struct CameraPoseLookAtError {
    /// The camera centre given (m).
    pub eye_m: [f64; 3],
    /// The target given (m).
    pub target_m: [f64; 3],
}

impl CameraPose {
    /// A camera at `eye_m` looking at `target_m`, image "up" towards world +z.
    ///
    /// # Errors
    /// [`CameraPoseLookAtError`] when the eye and target coincide or the view direction is
    /// vertical.
    pub fn look_at(eye_m: [f64; 3], target_m: [f64; 3]) -> Result<Self, CameraPoseLookAtError> {
        let eye = Vector3::from(eye_m);
        let forward = Vector3::from(target_m) - eye;
        let up = Vector3::z();
        let right = forward.cross(&up);
        if forward.norm() < 1e-6 || right.norm() < 1e-6 * forward.norm() {
            return Err(CameraPoseLookAtError { eye_m, target_m });
        }
        let f = forward.normalize();
        let r = right.normalize();
        let d = f.cross(&r);
        let m = Matrix3::from_rows(&[r.transpose(), d.transpose(), f.transpose()]);
        let rotation = Rotation3::from_matrix_unchecked(m);
        Ok(Self {
            rotation,
            translation_m: -(rotation * eye),
        })
    }

    /// The camera centre in the world (m).
    pub fn eye_m(&self) -> Vector3<f64> {
        -(self.rotation.inverse() * self.translation_m)
    }

    /// World point → camera frame.
    pub fn to_camera(&self, p_world_m: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p_world_m.coords + self.translation_m)
    }

    /// Camera frame → world point.
    pub fn to_world(&self, p_cam_m: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation.inverse() * (p_cam_m.coords - self.translation_m))
    }
}

/// Intrinsics plus pose: everything needed to map between pixels and the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    /// Intrinsics.
    pub intrinsics: Intrinsics,
    /// Pose in the twin's frame.
    pub pose: CameraPose,
}

impl CameraModel {
    /// Projects a world point to a pixel (sub-pixel) and its depth (m); `None` behind the camera.
    pub fn project(&self, p_world_m: [f64; 3]) -> Option<([f64; 2], f64)> {
        let c = self.pose.to_camera(&Point3::from(p_world_m));
        if c.z <= 1e-9 {
            return None;
        }
        let k = &self.intrinsics;
        Some((
            [k.fx_px * c.x / c.z + k.cx_px, k.fy_px * c.y / c.z + k.cy_px],
            c.z,
        ))
    }

    /// Back-projects pixel `(u, v)` at depth `depth_m` (camera z) to a world point.
    pub fn unproject(&self, u_px: f64, v_px: f64, depth_m: f64) -> [f64; 3] {
        let k = &self.intrinsics;
        let c = Point3::new(
            (u_px - k.cx_px) / k.fx_px * depth_m,
            (v_px - k.cy_px) / k.fy_px * depth_m,
            depth_m,
        );
        let w = self.pose.to_world(&c);
        [w.x, w.y, w.z]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> CameraModel {
        CameraModel {
            intrinsics: Intrinsics {
                fx_px: 900.0,
                fy_px: 900.0,
                cx_px: 640.0,
                cy_px: 360.0,
                width_px: 1280,
                height_px: 720,
            },
            pose: CameraPose::look_at([1.2, 0.0, 0.8], [0.4, 0.0, 0.0]).unwrap(),
        }
    }

    #[test]
    fn look_at_centres_the_target_and_keeps_up_up() {
        let m = model();
        let (px, depth) = m.project([0.4, 0.0, 0.0]).unwrap();
        assert!(
            (px[0] - 640.0).abs() < 1e-9 && (px[1] - 360.0).abs() < 1e-9,
            "{px:?}"
        );
        assert!((depth - (0.8f64.powi(2) * 2.0).sqrt()).abs() < 1e-9);
        // A point higher in the world appears higher (smaller v) in the image.
        let (hi, _) = m.project([0.4, 0.0, 0.2]).unwrap();
        assert!(hi[1] < 360.0);
        // World +y is image right for a camera in front of the robot looking back at it.
        let (left, _) = m.project([0.4, 0.1, 0.0]).unwrap();
        assert!(left[0] > 640.0);
        assert!((m.pose.eye_m() - Vector3::new(1.2, 0.0, 0.8)).norm() < 1e-12);
    }

    #[test]
    fn project_unproject_round_trip() {
        let m = model();
        for p in [[0.3, 0.2, 0.05], [0.6, -0.3, 0.25], [0.1, 0.0, 0.0]] {
            let (px, d) = m.project(p).unwrap();
            let back = m.unproject(px[0], px[1], d);
            for i in 0..3 {
                assert!((back[i] - p[i]).abs() < 1e-12, "{back:?} vs {p:?}");
            }
        }
        assert!(m.project([2.0, 0.0, 1.0]).is_none());
    }

    #[test]
    fn degenerate_views_and_intrinsics_are_rejected() {
        assert!(CameraPose::look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]).is_err());
        let mut k = model().intrinsics;
        assert!(k.validate().is_ok());
        k.cx_px = 2000.0;
        assert!(k.validate().unwrap_err().to_string().contains("cx_px"));
        k.cx_px = 640.0;
        k.fx_px = f64::NAN;
        let e = k.validate().unwrap_err();
        assert!(matches!(
            e,
            IntrinsicsValidateError::FocalLength { field: "fx_px", .. }
        ));
        assert!(e.to_string().contains("fx_px"), "{e}");
    }
}
