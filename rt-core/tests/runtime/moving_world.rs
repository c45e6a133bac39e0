//! Issue 42 item 1, planning while the world moves, through the production worker (real
//! twin, lookahead, shield model, intake and plan guard) and a cycle over an in-process arm,
//! stepped on a manual clock with 62.5 Hz frames delivered 16 ms after their capture. Every
//! command is checked against the moving box's *true* position at that time.
//!
//! A box moving about 0.2 m beside the arm's way no longer delays the start: the first plan
//! is approved and adopted while the box still moves (before any settled frame), and the arm
//! reaches its goal without touching it.
//!
//! Item 5, the prediction horizon covers the stop: a box that chases the arm along its way
//! faster than the arm moves is seen coming in time with the horizon as shipped (and as
//! raised to its floor), and too late with the 0.25 s horizon of before.

use policy::{PolicyExpectation, PolicyLoader};
use rt_core::config::{MotionLimits, RuntimeConfig, SHIPPED_RUNTIME_TOML};
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::plan::MotionState;
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::{self, Cycle, CycleConfig, Mode};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::intake::SceneIntake;
use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use rt_core::twin_thread::node::ProductionWorker;
use rt_core::twin_thread::scene_path::ScenePath;
use rt_core::twin_thread::serve::{cycle_shield, plan_shield};
use shm_schemas::{ACT_DIM, DetectedObject, DetectionFrame, ObjectClass, PolicyBlobBuilder};
use twin::{BoxObstacle, DOF, Goal, Joints, RobotGeometry, RobotModel, Scene};

use crate::common::deliver;
use crate::twin_common;

/// `CLOCK_MONOTONIC` at the cycle clock's origin, ns.
const ORIGIN_NS: u64 = 1_000_000_000_000;

/// The goal (the small-box scene's, in reach in front of the arm).
const GOAL_M: [f32; 3] = [0.30, 0.25, 0.025];

/// Cycles between frames (62.5 Hz at 250 Hz).
const FRAME_EVERY: u64 = 4;

/// Capture to delivery, ns.
const LATENCY_NS: u64 = 16_000_000;

/// A box that stands, then moves at a constant velocity for a while, then stands again
/// (present only from `appears_s`).
#[derive(Debug, Clone, Copy)]
struct MovingBox {
    start_m: [f64; 3],
    size_m: [f64; 3],
    velocity_m_s: [f64; 3],
    appears_s: f64,
    moves_from_s: f64,
    moves_until_s: f64,
}

impl MovingBox {
    fn center_at(&self, t_s: f64) -> [f64; 3] {
        let dt = t_s.clamp(self.moves_from_s, self.moves_until_s) - self.moves_from_s;
        std::array::from_fn(|k| self.start_m[k] + self.velocity_m_s[k] * dt)
    }

    fn moving_at(&self, t_s: f64) -> bool {
        (self.moves_from_s..self.moves_until_s).contains(&t_s)
    }

    /// As perception's tracker would mark a frame captured at `t_s`: settled only when the
    /// box has stood for 0.3 s (or is not there yet).
    fn settled_at(&self, t_s: f64) -> bool {
        t_s < self.appears_s
            || (!self.moving_at(t_s)
                && (t_s < self.moves_from_s || t_s >= self.moves_until_s + 0.3))
    }
}

struct World {
    clock: ManualClock,
    period_ns: u64,
    cycle: Cycle<TwinModel, InProcessArm>,
    worker: ProductionWorker,
    path: ScenePath<TwinModel>,
    intake: SceneIntake,
    model: RobotModel,
    geometry: RobotGeometry,
    moving_box: Option<MovingBox>,
    /// The goal is seen from then on, s.
    goal_from_s: f64,
    events: Vec<TwinEvent<Scene>>,
    sequence: u64,
    cycles: u64,
    /// The command of each cycle.
    commands: Vec<Joints>,
    /// The command of each cycle with its velocity and acceleration.
    states: Vec<MotionState>,
    /// The arm's smallest distance to the box's true position over the cycles whose command
    /// moved the arm, m.
    min_distance_moving_m: f64,
    /// Cycles whose command moved the arm into the box.
    contacts_while_moving: u64,
    /// Index into `events` when the first settled frame showing the box was delivered.
    first_settled_at_event: Option<usize>,
}

