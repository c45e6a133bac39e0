//! Foresight's adversarial safety sweep: the production twin worker
//! ([`ProductionWorker`]: the real lookahead on the task of `assets/task.toml`, the real
//! plan shield and smoother) and the production cycle ([`Cycle`] with
//! [`serve::cycle_shield`], [`Brake`] and the in-process arm) stepped together in one
//! thread on a [`ManualClock`], episode after episode, in randomised and hostile worlds.
//! Every command the cycle sends through the link is checked by the independent
//! [`oracle`] against the *ground truth* (the world the sweep made up, not the scene
//! the runtime believes).
//!
//! # An episode
//! A seeded world (a scene as the task samples it, a goal alone, or clutter; sometimes a goal
//! near the base), a policy (the bundled blob, random weights, a goal-seeker that drives
//! straight at the goal through anything, or random weights × 1e6 that saturate), and some
//! adversarial twists, each drawn with its own probability ([`TwistRates`]):
//! - a box injected `k` ∈ 0..=200 cycles ahead of the arm on its running plan: the episode
//!   is first *rehearsed* without the box (everything is deterministic), the box is put
//!   where the rehearsal's arm was `k` cycles after the injection time (at its TCP, wrist,
//!   elbow or a point of a link axis), then the episode runs for real; 5 mm boxes among them;
//! - detection frames with a zero, future, stale or pre-start stamp, a repeated sequence, an
//!   object outside the calibrated workspace, more obstacles than a frame holds
//!   (`dropped_count > 0`), a dropout (no frames), a goal below the confidence floor;
//! - the link cut in the middle of a stop (a refused frame starts one), restored later,
//!   with the operator's acknowledgement or the cycle's auto-resume;
//! - a policy swapped in mid-episode.
//!
//! Frames go through the production intake ([`SceneIntake::accept`]), then onto the worker's
//! scene path (the cycle, the plan guard) and only then to the worker's one door,
//! `TwinWorker::note_frame` / `note_refused`: the order and the doors of `rt-core run`'s
//! intake thread and `TwinNode::receive` (`sweep::SweepIntake`).
//!
//! # What is counted
//! Hard counts (must be zero): commanded poses that penetrate (nominal geometry, see the
//! oracle) a box the runtime has known for at least one braking horizon, or the table;
//! joint steps over one period at the velocity limit (+ [`STEP_TOLERANCE`]); TCP speeds over
//! `max_tcp_speed_m_s`; TCP steps over the controller's 5 mm per target
//! ([`oracle::CONTROLLER_TCP_STEP_M`]); commands outside the joint limits; non-finite
//! commands.
//!
//! A box is *known* from the delivery of the first detection frame that carries it (accepted
//! or refused: a refused frame stops the arm). The *braking horizon* ([`BrakingHorizon`]) is
//! the time the cycle needs to stop from the velocity limit: the longer of the per-joint
//! brake (simulated from every joint at its velocity limit) and the stop along the plan
//! ([`PathStop::duration_s`]), plus one period for the cycle to act. A penetration of a box
//! known for less than that (or not yet known) is an *unavoidable intrusion*: counted
//! apart, with its depth. An arm caught inside a box that way may stay there (holds, sent
//! without a scene or while the box keeps every move refused): a later pose inside a known
//! box counts as hard only when it is *deeper* than the command before (by more than
//! 1 µm) or newly inside; otherwise it is counted as held inside. The table counts always.
//!
//! # Running it
//! The `sweep` binary (`make sweep`: 10 000 episodes) prints a table and writes
//! `summary.json`; it exits 1 when a hard count is not zero. A library call:
//!
//! ```no_run
//! use sweep::{SweepAssets, SweepSettings, run_sweep};
//! let assets = SweepAssets::load(std::path::Path::new("assets"))?;
//! let settings = SweepSettings { seed: 1, episodes: 100, ..SweepSettings::default() };
//! let summary = run_sweep(&assets, &settings, |_, _| {});
//! assert_eq!(summary.hard.total(), 0);
//! # Ok::<(), sweep::SweepAssetsError>(())
//! ```
//!
//! Replay one episode with `--first-episode I --episodes 1` (or [`run_episode`]): episodes
//! are independent and deterministic, whatever the number of threads.
//!
//! # The dynamic sweep
//! `sweep --dynamic` (`make sweep-dynamic`: 1 000 episodes) runs [`dynamic`] instead:
//! intruders that enter the workspace *during a motion* (stop on the path, cross it, stop
//! then leave, appear at once) at 0.1–1.6 m/s, 60 Hz frames with tracked velocities through
//! the same intake, every pose checked against the intruder's true box; contacts while
//! moving are split into unavoidable (closer than the arm could stop) and avoidable (a
//! failure: exit 1). Its summary has its own form; without `--dynamic` nothing changes.
//!
//! ```no_run
//! use sweep::SweepAssets;
//! use sweep::dynamic::{DynamicSettings, run_dynamic_sweep};
//! let assets = SweepAssets::load(std::path::Path::new("assets"))?;
//! let settings = DynamicSettings { seed: 1, episodes: 20, ..DynamicSettings::default() };
//! let summary = run_dynamic_sweep(&assets, &settings, |_, _| {});
//! assert_eq!(summary.failures_total(), 0);
//! # Ok::<(), sweep::SweepAssetsError>(())
//! ```
//!
//! [`ProductionWorker`]: rt_core::twin_thread::node::ProductionWorker
//! [`Cycle`]: rt_core::cycle::Cycle
//! [`serve::cycle_shield`]: rt_core::twin_thread::serve::cycle_shield
//! [`Brake`]: rt_core::cycle::brake::Brake
//! [`ManualClock`]: rt_core::rt::clock::ManualClock
//! [`SceneIntake::accept`]: rt_core::twin_thread::intake::SceneIntake::accept
//! [`PathStop::duration_s`]: rt_core::cycle::brake::PathStop::duration_s
//! [`STEP_TOLERANCE`]: rt_core::cycle::shield::STEP_TOLERANCE

#![forbid(unsafe_code)]

pub mod dynamic;
pub mod oracle;
mod sweep;

pub use sweep::{
    BrakingHorizon, BundledPolicyProblem, EpisodeReport, HardCounts, HardFailure, InjectionRecord,
    IntrusionSummary, MAX_INJECT_AHEAD_CYCLES, PolicyKind, SweepAssets, SweepAssetsError,
    SweepSettings, SweepSummary, SweepTally, TwistRates, goal_seeking_blob, run_episode, run_sweep,
};
