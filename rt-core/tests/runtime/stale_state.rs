//! Robot states that arrive late (a loaded machine, a congested link): readings older than
//! `stale.max_robot_state_age_s` show joints from before, far from the commands sent since.
//! They stop the arm as stale (a pause that ends with fresh readings), and are never taken
//! for an arm that stopped following the commands (a latched fault needing an operator).

use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::link::{InProcessArm, LinkError, LinkState, RobotLink};
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::cycle::{self, Cycle, CycleConfig, CycleEvent, Mode, StopReason};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::testing::toy::{ToyArm, ToyLookahead, ToyPolicy, ToyScene};
use rt_core::twin_thread::TwinWorker;
use twin::{DOF, Joints};

use crate::common::{START, TARGET_A, deliver, frame};

/// An in-process arm whose report stream can stall: while `stalled`, every read returns the
/// reading taken when the stall began (its stamp and joints), while the commands still reach
/// the arm and move it.
struct StallingLink {
    arm: InProcessArm,
    stalled: bool,
    held: Option<LinkState>,
}

impl RobotLink for StallingLink {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        let fresh = self.arm.read_state(now_ns)?;
        if !self.stalled {
            self.held = None;
            return Ok(fresh);
        }
        Ok(*self.held.get_or_insert(fresh))
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        self.arm.send_servo(now_ns, q_rad)
    }
}

#[test]
fn late_readings_pause_the_arm_as_stale_and_never_latch_a_tracking_fault() {
    let mut cfg = RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (twin_io, cycle_io, mut log) = cycle::wire::<ToyScene>();
    let link = StallingLink {
        arm: InProcessArm::new(
            START,
            cfg.limits.joint_min_rad,
            cfg.limits.joint_max_rad,
            [3.0; DOF],
        ),
        stalled: false,
        held: None,
    };
    let mut cycle = Cycle::new(
        CycleConfig::from_runtime(&cfg),
        Shield::new(ToyArm, limits),
        Brake::new(&cfg.limits),
        link,
        cycle_io,
    );
    let clock = ManualClock::new(1_000_000_000);
    cycle.start(clock.now_ns()).expect("start");
    let (mut twin, mut path) = TwinWorker::new(
        &cfg,
        ToyLookahead::default(),
        Shield::new(ToyArm, limits),
        twin_io,
    );
    let mut events = Vec::new();
    twin.on_policy(Box::new(ToyPolicy::random(1, TARGET_A, 1)), &mut events);
    let period = cfg.period_ns();
    let mut cycle_events = Vec::new();
    let mut step = |cycle: &mut Cycle<ToyArm, StallingLink>,
                    twin: &mut TwinWorker<ToyLookahead, ToyArm>,
                    n: u64| {
        for _ in 0..n {
            let now = clock.now_ns();
            deliver(
                &mut path,
                twin,
                &frame(ToyScene::empty(), now, true, true),
                &mut events,
            );
            twin.step(&mut events);
            cycle.process(now);
            log.drain(|r| cycle_events.push(r.event));
            clock.advance_ns(period);
        }
    };
    step(&mut cycle, &mut twin, 150);
    assert_eq!(cycle.mode(), Mode::Following);
    // The reports stall for 0.4 s (the commands still reach the arm).
    cycle.link_mut().stalled = true;
    step(&mut cycle, &mut twin, 100);
    let r = *cycle.report();
    assert_ne!(r.mode, Mode::Following);
    assert_eq!(r.stop_reason, StopReason::StaleRobotState, "{r:?}");
    assert!(!r.awaiting_ack, "a late report latched a fault: {r:?}");
    // Fresh readings again: no operator needed, the arm goes on to its goal.
    cycle.link_mut().stalled = false;
    step(&mut cycle, &mut twin, 2500);
    assert!(
        !cycle_events
            .iter()
            .any(|e| matches!(e, CycleEvent::TrackingLost { .. })),
        "{cycle_events:?}"
    );
    let q = cycle.link().arm.q_rad();
    assert!(
        (0..DOF).all(|j| (q[j] - TARGET_A[j]).abs() < 0.03),
        "the arm did not go on: {q:?}"
    );
}
