//! Calibration: ties the image to the twin's frame through the taped workspace rectangle.
//!
//! Four workspace-corner pixels (given, or found from the tape with
//! [`find_workspace_corners`]) plus the rectangle's size give
//! - a homography from image pixels to table coordinates (OpenCV `getPerspectiveTransform`),
//!   used for the rectified top view and for depth-less table positions, and
//! - the camera pose (OpenCV `solvePnP`, IPPE for planar targets, with the known
//!   intrinsics), used with depth to map any pixel to a 3D point in the twin's frame.
//!
//! Saved to and loaded from TOML ([`CalibrationFile`]); loading validates everything and
//! rejects a calibration whose corners do not reproject within [`MAX_REPROJECTION_ERROR_PX`].
//!
//! A calibration belongs to one camera: its `[camera]` table names the camera's frame id
//! (optionally its serial) and when it was made ([`crate::camera_id`]). A file without it
//! is refused ([`CalibrationError::NoCamera`]) with a hint to re-run `perception calibrate`.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, Vector3};
use opencv::core::{Mat, Point2d, Point2f, Point3d, Vector};
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera_id::{CalibratedAt, CalibrationCamera};
use crate::geometry::{CameraModel, CameraPose, Intrinsics};
use crate::workspace::WorkspaceRect;

/// Largest accepted mean reprojection error of the four corners (px).
pub const MAX_REPROJECTION_ERROR_PX: f64 = 2.0;

/// What is wrong with a calibration's numbers or geometry, or with the image it is made
/// from.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationDefect {
    /// The `[camera]` table.
    #[error(transparent)]
    Camera(#[from] crate::camera_id::CameraIdentityError),
    /// The intrinsics.
    #[error(transparent)]
    Intrinsics(#[from] crate::geometry::IntrinsicsValidateError),
    /// The workspace rectangle.
    #[error(transparent)]
    Workspace(#[from] crate::workspace::WorkspaceValidateError),
    /// The calibration could not be written as TOML.
    #[error(transparent)]
    Encode(#[from] toml::ser::Error),
    /// `rectified_px_per_m` is out of bounds.
    #[error("rectified_px_per_m = {0} must be in 10..=10000")]
    PxPerM(f64),
    /// A corner lies outside the image.
    #[error("corners_px[{index}] = {corner:?} lies outside the {width}x{height} image")]
    CornerOutside {
        /// Which corner.
        index: usize,
        /// Where (px).
        corner: [f64; 2],
        /// The image's width (px).
        width: f64,
        /// The image's height (px).
        height: f64,
    },
    /// The corners are not a convex quadrilateral.
    #[error(
        "corners_px {0:?} do not form a convex quadrilateral (wrong order or a misplaced corner?)"
    )]
    NotConvex([[f64; 2]; 4]),
    /// The solved camera is below the table.
    #[error(
        "the solved camera lies below the table (z = {0:.3} m): are the corners in the documented order?"
    )]
    BelowTable(f64),
    /// The corners reproject too far from where they were given.
    #[error(
        "corners reproject with a mean error of {0:.2} px (> {MAX_REPROJECTION_ERROR_PX} px): intrinsics and corners disagree"
    )]
    Reprojection(f64),
    /// solvePnP found no pose.
    #[error("solvePnP found no camera pose for these corners")]
    NoPose,
    /// solvePnP returned a vector of the wrong length.
    #[error("solvePnP returned {0} values for a 3-vector")]
    PoseLength(usize),
    /// A workspace corner projects from behind the camera.
    #[error("a workspace corner lies behind the camera")]
    BehindCamera,
    /// No pixel has the tape's colour.
    #[error("no tape-coloured pixels in the image")]
    NoTape,
    /// The tape region is too small to be the taped rectangle.
    #[error(
        "the largest tape-coloured region covers only {0:.0} px²: is the taped rectangle in view?"
    )]
    TapeTooSmall(f64),
    /// The tape outline is not a 4-gon.
    #[error("the tape outline has {0} corners, expected 4 (occluded corner?)")]
    TapeCorners(usize),
    /// A side of the tape outline has too few points for a line.
    #[error("side {0} of the tape outline is too short to fit")]
    TapeSideShort(usize),
    /// Two sides of the tape outline do not meet.
    #[error("two tape sides are parallel")]
    TapeSidesParallel,
}

