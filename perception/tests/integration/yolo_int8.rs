//! The int8 (QDQ) quantization of the project's model (issue 32 item 5;
//! assets/perception/models/foresight-tiny-320-int8.onnx, made by scripts/quantize-yolo.sh
//! from the fp32 export the bundled settings run): it loads on ONNX Runtime with its classes
//! from the metadata and finds the goal and the obstacles of a synthetic frame where they are,
//! with the boxes of the fp32 model; OpenCV DNN, which cannot run QDQ models, gets the fp32
//! export a settings file names in `opencv_model` (explicitly and as `auto`'s fallback). No
//! Python needed.

use perception::detection::ObjectKind;
use perception::frame::Frame;
use perception::yolo::{BackendChoice, YoloConfig, YoloDetector, YoloFile, YoloLoadError};
use shm_schemas::scene_file::SceneFile;

/// Settings naming the int8 model, and the fp32 export for OpenCV DNN (as the bundled
/// yolo.toml's comment shows), with the bundled `[detector]` settings.
fn int8_settings() -> YoloFile {
    let models = crate::common::assets().join("models");
    let bundled = YoloFile::load(&crate::common::assets().join("yolo.toml")).unwrap();
    assert_eq!(
        bundled.model,
        models.join("foresight-tiny-320.onnx"),
        "the bundled settings run the fp32 export"
    );
    let dir = std::env::temp_dir().join(format!("foresight-yolo-int8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("yolo.toml");
    std::fs::write(
        &path,
        format!(
            "model = {:?}\nopencv_model = {:?}\n[detector]\nconfidence_threshold = {}\nnms_iou = {}\n",
            models.join("foresight-tiny-320-int8.onnx"),
            models.join("foresight-tiny-320.onnx"),
            bundled.detector.confidence_threshold,
            bundled.detector.nms_iou,
        ),
    )
    .unwrap();
    let file = YoloFile::load(&path).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(file.detector, bundled.detector);
    file
}

fn with(file: &YoloFile, backend: BackendChoice) -> YoloConfig {
    YoloConfig {
        backend,
        ..file.detector.clone()
    }
}

/// A goal and two boxes apart from each other.
fn scene() -> SceneFile {
    SceneFile::from_toml_str(
        "[goal]\ncenter_m = [0.45, 0.18, 0.025]\nsize_m = 0.05\n\
         [[obstacle]]\ncenter_m = [0.35, 0.0, 0.06]\nsize_m = [0.06, 0.06, 0.12]\n\
         [[obstacle]]\ncenter_m = [0.50, -0.20, 0.04]\nsize_m = [0.08, 0.05, 0.08]\n",
        std::path::Path::new("<int8 test>"),
    )
    .unwrap()
}

#[test]
fn quantized_model_finds_the_goal_and_the_obstacles() {
    let file = int8_settings();
    let mut det = YoloDetector::load(
        &file.model,
        file.labels.as_deref(),
        with(&file, BackendChoice::Ort),
    )
    .unwrap();
    assert_eq!(det.backend_name(), "ort");
    assert_eq!(det.input_px(), 320);
    let cam = crate::common::camera();
    let scene = scene();
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = crate::common::exact_calibration(&cam, &scene);
    let dets = det.detect(&frame, Some(&cal)).unwrap();
    eprintln!(
        "int8: {:?}",
        dets.iter()
            .map(|d| (d.kind, d.confidence, d.position_m))
            .collect::<Vec<_>>()
    );
    let truth = std::iter::once((ObjectKind::Goal, scene.goal.center_m)).chain(
        scene
            .obstacles
            .iter()
            .map(|b| (ObjectKind::Obstacle, b.center_m)),
    );
    for (kind, c) in truth {
        let found = dets.iter().find(|d| {
            d.kind == kind
                && d.confidence >= 0.5
                && (0..3)
                    .map(|k| (d.position_m[k] - c[k]).powi(2))
                    .sum::<f64>()
                    .sqrt()
                    <= 0.01
        });
        assert!(
            found.is_some(),
            "{kind:?} at {c:?} not found within 1 cm with confidence >= 0.5: {dets:?}"
        );
    }
    assert_eq!(dets.len(), 3, "one goal and two obstacles: {dets:?}");

    // The same objects as the fp32 export it was quantized from, boxes within 2 px.
    let fp32 = file.opencv_model.clone().unwrap();
    let mut reference = YoloDetector::load(
        &fp32,
        file.labels.as_deref(),
        with(&file, BackendChoice::Ort),
    )
    .unwrap();
    let mut ours = det.boxes(&frame.bgr).unwrap();
    let mut want = reference.boxes(&frame.bgr).unwrap();
    for v in [&mut ours, &mut want] {
        v.sort_by(|a, b| a.xyxy[0].total_cmp(&b.xyxy[0]));
    }
    assert_eq!(ours.len(), want.len(), "int8 {ours:?} vs fp32 {want:?}");
    for (o, w) in ours.iter().zip(&want) {
        assert_eq!(o.class, w.class, "int8 {o:?} vs fp32 {w:?}");
        assert!((o.score - w.score).abs() < 0.1, "int8 {o:?} vs fp32 {w:?}");
        for k in 0..4 {
            assert!(
                (o.xyxy[k] - w.xyxy[k]).abs() <= 2.0,
                "int8 {o:?} vs fp32 {w:?}"
            );
        }
    }
}

#[test]
fn opencv_runs_the_fp32_model_named_by_opencv_model() {
    let file = int8_settings();
    let fp32 = file.opencv_model.clone().unwrap();
    // OpenCV 4.6 cannot run the QDQ model: refused with its reason, never a panic.
    match YoloDetector::load(&file.model, None, with(&file, BackendChoice::OpenCv)) {
        Err(e @ YoloLoadError::Unrunnable { .. }) => {
            assert!(e.to_string().contains("OpenCV DNN"), "{e}");
        }
        Err(e) => panic!("unexpected error: {e}"),
        Ok(_) => panic!("OpenCV 4.6 ran the int8 model: opencv_model is no longer needed"),
    }
    // With the settings' `opencv_model`: OpenCV runs the fp32 export, explicitly...
    let cam = crate::common::camera();
    let scene = scene();
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = crate::common::exact_calibration(&cam, &scene);
    let opencv = YoloDetector::load_with_opencv_model(
        &file.model,
        Some(&fp32),
        file.labels.as_deref(),
        with(&file, BackendChoice::OpenCv),
    )
    .unwrap();
    // ... and when `auto` finds no ONNX Runtime library.
    let fallback = YoloDetector::load_with_opencv_model(
        &file.model,
        Some(&fp32),
        file.labels.as_deref(),
        YoloConfig {
            ort_library: Some("/nonexistent/libonnxruntime.so".into()),
            ..with(&file, BackendChoice::Auto)
        },
    )
    .unwrap();
    assert!(fallback.fallback_reason.is_some());
    for mut det in [opencv, fallback] {
        assert_eq!(det.backend_name(), "opencv");
        assert_eq!(det.model_path(), fp32.as_path());
        let dets = det.detect(&frame, Some(&cal)).unwrap();
        assert_eq!(
            dets.iter().filter(|d| d.kind == ObjectKind::Goal).count(),
            1,
            "{dets:?}"
        );
        assert_eq!(
            dets.iter()
                .filter(|d| d.kind == ObjectKind::Obstacle)
                .count(),
            2,
            "{dets:?}"
        );
    }
    // On ONNX Runtime the int8 model runs, whatever `opencv_model` says.
    let ort = YoloDetector::load_with_opencv_model(
        &file.model,
        Some(&fp32),
        file.labels.as_deref(),
        with(&file, BackendChoice::Ort),
    )
    .unwrap();
    assert_eq!(ort.model_path(), file.model.as_path());
}
