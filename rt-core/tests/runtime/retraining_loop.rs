//! Issue 40 item 2, a loop that converges or says why, on the production worker and cycle
//! (toy arm, scripted lookahead):
//! - with camera goals, a goal reached is not driven again: a policy received once the arm
//!   is back home is judged from there (a verdict in phase `verification`) and not sent;
//! - a retrained policy refused in the scene it was retrained for is a refused retraining,
//!   and after `max_refused_retrainings` of them the scene is "not learned": no more
//!   retraining is asked for it.

use rt_core::config::RuntimeConfig;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_cycle};
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use shm_schemas::PhaseCode;
use twin::Joints;

use crate::common::{START, TARGET_A, deliver, frame};

/// A scripted lookahead: straight waypoints from where the arm is to [`TARGET_A`] for every
/// policy; only the policies in `solves` pass (the others "end in contact"), and those in
/// `from_home_only` pass only from [`START`] (a join from a moving arm fails). A scene with
/// any box blocks every policy.
struct ScriptedLookahead {
    solves: Vec<u64>,
    from_home_only: Vec<u64>,
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
        scene: &ToyScene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        waypoints.clear();
        for i in 1..=20 {
            let t = f64::from(i) / 20.0;
            waypoints.push(std::array::from_fn(|j| {
                start_q_rad[j] + (TARGET_A[j] - start_q_rad[j]) * t
            }));
        }
        let at_home = start_q_rad
            .iter()
            .zip(START.iter())
            .all(|(a, b)| (a - b).abs() < 1e-6);
        let ok = scene.count == 0
            && (self.solves.contains(&policy.id)
                || (at_home && self.from_home_only.contains(&policy.id)));
        Verdict {
            task_ok: ok,
            safe: ok,
            min_distance_m: if ok { 0.1 } else { -0.01 },
            steps: 20,
            policy_id: policy.id,
        }
    }

    fn goal_approach(&mut self, _: &ToyPolicy, _: &ToyScene, _: &[Joints]) -> GoalApproach {
        GoalApproach {
            closest_m: 0.0,
            tolerance_m: 0.02,
        }
    }
}

/// The worker and the cycle on one settled scene with camera goals; `arrivals` are
/// `(cycle, policy id)`: each policy is received before that cycle of the run.
fn run(
    cfg: &RuntimeConfig,
    la: ScriptedLookahead,
    arrivals: &[(u64, u64)],
    seconds: u64,
) -> Vec<TwinEvent<ToyScene>> {
    run_in(cfg, la, arrivals, seconds, |_| ToyScene::empty())
}

/// [`run`] with the scene of each frame from `scene_at(cycle)`.
fn run_in(
    cfg: &RuntimeConfig,
    la: ScriptedLookahead,
    arrivals: &[(u64, u64)],
    seconds: u64,
    scene_at: impl Fn(u64) -> ToyScene,
) -> Vec<TwinEvent<ToyScene>> {
    let (mut cycle, twin_io, _log) = toy_cycle(cfg, START);
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).unwrap();
    let (mut twin, mut path) = TwinWorker::new(cfg, la, Shield::new(ToyArm, limits), twin_io);
    let mut events = Vec::new();
    let per_s = cfg.rate_hz as u64;
    for k in 0..seconds * per_s {
        for &(at, id) in arrivals {
            if k == at {
                twin.on_policy(Box::new(ToyPolicy::random(id, TARGET_A, id)), &mut events);
            }
        }
        let now = clock.now_ns();
        if k.is_multiple_of(8) {
            deliver(
                &mut path,
                &mut twin,
                &frame(scene_at(k), now, true, true),
                &mut events,
            );
        }
        twin.step(&mut events);
        cycle.process(now);
        clock.advance_ns(cfg.period_ns());
    }
    events
}

fn solving(solves: Vec<u64>) -> ScriptedLookahead {
    ScriptedLookahead {
        solves,
        from_home_only: Vec::new(),
    }
}

/// The cycle at `s` seconds.
fn at_s(cfg: &RuntimeConfig, s: f64) -> u64 {
    (s * cfg.rate_hz) as u64
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

#[test]
fn a_goal_reached_is_not_driven_again_and_a_policy_received_then_is_judged_from_home() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.dwell_at_goal_s = 0.2;
    // Policy 1 reaches the goal (1 s), rests, and returns home (about 1 s); policy 2
    // arrives at 5 s, with the arm at home in the same scene.
    let events = run(
        &cfg,
        solving(vec![1, 2]),
        &[(0, 1), (at_s(&cfg, 5.0), 2)],
        8,
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::ReturningHome { .. })),
        "{events:?}"
    );
    // Only policy 1's episode was driven; policy 2 was judged from home, not sent.
    assert_eq!(approved_by(&events), vec![1], "{events:?}");
    let judged: Vec<(PhaseCode, bool)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict {
                verdict, source, ..
            } if verdict.policy_id == 2 => Some((source.phase, verdict.task_ok && verdict.safe)),
            _ => None,
        })
        .collect();
    assert_eq!(judged, vec![(PhaseCode::Verification, true)], "{events:?}");
}

