//! The real `perception` process: synthetic camera → colour detector → `DetectionFrame`s
//! over iceoryx2, received by an ordinary subscriber; a world script swaps the small box
//! for a tall one and the published obstacle (same id) grows; corrupt and empty image files
//! are skipped while the good ones are served; bad inputs give clear errors; a calibration
//! is used only with its own camera (issue 30 item 2).
//!
//! Needs `cargo build --release -p perception` (the binary) first.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use foresight_tests::{ChildGuard, bin_path, unique_prefix, wait_for};
use iceoryx2::prelude::*;
use shm_schemas::{DetectionFrame, ObjectClass, services};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foresight-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

const SMALL: &str = "name = \"small\"\n[goal]\ncenter_m = [0.45, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, -0.05, 0.05]\nsize_m = [0.06, 0.06, 0.10]\n";

fn write_world(dir: &Path) -> PathBuf {
    std::fs::write(dir.join("small.toml"), SMALL).unwrap();
    std::fs::write(
        dir.join("tall.toml"),
        SMALL.replace(
            "0.05]\nsize_m = [0.06, 0.06, 0.10]",
            "0.15]\nsize_m = [0.06, 0.06, 0.30]",
        ),
    )
    .unwrap();
    let w = dir.join("world.toml");
    std::fs::write(&w, "[[step]]\nat_s = 0.0\nscene = \"small.toml\"\n[[step]]\nat_s = 1.0\nscene = \"tall.toml\"\n").unwrap();
    w
}

fn drain(
    sub: &iceoryx2::port::subscriber::Subscriber<ipc::Service, DetectionFrame, ()>,
    into: &mut Vec<DetectionFrame>,
) {
    while let Ok(Some(s)) = sub.receive() {
        let f = *s.payload();
        f.validate().expect("published frames validate");
        into.push(f);
    }
}

