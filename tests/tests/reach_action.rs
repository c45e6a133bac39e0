//! The ROS 2 `Reach` action end to end (issue 32 item 1): `foresight --ros --goal-source
//! action` starts the real processes (`xarm-sim`, `perception`, `learner serve`, `rt-core
//! run`, `ros-bridge`) on `assets/scenes/reach_action_world.toml` (a wall in front of
//! (0.0, 0.42)), and separate `foresight reach` processes drive the action as DDS clients:
//!
//! - a goal out of bounds is refused, naming the bound;
//! - a feasible goal ends `reached`;
//! - a goal behind the wall ends `infeasible` with the feasibility check's reason;
//! - a cancelled goal ends `cancelled` (rt-core revoked its plan: the arm stopped on the
//!   way), and the arm's reported joint velocities are then zero;
//! - the run's summary.json says the goal came from the action.
//!
//! A second test drives the real `ros-bridge` alone, with the test standing in for rt-core
//! on shared memory (it publishes the robot state): a newer goal pre-empts the running one,
//! whose result says so, and rt-core is sent a cancel of it; each accepted goal reaches
//! rt-core as an iceoryx2 `GoalRequest` (a reach, then a cancel, or a release once reached).
//!
//! A third drives the real `ros-bridge` the same way and answers its reach request as
//! rt-core answers one that reached it too old (a `GoalRefusal`): the goal, which has no
//! deadline, ends at once, refused (aborted), naming the age and the bound.
//!
//! Everything runs inside a private network namespace (DDS stays there). The test asserts
//! outcomes, never times (the limits only stop a hung run). Needs the binaries built
//! (`cargo build --release -p launcher -p rt-core -p ros-bridge -p perception -p learner
//! -p xarm-sim`).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use foresight_tests::runs::{newest_run, scratch_dir};
use foresight_tests::{
    ChildGuard, NetnsOutcome, asset, bin_path, repo_root, run_in_private_netns, unique_prefix,
};
use iceoryx2::prelude::*;
use ros_bridge::reach_client::{ReachClientOptions, ReachEnd, ReachEvent};
use ros_bridge::reach_msgs::{ReachGoal, ReachOutcome};
use shm_schemas::{
    GoalCommand, GoalRefusal, GoalRequest, GoalRequestAgeError, RobotState, services,
};

/// Runs `foresight reach <args>` to its end; returns its exit code and stdout.
fn reach(args: &[&str]) -> (i32, String) {
    let mut guard = ChildGuard::spawn(
        "foresight reach",
        Command::new(bin_path("foresight"))
            .current_dir(repo_root())
            .arg("reach")
            .args(args)
            .args(["--connect-timeout-s", "120"])
            .stdout(Stdio::piped()),
    );
    let stdout = guard.child.stdout.take().unwrap();
    let lines = std::thread::spawn(move || {
        BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
            .inspect(|l| println!("  [reach] {l}"))
            .collect::<Vec<_>>()
            .join("\n")
    });
    let code = guard.wait_exit(Duration::from_secs(240));
    (code, lines.join().unwrap())
}

