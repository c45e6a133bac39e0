//! The safety paths on the real protocol: the production cycle (twin shield model, xArm
//! driver) against `xarm-sim`, whose protective faults are on and which measures every
//! target it receives. A link cut while the arm moves, a collision error from the
//! controller, a stop from another client, a frozen arm, and an acknowledgement given while
//! the link is down.

use std::time::Duration;

use crate::xarm_rig::{MOVE, XRig, max_step_rad};
use rt_core::cycle::plan::Plan;
use rt_core::cycle::shield::ShieldViolation;
use rt_core::cycle::{Mode, StopReason};
use xarm::codes::ControllerError;

/// Cuts the link for `cut` while the arm moves at ~0.6 rad/s; the reconnect helper (2 ms
/// back-off) brings it back while the stop is still under way.
fn cut_while_moving(cut: Duration) {
    let mut rig = XRig::start(true);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(700));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    rig.command_proxy.cut(cut);
    rig.report_proxy.cut(cut);
    rig.run_for(Duration::from_millis(1200));
    let r = *rig.cycle.report();
    let s = rig.sim_summary();
    let limit = max_step_rad(&rig.cfg);
    assert!(
        s.connections >= 2,
        "the link never came back ({cut:?} cut): {s:?}"
    );
    assert!(
        s.max_joint_step_rad <= limit,
        "a {cut:?} cut: a step of {} rad reached the controller (limit {limit}); {s:?}",
        s.max_joint_step_rad
    );
    assert_eq!(s.protective_faults, 0, "{s:?}");
    assert_eq!(r.stop_reason, StopReason::LinkLost, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped, "{r:?}");
    assert!(s.counters.servo_accepted > 100, "{s:?}");
}

#[test]
fn a_1_ms_link_cut_while_moving_puts_no_jump_on_the_wire() {
    cut_while_moving(Duration::from_millis(1));
}

#[test]
fn a_5_ms_link_cut_while_moving_puts_no_jump_on_the_wire() {
    cut_while_moving(Duration::from_millis(5));
}

#[test]
fn a_10_ms_link_cut_while_moving_puts_no_jump_on_the_wire() {
    cut_while_moving(Duration::from_millis(10));
}

#[test]
fn after_a_link_cut_a_real_arm_waits_for_the_acknowledgement() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(500));
    rig.command_proxy.cut(Duration::from_millis(5));
    rig.report_proxy.cut(Duration::from_millis(5));
    rig.run_for(Duration::from_millis(800));
    assert!(rig.cycle.report().awaiting_ack);
    let accepted = rig.sim_summary().counters.servo_accepted;
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(500));
    let s = rig.sim_summary();
    assert_eq!(
        s.counters.servo_accepted, accepted,
        "targets reached the arm before the acknowledgement: {s:?}"
    );
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(100));
    assert!(!rig.cycle.report().awaiting_ack);
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let s = rig.sim_summary();
    assert!(s.counters.servo_accepted > accepted + 50, "{s:?}");
    assert!(s.max_joint_step_rad <= max_step_rad(&rig.cfg), "{s:?}");
    assert_eq!(s.protective_faults, 0, "{s:?}");
}

#[test]
fn a_collision_error_is_an_arm_error_and_nothing_moves_until_acknowledged() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(500));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    rig.sim
        .as_ref()
        .expect("sim")
        .inject_error(ControllerError::Collision);
    for _ in 0..500 {
        rig.cycle_once();
        if rig.cycle.report().awaiting_ack {
            break;
        }
    }
    rig.run_for(Duration::from_millis(100));
    let r = *rig.cycle.report();
    assert_eq!(r.stop_reason, StopReason::ArmError(31), "{r:?}");
    assert_eq!(r.arm_error_code, 31, "{r:?}");
    assert!(r.awaiting_ack, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped);
    // No motion, no CLEAN_ERROR, whatever plans arrive.
    let before = rig.sim_summary();
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(600));
    let s = rig.sim_summary();
    assert_eq!(
        s.clean_error_requests, 0,
        "rt-core cleared the error: {s:?}"
    );
    assert_eq!(s.q_rad, before.q_rad, "the arm moved: {s:?}");
    assert_eq!(s.error_code, 31, "{s:?}");
    // The operator acknowledges: the error is cleared once, and a fresh plan moves.
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(300));
    let r = *rig.cycle.report();
    assert!(!r.awaiting_ack, "{r:?}");
    let s = rig.sim_summary();
    assert_eq!(s.clean_error_requests, 1, "{s:?}");
    assert_eq!(s.error_code, 0, "{s:?}");
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let after = rig.sim_summary();
    assert!(
        (after.q_rad[0] - s.q_rad[0]).abs() > 0.05,
        "no motion after the acknowledgement: {after:?}"
    );
    assert_eq!(after.protective_faults, 0, "{after:?}");
}

