//! What the real `perception` process puts in its `DetectionFrame`s (issue 14, perception
//! side): a table with more objects than a frame holds is published with the goal and the
//! obstacles nearest the robot base, `dropped_count` saying how many were left out (and
//! counted in the printed stats); a goal seen with less confidence than the floor is
//! reported as an obstacle; bad floors are refused at start naming the field; the ROS 2
//! source is loopback-only unless `--ros2-open-network` is given, and `--help` says so.
//!
//! Needs `cargo build --release -p perception` (the binary) first.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use foresight_tests::{ChildGuard, bin_path, unique_prefix, wait_for};
use iceoryx2::prelude::*;
use shm_schemas::{DetectionFrame, MAX_DETECTIONS, ObjectClass, services};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foresight-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The goal and a 4 × 4 grid of low boxes: 17 objects, one more than a frame holds.
fn crowded_scene() -> String {
    let mut s =
        String::from("name = \"crowded\"\n[goal]\ncenter_m = [0.45, 0.27, 0.025]\nsize_m = 0.05\n");
    for x in [0.22, 0.33, 0.44, 0.55] {
        for y in [-0.28, -0.14, 0.0, 0.14] {
            s += &format!(
                "[[obstacle]]\ncenter_m = [{x}, {y}, 0.015]\nsize_m = [0.04, 0.04, 0.03]\n"
            );
        }
    }
    s
}

