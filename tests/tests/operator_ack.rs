//! The operator's acknowledgement through the real processes: `rt-core run --link xarm`
//! against `xarm-sim`, a controller restart latches a protective stop (a real arm's rule:
//! no `--auto-resume`), and then
//! - SIGUSR1 (the acknowledgement of earlier versions, which any process of the same user
//!   could send) clears nothing;
//! - `rt-core ack` names the latched stop, refuses to clear another one, and clears the one
//!   named;
//! - where the test runs as root, the same command run as another user (`setpriv`) is
//!   refused by rt-core (that user is no operator of it).
//!
//! Needs the workspace's binaries built (`cargo build --release --workspace --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use foresight_tests::sim_proc::SimProc;
use foresight_tests::{ChildGuard, bin_path, unique_prefix, wait_for};

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout: {}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Whether this process's effective user is root.
fn running_as_root() -> bool {
    read(Path::new("/proc/self/status"))
        .lines()
        .find_map(|l| l.strip_prefix("Uid:"))
        .and_then(|l| l.split_whitespace().nth(1))
        == Some("0")
}

#[test]
fn a_latched_stop_is_cleared_only_by_an_operator_naming_it() {
    let dir = std::env::temp_dir().join(unique_prefix("operator_ack"));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let log = dir.join("rt-core.log");
    let sim = SimProc::start([0; 6], &[]);
    let ports = sim.ports;
    let robot = format!("127.0.0.1:{}", sim.command_port());
    // No `--auto-resume`: a lost link latches, as on a real arm.
    let mut rt = ChildGuard::spawn("rt-core", &mut sim.rt_core_run(&[], &log));
    let wait_log = |needle: &str, secs: u64| {
        wait_for(Duration::from_secs(secs), || {
            read(&log).contains(needle).then_some(())
        })
        .unwrap_or_else(|| panic!("no {needle:?} in the rt-core log:\n{}", read(&log)));
    };
    wait_log("iceoryx2 node up", 30);
    wait_log("operator acknowledgement channel open", 5);
    let ack = |extra: &[&str]| {
        Command::new(bin_path("rt-core"))
            .args(["ack", "--robot", &robot])
            .args(extra)
            .stdin(Stdio::null())
            .output()
            .expect("rt-core ack")
    };
    // Nothing latched yet: nothing to acknowledge.
    let out = ack(&["--clears", "1"]);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no protective stop is latched"),
        "{}",
        text(&out)
    );

    // The controller restarts: the lost link latches (stop #1).
    let secret = sim.secret.clone();
    let mut sim = sim;
    let _ = sim.guard.child.kill();
    let _ = sim.guard.child.wait();
    wait_log("reconnecting off the cycle", 10);
    let _sim2 = SimProc::start_with_secret(ports, &[], secret);
    wait_log("xArm link re-established", 20);
    let latched =
        |out: &Output| String::from_utf8_lossy(&out.stdout).contains("stop #1 (lost link");
    let out = wait_for(Duration::from_secs(5), || {
        let out = ack(&[]);
        latched(&out).then_some(out)
    })
    .unwrap_or_else(|| panic!("stop #1 never showed as latched:\n{}", text(&ack(&[]))));
    // Without a terminal to confirm at, the stop must be named.
    assert!(!out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--clears 1"),
        "{}",
        text(&out)
    );

    // SIGUSR1 from a process of the same user clears nothing.
    let pid = rt.child.id().to_string();
    for _ in 0..3 {
        let st = Command::new("kill").args(["-USR1", &pid]).status().unwrap();
        assert!(st.success());
        std::thread::sleep(Duration::from_millis(100));
    }
    wait_log("SIGUSR1 ignored", 5);
    std::thread::sleep(Duration::from_millis(300));
    let out = ack(&[]);
    assert!(latched(&out), "SIGUSR1 cleared the stop:\n{}", text(&out));

    // Another user is no operator of this rt-core (checked where the test may switch users).
    if running_as_root() && Path::new("/usr/bin/setpriv").exists() {
        let out = Command::new("/usr/bin/setpriv")
            .args(["--reuid=65534", "--regid=65534", "--clear-groups"])
            .arg(bin_path("rt-core"))
            .args(["ack", "--robot", &robot, "--clears", "1"])
            .stdin(Stdio::null())
            .output()
            .unwrap();
        assert!(!out.status.success(), "{}", text(&out));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("uid 65534 is not an operator"),
            "{}",
            text(&out)
        );
        assert!(latched(&ack(&[])), "a non-operator cleared the stop");
    } else {
        eprintln!("not root or no setpriv: the other-user refusal is left to the library test");
    }

    // Naming another stop clears nothing; naming this one clears it.
    let out = ack(&["--clears", "2"]);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("you named stop #2"),
        "{}",
        text(&out)
    );
    assert!(latched(&ack(&[])));
    let out = ack(&["--clears", "1"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("cleared stop #1 (lost link"),
        "{}",
        text(&out)
    );
    wait_log("operator acknowledgement: clearing", 5);
    let out = ack(&["--clears", "1"]);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no protective stop is latched"),
        "{}",
        text(&out)
    );

    let status = rt.interrupt_and_wait(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "rt-core stops cleanly: {status:?}\n{}",
        read(&log)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
