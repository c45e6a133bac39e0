//! Issue 42 item 2, in part: a plan the planner fallback makes to join the running plan
//! reaches the cycle in time. The search takes up to its budget (0.25 s), longer than
//! `join_ahead_s` (0.1 s), and the cycle runs on meanwhile. Before, the join point came from
//! the cycle's report read before the search, lay behind the arm when the plan arrived, and
//! the cycle refused the plan as late. Here the planner's search runs the cycle on for its
//! budget (as the cycle thread does in `rt-core run`).

use std::sync::{Arc, Mutex};

use rt_core::config::RuntimeConfig;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::cycle::{Cycle, CycleReport};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_closest_approach_m, toy_cycle};
use rt_core::twin_thread::worker::{FallbackPlanner, PLANNER_POLICY_ID};
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use twin::Joints;

use crate::common::{START, TARGET_A, deliver, frame};

type ToyCycle = Cycle<ToyArm, InProcessArm>;

/// Straight joint-space waypoints from `from` to `to`, 20 of them.
fn straight(from: &Joints, to: &Joints, out: &mut Vec<Joints>) {
    out.clear();
    for i in 1..=20 {
        let t = f64::from(i) / 20.0;
        out.push(std::array::from_fn(|j| from[j] + (to[j] - from[j]) * t));
    }
}

/// A lookahead no policy passes: every plan is the planner's.
struct NoPolicyPasses;

impl Lookahead for NoPolicyPasses {
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
        Verdict {
            task_ok: false,
            safe: false,
            min_distance_m: -0.01,
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

/// A planner straight to [`TARGET_A`] whose search lasts `search_cycles` periods of the
/// cycle, which runs on meanwhile (its reports reach the worker as in `rt-core run`).
struct SlowPlanner {
    cycle: Arc<Mutex<ToyCycle>>,
    reports: Arc<Mutex<Vec<CycleReport>>>,
    clock: ManualClock,
    period_ns: u64,
    search_cycles: u64,
}

impl SlowPlanner {
    fn run_cycle(&self) {
        let now = self.clock.now_ns();
        let mut cycle = self.cycle.lock().unwrap();
        cycle.process(now);
        self.reports.lock().unwrap().push(*cycle.report());
        self.clock.advance_ns(self.period_ns);
    }
}

impl FallbackPlanner<ToyScene> for SlowPlanner {
    fn plan(&mut self, _: &ToyScene, start_q_rad: &Joints, waypoints: &mut Vec<Joints>) -> Verdict {
        for _ in 0..self.search_cycles {
            self.run_cycle();
        }
        straight(start_q_rad, &TARGET_A, waypoints);
        Verdict {
            task_ok: true,
            safe: true,
            min_distance_m: 0.1,
            steps: 20,
            policy_id: PLANNER_POLICY_ID,
        }
    }

    fn goal_approach(&mut self, _: &ToyScene, path_q_rad: &[Joints]) -> GoalApproach {
        GoalApproach {
            closest_m: toy_closest_approach_m(&ToyArm::points_m(&TARGET_A)[4], path_q_rad),
            tolerance_m: 0.01,
        }
    }
}

#[test]
fn a_planner_made_join_plan_reaches_the_cycle_in_time_despite_its_search() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let (cycle, twin_io, _log) = toy_cycle(&cfg, START);
    let cycle = Arc::new(Mutex::new(cycle));
    let reports = Arc::new(Mutex::new(Vec::new()));
    let clock = ManualClock::new(1_000_000_000);
    cycle.lock().unwrap().start(clock.now_ns()).unwrap();
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (mut twin, mut path) =
        TwinWorker::new(&cfg, NoPolicyPasses, Shield::new(ToyArm, limits), twin_io);
    let planner = SlowPlanner {
        cycle: cycle.clone(),
        reports: reports.clone(),
        clock: clock.clone(),
        period_ns: cfg.period_ns(),
        // The whole search budget.
        search_cycles: (cfg.planner_fallback.budget_s * cfg.rate_hz).round() as u64,
    };
    twin.set_fallback_planner(Box::new(planner));
    let mut events = Vec::new();
    twin.on_policy(Box::new(ToyPolicy::random(1, TARGET_A, 1)), &mut events);
    let mut scene = ToyScene::empty();
    scene.push_obstacle([-0.4, -0.4, 0.05], [0.05, 0.05, 0.05]);
    let mut approved_at = None;
    for k in 0..1500u64 {
        let now = clock.now_ns();
        if approved_at.is_some_and(|a| k == a + 40) {
            // A still box set down far from the way, while the planner's plan runs: the
            // scene changed, the plan is made again, joining the running one.
            scene.push_obstacle([-0.4, 0.4, 0.05], [0.05, 0.05, 0.05]);
        }
        if k.is_multiple_of(8) {
            deliver(
                &mut path,
                &mut twin,
                &frame(scene, now, true, true),
                &mut events,
            );
        }
        twin.step(&mut events);
        if approved_at.is_none()
            && events
                .iter()
                .any(|e| matches!(e, TwinEvent::PlanApproved { .. }))
        {
            approved_at = Some(k);
        }
        let now = clock.now_ns();
        let mut c = cycle.lock().unwrap();
        c.process(now);
        reports.lock().unwrap().push(*c.report());
        drop(c);
        clock.advance_ns(cfg.period_ns());
    }
    let joining: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::PlanApproved {
                plan_id,
                joins: true,
                ..
            } => Some(*plan_id),
            _ => None,
        })
        .collect();
    assert!(!joining.is_empty(), "no joining plan: {events:?}");
    let reports = reports.lock().unwrap();
    let mut refused: Vec<u64> = reports
        .iter()
        .map(|r| r.last_refused_plan_id)
        .filter(|&id| id != 0)
        .collect();
    refused.dedup();
    assert!(
        refused.is_empty(),
        "the cycle refused {refused:?} (joining plans {joining:?})"
    );
    // The joining plan ran: the cycle followed it.
    assert!(
        reports.iter().any(|r| joining.contains(&r.plan_id)),
        "{joining:?} never ran"
    );
}