/// Why a calibration could not be loaded, built or saved.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The file could not be read or written.
    #[error("calibration file {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Malformed TOML.
    #[error("malformed calibration file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// Values out of range or geometrically inconsistent (in the file `path`, when loaded
    /// from one).
    #[error(
        "invalid calibration{}",
        .path.as_ref().map(|p| format!(": {}", p.display())).unwrap_or_default()
    )]
    Invalid {
        /// The calibration file, if any.
        path: Option<PathBuf>,
        /// What is wrong.
        #[source]
        defect: CalibrationDefect,
    },
    /// The file has no `[camera]` table (made before it existed, or by hand): which camera
    /// it belongs to is unknown.
    #[error(
        "calibration file {path} has no [camera] table (frame_id, calibrated_at): it does not say \
         which camera it was made for, so it is refused; re-run `perception calibrate --image \
         FRAME.png --frame-id FRAME_ID …` for this camera (FRAME_ID: the header.frame_id of its \
         colour images; docs/real-arm.md, checklist step 3)"
    )]
    NoCamera {
        /// The file.
        path: PathBuf,
    },
    /// OpenCV failed.
    #[error("OpenCV failed during calibration")]
    OpenCv(#[from] opencv::Error),
}

/// What a calibration file holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// The camera it was made for (`[camera]`: `frame_id`, optional `serial`,
    /// `calibrated_at`).
    pub camera: CalibrationCamera,
    /// Intrinsics of the (rectified) colour and depth images.
    pub intrinsics: Intrinsics,
    /// The taped rectangle in the twin's frame.
    pub workspace: WorkspaceRect,
    /// Pixels of the corners, in [`WorkspaceRect::corners_xy_m`] order.
    pub corners_px: [[f64; 2]; 4],
    /// Scale of the rectified top view (px per metre).
    #[serde(default = "default_rectified_px_per_m")]
    pub rectified_px_per_m: f64,
}

fn default_rectified_px_per_m() -> f64 {
    1000.0
}

/// A validated calibration, ready to map pixels to the world.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// What was loaded.
    pub file: CalibrationFile,
    /// Intrinsics and the solved camera pose.
    pub model: CameraModel,
    /// Image pixel → table (x, y) in metres, homogeneous.
    pub pixel_to_table: Matrix3<f64>,
    /// Mean distance between the given corners and the corners reprojected with the pose (px).
    pub reprojection_error_px: f64,
}

/// [`CalibrationError::Invalid`] with `defect`, before the file is known.
fn invalid(defect: impl Into<CalibrationDefect>) -> CalibrationError {
    CalibrationError::Invalid {
        path: None,
        defect: defect.into(),
    }
}

impl Calibration {
    /// Validates `file` and solves the homography and the camera pose.
    ///
    /// # Errors
    /// [`CalibrationError::Invalid`] for a bad `[camera]` table
    /// ([`CalibrationCamera::validate`], against this machine's clock), bad numbers, a
    /// degenerate quadrilateral, a pose that puts the camera below the table or a
    /// reprojection error above [`MAX_REPROJECTION_ERROR_PX`]; [`CalibrationError::OpenCv`]
    /// when OpenCV fails.
    pub fn new(file: CalibrationFile) -> Result<Self, CalibrationError> {
        file.camera.validate(CalibratedAt::now()).map_err(invalid)?;
        check_file(&file)?;
        let pixel_to_table = pixel_to_table_homography(&file)?;
        let z = file.workspace.table_height_m;
        let pose = solve_pose(&file)?;
        let model = CameraModel {
            intrinsics: file.intrinsics,
            pose,
        };
        if pose.eye_m().z <= z {
            return Err(invalid(CalibrationDefect::BelowTable(pose.eye_m().z)));
        }
        let err = reprojection_error_px(&model, &file)?;
        if err > MAX_REPROJECTION_ERROR_PX {
            return Err(invalid(CalibrationDefect::Reprojection(err)));
        }
        Ok(Self {
            file,
            model,
            pixel_to_table,
            reprojection_error_px: err,
        })
    }

