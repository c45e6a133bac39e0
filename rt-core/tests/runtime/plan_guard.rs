//! Issue 33, the two gaps of the twin's re-verification:
//!
//! 1. A plan the worker has handed over but the cycle has not adopted yet is re-verified
//!    against a scene that arrives meanwhile, and a plan the cycle refuses never replaces
//!    the running plan in the worker's view (before: the worker re-verified only "the plan
//!    it sent last" when the cycle's progress named it, so both plans went unchecked).
//! 2. An accepted frame reaches the cycle's shield, and the plan guard, within one cycle
//!    while the twin worker is busy in a long planner search on its own thread (before: one
//!    thread received detections and planned, so no frame reached the cycle during a
//!    search).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};

use rt_core::config::RuntimeConfig;
use rt_core::cycle::plan::Plan;
use rt_core::cycle::shield::{Shield, ShieldLimits, ShieldModel};
use rt_core::cycle::{Intruders, Mode, SceneUpdate, StopReason};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyPolicy, ToyScene, toy_closest_approach_m, toy_cycle};
use rt_core::twin_thread::plan_guard::PlanGuard;
use rt_core::twin_thread::worker::{FallbackPlanner, PLANNER_POLICY_ID};
use rt_core::twin_thread::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict};
use twin::Joints;

use crate::common::{Rig, START, TARGET_A};

fn approved(events: &[TwinEvent<ToyScene>]) -> Vec<u64> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::PlanApproved { plan_id, .. } => Some(*plan_id),
            _ => None,
        })
        .collect()
}

fn revoked(events: &[TwinEvent<ToyScene>]) -> Vec<u64> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Revoked { plan_id, .. } => Some(*plan_id),
            _ => None,
        })
        .collect()
}

/// Plans the guard found failing: revoked, or their stop scheduled.
fn reverified_and_failed(events: &[TwinEvent<ToyScene>]) -> Vec<u64> {
    events
        .iter()
        .filter_map(|e| match e {
            TwinEvent::Revoked { plan_id, .. } | TwinEvent::StopScheduled { plan_id, .. } => {
                Some(*plan_id)
            }
            _ => None,
        })
        .collect()
}

/// The scene with a box where `TARGET_A` puts the toy arm's tool: on the plan to it.
fn with_box_at_target_a(scene: ToyScene) -> ToyScene {
    let mut s = scene;
    s.push_obstacle(ToyArm.tcp_position_m(&TARGET_A), [0.08; 3]);
    s
}

/// A box far from every path between START and TARGET_A.
const FAR_BOX: ([f64; 3], [f64; 3]) = ([-0.4, -0.4, 0.05], [0.05, 0.05, 0.05]);

#[test]
fn a_scene_change_between_sending_a_plan_and_its_adoption_revokes_the_plan() {
    let mut rig = Rig::new();
    rig.detections_on = false;
    let now = rig.clock.now_ns();
    let scene = rig.scene;
    rig.detect(scene, now, true, true);
    rig.policy(1, TARGET_A);
    rig.twin.step(&mut rig.events);
    let sent = approved(&rig.events);
    assert_eq!(sent.len(), 1, "{:?}", rig.events);
    // The plan is in the hand-over, the cycle has not run: a box lands on its path.
    rig.detect(with_box_at_target_a(scene), now, true, true);
    assert_eq!(revoked(&rig.events), sent, "{:?}", rig.events);
    rig.cycle.process(now);
    assert_ne!(rig.mode(), Mode::Following, "the revoked plan was adopted");
    assert_eq!(rig.cycle.report().plans_taken, 0);
    assert_eq!(rig.cycle.report().last_refused_plan_id, sent[0]);
}

