//! Issue 15, one truth for "goal reached": the twin declared the goal reached while the
//! commanded (smoothed) path's closest approach to the target was 20.4 mm against a 20 mm
//! tolerance. The worker now measures the smoothed plan itself
//! (`Lookahead::goal_approach`) and approves it only within the tolerance; a miss is a
//! failed lookahead (verdict `task_ok = false`, a retrain request).
//!
//! The lookahead here is scripted on the toy arm: its waypoints run from the start to an
//! end pose with one waypoint off the line — the goal pose, where its TCP is the goal
//! target. Ruckig, passing through the waypoints at their time, cuts that corner: the
//! waypoints reach the target exactly, the smoothed path passes it a few millimetres off.

use rt_core::config::RuntimeConfig;
use rt_core::cycle::Mode;
use rt_core::cycle::plan::MotionState;
use rt_core::cycle::plan::Plan;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_closest_approach_m, toy_cycle};
use rt_core::twin_thread::smoother::PlanSmoother;
use rt_core::twin_thread::worker::PlanRejection;
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use twin::{DOF, Joints};

use crate::common::{START, TARGET_A, deliver, frame};

const STEP_S: f64 = 0.05;

/// Waypoints from [`START`] to [`TARGET_A`] in 20 steps; waypoint 10 lifted by 0.05 rad on
/// joint 1: the goal pose.
fn waypoints() -> (Vec<Joints>, Joints) {
    let mut w: Vec<Joints> = (1..=20)
        .map(|i| {
            let t = f64::from(i) / 20.0;
            let mut q = [0.0; DOF];
            for j in 0..DOF {
                q[j] = START[j] + (TARGET_A[j] - START[j]) * t;
            }
            q
        })
        .collect();
    w[9][1] += 0.05;
    let goal_pose = w[9];
    (w, goal_pose)
}

/// The scripted lookahead: always the same waypoints; `task_ok` when they come within
/// `tolerance_m` of the target (as the twin's rollout judges its steps); the smoothed path
/// judged by the same measure and tolerance.
struct CornerLookahead {
    waypoints: Vec<Joints>,
    target_m: [f64; 3],
    tolerance_m: f64,
}

impl Lookahead for CornerLookahead {
    type Scene = ToyScene;
    type Policy = ToyPolicy;

    fn step_s(&self) -> f64 {
        STEP_S
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
        waypoints.clone_from(&self.waypoints);
        Verdict {
            task_ok: toy_closest_approach_m(&self.target_m, waypoints) <= self.tolerance_m,
            safe: true,
            min_distance_m: f64::INFINITY,
            steps: waypoints.len() as u32,
            policy_id: policy.id,
        }
    }

    fn goal_approach(
        &mut self,
        _policy: &ToyPolicy,
        _scene: &ToyScene,
        path_q_rad: &[Joints],
    ) -> GoalApproach {
        GoalApproach {
            closest_m: toy_closest_approach_m(&self.target_m, path_q_rad),
            tolerance_m: self.tolerance_m,
        }
    }
}

/// The smoothed path's closest approach to the target, as the worker's smoother makes it
/// (same limits, period and step).
fn smoothed_closest_m(cfg: &RuntimeConfig, waypoints: &[Joints], target_m: &[f64; 3]) -> f64 {
    let period_s = 1.0 / cfg.rate_hz;
    let mut smoother = PlanSmoother::new(period_s, cfg.limits, (60.0 * cfg.rate_hz) as usize);
    let mut plan = Plan::with_capacity(1, 1, period_s, 0);
    smoother
        .smooth(
            &MotionState::at_rest(START),
            waypoints,
            STEP_S,
            &mut ToyArm,
            &mut plan,
        )
        .unwrap();
    toy_closest_approach_m(target_m, &plan.q_rad)
}

/// A cycle over the toy arm and a worker with the corner lookahead of `tolerance_m`, run
/// for 2 s with fresh detections of an empty scene; returns the events and the cycle's
/// last mode and plans taken.
fn run(cfg: &RuntimeConfig, tolerance_m: f64) -> (Vec<TwinEvent<ToyScene>>, Mode, u64) {
    let (waypoints, goal_pose) = waypoints();
    let target_m = ToyArm::points_m(&goal_pose)[4];
    let (mut cycle, twin_io, _log) = toy_cycle(cfg, START);
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).unwrap();
    let lookahead = CornerLookahead {
        waypoints,
        target_m,
        tolerance_m,
    };
    let (mut twin, mut path) =
        TwinWorker::new(cfg, lookahead, Shield::new(ToyArm, limits), twin_io);
    let mut events = Vec::new();
    twin.on_policy(Box::new(ToyPolicy::random(1, TARGET_A, 1)), &mut events);
    for k in 0..(2 * cfg.rate_hz as u64) {
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
    let report = *cycle.report();
    (events, report.mode, report.plans_taken)
}

