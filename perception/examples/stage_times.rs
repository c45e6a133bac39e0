//! Prints median times of the colour path's stages on one core (a profiling aid).
//! `scripts/cargo.sh run --release -p perception --example stage_times`

// A developer tool over test fixtures: a failed unwrap or expect ends the run with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::time::Instant;

use opencv::core::{CV_32S, Mat, Scalar};
use perception::calibration::{Calibration, CalibrationFile};
use perception::color_detector::{ColourDetector, ColourDetectorConfig};
use perception::frame::Frame;
use perception::synthetic::SyntheticCamera;
use shm_schemas::scene_file::SceneFile;

fn median(mut f: impl FnMut()) -> f64 {
    let mut v: Vec<f64> = (0..60)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    opencv::core::set_num_threads(1).unwrap();
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception");
    let cam = SyntheticCamera::load(&assets.join("synthetic_camera.toml")).unwrap();
    let scene = SceneFile::from_toml_str(
        "[goal]\ncenter_m = [0.4, 0.2, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, 0.0, 0.05]\nsize_m = [0.06, 0.06, 0.1]\n[[obstacle]]\ncenter_m = [0.25, -0.2, 0.15]\nsize_m = [0.08, 0.05, 0.3]\n",
        Path::new("<x>"),
    )
    .unwrap();
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = Calibration::new(CalibrationFile {
        camera: perception::camera_id::CalibrationCamera::synthetic(
            perception::camera_id::CalibratedAt::now(),
        ),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(&scene),
        corners_px: cam.workspace_corners_px(&scene).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap();
    let mut det = ColourDetector::new(
        ColourDetectorConfig::load(&assets.join("colour_detector.toml")).unwrap(),
    )
    .unwrap();
    let roi = det.search_region(1280, 720, Some(&cal));
    println!("roi {roi:?}");
    let view = Mat::roi(&frame.bgr, roi).unwrap();
    let mut hsv = Mat::default();
    println!(
        "cvtColor   {:.3} ms",
        median(
            || opencv::imgproc::cvt_color(&view, &mut hsv, opencv::imgproc::COLOR_BGR2HSV, 0)
                .unwrap()
        )
    );
    let mut mask = Mat::default();
    let lo = Scalar::new(95.0, 100.0, 40.0, 0.0);
    let hi = Scalar::new(125.0, 255.0, 255.0, 0.0);
    println!(
        "inRange    {:.3} ms",
        median(|| opencv::core::in_range(&hsv, &lo, &hi, &mut mask).unwrap())
    );
    let (mut l, mut s, mut c) = (Mat::default(), Mat::default(), Mat::default());
    println!(
        "OpenCV connectedComponentsWithStats (replaced by runs) {:.3} ms",
        median(|| {
            opencv::imgproc::connected_components_with_stats(
                &mask, &mut l, &mut s, &mut c, 4, CV_32S,
            )
            .unwrap();
        })
    );
    println!(
        "detect     {:.3} ms",
        median(|| {
            det.detect(&frame, Some(&cal)).unwrap();
        })
    );
}
