//! Issue 26, the planner fallback: when no policy passes the lookahead but the planner has
//! a collision-free path, the worker executes that path — smoothed, checked by the shield
//! and for reaching the goal like a policy's plan, re-verified on every scene change — while
//! retraining is asked for. Without the fallback, the arm holds and only retraining is
//! asked for.

use rt_core::config::RuntimeConfig;
use rt_core::cycle::shield::{Shield, ShieldLimits, ShieldModel};
use rt_core::cycle::{CycleReport, Mode};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_closest_approach_m, toy_cycle};
use rt_core::twin_thread::worker::{FallbackPlanner, PLANNER_POLICY_ID, PlanRejection};
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use shm_schemas::Executor;
use twin::Joints;

use crate::common::{Rig, START, TARGET_A, deliver, frame};

/// Straight joint-space waypoints from `from` to `to`, 20 of them.
fn straight(from: &Joints, to: &Joints, out: &mut Vec<Joints>) {
    out.clear();
    for i in 1..=20 {
        let t = f64::from(i) / 20.0;
        out.push(std::array::from_fn(|j| from[j] + (to[j] - from[j]) * t));
    }
}

/// A lookahead only the policies in `solves` pass (straight to [`TARGET_A`]); the others'
/// episodes "end in contact".
struct ScriptedLookahead {
    solves: Vec<u64>,
}

impl Lookahead for ScriptedLookahead {
    type Scene = ToyScene;
    type Policy = ToyPolicy;

    fn step_s(&self) -> f64 {
        0.05
    }

    fn policy_id(policy: &ToyPolicy) -> u64 {
        policy.id
    }

    fn lookahead(
        &mut self,
        policy: &ToyPolicy,
        _scene: &ToyScene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        straight(start_q_rad, &TARGET_A, waypoints);
        let ok = self.solves.contains(&policy.id);
        Verdict {
            task_ok: ok,
            safe: ok,
            min_distance_m: if ok { 0.1 } else { -0.01 },
            steps: 20,
            policy_id: policy.id,
        }
    }

    fn goal_approach(&mut self, _: &ToyPolicy, _: &ToyScene, path: &[Joints]) -> GoalApproach {
        GoalApproach {
            closest_m: toy_closest_approach_m(&ToyArm::points_m(&TARGET_A)[4], path),
            tolerance_m: 0.01,
        }
    }
}

/// A planner that goes straight to [`TARGET_A`] when every waypoint keeps `clearance_m` from
/// the boxes (the toy arm's own distance), and has no path otherwise.
struct StraightPlanner {
    clearance_m: f64,
    /// The goal tolerance its goal check applies, m.
    tolerance_m: f64,
}

impl FallbackPlanner<ToyScene> for StraightPlanner {
    fn plan(
        &mut self,
        scene: &ToyScene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        straight(start_q_rad, &TARGET_A, waypoints);
        let min_distance_m = waypoints
            .iter()
            .map(|q| ToyArm.min_distance_m(q, scene))
            .fold(f64::INFINITY, f64::min);
        let found = min_distance_m >= self.clearance_m;
        if !found {
            waypoints.clear();
        }
        Verdict {
            task_ok: found,
            safe: true,
            min_distance_m,
            steps: waypoints.len() as u32,
            policy_id: PLANNER_POLICY_ID,
        }
    }

    fn goal_approach(&mut self, _: &ToyScene, path_q_rad: &[Joints]) -> GoalApproach {
        GoalApproach {
            closest_m: toy_closest_approach_m(&ToyArm::points_m(&TARGET_A)[4], path_q_rad),
            tolerance_m: self.tolerance_m,
        }
    }
}

/// How a run is set up.
#[derive(Clone, Copy)]
struct Setup {
    /// The planner fallback is installed.
    fallback: bool,
    /// Its goal check's tolerance, m.
    planner_tolerance_m: f64,
    /// Policy 2, which passes the lookahead, arrives at this cycle.
    policy_2_at: Option<u64>,
}

const ON: Setup = Setup {
    fallback: true,
    planner_tolerance_m: 0.01,
    policy_2_at: None,
};