#[test]
fn a_plan_the_cycle_refuses_does_not_hide_the_running_plan_from_re_verification() {
    let mut rig = Rig::new();
    rig.detections_on = false;
    let now = rig.clock.now_ns();
    let scene = rig.scene;
    rig.detect(scene, now, true, true);
    rig.policy(1, TARGET_A);
    rig.twin.step(&mut rig.events);
    // Before the cycle ran, an unrelated change: the worker's last report still reads
    // "idle", so it plans again from rest — a plan the cycle will refuse.
    let mut far = scene;
    far.push_obstacle(FAR_BOX.0, FAR_BOX.1);
    rig.detect(far, now, true, true);
    rig.twin.step(&mut rig.events);
    let sent = approved(&rig.events);
    assert_eq!(sent.len(), 2, "{:?}", rig.events);
    rig.cycle.process(now);
    assert_eq!(rig.mode(), Mode::Following);
    assert_eq!(rig.cycle.report().plan_id, sent[0]);
    assert_eq!(rig.cycle.report().last_refused_plan_id, sent[1]);
    // The arm moves a little on the first plan, fed fresh frames of the same scene.
    rig.scene = far;
    rig.detections_on = true;
    rig.run(20);
    assert_eq!(rig.mode(), Mode::Following);
    assert!(revoked(&rig.events).is_empty(), "{:?}", rig.events);
    // Now a box lands on the running plan's path.
    let blocked = with_box_at_target_a(far);
    let now = rig.clock.now_ns();
    rig.detect(blocked, now, true, true);
    // Re-verified: revoked, or (failing far enough ahead) its stop scheduled so that a
    // joining plan may take over first (issue 33 item 5).
    assert_eq!(
        reverified_and_failed(&rig.events).first(),
        Some(&sent[0]),
        "the running plan was not re-verified: {:?}",
        rig.events
    );
    rig.scene = blocked;
    for _ in 0..2000 {
        rig.run(1);
        if rig.mode() != Mode::Following {
            break;
        }
    }
    assert_eq!(rig.cycle.report().stop_reason, StopReason::Revoked);
}

/// A lookahead that passes policy 1 (straight to [`TARGET_A`]) while `solvable`, and fails
/// every policy otherwise.
struct SwitchLookahead {
    solvable: Arc<AtomicBool>,
}

fn straight(from: &Joints, to: &Joints, out: &mut Vec<Joints>) {
    out.clear();
    for i in 1..=20 {
        let t = f64::from(i) / 20.0;
        out.push(std::array::from_fn(|j| from[j] + (to[j] - from[j]) * t));
    }
}

impl Lookahead for SwitchLookahead {
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
        let ok = self.solvable.load(Ordering::SeqCst);
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

/// A planner whose search, once `armed`, lasts until the test lets it go; it finds nothing.
struct BlockedPlanner {
    armed: Arc<AtomicBool>,
    entered: mpsc::Sender<()>,
    release: mpsc::Receiver<()>,
}

impl FallbackPlanner<ToyScene> for BlockedPlanner {
    fn plan(&mut self, _: &ToyScene, _: &Joints, waypoints: &mut Vec<Joints>) -> Verdict {
        if self.armed.load(Ordering::SeqCst) {
            let _ = self.entered.send(());
            let _ = self.release.recv();
        }
        waypoints.clear();
        Verdict {
            task_ok: false,
            safe: true,
            min_distance_m: 0.0,
            steps: 0,
            policy_id: PLANNER_POLICY_ID,
        }
    }

