//! Simulation rights by identity, not address (issue 30 item 1): a controller that speaks
//! the real xArm protocol on 127.0.0.1 but is not this run's `xarm-sim` — here a real
//! `xarm-sim` started without the secret, which answers the identity challenge as a real
//! controller answers a register it does not have — is a real arm:
//! - `rt-core run --link xarm` refuses it blind mode (`--no-lookahead`) and `--auto-resume`,
//!   and the simulated sensors (`--simulated-sensors`), before any `servo_j` (or anything
//!   but `GET_VERSION` and the challenge) reaches it — with a secret that it does not hold,
//!   and without any secret (then before any connection);
//! - `foresight --robot 127.0.0.1:PORT` refuses it the synthetic camera, the bundled
//!   calibration and blind mode before any process starts;
//! - the same `xarm-sim` started with the secret gets blind mode (and the launcher's own
//!   `xarm-sim` keeps getting everything: `demo_scenario`, `xarm_reconnect`).
//!
//! Needs the binaries built (`scripts/cargo.sh build --release -p launcher -p rt-core
//! -p xarm-sim --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::{Command, Output};
use std::time::Duration;

use foresight_tests::bounded::run_bounded;
use foresight_tests::sim_proc::{SIM_SECRET_ENV, SimProc, fresh_secret};
use foresight_tests::{bin_path, repo_root, unique_prefix};

/// `rt-core run --link xarm` against `sim` on loopback for at most 3 s of run time, with
/// `flags` and (when given) `secret` in its environment.
fn rt_core_run(sim: &SimProc, flags: &[&str], secret: Option<&str>) -> Output {
    let mut cmd = Command::new(bin_path("rt-core"));
    cmd.args(["run", "--link", "xarm", "--no-mlock", "--seconds", "3"])
        .arg("--robot")
        .arg(format!("127.0.0.1:{}", sim.command_port()))
        .arg("--report-port")
        .arg(sim.report_real_port().to_string())
        .arg("--prefix")
        .arg(unique_prefix("simid"))
        .args(flags)
        .env_remove(SIM_SECRET_ENV);
    if let Some(s) = secret {
        cmd.env(SIM_SECRET_ENV, s);
    }
    run_bounded(&mut cmd, Duration::from_secs(30))
}

/// The `servo_j` targets the simulator received (accepted or refused).
fn servo_targets(summary: &serde_json::Value) -> u64 {
    let c = &summary["counters"];
    c["servo_accepted"].as_u64().unwrap_or(0) + c["servo_rejected"].as_u64().unwrap_or(0)
}

#[test]
fn rt_core_refuses_simulation_rights_to_a_loopback_controller_that_is_not_xarm_sim() {
    let sim = SimProc::start_with_secret([0; 6], &[], None);
    let addr = format!("127.0.0.1:{}", sim.command_port());
    let mut challenges = 0;
    for flags in [
        &["--no-lookahead"][..],
        &["--auto-resume"][..],
        &["--simulated-sensors"][..],
        &["--no-lookahead", "--auto-resume"][..],
    ] {
        // A secret the controller does not hold: asked, and no proof comes back.
        let secret = fresh_secret();
        let out = rt_core_run(&sim, flags, Some(&secret));
        let stderr = String::from_utf8_lossy(&out.stderr);
        eprintln!("rt-core run {flags:?}: {}; stderr:\n{stderr}", out.status);
        challenges += 1;
        assert!(
            !out.status.success(),
            "rt-core run {flags:?} drove a loopback controller that is not xarm-sim:\n{stderr}"
        );
        assert!(
            stderr.contains(&format!(
                "{} refused for the robot at {addr}",
                flags.join(", ")
            )) && stderr.contains("has not proven it is this run's xarm-sim")
                && stderr.contains("as a real xArm or an xarm-sim without the run's secret")
                && stderr.contains("nothing was moved"),
            "rt-core run {flags:?}: the refusal does not name the flags and why:\n{stderr}"
        );
        assert!(
            !secret.is_empty() && !stderr.contains(&secret),
            "the secret reached the log"
        );
        // No secret at all: refused before any connection.
        let out = rt_core_run(&sim, flags, None);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success()
                && stderr.contains(&format!("no simulator secret in {SIM_SECRET_ENV}"))
                && stderr.contains("No connection was attempted"),
            "rt-core run {flags:?} without a secret:\n{stderr}"
        );
    }
    let summary = sim.finish();
    eprintln!("xarm-sim summary: {summary}");
    assert_eq!(
        servo_targets(&summary),
        0,
        "servo_j reached a controller that is not xarm-sim: {summary}"
    );
    assert_eq!(
        summary["counters"]["identity_challenges"], challenges,
        "each run with a secret asks once, each run without one never connects: {summary}"
    );
    assert_eq!(summary["counters"]["identity_proofs"], 0, "{summary}");
    // GET_VERSION and the challenge, nothing else (no GET_ERROR, MOTION_EN, SET_MODE, …).
    assert_eq!(
        summary["counters"]["frames"],
        2 * challenges,
        "more than the handshake and the challenge reached it: {summary}"
    );
    assert_eq!(summary["connections"], challenges, "{summary}");
}

