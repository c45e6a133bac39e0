//! A controller starved of CPU while the arm moves (`xarm-sim` on a loaded machine, the cycle
//! on `SCHED_FIFO`): the servo targets still reach it, but its joints and its report stream
//! stall, so the cycle's robot state goes stale (a stop along the plan, then no state at
//! all) while the controller keeps taking the stop's targets. When the reports return, the
//! first ones show the joints from before the stall. The controller checks every `servo_j`
//! target against the last target it accepted on the connection, not against the measured
//! joints: the first command after the stall must lie within one period's step of the last
//! command sent, or the controller raises error 24 (joint speed) and latches the arm.

use std::time::Duration;

use crate::xarm_rig::{MOVE, XRig, max_step_rad};
use rt_core::cycle::{CycleEvent, Mode, StopReason};

/// The field failure: a protective fault (error 24) after the reports went stale while the
/// stop's targets still reached the controller, and the cycle resumed from the stale joints.
#[test]
fn a_stalled_report_stream_while_moving_puts_no_jump_on_the_wire() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(400));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    let sim = rig.sim.take().expect("sim");
    let fault_rad = sim.summary().protective_limits.max_joint_step_rad();
    // Starved: targets taken, joints and reports still.
    sim.freeze(true);
    rig.report_proxy.hold(true);
    let frozen_at = sim.summary().q_rad;
    // Until the cycle has no state at all (the driver's 200 ms), and a little longer.
    let mut events = Vec::new();
    rig.log.drain(|_| {});
    for _ in 0..200 {
        rig.cycle_once();
        rig.log.drain(|r| events.push(r.event));
        if events
            .iter()
            .any(|e| matches!(e, CycleEvent::LinkError { .. }))
        {
            break;
        }
    }
    assert!(
        events
            .iter()
            .any(|e| matches!(e, CycleEvent::LinkError { .. })),
        "the state never went missing: {events:?}"
    );
    rig.run_for(Duration::from_millis(40));
    let r = *rig.cycle.report();
    // (A loaded machine may also have stalled the test's cycle past the freeze bound.)
    assert!(
        matches!(
            r.stop_reason,
            StopReason::StaleRobotState | StopReason::Frozen
        ),
        "{r:?}"
    );
    let commanded = sim.summary();
    let lag_rad = frozen_at
        .iter()
        .zip(r.cmd.q_rad)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        lag_rad > fault_rad,
        "the stop's targets should have left the stalled joints behind: {lag_rad} rad"
    );
    // The reports come back, first those from the stall (the joints where they stood).
    rig.report_proxy.hold(false);
    rig.run_for(Duration::from_millis(40));
    sim.freeze(false);
    rig.run_for(Duration::from_millis(400));
    let r = *rig.cycle.report();
    let s = sim.summary();
    rig.sim = Some(sim);
    rig.log.drain(|r| events.push(r.event));
    let limit = max_step_rad(&rig.cfg);
    assert_eq!(
        s.protective_faults, 0,
        "the controller faulted: {:?} (accepted before: {}, after: {}); {events:?}",
        s.last_protective_fault, commanded.counters.servo_accepted, s.counters.servo_accepted
    );
    assert!(
        s.max_joint_step_rad <= limit,
        "a step of {} rad reached the controller (limit {limit}): {s:?}",
        s.max_joint_step_rad
    );
    assert_eq!(s.error_code, 0, "{s:?}");
    assert!(!r.awaiting_ack, "{r:?}");
    assert_eq!(r.arm_error_code, 0, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped, "{r:?}");
    // The arm stands where the last command sent put it, and the cycle holds it there.
    let gap = s
        .q_rad
        .iter()
        .zip(r.cmd.q_rad)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(gap < 1e-3, "arm {:?}, command {:?}", s.q_rad, r.cmd.q_rad);
    // A fresh plan from there moves it without a fault.
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let after = rig.sim_summary();
    assert!(
        after.counters.servo_accepted > s.counters.servo_accepted + 100,
        "{after:?}"
    );
    assert_eq!(after.protective_faults, 0, "{after:?}");
}

/// The whole machine stalls (a paused VM, heavy load): the controller, starved, still takes
/// the targets for a while but its joints and reports stall; then the cycle itself is not
/// run for longer than the freeze bound, and resumes on a state that is late but not yet
/// missing. The stop for the freeze ends where the controller holds the arm, the last
/// command sent, not at the stalled joints: a simulated arm that resumes on its own sends a
/// command at once, and one at the stalled joints would be a jump back (error 24).
#[test]
fn a_frozen_cycle_on_a_stalled_report_stream_puts_no_jump_on_the_wire() {
    let mut rig = XRig::start(true);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(1000));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    let sim = rig.sim.take().expect("sim");
    let fault_rad = sim.summary().protective_limits.max_joint_step_rad();
    sim.freeze(true);
    rig.report_proxy.hold(true);
    let frozen_at = sim.summary().q_rad;
    rig.run_for(Duration::from_millis(32));
    let sent = rig.cycle.report().cmd.q_rad;
    // The cycle stalls too, past the freeze bound (100 ms), and runs again while the state
    // is late but not yet missing (the driver's 200 ms).
    std::thread::sleep(Duration::from_millis(105));
    let mut events = Vec::new();
    rig.log.drain(|_| {});
    rig.run_for(Duration::from_millis(4));
    rig.log.drain(|r| events.push(r.event));
    assert!(
        events
            .iter()
            .any(|e| matches!(e, CycleEvent::Frozen { .. })),
        "{events:?}"
    );
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Frozen);
    let lag_rad = frozen_at
        .iter()
        .zip(sent)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        lag_rad > fault_rad,
        "the targets should have left the stalled joints behind: {lag_rad} rad"
    );
    rig.report_proxy.hold(false);
    rig.run_for(Duration::from_millis(20));
    sim.freeze(false);
    rig.run_for(Duration::from_millis(400));
    let s = sim.summary();
    rig.sim = Some(sim);
    rig.log.drain(|r| events.push(r.event));
    assert_eq!(
        s.protective_faults, 0,
        "the controller faulted: {:?}; {events:?}",
        s.last_protective_fault
    );
    let limit = max_step_rad(&rig.cfg);
    assert!(
        s.max_joint_step_rad <= limit,
        "a step of {} rad reached the controller (limit {limit}): {s:?}",
        s.max_joint_step_rad
    );
    assert_eq!(s.error_code, 0, "{s:?}");
    assert!(!rig.cycle.report().awaiting_ack, "{:?}", rig.cycle.report());
}
