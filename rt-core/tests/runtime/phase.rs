//! Issue 27: the twin worker's state is one `Phase` — an excursion goes episode → dwell at
//! the goal → returning home, each visible from outside (`TwinWorker::phase`, and in every
//! verdict's `VerdictSource`).

use rt_core::config::RuntimeConfig;
use rt_core::cycle::Mode;
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::worker::Phase;
use shm_schemas::{Executor, PhaseCode};

use crate::common::{Rig, START, TARGET_A};

fn kind(p: Phase) -> &'static str {
    match p {
        Phase::Episode => "episode",
        Phase::DwellAtGoal { .. } => "dwell",
        Phase::ReturningHome => "home",
        Phase::HoldingAfterRefusedReturn { .. } => "holding",
        Phase::Continuing { .. } => "continuing",
        Phase::Paused { .. } => "paused",
        Phase::BackingOut { .. } => "backing-out",
    }
}

#[test]
fn an_excursion_goes_episode_then_dwell_at_the_goal_then_home() {
    let cfg = RuntimeConfig::xarm5_default();
    let dwell_cycles = (cfg.dwell_at_goal_s * cfg.rate_hz) as u64;
    let mut rig = Rig::with_config(cfg);
    rig.policy(1, TARGET_A);
    let mut phases: Vec<(&str, u64)> = Vec::new();
    let mut dwell_starts_at = None;
    for k in 0..3000 {
        rig.run(1);
        let p = kind(rig.twin.phase());
        if phases.last().map(|x| x.0) != Some(p) {
            phases.push((p, k));
            if p == "dwell" {
                dwell_starts_at = Some((rig.arm_q(), rig.mode()));
            }
        }
    }
    let names: Vec<&str> = phases.iter().map(|x| x.0).collect();
    assert_eq!(names, ["episode", "dwell", "home"], "{phases:?}");
    // The dwell begins once the arm rests at the goal and lasts `dwell_at_goal_s`.
    let (dwell_from, home_from) = (phases[1].1, phases[2].1);
    let (q, mode) = dwell_starts_at.unwrap();
    assert!(
        Rig::near(&q, &TARGET_A, 0.03) && mode == Mode::Idle,
        "{q:?} {mode:?}"
    );
    assert!(home_from - dwell_from >= dwell_cycles, "{phases:?}");
    assert!(Rig::near(&rig.arm_q(), &START, 1e-6), "{:?}", rig.arm_q());
    // The verdict that started the excursion was made in the episode phase, by a policy.
    let first = rig.events.iter().find_map(|e| match e {
        TwinEvent::Verdict { source, .. } => Some(*source),
        _ => None,
    });
    assert!(
        first.is_some_and(|s| s.phase == PhaseCode::Episode && s.executor == Executor::Policy),
        "{first:?}"
    );
}