#[test]
fn a_plan_sample_that_jumps_never_reaches_the_controller() {
    // A plan (as a faulty twin could hand over) whose sample 100 jumps 0.02 rad on joint 1:
    // the one check refuses it before the wire and the arm brakes from the last command.
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    let q0 = rig.cycle.report().measured_q_rad;
    let dt = 1.0 / rig.cfg.rate_hz;
    let mut plan = Plan::with_capacity(0, 1, dt, 300);
    for i in 0..300 {
        let mut q = q0;
        q[0] += 0.002 * i as f64 + if i >= 100 { 0.02 } else { 0.0 };
        plan.push(q, [0.5, 0.0, 0.0, 0.0, 0.0], [0.0; 5]);
    }
    rig.send_raw_plan(plan);
    rig.run_for(Duration::from_millis(900));
    let r = *rig.cycle.report();
    let s = rig.sim_summary();
    assert_eq!(
        r.stop_reason,
        StopReason::Shield(ShieldViolation::JointStep { joint: 0 }),
        "{r:?}"
    );
    assert!(r.commands_refused >= 1, "{r:?}");
    assert!(s.max_joint_step_rad <= max_step_rad(&rig.cfg), "{s:?}");
    assert_eq!(s.protective_faults, 0, "{s:?}");
    assert_eq!(r.mode, Mode::Stopped);
}

/// Issue 25 item 11: a stop the cycle did not ask for (the pendant, the SDK, another
/// client's `SET_STATE 4`) latches like an arm error: before, it read as a refused target
/// ("link lost"), and once the state was back to ready a fresh plan moved the arm without
/// the operator.
#[test]
fn a_stop_from_another_client_latches_until_acknowledged() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(500));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    let sim = rig.sim.as_ref().expect("sim");
    sim.inject_state(4);
    rig.run_for(Duration::from_millis(300));
    let r = *rig.cycle.report();
    assert_eq!(
        r.stop_reason,
        StopReason::ControllerStopped { state: 4 },
        "{r:?}"
    );
    assert!(r.awaiting_ack, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped);
    // Someone else makes the controller ready again: still nothing moves.
    rig.sim.as_ref().expect("sim").inject_state(0);
    rig.run_for(Duration::from_millis(100));
    let before = rig.sim_summary();
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let s = rig.sim_summary();
    assert_eq!(
        s.counters.servo_accepted, before.counters.servo_accepted,
        "the arm resumed without the operator: {s:?}"
    );
    assert_eq!(s.q_rad, before.q_rad, "{s:?}");
    assert!(rig.cycle.report().awaiting_ack);
    // The operator acknowledges: servo mode again, and a fresh plan moves.
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(300));
    assert!(!rig.cycle.report().awaiting_ack, "{:?}", rig.cycle.report());
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let after = rig.sim_summary();
    assert!(
        (after.q_rad[0] - s.q_rad[0]).abs() > 0.05,
        "no motion after the acknowledgement: {after:?}"
    );
    assert_eq!(after.protective_faults, 0, "{after:?}");
}

/// Issue 25 item 12: an arm that accepts targets and does not move (frozen, blocked) is a
/// latched stop, and the controller holds it where it stands (thawed, it does not run to
/// the last target); before, the cycle streamed on and, the plan over, took the next one
/// at full speed from wherever the commands had got to.
#[test]
fn a_frozen_arm_is_a_latched_stop_not_a_resumed_stream() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(400));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    rig.sim.as_ref().expect("sim").freeze(true);
    let frozen_at = rig.sim_summary().q_rad;
    rig.run_for(Duration::from_millis(1500));
    let r = *rig.cycle.report();
    assert_eq!(r.stop_reason, StopReason::TrackingLost, "{r:?}");
    assert!(r.awaiting_ack, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped);
    let s = rig.sim_summary();
    assert_eq!(s.q_rad, frozen_at, "the frozen arm moved: {s:?}");
    // The controller was told to hold the arm where it stands (its old target dropped).
    assert!(s.stop_requests >= 1, "{s:?}");
    // Thawed, the arm still waits for the operator; no plan moves it.
    rig.sim.as_ref().expect("sim").freeze(false);
    let before = rig.sim_summary();
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(600));
    let s = rig.sim_summary();
    assert_eq!(
        s.counters.servo_accepted, before.counters.servo_accepted,
        "streamed on after a frozen arm: {s:?}"
    );
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(300));
    assert!(!rig.cycle.report().awaiting_ack, "{:?}", rig.cycle.report());
    assert_eq!(rig.sim_summary().protective_faults, 0);
}

/// Issue 25 item 6: an acknowledgement given while the link is down is dropped, not kept
/// to re-enable the arm once the link returns.
#[test]
fn an_acknowledgement_while_the_link_is_down_is_dropped() {
    let mut rig = XRig::start(false);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(500));
    rig.command_proxy.cut(Duration::from_millis(400));
    rig.report_proxy.cut(Duration::from_millis(400));
    // Until the cycle has seen the link go down.
    for _ in 0..500 {
        rig.cycle_once();
        if rig.cycle.report().awaiting_ack {
            break;
        }
    }
    assert!(rig.cycle.report().awaiting_ack);
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(1200));
    let r = *rig.cycle.report();
    assert!(r.acks_dropped >= 1, "{r:?}");
    assert!(
        r.awaiting_ack,
        "an acknowledgement from while the link was down re-enabled the arm: {r:?}"
    );
    let s = rig.sim_summary();
    assert!(s.connections >= 2, "the link never came back: {s:?}");
    // A new acknowledgement, on a live link with the arm at rest, counts.
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(300));
    assert!(!rig.cycle.report().awaiting_ack, "{:?}", rig.cycle.report());
}
