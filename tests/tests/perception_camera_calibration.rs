//! A calibration belongs to one camera (issue 30 item 2), as the launcher enforces it:
//! `foresight --robot <a real arm> --camera ros2 --calibration FILE` is refused before
//! anything starts when FILE is the synthetic camera's (the bundled
//! `assets/perception/calibration.toml`, which the remote-arm check used to accept because
//! a `--calibration` was given) or names no camera (an old file without `[camera]`); the
//! arm's controller never sees a connection and no run folder is made.
//!
//! Runs inside a private network namespace (`run_in_private_netns`) in which the "remote"
//! robot address 192.0.2.10 (TEST-NET-1) is put on `lo` and a real `xarm-sim` listens on it,
//! as in `real_arm_sensors.rs`. Needs `unshare`, `ip` and the binaries built
//! (`scripts/cargo.sh build --release -p launcher -p xarm-sim --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;
use std::time::Duration;

use foresight_tests::bounded::{REMOTE, remote_sim, run_bounded};
use foresight_tests::{NetnsOutcome, bin_path, repo_root, run_in_private_netns, unique_prefix};

#[test]
fn foresight_refuses_a_live_camera_with_the_synthetic_or_an_unnamed_calibration() {
    let name = "foresight_refuses_a_live_camera_with_the_synthetic_or_an_unnamed_calibration";
    if run_in_private_netns(name) == NetnsOutcome::RanInChild {
        return;
    }
    let dir = std::env::temp_dir().join(unique_prefix("perc_launch_cal"));
    std::fs::create_dir_all(&dir).unwrap();
    let bundled = repo_root().join("assets/perception/calibration.toml");
    let text = std::fs::read_to_string(&bundled).unwrap();
    let start = text.find("\n[camera]\n").unwrap() + 1;
    let end = start + text[start..].find("\n\n").unwrap();
    let old = dir.join("old_calibration.toml");
    std::fs::write(&old, format!("{}{}", &text[..start], &text[end..])).unwrap();

    let sim = remote_sim();
    let robot = format!("{REMOTE}:{}", sim.command_port());
    for (cal, why) in [
        (&bundled, "was made for the synthetic camera"),
        (&old, "has no [camera] frame_id"),
    ] {
        let out_dir = std::env::temp_dir().join(unique_prefix("perc_launch_runs"));
        let out = run_bounded(
            Command::new(bin_path("foresight"))
                .args(["--robot", &robot, "--camera", "ros2", "--calibration"])
                .arg(cal)
                .arg("--out")
                .arg(&out_dir),
            Duration::from_secs(30),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        let started_anything = out_dir.exists();
        let _ = std::fs::remove_dir_all(&out_dir);
        assert!(
            !out.status.success() && !started_anything,
            "foresight --camera ros2 --calibration {} went on to start a run on a real arm:\n{stderr}",
            cal.display()
        );
        assert!(
            stderr.contains(why) && stderr.contains("perception calibrate --frame-id"),
            "foresight --calibration {}: the refusal does not say why:\n{stderr}",
            cal.display()
        );
    }
    let summary = sim.finish();
    assert_eq!(
        summary["connections"], 0,
        "the arm's controller saw a connection: {summary}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