#[test]
fn synthetic_world_script_is_published_with_stable_ids_and_the_tall_box_grows() {
    let dir = tmpdir("perc-run");
    let world = write_world(&dir);
    let prefix = unique_prefix("perc");
    let (node, _) = services::create_node::<ipc::Service>("perception-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run",
        Command::new(bin_path("perception"))
            .args([
                "run",
                "--source",
                &format!("synthetic:{}", world.display()),
                "--prefix",
                &prefix,
            ])
            .args([
                "--rate",
                "20",
                "--fixed-step",
                "--frames",
                "60",
                "--persist-frames",
                "2",
            ])
            .stdout(Stdio::piped()),
    );
    let mut frames = Vec::new();
    let done = wait_for(Duration::from_secs(60), || {
        drain(&sub, &mut frames);
        p.child.try_wait().unwrap().map(|s| s.success())
    });
    drain(&sub, &mut frames);
    assert_eq!(done, Some(true), "perception run did not finish cleanly");
    assert!(frames.len() >= 30, "only {} frames received", frames.len());
    for w in frames.windows(2) {
        assert!(w[1].sequence > w[0].sequence, "sequence must increase");
        assert!(
            w[1].capture_time_ns > w[0].capture_time_ns,
            "capture time must increase"
        );
    }
    let last = frames.last().unwrap();
    assert_eq!(last.sequence, 60);
    // Objects: a goal and an obstacle, with stable ids; the obstacle is 0.10 m tall before
    // the swap (t < 1 s, frames 1..=20) and 0.30 m after.
    let with_both: Vec<&DetectionFrame> = frames.iter().filter(|f| f.count == 2).collect();
    assert!(
        with_both.len() >= 25,
        "{} frames with both objects",
        with_both.len()
    );
    let ids = |f: &DetectionFrame| (f.objects()[0].object_id, f.objects()[1].object_id);
    let first_ids = ids(with_both[0]);
    assert!(
        with_both.iter().all(|f| ids(f) == first_ids),
        "ids changed across frames"
    );
    for f in &with_both {
        let goal = f.objects()[0];
        let obs = f.objects()[1];
        assert_eq!(goal.class().unwrap(), ObjectClass::Goal);
        assert_eq!(obs.class().unwrap(), ObjectClass::Obstacle);
        assert!(
            (goal.center_m[0] - 0.45).abs() < 0.01 && (goal.center_m[1] - 0.20).abs() < 0.01,
            "{goal:?}"
        );
        let h = obs.size_m[2];
        if f.sequence <= 20 {
            assert!((h - 0.10).abs() < 0.01, "seq {}: height {h}", f.sequence);
        } else if f.sequence >= 23 {
            assert!((h - 0.30).abs() < 0.01, "seq {}: height {h}", f.sequence);
            assert!((obs.center_m[2] - 0.15).abs() < 0.01);
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn corrupt_and_empty_files_are_skipped_and_good_frames_served() {
    let dir = tmpdir("perc-files");
    let world = write_world(&dir);
    // Render one good frame (colour + depth + exact calibration) with the binary itself.
    let out = Command::new(bin_path("perception"))
        .args(["render", "--scene", world.to_str().unwrap(), "--out"])
        .arg(dir.join("r"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    std::fs::copy(dir.join("r/colour.png"), frames.join("a.png")).unwrap();
    std::fs::copy(dir.join("r/colour.depth.tiff"), frames.join("a.depth.tiff")).unwrap();
    std::fs::write(frames.join("b.png"), b"\x89PNG\r\n\x1a\n garbage").unwrap();
    std::fs::write(frames.join("c.png"), b"").unwrap();
    std::fs::copy(dir.join("r/colour.png"), frames.join("d.png")).unwrap();
    std::fs::copy(dir.join("r/colour.depth.tiff"), frames.join("d.depth.tiff")).unwrap();

    let prefix = unique_prefix("percf");
    let (node, _) = services::create_node::<ipc::Service>("perception-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run",
        Command::new(bin_path("perception"))
            .args([
                "run",
                "--source",
                &format!("file:{}", frames.display()),
                "--prefix",
                &prefix,
            ])
            .args([
                "--calibration",
                dir.join("r/calibration.toml").to_str().unwrap(),
            ])
            .args(["--rate", "20", "--persist-frames", "1"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    let mut got = Vec::new();
    let done = wait_for(Duration::from_secs(30), || {
        drain(&sub, &mut got);
        p.child.try_wait().unwrap()
    });
    drain(&sub, &mut got);
    assert!(done.is_some_and(|s| s.success()), "perception run failed");
    let mut stdout = String::new();
    let mut stderr = String::new();
    use std::io::Read;
    p.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    p.child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(stats["published"], 2, "{stdout}\n{stderr}");
    assert_eq!(stats["bad_frames"], 2, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("b.png") && stderr.contains("c.png"),
        "the bad files are named in the log:\n{stderr}"
    );
    assert_eq!(got.len(), 2);
    assert_eq!(got[1].count, 2, "{:?}", got[1]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tmpdir("perc-bad");
    let run = |args: &[&str]| {
        let o = Command::new(bin_path("perception"))
            .args(args)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    std::fs::write(dir.join("cal.toml"), "corners_px = [[1.0, 2.0]]\n").unwrap();
    let (ok, err) = run(&[
        "run",
        "--source",
        "file:/nonexistent",
        "--calibration",
        dir.join("cal.toml").to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("cannot open source") || err.contains("calibration"),
        "{err}"
    );
    let world = write_world(&dir);
    let (ok, err) = run(&[
        "run",
        "--source",
        &format!("synthetic:{}", world.display()),
        "--calibration",
        dir.join("cal.toml").to_str().unwrap(),
        "--frames",
        "1",
    ]);
    assert!(!ok);
    assert!(
        err.contains("malformed calibration file") && err.contains("cal.toml"),
        "{err}"
    );
    let (ok, err) = run(&["detect", "--image", "/nonexistent.png"]);
    assert!(!ok && err.contains("/nonexistent.png"), "{err}");
    std::fs::write(dir.join("labels.txt"), "goal\nobstacle\n").unwrap();
    let (ok, err) = run(&[
        "detect",
        "--image",
        "/nonexistent.png",
        "--model",
        dir.join("missing.onnx").to_str().unwrap(),
        "--labels",
        dir.join("labels.txt").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("missing.onnx"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 30 item 2: a calibration belongs to one camera. `perception run --source ros2`
/// without `--calibration` is refused saying why (it used to load the bundled synthetic
/// calibration silently); the bundled calibration (the synthetic camera's) is refused with
/// the ROS 2 source; an old calibration without `[camera]` is refused with the hint to
/// re-run `perception calibrate`; a live camera's calibration is refused with the synthetic
/// source. All before the source is opened: nothing waits for images.
#[test]
fn a_calibration_is_used_only_with_its_own_camera() {
    let dir = tmpdir("perc-calcam");
    let run = |args: &[&str]| {
        let o = Command::new(bin_path("perception"))
            .args(args)
            .args(["--prefix", &unique_prefix("perccalcam")])
            .output()
            .unwrap();
        (
            o.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            ),
        )
    };
    // Quick to give up on a camera that never sends (before: the run waited for images).
    let topics = dir.join("topics.toml");
    std::fs::write(
        &topics,
        "colour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\ntimeout_s = 0.2\n",
    )
    .unwrap();
    let ros2 = ["run", "--source", "ros2", "--frames", "1", "--ros2-topics"];
    let ros2 = |extra: &[&str]| {
        let mut a = ros2.to_vec();
        a.push(topics.to_str().unwrap());
        a.extend_from_slice(extra);
        run(&a)
    };
    let (ok, out) = ros2(&[]);
    assert!(
        !ok && out.contains("--source ros2 needs --calibration FILE")
            && out.contains("synthetic camera"),
        "--source ros2 without --calibration was not refused:\n{out}"
    );
    let bundled = foresight_tests::asset("perception/calibration.toml");
    let (ok, out) = ros2(&["--calibration", bundled.to_str().unwrap()]);
    assert!(
        !ok && out.contains("made for the synthetic camera")
            && out.contains("calibration.toml")
            && out.contains("--frame-id"),
        "the synthetic camera's calibration was not refused with --source ros2:\n{out}"
    );
    let text = std::fs::read_to_string(&bundled).unwrap();
    let start = text.find("\n[camera]\n").unwrap() + 1;
    let end = start + text[start..].find("\n\n").unwrap();
    let old = dir.join("old_calibration.toml");
    std::fs::write(&old, format!("{}{}", &text[..start], &text[end..])).unwrap();
    let (ok, out) = ros2(&["--calibration", old.to_str().unwrap()]);
    assert!(
        !ok && out.contains("old_calibration.toml")
            && out.contains("no [camera] table")
            && out.contains("perception calibrate"),
        "a calibration without [camera] was not refused:\n{out}"
    );
    let zed = dir.join("zed_calibration.toml");
    std::fs::write(
        &zed,
        text.replace(
            "frame_id = \"foresight_synthetic_camera\"",
            "frame_id = \"zed_left_camera_frame_optical\"",
        ),
    )
    .unwrap();
    let world = write_world(&dir);
    let (ok, out) = run(&[
        "run",
        "--source",
        &format!("synthetic:{}", world.display()),
        "--frames",
        "1",
        "--calibration",
        zed.to_str().unwrap(),
    ]);
    assert!(
        !ok && out.contains("zed_left_camera_frame_optical")
            && out.contains("not for the synthetic camera"),
        "a live camera's calibration was not refused with the synthetic source:\n{out}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