    fn goal_approach(&mut self, _: &ToyScene, _: &[Joints]) -> GoalApproach {
        GoalApproach {
            closest_m: f64::INFINITY,
            tolerance_m: 0.01,
        }
    }
}

#[test]
fn a_frame_during_a_long_planner_search_reaches_the_cycle_and_the_guard_within_one_cycle() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let (mut cycle, twin_io, _log) = toy_cycle(&cfg, START);
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).unwrap();
    let solvable = Arc::new(AtomicBool::new(true));
    let (mut worker, mut path) = TwinWorker::new(
        &cfg,
        SwitchLookahead {
            solvable: solvable.clone(),
        },
        Shield::new(ToyArm, limits),
        twin_io,
    );
    let (entered_tx, entered) = mpsc::channel();
    let (release, release_rx) = mpsc::channel();
    let armed = Arc::new(AtomicBool::new(false));
    worker.set_fallback_planner(Box::new(BlockedPlanner {
        armed: armed.clone(),
        entered: entered_tx,
        release: release_rx,
    }));
    // As in `rt-core run`: the scene path runs apart from the worker (the intake thread's).
    let mut events = Vec::new();
    let period = cfg.period_ns();
    let mut scene = ToyScene::empty();
    let deliver = |path: &mut rt_core::twin_thread::scene_path::ScenePath<ToyArm>,
                   worker: Option<&mut TwinWorker<SwitchLookahead, ToyArm>>,
                   scene: ToyScene,
                   now: u64,
                   events: &mut Vec<TwinEvent<ToyScene>>| {
        path.accepted(scene, now, rt_core::cycle::Intruders::NONE);
        if let Some(w) = worker {
            w.note_frame(&crate::common::frame(scene, now, true, true), events);
        }
    };
    deliver(
        &mut path,
        Some(&mut worker),
        scene,
        clock.now_ns(),
        &mut events,
    );
    worker.on_policy(Box::new(ToyPolicy::random(1, TARGET_A, 1)), &mut events);
    worker.step(&mut events);
    for _ in 0..10 {
        cycle.process(clock.now_ns());
        clock.advance_ns(period);
    }
    assert_eq!(cycle.mode(), Mode::Following, "{events:?}");
    let running = cycle.report().plan_id;
    armed.store(true, Ordering::SeqCst);
    // The world changes so that no policy passes any more: the worker asks the planner,
    // whose search outlasts the detections' age limit, on a thread of its own.
    solvable.store(false, Ordering::SeqCst);
    scene.push_obstacle(FAR_BOX.0, FAR_BOX.1);
    deliver(
        &mut path,
        Some(&mut worker),
        scene,
        clock.now_ns(),
        &mut events,
    );
    let searching = std::thread::spawn(move || {
        worker.step(&mut events);
        (worker, events)
    });
    if entered
        .recv_timeout(std::time::Duration::from_secs(20))
        .is_err()
    {
        let (_, events) = searching.join().unwrap();
        panic!("the worker never searched: {events:?}");
    }
    // Meanwhile frames keep coming, through the scene path alone: for longer than the
    // detections' age limit, the cycle keeps following on fresh scenes.
    let max_age_cycles = (cfg.stale.max_detection_age_s * cfg.rate_hz).ceil() as u64;
    for k in 0..max_age_cycles + 5 {
        if k % 8 == 0 {
            deliver(&mut path, None, scene, clock.now_ns(), &mut Vec::new());
        }
        cycle.process(clock.now_ns());
        clock.advance_ns(period);
    }
    assert_eq!(
        (cycle.mode(), cycle.report().stops),
        (Mode::Following, 0),
        "frames did not reach the cycle during the search: {:?}",
        cycle.report().stop_reason
    );
    // A box lands on the running plan: the very next cycle stops the arm (revoked by the
    // plan guard on the scene path), while the worker still searches.
    deliver(
        &mut path,
        None,
        with_box_at_target_a(scene),
        clock.now_ns(),
        &mut Vec::new(),
    );
    cycle.process(clock.now_ns());
    assert_eq!(cycle.mode(), Mode::Stopping);
    assert_eq!(cycle.report().stop_reason, StopReason::Revoked);
    assert_eq!(cycle.report().plan_id, running);
    assert!(!searching.is_finished(), "the search ended early");
    armed.store(false, Ordering::SeqCst);
    release.send(()).unwrap();
    let (mut worker, mut events) = searching.join().unwrap();
    // The worker logs the revocation the scene path made while it searched.
    worker.step(&mut events);
    assert!(
        events
            .iter()
            .any(|e| matches!(e, TwinEvent::Revoked { plan_id, .. } if *plan_id == running)),
        "{events:?}"
    );
}

/// An in-process arm whose next servo send, once armed, hands the plan guard a frame: the
/// frame reaches the guard between the cycle's adoption of a plan and its report of it
/// (a real link's send takes that long).
struct InjectingLink {
    arm: rt_core::cycle::link::InProcessArm,
    guard: Arc<std::sync::Mutex<PlanGuard<ToyArm>>>,
    inject: Option<ToyScene>,
}

impl rt_core::cycle::link::RobotLink for InjectingLink {
    fn read_state(
        &mut self,
        now_ns: u64,
    ) -> Result<rt_core::cycle::link::LinkState, rt_core::cycle::link::LinkError> {
        self.arm.read_state(now_ns)
    }

    fn send_servo(
        &mut self,
        now_ns: u64,
        q_rad: &Joints,
    ) -> Result<(), rt_core::cycle::link::LinkError> {
        if let Some(scene) = self.inject.take() {
            self.guard.lock().unwrap().scene(scene);
        }
        self.arm.send_servo(now_ns, q_rad)
    }
}