#[test]
fn a_plan_whose_smoothed_path_misses_the_goal_is_not_approved_and_asks_for_retraining() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let (waypoints, goal_pose) = waypoints();
    let target_m = ToyArm::points_m(&goal_pose)[4];
    assert_eq!(toy_closest_approach_m(&target_m, &waypoints), 0.0);
    let smoothed_m = smoothed_closest_m(&cfg, &waypoints, &target_m);
    assert!(
        (0.002..0.03).contains(&smoothed_m),
        "the smoothed path passes the target {smoothed_m} m off"
    );

    // The tolerance 0.4 mm short of the smoothed path's approach: the waypoints reach the
    // target, the path the arm would follow misses it by a little. Not approved, the arm
    // stays; the verdict fails the task (not safety) and retraining is asked for once.
    let tolerance_m = smoothed_m - 0.0004;
    let (events, mode, plans_taken) = run(&cfg, tolerance_m);
    assert!(
        !events
            .iter()
            .any(|e| matches!(e, TwinEvent::PlanApproved { .. })),
        "{events:?}"
    );
    assert_eq!((mode, plans_taken), (Mode::Idle, 0));
    let goal = events
        .iter()
        .find_map(|e| match e {
            TwinEvent::PlanRejected {
                why: PlanRejection::MissesGoal(g),
                ..
            } => Some(*g),
            _ => None,
        })
        .unwrap_or_else(|| panic!("a rejection for the goal: {events:?}"));
    assert!((goal.closest_m - smoothed_m).abs() < 1e-9, "{goal:?}");
    assert_eq!(goal.tolerance_m, tolerance_m);
    assert!(!goal.reached());
    let retrains: Vec<&Verdict> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Retrain { verdict, .. } => Some(verdict),
            _ => None,
        })
        .collect();
    assert_eq!(retrains.len(), 1, "{events:?}");
    assert!(
        !retrains[0].task_ok && retrains[0].safe,
        "{:?}",
        retrains[0]
    );
    // The lookahead itself passed (a plan is rejected only after it), and one verdict is
    // published for the try, once its smoothed plan was checked: the failed one (issue 40
    // item 2: a published verdict's approval is rt-core's final word).
    let verdicts: Vec<&Verdict> = events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Verdict { verdict, .. } => Some(verdict),
            _ => None,
        })
        .collect();
    assert!(
        !verdicts.is_empty() && verdicts.iter().all(|v| !v.task_ok && v.safe),
        "{events:?}"
    );

    // The same plan with the tolerance 0.4 mm beyond the approach is approved and run.
    let (events, _, plans_taken) = run(&cfg, smoothed_m + 0.0004);
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::PlanApproved { .. })),
        "{events:?}"
    );
    assert_eq!(plans_taken, 1);
}

/// A world of `foresight --runs 40 --seed 7 --worlds random` (world 5): the bundled policy's
/// episode ends 17 mm from the goal target — inside the 20 mm tolerance, but a millimetre of
/// perception error left the real goal outside it and the launcher never counted the goal.
/// The lookahead now settles the plan's end on the target.
#[test]
fn the_plan_ends_on_the_goal_target_not_at_the_tolerance_edge() {
    use policy::{PolicyExpectation, PolicyLoader};
    use rt_core::twin_thread::lookahead::{LookaheadActions, SETTLE_DONE_M, TwinLookahead};
    use twin::{BoxObstacle, Goal, Scene};

    let task = crate::twin_common::task();
    let model = crate::twin_common::model();
    let bytes = std::fs::read(crate::twin_common::assets().join("policy/policy.blob")).unwrap();
    let blob = shm_schemas::PolicyBlob::from_bytes(&bytes)
        .unwrap()
        .to_boxed();
    let policy = PolicyLoader::new(PolicyExpectation::for_task_obs(task.hash(), task.obs_dim()))
        .prepare(&blob)
        .unwrap();
    let mut scene = Scene::empty(
        0.0,
        Goal {
            center_m: [0.2110, 0.1525, 0.025],
            size_m: 0.05,
        },
    );
    scene
        .obstacles
        .push(BoxObstacle {
            center_m: [0.5267, 0.3607, 0.1152],
            size_m: [0.0440, 0.0628, 0.2303],
        })
        .unwrap();
    let target_m = scene.goal_target_m(task.success.goal_hover_m);
    let tolerance_m = task.success.tolerance_m;
    let start = task.start.joints_rad;
    let mut la = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
    let mut waypoints = Vec::new();
    let verdict = la.lookahead(&policy, &scene, &start, &mut waypoints);
    assert!(verdict.task_ok && verdict.safe, "{verdict:?}");
    // The episode itself ended inside the tolerance but well off the target...
    let episode_end = waypoints[verdict.steps as usize - 1];
    let episode_end_m = (model.tcp_m(&episode_end) - target_m).norm();
    assert!(
        (0.005..=tolerance_m).contains(&episode_end_m),
        "{episode_end_m}"
    );
    // ...and the plan goes on to the target itself.
    let end_m = (model.tcp_m(waypoints.last().unwrap()) - target_m).norm();
    assert!(
        end_m <= SETTLE_DONE_M,
        "the plan ends {end_m} m off the target"
    );
    assert!(waypoints.len() > verdict.steps as usize);
}
