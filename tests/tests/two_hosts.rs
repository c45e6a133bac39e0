//! The learner on another host, on one machine: two network namespaces joined by a veth
//! pair stand for the robot PC and the GPU box. The robot side runs `foresight
//! --learner-host` (xarm-sim, perception, rt-core and the controller relay, no learner); the
//! learner side runs `zenoh-relay learner-host` (`learner serve` plus the learner relay)
//! listening on its veth address only. Shared memory is common to both namespaces, so the
//! two sides use different iceoryx2 prefixes: the only way across is Zenoh over the veth.
//!
//! The two sides authenticate each other with keys made by `zenoh-relay keygen` (one folder
//! per side): each relay's gate makes the other prove its host key before Zenoh sees the
//! connection, then every message is signed. The run must see no refusal of a message, and
//! (without a link cut) no connection refused at either gate.
//!
//! The namespaces are made with `ip netns` as root and removed at the end; without the
//! permission the tests say so and return (CI runs as root). Nothing leaves the machine:
//! endpoints are the veth's private addresses and multicast scouting is off.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Stdio;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use foresight_tests::runs::{LogsOnFailure, newest_run, scratch_dir};
use foresight_tests::veth::TwoHosts;
use foresight_tests::{ChildGuard, bin_path};

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn json(path: &Path) -> Option<serde_json::Value> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// The demo's fast world across two hosts; `during_retraining` runs once the learner
/// host has started answering the first retrain request. With `clean_gates`, neither relay's
/// gate may have refused a connection (a cut link can time a handshake out). Returns the
/// summary.
fn two_host_run(
    tag: &str,
    clean_gates: bool,
    during_retraining: impl FnOnce(&TwoHosts),
) -> Option<serde_json::Value> {
    let hosts = match TwoHosts::make(tag) {
        Ok(h) => h,
        Err(why) => {
            println!(
                "SKIPPED: cannot make two network namespaces here ({why}); this test needs root \
                 (ip netns) and runs in CI"
            );
            return None;
        }
    };
    let dir = scratch_dir("two-hosts", tag);
    let _logs = LogsOnFailure {
        runs: dir.join("runs"),
        extra: vec![dir.join("learner-host.log")],
    };
    let port = "7447";
    // The link's keys, made once as a user would; each side gets its own folder.
    let keys = dir.join("keys");
    let keygen = std::process::Command::new(bin_path("zenoh-relay"))
        .arg("keygen")
        .arg("--out")
        .arg(&keys)
        .output()
        .expect("zenoh-relay keygen");
    assert!(keygen.status.success(), "zenoh-relay keygen: {keygen:?}");
    let learner_log = std::fs::File::create(dir.join("learner-host.log")).expect("log file");
    let mut learner_cmd = hosts.exec(&hosts.learner_ns, &bin_path("zenoh-relay"));
    learner_cmd
        .args(["learner-host", "--listen"])
        .arg(format!("tcp/{}:{port}", hosts.learner_addr))
        .arg("--status")
        .arg(dir.join("learner-relay.json"))
        .arg("--link-keys")
        .arg(keys.join("learner-host"))
        .arg("--out")
        .arg(dir.join("learner-runs"))
        .args(["--time-budget-s", "40"])
        .stdout(learner_log.try_clone().expect("log file"))
        .stderr(learner_log);
    let _learner = ChildGuard::spawn("zenoh-relay learner-host", &mut learner_cmd);

    let out = dir.join("runs");
    let mut robot_cmd = hosts.exec(&hosts.robot_ns, &bin_path("foresight"));
    robot_cmd
        .args(["--world", "assets/scenes/fast_world.toml"])
        .args(["--phase-timeout-s", "60", "--retrain-budget-s", "40"])
        // The retraining link is what these tests exercise: the arm waits for the retrained
        // policy (with the default planner fallback it would reach the goal without it).
        .args(["--planner-fallback", "off"])
        .arg("--learner-host")
        .arg("--peer")
        .arg(format!("tcp/{}:{port}", hosts.learner_addr))
        .arg("--link-keys")
        .arg(keys.join("robot-pc"))
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::inherit());
    let mut robot = ChildGuard::spawn("foresight --learner-host", &mut robot_cmd);

    let deadline = Instant::now() + Duration::from_secs(300);
    let mut hook = Some(during_retraining);
    let code = loop {
        if let Some(status) = robot.child.try_wait().expect("waiting for foresight") {
            break status.code().unwrap_or(-1);
        }
        assert!(
            Instant::now() < deadline,
            "foresight did not finish in time"
        );
        if hook.is_some()
            && let Some(st) = newest_run(&out).and_then(|r| json(&r.join("relay.json")))
            && st["requests"][0]["first_progress_unix_s"].is_number()
            && let Some(f) = hook.take()
        {
            f(&hosts);
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(hook.is_none(), "the learner host never started retraining");
    let run = newest_run(&out).expect("a run folder");
    let s = json(&run.join("summary.json")).expect("summary.json");
    assert_eq!(code, 0, "foresight exit code; summary: {s}");
    assert_eq!(s["goal_reached"], true, "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    assert_eq!(s["arm_rejected_commands"], 0, "{s}");
    assert!(s["policy_swaps"].as_u64().unwrap_or(0) >= 1, "{s}");
    let remote = &s["remote_learner"];
    assert!(
        remote["host"].as_str().is_some_and(|h| !h.is_empty()),
        "the learner host was heard from: {s}"
    );
    assert!(remote["answered"].as_u64().unwrap_or(0) >= 1, "{s}");
    assert_eq!(remote["rejected"], 0, "{s}");
    // No learner ran on the robot side: every policy came over the link.
    assert!(
        !run.join("logs/learner.log").exists(),
        "a learner was started on the robot side"
    );
    let report = std::fs::read_to_string(run.join("report.md")).expect("report.md");
    assert!(report.contains("remote learner"), "{report}");
    // The gates: what each relay refused at its door or dialler.
    for (side, path) in [
        ("robot PC", run.join("relay.json")),
        ("learner host", dir.join("learner-relay.json")),
    ] {
        let st = json(&path).expect("relay status");
        let refused = &st["refused_connections"];
        println!("{side}: connections refused at the gate: {refused}");
        if clean_gates {
            assert!(
                refused.as_object().is_none_or(|m| m.is_empty()),
                "{side} refused a connection of the other relay: {refused}; the last: {}",
                st["last_connection_refusal"]
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    Some(s)
}

#[test]
fn a_retrain_request_crosses_to_the_learner_host_and_its_policy_brings_the_arm_to_the_goal() {
    let _one = one_at_a_time();
    let Some(s) = two_host_run("a", true, |_| {}) else {
        return;
    };
    println!(
        "two hosts: world change → motion {} s, retraining {} s, {}",
        s["world_change_to_motion_s"], s["retrain_s"], s["remote_learner"]
    );
}

#[test]
fn the_link_cut_for_5_s_during_retraining_still_ends_at_the_goal() {
    let _one = one_at_a_time();
    let Some(s) = two_host_run("b", false, |hosts| {
        hosts.link(false);
        std::thread::sleep(Duration::from_secs(5));
        hosts.link(true);
    }) else {
        return;
    };
    let remote = &s["remote_learner"];
    assert!(
        remote["link_losses"].as_u64().unwrap_or(0) >= 1,
        "the cut was noticed: {s}"
    );
    assert!(remote["link_down_s"].as_f64().unwrap_or(0.0) >= 2.0, "{s}");
}
