//! The ONNX Runtime path of the real `perception` binary (issue 17), with the project's own
//! trained detector (assets/perception/models/foresight-tiny-320.onnx) on a synthetic frame:
//! - `detect --backend ort --repeat N` finds the goal and the box and prints the per-frame
//!   timing (median, p95) of the ONNX Runtime engine at the model's own input size;
//! - a missing library, a library that is not ONNX Runtime, and an ONNX Runtime older than
//!   this build supports (1.20.1, from PyPI) are refused with a message naming the library
//!   and the reason — never a panic; `--backend auto` falls back to OpenCV with a warning;
//! - bad settings are refused naming the field.
//!
//! Each case runs in its own process: a process loads one ONNX Runtime library for good.
//! Needs `cargo build --release -p perception` (the binary) first.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use foresight_tests::{asset, bin_path, repo_root};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foresight-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Renders a small scene (goal + one box) with depth and its exact calibration.
fn rendered(dir: &Path) -> PathBuf {
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "name = \"ort\"\n[goal]\ncenter_m = [0.45, 0.15, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, -0.1, 0.06]\nsize_m = [0.06, 0.05, 0.12]\n",
    )
    .unwrap();
    let out = dir.join("frame");
    let st = Command::new(bin_path("perception"))
        .args(["render", "--scene"])
        .arg(&scene)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    out
}

