//! Scenario tests of the cycle and the twin worker together (toy twin, in-process arm,
//! manual clock): following an approved plan, hot-swaps that join only after a passing
//! lookahead, revocation and controlled stops, stale inputs, a lost link, determinism.

use std::sync::atomic::Ordering;

use crate::common::{Rig, START, TARGET_A, TARGET_B};
use rt_core::cycle::shield::ShieldModel;
use rt_core::cycle::{Mode, StopReason};
use rt_core::testing::toy::ToyArm;
use rt_core::twin_thread::TwinEvent;

#[test]
fn an_approved_plan_is_followed_to_the_policy_target_and_the_arm_rests() {
    let mut rig = Rig::new();
    rig.run(10);
    assert_eq!(rig.mode(), Mode::Idle, "no policy, no plan");
    rig.policy(1, TARGET_A);
    rig.run(2500);
    assert_eq!(rig.approvals().len(), 1, "{:?}", rig.events);
    assert_eq!(rig.mode(), Mode::Idle);
    assert!(
        Rig::near(&rig.arm_q(), &TARGET_A, 0.03),
        "{:?}",
        rig.arm_q()
    );
    let r = rig.cycle.report();
    assert_eq!(r.stops, 0);
    assert!(r.cmd.dq_rad_s.iter().all(|v| *v == 0.0));
    // every command respected the velocity limit
    rig.assert_commands_within_velocity_limits();
}

#[test]
fn after_the_goal_the_arm_rests_then_returns_home_along_its_path_and_stays() {
    let cfg = rt_core::config::RuntimeConfig::xarm5_default();
    assert!(cfg.return_home);
    let dwell_cycles = (cfg.dwell_at_goal_s * cfg.rate_hz) as usize;
    let mut rig = Rig::with_config(cfg);
    rig.policy(1, TARGET_A);
    rig.run(4000);
    let homeward = rig
        .events
        .iter()
        .filter(|e| matches!(e, TwinEvent::ReturningHome { .. }))
        .count();
    assert_eq!(homeward, 1, "{:?}", rig.events);
    assert_eq!(
        rig.approvals().len(),
        1,
        "no second episode: {:?}",
        rig.events
    );
    assert_eq!(rig.mode(), Mode::Idle);
    assert!(Rig::near(&rig.arm_q(), &START, 1e-6), "{:?}", rig.arm_q());
    // It rested at the goal for the dwell before turning back.
    let resting_at_goal = rig
        .reports
        .windows(2)
        .filter(|w| w[0].cmd.q_rad == w[1].cmd.q_rad && Rig::near(&w[1].cmd.q_rad, &TARGET_A, 0.03))
        .count();
    assert!(
        resting_at_goal >= dwell_cycles,
        "{resting_at_goal} cycles at rest at the goal"
    );
    // The way back respected the velocity limit like every plan.
    rig.assert_commands_within_velocity_limits();
    assert_eq!(rig.cycle.report().stops, 0);
}

#[test]
fn a_hot_swap_joins_the_running_plan_only_after_its_lookahead_passes() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(150);
    assert_eq!(rig.mode(), Mode::Following);
    let before = rig.cycle.report().plans_taken;
    // A policy whose episode leaves the joint limits fails verification: the arm keeps
    // executing plan 1.
    rig.policy(2, [0.0, 2.5, 0.0, 0.0, 0.0]);
    rig.run(5);
    assert!(
        rig.events
            .iter()
            .any(|e| matches!(e, TwinEvent::PlanRejected { policy_id: 2, .. })),
        "{:?}",
        rig.events
    );
    // The policy library: the refused policy 2 falls back to the base policy 1, whose plan
    // (to the same target) may join; nothing of policy 2 reaches the cycle.
    assert!(
        rig.approvals().iter().all(|a| a.1 == 1),
        "a refused policy's plan was approved: {:?}",
        rig.events
    );
    assert!(rig.cycle.report().plans_taken >= before);
    assert_eq!(rig.cycle.report().policy_id, 1);
    // A good policy: plan approved, joins the running one, the arm ends at its target.
    rig.policy(3, TARGET_B);
    // (Planned once the base's join, if any, has taken over.)
    for _ in 0..200 {
        rig.run(1);
        if rig.approvals().iter().any(|a| a.1 == 3) {
            break;
        }
    }
    let joined: Vec<_> = rig.approvals().into_iter().filter(|a| a.1 == 3).collect();
    assert_eq!(joined.len(), 1, "{:?}", rig.events);
    assert!(joined[0].2, "the swap should join the running plan");
    rig.run(3000);
    assert_eq!(rig.cycle.report().policy_id, 3);
    assert_eq!(rig.cycle.report().stops, 0, "the join must be continuous");
    assert!(
        Rig::near(&rig.arm_q(), &TARGET_B, 0.03),
        "{:?}",
        rig.arm_q()
    );
    // continuity: no command jumped more than the velocity limit allows
    for w in rig.reports.windows(2) {
        for j in 0..5 {
            let v = (w[1].cmd.q_rad[j] - w[0].cmd.q_rad[j]) / 0.004;
            assert!(
                v.abs() <= rig.cfg.limits.max_velocity_rad_s[j] + 1e-6,
                "jump {v}"
            );
        }
    }
}