const OFF: Setup = Setup {
    fallback: false,
    ..ON
};

/// A box far from every path between START and TARGET_A.
const FAR_BOX: ([f64; 3], [f64; 3]) = ([-0.4, -0.4, 0.05], [0.05, 0.05, 0.05]);

struct Run {
    events: Vec<TwinEvent<ToyScene>>,
    reports: Vec<CycleReport>,
    arm_q: Joints,
}

/// Runs the worker and the cycle for `seconds` with policy 1 (which fails every world), the
/// planner fallback when `fallback`, and a settled detection every 8 cycles of the scene
/// `scene_at(cycle, events so far)`.
fn run(
    setup: Setup,
    seconds: f64,
    mut scene_at: impl FnMut(u64, &[TwinEvent<ToyScene>]) -> ToyScene,
) -> Run {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let (mut cycle, twin_io, _log) = toy_cycle(&cfg, START);
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).unwrap();
    let la = ScriptedLookahead { solves: vec![2] };
    let (mut twin, mut path) = TwinWorker::new(&cfg, la, Shield::new(ToyArm, limits), twin_io);
    if setup.fallback {
        twin.set_fallback_planner(Box::new(StraightPlanner {
            clearance_m: cfg.shield.min_distance_m,
            tolerance_m: setup.planner_tolerance_m,
        }));
    }
    let mut events = Vec::new();
    twin.on_policy(Box::new(ToyPolicy::random(1, TARGET_A, 1)), &mut events);
    let mut reports = Vec::new();
    for k in 0..(seconds * cfg.rate_hz) as u64 {
        let now = clock.now_ns();
        if setup.policy_2_at == Some(k) {
            twin.on_policy(Box::new(ToyPolicy::random(2, TARGET_A, 2)), &mut events);
        }
        if k.is_multiple_of(8) {
            let scene = scene_at(k, &events);
            deliver(
                &mut path,
                &mut twin,
                &frame(scene, now, true, true),
                &mut events,
            );
        }
        twin.step(&mut events);
        cycle.process(now);
        reports.push(*cycle.report());
        clock.advance_ns(cfg.period_ns());
    }
    Run {
        events,
        reports,
        arm_q: cycle.link().q_rad(),
    }
}

fn far_box_scene() -> ToyScene {
    let mut s = ToyScene::empty();
    s.push_obstacle(FAR_BOX.0, FAR_BOX.1);
    s
}

fn verdicts_by(events: &[TwinEvent<ToyScene>], executor: Executor) -> Vec<Verdict> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict {
                verdict, source, ..
            } if source.executor == executor => Some(*verdict),
            _ => None,
        })
        .collect()
}

fn approved_by(events: &[TwinEvent<ToyScene>]) -> Vec<u64> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::PlanApproved { policy_id, .. } => Some(*policy_id),
            _ => None,
        })
        .collect()
}

fn retrains(events: &[TwinEvent<ToyScene>]) -> usize {
    events
        .iter()
        .filter(|e| matches!(e, TwinEvent::Retrain { .. }))
        .count()
}

/// No command came within the shield's clearance of a box of the scene in force.
fn assert_no_contact(r: &Run) {
    for rep in &r.reports {
        assert!(rep.clearance_m > 0.0, "contact: {rep:?}");
    }
}

#[test]
fn with_the_fallback_the_planner_moves_the_arm_to_the_goal_while_retraining_is_asked_for() {
    let r = run(ON, 4.0, |_, _| far_box_scene());
    assert!(retrains(&r.events) >= 1, "{:?}", r.events);
    assert!(
        verdicts_by(&r.events, Executor::Policy)
            .iter()
            .all(|v| !v.task_ok),
        "{:?}",
        r.events
    );
    let planner = verdicts_by(&r.events, Executor::Planner);
    assert!(
        planner.first().is_some_and(|v| v.task_ok && v.safe),
        "{:?}",
        r.events
    );
    assert_eq!(
        approved_by(&r.events),
        vec![PLANNER_POLICY_ID],
        "{:?}",
        r.events
    );
    assert!(Rig::near(&r.arm_q, &TARGET_A, 1e-3), "{:?}", r.arm_q);
    assert_eq!(r.reports.last().map(|x| x.mode), Some(Mode::Idle));
    assert_no_contact(&r);
}