impl World {
    /// The runtime as `rt-core run` builds it from `cfg` (the task's tool on the model), a
    /// policy swapped in; the lookahead executes the task's straight line to the goal.
    fn new(mut cfg: RuntimeConfig, moving_box: Option<MovingBox>) -> Self {
        cfg.return_home = false;
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
            geometry: RobotGeometry::new(&model),
            model,
            moving_box,
            goal_from_s: 0.0,
            events,
            sequence: 0,
            cycles: 0,
            commands: Vec::new(),
            states: Vec::new(),
            min_distance_moving_m: f64::INFINITY,
            contacts_while_moving: 0,
            first_settled_at_event: None,
        }
    }

    /// Seconds since the start at cycle-clock time `now_ns`.
    fn t_s(&self, now_ns: u64) -> f64 {
        (now_ns - 1_000_000_000) as f64 * 1e-9
    }

    /// The frame captured `LATENCY_NS` before `now_ns`, through the intake onto the scene
    /// path and into the worker.
    fn detect(&mut self, now_ns: u64) {
        let capture_ns = now_ns.saturating_sub(LATENCY_NS);
        let t_s = self.t_s(capture_ns.max(1_000_000_000));
        self.sequence += 1;
        let mut frame = DetectionFrame {
            sequence: self.sequence,
            capture_time_ns: ORIGIN_NS + capture_ns,
            camera_id: 1,
            ..DetectionFrame::default()
        };
        if t_s >= self.goal_from_s {
            assert!(frame.push(DetectedObject::new(
                1,
                ObjectClass::Goal,
                0.99,
                GOAL_M,
                [0.05; 3],
            )));
        }
        let mut settled = true;
        if let Some(b) = self.moving_box.filter(|b| t_s >= b.appears_s) {
            let (velocity, sigma) = if b.moving_at(t_s) {
                (b.velocity_m_s.map(|v| v as f32), 0.03)
            } else {
                ([0.0; 3], 0.01)
            };
            let o = DetectedObject::new(
                50,
                ObjectClass::Obstacle,
                0.95,
                b.center_at(t_s).map(|c| c as f32),
                b.size_m.map(|s| s as f32),
            )
            .with_velocity(velocity, sigma);
            assert!(frame.push(o));
            settled = b.settled_at(t_s);
        }
        frame.set_settled(settled);
        let accepted = self.intake.accept(&frame, ORIGIN_NS + now_ns, 1).unwrap();
        deliver(
            &mut self.path,
            &mut self.worker,
            &accepted,
            &mut self.events,
        );
        if settled && self.moving_box.is_some_and(|b| t_s >= b.appears_s) {
            self.first_settled_at_event.get_or_insert(self.events.len());
        }
    }

    /// The arm's distance at `q` to the box's true position at `t_s` (`None`: no box), m.
    fn box_distance_m(&self, q: &Joints, t_s: f64) -> Option<f64> {
        let b = self.moving_box.filter(|b| t_s >= b.appears_s)?;
        Some(distance_to_box_m(
            &self.model,
            &self.geometry,
            q,
            b.center_at(t_s),
            b.size_m,
        ))
    }

    /// Runs `n` cycles: a frame every [`FRAME_EVERY`], the worker, the cycle; each command
    /// that moved the arm is checked against the box's true position.
    fn run(&mut self, n: u64) {
        for _ in 0..n {
            let now = self.clock.now_ns();
            if self.cycles.is_multiple_of(FRAME_EVERY) {
                self.detect(now);
            }
            self.worker.step(&mut self.events);
            self.cycle.process(now);
            let cmd = self.cycle.report().cmd.q_rad;
            let moved = self.commands.last().is_some_and(|prev| *prev != cmd);
            if moved && let Some(d) = self.box_distance_m(&cmd, self.t_s(now)) {
                self.min_distance_moving_m = self.min_distance_moving_m.min(d);
                if d <= 0.0 {
                    self.contacts_while_moving += 1;
                }
            }
            self.commands.push(cmd);
            self.states.push(self.cycle.report().cmd);
            self.clock.advance_ns(self.period_ns);
            self.cycles += 1;
        }
    }

    /// The cycles in which the command moved: (first, last).
    fn motion(&self) -> Option<(usize, usize)> {
        let moved = |i: &usize| self.commands[*i] != self.commands[*i - 1];
        let first = (1..self.commands.len()).find(moved)?;
        let last = (1..self.commands.len()).rev().find(moved)?;
        Some((first, last))
    }

    fn tcp_m(&self, cycle: usize) -> [f64; 3] {
        let p = self.model.fk(&self.commands[cycle]).tcp_m();
        [p.x, p.y, p.z]
    }

    /// At rest above the goal (the task's target lies above the cube).
    fn at_goal(&self) -> bool {
        let p = self.tcp_m(self.commands.len() - 1);
        let g = GOAL_M.map(f64::from);
        self.cycle.report().mode == Mode::Idle && (p[0] - g[0]).hypot(p[1] - g[1]) < 0.02
    }

    fn first_approved_at_event(&self) -> Option<usize> {
        self.events
            .iter()
            .position(|e| matches!(e, TwinEvent::PlanApproved { .. }))
    }
}

