//! Interop proof: the unmodified official xArm Python SDK (`xarm-python-sdk` 1.18.4 from
//! PyPI) drives `xarm-sim`. The SDK's ports are hard-coded (502, 30002), so the simulator and
//! the script run inside a private network namespace (`unshare -n`, `lo` up) where those
//! ports are free and nothing leaves the machine.
//!
//! The virtual environment lives under `$FORESIGHT_CACHE` (default `~/.cache/foresight`)
//! and is created once, from PyPI, before entering the namespace.
//!
//! Needs: `python3` with `venv`, `unshare` and `ip`, and `xarm-sim` built
//! (`scripts/cargo.sh build --release -p rt-core --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use foresight_tests::{ChildGuard, NetnsOutcome, bin_path, repo_root, run_in_private_netns};

const SDK_VERSION: &str = "1.18.4";

fn cache_dir() -> PathBuf {
    std::env::var_os("FORESIGHT_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(std::env::var_os("HOME").expect("HOME is set")).join(".cache/foresight")
        })
}

/// Creates (once) a venv with the SDK and returns its python. Idempotent: a marker file is
/// written only after a successful install and import.
fn sdk_python() -> PathBuf {
    let venv = cache_dir().join(format!("venv-xarm-sdk-{SDK_VERSION}"));
    let py = venv.join("bin/python");
    let marker = venv.join(".foresight-ready");
    if marker.is_file() && py.is_file() {
        return py;
    }
    std::fs::create_dir_all(cache_dir()).expect("cache dir");
    let ok = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&venv)
        .status()
        .expect("python3 -m venv");
    assert!(ok.success(), "python3 -m venv failed");
    let ok = Command::new(&py)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            &format!("xarm-python-sdk=={SDK_VERSION}"),
        ])
        .status()
        .expect("pip install");
    assert!(ok.success(), "pip install xarm-python-sdk failed");
    let ok = Command::new(&py)
        .args(["-c", "import xarm.wrapper"])
        .status()
        .expect("python import");
    assert!(ok.success(), "the SDK does not import");
    std::fs::write(&marker, SDK_VERSION).expect("marker");
    py
}

#[test]
fn official_sdk_drives_xarm_sim() {
    // Provision outside the namespace (PyPI is reachable there); the re-run inside finds it.
    let py = sdk_python();
    if run_in_private_netns("official_sdk_drives_xarm_sim") == NetnsOutcome::RanInChild {
        return;
    }
    let root = repo_root();
    let mut sim = ChildGuard::spawn(
        "xarm-sim",
        Command::new(bin_path("xarm-sim"))
            .args(["--bind", "127.0.0.1", "--urdf"])
            .arg(root.join("assets/xarm5.urdf"))
            .arg("--scene")
            .arg(root.join("assets/scenes/small_box.toml"))
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit()),
    );
    let mut out = BufReader::new(sim.child.stdout.take().expect("sim stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("listening line");
    assert!(
        line.contains("\"listening\""),
        "xarm-sim did not start: {line}"
    );

    let script = root.join("tests/python/xarm_sdk_check.py");
    let run = Command::new(&py)
        .arg(&script)
        .arg("127.0.0.1")
        .output()
        .expect("run the SDK script");
    let stdout = String::from_utf8_lossy(&run.stdout);
    print!("{stdout}");
    eprint!("{}", String::from_utf8_lossy(&run.stderr));
    assert!(run.status.success(), "SDK script failed: {stdout}");
    let result = stdout
        .lines()
        .find_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .expect("a JSON result line");
    assert_eq!(result["ok"], true);

    let status = sim.interrupt_and_wait(Duration::from_secs(5));
    assert!(
        status.is_some_and(|s| s.success()),
        "xarm-sim exits cleanly on SIGINT"
    );
    let mut summary = String::new();
    out.read_line(&mut summary).expect("summary line");
    let summary: serde_json::Value = serde_json::from_str(&summary).expect("summary JSON");
    println!("xarm-sim summary: {summary}");
    assert_eq!(summary["event"], "summary");
    assert_eq!(
        summary["counters"]["servo_accepted"], 150,
        "every SDK target executed"
    );
    assert_eq!(summary["counters"]["servo_rejected"], 0);
    assert_eq!(summary["counters"]["bad_frames"], 0);
    assert_eq!(summary["collisions"], 0);
}