    /// Loads and validates a calibration file.
    ///
    /// # Errors
    /// See [`Calibration::new`]; plus I/O and TOML errors, and
    /// [`CalibrationError::NoCamera`] for a file that would be valid but for its missing
    /// `[camera]` table.
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let file: CalibrationFile = toml::from_str(&text).map_err(|e| {
            if lacks_only_camera(&text) {
                CalibrationError::NoCamera {
                    path: path.to_path_buf(),
                }
            } else {
                CalibrationError::Parse {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                }
            }
        })?;
        Self::new(file).map_err(|e| match e {
            CalibrationError::Invalid { defect, .. } => CalibrationError::Invalid {
                path: Some(path.to_path_buf()),
                defect,
            },
            other => other,
        })
    }

    /// Writes the calibration file (TOML).
    ///
    /// # Errors
    /// [`CalibrationError::Io`].
    pub fn save(&self, path: &Path) -> Result<(), CalibrationError> {
        let text = toml::to_string_pretty(&self.file).map_err(invalid)?;
        let header = format!(
            "# Foresight perception calibration of camera {:?}, made {}. It is used only with that camera.\n\
             # Corner order: (xmin,ymin), (xmin,ymax), (xmax,ymax), (xmax,ymin).\n\
             # Solved camera centre: {:?} m; mean corner reprojection error {:.3} px.\n",
            self.file.camera.frame_id,
            self.file.camera.calibrated_at,
            self.model.pose.eye_m().as_slice(),
            self.reprojection_error_px
        );
        std::fs::write(path, header + &text).map_err(|source| CalibrationError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Table coordinates (x, y) in metres of an image pixel, through the homography.
    pub fn pixel_to_table_m(&self, u_px: f64, v_px: f64) -> [f64; 2] {
        let p = self.pixel_to_table * Vector3::new(u_px, v_px, 1.0);
        [p.x / p.z, p.y / p.z]
    }

    /// The homography from image pixels to the rectified top view (rows along +x from the
    /// workspace's `xmin` edge, columns along +y from its `ymin` edge).
    pub fn rectify_homography(&self) -> Matrix3<f64> {
        let s = self.file.rectified_px_per_m;
        let [x0, y0] = self.file.workspace.min_xy_m;
        // table (x, y) → rectified (col, row) = ((y - y0) s, (x - x0) s)
        let table_to_rect = Matrix3::new(0.0, s, -y0 * s, s, 0.0, -x0 * s, 0.0, 0.0, 1.0);
        table_to_rect * self.pixel_to_table
    }

    /// Size of the rectified top view (width, height) in px.
    pub fn rectified_size_px(&self) -> (i32, i32) {
        let s = self.file.rectified_px_per_m;
        let ws = self.file.workspace.size_m;
        ((ws[1] * s).round() as i32, (ws[0] * s).round() as i32)
    }

    /// Warps a colour image to the rectified top view of the workspace.
    ///
    /// # Errors
    /// OpenCV errors.
    pub fn rectify(&self, bgr: &Mat) -> Result<Mat, CalibrationError> {
        let h = self.rectify_homography();
        let hm = Mat::from_slice_2d(&[
            [h[(0, 0)], h[(0, 1)], h[(0, 2)]],
            [h[(1, 0)], h[(1, 1)], h[(1, 2)]],
            [h[(2, 0)], h[(2, 1)], h[(2, 2)]],
        ])?;
        let (w, hh) = self.rectified_size_px();
        let mut out = Mat::default();
        opencv::imgproc::warp_perspective(
            bgr,
            &mut out,
            &hm,
            opencv::core::Size::new(w, hh),
            opencv::imgproc::INTER_LINEAR,
            opencv::core::BORDER_CONSTANT,
            opencv::core::Scalar::all(0.0),
        )?;
        Ok(out)
    }
}

/// Whether `text` lacks a `[camera]` table and would parse as a [`CalibrationFile`] with one
/// (an old calibration file): then the missing table is the error to report.
fn lacks_only_camera(text: &str) -> bool {
    let Ok(mut table) = toml::from_str::<toml::Table>(text) else {
        return false;
    };
    if table.contains_key("camera") {
        return false;
    }
    let Ok(camera) = toml::Value::try_from(CalibrationCamera::synthetic(CalibratedAt::now()))
    else {
        return false;
    };
    table.insert("camera".into(), camera);
    toml::Value::Table(table)
        .try_into::<CalibrationFile>()
        .is_ok()
}

/// Checks the numbers of a calibration file: intrinsics, workspace, scale, corners inside
/// the image and forming a convex quadrilateral.
fn check_file(file: &CalibrationFile) -> Result<(), CalibrationError> {
    file.intrinsics.validate().map_err(invalid)?;
    file.workspace.validate().map_err(invalid)?;
    if !(file.rectified_px_per_m.is_finite()
        && (10.0..=10_000.0).contains(&file.rectified_px_per_m))
    {
        return Err(invalid(CalibrationDefect::PxPerM(file.rectified_px_per_m)));
    }
    let (w, h) = (
        f64::from(file.intrinsics.width_px),
        f64::from(file.intrinsics.height_px),
    );
    for (i, c) in file.corners_px.iter().enumerate() {
        if !(c[0].is_finite()
            && c[1].is_finite()
            && (0.0..w).contains(&c[0])
            && (0.0..h).contains(&c[1]))
        {
            return Err(invalid(CalibrationDefect::CornerOutside {
                index: i,
                corner: *c,
                width: w,
                height: h,
            }));
        }
    }
    if !is_convex_quad(&file.corners_px) {
        return Err(invalid(CalibrationDefect::NotConvex(file.corners_px)));
    }
    Ok(())
}

/// Image pixel → table (x, y) from the four corners (OpenCV `getPerspectiveTransform`).
fn pixel_to_table_homography(file: &CalibrationFile) -> Result<Matrix3<f64>, CalibrationError> {
    let src: Vector<Point2f> = file
        .corners_px
        .iter()
        .map(|c| Point2f::new(c[0] as f32, c[1] as f32))
        .collect();
    let dst: Vector<Point2f> = file
        .workspace
        .corners_xy_m()
        .iter()
        .map(|c| Point2f::new(c[0] as f32, c[1] as f32))
        .collect();
    let hm = opencv::imgproc::get_perspective_transform(&src, &dst, opencv::core::DECOMP_LU)?;
    mat3_from_cv(&hm)
}

/// The camera pose from the four corners and the intrinsics (OpenCV `solvePnP`, IPPE).
fn solve_pose(file: &CalibrationFile) -> Result<CameraPose, CalibrationError> {
    let z = file.workspace.table_height_m;
    let object: Vector<Point3d> = file
        .workspace
        .corners_xy_m()
        .iter()
        .map(|c| Point3d::new(c[0], c[1], z))
        .collect();
    let image: Vector<Point2d> = file
        .corners_px
        .iter()
        .map(|c| Point2d::new(c[0], c[1]))
        .collect();
    let k = file.intrinsics;
    let camera_matrix = Mat::from_slice_2d(&[
        [k.fx_px, 0.0, k.cx_px],
        [0.0, k.fy_px, k.cy_px],
        [0.0, 0.0, 1.0],
    ])?;
    let mut rvec = Mat::default();
    let mut tvec = Mat::default();
    let ok = opencv::calib3d::solve_pnp(
        &object,
        &image,
        &camera_matrix,
        &Mat::default(),
        &mut rvec,
        &mut tvec,
        false,
        opencv::calib3d::SOLVEPNP_IPPE,
    )?;
    if !ok {
        return Err(invalid(CalibrationDefect::NoPose));
    }
    Ok(CameraPose {
        rotation: Rotation3::from_scaled_axis(vec3_from_cv(&rvec)?),
        translation_m: vec3_from_cv(&tvec)?,
    })
}

/// Mean distance between the given corners and the workspace corners projected by `model`.
fn reprojection_error_px(
    model: &CameraModel,
    file: &CalibrationFile,
) -> Result<f64, CalibrationError> {
    let z = file.workspace.table_height_m;
    let mut err = 0.0;
    for (c, px) in file
        .workspace
        .corners_xy_m()
        .iter()
        .zip(file.corners_px.iter())
    {
        let (p, _) = model
            .project([c[0], c[1], z])
            .ok_or_else(|| invalid(CalibrationDefect::BehindCamera))?;
        err += ((p[0] - px[0]).powi(2) + (p[1] - px[1]).powi(2)).sqrt() / 4.0;
    }
    Ok(err)
}

fn mat3_from_cv(m: &Mat) -> Result<Matrix3<f64>, CalibrationError> {
    let mut out = Matrix3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            out[(r, c)] = *m.at_2d::<f64>(r as i32, c as i32)?;
        }
    }
    Ok(out)
}

