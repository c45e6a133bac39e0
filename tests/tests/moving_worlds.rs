//! Moving boxes through the real processes (`foresight` starting `xarm-sim`, `perception`,
//! `learner serve` and `rt-core run`): a box crosses the arm's way while it moves, and a box
//! stands on the arm's way for a second and leaves. Each world's scene files say what it
//! exercises (`assets/scenes/crossing_world.toml`, `assets/scenes/stop_on_the_way_world.toml`).
//!
//! The tests assert outcomes, never times: the simulated arm's referee saw no contact while
//! the arm moved, the arm really reacted to the box (a `paused` line in the timeline, a stop
//! for an obstacle, after the box set off), it moved on after the pause, and it reached the
//! moving scene's goal after the box had come to rest for good (the continuation).
//! Needs the workspace's binaries built (`cargo build --release --workspace --bins`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use foresight_tests::runs::{LogsOnFailure, newest_run, scratch_dir};
use foresight_tests::{ChildGuard, bin_path, repo_root};

/// One whole system at a time: two of them at once on two cores would measure the machine,
/// not the product.
static ONE_SYSTEM_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_SYSTEM_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Runs `foresight` on `world` (relative to the repository root) to its end; returns the
/// exit code and the run folder.
fn run_world(out: &Path, world: &str) -> (i32, PathBuf) {
    let mut cmd = Command::new(bin_path("foresight"));
    cmd.current_dir(repo_root())
        .args(["--world", world])
        .args(["--phase-timeout-s", "40"])
        .args(["--retrain-budget-s", "30"])
        .arg("--out")
        .arg(out)
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit());
    let mut guard = ChildGuard::spawn("foresight", &mut cmd);
    let code = guard.wait_exit(Duration::from_secs(180));
    (code, newest_run(out).expect("a run folder"))
}

fn summary(run: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(run.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("summary.json is JSON")
}

/// The timeline's `(kind, detail)` lines, in order.
fn timeline(run: &Path) -> Vec<(String, String)> {
    std::fs::read_to_string(run.join("timeline.jsonl"))
        .expect("timeline.jsonl")
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .map(|v| {
            (
                v["kind"].as_str().unwrap_or_default().to_owned(),
                v["detail"].as_str().unwrap_or_default().to_owned(),
            )
        })
        .collect()
}

/// Runs `world` (a still first scene, then one with a moving box) and checks the outcome:
/// no contact while the arm moved, a pause for the box, the arm moving on, and the moving
/// scene's goal reached after the box came to rest for good.
fn the_arm_pauses_for_the_box_and_reaches_the_goal(test: &str, world: &str) {
    let _one = one_at_a_time();
    let out = scratch_dir("moving", test);
    let _logs = LogsOnFailure {
        runs: out.to_path_buf(),
        extra: Vec::new(),
    };
    let (code, run) = run_world(&out, world);
    let s = summary(&run);
    let events = timeline(&run);
    let kinds: Vec<&str> = events.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(code, 0, "foresight exit code; summary: {s}");
    assert_eq!(s["referee"]["contacts_while_moving"], 0, "{s}");
    // The launcher's own separation curve (the datasheet arm against the true boxes) agrees:
    // the arm never touched a box, moving or at rest, and the report plots it.
    for key in ["min_separation_moving_m", "min_separation_at_rest_m"] {
        assert!(
            s[key].as_f64().is_some_and(|d| d > 0.0),
            "{key} missing or not positive: {s}"
        );
    }
    assert!(run.join("separation.png").is_file(), "no separation.png");
    assert_eq!(s["referee"]["contacts"], 0, "{s}");
    assert_eq!(s["collisions"], 0, "{s}");
    assert_eq!(s["goal_reached"], true, "{s}");
    assert_eq!(s["outcome"], "reached", "{s}");
    assert!(!kinds.contains(&"timeout"), "a phase timed out: {kinds:?}");
    // The reaction: the arm stopped for an obstacle after the box set off in the moving scene.
    let change = kinds
        .iter()
        .rposition(|k| *k == "world_change")
        .expect("the world changed to the moving scene");
    let box_moves = change
        + kinds[change..]
            .iter()
            .position(|k| *k == "obstacle_moves")
            .expect("the box set off");
    let paused = box_moves
        + kinds[box_moves..]
            .iter()
            .position(|k| *k == "paused")
            .unwrap_or_else(|| panic!("the arm never paused for the box: {kinds:?}"));
    assert!(s["pauses"].as_u64().unwrap_or(0) >= 1, "{s}");
    // rt-core measured that reaction from the causing camera frame's capture to the changed
    // command (the figure itself is a benchmark's: README "Results").
    assert!(s["reaction"]["reactions"].as_u64().unwrap_or(0) >= 1, "{s}");
    assert!(
        s["reaction"]["capture_to_command_us"]["max"]
            .as_f64()
            .is_some_and(|us| us > 0.0),
        "{s}"
    );
    // The continuation: the arm moved on, and reached the goal after the box came to rest
    // for good.
    assert!(
        kinds[paused..].contains(&"resumed"),
        "the arm never moved on after its pause: {kinds:?}"
    );
    let goal = kinds
        .iter()
        .rposition(|k| *k == "goal_reached")
        .expect("goal_reached");
    assert!(
        events[goal].1.starts_with("goal 1 "),
        "the last goal reached is not the moving scene's: {events:?}"
    );
    let box_rests = kinds
        .iter()
        .rposition(|k| *k == "obstacle_stops")
        .expect("the box came to rest");
    assert!(
        paused < goal && box_rests < goal,
        "the goal was not reached after the pause and the box's rest: {kinds:?}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_box_crossing_the_way_pauses_the_arm_without_contact_and_the_arm_goes_on() {
    the_arm_pauses_for_the_box_and_reaches_the_goal(
        "crossing",
        "assets/scenes/crossing_world.toml",
    );
}

#[test]
fn a_box_standing_on_the_way_holds_the_arm_until_it_leaves() {
    the_arm_pauses_for_the_box_and_reaches_the_goal(
        "stop-on-the-way",
        "assets/scenes/stop_on_the_way_world.toml",
    );
}