/// The arm's (capsules') distance at `q` to a box, m.
fn distance_to_box_m(
    model: &RobotModel,
    geometry: &RobotGeometry,
    q: &Joints,
    center_m: [f64; 3],
    size_m: [f64; 3],
) -> f64 {
    let mut scene = Scene::empty(
        0.0,
        Goal {
            center_m: GOAL_M.map(f64::from),
            size_m: 0.05,
        },
    );
    scene
        .obstacles
        .push(BoxObstacle { center_m, size_m })
        .unwrap();
    geometry
        .distance_to_boxes(&model.fk(q), &scene)
        .map_or(f64::INFINITY, |r| r.distance_m)
}

/// The arm's way without any box: the rehearsal, run until it rests at the goal.
fn rehearsal(goal_from_s: f64) -> World {
    let mut w = World::new(RuntimeConfig::xarm5_default(), None);
    w.goal_from_s = goal_from_s;
    w.run(2500);
    assert!(
        w.motion().is_some() && w.at_goal(),
        "motion {:?}, tcp {:?}, report {:?}",
        w.motion(),
        w.tcp_m(w.commands.len() - 1),
        w.cycle.report()
    );
    w
}

fn unit_xy(v: [f64; 3]) -> [f64; 3] {
    let n = v[0].hypot(v[1]);
    [v[0] / n, v[1] / n, 0.0]
}

/// A low box (10 cm) moving at 0.3 m/s along the TCP's way, its centre 0.2 m beside it, on
/// the side away from the base, from before the goal is seen until after the arm has reached
/// it.
fn box_beside_the_way(way: &World) -> MovingBox {
    let (first, last) = way.motion().unwrap();
    let mid = (first + last) / 2;
    let p = way.tcp_m(mid);
    let along = unit_xy({
        let (a, b) = (way.tcp_m(first), way.tcp_m(last));
        [b[0] - a[0], b[1] - a[1], 0.0]
    });
    let mut side = [-along[1], along[0], 0.0];
    if side[0] * p[0] + side[1] * p[1] < 0.0 {
        side = side.map(|c| -c);
    }
    let speed_m_s = 0.3;
    let t_mid = mid as f64 * 0.004;
    let start = [
        p[0] + side[0] * 0.2 - along[0] * speed_m_s * t_mid,
        p[1] + side[1] * 0.2 - along[1] * speed_m_s * t_mid,
        0.05,
    ];
    MovingBox {
        start_m: start,
        size_m: [0.1, 0.1, 0.1],
        velocity_m_s: along.map(|c| c * speed_m_s),
        appears_s: 0.0,
        moves_from_s: 0.0,
        moves_until_s: 2.0 * t_mid + 1.0,
    }
}

