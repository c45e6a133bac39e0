//! Issue 33 item 5, the first step of the reaction: when a new scene makes the running plan
//! unsafe far enough ahead, the plan guard schedules its stop (where the stop still ends
//! before the danger) instead of revoking it, and a re-verified plan joining the running one
//! before then takes over: the arm goes on without stopping. Without a joining plan in time
//! the arm stops at the scheduled sample, short of the danger, as a pause.

use rt_core::config::RuntimeConfig;
use rt_core::cycle::{Mode, StopReason};
use rt_core::rt::clock::Clock;
use rt_core::testing::toy::{ToyArm, ToyScene};
use rt_core::twin_thread::TwinEvent;
use twin::{DOF, Joints};

use crate::common::{Rig, START, TARGET_A, TARGET_B};

/// A box on the path from START to TARGET_A, `at` of the way (joint-space interpolation).
fn with_box_on_the_path(scene: ToyScene, at: f64) -> ToyScene {
    let q: Joints = std::array::from_fn(|j| START[j] + (TARGET_A[j] - START[j]) * at);
    let mut s = scene;
    s.push_obstacle(ToyArm::points_m(&q)[4], [0.06; 3]);
    s
}

fn rig(join_before_stopping: bool) -> Rig {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    cfg.join_before_stopping = join_before_stopping;
    Rig::with_config(cfg)
}

/// The arm on its way to TARGET_A (policy 1, 20 cycles in), and the box that lands late on
/// its path: the rig and the scene with the box (not yet seen by the twin).
fn on_the_way_with_a_box_ahead(join_before_stopping: bool) -> (Rig, ToyScene) {
    let mut rig = rig(join_before_stopping);
    rig.policy(1, TARGET_A);
    rig.run(20);
    assert_eq!(rig.mode(), Mode::Following);
    let blocked = with_box_on_the_path(rig.scene, 0.85);
    rig.scene = blocked;
    (rig, blocked)
}

/// (plan, first unsafe sample, sample the stop is due from) of each stop scheduled.
fn scheduled(events: &[TwinEvent<ToyScene>]) -> Vec<(u64, usize, usize)> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::StopScheduled {
                plan_id,
                at_index,
                stop_due_index,
            } => Some((*plan_id, *at_index, *stop_due_index)),
            _ => None,
        })
        .collect()
}

fn revoked(events: &[TwinEvent<ToyScene>]) -> usize {
    events
        .iter()
        .filter(|e| matches!(e, TwinEvent::Revoked { .. }))
        .count()
}

/// The arm on its way to TARGET_A; then a box lands late on that path and, with it, the goal
/// moves to TARGET_B (policy 2), away from the box. The frames from then on are `settled` or
/// not (the world still changing: no plan but a joining one is made on them). Returns the
/// rig after the run.
fn box_late_on_the_path_and_a_way_around(join_before_stopping: bool, settled: bool) -> Rig {
    let (mut rig, blocked) = on_the_way_with_a_box_ahead(join_before_stopping);
    rig.settled = settled;
    let now = rig.clock.now_ns();
    rig.detect(blocked, now, true, settled);
    rig.policy(2, TARGET_B);
    rig.run(300);
    rig.settled = true;
    rig.run(1200);
    rig
}

#[test]
fn a_plan_unsafe_far_ahead_is_joined_by_a_safe_plan_without_stopping() {
    joined_without_stopping(true);
}

/// The same while the world still changes (frames not settled): before, no plan of any kind
/// was made on such a scene, so the stop came whatever the way around.
#[test]
fn a_joining_plan_is_made_while_the_scene_still_changes() {
    joined_without_stopping(false);
}