#[test]
fn a_scene_change_that_makes_the_plan_unsafe_stops_the_arm_and_requests_retraining() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert_eq!(rig.mode(), Mode::Following);
    // Put a box where the plan passes later.
    let wp = {
        let mut la = rt_core::testing::toy::ToyLookahead::default();
        let mut wps = Vec::new();
        use rt_core::twin_thread::Lookahead;
        la.lookahead(
            rig.twin.policy().expect("policy"),
            &rig.scene,
            &START,
            &mut wps,
        );
        wps[wps.len() * 2 / 3]
    };
    rig.scene
        .push_obstacle(ToyArm.tcp_position_m(&wp), [0.08; 3]);
    let retrains_before = rig.retrains();
    rig.run(300);
    assert!(
        rig.events
            .iter()
            .any(|e| matches!(e, TwinEvent::Revoked { plan_id: 1, .. })),
        "{:?}",
        rig.events
    );
    assert_eq!(rig.mode(), Mode::Stopped);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Revoked);
    assert!(rig.retrains() > retrains_before, "no retrain request");
    let at_stop = rig.arm_q();
    rig.run(500);
    assert_eq!(
        rig.mode(),
        Mode::Stopped,
        "resumed without a fresh approved plan"
    );
    assert!(Rig::near(&rig.arm_q(), &at_stop, 1e-9));
    // A retrained policy that is safe in the new scene resumes from the stopped pose.
    rig.scene = rt_core::testing::toy::ToyScene::empty();
    rig.policy(2, TARGET_B);
    rig.run(3000);
    assert!(Rig::near(&rig.arm_q(), &TARGET_B, 0.03));
}

/// Issue 14, items 1, 3 and 7: a refused frame (overfull, stale stamp, second publisher…)
/// stops the arm at once — not after the detection age runs out — and nothing is planned
/// until a good frame arrives.
#[test]
fn a_refused_detection_frame_stops_the_arm_at_once_and_a_good_frame_resumes_it() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert_eq!(rig.mode(), Mode::Following);
    rig.refusing = true;
    rig.run(9); // one refused frame (every 8 cycles)
    assert_eq!(
        rig.mode(),
        Mode::Stopping,
        "the stop begins with the refused frame"
    );
    assert_eq!(rig.cycle.report().stop_reason, StopReason::DetectionRefused);
    rig.run(500);
    assert_eq!(rig.mode(), Mode::Stopped);
    let approvals = rig.approvals().len();
    assert_eq!(approvals, 1, "no plan while the frames are refused");
    rig.refusing = false;
    rig.run(2500);
    assert!(rig.approvals().len() > approvals, "{:?}", rig.approvals());
    assert!(Rig::near(&rig.arm_q(), &TARGET_A, 0.03));
}

