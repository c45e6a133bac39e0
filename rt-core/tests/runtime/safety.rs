//! The safety paths of the cycle and the twin worker on the toy rig (deterministic, one
//! thread): the one check on every command across a link cut, re-verification of a plan
//! scheduled to join, a plan the shield refuses after a passing lookahead, a shutdown
//! request, and the latch of a protective stop.

use std::sync::atomic::Ordering;

use crate::common::{Rig, START, TARGET_A, TARGET_B};
use rt_core::cycle::shield::ShieldModel;
use rt_core::cycle::{Mode, StopReason};
use rt_core::testing::toy::ToyArm;
use rt_core::twin_thread::TwinEvent;

/// The most one joint may move between two targets (+ rounding).
fn max_step_rad(rig: &Rig) -> f64 {
    crate::xarm_rig::max_step_rad(&rig.cfg) + 1e-12
}

/// A link cut of `cut_cycles` periods while the arm moves (a simulated arm that resumes
/// without an acknowledgement, so commands flow again at once): the first target after
/// the link returns is where the arm stands, never the stop's virtual position.
fn link_cut_while_moving(cut_cycles: u64) {
    let mut rig = Rig::auto_resuming();
    rig.policy(1, TARGET_A);
    rig.run(150);
    assert_eq!(rig.mode(), Mode::Following);
    let conn = rig.cycle.link().connection();
    conn.store(false, Ordering::Release);
    rig.run(cut_cycles);
    conn.store(true, Ordering::Release);
    rig.run(200);
    let limit = max_step_rad(&rig);
    let seen = rig.cycle.link().max_target_step_rad();
    assert!(
        seen <= limit,
        "a {cut_cycles}-cycle cut: a target step of {seen} rad on the wire (limit {limit})"
    );
    // It stopped for the lost link (and, resuming on its own, may be moving again).
    assert!(rig.cycle.report().stops >= 1);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::LinkLost);
    // The stop ended where the arm stands: no command had to be refused (a stop that ran on
    // without the arm would have put a jump before the check).
    assert_eq!(
        rig.cycle.report().commands_refused,
        0,
        "the first command after the link returned was not the measured pose"
    );
}

#[test]
fn a_link_cut_of_one_cycle_while_moving_puts_no_jump_on_the_wire() {
    link_cut_while_moving(1);
}

#[test]
fn a_link_cut_of_two_three_and_ten_cycles_while_moving_puts_no_jump_on_the_wire() {
    link_cut_while_moving(2);
    link_cut_while_moving(3);
    link_cut_while_moving(10);
}

#[test]
fn every_command_of_a_run_stays_within_one_period_at_the_velocity_limit() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(300);
    rig.policy(2, TARGET_B);
    rig.run(1500);
    let seen = rig.cycle.link().max_target_step_rad();
    assert!(seen > 0.0 && seen <= max_step_rad(&rig), "{seen}");
    assert_eq!(rig.cycle.report().commands_refused, 0);
}

#[test]
fn a_box_on_the_path_of_a_plan_scheduled_to_join_revokes_it_and_the_running_plan() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(120);
    assert_eq!(rig.mode(), Mode::Following);
    // A hot swap: the new policy's plan joins the running one `join_ahead_s` ahead.
    rig.policy(2, TARGET_B);
    let mut joined_id = None;
    for _ in 0..40 {
        rig.run(1);
        joined_id = rig.events.iter().find_map(|e| match e {
            TwinEvent::PlanApproved {
                plan_id,
                joins: true,
                ..
            } => Some(*plan_id),
            _ => None,
        });
        if joined_id.is_some() {
            break;
        }
    }
    let joined_id = joined_id.expect("a join plan was approved");
    assert_eq!(rig.cycle.report().plan_id, 1, "still before the join point");
    // In the join window a box appears where the joining plan ends (far from the
    // running plan's rest).
    rig.scene
        .push_obstacle(ToyArm.tcp_position_m(&TARGET_B), [0.08; 3]);
    rig.run(200);
    assert!(
        rig.events.iter().any(|e| matches!(
            e,
            TwinEvent::Revoked { plan_id, .. } if *plan_id == joined_id
        )),
        "the joining plan was not re-verified: {:?}",
        rig.events
    );
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Revoked);
    assert_ne!(
        rig.cycle.report().plan_id,
        joined_id,
        "the revoked plan took over"
    );
    // After the stop only the base policy 1 (the policy library's fallback), whose episode
    // to TARGET_A stays clear of the box, may be planned with again; policy 2 never.
    let revoked_at = rig
        .events
        .iter()
        .position(|e| matches!(e, TwinEvent::Revoked { .. }))
        .unwrap();
    assert!(
        rig.events[revoked_at..]
            .iter()
            .all(|e| !matches!(e, TwinEvent::PlanApproved { policy_id: 2, .. })),
        "{:?}",
        rig.events
    );
    assert!(matches!(rig.mode(), Mode::Stopped | Mode::Following));
}