/// Runs `perception` with `args` to the end; returns (success, stdout, stderr, the frames
/// received on `sub_prefix`).
fn run_to_end(
    args: &[&str],
    sub_prefix: Option<&str>,
) -> (bool, String, String, Vec<DetectionFrame>) {
    let (node, _) = services::create_node::<ipc::Service>("perception-frames-test").unwrap();
    let sub = sub_prefix.map(|p| services::open_subscriber::<DetectionFrame, _>(&node, p).unwrap());
    let mut p = ChildGuard::spawn(
        "perception run",
        Command::new(bin_path("perception"))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    // Drain stderr on a thread so a chatty child never blocks on a full pipe.
    let mut err_pipe = p.child.stderr.take().unwrap();
    let err_reader = std::thread::spawn(move || {
        let mut s = String::new();
        err_pipe.read_to_string(&mut s).ok();
        s
    });
    let mut frames = Vec::new();
    let drain = |frames: &mut Vec<DetectionFrame>| {
        if let Some(sub) = &sub {
            while let Ok(Some(s)) = sub.receive() {
                frames.push(*s.payload());
            }
        }
    };
    let status = wait_for(Duration::from_secs(90), || {
        drain(&mut frames);
        p.child.try_wait().unwrap()
    });
    drain(&mut frames);
    let mut stdout = String::new();
    p.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let stderr = err_reader.join().unwrap();
    (status.is_some_and(|s| s.success()), stdout, stderr, frames)
}

#[test]
fn a_crowded_table_publishes_the_nearest_objects_and_says_how_many_were_left_out() {
    let dir = tmpdir("perc-crowded");
    let scene = dir.join("crowded.toml");
    std::fs::write(&scene, crowded_scene()).unwrap();
    let prefix = unique_prefix("perccrowd");
    let (ok, stdout, stderr, frames) = run_to_end(
        &[
            "run",
            "--source",
            &format!("synthetic:{}", scene.display()),
            "--prefix",
            &prefix,
            "--rate",
            "20",
            "--fixed-step",
            "--frames",
            "8",
            "--persist-frames",
            "1",
        ],
        Some(&prefix),
    );
    assert!(ok, "perception run failed:\n{stderr}");
    assert_eq!(frames.len(), 8, "{stderr}");
    for f in &frames {
        assert!(
            f.capture_time_ns > 0,
            "a frame without a capture time: {f:?}"
        );
        assert_eq!(f.count as usize, MAX_DETECTIONS, "{f:?}");
        assert_eq!(f.dropped_count, 1, "17 objects seen, 16 fit: {f:?}");
        assert!(
            f.validate().is_err(),
            "rt-core must refuse a truncated frame"
        );
        let objs = f.objects();
        assert_eq!(
            objs[0].class().unwrap(),
            ObjectClass::Goal,
            "the goal first"
        );
        assert!(
            objs[1..]
                .iter()
                .all(|o| o.class().unwrap() == ObjectClass::Obstacle)
        );
        // Nearest first; the one left out is the farthest box from the base, (0.55, -0.28).
        let dist = |c: [f32; 3]| (c[0].powi(2) + c[1].powi(2)).sqrt();
        for w in objs[1..].windows(2) {
            assert!(
                dist(w[0].center_m) <= dist(w[1].center_m) + 0.01,
                "obstacles out of order: {:?} before {:?}",
                w[0].center_m,
                w[1].center_m
            );
        }
        assert!(
            !objs
                .iter()
                .any(|o| (o.center_m[0] - 0.55).abs() < 0.02 && (o.center_m[1] + 0.28).abs() < 0.02),
            "the farthest box was kept: {objs:?}"
        );
    }
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(stats["truncated_frames"], 8, "{stdout}");
    assert_eq!(stats["dropped_objects"], 8, "{stdout}");
    assert!(
        stderr.contains("dropped_count = 1"),
        "the truncation is logged:\n{stderr}"
    );
    assert_eq!(
        stderr.matches("dropped_count = 1").count(),
        1,
        "the warning is rate-limited:\n{stderr}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_goal_below_the_confidence_floor_is_reported_as_an_obstacle() {
    let dir = tmpdir("perc-floor");
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "[goal]\ncenter_m = [0.45, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, -0.05, 0.05]\nsize_m = [0.06, 0.06, 0.10]\n",
    )
    .unwrap();
    let out = Command::new(bin_path("perception"))
        .args(["render", "--scene", scene.to_str().unwrap(), "--out"])
        .arg(dir.join("r"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Colour only (no depth companion): the colour detector gives confidence 0.5.
    let frames_dir = dir.join("frames");
    std::fs::create_dir_all(&frames_dir).unwrap();
    std::fs::copy(dir.join("r/colour.png"), frames_dir.join("a.png")).unwrap();
    let prefix = unique_prefix("percfloor");
    let cal = dir.join("r/calibration.toml");
    let (ok, stdout, stderr, frames) = run_to_end(
        &[
            "run",
            "--source",
            &format!("file:{}", frames_dir.display()),
            "--calibration",
            cal.to_str().unwrap(),
            "--prefix",
            &prefix,
            "--persist-frames",
            "1",
            "--min-goal-confidence",
            "0.6",
        ],
        Some(&prefix),
    );
    assert!(ok, "perception run failed:\n{stderr}");
    assert_eq!(frames.len(), 1, "{stdout}\n{stderr}");
    let f = frames[0];
    f.validate().unwrap();
    assert_eq!(f.count, 2, "{f:?}");
    assert!(
        f.goal().is_none(),
        "a doubtful goal must not be reported as the goal: {f:?}"
    );
    assert!(
        f.objects()
            .iter()
            .all(|o| o.class().unwrap() == ObjectClass::Obstacle),
        "{f:?}"
    );
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(stats["goals_demoted"], 1, "{stdout}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_confidence_floors_are_refused_at_start_naming_the_field() {
    let dir = tmpdir("perc-badfloor");
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "[goal]\ncenter_m = [0.45, 0.20, 0.025]\nsize_m = 0.05\n",
    )
    .unwrap();
    let run = |extra: &[&str]| {
        let o = Command::new(bin_path("perception"))
            .args(["run", "--source", &format!("synthetic:{}", scene.display())])
            .args(["--frames", "1", "--prefix", &unique_prefix("percbad")])
            .args(extra)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (ok, err) = run(&["--min-goal-confidence", "1.5"]);
    // Refused by the flag's own bound (issue 25 item 13), which names the flag.
    assert!(!ok && err.contains("--min-goal-confidence"), "{err}");
    let (ok, err) = run(&["--min-obstacle-confidence", "0.9"]);
    assert!(!ok && err.contains("--min-obstacle-confidence"), "{err}");
    let cfg = dir.join("selection.toml");
    std::fs::write(&cfg, "min_obstacle_confidence = -0.5\n").unwrap();
    let (ok, err) = run(&["--selection-config", cfg.to_str().unwrap()]);
    assert!(
        !ok && err.contains("min_obstacle_confidence") && err.contains("selection.toml"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_ros2_source_is_loopback_only_unless_opened_and_help_says_so() {
    let help = Command::new(bin_path("perception"))
        .args(["run", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains("--ros2-open-network") && help.contains("loopback"),
        "{help}"
    );
    let dir = tmpdir("perc-open");
    // A live camera's calibration (the bundled one, renamed to a ZED's frame id): the
    // synthetic camera's is refused with --source ros2 before the networks are looked at.
    let cal = dir.join("zed_calibration.toml");
    let bundled =
        std::fs::read_to_string(foresight_tests::asset("perception/calibration.toml")).unwrap();
    std::fs::write(
        &cal,
        bundled.replace(
            "frame_id = \"foresight_synthetic_camera\"",
            "frame_id = \"zed_left_camera_frame_optical\"",
        ),
    )
    .unwrap();
    let run = |extra: &[&str]| {
        let o = Command::new(bin_path("perception"))
            .args(["run", "--source", "ros2", "--frames", "1"])
            .args(["--prefix", &unique_prefix("percopen")])
            .arg("--calibration")
            .arg(&cal)
            .args(extra)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    // A LAN address without the flag: refused before any DDS traffic, naming the field.
    let (ok, err) = run(&["--ros2-network", "192.168.77.20"]);
    assert!(
        !ok && err.contains("networks") && err.contains("--ros2-open-network"),
        "{err}"
    );
    // Every interface (an empty list in the topics file) without the flag: refused too.
    let topics = dir.join("topics.toml");
    std::fs::write(
        &topics,
        "networks = []\ncolour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\n",
    )
    .unwrap();
    let (ok, err) = run(&["--ros2-topics", topics.to_str().unwrap()]);
    assert!(
        !ok && err.contains("networks") && err.contains("every interface"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
