//! Issue 42 item 4, a taken goal is said at once: a box slides onto the goal cube and stays.
//! Before, every candidate failed, a retrain request went to the learner and the run said
//! nothing until its retraining timed out (30 s). Now the frame that shows the box on the
//! goal gets `infeasible: <reason>` on its own planning ([`TwinEvent::GoalTaken`]), no retrain
//! request is made, the arm holds; when the box leaves, the goal is live again and reached.
//! The production worker (real twin, shield model and intake) and a cycle over an in-process
//! arm, stepped on a manual clock; frames through the production intake.

use policy::{PolicyExpectation, PolicyLoader};
use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::{self, Cycle, CycleConfig, Mode};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::intake::SceneIntake;
use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use rt_core::twin_thread::node::ProductionWorker;
use rt_core::twin_thread::path_planner::TwinPathPlanner;
use rt_core::twin_thread::scene_path::ScenePath;
use rt_core::twin_thread::serve::{cycle_shield, plan_shield};
use shm_schemas::{ACT_DIM, DetectedObject, DetectionFrame, ObjectClass, PolicyBlobBuilder};
use twin::{Blocker, DOF, InfeasibleReason, RobotModel, Scene, TaskConfig};

use crate::common::deliver;
use crate::twin_common;

/// `CLOCK_MONOTONIC` at the cycle clock's origin, ns.
const ORIGIN_NS: u64 = 1_000_000_000_000;

/// The small-box scene's goal, in reach in front of the arm.
pub(crate) const GOAL_M: [f32; 3] = [0.30, 0.25, 0.025];

/// The box: 6 × 6 × 12 cm, waiting out of the way, then on the goal cube.
const BOX_SIZE_M: [f32; 3] = [0.06, 0.06, 0.12];
const BOX_AWAY_M: [f32; 3] = [0.60, -0.25, 0.06];
const BOX_ON_GOAL_M: [f32; 3] = [0.31, 0.25, 0.06];

pub(crate) struct Rig {
    pub(crate) clock: ManualClock,
    pub(crate) period_ns: u64,
    pub(crate) cycle: Cycle<TwinModel, InProcessArm>,
    pub(crate) worker: ProductionWorker,
    pub(crate) path: ScenePath<TwinModel>,
    pub(crate) intake: SceneIntake,
    pub(crate) events: Vec<TwinEvent<Scene>>,
    pub(crate) model: RobotModel,
    pub(crate) task: TaskConfig,
    pub(crate) sequence: u64,
    pub(crate) cycles: u64,
}

/// One box of a frame: centre, size, velocity (m, m, m/s).
pub(crate) type SeenBox = ([f32; 3], [f32; 3], [f32; 3]);

impl Rig {
    /// The runtime as `rt-core run` builds it, a policy swapped in; the lookahead executes
    /// the task's straight line to the goal (the policy still evaluated).
    pub(crate) fn new() -> Self {
        Self::with_planner(false)
    }

