//! Issue 15, retraining that keeps what it knew: the worker keeps the first policy it
//! received (the bundled generalist) when a retrained one replaces it, and the lookahead
//! falls back to it when the current policy fails a world. Without the library, a
//! fine-tuned policy that forgot a world the generalist solved refuses it and asks for
//! retraining again.

use rt_core::config::RuntimeConfig;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_cycle};
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use twin::Joints;

use crate::common::{START, TARGET_A, deliver, frame};

/// A scripted lookahead: the same straight waypoints to [`TARGET_A`] for every policy; only
/// the policies in `solves` pass (the others "end in contact").
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
        _start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        waypoints.clear();
        for i in 1..=20 {
            let t = f64::from(i) / 20.0;
            waypoints.push(std::array::from_fn(|j| {
                START[j] + (TARGET_A[j] - START[j]) * t
            }));
        }
        let ok = self.solves.contains(&policy.id);
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

/// Runs the worker and the cycle for 1 s with `policies` received in order and a fresh,
/// settled detection every 8 cycles; returns the events.
fn run(solves: Vec<u64>, policies: &[u64]) -> Vec<TwinEvent<ToyScene>> {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let (mut cycle, twin_io, _log) = toy_cycle(&cfg, START);
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).unwrap();
    let la = ScriptedLookahead { solves };
    let (mut twin, mut path) = TwinWorker::new(&cfg, la, Shield::new(ToyArm, limits), twin_io);
    let mut events = Vec::new();
    for id in policies {
        twin.on_policy(Box::new(ToyPolicy::random(*id, TARGET_A, *id)), &mut events);
    }
    for k in 0..cfg.rate_hz as u64 {
        let now = clock.now_ns();
        if k.is_multiple_of(8) {
            deliver(
                &mut path,
                &mut twin,
                &frame(ToyScene::empty(), now, true, true),
                &mut events,
            );
        }
        twin.step(&mut events);
        cycle.process(now);
        clock.advance_ns(cfg.period_ns());
    }
    events
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

#[test]
fn a_world_the_base_policy_solves_is_planned_with_it_after_a_retrained_policy_fails() {
    // Policy 1 (the generalist) solves the world, policy 2 (retrained elsewhere) does not:
    // the current policy's verdict fails, the base's passes and its plan is approved; no
    // retraining is asked for.
    let events = run(vec![1], &[1, 2]);
    assert_eq!(approved_by(&events), vec![1], "{events:?}");
    assert_eq!(retrains(&events), 0, "{events:?}");
    let verdicts: Vec<(u64, bool)> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict { verdict, .. } => Some((verdict.policy_id, verdict.task_ok)),
            _ => None,
        })
        .collect();
    assert_eq!(verdicts[..2], [(2, false), (1, true)], "{events:?}");
}

#[test]
fn the_current_policy_comes_first_and_only_the_first_policy_is_kept_as_base() {
    // Both solve it: the current (retrained) policy's plan is taken.
    assert_eq!(approved_by(&run(vec![1, 3], &[1, 3])), vec![3]);
    // Policies 1, 2, 3 received: 1 stays the base, 2 is dropped. Only 2 solves the world:
    // nothing is approved and retraining is asked for, for the current policy 3.
    let events = run(vec![2], &[1, 2, 3]);
    assert!(approved_by(&events).is_empty(), "{events:?}");
    let asked: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Retrain { verdict, .. } => Some(verdict.policy_id),
            _ => None,
        })
        .collect();
    assert_eq!(asked, vec![3], "{events:?}");
}
