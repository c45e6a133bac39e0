//! Blind mode (`--no-lookahead`) never reaches a real arm: `rt-core run --link xarm` and the
//! `foresight` launcher refuse it for a non-loopback `--robot` address, from the address
//! alone, before any connection or process start.
//!
//! Each test runs inside a private network namespace (`unshare -n` as root, else
//! `unshare -rn`, made by `run_in_private_netns`), so that even a build without the refusal
//! cannot send a packet off the machine. Inside it the "remote" robot address 192.0.2.10
//! (TEST-NET-1) is put on `lo` with a listener behind it: a build that tried to connect
//! would be accepted there, and the test sees it. Needs `unshare` and `ip`, and the
//! binaries built (`scripts/cargo.sh build --release -p rt-core -p launcher --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::TcpListener;
use std::process::{Command, Output};
use std::time::Duration;

use foresight_tests::bounded::{REMOTE, add_remote_address, run_bounded_timed};
use foresight_tests::{NetnsOutcome, bin_path, repo_root, run_in_private_netns, unique_prefix};

/// The driver's TCP connect timeout: a refusal decided from the address alone comes well
/// before a connection attempt could even time out.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(1);

/// Puts [`REMOTE`] on `lo` of the private namespace and listens on it (port chosen by the
/// OS), so that any connection attempt to it is seen.
fn remote_listener() -> TcpListener {
    add_remote_address();
    let l = TcpListener::bind((REMOTE, 0)).expect("listening on the remote address");
    l.set_nonblocking(true).expect("non-blocking listener");
    l
}

/// The refusal's checks: a non-zero exit well before the connect timeout, stderr naming
/// the refusal and the address, and no connection at the listener.
fn assert_refused(who: &str, out: &Output, elapsed: Duration, listener: &TcpListener) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{who}: {} after {elapsed:?}; stderr:\n{stderr}", out.status);
    let connected = match listener.accept() {
        Ok((_, peer)) => Some(peer),
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => None,
        Err(e) => panic!("listener: {e}"),
    };
    assert!(
        connected.is_none(),
        "{who} connected to {REMOTE} (from {connected:?}) in blind mode; stderr:\n{stderr}"
    );
    assert!(
        !out.status.success(),
        "{who} accepted --no-lookahead with --robot {REMOTE}; stderr:\n{stderr}"
    );
    assert!(
        elapsed < CONNECT_TIMEOUT,
        "{who} took {elapsed:?} to refuse (connect timeout {CONNECT_TIMEOUT:?}); stderr:\n{stderr}"
    );
    assert!(
        stderr.contains(&format!(
            "--no-lookahead is refused for the non-loopback robot address {REMOTE}"
        )) && stderr.contains("simulation-only")
            && stderr.contains("no connection was attempted"),
        "{who}'s stderr does not name the refusal:\n{stderr}"
    );
}

#[test]
fn rt_core_run_refuses_blind_mode_on_a_remote_robot() {
    if run_in_private_netns("rt_core_run_refuses_blind_mode_on_a_remote_robot")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let listener = remote_listener();
    let port = listener.local_addr().expect("listener address").port();
    let (out, elapsed) = run_bounded_timed(
        Command::new(bin_path("rt-core"))
            .current_dir(repo_root())
            .args(["run", "--link", "xarm", "--no-mlock", "--seconds", "5"])
            .arg("--robot")
            .arg(format!("{REMOTE}:{port}"))
            .arg("--report-port")
            .arg(port.to_string())
            .arg("--prefix")
            .arg(unique_prefix("blind"))
            .arg("--no-lookahead")
            .env("NO_COLOR", "1"),
        Duration::from_secs(15),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("xArm at") && !stderr.contains("iceoryx2 node up"),
        "rt-core went on past the address check:\n{stderr}"
    );
    assert_refused("rt-core run", &out, elapsed, &listener);
}

#[test]
fn foresight_refuses_blind_mode_on_a_remote_robot() {
    if run_in_private_netns("foresight_refuses_blind_mode_on_a_remote_robot")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let listener = remote_listener();
    let port = listener.local_addr().expect("listener address").port();
    let out_dir = std::env::temp_dir().join(unique_prefix("blind_runs"));
    let (out, elapsed) = run_bounded_timed(
        Command::new(bin_path("foresight"))
            .current_dir(repo_root())
            .arg("--robot")
            .arg(format!("{REMOTE}:{port}"))
            .arg("--no-lookahead")
            .arg("--out")
            .arg(&out_dir)
            .env("NO_COLOR", "1"),
        Duration::from_secs(30),
    );
    let started_anything = out_dir.exists();
    let _ = std::fs::remove_dir_all(&out_dir);
    assert!(
        !started_anything,
        "foresight created a run folder (it went on to start the run); stderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no process was started"),
        "foresight's refusal does not say that nothing was started:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_refused("foresight", &out, elapsed, &listener);
}
