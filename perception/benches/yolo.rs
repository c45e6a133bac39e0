//! YOLOv8n 640×640 through OpenCV DNN (CPU, OpenCV's default threads — this machine has
//! two cores): letterbox, inference, decoding and NMS of a 1280×720 frame. The model is a
//! stock ultralytics export with random weights made by tests/python/make_onnx_yolov8n_stock.py
//! (set FORESIGHT_YOLO_MODEL to use another one; the bench provisions the Python tools with
//! scripts/perception-pyenv.sh --ultralytics when it has to build the model).
//!
//! `scripts/cargo.sh bench -p perception --bench yolo`

use std::path::{Path, PathBuf};
use std::process::Command;

use criterion::{Criterion, criterion_group, criterion_main};
use perception::frame::Frame;
use perception::synthetic::SyntheticCamera;
use perception::yolo::{YoloConfig, YoloDetector};
use shm_schemas::scene_file::SceneFile;

fn model() -> PathBuf {
    if let Ok(p) = std::env::var("FORESIGHT_YOLO_MODEL") {
        return p.into();
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let cache = std::env::var("FORESIGHT_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|_| std::env::temp_dir());
    let out = cache.join("yolov8n-random-2cls.onnx");
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
            .arg(repo.join("tests/python/make_onnx_yolov8n_stock.py"))
            .arg(&out)
            .status()
            .unwrap();
        assert!(st.success());
    }
    out
}

fn bench(c: &mut Criterion) {
    let model = model();
    let dir = std::env::temp_dir().join(format!("foresight-yolo-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("labels.txt"), "goal\nobstacle\n").unwrap();
    let mut det =
        YoloDetector::load(&model, &dir.join("labels.txt"), YoloConfig::default()).unwrap();
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception");
    let cam = SyntheticCamera::load(&assets.join("synthetic_camera.toml")).unwrap();
    let scene = SceneFile::from_toml_str(
        "[goal]\ncenter_m = [0.4, 0.2, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, 0.0, 0.05]\nsize_m = [0.06, 0.06, 0.1]\n",
        Path::new("<bench>"),
    )
    .unwrap();
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let mut g = c.benchmark_group("yolov8n_640");
    g.sample_size(20);
    g.bench_function(
        format!(
            "opencv_dnn_{}_threads",
            opencv::core::get_num_threads().unwrap()
        ),
        |b| b.iter(|| det.detect(std::hint::black_box(&frame), None).unwrap()),
    );
    opencv::core::set_num_threads(1).unwrap();
    g.bench_function("opencv_dnn_1_thread", |b| {
        b.iter(|| det.detect(std::hint::black_box(&frame), None).unwrap())
    });
    g.finish();
    std::fs::remove_dir_all(&dir).ok();
}

criterion_group!(benches, bench);
criterion_main!(benches);