fn joined_without_stopping(settled: bool) {
    let rig = box_late_on_the_path_and_a_way_around(true, settled);
    let report = *rig.cycle.report();
    let stops = scheduled(&rig.events);
    assert_eq!(stops.len(), 1, "{:?}", rig.events);
    assert_eq!(revoked(&rig.events), 0, "{:?}", rig.events);
    assert_eq!(report.joins_before_stop, 1, "{:?}", rig.events);
    assert_eq!(report.stops, 0, "the arm stopped: {:?}", report.stop_reason);
    assert!(
        Rig::near(&rig.arm_q(), &TARGET_B, 0.05),
        "the arm did not go on to the new goal: {:?}",
        rig.arm_q()
    );
    rig.assert_commands_within_velocity_limits();
    // Before this change (and with `join_before_stopping = false`): the guard revoked the
    // running plan at once and the arm stopped before going on.
    let before = box_late_on_the_path_and_a_way_around(false, settled);
    assert!(scheduled(&before.events).is_empty());
    assert!(revoked(&before.events) >= 1, "{:?}", before.events);
    assert!(before.cycle.report().stops >= 1);
    assert_eq!(before.cycle.report().joins_before_stop, 0);
}

#[test]
fn without_a_joining_plan_in_time_the_arm_stops_where_scheduled_short_of_the_danger() {
    let (mut rig, blocked) = on_the_way_with_a_box_ahead(true);
    let now = rig.clock.now_ns();
    rig.detect(blocked, now, true, true);
    let stops = scheduled(&rig.events);
    assert_eq!(stops.len(), 1, "{:?}", rig.events);
    let (plan_id, at_index, due) = stops[0];
    assert!(due < at_index);
    // The worker is busy (a long planner search): only the cycle runs, fed the new scene.
    let period = rig.cfg.period_ns();
    let mut stopped_at = None;
    for _ in 0..3000 {
        let now = rig.clock.now_ns();
        rig.cycle.process(now);
        let r = *rig.cycle.report();
        if r.mode == Mode::Following {
            assert_eq!(r.plan_id, plan_id);
            assert!(
                r.next_index <= due,
                "went past the due sample: {}",
                r.next_index
            );
        } else if stopped_at.is_none() {
            stopped_at = Some(r.next_index);
        }
        rig.reports.push(r);
        rig.clock.advance_ns(period);
        if r.mode == Mode::Stopped {
            break;
        }
    }
    let report = *rig.cycle.report();
    assert_eq!(report.mode, Mode::Stopped, "{report:?}");
    assert_eq!(report.stop_reason, StopReason::Revoked);
    assert!(!report.awaiting_ack, "a pause, not a protective stop");
    assert_eq!(
        report.commands_refused, 0,
        "the cycle's own check had to step in"
    );
    // The arm came to rest clear of the box, along the plan.
    let mut arm = ToyArm;
    for r in &rig.reports {
        let d =
            rt_core::cycle::shield::ShieldModel::min_distance_m(&mut arm, &r.cmd.q_rad, &blocked);
        assert!(
            d > 0.0,
            "a command touched the box: {d} m at {:?}",
            r.cmd.q_rad
        );
    }
    assert!(report.cmd.dq_rad_s.iter().all(|v| v.abs() < 1e-9));
    assert!((0..DOF).any(|j| (report.cmd.q_rad[j] - START[j]).abs() > 0.01));
    rig.assert_commands_within_velocity_limits();
}

/// A box seen *moving* onto the path far ahead: no stop waits (its occupancy is predicted
/// only over a short horizon, so where it will be when the arm gets there is unknown); the
/// plan is revoked at once and the arm pauses.
#[test]
fn a_moving_box_far_ahead_stops_the_arm_at_once() {
    let (mut rig, blocked) = on_the_way_with_a_box_ahead(true);
    let now = rig.clock.now_ns();
    rig.detect_moving(blocked, now, false, rt_core::cycle::Intruders::ALL_UNKNOWN);
    assert!(scheduled(&rig.events).is_empty(), "{:?}", rig.events);
    assert_eq!(revoked(&rig.events), 1, "{:?}", rig.events);
    let now = rig.clock.now_ns();
    rig.cycle.process(now);
    assert_eq!(rig.mode(), Mode::Stopping);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Revoked);
}