#[test]
fn without_the_fallback_the_arm_holds_and_retraining_is_asked_for() {
    let r = run(OFF, 2.0, |_, _| far_box_scene());
    assert_eq!(retrains(&r.events), 1, "{:?}", r.events);
    assert!(approved_by(&r.events).is_empty(), "{:?}", r.events);
    assert!(verdicts_by(&r.events, Executor::Planner).is_empty());
    assert!(Rig::near(&r.arm_q, &START, 1e-9), "{:?}", r.arm_q);
}

#[test]
fn a_box_on_the_planner_path_during_its_execution_revokes_it_and_the_arm_stops_short() {
    let target_tcp = ToyArm::points_m(&TARGET_A)[4];
    // Once the planner's plan has run for 0.4 s, a box appears around the goal pose's TCP.
    let mut moving_since: Option<u64> = None;
    let r = run(ON, 4.0, |k, events| {
        if moving_since.is_none() && !approved_by(events).is_empty() {
            moving_since = Some(k);
        }
        let mut s = far_box_scene();
        if moving_since.is_some_and(|k0| k >= k0 + 100) {
            s.push_obstacle(target_tcp, [0.08, 0.08, 0.08]);
        }
        s
    });
    assert_eq!(
        approved_by(&r.events),
        vec![PLANNER_POLICY_ID],
        "{:?}",
        r.events
    );
    assert!(
        r.events
            .iter()
            .any(|e| matches!(e, TwinEvent::Revoked { .. })),
        "{:?}",
        r.events
    );
    // Re-planned in the new scene: the planner has no path now.
    assert!(
        verdicts_by(&r.events, Executor::Planner)
            .last()
            .is_some_and(|v| !v.task_ok),
        "{:?}",
        r.events
    );
    assert!(!Rig::near(&r.arm_q, &TARGET_A, 1e-2), "{:?}", r.arm_q);
    assert!(matches!(
        r.reports.last().map(|x| x.mode),
        Some(Mode::Stopped | Mode::Idle)
    ));
    assert_no_contact(&r);
}

#[test]
fn a_planner_path_whose_smoothed_plan_misses_the_goal_is_rejected() {
    // The same checks as a policy's plan: the smoothed path must reach the goal by the
    // planner's own measure (here a tolerance nothing meets).
    let setup = Setup {
        planner_tolerance_m: -1.0,
        ..ON
    };
    let r = run(setup, 2.0, |_, _| far_box_scene());
    assert!(approved_by(&r.events).is_empty(), "{:?}", r.events);
    assert!(
        r.events.iter().any(|e| matches!(
            e,
            TwinEvent::PlanRejected {
                policy_id: PLANNER_POLICY_ID,
                why: PlanRejection::MissesGoal(_),
            }
        )),
        "{:?}",
        r.events
    );
    assert!(Rig::near(&r.arm_q, &START, 1e-9), "{:?}", r.arm_q);
}

#[test]
fn a_policy_that_passes_replaces_the_planner_at_once() {
    // Policy 2 (which passes) arrives while the planner's plan runs: its plan joins it.
    let setup = Setup {
        policy_2_at: Some(100),
        ..ON
    };
    let r = run(setup, 4.0, |_, _| far_box_scene());
    let approvals: Vec<(u64, bool)> = r
        .events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::PlanApproved {
                policy_id, joins, ..
            } => Some((*policy_id, *joins)),
            _ => None,
        })
        .collect();
    assert_eq!(
        approvals,
        vec![(PLANNER_POLICY_ID, false), (2, true)],
        "{:?}",
        r.events
    );
    assert!(Rig::near(&r.arm_q, &TARGET_A, 1e-3), "{:?}", r.arm_q);
    assert_no_contact(&r);
}
