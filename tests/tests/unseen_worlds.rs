//! Unseen worlds through the whole product (`foresight` with the real processes on the
//! simulated arm), the short version of the README's unseen-worlds benchmark:
//!
//! - a world script with an infeasible scene in the middle (`assets/scenes/
//!   infeasible_world.toml`): the learner's feasibility check refuses it with the reason,
//!   the arm is held (it never moves toward that goal), `summary.json` says `outcome =
//!   "infeasible"` with the blocking box named, and the next scene is reached;
//! - `--runs 3 --worlds random`: three random worlds of the task's `[world]`, each reached
//!   or refused as infeasible, no collision, and the benchmark's table, JSON and plot.
//!
//! Outcomes are asserted, not times. Needs the workspace's binaries built.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use foresight_tests::runs::{LogsOnFailure, newest_run, scratch_dir};
use foresight_tests::{ChildGuard, bin_path, repo_root};

/// One whole system at a time (two cores).
static ONE_SYSTEM_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_SYSTEM_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Runs `foresight` with `args` from the repository root until it exits (at most `limit`);
/// returns the exit code.
fn run_foresight(out: &Path, args: &[&str], limit: Duration) -> i32 {
    let mut cmd = Command::new(bin_path("foresight"));
    cmd.current_dir(repo_root())
        .args(["--phase-timeout-s", "60", "--retrain-budget-s", "40"])
        .arg("--out")
        .arg(out)
        .args(args)
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit());
    ChildGuard::spawn("foresight", &mut cmd).wait_exit(limit)
}

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).expect("JSON")
}

fn logs(out: &Path) -> LogsOnFailure {
    LogsOnFailure {
        runs: out.to_path_buf(),
        extra: Vec::new(),
    }
}

#[test]
fn an_infeasible_world_is_refused_with_its_reason_and_the_arm_is_held() {
    let _one = one_at_a_time();
    let out = scratch_dir("worlds", "infeasible");
    let _logs = logs(&out);
    let code = run_foresight(
        &out,
        &["--world", "assets/scenes/infeasible_world.toml"],
        Duration::from_secs(300),
    );
    let run = newest_run(&out).expect("a run folder");
    let s = json(&run.join("summary.json"));
    assert_eq!(s["collisions"], 0, "{s}");
    assert_eq!(s["arm_rejected_commands"], 0, "{s}");
    // The last scene (the small box again) is reached after the refusal.
    assert_eq!(s["goal_reached"], true, "{s}");
    assert_eq!(s["outcome"], "infeasible", "{s}");
    let reason = s["outcome_reason"].as_str().unwrap_or("");
    assert!(
        reason.contains("scene 1") && reason.contains("box 0"),
        "the reason names the scene and the blocking box: {reason}"
    );
    assert_ne!(
        code, 0,
        "a world with an infeasible goal is not a success: {s}"
    );
    let timeline = std::fs::read_to_string(run.join("timeline.jsonl")).expect("timeline");
    let events: Vec<serde_json::Value> = timeline
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    let kind_at = |k: &str| events.iter().position(|e| e["kind"] == k);
    let change = events
        .iter()
        .position(|e| {
            e["kind"] == "world_change"
                && e["detail"].as_str().is_some_and(|d| d.contains("scene 1"))
        })
        .expect("the world changes to the infeasible scene");
    // rt-core says it at once (`goal_taken`, "infeasible: <reason>", issue 42 item 4): the box
    // blocks every goal posture, so the learner is not asked (before, its answer was the
    // timeline's `infeasible`).
    let refused = kind_at("goal_taken").expect("a goal_taken event");
    assert!(change < refused, "{timeline}");
    // Between the change to scene 1 and the change to scene 2 the arm does not move.
    let next_change = events
        .iter()
        .position(|e| {
            e["kind"] == "world_change"
                && e["detail"].as_str().is_some_and(|d| d.contains("scene 2"))
        })
        .expect("the world goes on to scene 2");
    assert!(
        !events[change..next_change]
            .iter()
            .any(|e| e["kind"] == "motion"),
        "the arm moved in the infeasible scene: {timeline}"
    );
    assert!(
        !events[change..next_change]
            .iter()
            .any(|e| e["kind"] == "retrain_progress"
                && e["detail"].as_str().is_some_and(|d| d.contains("Training"))),
        "the learner trained on the infeasible scene: {timeline}"
    );
    let report = std::fs::read_to_string(run.join("report.md")).expect("report.md");
    assert!(report.contains("no safe way found"), "{report}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn random_unseen_worlds_are_reached_or_refused_without_collision() {
    let _one = one_at_a_time();
    let out = scratch_dir("worlds", "random");
    let _logs = logs(&out);
    let code = run_foresight(
        &out,
        &["--runs", "3", "--seed", "11", "--worlds", "random"],
        Duration::from_secs(600),
    );
    let bench = out.join("worlds-seed11");
    let j = json(&bench.join("worlds.json"));
    assert_eq!(code, 0, "{j}");
    let worlds = j["worlds"].as_array().expect("worlds");
    assert_eq!(worlds.len(), 3, "{j}");
    for w in worlds {
        assert!(
            w["outcome"] == "reached" || w["outcome"] == "infeasible",
            "{w}"
        );
        assert_eq!(w["collisions"], 0, "{w}");
    }
    assert_eq!(j["aggregate"]["collisions"], 0, "{j}");
    let md = std::fs::read_to_string(bench.join("worlds.md")).expect("worlds.md");
    assert_eq!(
        md.lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| #"))
            .count(),
        3,
        "{md}"
    );
    assert!(std::fs::metadata(bench.join("worlds.png")).is_ok_and(|m| m.len() > 1000));
    let _ = std::fs::remove_dir_all(&out);
}
