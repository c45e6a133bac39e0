//! Every run is recorded (issue 27): the `foresight` launcher with the real processes on the
//! simulated arm leaves `<run>/run.mcap`, and an independent reader — the `mcap` Python
//! package with `mcap-ros2-support`, in the project's venv (`scripts/setup.sh`) — reads it
//! back: topics, message counts, schemas, CDR bytes that decode against their schemas, and
//! log time never going back (`tests/scripts/check_mcap.py`). A launcher killed with
//! SIGKILL leaves a file readable up to its last chunk.
//!
//! The run folder is a rosbag2 bag (issue 32): a second independent reader, `rosbags`' rosbag2
//! `Reader`, opens the folder through its `metadata.yaml` and finds every topic with the
//! count the MCAP reader counted, `/robot_description` offered transient local and the
//! streaming topics volatile, in `metadata.yaml` and in the MCAP channels alike
//! (`tests/scripts/check_bag.py`). A killed launcher leaves the `metadata.yaml` written at the
//! start: the topics and their QoS, state `recording`.
//!
//! The recorded run is one scene (`assets/scenes/small_box.toml`): the shortest whole run;
//! the killed one is `assets/scenes/fast_world.toml` (long enough to kill mid-run). Needs
//! the workspace's binaries built and `make setup` done.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use foresight_tests::runs::{LogsOnFailure, newest_run, scratch_dir};
use foresight_tests::{ChildGuard, bin_path, repo_root};

/// One whole system at a time (two cores).
static ONE_SYSTEM_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_SYSTEM_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The project's Python: `$FORESIGHT_VENV/bin/python`, the venv `scripts/setup.sh` made
/// (named in `build/env.mk`).
fn venv_python() -> PathBuf {
    let venv = std::env::var_os("FORESIGHT_VENV")
        .map(PathBuf::from)
        .or_else(|| {
            let env_mk = std::fs::read_to_string(repo_root().join("build/env.mk")).ok()?;
            env_mk.lines().find_map(|l| {
                l.strip_prefix("FORESIGHT_VENV := ")
                    .map(|v| PathBuf::from(v.trim()))
            })
        })
        .expect("FORESIGHT_VENV unset and no build/env.mk: run `make setup`");
    let py = venv.join("bin/python");
    assert!(py.is_file(), "{} missing: run `make setup`", py.display());
    py
}

/// A world script of the one small-box scene, in `dir`.
fn one_scene_world(dir: &Path) -> PathBuf {
    let world = dir.join("one_scene.toml");
    let scene = repo_root().join("assets/scenes/small_box.toml");
    std::fs::write(
        &world,
        format!(
            "[[step]]\nat_s = 0.0\nscene = {:?}\n",
            scene.display().to_string()
        ),
    )
    .expect("world script");
    world
}

/// `foresight` on `world` from the repository root, run folders under `out`.
fn launch(out: &Path, world: &Path) -> ChildGuard {
    let mut cmd = Command::new(bin_path("foresight"));
    cmd.current_dir(repo_root())
        .arg("--world")
        .arg(world)
        .args(["--phase-timeout-s", "60"])
        .arg("--out")
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::inherit());
    ChildGuard::spawn("foresight", &mut cmd)
}

/// Runs the independent reader on `mcap`; returns its exit code and its JSON report.
fn check(mcap: &Path, extra: &[&str]) -> (i32, serde_json::Value) {
    let script = repo_root().join("tests/scripts/check_mcap.py");
    let out = Command::new(venv_python())
        .arg(&script)
        .arg(mcap)
        .args(extra)
        .output()
        .expect("running check_mcap.py");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}");
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    let report = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("check_mcap.py printed no JSON ({e}): {stdout}"));
    (out.status.code().unwrap_or(-1), report)
}

/// Runs `rosbags` on the run folder `run` as a rosbag2 bag; returns its exit code and its
/// JSON report.
fn check_bag(run: &Path, extra: &[&str]) -> (i32, serde_json::Value) {
    let script = repo_root().join("tests/scripts/check_bag.py");
    let out = Command::new(venv_python())
        .arg(&script)
        .arg(run)
        .args(extra)
        .output()
        .expect("running check_bag.py");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}");
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    let report = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("check_bag.py printed no JSON ({e}): {stdout}"));
    (out.status.code().unwrap_or(-1), report)
}

/// The QoS arguments of `check_bag.py`: the URDF latched, the streams volatile.
const BAG_QOS: [&str; 6] = [
    "--transient-local",
    "/robot_description",
    "--volatile",
    "/joint_states",
    "--volatile",
    "/tf",
];

fn count(report: &serde_json::Value, topic: &str) -> u64 {
    report["topics"][topic]["count"].as_u64().unwrap_or(0)
}

