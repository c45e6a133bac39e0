//! Issue 31, verified sampling before the planner: the production worker (real twin, shield
//! model, lookahead with the distilled generalist's blob) and a cycle over an in-process
//! arm, stepped on a manual clock, in `assets/scenes/wide_tall_box.toml` — a world whose
//! deterministic rollout collides (the demo's second act). With `[sampling]` on, a perturbed
//! variant passes the twin, and that candidate's plan is the one approved and sent (its
//! verdict says which sample); off, the old behaviour: no plan, a retrain request.

use policy::{PolicyExpectation, PolicyLoader, read_policy_file};
use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::{self, Cycle, CycleConfig, Mode};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use rt_core::twin_thread::node::ProductionWorker;
use rt_core::twin_thread::serve::{cycle_shield, plan_shield};
use shm_schemas::Executor;
use twin::{DOF, Scene};

use crate::common::{deliver, frame};
use crate::twin_common;

/// The events of 2 s of the runtime in the wide tall box with the distilled policy, and
/// the cycle's plans taken and mode at the end.
fn run(sampling: bool) -> (Vec<TwinEvent<Scene>>, u64, Mode, u64) {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    cfg.sampling.enabled = sampling;
    // Outcomes, not times: a budget no loaded test machine runs out of.
    cfg.sampling.budget_s = 2.0;
    let task = twin_common::task();
    let model = twin_common::model().with_tool(task.tool.map(|t| t.capsule()));
    let start = task.start.joints_rad;
    let (twin_io, cycle_io, _log) = cycle::wire::<Scene>();
    let arm = InProcessArm::new(
        start,
        cfg.limits.joint_min_rad,
        cfg.limits.joint_max_rad,
        [std::f64::consts::PI; DOF],
    );
    let mut cyc: Cycle<TwinModel, InProcessArm> = Cycle::new(
        CycleConfig::from_runtime(&cfg),
        cycle_shield(&cfg, &model, false),
        Brake::new(&cfg.limits),
        arm,
        cycle_io,
    );
    let clock = ManualClock::new(1_000_000_000);
    cyc.start(clock.now_ns()).unwrap();
    let mut lookahead = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
    if cfg.sampling.enabled {
        lookahead.set_sampling(Some(cfg.sampling.settings()));
    }
    let (mut worker, mut path) =
        ProductionWorker::new(&cfg, lookahead, plan_shield(&cfg, &model, false), twin_io);
    let loader = PolicyLoader::new(PolicyExpectation::for_task_obs(task.hash(), task.obs_dim()));
    let blob =
        read_policy_file(&twin_common::assets().join("policy-distilled/policy.blob")).unwrap();
    let policy = loader.prepare(&blob).unwrap();
    let policy_id = policy.policy_id();
    let mut events = Vec::new();
    worker.on_policy(Box::new(policy), &mut events);
    let scene = twin_common::scene("wide_tall_box.toml");
    for k in 0..500u64 {
        let now = clock.now_ns();
        if k.is_multiple_of(8) {
            deliver(
                &mut path,
                &mut worker,
                &frame(scene, now, true, true),
                &mut events,
            );
        }
        worker.step(&mut events);
        cyc.process(now);
        clock.advance_ns(cfg.period_ns());
    }
    let report = *cyc.report();
    (events, report.plans_taken, report.mode, policy_id)
}

#[test]
fn a_sampled_variant_passes_where_the_deterministic_rollout_collides_and_is_the_plan_sent() {
    let (events, plans_taken, mode, policy_id) = run(true);
    let verdicts: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict {
                verdict, source, ..
            } => Some((*verdict, *source)),
            _ => None,
        })
        .collect();
    // First the deterministic rollout, predicted to collide.
    let (first, source) = verdicts.first().copied().expect("a verdict");
    assert_eq!(source.sample, None);
    assert!(!first.safe, "the deterministic rollout collides: {first:?}");
    // Then a sampled candidate of the same policy that passes, and its plan is approved.
    let at = events
        .iter()
        .position(|e| {
            matches!(e, TwinEvent::Verdict { verdict, source, .. }
                if source.sample.is_some() && verdict.task_ok && verdict.safe)
        })
        .unwrap_or_else(|| panic!("a passing sampled verdict: {events:?}"));
    let TwinEvent::Verdict {
        verdict, source, ..
    } = &events[at]
    else {
        unreachable!()
    };
    let tag = source.sample.unwrap();
    assert!(tag.index >= 1 && tag.index < tag.of, "{tag:?}");
    assert_eq!(tag.of, RuntimeConfig::xarm5_default().sampling.candidates);
    assert_eq!(source.executor, Executor::Policy);
    assert_eq!(verdict.policy_id, policy_id);
    assert!(
        matches!(events.get(at + 1), Some(TwinEvent::PlanApproved { policy_id: p, .. }) if *p == policy_id),
        "the sampled candidate's plan is the one approved: {:?}",
        &events[at..]
    );
    // It reaches the cycle and the arm moves; no retraining is asked for the world solved.
    assert!(plans_taken >= 1);
    assert_ne!(mode, Mode::Stopped);
    assert!(
        !events
            .iter()
            .any(|e| matches!(e, TwinEvent::Retrain { .. })),
        "{events:?}"
    );
}

#[test]
fn with_sampling_off_the_deterministic_failure_holds_the_arm_and_asks_for_retraining() {
    let (events, plans_taken, mode, _) = run(false);
    assert!(
        !events.iter().any(|e| matches!(
            e,
            TwinEvent::PlanApproved { .. }
                | TwinEvent::Verdict {
                    source: rt_core::twin_thread::VerdictSource {
                        sample: Some(_),
                        ..
                    },
                    ..
                }
        )),
        "{events:?}"
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::Retrain { .. })),
        "{events:?}"
    );
    assert_eq!((plans_taken, mode), (0, Mode::Idle));
}