fn detect(frame: &Path, extra: &[&str]) -> (bool, String, String) {
    let out = Command::new(bin_path("perception"))
        .arg("detect")
        .arg("--image")
        .arg(frame.join("colour.png"))
        .arg("--depth")
        .arg(frame.join("colour.depth.tiff"))
        .arg("--calibration")
        .arg(frame.join("calibration.toml"))
        .arg("--annotated")
        .arg(frame.join("annotated.png"))
        .arg("--model")
        .arg(asset("perception/models/foresight-tiny-320.onnx"))
        .args(extra)
        .env_remove("ORT_DYLIB_PATH")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// libonnxruntime.so of an ONNX Runtime release older than ort 2.0.0-rc.15 supports
/// (1.20.1), taken from its PyPI wheel once into the cache.
fn old_onnxruntime() -> PathBuf {
    let cache = std::env::var_os("FORESIGHT_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("foresight-cache"));
    let dir = cache.join("onnxruntime-1.20.1");
    let lib = dir.join("onnxruntime/capi/libonnxruntime.so.1.20.1");
    if !lib.is_file() {
        std::fs::create_dir_all(&dir).unwrap();
        let st = Command::new("python3")
            .args([
                "-m",
                "pip",
                "download",
                "-q",
                "--no-deps",
                "--only-binary=:all:",
                "--python-version",
                "3.11",
                "--platform",
                "manylinux_2_28_x86_64",
                "--platform",
                "manylinux_2_27_x86_64",
                "onnxruntime==1.20.1",
                "-d",
            ])
            .arg(&dir)
            .status()
            .unwrap();
        assert!(st.success(), "pip download onnxruntime==1.20.1 failed");
        let wheel = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| p.extension().is_some_and(|e| e == "whl"))
            .expect("the wheel");
        let st = Command::new("python3")
            .args(["-m", "zipfile", "-e"])
            .arg(&wheel)
            .arg(&dir)
            .status()
            .unwrap();
        assert!(st.success());
    }
    lib
}

#[test]
fn onnx_runtime_detects_with_timing_and_bad_libraries_are_clear_errors() {
    let dir = tmpdir("perception-ort");
    let frame = rendered(&dir);

    // The trained model on ONNX Runtime: both objects, and the timing of N runs.
    let (ok, stdout, stderr) = detect(&frame, &["--backend", "ort", "--repeat", "5"]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    let objects = v["objects"].as_array().unwrap();
    let classes: Vec<&str> = objects
        .iter()
        .map(|o| o["class"].as_str().unwrap())
        .collect();
    assert_eq!(
        classes.iter().filter(|c| **c == "goal").count(),
        1,
        "{stdout}"
    );
    assert_eq!(
        classes.iter().filter(|c| **c == "obstacle").count(),
        1,
        "{stdout}"
    );
    let goal = objects.iter().find(|o| o["class"] == "goal").unwrap();
    let p = &goal["position_m"];
    let err =
        ((p[0].as_f64().unwrap() - 0.45).powi(2) + (p[1].as_f64().unwrap() - 0.15).powi(2)).sqrt();
    assert!(err < 0.01, "goal at {p}: {err} m off");
    let t = &v["timing"];
    assert_eq!(t["backend"], "ort", "{stdout}");
    assert_eq!(t["input_px"], 320);
    assert_eq!(t["runs"], 5);
    let (median, p95) = (
        t["median_ms"].as_f64().unwrap(),
        t["p95_ms"].as_f64().unwrap(),
    );
    assert!(median > 0.0 && p95 >= median, "{t}");
    eprintln!("ONNX Runtime, 320 px: median {median:.1} ms, p95 {p95:.1} ms (5 runs)");

    // No such library: named, with the OS reason.
    let (ok, _, stderr) = detect(
        &frame,
        &[
            "--backend",
            "ort",
            "--ort-library",
            "/nonexistent/libonnxruntime.so",
        ],
    );
    assert!(!ok);
    assert!(
        stderr.contains("ONNX Runtime library /nonexistent/libonnxruntime.so")
            && stderr.contains("cannot open"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");

    // A shared library that is not ONNX Runtime.
    let libm = [
        "/lib/x86_64-linux-gnu/libm.so.6",
        "/usr/lib/x86_64-linux-gnu/libm.so.6",
    ]
    .into_iter()
    .find(|p| Path::new(p).is_file())
    .expect("libm");
    let (ok, _, stderr) = detect(&frame, &["--backend", "ort", "--ort-library", libm]);
    assert!(!ok);
    assert!(stderr.contains("OrtGetApiBase"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    // ONNX Runtime 1.20.1: too old for this build (it needs >= 1.22).
    let old = old_onnxruntime();
    let (ok, _, stderr) = detect(
        &frame,
        &["--backend", "ort", "--ort-library", old.to_str().unwrap()],
    );
    assert!(!ok);
    assert!(
        stderr.contains("1.20.1") && stderr.contains("expected version >= '1.22"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");

    // auto: the library cannot be loaded → OpenCV DNN, with a warning saying why.
    let (ok, stdout, stderr) = detect(
        &frame,
        &[
            "--backend",
            "auto",
            "--ort-library",
            old.to_str().unwrap(),
            "--repeat",
            "2",
        ],
    );
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("running the model on OpenCV DNN"),
        "{stderr}"
    );
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["timing"]["backend"], "opencv");
    assert_eq!(v["objects"].as_array().unwrap().len(), 2, "{stdout}");

    // Bad settings name the field.
    let cfg = dir.join("yolo.toml");
    std::fs::write(
        &cfg,
        "model = \"m.onnx\"\n[detector]\nconfidence_threshold = 1.5\n",
    )
    .unwrap();
    let (ok, _, stderr) = detect(&frame, &["--yolo-config", cfg.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("confidence_threshold"), "{stderr}");
    std::fs::write(&cfg, "model = \"m.onnx\"\n[detector]\nbackend = \"cuda\"\n").unwrap();
    let (ok, _, stderr) = detect(&frame, &["--yolo-config", cfg.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("backend"), "{stderr}");
    let (ok, _, stderr) = detect(&frame, &["--repeat", "0"]);
    assert!(!ok && stderr.contains("--repeat"), "{stderr}");

    // The bundled settings file loads and runs (the demo's `--detector yolo`).
    let (ok, stdout, stderr) = detect(
        &frame,
        &[
            "--yolo-config",
            repo_root()
                .join("assets/perception/yolo.toml")
                .to_str()
                .unwrap(),
        ],
    );
    assert!(ok, "{stderr}");
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(stdout.trim()).unwrap()["objects"]
            .as_array()
            .unwrap()
            .len(),
        2
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A settings file naming the int8 model (issue 32 item 5) with `opencv_model`: ONNX Runtime
/// runs the int8 model, OpenCV DNN (`--backend opencv`, and `auto` without an ONNX Runtime
/// library) the fp32 export — each finding the goal and the box; without `opencv_model`,
/// OpenCV refuses the int8 model with its reason.
#[test]
fn int8_settings_run_the_fp32_export_on_opencv() {
    let dir = tmpdir("perception-int8");
    let frame = rendered(&dir);
    let int8 = asset("perception/models/foresight-tiny-320-int8.onnx");
    let fp32 = asset("perception/models/foresight-tiny-320.onnx");
    let cfg = dir.join("yolo.toml");
    let run = |extra: &[&str]| {
        let out = Command::new(bin_path("perception"))
            .arg("detect")
            .arg("--image")
            .arg(frame.join("colour.png"))
            .arg("--depth")
            .arg(frame.join("colour.depth.tiff"))
            .arg("--calibration")
            .arg(frame.join("calibration.toml"))
            .arg("--yolo-config")
            .arg(&cfg)
            .args(extra)
            .env_remove("ORT_DYLIB_PATH")
            .env("NO_COLOR", "1")
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let objects = |stdout: &str| {
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        let mut classes: Vec<String> = v["objects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["class"].as_str().unwrap().to_string())
            .collect();
        classes.sort();
        classes
    };
    std::fs::write(
        &cfg,
        format!("model = {int8:?}\nopencv_model = {fp32:?}\n[detector]\nbackend = \"auto\"\n"),
    )
    .unwrap();
    for (extra, engine, model) in [
        (&["--backend", "ort"][..], "ort", &int8),
        (&["--backend", "opencv"][..], "opencv", &fp32),
        (
            &["--ort-library", "/nonexistent/libonnxruntime.so"][..],
            "opencv",
            &fp32,
        ),
    ] {
        let (ok, stdout, stderr) = run(extra);
        assert!(ok, "{extra:?}: {stderr}");
        assert_eq!(
            objects(&stdout),
            ["goal", "obstacle"],
            "{extra:?}: {stdout}"
        );
        let line = format!("YOLO model {} on {engine}", model.display());
        assert!(stderr.contains(&line), "{extra:?}: no '{line}' in {stderr}");
    }
    std::fs::write(&cfg, format!("model = {int8:?}\n")).unwrap();
    let (ok, _, stderr) = run(&["--backend", "opencv"]);
    assert!(!ok);
    assert!(stderr.contains("OpenCV DNN cannot run model"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}