    /// With the planner fallback (`planner_fallback`, a generous budget) or without.
    pub(crate) fn with_planner(planner: bool) -> Self {
        let mut cfg = RuntimeConfig::xarm5_default();
        cfg.return_home = false;
        cfg.planner_fallback.budget_s = 2.0;
        let task = twin_common::task();
        let model = twin_common::model().with_tool(task.tool.map(|t| t.capsule()));
        let (twin_io, cycle_io, _log) = cycle::wire::<Scene>();
        let arm = InProcessArm::new(
            task.start.joints_rad,
            cfg.limits.joint_min_rad,
            cfg.limits.joint_max_rad,
            [std::f64::consts::PI; DOF],
        );
        let mut cycle = Cycle::new(
            CycleConfig::from_runtime(&cfg),
            cycle_shield(&cfg, &model, false),
            Brake::new(&cfg.limits),
            arm,
            cycle_io,
        );
        let clock = ManualClock::new(1_000_000_000);
        cycle.start(clock.now_ns()).unwrap();
        let lookahead = TwinLookahead::new(
            model.clone(),
            task,
            LookaheadActions::ScriptedWithPolicyCost,
        );
        let (mut worker, path) =
            ProductionWorker::new(&cfg, lookahead, plan_shield(&cfg, &model, false), twin_io);
        let hash = task.hash();
        let loader = PolicyLoader::new(PolicyExpectation::for_task_obs(hash, task.obs_dim()));
        let blob = PolicyBlobBuilder::random(1, hash, task.obs_dim(), &[64, 64], ACT_DIM, 1)
            .build()
            .unwrap();
        let mut events = Vec::new();
        worker.on_policy(Box::new(loader.prepare(&blob).unwrap()), &mut events);
        if planner {
            worker.set_fallback_planner(Box::new(TwinPathPlanner::new(model.clone(), task, &cfg)));
        }
        let intake = SceneIntake::new(
            cfg.intake,
            (cfg.stale.max_detection_age_s * 1e9) as u64,
            task.sampling.table_height_m,
            ORIGIN_NS,
        );
        Self {
            clock,
            period_ns: cfg.period_ns(),
            cycle,
            worker,
            path,
            intake,
            events,
            model,
            task,
            sequence: 0,
            cycles: 0,
        }
    }

    /// Runs `n` cycles with a frame every 8 cycles (captured 1 ms before it arrives): the
    /// goal and the box at `box_at(cycle)` moving at its velocity (then the frame is not
    /// settled) or still (settled).
    fn run(&mut self, n: u64, box_at: impl Fn(u64) -> ([f32; 3], [f32; 3])) {
        self.run_with(n, |k| {
            let (c, v) = box_at(k);
            vec![(c, BOX_SIZE_M, v)]
        });
    }

    /// Runs `n` cycles with a frame every 8 cycles: the goal and `boxes(cycle)`; a frame is
    /// settled when no box moves and `settled(cycle)`.
    pub(crate) fn run_with(&mut self, n: u64, boxes: impl Fn(u64) -> Vec<SeenBox>) {
        self.run_frames(n, boxes, |_| true);
    }

    /// [`Rig::run_with`], settled only where `settled(cycle)` too.
    pub(crate) fn run_frames(
        &mut self,
        n: u64,
        boxes: impl Fn(u64) -> Vec<SeenBox>,
        settled: impl Fn(u64) -> bool,
    ) {
        for k in 0..n {
            let now = self.clock.now_ns();
            if self.cycles.is_multiple_of(8) {
                self.sequence += 1;
                let mut frame = DetectionFrame {
                    sequence: self.sequence,
                    capture_time_ns: ORIGIN_NS + now - 1_000_000,
                    camera_id: 1,
                    ..DetectionFrame::default()
                };
                let seen = boxes(k);
                let moving = seen.iter().any(|(_, _, v)| v.iter().any(|x| *x != 0.0));
                frame.set_settled(!moving && settled(k));
                assert!(frame.push(DetectedObject::new(
                    1,
                    ObjectClass::Goal,
                    0.99,
                    GOAL_M,
                    [0.05; 3],
                )));
                for (i, (center_m, size_m, velocity_m_s)) in seen.into_iter().enumerate() {
                    let sigma = if velocity_m_s.iter().any(|x| *x != 0.0) {
                        0.05
                    } else {
                        0.0
                    };
                    assert!(
                        frame.push(
                            DetectedObject::new(
                                2 + i as u32,
                                ObjectClass::Obstacle,
                                0.99,
                                center_m,
                                size_m
                            )
                            .with_velocity(velocity_m_s, sigma)
                        )
                    );
                }
                let accepted = self.intake.accept(&frame, ORIGIN_NS + now, 1).unwrap();
                deliver(
                    &mut self.path,
                    &mut self.worker,
                    &accepted,
                    &mut self.events,
                );
            }
            self.worker.step(&mut self.events);
            self.cycle.process(now);
            self.clock.advance_ns(self.period_ns);
            self.cycles += 1;
        }
    }

