//! Every way out of `rt-core run` is a controlled stop, on the real protocol: the real
//! binary drives `xarm-sim` (protective faults on), a test detector and a straight-line
//! policy make the arm move, and 0.3 s into the plan the process is told to end — SIGINT,
//! SIGTERM, a twin-loop error (the command log on a full disk, `/dev/full`) or a twin-thread
//! panic (the hidden `--inject-fault`). In each case the commanded speed falls to rest
//! before the process exits, the controller ends in its stop state (SET_STATE 4), no
//! protective fault was raised, and the exit status says whether it was an error.
//! Needs the workspace's binaries built (`cargo build --release --workspace --bins`).

use std::process::Command;
use std::time::{Duration, Instant};

use foresight_tests::rt_rig::{Rig, Seen, straight_line_blob, task};
use foresight_tests::sim_proc::SimProc;

/// How the run is ended.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Ending {
    Signal(&'static str),
    /// Arguments that make the twin loop fail on its own.
    Fault,
}

fn speed(s: &shm_schemas::RobotState) -> f64 {
    s.joint_velocities_rad_s
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()))
}

fn states_after(seen: &[(Instant, Seen)], t: Instant) -> Vec<shm_schemas::RobotState> {
    seen.iter()
        .filter(|(at, _)| *at >= t)
        .filter_map(|(_, s)| match s {
            Seen::State(st) => Some(*st),
            _ => None,
        })
        .collect()
}

/// Starts the run, waits until the arm moves, ends it 0.3 s later, and checks the stop.
/// One run at a time (each is a real-time process and a simulated controller; on a loaded
/// 2-core machine four at once would measure the machine, not the stop).
fn end_a_moving_run(test: &str, extra: &[&str], ending: Ending, expect_success: bool) {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _serial = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let sim = SimProc::start([0; 6], &[]);
    let mut args: Vec<String> = [
        "--link",
        "xarm",
        "--robot",
        &format!("127.0.0.1:{}", sim.command_port()),
        "--report-port",
        &sim.report_real_port().to_string(),
    ]
    .iter()
    .map(ToString::to_string)
    .collect();
    args.extend(extra.iter().map(ToString::to_string));
    let mut rig = Rig::start_with(test, &args);
    rig.wait("the first robot state", Duration::from_secs(30), |s| {
        s.iter()
            .any(|(_, x)| matches!(x, Seen::State(_)))
            .then_some(())
    });
    rig.publish_policy(&straight_line_blob(1, &task(), 0.0), false);
    let moving_at = rig.wait("the arm moving", Duration::from_secs(20), |s| {
        s.iter().find_map(|(t, x)| match x {
            Seen::State(st) if st.active_policy_id == 1 && speed(st) > 0.02 => Some(*t),
            _ => None,
        })
    });
    if let Ending::Signal(sig) = ending {
        while moving_at.elapsed() < Duration::from_millis(300) {
            rig.pump();
            std::thread::sleep(Duration::from_millis(2));
        }
        let pid = rig.rt.child.id().to_string();
        let ok = Command::new("kill")
            .args([&format!("-{sig}"), &pid])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill -{sig} {pid}");
    }
    let deadline = Instant::now() + Duration::from_secs(15);
    let status = loop {
        rig.pump();
        if let Ok(Some(st)) = rig.rt.child.try_wait() {
            break st;
        }
        assert!(Instant::now() < deadline, "rt-core did not exit");
        std::thread::sleep(Duration::from_millis(2));
    };
    rig.pump();
    let log = std::fs::read_to_string(&rig.log).unwrap_or_default();
    assert_eq!(
        status.success(),
        expect_success,
        "exit status {status:?} for {ending:?}\n{log}"
    );
    // The commanded speed decelerates from where the stop began to rest, and the stop is
    // reported before the exit.
    let after = states_after(&rig.seen, moving_at);
    let begun = after
        .iter()
        .position(shm_schemas::RobotState::is_stopped)
        .unwrap_or_else(|| panic!("no controlled stop reported\n{log}"));
    let stopping = &after[begun.saturating_sub(1)..];
    let last = stopping[stopping.len() - 1];
    assert!(
        last.is_stopped() && speed(&last) == 0.0,
        "not at rest before the exit: {last:?}\n{log}"
    );
    assert_eq!(last.stop_reason, 7, "not a requested stop: {last:?}");
    let first_speed = speed(&stopping[0]);
    let peak = stopping.iter().map(speed).fold(0.0, f64::max);
    assert!(
        first_speed > 0.02,
        "the arm was not moving when ended: {first_speed}"
    );
    // A jerk-limited stop begun while the plan accelerates keeps speeding up until the
    // acceleration has ramped down: at most a²/(2J) = 4²/(2·40) = 0.2 rad/s more (the
    // runtime's limits), never above the velocity limit (1 rad/s).
    assert!(
        peak <= first_speed + 0.2 && peak <= 1.0 + 1e-9,
        "sped up while stopping: {peak} from {first_speed}"
    );
    assert!(
        log.contains("the arm is at rest") || log.contains("stopping the arm under control"),
        "{log}"
    );
    // The controller ends in its stop state; nothing the controller would fault on.
    let s = sim.finish();
    assert_eq!(
        s["state"], 4,
        "controller not in its stop state: {s}\n{log}"
    );
    assert!(s["stop_requests"].as_u64().unwrap_or(0) >= 1, "{s}");
    assert_eq!(s["protective_faults"], 0, "{s}");
    assert_eq!(s["clean_error_requests"], 0, "{s}");
}

#[test]
fn sigint_0_3_s_into_a_plan_stops_the_arm_then_the_controller() {
    end_a_moving_run("exit_sigint", &[], Ending::Signal("INT"), true);
}

#[test]
fn sigterm_0_3_s_into_a_plan_stops_the_arm_then_the_controller() {
    end_a_moving_run("exit_sigterm", &[], Ending::Signal("TERM"), true);
}

#[test]
fn a_twin_loop_error_stops_the_arm_then_exits_non_zero() {
    // The command log on a full disk: its first flush, 0.1 s after the first command line,
    // fails.
    end_a_moving_run(
        "exit_twin_error",
        &["--command-log", "/dev/full"],
        Ending::Fault,
        false,
    );
}

#[test]
fn a_twin_thread_panic_stops_the_arm_then_exits_non_zero() {
    end_a_moving_run(
        "exit_twin_panic",
        &["--inject-fault", "twin-panic:300"],
        Ending::Fault,
        false,
    );
}
