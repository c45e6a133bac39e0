//! Colour path, frame → published `DetectionFrame`, on one core (OpenCV limited to one
//! thread): HSV conversion, thresholds, depth-edge cut, connected components, 3D measurement
//! of every blob, tracking and publishing over iceoryx2. 1280×720 frames of the synthetic
//! camera with a goal cube and three boxes. Also the synthetic render itself (not on the
//! timed path) for reference.
//!
//! `scripts/cargo.sh bench -p perception --bench colour_path`

// Benchmarks: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use perception::calibration::{Calibration, CalibrationFile};
use perception::color_detector::{ColourDetector, ColourDetectorConfig};
use perception::frame::Frame;
use perception::pipeline::{Detector, Pipeline};
use perception::publisher::DetectionPublisher;
use perception::synthetic::SyntheticCamera;
use perception::tracker::{Tracker, TrackerConfig};
use shm_schemas::scene_file::SceneFile;

const SCENE: &str = r#"
[goal]
center_m = [0.40, 0.20, 0.025]
size_m = 0.05
[[obstacle]]
center_m = [0.35, 0.0, 0.05]
size_m = [0.06, 0.06, 0.10]
[[obstacle]]
center_m = [0.25, -0.2, 0.15]
size_m = [0.08, 0.05, 0.30]
[[obstacle]]
center_m = [0.55, -0.15, 0.04]
size_m = [0.10, 0.07, 0.08]
"#;

fn bench(c: &mut Criterion) {
    opencv::core::set_num_threads(1).unwrap();
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception");
    let cam = SyntheticCamera::load(&assets.join("synthetic_camera.toml")).unwrap();
    let scene = SceneFile::from_toml_str(SCENE, Path::new("<bench>")).unwrap();
    let rendered = cam.render(&scene);
    let frame = Frame::from_rendered(&rendered, 1, shm_schemas::clock::monotonic_now_ns()).unwrap();
    let calibration = Calibration::new(CalibrationFile {
        camera: perception::camera_id::CalibrationCamera::synthetic(
            perception::camera_id::CalibratedAt::now(),
        ),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(&scene),
        corners_px: cam.workspace_corners_px(&scene).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap();
    let detector = ColourDetector::new(
        ColourDetectorConfig::load(&assets.join("colour_detector.toml")).unwrap(),
    )
    .unwrap();
    let prefix = format!("bench{}", std::process::id());
    let mut pipeline = Pipeline {
        detector: Detector::Colour(Box::new(detector)),
        calibration,
        selection: perception::selection::SelectionConfig::default(),
        tracker: Tracker::new(TrackerConfig::default()).unwrap(),
        publisher: DetectionPublisher::open(&prefix, 0).unwrap(),
    };
    let dets = pipeline
        .detector
        .detect(&frame, Some(&pipeline.calibration))
        .unwrap();
    assert_eq!(dets.len(), 4, "{dets:?}");
    let mut g = c.benchmark_group("colour_path_1280x720");
    g.bench_function("frame_to_published_detection_frame", |b| {
        b.iter(|| pipeline.process(std::hint::black_box(&frame)).unwrap())
    });
    g.sample_size(10);
    g.bench_function("synthetic_render (not timed path)", |b| {
        b.iter(|| cam.render(std::hint::black_box(&scene)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