/// The latest robot state of the run under `prefix`, once one arrives.
fn latest_state(prefix: &str) -> RobotState {
    let (node, _cleanup) = services::create_node::<ipc::Service>("reach-action-test").unwrap();
    let sub = services::open_subscriber::<RobotState, _>(&node, prefix).unwrap();
    let mut latest = None;
    for _ in 0..500 {
        while let Ok(Some(s)) = sub.receive() {
            latest = Some(*s);
        }
        if latest.is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    latest.expect("a robot state from rt-core")
}

#[test]
fn the_reach_action_reaches_refuses_reports_infeasible_and_cancels() {
    if run_in_private_netns("the_reach_action_reaches_refuses_reports_infeasible_and_cancels")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let out = scratch_dir("runs", "reach_action");
    let mut foresight = ChildGuard::spawn(
        "foresight",
        Command::new(bin_path("foresight"))
            .current_dir(repo_root())
            .args(["--world", "assets/scenes/reach_action_world.toml"])
            .args(["--ros", "--goal-source", "action", "--no-record"])
            .args(["--phase-timeout-s", "3000"])
            .arg("--out")
            .arg(&out)
            .stdout(Stdio::piped()),
    );
    let stdout = foresight.child.stdout.take().unwrap();
    let printed = Arc::new(Mutex::new(Vec::<String>::new()));
    {
        let printed = printed.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(stdout).lines().map_while(Result::ok) {
                println!("[foresight] {l}");
                printed.lock().unwrap().push(l);
            }
        });
    }

    // Out of bounds: refused, naming the bound (no arm needed for that).
    let (code, text) = reach(&["--goal", "0.9,0.0"]);
    assert_eq!(code, 7, "refused: {text}");
    assert!(text.contains("result: refused"), "{text}");
    assert!(text.contains("intake.goal_max_radius_m"), "{text}");

    // A feasible goal on the clear half of the table.
    let (code, text) = reach(&["--goal", "0.30,-0.20"]);
    assert_eq!(code, 0, "reached: {text}");
    assert!(text.contains("result: reached"), "{text}");

    // Behind the wall: infeasible, with the feasibility check's reason.
    let (code, text) = reach(&["--goal", "0.0,0.42"]);
    assert_eq!(code, 3, "infeasible: {text}");
    assert!(text.contains("result: infeasible"), "{text}");
    assert!(
        text.contains("no safe goal posture") || text.contains("no collision-free path"),
        "the reason is given: {text}"
    );

    // Cancelled on the way: ends cancelled, the arm at rest.
    let (code, text) = reach(&["--goal", "0.35,0.15", "--cancel-after-s", "0.5"]);
    assert_eq!(code, 5, "cancelled: {text}");
    assert!(text.contains("result: cancelled"), "{text}");
    // The result says where the arm was when the cancel took effect, and how close to the
    // target it came afterwards (issue 41, item 1).
    assert!(
        text.contains("cancelled with the TCP at (")
            && text.contains("closest to the target afterwards"),
        "the result says where the cancel took effect: {text}"
    );
    let prefix = printed
        .lock()
        .unwrap()
        .iter()
        .find_map(|l| l.split("service prefix ").nth(1).map(str::to_owned))
        .expect("foresight prints its service prefix");
    let state = latest_state(prefix.trim());
    let fastest = state
        .joint_velocities_rad_s
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        fastest < 0.01,
        "the arm is at rest after the cancel: {state:?}"
    );

    // An orderly stop; the summary names the goal's source.
    assert!(
        foresight
            .interrupt_and_wait(Duration::from_secs(120))
            .is_some(),
        "foresight stops on SIGINT"
    );
    let run = newest_run(&out).expect("a run folder");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["goal_source"], "action", "{summary}");
    // The cancel stopped the plan under way (rt-core revoked it), not merely waited for it.
    let rt_log = std::fs::read_to_string(run.join("logs/rt-core.log")).unwrap();
    assert!(
        rt_log.contains("StopBegun { reason: Revoked }"),
        "rt-core revoked the cancelled goal's plan"
    );
}

