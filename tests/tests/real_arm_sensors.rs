//! A real arm is never driven from an imaginary world, nor resumed without its operator
//! (issue 25 items 2 and 7):
//! - `foresight --robot <address off this machine>` without a live camera (`--camera ros2`)
//!   and an explicit `--calibration` is refused, naming both flags, before any process
//!   starts — the arm's controller never sees a connection;
//! - `rt-core run --link xarm --robot <address off this machine> --auto-resume` is refused
//!   by blind mode's address check, before any connection.
//!
//! Each test runs inside a private network namespace (`run_in_private_netns`) in which the
//! "remote" robot address 192.0.2.10 (TEST-NET-1) is put on `lo` and a real `xarm-sim`
//! listens on it: a build without the refusal would connect to it (and start a run), which
//! its summary (`connections`) shows. Needs `unshare`, `ip` and the binaries built
//! (`scripts/cargo.sh build --release -p launcher -p rt-core -p xarm-sim --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;
use std::time::Duration;

use foresight_tests::bounded::{REMOTE, remote_sim, run_bounded};
use foresight_tests::{NetnsOutcome, bin_path, run_in_private_netns, unique_prefix};

#[test]
fn foresight_refuses_a_remote_arm_without_a_live_camera_and_an_explicit_calibration() {
    if run_in_private_netns(
        "foresight_refuses_a_remote_arm_without_a_live_camera_and_an_explicit_calibration",
    ) == NetnsOutcome::RanInChild
    {
        return;
    }
    let sim = remote_sim();
    let robot = format!("{REMOTE}:{}", sim.command_port());
    for extra in [
        &[][..],
        &["--camera", "ros2"][..],
        &["--calibration", "assets/perception/calibration.toml"][..],
    ] {
        let out_dir = std::env::temp_dir().join(unique_prefix("realarm_runs"));
        let out = run_bounded(
            Command::new(bin_path("foresight"))
                .args(["--robot", &robot, "--out"])
                .arg(&out_dir)
                .args(extra),
            Duration::from_secs(30),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        let started_anything = out_dir.exists();
        let _ = std::fs::remove_dir_all(&out_dir);
        assert!(
            !out.status.success(),
            "foresight {extra:?} ran a remote arm on imaginary sensors:\n{stderr}"
        );
        assert!(
            !started_anything,
            "foresight {extra:?} created a run folder (it went on to start the run):\n{stderr}"
        );
        assert!(
            stderr.contains(&format!("--robot {robot} is a real arm"))
                && stderr.contains("--camera ros2")
                && stderr.contains("--calibration FILE")
                && stderr.contains("no process was started"),
            "foresight {extra:?}: the refusal does not name both flags:\n{stderr}"
        );
    }
    let summary = sim.finish();
    assert_eq!(
        summary["connections"], 0,
        "the arm's controller saw a connection: {summary}"
    );
}

#[test]
fn rt_core_refuses_auto_resume_on_a_remote_arm() {
    if run_in_private_netns("rt_core_refuses_auto_resume_on_a_remote_arm")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let sim = remote_sim();
    let out = run_bounded(
        Command::new(bin_path("rt-core"))
            .args(["run", "--link", "xarm", "--no-mlock", "--seconds", "5"])
            .arg("--robot")
            .arg(format!("{REMOTE}:{}", sim.command_port()))
            .arg("--report-port")
            .arg(sim.report_real_port().to_string())
            .arg("--prefix")
            .arg(unique_prefix("autoresume"))
            .arg("--auto-resume"),
        Duration::from_secs(20),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "rt-core accepted --auto-resume for a remote arm:\n{stderr}"
    );
    assert!(
        stderr.contains(&format!(
            "--auto-resume is refused for the non-loopback robot address {REMOTE}"
        )) && stderr.contains("no connection was attempted"),
        "rt-core's refusal does not name --auto-resume:\n{stderr}"
    );
    let summary = sim.finish();
    assert_eq!(
        summary["connections"], 0,
        "the arm's controller saw a connection: {summary}"
    );
}