#[test]
fn xarm_sim_with_the_secret_gets_blind_mode_and_auto_resume() {
    let sim = SimProc::start([0; 6], &[]);
    let out = rt_core_run(
        &sim,
        &["--no-lookahead", "--auto-resume"],
        Some(sim.secret()),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "rt-core refused the launcher-style xarm-sim that holds the secret:\n{stderr}"
    );
    assert!(
        stderr.contains("simulation-only rights granted"),
        "rt-core does not say it granted the rights:\n{stderr}"
    );
    let summary = sim.finish();
    assert_eq!(summary["counters"]["identity_proofs"], 1, "{summary}");
    assert!(servo_targets(&summary) > 0, "{summary}");
}

#[test]
fn foresight_refuses_the_synthetic_camera_and_blind_mode_to_a_loopback_arm_that_is_not_xarm_sim() {
    let sim = SimProc::start_with_secret([0; 6], &[], None);
    let robot = format!("127.0.0.1:{}", sim.command_port());
    let calibration = repo_root().join("assets/perception/calibration.toml");
    let cases: [(&[&str], &[&str]); 3] = [
        (
            &[],
            &[
                "from the synthetic camera (--camera synthetic)",
                "with the bundled calibration (no --calibration)",
            ],
        ),
        (
            &["--no-lookahead", "--camera", "ros2", "--calibration"],
            &["blind (--no-lookahead)"],
        ),
        (&["--camera", "file:rec.mp4"], &["--camera file:rec.mp4"]),
    ];
    let mut asked = 0;
    for (extra, names) in cases {
        for secret in [Some(fresh_secret()), None] {
            let out_dir = std::env::temp_dir().join(unique_prefix("simid_runs"));
            let mut cmd = Command::new(bin_path("foresight"));
            cmd.args(["--robot", &robot, "--out"])
                .arg(&out_dir)
                .args(extra)
                .env_remove(SIM_SECRET_ENV);
            if extra.last() == Some(&"--calibration") {
                cmd.arg(&calibration);
            }
            if let Some(s) = &secret {
                cmd.env(SIM_SECRET_ENV, s);
                asked += 1;
            }
            let out = run_bounded(&mut cmd, Duration::from_secs(30));
            let stderr = String::from_utf8_lossy(&out.stderr);
            eprintln!(
                "foresight {extra:?} (secret: {}): {}",
                secret.is_some(),
                out.status
            );
            let started_anything = out_dir.exists();
            let _ = std::fs::remove_dir_all(&out_dir);
            assert!(
                !out.status.success() && !started_anything,
                "foresight {extra:?} went on to start a run on a loopback arm that is not \
                 xarm-sim:\n{stderr}"
            );
            let why = if secret.is_some() {
                "as a real xArm or an xarm-sim without the run's secret".to_owned()
            } else {
                format!("no simulator secret in {SIM_SECRET_ENV}; no connection was attempted")
            };
            assert!(
                stderr.contains(&format!("--robot {robot} has not proven it is xarm-sim"))
                    && stderr.contains("it is treated as a real arm")
                    && stderr.contains(&why)
                    && names.iter().all(|n| stderr.contains(n))
                    && stderr.contains("no process was started"),
                "foresight {extra:?}: the refusal does not name what was refused and why:\n\
                 {stderr}"
            );
        }
    }
    let summary = sim.finish();
    assert_eq!(
        servo_targets(&summary),
        0,
        "servo_j reached a controller that is not xarm-sim: {summary}"
    );
    assert_eq!(
        summary["counters"]["identity_challenges"], asked,
        "the launcher asks once per run with a secret, never without: {summary}"
    );
    assert_eq!(summary["counters"]["frames"], 2 * asked, "{summary}");
}