/// Item 1: a box moving beside the arm's way does not delay the start — the first plan is
/// approved before any settled frame (on settled-only planning it waited for the box to
/// stop), the cycle adopts it while the box still moves, and the arm reaches the goal
/// without touching the box.
#[test]
fn a_box_moving_beside_the_way_does_not_delay_the_start() {
    let way = rehearsal(0.0);
    let b = box_beside_the_way(&way);
    // The premise: the box's whole run keeps clear of the rehearsed way.
    let (first, last) = way.motion().unwrap();
    let mut clear_m = f64::INFINITY;
    for c in (first..=last).step_by(5) {
        for i in 0..=40 {
            let t_s = b.moves_until_s * f64::from(i) / 40.0;
            let d = distance_to_box_m(
                &way.model,
                &way.geometry,
                &way.commands[c],
                b.center_at(t_s),
                b.size_m,
            );
            clear_m = clear_m.min(d);
        }
    }
    assert!(
        clear_m > 0.08,
        "the box comes within {clear_m:.3} m of the way"
    );

    let mut w = World::new(RuntimeConfig::xarm5_default(), Some(b));
    let moving_cycles = (b.moves_until_s / 0.004) as u64;
    w.run(moving_cycles);
    let approved = w.first_approved_at_event();
    assert!(
        approved.is_some(),
        "no plan while the box moves: {:?}",
        w.events
    );
    assert!(w.first_settled_at_event.is_none());
    assert!(
        w.cycle.report().plans_taken >= 1,
        "not adopted while the box moves"
    );
    w.run(1000);
    assert!(w.at_goal(), "{:?}", w.events);
    assert_eq!(
        w.contacts_while_moving, 0,
        "touched while moving (closest {:.3} m)",
        w.min_distance_moving_m
    );
}

/// Item 5: the prediction horizon covers the stop. A box chases the arm along its way from
/// behind (it stands with its centre 0.7 m behind the TCP's start, then moves along the way
/// faster than the arm); the plan guard and the cycle see it coming only as far as its
/// predicted volume reaches.
///
/// The plan guard or the cycle stops the arm once the volume reaches its way, and the cycle
/// cuts the stop short where its next step would enter the growing volume: the command
/// jumps from speed to rest in one period. No arm stops like that, so the arm is taken to
/// run on from its last moving command along the fastest stop its limits allow (the
/// cycle's per-joint [`Brake`]); the distance that counts is the smallest of the commanded
/// motion and that run-on to the box's true position ([`World::closest_with_run_on_m`]).
///
/// With the horizon as shipped, and as raised to its floor when 0.25 s is configured, the
/// arm stays farther than the clearance from the box at 1.0 and 1.6 m/s. Predicted over
/// 0.25 s only (the value before item 5, forced past the floor here), the box is seen too
/// late and reaches the arm before it can have stopped: closer than the clearance, in
/// contact.
#[test]
fn the_horizon_covers_the_stop_of_an_arm_a_fast_box_chases() {
    let way = rehearsal(0.0);
    let shipped = RuntimeConfig::xarm5_default();
    let clearance_m = shipped.shield.min_distance_m;
    let asked_short =
        SHIPPED_RUNTIME_TOML.replace("prediction_horizon_s = 0.6", "prediction_horizon_s = 0.25");
    assert_ne!(
        asked_short, SHIPPED_RUNTIME_TOML,
        "the shipped horizon line moved"
    );
    let raised = RuntimeConfig::from_toml(&asked_short).unwrap();
    assert!(raised.horizon_raised().is_some());
    assert!((raised.intake.prediction_horizon_s - raised.prediction_floor_s()).abs() < 1e-9);
    // The value before item 5, kept below the floor (a test-only bypass of the raise).
    let mut short = shipped.clone();
    short.intake.prediction_horizon_s = 0.25;

    // (speed, when the box starts moving): the arm is at about a third of its way then,
    // near its full speed.
    for (speed_m_s, moves_from_s) in [(1.0, 0.4), (1.6, 0.6)] {
        let b = box_chasing(&way, -0.7, moves_from_s, speed_m_s);
        for (name, cfg) in [("shipped", &shipped), ("raised", &raised)] {
            let w = chased(cfg.clone(), b);
            let closest_m = w.closest_with_run_on_m(&cfg.limits);
            assert!(
                closest_m > clearance_m,
                "{name} horizon {:.3} s, box at {speed_m_s} m/s: the arm comes within \
                 {closest_m:.4} m of it",
                cfg.intake.prediction_horizon_s
            );
            assert!(w.motion().is_some(), "{name}: the arm never moved");
            assert_eq!(w.contacts_while_moving, 0, "{name}, {speed_m_s} m/s");
            assert!(w.cycle.report().stops >= 1, "{name}: the arm never stopped");
        }
        let w = chased(short.clone(), b);
        let closest_m = w.closest_with_run_on_m(&short.limits);
        assert!(
            closest_m < clearance_m,
            "predicted over 0.25 s, a box at {speed_m_s} m/s was seen in time \
             (closest {closest_m:.4} m): the scenario no longer tests the horizon"
        );
    }
}