#[test]
fn a_plan_the_shield_refuses_after_a_passing_lookahead_asks_for_retraining() {
    let mut rig = Rig::new();
    // The lookahead sees no obstacle closer than it cares about; the shield does.
    rig.twin.lookahead_mut().min_distance_m = f64::NEG_INFINITY;
    let wp = {
        let mut la = rt_core::testing::toy::ToyLookahead::default();
        let mut wps = Vec::new();
        let probe = rt_core::testing::toy::ToyPolicy::random(1, TARGET_A, 1);
        use rt_core::twin_thread::Lookahead;
        la.lookahead(&probe, &rig.scene, &START, &mut wps);
        wps[wps.len() / 2]
    };
    rig.scene
        .push_obstacle(ToyArm.tcp_position_m(&wp), [0.05; 3]);
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert!(
        rig.events
            .iter()
            .any(|e| matches!(e, TwinEvent::PlanRejected { .. })),
        "{:?}",
        rig.events
    );
    assert!(
        rig.events.iter().any(|e| matches!(
            e,
            TwinEvent::Verdict { verdict, .. } if !verdict.safe
        )),
        "no failed verdict published"
    );
    assert_eq!(rig.retrains(), 1, "one retrain request: {:?}", rig.events);
    assert_ne!(rig.mode(), Mode::Following);
}

#[test]
fn a_shutdown_request_stops_the_arm_along_its_plan_and_takes_no_new_plan() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(120);
    assert_eq!(rig.mode(), Mode::Following);
    let moving = rig.cycle.report().cmd.dq_rad_s;
    assert!(moving.iter().any(|v| v.abs() > 0.05), "{moving:?}");
    rig.cycle.control().request_shutdown();
    let mut speeds = Vec::new();
    for _ in 0..400 {
        rig.run(1);
        let r = rig.cycle.report();
        speeds.push(r.cmd.dq_rad_s.iter().fold(0.0_f64, |m, v| m.max(v.abs())));
        if r.shutdown_complete {
            break;
        }
    }
    let r = *rig.cycle.report();
    assert!(r.shutdown_complete, "not at rest after 1.6 s");
    assert_eq!(r.stop_reason, StopReason::Shutdown);
    assert!(r.cmd.dq_rad_s.iter().all(|v| *v == 0.0));
    // Along the plan the speed may rise briefly with the plan's own acceleration (the
    // time scaling starts with zero slope), then falls to rest.
    let peak = speeds.iter().copied().fold(0.0, f64::max);
    assert!(peak <= speeds[0] * 1.05, "the stop speeds up: {speeds:?}");
    let half = speeds.len() / 2;
    assert!(speeds[half] < 0.7 * speeds[0], "{speeds:?}");
    assert!(rig.cycle.link().max_target_step_rad() <= max_step_rad(&rig));
    // No plan is taken any more.
    rig.policy(2, TARGET_B);
    rig.run(300);
    assert_eq!(rig.mode(), Mode::Stopped);
}

#[test]
fn an_unsafe_lookahead_after_a_scene_change_revokes_the_plan_under_way() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert_eq!(rig.mode(), Mode::Following);
    // A box the running plan clears by the shield's margin, but closer than the twin's
    // episode check allows: the plan passes re-verification, the lookahead from the join
    // point fails, and the plan under way is revoked (the arm stops along it).
    rig.twin.lookahead_mut().min_distance_m = 0.3;
    let tcp = ToyArm.tcp_position_m(&TARGET_A);
    rig.scene
        .push_obstacle([tcp[0], tcp[1], tcp[2] + 0.25], [0.05; 3]);
    rig.run(200);
    assert!(
        rig.events
            .iter()
            .any(|e| matches!(e, TwinEvent::Revoked { plan_id: 1, .. })),
        "{:?}",
        rig.events
    );
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Revoked);
}

/// Issue 30 item 3: a cycle that was not run for longer than the freeze bound while the arm
/// moved (SIGSTOP, a paused VM, a long page fault) ends the stop at the measured joints and
/// latches, instead of streaming on from where the plan's clock left off (a jump from rest
/// to the plan's speed). Before, the cycle took the next sample as if nothing had happened.
#[test]
fn a_frozen_cycle_stops_at_the_measured_joints_and_latches() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(60);
    assert_eq!(rig.mode(), Mode::Following);
    let held = rig.arm_q();
    // Half a second without a cycle: the controller holds the last target.
    rig.clock.advance_ns(500_000_000);
    rig.run(1);
    let r = *rig.cycle.report();
    assert_eq!(r.stop_reason, StopReason::Frozen, "{r:?}");
    assert_eq!(rig.mode(), Mode::Stopped);
    assert!(
        r.awaiting_ack,
        "a frozen stop latches on an arm that does not auto-resume"
    );
    assert_eq!(rig.arm_q(), held, "a target was streamed after the freeze");
    rig.run(200);
    assert_eq!(rig.arm_q(), held, "moved without an acknowledgement");
    assert_eq!(rig.mode(), Mode::Stopped);
}