/// Issue 14, item 2: frames without a goal gave a plan toward an invented goal. Now no
/// plan is made, the arm holds, and the verdict says why; a goal seen again plans.
#[test]
fn without_a_goal_nothing_is_planned_and_the_arm_holds() {
    let mut rig = Rig::new();
    rig.goal_seen = false;
    rig.policy(1, TARGET_A);
    rig.run(500);
    assert_eq!(rig.mode(), Mode::Idle);
    assert!(rig.approvals().is_empty(), "{:?}", rig.events);
    assert!(Rig::near(&rig.arm_q(), &START, 1e-9));
    let no_goal = rig
        .events
        .iter()
        .filter(|e| matches!(e, TwinEvent::NoGoal { policy_id: 1 }))
        .count();
    assert_eq!(no_goal, 1, "said once: {:?}", rig.events);
    rig.goal_seen = true;
    rig.run(2500);
    assert_eq!(rig.approvals().len(), 1);
    assert!(Rig::near(&rig.arm_q(), &TARGET_A, 0.03));
}

#[test]
fn stale_detections_stop_the_arm_and_it_resumes_only_with_a_fresh_plan() {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert_eq!(rig.mode(), Mode::Following);
    rig.detections_on = false;
    rig.run(200); // 0.8 s > 0.5 s
    assert_eq!(rig.mode(), Mode::Stopped);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::StaleDetection);
    rig.detections_on = true;
    rig.run(2500);
    assert!(rig.approvals().len() >= 2, "{:?}", rig.approvals());
    assert!(Rig::near(&rig.arm_q(), &TARGET_A, 0.03));
}

/// What followed a pause on the way to TARGET_A (policy 1; stale detections stop the arm,
/// then 4 000 cycles with fresh ones): the rig, where the brake left the arm, the plans
/// approved and ways home after the stop (in order, as `(is a way home, joins)`), and the
/// measured path after it.
struct AfterPause {
    rig: Rig,
    stopped_at: twin::Joints,
    plans: Vec<(bool, bool)>,
    path: Vec<twin::Joints>,
}

fn after_a_pause(continue_after_pause: bool) -> AfterPause {
    let mut cfg = rt_core::config::RuntimeConfig::xarm5_default();
    cfg.continue_after_pause = continue_after_pause;
    let mut rig = Rig::with_config(cfg);
    rig.policy(1, TARGET_A);
    rig.run(100);
    assert_eq!(rig.mode(), Mode::Following);
    rig.detections_on = false;
    rig.run(200);
    assert_eq!(rig.mode(), Mode::Stopped);
    let stopped_at = rig.arm_q();
    let (events_at_stop, reports_at_stop) = (rig.events.len(), rig.reports.len());
    rig.detections_on = true;
    rig.run(4000);
    let plans = rig.events[events_at_stop..]
        .iter()
        .filter_map(|e| match e {
            TwinEvent::ReturningHome { .. } => Some((true, false)),
            TwinEvent::PlanApproved { joins, .. } => Some((false, *joins)),
            _ => None,
        })
        .collect();
    let path = rig.reports[reports_at_stop..]
        .iter()
        .map(|r| r.measured_q_rad)
        .collect();
    AfterPause {
        rig,
        stopped_at,
        plans,
        path,
    }
}

/// Issue 33 item 5, continuation: after a pause the arm goes on to its goal from where it
/// stopped, by a plan checked from there (before: always home along its path first, then the
/// episode again from the start), and home after the goal as ever.
#[test]
fn after_a_pause_the_arm_goes_on_to_its_goal_from_where_it_stopped() {
    let a = after_a_pause(true);
    assert_eq!(a.plans.first(), Some(&(false, false)), "{:?}", a.plans);
    let at_goal = a
        .path
        .iter()
        .position(|q| Rig::near(q, &TARGET_A, 0.03))
        .expect("the arm reached its goal");
    assert!(
        !a.path[..at_goal].iter().any(|q| Rig::near(q, &START, 1e-3)),
        "the arm went home before the goal"
    );
    // Then home after the goal, as ever.
    assert!(a.plans.contains(&(true, false)), "{:?}", a.plans);
}

/// With `continue_after_pause = false`: home along the path first, as before.
#[test]
fn after_a_stop_on_the_way_the_arm_still_finds_its_way_home() {
    let a = after_a_pause(false);
    assert!(a.rig.approvals().len() >= 2, "{:?}", a.rig.approvals());
    // First back along the path from where the brake left the arm (no new episode plan
    // from the stop pose), then the episode again from home, then home after the goal.
    assert_eq!(a.plans.first(), Some(&(true, false)), "{:?}", a.plans);
    let home_again = a
        .path
        .iter()
        .position(|q| Rig::near(q, &START, 1e-3))
        .expect("the arm went home first");
    assert!(
        a.path[home_again..]
            .iter()
            .any(|q| Rig::near(q, &TARGET_A, 0.03)),
        "then it reached the goal from home"
    );
    // Home is where the excursion began, not where the brake left the arm.
    assert!(!Rig::near(&a.stopped_at, &START, 0.01));
    assert!(
        Rig::near(&a.rig.arm_q(), &START, 1e-6),
        "{:?}",
        a.rig.arm_q()
    );
}

