//! YOLOv8n on this machine's CPU: letterbox, inference, decoding and NMS of a 1280×720
//! synthetic frame, through ONNX Runtime (at 640 and 320, fp32 and int8) and OpenCV DNN (at
//! 640), each with the threads the process may use; and the full frame → published
//! `DetectionFrame` path (detector + 3D measurement from depth + tracker + iceoryx2 publish)
//! with YOLO at 640 and with the project's model (fp32, the default, and int8).
//!
//! The int8 models are made from the fp32 ones by scripts/quantize-yolo.sh (static QDQ
//! quantization calibrated on synthetic frames, issue 32 item 5); set
//! FORESIGHT_YOLO_MODEL_INT8 / FORESIGHT_YOLO_MODEL_320_INT8 to use others.
//!
//! The models are stock Ultralytics exports with random weights made by
//! tests/python/make_onnx_ultralytics.py (inference time does not depend on the weights);
//! set FORESIGHT_YOLO_MODEL (640) / FORESIGHT_YOLO_MODEL_320 to use others. The bench
//! provisions the Python tools with scripts/perception-pyenv.sh --ultralytics when it has to
//! build a model.
//!
//! `scripts/cargo.sh bench -p perception --bench yolo`

// Benchmarks: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use criterion::{Criterion, criterion_group, criterion_main};
use perception::calibration::{Calibration, CalibrationFile};
use perception::frame::Frame;
use perception::pipeline::{Detector, Pipeline};
use perception::publisher::DetectionPublisher;
use perception::synthetic::SyntheticCamera;
use perception::tracker::{Tracker, TrackerConfig};
use perception::yolo::{BackendChoice, YoloConfig, YoloDetector, default_threads};
use shm_schemas::scene_file::SceneFile;

