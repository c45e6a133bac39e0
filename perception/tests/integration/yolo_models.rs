//! The YOLOv8 path on ONNX models the tests build themselves (Python tools provisioned
//! idempotently by scripts/perception-pyenv.sh into ${FORESIGHT_CACHE}/venv-perception):
//! - a small graph made with the `onnx` package whose output is known exactly, with the
//!   stock head's strides `Mul`: decoding, thresholding and class-aware NMS are checked
//!   against the expected boxes;
//! - a stock ultralytics YOLOv8n export (random weights, 2 classes, opset 12): it must load
//!   and run through OpenCV 4.6 DNN, and its output must equal PyTorch's for the same input.

use std::path::{Path, PathBuf};
use std::process::Command;

use opencv::core::{Mat, Scalar};
use opencv::prelude::*;
use perception::detection::ObjectKind;
use perception::frame::Frame;
use perception::yolo::{YoloConfig, YoloDetector, YoloLoadError};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn python(ultralytics: bool) -> PathBuf {
    let mut cmd = Command::new("bash");
    cmd.arg(repo().join("scripts/perception-pyenv.sh"));
    if ultralytics {
        cmd.arg("--ultralytics");
    }
    let t = std::time::Instant::now();
    let out = cmd.output().expect("run scripts/perception-pyenv.sh");
    assert!(
        out.status.success(),
        "provisioning failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("python tools ready in {:.1} s", t.elapsed().as_secs_f64());
    let stdout = String::from_utf8_lossy(&out.stdout);
    PathBuf::from(stdout.lines().last().expect("python path").trim())
}

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foresight-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn labels(dir: &Path) -> PathBuf {
    let p = dir.join("labels.txt");
    std::fs::write(&p, "goal\nobstacle\n").unwrap();
    p
}

struct Anchor {
    index: usize,
    box_px: [f32; 4],
    scores: [f32; 2],
}

#[test]
fn toy_model_decodes_to_the_expected_boxes() {
    let dir = tmpdir("yolo-toy");
    let py = python(false);
    let anchors = [
        // goal, kept
        Anchor {
            index: 10,
            box_px: [200.0, 300.0, 80.0, 60.0],
            scores: [0.9, 0.05],
        },
        // goal overlapping the first one: suppressed by NMS
        Anchor {
            index: 11,
            box_px: [205.0, 302.0, 80.0, 60.0],
            scores: [0.8, 0.1],
        },
        // obstacle overlapping the goal: another class, kept
        Anchor {
            index: 250,
            box_px: [210.0, 300.0, 70.0, 70.0],
            scores: [0.1, 0.85],
        },
        // below the confidence threshold: dropped
        Anchor {
            index: 300,
            box_px: [500.0, 450.0, 40.0, 40.0],
            scores: [0.2, 0.15],
        },
        // obstacle elsewhere, kept
        Anchor {
            index: 399,
            box_px: [100.0, 400.0, 50.0, 100.0],
            scores: [0.3, 0.6],
        },
    ];
    let strides: Vec<f32> = (0..400).map(|i| if i < 200 { 8.0 } else { 16.0 }).collect();
    let spec = format!(
        "{{\"imgsz\":640,\"stride\":32,\"num_classes\":2,\"strides\":{:?},\"anchors\":[{}]}}",
        strides,
        anchors
            .iter()
            .map(|a| format!(
                "{{\"index\":{},\"box\":{:?},\"scores\":{:?}}}",
                a.index, a.box_px, a.scores
            ))
            .collect::<Vec<_>>()
            .join(",")
    );
    std::fs::write(dir.join("spec.json"), spec).unwrap();
    let model = dir.join("toy.onnx");
    let st = Command::new(&py)
        .arg(repo().join("tests/python/make_onnx_yolo_toy.py"))
        .arg(dir.join("spec.json"))
        .arg(&model)
        .status()
        .unwrap();
    assert!(st.success());

    // The fact the loader works around: OpenCV 4.6 cannot run the unpatched model.
    let raw = std::fs::read(&model).unwrap();
    let mut net =
        opencv::dnn::read_net_from_onnx_buffer(&opencv::core::Vector::from_slice(&raw)).unwrap();
    let blob = opencv::dnn::blob_from_image(
        &Mat::new_rows_cols_with_default(640, 640, opencv::core::CV_8UC3, Scalar::all(114.0))
            .unwrap(),
        1.0 / 255.0,
        opencv::core::Size::new(640, 640),
        Scalar::default(),
        true,
        false,
        opencv::core::CV_32F,
    )
    .unwrap();
    net.set_input(&blob, "", 1.0, Scalar::default()).unwrap();
    let unpatched = net.forward_single("");
    eprintln!(
        "unpatched model on OpenCV DNN: {}",
        match &unpatched {
            Ok(_) => "ran".to_string(),
            Err(e) => e.message.clone(),
        }
    );

    let mut det = YoloDetector::load(&model, &labels(&dir), YoloConfig::default()).unwrap();
    assert_eq!(det.rewritten_nodes, vec!["/model.22/Mul_2".to_string()]);
    let frame = Frame {
        sequence: 1,
        capture_time_ns: 0,
        bgr: Mat::new_rows_cols_with_default(720, 1280, opencv::core::CV_8UC3, Scalar::all(90.0))
            .unwrap(),
        depth_m: None,
    };
    let mut dets = det.detect(&frame, None).unwrap();
    dets.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
    // 1280x720 → 640: scale 0.5, 140 px of padding above and below.
    let expect = |a: &Anchor| {
        let [cx, cy, w, h] = a.box_px;
        [
            (cx - w / 2.0) / 0.5,
            (cy - h / 2.0 - 140.0) / 0.5,
            w / 0.5,
            h / 0.5,
        ]
    };
    let want = [
        (&anchors[0], ObjectKind::Goal, 0.9),
        (&anchors[2], ObjectKind::Obstacle, 0.85),
        (&anchors[4], ObjectKind::Obstacle, 0.6),
    ];
    assert_eq!(dets.len(), want.len(), "{dets:?}");
    for (d, (a, kind, score)) in dets.iter().zip(want) {
        assert_eq!(d.kind, kind, "{d:?}");
        assert!((d.confidence - score).abs() < 1e-4, "{d:?}");
        let e = expect(a);
        for i in 0..4 {
            assert!((d.bbox_px[i] as f32 - e[i]).abs() <= 1.0, "{d:?} vs {e:?}");
        }
    }

    // A missing model file and a labels file that disagrees with the model are clear errors.
    let missing = YoloDetector::load(&dir.join("nope.onnx"), &labels(&dir), YoloConfig::default())
        .err()
        .unwrap();
    assert!(
        matches!(missing, YoloLoadError::Io { .. }) && missing.to_string().contains("nope.onnx"),
        "{missing}"
    );
    std::fs::write(dir.join("three.txt"), "goal\nobstacle\nhand: ignore\n").unwrap();
    let mismatch = YoloDetector::load(&model, &dir.join("three.txt"), YoloConfig::default())
        .err()
        .unwrap();
    assert!(mismatch.to_string().contains("3 classes"), "{mismatch}");
    std::fs::write(dir.join("bad.onnx"), b"\x0a\xff\xff\xff").unwrap();
    let bad = YoloDetector::load(&dir.join("bad.onnx"), &labels(&dir), YoloConfig::default())
        .err()
        .unwrap();
    assert!(bad.to_string().contains("bad.onnx"), "{bad}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn stock_yolov8n_export_runs_and_matches_pytorch() {
    let dir = tmpdir("yolo-stock");
    let py = python(true);
    // A deterministic pseudo-random input blob.
    let n = 3 * 640 * 640;
    let mut state = 12345u32;
    let input: Vec<f32> = (0..n)
        .map(|_| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        })
        .collect();
    let bytes: Vec<u8> = input.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("input.f32"), bytes).unwrap();
    let model = dir.join("yolov8n.onnx");
    let t = std::time::Instant::now();
    let out = Command::new(&py)
        .env("YOLO_OFFLINE", "1")
        .env("YOLO_CONFIG_DIR", &dir)
        .arg(repo().join("tests/python/make_onnx_yolov8n_stock.py"))
        .arg(&model)
        .arg("640")
        .arg(dir.join("input.f32"))
        .arg(dir.join("torch.f32"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "export failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!(
        "stock export + PyTorch reference in {:.1} s",
        t.elapsed().as_secs_f64()
    );

    let blob = Mat::new_nd_with_data::<f32>(&[1, 3, 640, 640], &input)
        .unwrap()
        .try_clone()
        .unwrap();
    // The known fact: Debian's OpenCV 4.6 cannot run the stock export as it is.
    let raw = std::fs::read(&model).unwrap();
    let unpatched = opencv::dnn::read_net_from_onnx_buffer(&opencv::core::Vector::from_slice(&raw))
        .and_then(|mut net| {
            net.set_input(&blob, "", 1.0, Scalar::default())?;
            net.forward_single("")
        });
    eprintln!(
        "unpatched stock export on OpenCV DNN: {}",
        match &unpatched {
            Ok(_) => "ran".to_string(),
            Err(e) => e.message.clone(),
        }
    );

    let mut det = YoloDetector::load(&model, &labels(&dir), YoloConfig::default()).unwrap();
    assert_eq!(
        det.rewritten_nodes.len(),
        1,
        "the strides Mul should have been rewritten"
    );
    let (c, anchors, got) = det.forward_blob(&blob).unwrap();
    assert_eq!((c, anchors), (6, 8400));
    let want: Vec<f32> = std::fs::read(dir.join("torch.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(want.len(), got.len());
    let max_box = (0..4 * anchors)
        .map(|i| (got[i] - want[i]).abs())
        .fold(0.0f32, f32::max);
    let max_cls = (4 * anchors..got.len())
        .map(|i| (got[i] - want[i]).abs())
        .fold(0.0f32, f32::max);
    eprintln!("OpenCV vs PyTorch: max |Δ| boxes {max_box:.2e} px, scores {max_cls:.2e}");
    assert!(max_box < 0.05, "boxes differ by up to {max_box} px");
    assert!(max_cls < 1e-3, "scores differ by up to {max_cls}");

    // And the full detector runs on a synthetic camera frame.
    let cam = crate::common::camera();
    let scene = crate::common::random_scene(&cam, &mut crate::common::rng(3));
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = crate::common::exact_calibration(&cam, &scene);
    det.detect(&frame, Some(&cal)).unwrap();
    std::fs::remove_dir_all(&dir).ok();
}