/// A rig whose link was cut 150 cycles into plan 1 (while following) and then run 300 more
/// cycles; the link's connection flag is returned to restore it.
pub(crate) fn link_lost_while_following() -> (Rig, std::sync::Arc<std::sync::atomic::AtomicBool>) {
    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(150);
    assert_eq!(rig.mode(), Mode::Following);
    let conn = rig.cycle.link().connection();
    conn.store(false, Ordering::Release);
    rig.run(300);
    (rig, conn)
}

#[test]
fn a_lost_link_brings_the_command_to_a_controlled_stop() {
    let (rig, _conn) = link_lost_while_following();
    assert_eq!(rig.mode(), Mode::Stopped);
    assert_eq!(rig.cycle.report().stop_reason, StopReason::LinkLost);
    let r = rig.cycle.report();
    assert!(r.cmd.dq_rad_s.iter().all(|v| *v == 0.0));
}

#[test]
fn when_the_link_returns_the_arm_is_held_where_it_is_and_a_fresh_plan_moves_it() {
    let (mut rig, conn) = link_lost_while_following();
    assert_eq!(rig.mode(), Mode::Stopped);
    // The arm got no commands while the link was down; the brake ran on without it.
    let arm_at = rig.arm_q();
    let braked_to = rig.cycle.report().cmd.q_rad;
    assert!(
        !Rig::near(&arm_at, &braked_to, 1e-3),
        "{arm_at:?} {braked_to:?}"
    );
    conn.store(true, Ordering::Release);
    rig.run(1);
    let r = rig.cycle.report();
    assert_eq!(
        r.cmd.q_rad, arm_at,
        "the first command after the link returns holds the arm"
    );
    assert!(r.cmd.dq_rad_s.iter().all(|v| *v == 0.0));
    // Latched: a fresh policy's plan does not move the arm before the operator
    // acknowledges the protective stop.
    assert!(r.awaiting_ack, "a lost link latches the stop");
    rig.policy(2, TARGET_B);
    rig.run(600);
    assert!(
        Rig::near(&rig.arm_q(), &arm_at, 1e-9),
        "moved without an acknowledgement: {:?}",
        rig.arm_q()
    );
    // The acknowledgement releases it; a fresh plan starts from there and reaches its target.
    rig.cycle.control().acknowledge_latched();
    rig.run(1);
    assert!(!rig.cycle.report().awaiting_ack);
    rig.policy(3, TARGET_B);
    rig.run(1500);
    assert!(
        Rig::near(&rig.arm_q(), &TARGET_B, 0.03),
        "{:?}",
        rig.arm_q()
    );
}

#[test]
fn an_acknowledgement_clears_only_the_stop_it_names() {
    let (mut rig, conn) = link_lost_while_following();
    conn.store(true, Ordering::Release);
    rig.run(1);
    let control = rig.cycle.control().clone();
    let (seq, code) = control.latched().expect("a lost link latches");
    assert_eq!(seq, 1, "the run's first latch");
    assert_eq!(code, StopReason::LinkLost.code());
    // A stop that is not the one latched (a later number, never latched) clears nothing.
    control.acknowledge(seq + 1);
    rig.run(1);
    let r = rig.cycle.report();
    assert!(
        r.awaiting_ack,
        "an acknowledgement of another stop cleared the latch"
    );
    assert_eq!(r.acks_refused, 1);
    // The named one does.
    control.acknowledge(seq);
    rig.run(1);
    assert!(!rig.cycle.report().awaiting_ack);
    assert_eq!(control.latched(), None);
    // The next latch has the next number; the earlier acknowledgement, replayed (a script
    // that acknowledges whatever happens, a stale request), does not clear it.
    rig.policy(2, TARGET_B);
    rig.run(150);
    conn.store(false, Ordering::Release);
    rig.run(300);
    conn.store(true, Ordering::Release);
    rig.run(1);
    assert_eq!(
        control.latched().map(|l| l.0),
        Some(2),
        "{:?}",
        rig.cycle.report()
    );
    control.acknowledge(seq);
    rig.run(1);
    let r = rig.cycle.report();
    assert!(
        r.awaiting_ack,
        "a replayed acknowledgement of stop #1 cleared stop #2"
    );
    assert_eq!(r.acks_refused, 2);
}

