//! One owner per arm, and no orphan driving it (issue 14), with the real binaries against a
//! real `xarm-sim` process:
//! - a second `rt-core run` on the controller a first one drives is refused, naming the
//!   first one's pid, and never connects;
//! - `kill -9` of the process that started `rt-core run` (a stand-in for the launcher) while
//!   the arm moves: rt-core gets SIGTERM from the kernel, brakes the arm to rest, puts the
//!   controller in its stop state and exits.
//!
//! Needs the workspace's binaries built (`cargo build --workspace --bins`, same profile).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use foresight_tests::rt_rig::{GOAL_M, GOAL_SIZE_M, Rig, Seen, straight_line_blob, task};
use foresight_tests::sim_proc::SimProc;
use foresight_tests::{ChildGuard, bin_path, repo_root, unique_prefix, wait_for};
use iceoryx2::prelude::*;
use shm_schemas::services::create_node;
use shm_schemas::{
    DetectedObject, DetectionFrame, ObjectClass, PolicyBlob, RobotState, loan_zeroed,
    open_publisher, open_subscriber,
};

fn robot_args(sim: &SimProc) -> Vec<String> {
    vec![
        "--link".into(),
        "xarm".into(),
        "--robot".into(),
        format!("127.0.0.1:{}", sim.command_port()),
        "--report-port".into(),
        sim.report_real_port().to_string(),
    ]
}

fn rt_core_run(prefix: &str) -> Command {
    let root = repo_root();
    let mut cmd = Command::new(bin_path("rt-core"));
    cmd.arg("run")
        .arg("--config")
        .arg(root.join("assets/runtime.toml"))
        .arg("--assets")
        .arg(root.join("assets"))
        .arg("--no-mlock")
        .arg("--prefix")
        .arg(prefix);
    cmd
}

#[test]
fn a_second_rt_core_on_one_controller_is_refused_naming_the_first() {
    let sim = SimProc::start([0; 6], &[]);
    let mut first = Rig::start_with("owner_first", &robot_args(&sim));
    first.wait(
        "the first run's robot state",
        Duration::from_secs(60),
        |s| {
            s.iter()
                .any(|(_, x)| matches!(x, Seen::State(_)))
                .then_some(())
        },
    );
    let first_pid = first.rt.child.id();
    // Bounded by `--seconds`: were it not refused, it would run and end on its own.
    let out = rt_core_run(&unique_prefix("owner_second"))
        .args(robot_args(&sim))
        .args(["--seconds", "10"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .expect("second rt-core");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a second owner ran: {log}");
    assert!(
        log.contains(&format!("already commanded by pid {first_pid}")) && log.contains("UTC"),
        "the holder is not named: {log}"
    );
    assert!(
        first.rt.child.try_wait().is_ok_and(|s| s.is_none()),
        "the first run died"
    );
    let first_log = first.finish();
    let s = sim.finish();
    assert_eq!(
        s["connections"], 1,
        "the second run reached the controller: {s}\n{first_log}"
    );
}

/// The robot states seen, with when they arrived.
type StateLog = Vec<(Instant, RobotState)>;

/// A process's state letter from /proc (None: gone).
fn proc_state(pid: u32) -> Option<char> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat[stat.rfind(')')? + 2..].chars().next()
}

fn speed(s: &RobotState) -> f64 {
    s.joint_velocities_rad_s
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()))
}