/// A box that chases the arm along its way from behind: it stands at `start_y_m` on the
/// line of the TCP's start (its x), 0.3 m high, then from `moves_from_s` moves along +y
/// (the way's direction) at `speed_m_s` for 0.9 m.
fn box_chasing(way: &World, start_y_m: f64, moves_from_s: f64, speed_m_s: f64) -> MovingBox {
    let (first, _) = way.motion().unwrap();
    let p = way.tcp_m(first);
    MovingBox {
        start_m: [p[0], start_y_m, 0.2],
        size_m: [0.1, 0.1, 0.3],
        velocity_m_s: [0.0, speed_m_s, 0.0],
        appears_s: 0.0,
        moves_from_s,
        moves_until_s: moves_from_s + 0.9 / speed_m_s,
    }
}

/// The runtime of `cfg` with the chasing box `b`, run until well after the arm's way.
fn chased(cfg: RuntimeConfig, b: MovingBox) -> World {
    let mut w = World::new(cfg, Some(b));
    w.run(2000);
    w
}

impl World {
    /// The arm's smallest distance to the box's true position over its commanded motion
    /// and, wherever the command changed velocity faster than the acceleration limit
    /// allows (a stop cut short: from speed to rest in one period), over the run-on of the
    /// fastest stop the arm can make from the command before (the per-joint [`Brake`] at
    /// `limits`), m.
    fn closest_with_run_on_m(&self, limits: &MotionLimits) -> f64 {
        let dt_s = self.period_ns as f64 * 1e-9;
        let mut closest_m = self.min_distance_moving_m;
        for i in 1..self.states.len() {
            let (before, after) = (&self.states[i - 1], &self.states[i]);
            let cut = (0..DOF).any(|j| {
                (after.dq_rad_s[j] - before.dq_rad_s[j]).abs()
                    > 2.0 * limits.max_acceleration_rad_s2[j] * dt_s
            });
            if !cut {
                continue;
            }
            let mut brake = Brake::new(limits);
            brake.start(*before);
            for k in 1.. {
                let q = brake.step(dt_s).q_rad;
                if let Some(d) = self.box_distance_m(&q, (i - 1 + k) as f64 * dt_s) {
                    closest_m = closest_m.min(d);
                }
                if brake.is_stopped() {
                    break;
                }
            }
        }
        closest_m
    }
}
