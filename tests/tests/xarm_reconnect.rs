//! `rt-core run` rides out a controller restart: `xarm-sim` is killed under a running
//! `rt-core run --link xarm` and started again on the same ports. The cycle keeps running
//! while the link is down (the reconnect happens on a helper thread), the link comes back,
//! the cycle streams hold targets to the new controller again, and nothing in the cycle
//! allocated. Needs the workspace's binaries built (`cargo build --release --workspace --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::time::Duration;

use foresight_tests::sim_proc::SimProc;
use foresight_tests::{ChildGuard, unique_prefix, wait_for};

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

#[test]
fn rt_core_run_rides_out_a_controller_restart() {
    let dir = std::env::temp_dir().join(unique_prefix("xarm_reconnect"));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let log = dir.join("rt-core.log");
    let mut sim = SimProc::start([0; 6], &[]);
    let ports = sim.ports;

    // A simulated controller: servo mode comes back after the reconnect without an
    // operator's acknowledgement (a real arm waits for one). `--auto-resume` is granted
    // only to a controller that proves it is xarm-sim holding the run's secret, at connect
    // and at every reconnect.
    let mut rt = ChildGuard::spawn("rt-core", &mut sim.rt_core_run(&["--auto-resume"], &log));
    let wait_log = |needle: &str, secs: u64| {
        wait_for(Duration::from_secs(secs), || {
            read(&log).contains(needle).then_some(())
        })
        .unwrap_or_else(|| panic!("no {needle:?} in the rt-core log:\n{}", read(&log)));
    };
    wait_log("iceoryx2 node up", 30);
    std::thread::sleep(Duration::from_millis(500));

    // The controller dies (power cut, crash): the cycle stops commanding and keeps running.
    let _ = sim.guard.child.kill();
    let _ = sim.guard.child.wait();
    wait_log("reconnecting off the cycle", 10);
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        matches!(rt.child.try_wait(), Ok(None)),
        "rt-core must survive a lost controller:\n{}",
        read(&log)
    );

    // The controller comes back on the same ports, with the run's secret (an xarm-sim
    // without it would be a real arm: rt-core would not reconnect to it on its own).
    let sim2 = SimProc::start_with_secret(ports, &[], sim.secret.clone());
    wait_log("xArm link re-established", 20);
    std::thread::sleep(Duration::from_millis(500));

    let status = rt.interrupt_and_wait(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "rt-core stops cleanly: {status:?}\n{}",
        read(&log)
    );
    let mut stdout = String::new();
    let _ = std::io::Read::read_to_string(
        rt.child.stdout.as_mut().expect("rt-core stdout"),
        &mut stdout,
    );
    let summary: serde_json::Value = stdout
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or_else(|| panic!("no JSON summary from rt-core: {stdout}"));
    assert_eq!(summary["allocations_in_cycle"], 0, "{summary}");
    assert!(summary["cycles"].as_u64().unwrap_or(0) > 0, "{summary}");

    // The new controller got the cycle's hold targets after the reconnect.
    let sim_summary = sim2.finish();
    assert!(
        sim_summary["counters"]["servo_accepted"]
            .as_u64()
            .unwrap_or(0)
            > 0,
        "{sim_summary}"
    );
    assert_eq!(sim_summary["collisions"], 0, "{sim_summary}");
    let _ = std::fs::remove_dir_all(&dir);
}