/// Issue 41 item 1, through the real processes: a goal behind the demo's wide tall box (the
/// planner must search), cancelled 0.1 s after its acceptance. Before, the cancel reached the
/// twin thread after its planning and revoked only a plan the cycle followed: a plan made
/// while the cancel came was adopted after it, the arm drove to the cancelled target and the
/// client was told "cancelled". Now the TCP never comes within 5 cm of the cancelled target.
/// The race itself (a cancel landing inside a planning of a few ms) is not hit on every run
/// here; `rt-core/tests/runtime/goal_cancel.rs` places it deterministically.
#[test]
fn a_cancel_while_the_plan_is_made_never_drives_toward_the_cancelled_target() {
    if run_in_private_netns(
        "a_cancel_while_the_plan_is_made_never_drives_toward_the_cancelled_target",
    ) == NetnsOutcome::RanInChild
    {
        return;
    }
    let out = scratch_dir("runs", "reach_cancel");
    let mut foresight = ChildGuard::spawn(
        "foresight",
        Command::new(bin_path("foresight"))
            .current_dir(repo_root())
            .args(["--world", "assets/scenes/reach_cancel_world.toml"])
            .args(["--ros", "--goal-source", "action", "--no-record"])
            .args(["--phase-timeout-s", "3000"])
            .arg("--out")
            .arg(&out)
            .stdout(Stdio::piped()),
    );
    let stdout = foresight.child.stdout.take().unwrap();
    let (prefix_tx, prefix_rx) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            println!("[foresight] {l}");
            if let Some(p) = l.split("service prefix ").nth(1) {
                let _ = prefix_tx.send(p.trim().to_owned());
            }
        }
    });
    let prefix = prefix_rx
        .recv_timeout(Duration::from_secs(240))
        .expect("foresight prints its service prefix");
    // The TCP's closest approach to the target (0.05 m cube on the table, 0.05 m hover).
    let target_m = [0.28, -0.28, 0.10];
    let closest_m = Arc::new(Mutex::new(f64::INFINITY));
    let watching = Arc::new(AtomicBool::new(true));
    let watcher = {
        let (closest_m, watching, prefix) = (closest_m.clone(), watching.clone(), prefix.clone());
        std::thread::spawn(move || {
            let (node, _cleanup) =
                services::create_node::<ipc::Service>("reach-cancel-test").unwrap();
            let sub = services::open_subscriber::<RobotState, _>(&node, &prefix).unwrap();
            while watching.load(Ordering::Relaxed) {
                while let Ok(Some(s)) = sub.receive() {
                    let d = (0..3)
                        .map(|k| (s.tcp_m[k] - target_m[k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    let mut c = closest_m.lock().unwrap();
                    *c = c.min(d);
                }
                std::thread::sleep(Duration::from_millis(2));
            }
        })
    };
    let (code, text) = reach(&["--goal", "0.28,-0.28", "--cancel-after-s", "0.1"]);
    assert_eq!(code, 5, "cancelled: {text}");
    assert!(text.contains("result: cancelled"), "{text}");
    // Long enough for a plan adopted after the cancel to have reached the target (3.6 s in
    // the reproduction).
    std::thread::sleep(Duration::from_secs(6));
    watching.store(false, Ordering::Relaxed);
    watcher.join().unwrap();
    let closest_m = *closest_m.lock().unwrap();
    assert!(
        closest_m >= 0.05,
        "the TCP came {closest_m:.3} m from the cancelled target"
    );
    // The result's own figure agrees: after the cancel the TCP stayed 5 cm away.
    let reported_m: f64 = text
        .split("closest to the target afterwards ")
        .nth(1)
        .and_then(|rest| rest.split(" m").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("the result gives the closest approach: {text}"));
    assert!(reported_m >= 0.05, "the result says {reported_m} m: {text}");
    assert!(
        foresight
            .interrupt_and_wait(Duration::from_secs(120))
            .is_some(),
        "foresight stops on SIGINT"
    );
}

/// What the stand-in for rt-core publishes: the TCP and whether the arm moves.
struct FakeArm {
    tcp_m: Mutex<[f64; 3]>,
    moving: AtomicBool,
    stop: AtomicBool,
}

/// Publishes a robot state every 10 ms from `arm` until told to stop.
fn publish_states(prefix: String, arm: Arc<FakeArm>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let (node, _cleanup) = services::create_node::<ipc::Service>("reach-fake-arm").unwrap();
        let publisher = services::open_publisher::<RobotState, _>(&node, &prefix).unwrap();
        while !arm.stop.load(Ordering::Relaxed) {
            let v = if arm.moving.load(Ordering::Relaxed) {
                0.5
            } else {
                0.0
            };
            let state = RobotState {
                time_ns: shm_schemas::clock::monotonic_now_ns(),
                joint_velocities_rad_s: [v; 5],
                tcp_m: *arm.tcp_m.lock().unwrap(),
                link_ok: 1,
                ..Default::default()
            };
            publisher.send_copy(state).unwrap();
            std::thread::sleep(Duration::from_millis(10));
        }
    })
}

/// Runs one client in a thread: its events go to the returned channel, its end to the
/// handle.
fn client(
    goal: ReachGoal,
    interrupt: Arc<AtomicBool>,
) -> (
    mpsc::Receiver<ReachEvent>,
    std::thread::JoinHandle<ReachEnd>,
) {
    let (tx, rx) = mpsc::channel();
    let handle = std::thread::spawn(move || {
        let opts = ReachClientOptions {
            domain_id: 0,
            networks: vec![std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST)],
            connect_timeout: Duration::from_secs(60),
            cancel_after: None,
        };
        ros_bridge::reach_client::reach(goal, &opts, &interrupt, |e| {
            let _ = tx.send(e.clone());
        })
        .unwrap()
    });
    (rx, handle)
}

fn wait_accepted(events: &mpsc::Receiver<ReachEvent>) {
    let first = events
        .iter()
        .find(|e| matches!(e, ReachEvent::Accepted | ReachEvent::Rejected));
    assert_eq!(first, Some(ReachEvent::Accepted));
}