#[test]
fn killing_rt_core_s_parent_with_sigkill_brakes_the_arm_and_ends_rt_core() {
    let sim = SimProc::start([0; 6], &[]);
    let prefix = unique_prefix("owner_orphan");
    let dir = std::env::temp_dir().join(&prefix);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let log_path = dir.join("rt-core.log");
    let log_file = std::fs::File::create(&log_path).expect("log");
    // The parent: a shell that starts rt-core in the background, says its pid and waits.
    let rt = rt_core_run(&prefix);
    let mut parent_cmd = Command::new("sh");
    parent_cmd
        .args(["-c", r#""$@" & echo $!; wait"#, "sh"])
        .arg(rt.get_program())
        .args(rt.get_args())
        .args(robot_args(&sim))
        .args(["--seconds", "120"])
        .stdout(Stdio::piped())
        .stderr(Stdio::from(log_file));
    let mut parent = ChildGuard::spawn("rt-core's parent", &mut parent_cmd);
    let mut out = BufReader::new(parent.child.stdout.take().expect("stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("rt-core's pid");
    let rt_pid: u32 = line.trim().parse().expect("a pid");
    // Our iceoryx2 ports: detections (goal only), the policy, the robot's state.
    let (node, _) = create_node::<ipc::Service>("owner_test").expect("node");
    let policies = open_publisher::<PolicyBlob, _>(&node, &prefix).expect("policies");
    let states = open_subscriber::<RobotState, _>(&node, &prefix).expect("states");
    let stop = Arc::new(AtomicBool::new(false));
    let (st, pfx) = (stop.clone(), prefix.clone());
    let detector = std::thread::spawn(move || {
        let (node, _) = create_node::<ipc::Service>("owner_detector").expect("node");
        let detections = open_publisher::<DetectionFrame, _>(&node, &pfx).expect("detections");
        let mut seq = 0;
        while !st.load(Ordering::Acquire) {
            seq += 1;
            let mut frame = DetectionFrame {
                sequence: seq,
                capture_time_ns: shm_schemas::clock::monotonic_now_ns(),
                camera_id: 1,
                flags: DetectionFrame::FRAME_SETTLED,
                ..DetectionFrame::default()
            };
            frame.push(DetectedObject::new(
                1,
                ObjectClass::Goal,
                0.99,
                GOAL_M,
                [GOAL_SIZE_M; 3],
            ));
            if let Ok(mut sample) = loan_zeroed(&detections) {
                *sample.payload_mut() = frame;
                let _ = sample.send();
            }
            std::thread::sleep(Duration::from_millis(33));
        }
    });
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    let mut seen: StateLog = Vec::new();
    let mut pump = |seen: &mut StateLog| {
        while let Ok(Some(s)) = states.receive() {
            seen.push((Instant::now(), *s.payload()));
        }
    };
    let until = |what: &str,
                 seen: &mut StateLog,
                 pump: &mut dyn FnMut(&mut StateLog),
                 f: &dyn Fn(&StateLog) -> bool| {
        // A hang guard, not a timing.
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            pump(seen);
            if f(seen) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}\n{}",
                log()
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    until("the first robot state", &mut seen, &mut pump, &|s| {
        !s.is_empty()
    });
    let mut sample = loan_zeroed(&policies).expect("loan");
    straight_line_blob(1, &task(), 0.0)
        .write_into(sample.payload_mut())
        .expect("blob");
    sample.send().expect("send policy");
    until("the arm moving", &mut seen, &mut pump, &|s| {
        s.iter()
            .any(|(_, st)| st.active_policy_id == 1 && speed(st) > 0.02)
    });
    let moving_at = Instant::now();
    while moving_at.elapsed() < Duration::from_millis(300) {
        pump(&mut seen);
        std::thread::sleep(Duration::from_millis(2));
    }
    // kill -9 the parent: it gets no chance to pass anything on.
    parent.child.kill().expect("kill -9 the parent");
    let _ = parent.child.wait();
    let killed_at = Instant::now();
    // rt-core ends by itself (re-parented, reaped by init or left a zombie).
    let ended = wait_for(Duration::from_secs(30), || {
        pump(&mut seen);
        matches!(proc_state(rt_pid), None | Some('Z')).then_some(())
    });
    if ended.is_none() {
        // Do not leave it running; then fail.
        let _ = Command::new("kill")
            .args(["-9", &rt_pid.to_string()])
            .status();
        panic!(
            "rt-core kept running after its parent was killed\n{}",
            log()
        );
    }
    pump(&mut seen);
    stop.store(true, Ordering::Release);
    let _ = detector.join();
    let log = log();
    // The arm was moving at the kill and was braked to rest: a stop requested of the
    // runtime (SIGTERM), the commanded speed falling to 0 before the exit.
    let after: Vec<RobotState> = seen
        .iter()
        .filter(|(t, _)| *t >= killed_at)
        .map(|(_, s)| *s)
        .collect();
    let last = after
        .last()
        .copied()
        .unwrap_or_else(|| panic!("no state after the kill\n{log}"));
    assert!(
        last.is_stopped() && speed(&last) == 0.0,
        "not at rest before the exit: {last:?}\n{log}"
    );
    assert_eq!(last.stop_reason, 7, "not a requested stop: {last:?}\n{log}");
    assert!(
        log.contains("stopping the arm under control") || log.contains("the arm is at rest"),
        "{log}"
    );
    // The controller: put in its stop state by rt-core, no protective fault.
    let s = sim.finish();
    assert_eq!(
        s["state"], 4,
        "controller not in its stop state: {s}\n{log}"
    );
    assert!(s["stop_requests"].as_u64().unwrap_or(0) >= 1, "{s}");
    assert_eq!(s["protective_faults"], 0, "{s}");
    std::fs::remove_dir_all(&dir).ok();
}