fn vec3_from_cv(m: &Mat) -> Result<Vector3<f64>, CalibrationError> {
    let d = m.data_typed::<f64>()?;
    if d.len() != 3 {
        return Err(invalid(CalibrationDefect::PoseLength(d.len())));
    }
    Ok(Vector3::new(d[0], d[1], d[2]))
}

fn is_convex_quad(c: &[[f64; 2]; 4]) -> bool {
    let mut sign = 0.0;
    for i in 0..4 {
        let a = c[i];
        let b = c[(i + 1) % 4];
        let d = c[(i + 2) % 4];
        let cross = (b[0] - a[0]) * (d[1] - b[1]) - (b[1] - a[1]) * (d[0] - b[0]);
        if cross.abs() < 1.0 {
            return false;
        }
        if sign == 0.0 {
            sign = cross.signum();
        } else if cross.signum() != sign {
            return false;
        }
    }
    true
}

/// HSV range (OpenCV scale: H 0..180, S and V 0..255), inclusive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HsvRange {
    /// Lower bound.
    pub hsv_min: [u8; 3],
    /// Upper bound.
    pub hsv_max: [u8; 3],
}

/// The default tape colour range (the synthetic camera's yellow-orange tape).
pub const DEFAULT_TAPE_HSV: HsvRange = HsvRange {
    hsv_min: [15, 120, 60],
    hsv_max: [35, 255, 255],
};

