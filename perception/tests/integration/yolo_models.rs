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
use perception::yolo::{BackendChoice, OutputLayout, YoloConfig, YoloDetector, YoloLoadError};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The perception venv's python, provisioned once per test process and always with
/// ultralytics: provisioning installs packages, so it must finish before any test of this
/// process starts a Python that imports them (a test that asked for `onnx` only used to run
/// while another's provisioning was still installing ultralytics' dependencies).
fn python() -> PathBuf {
    static PYTHON: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    PYTHON.get_or_init(provision_python).clone()
}

fn provision_python() -> PathBuf {
    let mut cmd = Command::new("bash");
    cmd.arg(repo().join("scripts/perception-pyenv.sh"))
        .arg("--ultralytics");
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

fn on(backend: BackendChoice) -> YoloConfig {
    YoloConfig {
        backend,
        ..YoloConfig::default()
    }
}

fn opencv() -> YoloConfig {
    on(BackendChoice::OpenCv)
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
    let py = python();
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

    let mut det = YoloDetector::load(&model, Some(&labels(&dir)), opencv()).unwrap();
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
    let missing = YoloDetector::load(&dir.join("nope.onnx"), Some(&labels(&dir)), opencv())
        .err()
        .unwrap();
    assert!(
        matches!(missing, YoloLoadError::Io { .. }) && missing.to_string().contains("nope.onnx"),
        "{missing}"
    );
    std::fs::write(dir.join("three.txt"), "goal\nobstacle\nhand: ignore\n").unwrap();
    let mismatch = YoloDetector::load(&model, Some(&dir.join("three.txt")), opencv())
        .err()
        .unwrap();
    assert!(mismatch.to_string().contains("3 classes"), "{mismatch}");
    std::fs::write(dir.join("bad.onnx"), b"\x0a\xff\xff\xff").unwrap();
    let bad = YoloDetector::load(&dir.join("bad.onnx"), Some(&labels(&dir)), opencv())
        .err()
        .unwrap();
    assert!(bad.to_string().contains("bad.onnx"), "{bad}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn stock_yolov8n_export_runs_and_matches_pytorch() {
    let dir = tmpdir("yolo-stock");
    let py = python();
    let t = std::time::Instant::now();
    let (model, blob, want) = export(&py, &dir, "yolov8n", 640, &[]);
    eprintln!(
        "stock export + PyTorch reference in {:.1} s",
        t.elapsed().as_secs_f64()
    );
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

    let mut det = YoloDetector::load(&model, Some(&labels(&dir)), opencv()).unwrap();
    assert_eq!(
        det.rewritten_nodes.len(),
        1,
        "the strides Mul should have been rewritten"
    );
    let (dims, got) = det.forward_blob(&blob).unwrap();
    assert_eq!(dims, [1, 6, 8400]);
    let anchors = 8400;
    let (max_box, max_cls) = max_diff(&got, &want, 4 * anchors);
    eprintln!("OpenCV vs PyTorch: max |Δ| boxes {max_box:.2e} px, scores {max_cls:.2e}");
    assert!(max_box < 0.05, "boxes differ by up to {max_box} px");
    assert!(max_cls < 1e-3, "scores differ by up to {max_cls}");

    // And the full detector runs on a synthetic camera frame.
    let cam = crate::common::camera();
    let scene = crate::common::random_scene(&cam, &mut crate::common::rng(3));
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = crate::common::exact_calibration(&cam, &scene);
    det.detect(&frame, Some(&cal)).unwrap();

    // ONNX Runtime runs the same stock file unpatched, with its class names from the
    // model's metadata (no labels file), and agrees with PyTorch too.
    let mut ort = YoloDetector::load(&model, None, on(BackendChoice::Ort)).unwrap();
    assert_eq!(ort.backend_name(), "ort");
    assert!(ort.rewritten_nodes.is_empty());
    assert_eq!(ort.input_px(), 640);
    let (dims, got) = ort.forward_blob(&blob).unwrap();
    assert_eq!(dims, [1, 6, 8400]);
    let (max_box, max_cls) = max_diff(&got, &want, 4 * anchors);
    eprintln!("ONNX Runtime vs PyTorch: max |Δ| boxes {max_box:.2e} px, scores {max_cls:.2e}");
    assert!(max_box < 0.05, "boxes differ by up to {max_box} px");
    assert!(max_cls < 1e-3, "scores differ by up to {max_cls}");
    ort.detect(&frame, Some(&cal)).unwrap();
    std::fs::remove_dir_all(&dir).ok();
}

/// Max |Δ| over the first `split` values (boxes) and the rest (scores).
fn max_diff(got: &[f32], want: &[f32], split: usize) -> (f32, f32) {
    assert_eq!(got.len(), want.len());
    let m = |r: std::ops::Range<usize>| r.map(|i| (got[i] - want[i]).abs()).fold(0.0f32, f32::max);
    (m(0..split), m(split..got.len()))
}

/// A deterministic pseudo-random `[1, 3, s, s]` input blob, and its raw bytes.
fn random_blob(s: i32) -> (Mat, Vec<u8>) {
    let n = (3 * s * s) as usize;
    let mut state = 777u32;
    let input: Vec<f32> = (0..n)
        .map(|_| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        })
        .collect();
    let bytes = input.iter().flat_map(|v| v.to_le_bytes()).collect();
    let blob = Mat::new_nd_with_data::<f32>(&[1, 3, s, s], &input)
        .unwrap()
        .try_clone()
        .unwrap();
    (blob, bytes)
}

/// Exports `arch` at `imgsz` (random weights, 2 classes) and PyTorch's output for a random
/// blob; returns (model, blob, PyTorch's output).
fn export(
    py: &Path,
    dir: &Path,
    arch: &str,
    imgsz: i32,
    extra: &[&str],
) -> (PathBuf, Mat, Vec<f32>) {
    let (blob, bytes) = random_blob(imgsz);
    std::fs::write(dir.join("input.f32"), bytes).unwrap();
    let model = dir.join(format!("{arch}-{imgsz}{}.onnx", extra.join("")));
    let out = Command::new(py)
        .env("YOLO_OFFLINE", "1")
        .env("YOLO_CONFIG_DIR", dir)
        .arg(repo().join("tests/python/make_onnx_ultralytics.py"))
        .arg(&model)
        .args(["--arch", arch, "--imgsz", &imgsz.to_string()])
        .args(extra)
        .arg("--input")
        .arg(dir.join("input.f32"))
        .arg("--output")
        .arg(dir.join("torch.f32"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "export of {arch} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let want = std::fs::read(dir.join("torch.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    (model, blob, want)
}

/// Stock YOLO11n (320) and the NMS-free exports (YOLOv10n's end-to-end head, and YOLOv8n
/// exported with `nms=True`) load on ONNX Runtime without patching or labels file: the input
/// size comes from the model, the layout is identified from the output shape, the output
/// equals PyTorch's, and the detector runs on a camera frame.
#[test]
fn yolo11_and_nms_free_exports_load_on_onnx_runtime() {
    let dir = tmpdir("yolo-exports");
    let py = python();
    let cam = crate::common::camera();
    let scene = crate::common::random_scene(&cam, &mut crate::common::rng(5));
    let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
    let cal = crate::common::exact_calibration(&cam, &scene);
    for (arch, extra, layout) in [
        (
            "yolo11n",
            &[][..],
            OutputLayout::Anchors {
                channels: 6,
                anchors: 2100,
            },
        ),
        ("yolov10n", &[][..], OutputLayout::EndToEnd { rows: 300 }),
        (
            "yolov8n",
            &["--nms"][..],
            OutputLayout::EndToEnd { rows: 300 },
        ),
    ] {
        let (model, blob, want) = export(&py, &dir, arch, 320, extra);
        let mut det = YoloDetector::load(&model, None, on(BackendChoice::Ort))
            .unwrap_or_else(|e| panic!("{arch} {extra:?}: {e}"));
        assert_eq!(det.input_px(), 320, "{arch}");
        assert_eq!(det.layout(), layout, "{arch} {extra:?}");
        assert_eq!(det.classes().len(), 2);
        let (dims, got) = det.forward_blob(&blob).unwrap();
        assert_eq!(dims.iter().product::<i64>() as usize, layout.len());
        match layout {
            OutputLayout::Anchors { anchors, .. } => {
                let (b, c) = max_diff(&got, &want, 4 * anchors);
                eprintln!(
                    "{arch}: ONNX Runtime vs PyTorch max |Δ| boxes {b:.2e} px, scores {c:.2e}"
                );
                assert!(b < 0.05 && c < 1e-3, "{arch}: {b} {c}");
            }
            OutputLayout::EndToEnd { .. } => {
                if want.len() != got.len() {
                    // `export(nms=True)` adds the NMS at export; PyTorch's forward has none.
                    eprintln!("{arch} {extra:?}: NMS added at export, no PyTorch reference");
                } else {
                    // Random weights score every anchor almost alike, so the order of rows
                    // (and which anchors make the top 300) differs at ties: compare as sets.
                    let rows = |v: &[f32]| -> Vec<[f32; 6]> {
                        v.chunks_exact(6)
                            .map(|r| [r[0], r[1], r[2], r[3], r[4], r[5]])
                            .collect()
                    };
                    let (g, w) = (rows(&got), rows(&want));
                    let matched = g
                        .iter()
                        .filter(|a| {
                            w.iter().any(|b| {
                                (0..4).all(|k| (a[k] - b[k]).abs() < 0.05)
                                    && (a[4] - b[4]).abs() < 1e-4
                                    && a[5] == b[5]
                            })
                        })
                        .count();
                    // Only a diagnostic: the exact comparison of an end-to-end export is the
                    // trained model's (`trained_model_boxes_match_ultralytics`).
                    eprintln!("{arch}: {matched} of {} rows equal PyTorch's", g.len());
                }
                // Either way: well-formed rows, best first.
                for r in got.chunks_exact(6) {
                    assert!(r.iter().all(|v| v.is_finite()), "{arch}: {r:?}");
                    assert!((0.0..=1.0).contains(&r[4]), "{arch}: score {r:?}");
                    assert!(r[5] == 0.0 || r[5] == 1.0, "{arch}: class {r:?}");
                }
                assert!(
                    got.chunks_exact(6)
                        .zip(got.chunks_exact(6).skip(1))
                        .all(|(a, b)| a[4] >= b[4]),
                    "{arch}: rows not sorted by score"
                );
            }
        }
        det.detect(&frame, Some(&cal)).unwrap();
        // OpenCV 4.6 either runs it with the same layout or refuses it with its reason.
        match YoloDetector::load(&model, None, opencv()) {
            Ok(cv) => assert_eq!(cv.layout(), layout),
            Err(e) => {
                eprintln!("{arch} {extra:?} on OpenCV 4.6: {e}");
                assert!(e.to_string().contains("OpenCV DNN"), "{e}");
            }
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Our letterbox, decode, NMS and mapping back to image pixels against Ultralytics' own
/// prediction (its letterbox, ONNX Runtime run, decode and NMS) of the project's trained
/// models — the stock `[1, 6, N]` export and the end-to-end `[1, N, 6]` one — on synthetic
/// 1280×720 frames: the same objects, classes, scores within 1e-3 and boxes within 1 px.
#[test]
fn trained_model_boxes_match_ultralytics() {
    let dir = tmpdir("yolo-reference");
    let py = python();
    let cam = crate::common::camera();
    let models = crate::common::assets().join("models");
    for name in ["foresight-tiny-320.onnx", "foresight-tiny-320-e2e.onnx"] {
        let model = models.join(name);
        if name.contains("e2e") && !model.is_file() {
            eprintln!("{name}: not bundled, skipped");
            continue;
        }
        let mut det = YoloDetector::load(&model, None, on(BackendChoice::Ort)).unwrap();
        let mut compared = 0;
        for seed in 0..5 {
            let scene = crate::common::random_scene(&cam, &mut crate::common::rng(100 + seed));
            let frame = Frame::from_rendered(&cam.render(&scene), 1, 0).unwrap();
            let image = dir.join(format!("frame{seed}.png"));
            opencv::imgcodecs::imwrite(
                image.to_str().unwrap(),
                &frame.bgr,
                &opencv::core::Vector::new(),
            )
            .unwrap();
            let json = dir.join("reference.json");
            let out = Command::new(&py)
                .env("YOLO_CONFIG_DIR", &dir)
                .arg(repo().join("tests/python/ultralytics_predict.py"))
                .arg(&model)
                .arg(&image)
                .arg(&json)
                .output()
                .unwrap();
            assert!(
                out.status.success(),
                "reference prediction failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            let reference: Vec<serde_json::Value> =
                serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            let mut ours = det.boxes(&frame.bgr).unwrap();
            ours.sort_by(|a, b| b.score.total_cmp(&a.score));
            assert_eq!(
                ours.len(),
                reference.len(),
                "{name}, scene {seed}: ours {ours:?} vs Ultralytics {reference:?}"
            );
            for (o, r) in ours.iter().zip(&reference) {
                assert_eq!(
                    o.class as u64,
                    r["class"].as_u64().unwrap(),
                    "{name}: {o:?} vs {r}"
                );
                assert!(
                    (f64::from(o.score) - r["score"].as_f64().unwrap()).abs() < 1e-3,
                    "{name}: {o:?} vs {r}"
                );
                for k in 0..4 {
                    let want = r["xyxy"][k].as_f64().unwrap();
                    assert!(
                        (f64::from(o.xyxy[k]) - want).abs() <= 1.0,
                        "{name}, scene {seed}: {o:?} vs {r}"
                    );
                }
                compared += 1;
            }
        }
        eprintln!("{name}: {compared} boxes equal Ultralytics' within 1 px");
        assert!(compared >= 10, "{name}: only {compared} boxes compared");
    }
    std::fs::remove_dir_all(&dir).ok();
}