/// A smooth (cosine) plan from `from` to `to` over `duration_s`, sampled at `period_s`.
fn cosine_plan(id: u64, from: &Joints, to: &Joints, duration_s: f64, period_s: f64) -> Plan {
    let n = (duration_s / period_s).ceil() as usize;
    let mut plan = Plan::with_capacity(id, 1, period_s, n + 1);
    let w = std::f64::consts::PI / duration_s;
    for k in 0..=n {
        let t = (k as f64 * period_s).min(duration_s);
        let s = 0.5 * (1.0 - (w * t).cos());
        let ds = 0.5 * w * (w * t).sin();
        let dds = 0.5 * w * w * (w * t).cos();
        plan.push(
            std::array::from_fn(|j| from[j] + (to[j] - from[j]) * s),
            std::array::from_fn(|j| (to[j] - from[j]) * ds),
            std::array::from_fn(|j| (to[j] - from[j]) * dds),
        );
    }
    plan
}

/// Issue 41 item 3: the cycle adopts a plan, sends its first command through the link, and
/// only then reports its progress. A frame that reaches the plan guard in that window (here
/// from inside the link's send) must still verify the just-adopted plan. Before the fix the
/// guard read "not following" (the old progress) and then "adopted up to this plan" (the
/// new adoption), took the plan for one that can no longer move the arm and verified
/// nothing: the plan ran on into the box, and later frames of the same scene never looked
/// at it again.
#[test]
fn a_frame_between_a_plans_adoption_and_the_cycles_report_still_verifies_the_plan() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (mut twin_io, cycle_io, _log) = rt_core::cycle::wire::<ToyScene>();
    let period_s = 1.0 / cfg.rate_hz;
    let guard = Arc::new(std::sync::Mutex::new(PlanGuard::new(
        Shield::new(ToyArm, limits),
        period_s,
        twin_io.control.clone(),
    )));
    let link = InjectingLink {
        arm: rt_core::cycle::link::InProcessArm::new(
            START,
            cfg.limits.joint_min_rad,
            cfg.limits.joint_max_rad,
            [3.0; twin::DOF],
        ),
        guard: guard.clone(),
        inject: None,
    };
    let mut cycle = rt_core::cycle::Cycle::new(
        rt_core::cycle::CycleConfig::from_runtime(&cfg),
        Shield::new(ToyArm, limits),
        rt_core::cycle::brake::Brake::new(&cfg.limits),
        link,
        cycle_io,
    );
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).expect("start");
    let clear = ToyScene::empty();
    let blocked = with_box_at_target_a(clear);
    // One period: the cycle's own scene stays clear (only the guard, which looks along
    // the whole plan, can find the box at its far end).
    macro_rules! period {
        () => {{
            let now = clock.now_ns();
            twin_io.scenes.send(SceneUpdate {
                scene: clear,
                stamp_ns: now,
                refused: false,
                intruders: Intruders::NONE,
            });
            let mode = cycle.process(now);
            clock.advance_ns(cfg.period_ns());
            mode
        }};
    }
    for _ in 0..5 {
        period!();
    }
    guard.lock().unwrap().scene(clear);
    let plan = cosine_plan(1, &START, &TARGET_A, 5.0, period_s);
    assert!(guard.lock().unwrap().sent(Arc::new(plan.clone()), clear, 0));
    assert!(twin_io.plans.send(Box::new(plan)).is_ok());
    cycle.link_mut().inject = Some(blocked);
    assert_eq!(period!(), Mode::Following, "the plan was not adopted");
    assert!(cycle.link().inject.is_none(), "the link sent nothing");
    assert!(
        twin_io.control.revoked_up_to() >= 1,
        "the just-adopted plan was not verified against the frame that came in between: {:?}",
        guard.lock().unwrap().take_revocations()
    );
    // Later frames of the same scene change nothing: only that verification could stop it.
    for _ in 0..5 {
        guard.lock().unwrap().scene(blocked);
        period!();
    }
    assert_ne!(cycle.mode(), Mode::Following);
    assert_eq!(cycle.report().stop_reason, StopReason::Revoked);
}