/// Finds the four outer corners of the taped rectangle in a BGR image, sub-pixel, in
/// [`WorkspaceRect::corners_xy_m`] order for a camera in front of the robot looking back at
/// it (image top-left, top-right, bottom-right, bottom-left).
///
/// Steps: tape-colour mask; largest outer contour; its convex hull (which bridges stretches
/// of tape hidden by objects); a 4-gon by `approxPolyDP`; each side
/// refined by a least-squares line through the contour points near it, moved out by half a
/// pixel (contour points are the centres of the outermost tape pixels); adjacent lines
/// intersected.
///
/// # Errors
/// [`CalibrationError::Invalid`] when no 4-sided tape outline is found.
pub fn find_workspace_corners(
    bgr: &Mat,
    tape: HsvRange,
) -> Result<[[f64; 2]; 4], CalibrationError> {
    let contour = largest_tape_contour(bgr, tape)?;
    let rough = rough_quad(&contour)?;
    let centroid = [
        rough.iter().map(|p| p[0]).sum::<f64>() / 4.0,
        rough.iter().map(|p| p[1]).sum::<f64>() / 4.0,
    ];
    let pts: Vec<[f64; 2]> = contour
        .iter()
        .map(|p| [f64::from(p.x), f64::from(p.y)])
        .collect();
    let mut lines = [([0.0; 2], 0.0); 4];
    for (i, line) in lines.iter_mut().enumerate() {
        *line = fit_side(&pts, rough[i], rough[(i + 1) % 4], centroid)
            .ok_or_else(|| invalid(CalibrationDefect::TapeSideShort(i)))?;
    }
    let mut corners = [[0.0; 2]; 4];
    for (i, corner) in corners.iter_mut().enumerate() {
        *corner = intersect(lines[(i + 3) % 4], lines[i])
            .ok_or_else(|| invalid(CalibrationDefect::TapeSidesParallel))?;
    }
    Ok(order_image_corners(corners))
}

/// The largest outer contour of the tape-coloured pixels.
fn largest_tape_contour(
    bgr: &Mat,
    tape: HsvRange,
) -> Result<Vector<opencv::core::Point>, CalibrationError> {
    use opencv::imgproc;
    let mut hsv = Mat::default();
    imgproc::cvt_color(bgr, &mut hsv, imgproc::COLOR_BGR2HSV, 0)?;
    let mut mask = Mat::default();
    let scalar = |v: [u8; 3]| {
        opencv::core::Scalar::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]), 0.0)
    };
    opencv::core::in_range(
        &hsv,
        &scalar(tape.hsv_min),
        &scalar(tape.hsv_max),
        &mut mask,
    )?;
    let mut contours: Vector<Vector<opencv::core::Point>> = Vector::new();
    imgproc::find_contours(
        &mask,
        &mut contours,
        imgproc::RETR_EXTERNAL,
        imgproc::CHAIN_APPROX_NONE,
        opencv::core::Point::new(0, 0),
    )?;
    let mut best: Option<(f64, Vector<opencv::core::Point>)> = None;
    for c in contours {
        let area = imgproc::contour_area(&c, false)?;
        if best.as_ref().is_none_or(|(a, _)| area > *a) {
            best = Some((area, c));
        }
    }
    let (area, contour) = best.ok_or_else(|| invalid(CalibrationDefect::NoTape))?;
    if area < 1000.0 {
        return Err(invalid(CalibrationDefect::TapeTooSmall(area)));
    }
    Ok(contour)
}