#[test]
fn a_run_leaves_an_mcap_file_that_an_independent_reader_validates() {
    let _one = one_at_a_time();
    let out = scratch_dir("mcap", "run");
    let _logs = LogsOnFailure {
        runs: out.to_path_buf(),
        extra: Vec::new(),
    };
    let mut guard = launch(&out, &one_scene_world(&out));
    let code = guard.wait_exit(Duration::from_secs(240));
    let run = newest_run(&out).expect("a run folder");
    assert_eq!(code, 0, "foresight exit code");
    let mcap = run.join("run.mcap");
    let topics = [
        "/joint_states",
        "/joint_commands",
        "/tf",
        "/robot_description",
        "/foresight/scene_markers",
        "/foresight/detections",
        "/foresight/verdicts",
        "/foresight/robot_status",
        "/foresight/referee",
    ];
    let mut args = Vec::new();
    for t in topics {
        args.extend(["--topic", t]);
    }
    let (code, report) = check(&mcap, &args);
    assert_eq!(code, 0, "the reader found problems: {}", report["errors"]);
    assert_eq!(report["footer"], true, "closed with summary and footer");
    assert_eq!(count(&report, "/robot_description"), 1, "the URDF once");
    // The arm moved: far more joint states than verdicts, and as many commands.
    assert!(count(&report, "/joint_states") > 100, "{report}");
    assert_eq!(
        count(&report, "/joint_states"),
        count(&report, "/joint_commands")
    );
    assert_eq!(
        report["topics"]["/joint_states"]["schema"],
        "sensor_msgs/msg/JointState"
    );
    assert_eq!(
        report["topics"]["/foresight/scene_markers"]["schema"],
        "visualization_msgs/msg/MarkerArray"
    );
    let md = std::fs::read_to_string(run.join("report.md")).expect("report.md");
    assert!(md.contains("run.mcap"), "the report links the recording");

    // The folder is a rosbag2 bag that rosbags opens, with the MCAP reader's counts.
    let (code, bag) = check_bag(&run, &BAG_QOS);
    assert_eq!(code, 0, "rosbags found problems: {}", bag["errors"]);
    assert_eq!(bag["version"], 9, "rosbag2 metadata version");
    assert_eq!(bag["storage"], "mcap");
    assert_eq!(bag["files"], serde_json::json!(["run.mcap"]));
    assert_eq!(bag["state"], "finished");
    let bag_topics = bag["topics"].as_object().expect("topics");
    for t in topics {
        assert!(
            bag_topics.contains_key(t),
            "{t} not in metadata.yaml: {bag}"
        );
    }
    for (name, t) in bag_topics {
        let mcap_count = count(&report, name);
        assert_eq!(
            t["count"], mcap_count,
            "{name}: metadata.yaml vs the MCAP reader"
        );
        assert_eq!(
            t["read"], mcap_count,
            "{name}: rosbags read vs the MCAP reader"
        );
    }
    assert_eq!(bag["message_count"], report["messages"]);
    let urdf = &bag["topics"]["/robot_description"];
    assert_eq!(urdf["durability"], "transient_local", "{urdf}");
    assert_eq!(urdf["channel"]["durability"], "transient_local", "{urdf}");
    assert_eq!(urdf["depth"], 1, "{urdf}");
    assert_eq!(
        bag["topics"]["/joint_states"]["durability"], "volatile",
        "{bag}"
    );
}

#[test]
fn a_killed_launcher_leaves_a_recording_readable_up_to_its_last_chunk() {
    let _one = one_at_a_time();
    let out = scratch_dir("mcap", "killed");
    let _logs = LogsOnFailure {
        runs: out.to_path_buf(),
        extra: Vec::new(),
    };
    // The two-scene world (retraining in the middle): long enough to be killed mid-run.
    let mut guard = launch(&out, &repo_root().join("assets/scenes/fast_world.toml"));
    // Wait until the recording holds a few seconds of the arm (chunks reach the disk at
    // least once a second), then kill the launcher without a chance to close the file.
    let deadline = Instant::now() + Duration::from_secs(120);
    let mcap = loop {
        let file = newest_run(&out).map(|r| r.join("run.mcap"));
        if let Some(f) = file.filter(|f| std::fs::metadata(f).is_ok_and(|m| m.len() > 150_000)) {
            break f;
        }
        assert!(Instant::now() < deadline, "no recording grew past 150 kB");
        assert!(
            guard.child.try_wait().ok().flatten().is_none(),
            "foresight ended before the recording grew"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    guard.child.kill().expect("SIGKILL foresight");
    let _ = guard.child.wait();
    let (code, report) = check(
        &mcap,
        &[
            "--allow-truncated",
            "--topic",
            "/joint_states",
            "--topic",
            "/tf",
        ],
    );
    assert_eq!(code, 0, "the reader found problems: {}", report["errors"]);
    assert_eq!(
        report["footer"], false,
        "a killed recorder writes no footer"
    );
    assert!(count(&report, "/joint_states") > 50, "{report}");
    assert_eq!(count(&report, "/robot_description"), 1, "{report}");

    // The metadata.yaml of the start is there: the topics and their QoS, still recording.
    let run = mcap.parent().expect("run folder");
    let mut args = vec!["--metadata-only"];
    args.extend(BAG_QOS);
    let (code, bag) = check_bag(run, &args);
    assert_eq!(code, 0, "metadata.yaml problems: {}", bag["errors"]);
    assert_eq!(bag["state"], "recording", "{bag}");
    assert_eq!(bag["topics"]["/robot_description"]["count"], 1, "{bag}");
    assert!(
        bag["topics"]["/foresight/scene_markers"].is_object(),
        "{bag}"
    );
}