#[test]
fn the_bridge_preempts_cancels_and_releases_goals_and_tells_rt_core() {
    if run_in_private_netns("the_bridge_preempts_cancels_and_releases_goals_and_tells_rt_core")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let prefix = unique_prefix("reach");
    let (node, _cleanup) = services::create_node::<ipc::Service>("reach-test").unwrap();
    let requests = services::open_subscriber::<GoalRequest, _>(&node, &prefix).unwrap();
    let arm = Arc::new(FakeArm {
        tcp_m: Mutex::new([0.3, 0.0, 0.3]),
        moving: AtomicBool::new(true),
        stop: AtomicBool::new(false),
    });
    let states = publish_states(prefix.clone(), arm.clone());
    let _bridge = ChildGuard::spawn(
        "ros-bridge",
        Command::new(bin_path("ros-bridge"))
            .current_dir(repo_root())
            .args([
                "--prefix",
                &prefix,
                "--goal-source",
                "action",
                "--seconds",
                "200",
            ])
            .args(["--urdf", asset("xarm5.urdf").to_str().unwrap()])
            .stdout(Stdio::null()),
    );
    let mut seen: Vec<GoalRequest> = Vec::new();
    let take_requests = |seen: &mut Vec<GoalRequest>| {
        while let Ok(Some(r)) = requests.receive() {
            r.validate().unwrap();
            seen.push(*r);
        }
    };

    // A goal, then a newer one: the first ends pre-empted, naming the newer goal.
    let goal_a = ReachGoal {
        x_m: 0.35,
        y_m: 0.15,
        ..ReachGoal::default()
    };
    let (events_a, a) = client(goal_a, Arc::new(AtomicBool::new(false)));
    wait_accepted(&events_a);
    let cancel_b = Arc::new(AtomicBool::new(false));
    let (events_b, b) = client(
        ReachGoal {
            x_m: 0.30,
            y_m: -0.20,
            ..ReachGoal::default()
        },
        cancel_b.clone(),
    );
    wait_accepted(&events_b);
    let end_a = a.join().unwrap();
    assert_eq!(
        end_a.result.outcome(),
        Some(ReachOutcome::Preempted),
        "{end_a:?}"
    );
    assert!(end_a.result.reason.contains("newer goal"), "{end_a:?}");

    // The newer goal cancelled: it ends only once the arm is at rest.
    cancel_b.store(true, Ordering::Relaxed);
    assert!(
        events_b.iter().any(|e| matches!(e, ReachEvent::Cancelling)),
        "the client asked for the cancel"
    );
    arm.moving.store(false, Ordering::Relaxed);
    let end_b = b.join().unwrap();
    assert_eq!(
        end_b.result.outcome(),
        Some(ReachOutcome::Cancelled),
        "{end_b:?}"
    );

    // A goal reached: the TCP at its target (0.05 m cube, 0.05 m hover: 0.10 m up).
    *arm.tcp_m.lock().unwrap() = [0.30, 0.20, 0.10];
    let (events_c, c) = client(
        ReachGoal {
            x_m: 0.30,
            y_m: 0.20,
            ..ReachGoal::default()
        },
        Arc::new(AtomicBool::new(false)),
    );
    wait_accepted(&events_c);
    let end_c = c.join().unwrap();
    assert_eq!(
        end_c.result.outcome(),
        Some(ReachOutcome::Reached),
        "{end_c:?}"
    );

    // Out of bounds: rejected, and its result names the bound.
    let (_events_d, d) = client(
        ReachGoal {
            x_m: 0.0,
            y_m: 0.05,
            ..ReachGoal::default()
        },
        Arc::new(AtomicBool::new(false)),
    );
    let end_d = d.join().unwrap();
    assert!(!end_d.accepted);
    assert_eq!(
        end_d.result.outcome(),
        Some(ReachOutcome::Refused),
        "{end_d:?}"
    );
    assert!(
        end_d.result.reason.contains("intake.goal_min_radius_m"),
        "{end_d:?}"
    );

    // rt-core was told: reach A, cancel A (pre-empted: its plan is revoked), reach B (a
    // newer id), cancel B, reach C, release C; nothing for the refused goal. (Before issue
    // 41 a pre-emption told rt-core nothing: reach A, reach B, cancel B, ….)
    let want = [
        GoalCommand::Reach,
        GoalCommand::Cancel,
        GoalCommand::Reach,
        GoalCommand::Cancel,
        GoalCommand::Reach,
        GoalCommand::Release,
    ];
    let complete = foresight_tests::wait_for(Duration::from_secs(10), || {
        take_requests(&mut seen);
        (seen.len() >= want.len()).then_some(())
    });
    assert!(complete.is_some(), "goal requests seen: {seen:?}");
    let commands: Vec<GoalCommand> = seen.iter().map(|r| r.command().unwrap()).collect();
    assert_eq!(commands, want, "{seen:?}");
    assert_eq!(
        seen[1].goal_id, seen[0].goal_id,
        "the pre-emption cancels goal A"
    );
    assert!(
        seen[2].goal_id > seen[0].goal_id,
        "a newer goal has a newer id"
    );
    assert_eq!(seen[3].goal_id, seen[2].goal_id, "the cancel names goal B");
    assert_eq!(seen[5].goal_id, seen[4].goal_id, "the release names goal C");
    assert_eq!(seen[0].target_m, [0.35, 0.15]);
    arm.stop.store(true, Ordering::Relaxed);
    states.join().unwrap();
}