/// The contour's convex hull (which bridges stretches of tape hidden behind objects
/// standing in front) simplified to a 4-gon by `approxPolyDP`.
fn rough_quad(contour: &Vector<opencv::core::Point>) -> Result<Vec<[f64; 2]>, CalibrationError> {
    use opencv::imgproc;
    let mut hull: Vector<opencv::core::Point> = Vector::new();
    imgproc::convex_hull(contour, &mut hull, false, true)?;
    let mut approx: Vector<opencv::core::Point> = Vector::new();
    let perimeter = imgproc::arc_length(&hull, true)?;
    imgproc::approx_poly_dp(&hull, &mut approx, 0.02 * perimeter, true)?;
    if approx.len() != 4 {
        return Err(invalid(CalibrationDefect::TapeCorners(approx.len())));
    }
    Ok(approx
        .iter()
        .map(|p| [f64::from(p.x), f64::from(p.y)])
        .collect())
}

/// The side from rough corner `a` to `b` refined by a line through the contour points near
/// its middle 80 %, as (normal n, offset d) with n·p = d, n pointing away from the centroid
/// and moved out by half a pixel; `None` when fewer than 10 points support it.
fn fit_side(
    pts: &[[f64; 2]],
    a: [f64; 2],
    b: [f64; 2],
    centroid: [f64; 2],
) -> Option<([f64; 2], f64)> {
    let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
    let dir = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
    let nrm = [-dir[1], dir[0]];
    let near: Vec<[f64; 2]> = pts
        .iter()
        .copied()
        .filter(|p| {
            let s = (p[0] - a[0]) * dir[0] + (p[1] - a[1]) * dir[1];
            let dist = ((p[0] - a[0]) * nrm[0] + (p[1] - a[1]) * nrm[1]).abs();
            s > 0.1 * len && s < 0.9 * len && dist < 4.0
        })
        .collect();
    if near.len() < 10 {
        return None;
    }
    let (mut n, mut d) = fit_line(&near);
    if n[0] * centroid[0] + n[1] * centroid[1] > d {
        n = [-n[0], -n[1]];
        d = -d;
    }
    Some((n, d + 0.5))
}

/// The intersection of two lines n·p = d; `None` when they are parallel.
fn intersect((n1, d1): ([f64; 2], f64), (n2, d2): ([f64; 2], f64)) -> Option<[f64; 2]> {
    let det = n1[0] * n2[1] - n1[1] * n2[0];
    if det.abs() < 1e-9 {
        return None;
    }
    Some([
        (d1 * n2[1] - d2 * n1[1]) / det,
        (n1[0] * d2 - n2[0] * d1) / det,
    ])
}

