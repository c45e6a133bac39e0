//! Running a binary for a bounded time, and a robot address off this machine: what the tests
//! that check refusals before anything starts (`blind_mode_target.rs`, `real_arm_sensors.rs`,
//! `sim_identity.rs`, `perception_camera_calibration.rs`) share.

// Test support: a failed start is a failed test, with its message.
#![allow(clippy::expect_used)]

use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::sim_proc::SimProc;

/// A robot address off this machine (TEST-NET-1, never routed).
pub const REMOTE: &str = "192.0.2.10";

/// Puts [`REMOTE`] on `lo` (call it inside a private network namespace:
/// [`crate::run_in_private_netns`]), so that a process can listen on it.
///
/// # Panics
/// When `ip` cannot run or refuses.
pub fn add_remote_address() {
    let out = Command::new("ip")
        .args(["addr", "add", &format!("{REMOTE}/32"), "dev", "lo"])
        .output()
        .unwrap_or_else(|e| panic!("cannot run `ip` (iproute2) in the namespace: {e}"));
    assert!(
        out.status.success(),
        "ip addr add {REMOTE}/32 dev lo failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `xarm-sim` listening on [`REMOTE`] (on `lo` of the private namespace), OS-chosen ports.
pub fn remote_sim() -> SimProc {
    add_remote_address();
    SimProc::start([0; 6], &["--bind", REMOTE])
}

/// Runs `cmd` (in its own process group, from the repository root, without colours) for at
/// most `limit`; kills the group if it has not exited by then. Returns its output and how
/// long it ran.
pub fn run_bounded_timed(cmd: &mut Command, limit: Duration) -> (Output, Duration) {
    use std::os::unix::process::CommandExt;
    let t0 = Instant::now();
    let mut child = cmd
        .current_dir(crate::repo_root())
        .env("NO_COLOR", "1")
        .process_group(0)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting the binary");
    while t0.elapsed() < limit {
        if let Ok(Some(_)) = child.try_wait() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let elapsed = t0.elapsed();
    if let Ok(None) = child.try_wait() {
        // Still running after `limit`: stop it and everything it started.
        let _ = Command::new("kill")
            .args(["-KILL", &format!("-{}", child.id())])
            .status();
    }
    let out = child.wait_with_output().expect("collecting the output");
    (out, elapsed)
}

/// [`run_bounded_timed`] without the time.
pub fn run_bounded(cmd: &mut Command, limit: Duration) -> Output {
    run_bounded_timed(cmd, limit).0
}