#[test]
fn runs_are_deterministic_under_the_manual_clock() {
    let run = || {
        let mut rig = Rig::new();
        rig.policy(1, TARGET_A);
        rig.run(200);
        rig.policy(2, TARGET_B);
        rig.run(800);
        rig.reports
            .iter()
            .map(|r| (r.mode, r.plan_id, r.cmd.q_rad))
            .collect::<Vec<_>>()
    };
    assert_eq!(run(), run());
}

#[test]
fn the_cycle_shield_stops_a_plan_that_runs_into_the_live_scene_without_the_twin() {
    use rt_core::config::RuntimeConfig;
    use rt_core::cycle::brake::Brake;
    use rt_core::cycle::link::InProcessArm;
    use rt_core::cycle::plan::Plan;
    use rt_core::cycle::shield::{Shield, ShieldLimits, ShieldViolation};
    use rt_core::cycle::{self, Cycle, CycleConfig, SceneUpdate};
    use rt_core::testing::toy::ToyScene;

    let cfg = RuntimeConfig::xarm5_default();
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (mut twin_io, cycle_io, _log) = cycle::wire::<ToyScene>();
    let arm = InProcessArm::new(
        START,
        cfg.limits.joint_min_rad,
        cfg.limits.joint_max_rad,
        [3.0; 5],
    );
    let mut cyc = Cycle::new(
        CycleConfig::from_runtime(&cfg),
        Shield::new(ToyArm, limits),
        Brake::new(&cfg.limits),
        arm,
        cycle_io,
    );
    let period = cfg.period_ns();
    let mut now = 1_000_000_000;
    cyc.start(now).expect("start");
    // A hand-made plan: 2 s of joint-space interpolation from START to TARGET_A.
    let n = 500;
    let mut plan = Plan::with_capacity(1, 1, 0.004, n);
    for k in 1..=n {
        let t = k as f64 / n as f64;
        let s = t * t * (3.0 - 2.0 * t);
        let q = std::array::from_fn(|j| START[j] + (TARGET_A[j] - START[j]) * s);
        plan.push(q, [0.0; 5], [0.0; 5]);
    }
    let late = plan.q_rad[400];
    assert!(twin_io.plans.send(Box::new(plan)).is_ok());
    let mut scene = ToyScene::empty();
    for _ in 0..100 {
        twin_io.scenes.send(SceneUpdate {
            scene,
            stamp_ns: now,
            refused: false,
            intruders: cycle::Intruders::NONE,
        });
        cyc.process(now);
        now += period;
    }
    assert_eq!(cyc.mode(), Mode::Following);
    // An obstacle appears where the plan goes later; nobody revokes the plan, the cycle's
    // own shield must stop the arm before it gets there.
    scene.push_obstacle(ToyArm.tcp_position_m(&late), [0.06; 3]);
    let mut min_clearance = f64::INFINITY;
    for _ in 0..500 {
        twin_io.scenes.send(SceneUpdate {
            scene,
            stamp_ns: now,
            refused: false,
            intruders: cycle::Intruders::NONE,
        });
        cyc.process(now);
        let q = cyc.report().cmd.q_rad;
        min_clearance = min_clearance.min(ToyArm.min_distance_m(&q, &scene));
        now += period;
    }
    assert_eq!(cyc.mode(), Mode::Stopped);
    assert!(
        matches!(
            cyc.report().stop_reason,
            StopReason::Shield(ShieldViolation::Clearance { .. })
        ),
        "{:?}",
        cyc.report().stop_reason
    );
    assert!(
        min_clearance > 0.0,
        "the arm touched the obstacle: {min_clearance}"
    );
    twin_io.plans.collect_returned();
}