/// Issue 41 item 5 (leftover): rt-core refuses a reach request that reaches it too old (or
/// made before it started), and the bridge was not told: a goal without a deadline waited
/// forever. Now rt-core answers with a `GoalRefusal` and the goal ends at once, refused
/// (status aborted), naming the refusal.
#[test]
fn a_goal_whose_reach_rt_core_refused_by_age_ends_aborted_naming_it() {
    if run_in_private_netns("a_goal_whose_reach_rt_core_refused_by_age_ends_aborted_naming_it")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let prefix = unique_prefix("reach_refused");
    let (node, _cleanup) = services::create_node::<ipc::Service>("reach-test").unwrap();
    let requests = services::open_subscriber::<GoalRequest, _>(&node, &prefix).unwrap();
    let refusals = services::open_publisher::<GoalRefusal, _>(&node, &prefix).unwrap();
    let arm = Arc::new(FakeArm {
        tcp_m: Mutex::new([0.3, 0.0, 0.3]),
        moving: AtomicBool::new(false),
        stop: AtomicBool::new(false),
    });
    let states = publish_states(prefix.clone(), arm.clone());
    let _bridge = ChildGuard::spawn(
        "ros-bridge",
        Command::new(bin_path("ros-bridge"))
            .current_dir(repo_root())
            .args([
                "--prefix",
                &prefix,
                "--goal-source",
                "action",
                "--seconds",
                "200",
            ])
            .args(["--urdf", asset("xarm5.urdf").to_str().unwrap()])
            .stdout(Stdio::null()),
    );
    // A goal without a deadline: before, nothing but a cancel ended it.
    let (events, goal) = client(
        ReachGoal {
            x_m: 0.35,
            y_m: 0.15,
            ..ReachGoal::default()
        },
        Arc::new(AtomicBool::new(false)),
    );
    wait_accepted(&events);
    let request = foresight_tests::wait_for(Duration::from_secs(30), || {
        requests.receive().ok().flatten().map(|r| *r)
    })
    .expect("the bridge sent the reach to rt-core");
    assert_eq!(request.command(), Ok(GoalCommand::Reach));
    // rt-core's answer to a request that reached it 2.5 s old.
    let too_old = GoalRefusal::by_age(
        request.goal_id,
        request.command,
        &GoalRequestAgeError::TooOld {
            age_ns: 2_500_000_000,
        },
        shm_schemas::clock::monotonic_now_ns(),
    );
    refusals.send_copy(too_old).unwrap();
    // Generous: the goal ends on the bridge's next iteration.
    let ended =
        foresight_tests::wait_for(Duration::from_secs(60), || goal.is_finished().then_some(()));
    assert!(
        ended.is_some(),
        "the goal never ended: the bridge did not take rt-core's refusal"
    );
    let end = goal.join().unwrap();
    assert!(end.accepted);
    assert_eq!(end.result.outcome(), Some(ReachOutcome::Refused), "{end:?}");
    assert_eq!(
        end.status,
        ros2_client::action_msgs::GoalStatusEnum::Aborted,
        "{end:?}"
    );
    assert!(
        end.result
            .reason
            .contains("refused by rt-core: the request is 2.500 s old, over the 2.000 s bound"),
        "{end:?}"
    );
    arm.stop.store(true, Ordering::Relaxed);
    states.join().unwrap();
}