/// Issue 41 item 5: a freeze of 50 ms at 250 Hz (12 periods missed) is a freeze. Before,
/// the bound had a 100 ms floor above its own 10 periods (40 ms), and freezes of 40–100 ms
/// went undetected: the cycle streamed on as if nothing had happened.
#[test]
fn a_freeze_of_fifty_milliseconds_stops_the_arm() {
    let mut rig = Rig::new();
    assert_eq!(rig.cfg.rate_hz, 250.0);
    rig.policy(1, TARGET_A);
    rig.run(60);
    assert_eq!(rig.mode(), Mode::Following);
    let held = rig.arm_q();
    rig.clock.advance_ns(50_000_000);
    rig.run(1);
    let r = *rig.cycle.report();
    assert_eq!(r.stop_reason, StopReason::Frozen, "{r:?}");
    assert_eq!(rig.arm_q(), held, "a target was streamed after the freeze");
}

/// The same freeze on a simulated arm that auto-resumes: a pause, then a fresh plan from
/// where the arm stands.
#[test]
fn a_frozen_cycle_on_an_auto_resuming_arm_stops_then_continues_on_a_fresh_plan() {
    let mut rig = Rig::auto_resuming();
    rig.policy(1, TARGET_A);
    rig.run(60);
    assert_eq!(rig.mode(), Mode::Following);
    let first_plan = rig.cycle.report().plan_id;
    rig.clock.advance_ns(500_000_000);
    rig.run(1);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Frozen);
    assert!(!rig.cycle.report().awaiting_ack);
    rig.run(400);
    assert!(
        rig.cycle.report().plan_id > first_plan,
        "{:?}",
        rig.cycle.report()
    );
}

/// An in-process arm whose measured joints drift at `drift_rad_s` (an arm still coasting,
/// or pushed by hand, while the cycle holds it latched).
struct DriftingArm {
    arm: rt_core::cycle::link::InProcessArm,
    drift_rad_s: f64,
}

impl rt_core::cycle::link::RobotLink for DriftingArm {
    fn read_state(
        &mut self,
        now_ns: u64,
    ) -> Result<rt_core::cycle::link::LinkState, rt_core::cycle::link::LinkError> {
        let mut st = self.arm.read_state(now_ns)?;
        st.dq_rad_s[0] += self.drift_rad_s;
        Ok(st)
    }

    fn send_servo(
        &mut self,
        now_ns: u64,
        q_rad: &twin::Joints,
    ) -> Result<(), rt_core::cycle::link::LinkError> {
        self.arm.send_servo(now_ns, q_rad)
    }
}

/// Issue 41 item 5: an acknowledgement counts only with the arm measured at rest. Before,
/// one taken while the measured joints still moved (an arm coasting or pushed, the stop
/// not over on the controller's side) re-enabled motion at once.
#[test]
fn an_acknowledgement_while_the_arm_is_measured_moving_is_dropped() {
    use rt_core::rt::clock::{Clock, ManualClock};
    let mut cfg = rt_core::config::RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let limits = rt_core::cycle::shield::ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (twin_io, cycle_io, _log) = rt_core::cycle::wire::<rt_core::testing::toy::ToyScene>();
    let arm = rt_core::cycle::link::InProcessArm::new(
        crate::common::START,
        cfg.limits.joint_min_rad,
        cfg.limits.joint_max_rad,
        [3.0; twin::DOF],
    );
    let conn = arm.connection();
    let mut cycle = rt_core::cycle::Cycle::new(
        rt_core::cycle::CycleConfig::from_runtime(&cfg),
        rt_core::cycle::shield::Shield::new(rt_core::testing::toy::ToyArm, limits),
        rt_core::cycle::brake::Brake::new(&cfg.limits),
        DriftingArm {
            arm,
            drift_rad_s: 0.0,
        },
        cycle_io,
    );
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).expect("start");
    let period = |cycle: &mut rt_core::cycle::Cycle<_, DriftingArm>| {
        cycle.process(clock.now_ns());
        clock.advance_ns(cfg.period_ns());
    };
    period(&mut cycle);
    // A lost link latches; it comes back.
    conn.store(false, Ordering::Release);
    period(&mut cycle);
    conn.store(true, Ordering::Release);
    period(&mut cycle);
    assert!(cycle.report().awaiting_ack, "{:?}", cycle.report());
    // The arm is measured moving: the acknowledgement is dropped, the stop stays.
    cycle.link_mut().drift_rad_s = 0.05;
    period(&mut cycle);
    twin_io.control.acknowledge_latched();
    period(&mut cycle);
    let r = *cycle.report();
    assert!(
        r.awaiting_ack,
        "cleared while the arm was measured moving: {r:?}"
    );
    assert_eq!(r.acks_dropped, 1, "{r:?}");
    // At rest, a new acknowledgement counts.
    cycle.link_mut().drift_rad_s = 0.0;
    period(&mut cycle);
    twin_io.control.acknowledge_latched();
    period(&mut cycle);
    assert!(!cycle.report().awaiting_ack, "{:?}", cycle.report());
}
