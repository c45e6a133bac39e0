//! Shared rig of the runtime's integration tests (included with `#[path]`): a cycle over the
//! toy arm and an in-process arm, a twin worker with the toy lookahead, and a manual clock,
//! stepped in one thread so every run is deterministic.

#![allow(dead_code, missing_docs, clippy::new_without_default)]

use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::InProcessArm;
use rt_core::cycle::shield::{Shield, ShieldLimits, ShieldModel};
use rt_core::cycle::{self, Cycle, CycleConfig, CycleEvent, CycleReport, Intruders, Mode};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::rt::rt_log::RtLogDrain;
use rt_core::testing::toy::{ToyArm, ToyLookahead, ToyPolicy, ToyScene};
use rt_core::twin_thread::intake::AcceptedFrame;
use rt_core::twin_thread::scene_path::ScenePath;
use rt_core::twin_thread::{Lookahead, TwinEvent, TwinWorker};
use twin::{DOF, Joints};

pub const START: Joints = [0.0, -0.3, -0.6, 0.4, 0.0];
pub const TARGET_A: Joints = [0.6, 0.2, -0.9, 0.3, 0.1];
pub const TARGET_B: Joints = [-0.5, 0.1, -0.7, 0.5, -0.1];

/// An accepted frame of `scene` captured at `stamp_ns`, with a goal or not, settled or not,
/// nothing moving.
pub fn frame<S>(scene: S, stamp_ns: u64, goal_seen: bool, settled: bool) -> AcceptedFrame<S> {
    AcceptedFrame {
        goal_seen,
        settled,
        ..AcceptedFrame::settled(scene, stamp_ns)
    }
}

/// An accepted frame through the one door `rt-core run` uses (the intake thread, then the
/// twin node): its scene onto the scene path — the cycle, the plan guard — then noted by
/// the worker.
pub fn deliver<L, M>(
    path: &mut ScenePath<M>,
    twin: &mut TwinWorker<L, M>,
    frame: &AcceptedFrame<L::Scene>,
    events: &mut Vec<TwinEvent<L::Scene>>,
) where
    L: Lookahead,
    M: ShieldModel<Scene = L::Scene>,
{
    path.accepted(frame.scene, frame.stamp_ns, frame.intruders);
    twin.note_frame(frame, events);
}

pub struct Rig {
    pub cfg: RuntimeConfig,
    pub clock: ManualClock,
    pub cycle: Cycle<ToyArm, InProcessArm>,
    pub twin: TwinWorker<ToyLookahead, ToyArm>,
    /// The twin's scene path (the intake thread's in `rt-core run`).
    pub path: ScenePath<ToyArm>,
    pub log: RtLogDrain<CycleEvent>,
    pub scene: ToyScene,
    pub events: Vec<TwinEvent<ToyScene>>,
    pub reports: Vec<CycleReport>,
    pub detections_every: u64,
    pub detections_on: bool,
    /// The frames carry a goal.
    pub goal_seen: bool,
    /// The frames are settled (perception's `FRAME_SETTLED`).
    pub settled: bool,
    /// The frames are refused by the intake (as `twin_thread::intake` does).
    pub refusing: bool,
    pub cycles: u64,
}

impl Rig {
    /// A rig whose arm stays at the goal (`return_home = false`).
    pub fn new() -> Self {
        let mut cfg = RuntimeConfig::xarm5_default();
        cfg.return_home = false;
        Self::with_config(cfg)
    }

    /// A rig over `cfg`.
    pub fn with_config(cfg: RuntimeConfig) -> Self {
        Self::build(cfg, false)
    }

    /// A rig whose cycle takes fresh plans after a lost link returns without an
    /// acknowledgement (a simulated arm's `--auto-resume`).
    pub fn auto_resuming() -> Self {
        let mut cfg = RuntimeConfig::xarm5_default();
        cfg.return_home = false;
        Self::build(cfg, true)
    }