/// Total-least-squares line through points: unit normal `n` and offset `d` with `n·p = d`.
fn fit_line(p: &[[f64; 2]]) -> ([f64; 2], f64) {
    let n = p.len() as f64;
    let mx = p.iter().map(|q| q[0]).sum::<f64>() / n;
    let my = p.iter().map(|q| q[1]).sum::<f64>() / n;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for q in p {
        let (dx, dy) = (q[0] - mx, q[1] - my);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Direction = principal eigenvector; normal is perpendicular to it.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let nrm = [-theta.sin(), theta.cos()];
    (nrm, nrm[0] * mx + nrm[1] * my)
}

/// Orders four image points as top-left, top-right, bottom-right, bottom-left.
pub fn order_image_corners(c: [[f64; 2]; 4]) -> [[f64; 2]; 4] {
    let mut by_y = c;
    by_y.sort_by(|a, b| a[1].total_cmp(&b[1]));
    let (mut top, mut bottom) = ([by_y[0], by_y[1]], [by_y[2], by_y[3]]);
    top.sort_by(|a, b| a[0].total_cmp(&b[0]));
    bottom.sort_by(|a, b| a[0].total_cmp(&b[0]));
    [top[0], top[1], bottom[1], bottom[0]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::SyntheticCamera;
    use shm_schemas::error_chain::error_chain;
    use shm_schemas::scene_file::SceneFile;

    fn setup() -> (SyntheticCamera, SceneFile, CalibrationFile) {
        let cam = SyntheticCamera::load(
            &Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../assets/perception/synthetic_camera.toml"),
        )
        .unwrap();
        let scene = SceneFile::from_toml_str(
            "[goal]\ncenter_m = [-2.5, 2.5, 0.01]\nsize_m = 0.02\n",
            Path::new("<empty>"),
        )
        .unwrap();
        let file = CalibrationFile {
            camera: CalibrationCamera::synthetic(CalibratedAt::now()),
            intrinsics: cam.config.intrinsics,
            workspace: cam.workspace_for(&scene),
            corners_px: cam.workspace_corners_px(&scene).unwrap(),
            rectified_px_per_m: 1000.0,
        };
        (cam, scene, file)
    }

    #[test]
    fn exact_corners_recover_the_pose_and_the_table_mapping() {
        let (cam, _, file) = setup();
        let cal = Calibration::new(file).unwrap();
        assert!(cal.reprojection_error_px < 1e-6);
        assert!((cal.model.pose.eye_m() - cam.model.pose.eye_m()).norm() < 1e-6);
        for p in [[0.2, -0.3], [0.6, 0.3], [0.4, 0.0]] {
            let (px, _) = cam.model.project([p[0], p[1], 0.0]).unwrap();
            let back = cal.pixel_to_table_m(px[0], px[1]);
            assert!(
                (back[0] - p[0]).abs() < 1e-5 && (back[1] - p[1]).abs() < 1e-5,
                "{back:?} vs {p:?}"
            );
        }
        assert_eq!(cal.rectified_size_px(), (700, 500));
    }

    #[test]
    fn save_load_round_trip_and_clear_errors() {
        let (_, _, file) = setup();
        let dir = std::env::temp_dir().join(format!("foresight-cal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cal = Calibration::new(file.clone()).unwrap();
        cal.save(&dir.join("c.toml")).unwrap();
        assert_eq!(Calibration::load(&dir.join("c.toml")).unwrap().file, file);
        // Wrong corner order (two swapped): not convex.
        let mut bad = file.clone();
        bad.corners_px.swap(0, 1);
        let e = error_chain(&Calibration::new(bad).unwrap_err()).to_string();
        assert!(e.contains("convex"), "{e}");
        // Mirrored order: convex, but the camera would have to stand below the table.
        let mut mirrored = file.clone();
        mirrored.corners_px.reverse();
        let e = error_chain(&Calibration::new(mirrored).unwrap_err()).to_string();
        assert!(
            e.contains("below the table") || e.contains("reproject"),
            "{e}"
        );
        // A corner off the image; a workspace that disagrees with the corners.
        let mut off = file.clone();
        off.corners_px[2] = [5000.0, 10.0];
        assert!(
            error_chain(&Calibration::new(off).unwrap_err())
                .to_string()
                .contains("outside")
        );
        let mut wrong = file.clone();
        wrong.workspace.size_m = [0.9, 0.3];
        assert!(
            error_chain(&Calibration::new(wrong).unwrap_err())
                .to_string()
                .contains("reproject")
        );
        std::fs::write(dir.join("bad.toml"), "corners_px = 3\n").unwrap();
        let e = error_chain(&Calibration::load(&dir.join("bad.toml")).unwrap_err()).to_string();
        assert!(
            e.contains("malformed calibration file") && e.contains("bad.toml"),
            "{e}"
        );
        assert!(
            error_chain(&Calibration::load(&dir.join("missing.toml")).unwrap_err())
                .to_string()
                .contains("missing.toml")
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Issue 30 item 2: a calibration names its camera; a file without `[camera]` is refused
    /// naming the table with the hint to re-run `perception calibrate`, a bad field is
    /// named, and the bundled file is the synthetic camera's.
    #[test]
    fn a_calibration_names_its_camera_and_an_old_file_without_it_is_refused() {
        let (_, _, mut file) = setup();
        file.camera = CalibrationCamera {
            frame_id: "zed_left_camera_frame_optical".into(),
            serial: Some("38492711".into()),
            calibrated_at: CalibratedAt::parse("2026-11-27T12:53:48Z").unwrap(),
        };
        let dir = std::env::temp_dir().join(format!("foresight-calcam-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("c.toml");
        Calibration::new(file.clone()).unwrap().save(&p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.contains("[camera]")
                && text.contains("frame_id = \"zed_left_camera_frame_optical\"")
                && text.contains("serial = \"38492711\"")
                && text.contains("calibrated_at = 2026-11-27T12:53:48Z"),
            "{text}"
        );
        assert_eq!(Calibration::load(&p).unwrap().file, file);
        // The same file without its [camera] table: an old calibration.
        let table_start = text.find("[camera]").unwrap();
        let table_end = table_start + text[table_start..].find("\n\n").unwrap();
        let old = format!("{}{}", &text[..table_start], &text[table_end..]);
        assert!(!old.contains("frame_id"), "{old}");
        std::fs::write(&p, &old).unwrap();
        let e = Calibration::load(&p).unwrap_err();
        assert!(matches!(e, CalibrationError::NoCamera { .. }), "{e:?}");
        let m = e.to_string();
        assert!(
            m.contains("c.toml")
                && m.contains("[camera]")
                && m.contains("perception calibrate")
                && m.contains("--frame-id"),
            "{m}"
        );
        // A [camera] table without frame_id: the field is named.
        std::fs::write(
            &p,
            old.replace(
                "[intrinsics]",
                "[camera]\ncalibrated_at = 2026-11-27T12:53:48Z\n\n[intrinsics]",
            ),
        )
        .unwrap();
        let m = error_chain(&Calibration::load(&p).unwrap_err()).to_string();
        assert!(m.contains("malformed") && m.contains("frame_id"), "{m}");
        // A bad value: the field is named with the file.
        std::fs::write(
            &p,
            old.replace(
                "[intrinsics]",
                "[camera]\nframe_id = \"\"\ncalibrated_at = 2026-11-27T12:53:48Z\n\n[intrinsics]",
            ),
        )
        .unwrap();
        let m = error_chain(&Calibration::load(&p).unwrap_err()).to_string();
        assert!(m.contains("camera.frame_id") && m.contains("c.toml"), "{m}");
        // A malformed file that also lacks [camera] is reported as malformed.
        std::fs::write(&p, "corners_px = [[1.0, 2.0]]\n").unwrap();
        let e = Calibration::load(&p).unwrap_err();
        assert!(matches!(e, CalibrationError::Parse { .. }), "{e:?}");
        std::fs::remove_dir_all(&dir).ok();
        // The bundled calibration is the synthetic camera's.
        let bundled = Calibration::load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception/calibration.toml"),
        )
        .unwrap();
        assert!(
            bundled.file.camera.is_synthetic(),
            "{:?}",
            bundled.file.camera
        );
        assert_eq!(
            bundled.file.camera.frame_id,
            crate::synthetic::SYNTHETIC_CAMERA_FRAME_ID
        );
    }

    #[test]
    fn tape_corners_are_found_to_sub_pixel_and_an_empty_image_is_refused() {
        let (cam, scene, file) = setup();
        let r = cam.render(&scene);
        let frame = crate::frame::Frame::from_rendered(&r, 0, 0).unwrap();
        let found = find_workspace_corners(&frame.bgr, DEFAULT_TAPE_HSV).unwrap();
        for (a, b) in found.iter().zip(file.corners_px.iter()) {
            assert!(
                (a[0] - b[0]).hypot(a[1] - b[1]) < 0.75,
                "{found:?} vs {:?}",
                file.corners_px
            );
        }
        let grey = Mat::new_rows_cols_with_default(
            720,
            1280,
            opencv::core::CV_8UC3,
            opencv::core::Scalar::all(128.0),
        )
        .unwrap();
        let e =
            error_chain(&find_workspace_corners(&grey, DEFAULT_TAPE_HSV).unwrap_err()).to_string();
        assert!(e.contains("tape"), "{e}");
    }
}