fn model(imgsz: u32, env: &str) -> PathBuf {
    if let Ok(p) = std::env::var(env) {
        return p.into();
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let cache = std::env::var("FORESIGHT_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|_| std::env::temp_dir());
    let out = cache.join(format!("yolov8n-random-2cls-{imgsz}.onnx"));
    if !out.is_file() {
        let py = Command::new("bash")
            .arg(repo.join("scripts/perception-pyenv.sh"))
            .arg("--ultralytics")
            .output()
            .unwrap();
        assert!(
            py.status.success(),
            "{}",
            String::from_utf8_lossy(&py.stderr)
        );
        let python = String::from_utf8_lossy(&py.stdout)
            .lines()
            .last()
            .unwrap()
            .trim()
            .to_string();
        let st = Command::new(python)
            .env("YOLO_OFFLINE", "1")
            .env("YOLO_CONFIG_DIR", std::env::temp_dir())
            .arg(repo.join("tests/python/make_onnx_ultralytics.py"))
            .arg(&out)
            .args(["--arch", "yolov8n", "--imgsz", &imgsz.to_string()])
            .status()
            .unwrap();
        assert!(st.success());
    }
    out
}

/// The int8 quantization of `fp32` (scripts/quantize-yolo.sh, next to it in the cache).
fn int8_model(fp32: &Path, env: &str) -> PathBuf {
    if let Ok(p) = std::env::var(env) {
        return p.into();
    }
    let out = fp32.with_extension("int8.onnx");
    if !out.is_file() {
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let st = Command::new("bash")
            .arg(repo.join("scripts/quantize-yolo.sh"))
            .arg(fp32)
            .arg(&out)
            .status()
            .unwrap();
        assert!(st.success(), "scripts/quantize-yolo.sh {}", fp32.display());
    }
    out
}

fn load(model: &Path, backend: BackendChoice) -> YoloDetector {
    YoloDetector::load(
        model,
        None,
        YoloConfig {
            backend,
            ..YoloConfig::default()
        },
    )
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let m640 = model(640, "FORESIGHT_YOLO_MODEL");
    let m320 = model(320, "FORESIGHT_YOLO_MODEL_320");
    let m640_int8 = int8_model(&m640, "FORESIGHT_YOLO_MODEL_INT8");
    let m320_int8 = int8_model(&m320, "FORESIGHT_YOLO_MODEL_320_INT8");
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception");
    let cam = SyntheticCamera::load(&assets.join("synthetic_camera.toml")).unwrap();
    let scene = SceneFile::from_toml_str(
        "[goal]\ncenter_m = [0.4, 0.2, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, 0.0, 0.05]\nsize_m = [0.06, 0.06, 0.1]\n",
        Path::new("<bench>"),
    )
    .unwrap();
    let frame = Frame::from_rendered(
        &cam.render(&scene),
        1,
        shm_schemas::clock::monotonic_now_ns(),
    )
    .unwrap();
    let threads = default_threads();
    let mut g = c.benchmark_group("yolov8n_1280x720");
    g.sample_size(30);
    let mut ort640 = load(&m640, BackendChoice::Ort);
    g.bench_function(format!("ort_640_{threads}_threads"), |b| {
        b.iter(|| ort640.detect(std::hint::black_box(&frame), None).unwrap())
    });
    let mut ort640_int8 = load(&m640_int8, BackendChoice::Ort);
    g.bench_function(format!("ort_640_int8_{threads}_threads"), |b| {
        b.iter(|| {
            ort640_int8
                .detect(std::hint::black_box(&frame), None)
                .unwrap()
        })
    });
    drop(ort640_int8);
    let mut ort320 = load(&m320, BackendChoice::Ort);
    g.bench_function(format!("ort_320_{threads}_threads"), |b| {
        b.iter(|| ort320.detect(std::hint::black_box(&frame), None).unwrap())
    });
    drop(ort320);
    let mut ort320_int8 = load(&m320_int8, BackendChoice::Ort);
    g.bench_function(format!("ort_320_int8_{threads}_threads"), |b| {
        b.iter(|| {
            ort320_int8
                .detect(std::hint::black_box(&frame), None)
                .unwrap()
        })
    });
    drop(ort320_int8);
    g.sample_size(10);
    let mut cv640 = load(&m640, BackendChoice::OpenCv);
    g.bench_function(
        format!(
            "opencv_dnn_640_{}_threads",
            opencv::core::get_num_threads().unwrap()
        ),
        |b| b.iter(|| cv640.detect(std::hint::black_box(&frame), None).unwrap()),
    );
    g.finish();

    // Frame → published DetectionFrame with YOLO (ONNX Runtime, 640) as the detector.
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
    let prefix = format!("benchyolo{}", std::process::id());
    let mut pipeline = Pipeline {
        detector: Detector::Yolo(Box::new(ort640)),
        calibration,
        selection: perception::selection::SelectionConfig::default(),
        tracker: Tracker::new(TrackerConfig::default()).unwrap(),
        publisher: DetectionPublisher::open(&prefix, 0).unwrap(),
    };
    let mut g = c.benchmark_group("yolo_path_1280x720");
    g.sample_size(30);
    g.bench_function("ort_640_frame_to_published_detection_frame", |b| {
        b.iter(|| pipeline.process(std::hint::black_box(&frame)).unwrap())
    });
    // The same path with the project's trained model and settings (real detections, each
    // measured from depth): the bundled settings' model (fp32) and its int8 quantization
    // (scripts/quantize-yolo.sh), both on ONNX Runtime.
    let bundled = perception::yolo::YoloFile::load(&assets.join("yolo.toml")).unwrap();
    let int8 = assets.join("models/foresight-tiny-320-int8.onnx");
    for (name, model) in [
        ("bundled_model", &bundled.model),
        ("bundled_model_int8", &int8),
    ] {
        pipeline.detector = Detector::Yolo(Box::new(
            YoloDetector::load(
                model,
                bundled.labels.as_deref(),
                perception::yolo::YoloConfig {
                    backend: BackendChoice::Ort,
                    ..bundled.detector.clone()
                },
            )
            .unwrap(),
        ));
        // New objects are published once they persisted a few frames (the tracker).
        let found = (0..5)
            .map(|_| pipeline.process(&frame).unwrap().sent.count)
            .last()
            .unwrap();
        assert_eq!(
            found,
            2,
            "{}: the bundled model should see the goal and the box",
            model.display()
        );
        g.bench_function(format!("{name}_frame_to_published_detection_frame"), |b| {
            b.iter(|| pipeline.process(std::hint::black_box(&frame)).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