    fn build(cfg: RuntimeConfig, auto_resume: bool) -> Self {
        let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
        let (twin_io, cycle_io, log) = cycle::wire::<ToyScene>();
        let arm = InProcessArm::new(
            START,
            cfg.limits.joint_min_rad,
            cfg.limits.joint_max_rad,
            [3.0; DOF],
        );
        let mut cycle_cfg = CycleConfig::from_runtime(&cfg);
        cycle_cfg.auto_resume_after_link_loss = auto_resume;
        let mut cycle = Cycle::new(
            cycle_cfg,
            Shield::new(ToyArm, limits),
            Brake::new(&cfg.limits),
            arm,
            cycle_io,
        );
        let clock = ManualClock::new(1_000_000_000);
        cycle.start(clock.now_ns()).expect("start");
        let (twin, path) = TwinWorker::new(
            &cfg,
            ToyLookahead::default(),
            Shield::new(ToyArm, limits),
            twin_io,
        );
        Self {
            cfg,
            clock,
            cycle,
            twin,
            path,
            log,
            scene: ToyScene::empty(),
            events: Vec::new(),
            reports: Vec::new(),
            detections_every: 8,
            detections_on: true,
            goal_seen: true,
            settled: true,
            refusing: false,
            cycles: 0,
        }
    }

    pub fn policy(&mut self, id: u64, target: Joints) {
        let p = Box::new(ToyPolicy::random(id, target, id));
        self.twin.on_policy(p, &mut self.events);
    }

    /// Runs `n` cycles: detections every `detections_every` cycles, a twin step, a cycle.
    pub fn run(&mut self, n: u64) {
        let period = self.cfg.period_ns();
        for _ in 0..n {
            let now = self.clock.now_ns();
            if self.detections_on && self.cycles.is_multiple_of(self.detections_every) {
                if self.refusing {
                    self.refuse();
                } else {
                    self.detect(self.scene, now, self.goal_seen, self.settled);
                }
            }
            self.twin.step(&mut self.events);
            self.cycle.process(now);
            self.reports.push(*self.cycle.report());
            self.clock.advance_ns(period);
            self.cycles += 1;
        }
    }

    /// An accepted frame of `scene` at `now`, through [`deliver`].
    pub fn detect(&mut self, scene: ToyScene, now: u64, goal_seen: bool, settled: bool) {
        self.deliver(&frame(scene, now, goal_seen, settled));
    }

    /// A settled frame with a goal whose obstacles in `intruders` are seen moving.
    pub fn detect_moving(
        &mut self,
        scene: ToyScene,
        now: u64,
        settled: bool,
        intruders: Intruders,
    ) {
        self.deliver(&AcceptedFrame {
            intruders,
            ..frame(scene, now, true, settled)
        });
    }

    /// `frame` through [`deliver`].
    pub fn deliver(&mut self, frame: &AcceptedFrame<ToyScene>) {
        deliver(&mut self.path, &mut self.twin, frame, &mut self.events);
    }

    /// A refused frame: the scene path tells the cycle, then the worker notes it.
    pub fn refuse(&mut self) {
        self.path.refused();
        self.twin.note_refused();
    }

    pub fn mode(&self) -> Mode {
        self.cycle.mode()
    }

    pub fn arm_q(&self) -> Joints {
        self.cycle.link().q_rad()
    }

    /// Every command so far moved each joint within its velocity limit.
    pub fn assert_commands_within_velocity_limits(&self) {
        let period_s = 1.0 / self.cfg.rate_hz;
        for w in self.reports.windows(2) {
            for j in 0..DOF {
                let v = (w[1].cmd.q_rad[j] - w[0].cmd.q_rad[j]) / period_s;
                assert!(
                    v.abs() <= self.cfg.limits.max_velocity_rad_s[j] + 1e-6,
                    "joint {j}: {v} rad/s"
                );
            }
        }
    }

    pub fn near(a: &Joints, b: &Joints, tol: f64) -> bool {
        (0..DOF).all(|j| (a[j] - b[j]).abs() <= tol)
    }

    pub fn retrains(&self) -> usize {
        self.events
            .iter()
            .filter(|e| matches!(e, TwinEvent::Retrain { .. }))
            .count()
    }

    pub fn approvals(&self) -> Vec<(u64, u64, bool)> {
        self.events
            .iter()
            .filter_map(|e| match e {
                TwinEvent::PlanApproved {
                    plan_id,
                    policy_id,
                    joins,
                } => Some((*plan_id, *policy_id, *joins)),
                _ => None,
            })
            .collect()
    }
}