#[test]
fn with_action_goals_a_new_policy_after_the_goal_is_driven_as_before() {
    // Each Reach goal is a request to drive: the rest after the goal is camera goals' only.
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.dwell_at_goal_s = 0.2;
    cfg.goal.source = shm_schemas::runtime_view::GoalSource::Action;
    let events = run(
        &cfg,
        solving(vec![1, 2]),
        &[(0, 1), (at_s(&cfg, 5.0), 2)],
        8,
    );
    assert_eq!(approved_by(&events), vec![1, 2], "{events:?}");
}

#[test]
fn refused_retrainings_are_said_and_bounded_and_the_scene_is_then_not_learned() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    cfg.max_refused_retrainings = 2;
    // Nothing solves the scene: the base policy 1 asks for retraining; its answers 2, 3 and
    // 4 all fail it.
    let arrivals = [1, 2, 3, 4].map(|id| (at_s(&cfg, (id - 1) as f64), id));
    let events = run(&cfg, solving(vec![]), &arrivals, 5);
    let asked: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Retrain { verdict, .. } => Some(verdict.policy_id),
            _ => None,
        })
        .collect();
    // Policy 2 refused (1 of 2): asked again with its verdict; policy 3 refused (2 of 2): not
    // learned; policy 4: nothing more is asked.
    assert_eq!(asked, vec![1, 2], "{events:?}");
    let refused: Vec<(u64, u32)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::RetrainingRefused { verdict, refusals } => {
                Some((verdict.policy_id, *refusals))
            }
            _ => None,
        })
        .collect();
    assert_eq!(refused, vec![(2, 1)], "{events:?}");
    let not_learned: Vec<(u64, u32)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::NotLearned {
                verdict, refusals, ..
            } => Some((verdict.policy_id, *refusals)),
            _ => None,
        })
        .collect();
    assert_eq!(not_learned, vec![(3, 2)], "{events:?}");
    assert!(approved_by(&events).is_empty(), "{events:?}");
}

#[test]
fn a_policy_that_arrives_while_the_arm_moves_and_cannot_join_is_judged_from_home_after_the_goal() {
    // Policy 2 (a retrained one, as the demo's act 2 on a slow machine) arrives halfway
    // through policy 1's plan; its join from the moving arm fails, the base policy's join
    // passes and reaches the goal. Back home, policy 2 is judged from there (it passes) and
    // not driven; no retraining is asked for.
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.dwell_at_goal_s = 0.2;
    let la = ScriptedLookahead {
        solves: vec![1],
        from_home_only: vec![2],
    };
    let events = run(&cfg, la, &[(0, 1), (at_s(&cfg, 0.5), 2)], 6);
    assert!(approved_by(&events).iter().all(|&id| id == 1), "{events:?}");
    let judged: Vec<(PhaseCode, bool)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict {
                verdict, source, ..
            } if verdict.policy_id == 2 => Some((source.phase, verdict.task_ok && verdict.safe)),
            _ => None,
        })
        .collect();
    assert_eq!(
        judged.last(),
        Some(&(PhaseCode::Verification, true)),
        "{events:?}"
    );
    assert!(
        judged[..judged.len() - 1].iter().all(|(_, ok)| !ok),
        "{events:?}"
    );
    assert!(
        !events
            .iter()
            .any(|e| matches!(e, TwinEvent::Retrain { .. })),
        "{events:?}"
    );
}

#[test]
fn a_policy_that_arrives_on_the_way_home_does_not_join_it_and_is_judged_at_home() {
    // The demo's act 2 with a slow learner: the retrained policy arrives while the arm
    // returns home from the goal it reached. Before, its episode joined the way home and
    // drove to the goal again.
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.dwell_at_goal_s = 0.2;
    // Policy 1 reaches the goal at about 1 s, rests 0.2 s, and is on its way home by 1.6 s.
    let events = run(
        &cfg,
        solving(vec![1, 2]),
        &[(0, 1), (at_s(&cfg, 1.6), 2)],
        6,
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::ReturningHome { .. })),
        "{events:?}"
    );
    assert_eq!(approved_by(&events), vec![1], "{events:?}");
    let judged: Vec<(PhaseCode, bool)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict {
                verdict, source, ..
            } if verdict.policy_id == 2 => Some((source.phase, verdict.task_ok && verdict.safe)),
            _ => None,
        })
        .collect();
    assert_eq!(judged, vec![(PhaseCode::Verification, true)], "{events:?}");
}

#[test]
fn back_in_a_scene_after_another_one_its_goal_is_driven_again() {
    // Scene A's goal reached; at home the world changes to B (a box that blocks every
    // policy: nothing is driven) and back to A: the world changed, so A's goal is driven
    // again (the launcher's acts expect one goal per world change). Before, A's goal stayed
    // "reached" through B and the arm was held.
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.dwell_at_goal_s = 0.2;
    let mut b = ToyScene::empty();
    b.push_obstacle([5.0, 5.0, 5.0], [0.1, 0.1, 0.1]);
    let (b_from, a_again) = (at_s(&cfg, 4.0), at_s(&cfg, 5.0));
    let events = run_in(&cfg, solving(vec![1]), &[(0, 1)], 8, |k| {
        if (b_from..a_again).contains(&k) {
            b
        } else {
            ToyScene::empty()
        }
    });
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::Retrain { .. })),
        "B refused: {events:?}"
    );
    assert_eq!(approved_by(&events), vec![1, 1], "{events:?}");
}