    /// Index of the first event matching `f`.
    pub(crate) fn first(&self, f: impl Fn(&TwinEvent<Scene>) -> bool) -> Option<usize> {
        self.events.iter().position(f)
    }

    /// The TCP's distance to the goal target point, m.
    pub(crate) fn tcp_to_goal_m(&self) -> f64 {
        let q = self.cycle.link().q_rad();
        let goal = twin::Goal {
            center_m: GOAL_M.map(f64::from),
            size_m: 0.05,
        };
        let target = Scene::empty(0.0, goal).goal_target_m(self.task.success.goal_hover_m);
        (self.model.tcp_m(&q) - target).norm()
    }
}

/// `from` → `to` over `cycles` cycles: the box's place and velocity at cycle `k`.
fn slide(from: [f32; 3], to: [f32; 3], cycles: u64, k: u64) -> ([f32; 3], [f32; 3]) {
    let dur_s = cycles as f32 / 250.0;
    let t = (k as f32 / cycles as f32).min(1.0);
    let v = if k < cycles {
        [0, 1, 2].map(|i| (to[i] - from[i]) / dur_s)
    } else {
        [0.0; 3]
    };
    ([0, 1, 2].map(|i| from[i] + (to[i] - from[i]) * t), v)
}

#[test]
fn a_box_taking_the_goal_is_said_at_once_without_retraining_and_the_goal_is_reached_once_it_leaves()
{
    let mut rig = Rig::new();
    // The box slides onto the goal cube (0.5 s, frames not settled), then stays (1 s).
    rig.run(125, |k| slide(BOX_AWAY_M, BOX_ON_GOAL_M, 125, k));
    rig.run(250, |_| (BOX_ON_GOAL_M, [0.0; 3]));
    let taken = rig
        .first(|e| matches!(e, TwinEvent::GoalTaken { .. }))
        .unwrap_or_else(|| panic!("the taken goal was never said: {:?}", rig.events));
    match &rig.events[taken] {
        TwinEvent::GoalTaken { reason, .. } => {
            assert!(
                matches!(
                    reason,
                    InfeasibleReason::NoGoalPosture {
                        blocker: Blocker::Box(0),
                        ..
                    }
                ),
                "{reason:?}"
            );
            assert!(reason.to_string().contains("box 0"), "{reason}");
        }
        _ => unreachable!(),
    }
    // Said on the planning of the first settled frame that shows it, before (and instead
    // of) a retrain request, whose answer would have come after a retraining timeout.
    assert_eq!(
        rig.first(|e| matches!(e, TwinEvent::Retrain { .. })),
        None,
        "{:?}",
        rig.events
    );
    assert_eq!(
        rig.events
            .iter()
            .filter(|e| matches!(e, TwinEvent::GoalTaken { .. }))
            .count(),
        1,
        "said once for the scene: {:?}",
        rig.events
    );
    // The arm holds.
    let report = *rig.cycle.report();
    assert_eq!((report.mode, report.plans_taken), (Mode::Idle, 0));

    // The box leaves (0.5 s) and the world settles: the goal is live again.
    rig.run(125, |k| slide(BOX_ON_GOAL_M, BOX_AWAY_M, 125, k));
    rig.run(1500, |_| (BOX_AWAY_M, [0.0; 3]));
    let approved = rig
        .first(|e| matches!(e, TwinEvent::PlanApproved { .. }))
        .unwrap_or_else(|| panic!("no plan once the box left: {:?}", rig.events));
    assert!(taken < approved);
    assert_eq!(rig.cycle.report().mode, Mode::Idle);
    let tolerance_m = rig.task.success.tolerance_m;
    assert!(
        rig.tcp_to_goal_m() <= tolerance_m,
        "goal not reached: {} m",
        rig.tcp_to_goal_m()
    );
    assert_eq!(rig.first(|e| matches!(e, TwinEvent::Retrain { .. })), None);
}
