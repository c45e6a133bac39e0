//! From a blob of pixels with depth to an axis-aligned box in the twin's frame.
//!
//! Every blob pixel with a valid depth is back-projected to a world point. The top of the
//! object is a high percentile of the points' heights (so "a taller box is seen as taller");
//! its footprint is the x/y extent of the points near the top (a box's top face covers its
//! whole footprint, and every visible point lies inside it); its centre is the footprint's
//! centre at half its height above the table.

use crate::geometry::CameraModel;

/// A measured object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Box centre (m).
    pub position_m: [f64; 3],
    /// Full extents along x, y, z (m).
    pub size_m: [f64; 3],
    /// Fraction of the blob's pixels that had a valid depth.
    pub valid_fraction: f32,
}

/// Fewest valid-depth points a blob needs to be measured.
pub const MIN_POINTS: usize = 20;

/// Reusable buffers of [`measure_blob`], so a steady stream of frames does not allocate.
#[derive(Debug, Default)]
pub struct MeasureScratch {
    xs: Vec<f64>,
    ys: Vec<f64>,
    zs: Vec<f64>,
    tmp: Vec<f64>,
}

/// A horizontal run of blob pixels: row `y`, columns `x0..x1` (image coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Run {
    /// Row.
    pub y: i32,
    /// First column.
    pub x0: i32,
    /// One past the last column.
    pub x1: i32,
}

/// A blob: its bounding box (x, y, w, h in image coordinates) and its pixels as runs.
pub struct Blob<'a> {
    /// Bounding box in the image (px).
    pub bbox_px: [i32; 4],
    /// The pixels.
    pub runs: &'a [Run],
}

/// The runs covering a whole box (for detectors that report boxes, not masks).
pub fn box_runs(bbox_px: [i32; 4]) -> Vec<Run> {
    let [x, y, w, h] = bbox_px;
    (y..y + h)
        .map(|y| Run {
            y,
            x0: x,
            x1: x + w,
        })
        .collect()
}

/// Measures a blob from a depth image (`CV_32FC1` data, row-major, `width_px` per row).
/// Returns `None` when fewer than [`MIN_POINTS`] pixels have a valid depth.
pub fn measure_blob(
    blob: &Blob<'_>,
    depth_m: &[f32],
    width_px: usize,
    model: &CameraModel,
    table_height_m: f64,
    scratch: &mut MeasureScratch,
) -> Option<Measurement> {
    let MeasureScratch { xs, ys, zs, tmp } = scratch;
    xs.clear();
    ys.clear();
    zs.clear();
    let k = &model.intrinsics;
    let rot = model.pose.rotation.inverse();
    let m = rot.matrix();
    let t = model.pose.translation_m;
    // world = R^T (cam - t) = R^T cam - R^T t
    let offset = -(m * t);
    let mut members = 0usize;
    for run in blob.runs {
        let b = (f64::from(run.y) - k.cy_px) / k.fy_px;
        let row = run.y as usize * width_px;
        members += (run.x1 - run.x0).max(0) as usize;
        for x in run.x0..run.x1 {
            let d = depth_m[row + x as usize];
            if !(d.is_finite() && d > 0.0) {
                continue;
            }
            let d = f64::from(d);
            let a = (f64::from(x) - k.cx_px) / k.fx_px;
            let (cx, cy, cz) = (a * d, b * d, d);
            xs.push(m[(0, 0)] * cx + m[(0, 1)] * cy + m[(0, 2)] * cz + offset.x);
            ys.push(m[(1, 0)] * cx + m[(1, 1)] * cy + m[(1, 2)] * cz + offset.y);
            zs.push(m[(2, 0)] * cx + m[(2, 1)] * cy + m[(2, 2)] * cz + offset.z);
        }
    }
    let n = zs.len();
    if n < MIN_POINTS {
        return None;
    }
    tmp.clear();
    tmp.extend_from_slice(zs);
    let top_z = percentile(tmp, 0.98);
    let height = (top_z - table_height_m).max(0.002);
    let band = (0.25 * height).max(0.01);
    // Footprint from the points near the top: reuse tmp for x, then y.
    let trim = if n > 400 { 0.002 } else { 0.0 };
    tmp.clear();
    tmp.extend(
        xs.iter()
            .zip(zs.iter())
            .filter(|(_, z)| **z >= top_z - band)
            .map(|(x, _)| *x),
    );
    if tmp.len() < MIN_POINTS / 2 {
        return None;
    }
    let (x0, x1) = (percentile(tmp, trim), percentile(tmp, 1.0 - trim));
    tmp.clear();
    tmp.extend(
        ys.iter()
            .zip(zs.iter())
            .filter(|(_, z)| **z >= top_z - band)
            .map(|(y, _)| *y),
    );
    let (y0, y1) = (percentile(tmp, trim), percentile(tmp, 1.0 - trim));
    Some(Measurement {
        position_m: [
            (x0 + x1) / 2.0,
            (y0 + y1) / 2.0,
            table_height_m + height / 2.0,
        ],
        size_m: [(x1 - x0).max(0.002), (y1 - y0).max(0.002), height],
        valid_fraction: n as f32 / members.max(1) as f32,
    })
}

/// The `q`-quantile (0..=1) of `v` by selection (reorders `v`). `v` must not be empty.
fn percentile(v: &mut [f64], q: f64) -> f64 {
    let i = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    *v.select_nth_unstable_by(i, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CameraPose, Intrinsics};

    #[test]
    fn percentile_picks_order_statistics() {
        let mut v = vec![5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert_eq!(percentile(&mut v, 1.0), 5.0);
        assert_eq!(percentile(&mut v, 0.5), 3.0);
    }

    #[test]
    fn too_few_depth_points_give_nothing() {
        let model = CameraModel {
            intrinsics: Intrinsics {
                fx_px: 100.0,
                fy_px: 100.0,
                cx_px: 8.0,
                cy_px: 8.0,
                width_px: 16,
                height_px: 16,
            },
            pose: CameraPose::look_at([1.0, 0.0, 1.0], [0.0, 0.0, 0.0]).unwrap(),
        };
        let depth = vec![f32::NAN; 256];
        let runs = box_runs([0, 0, 16, 16]);
        let blob = Blob {
            bbox_px: [0, 0, 16, 16],
            runs: &runs,
        };
        assert!(
            measure_blob(
                &blob,
                &depth,
                16,
                &model,
                0.0,
                &mut MeasureScratch::default()
            )
            .is_none()
        );
    }
}
