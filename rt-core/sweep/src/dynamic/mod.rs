//! The dynamic sweep (`sweep --dynamic`, `make sweep-dynamic`): randomised intrusions
//! *during a motion*, on the same production rig as the static sweep (the twin worker with
//! the real lookahead, plan guard and intake; the cycle with its shield and brakes; a manual
//! clock).
//!
//! # An episode
//! A still world (a task scene, or the goal alone) and a policy (the bundled one, or the
//! goal-seeker) are *rehearsed* without an intruder: the arm must get a plan and reach its
//! goal, else another world is drawn. At a random point of the rehearsal's motion an
//! intruder box (random size, speed 0.1–1.6 m/s, random direction) is placed on the arm's
//! path ([`IntruderKind`]): it enters the workspace and stops on the path, crosses the path,
//! stops on it and leaves, or appears at once on or near it (and later leaves). Issue 42's
//! kinds ([`IntruderKind::GROWN`], [`intruder::grown`]; `--kinds` selects, [`kinds`]): a box
//! already moving when the arm starts, a near miss beside the way, a box that parks on the
//! path, one that takes the goal, one that appears next to the arm. The episode then runs
//! again with it. Frames come at 60 Hz, stamped with their capture time and
//! delivered 10–30 ms later through the production intake; each carries the intruder's true
//! centre at capture plus noise, its velocity as a tracker reports it (true velocity plus
//! noise; zero with `UNKNOWN_VELOCITY_SIGMA_M_S` for its first two frames), and is settled
//! only when nothing moves and nothing changed for 0.3 s.
//!
//! # What is counted
//! Every pose of the arm is checked against the intruder's *true* box at that time by the
//! oracle: a contact *while moving* (a capsule in contact moved with that command) or *at
//! rest* (the intruder walked into a still arm). Each time the intruder starts to threaten
//! (it appears, or moves off after standing) is an [`Onset`], judged at the capture of the
//! first frame that shows it: *unavoidable* when its clearance to the arm is below the
//! stopping distance (the arm's travel during the reaction and its path stop from its
//! current speed, plus the intruder's travel meanwhile); a contact while moving within such
//! an onset's window (reaction plus stop) is unavoidable, any other is *avoidable* — a
//! failure, like any static hard count. Besides: the reaction latency (from the first frame
//! in which the intruder came near the rest of the path to the first command that differs
//! from the rehearsal's), whether the arm reaches its goal after the intruder left (or came
//! to rest out of the way), and the time lost against the rehearsal.
//!
//! [`Onset`]: report::Onset

pub mod episode;
pub mod intruder;
pub mod kinds;
pub mod outcome;
pub mod report;
pub mod summary;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use serde::Serialize;

pub use episode::run_dynamic_episode;
pub use intruder::{Intruder, IntruderKind};
pub use kinds::KindSet;
pub use report::DynamicEpisodeReport;
pub use summary::{DynamicSummary, DynamicTally, GroupFigures};

use crate::sweep::{BrakingHorizon, SweepAssets};

/// Mixed into the sweep's seed, so a dynamic episode draws apart from the static one of the
/// same index.
pub(crate) const DYNAMIC_SEED_SALT: u64 = 0xd1a7_1c5e_ed00_0001;

/// How the dynamic sweep runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DynamicSettings {
    /// Seed of the whole sweep.
    pub seed: u64,
    /// Number of episodes.
    pub episodes: u64,
    /// Index of the first episode (replay one: `first_episode = i, episodes = 1`).
    pub first_episode: u64,
    /// Worker threads.
    pub jobs: usize,
    /// Longest run with the intruder, s.
    pub max_episode_s: f64,
    /// Frames per second.
    pub frame_rate_hz: f64,
    /// Shortest capture-to-delivery latency, s.
    pub latency_min_s: f64,
    /// Longest capture-to-delivery latency, s.
    pub latency_max_s: f64,
    /// Slowest intruder, m/s.
    pub min_speed_m_s: f64,
    /// Fastest intruder, m/s.
    pub max_speed_m_s: f64,
    /// A frame is settled only this long after the world last changed, s.
    pub settle_quiet_s: f64,
    /// The arm counts as continuing to its goal when it reaches it within this long after
    /// the intruder left (or came to rest out of the way), s.
    pub reach_limit_s: f64,
    /// Noise of the intruder's reported centre, 1 sigma per axis, m.
    pub position_noise_m: f64,
    /// Noise of its reported velocity, 1 sigma per axis (also the sigma reported), m/s.
    pub velocity_noise_m_s: f64,
    /// Still worlds tried per episode until one is reached in rehearsal.
    pub world_attempts: u32,
    /// Perception never sees the intruder (frames without it, settled): a runtime that
    /// cannot react, for the sweep's own test that its checks find the contacts.
    pub blind_to_intruder: bool,
    /// The planner fallback installed in the worker (`rt-core run --planner-fallback on`):
    /// the continuation after the intruder has left may then go by the planner's path where
    /// no policy passes from where the arm stopped.
    pub planner_fallback: bool,
    /// The intruder kinds drawn (`--kinds`; default all): [`KindSet::CLASSIC`] is the sweep
    /// before issue 42, episode for episode.
    pub kinds: KindSet,
}

impl Default for DynamicSettings {
    fn default() -> Self {
        Self {
            seed: 1,
            episodes: 100,
            first_episode: 0,
            jobs: 1,
            max_episode_s: 30.0,
            frame_rate_hz: 60.0,
            latency_min_s: 0.010,
            latency_max_s: 0.030,
            min_speed_m_s: 0.1,
            max_speed_m_s: 1.6,
            settle_quiet_s: 0.3,
            reach_limit_s: 10.0,
            position_noise_m: 0.002,
            velocity_noise_m_s: 0.03,
            world_attempts: 8,
            blind_to_intruder: false,
            planner_fallback: false,
            kinds: KindSet::ALL,
        }
    }
}

impl DynamicSettings {
    /// `latency_max_s - latency_min_s` (never negative).
    pub fn latency_span_s(&self) -> f64 {
        (self.latency_max_s - self.latency_min_s).max(0.0)
    }
}

/// Runs the dynamic sweep on `settings.jobs` threads; `progress` is called (on the calling
/// thread) after each episode with the tally so far. The figures do not depend on the number
/// of threads.
// Wall time of the sweep, for its summary only; never fed to the cycle or the worker.
#[allow(clippy::disallowed_methods)]
pub fn run_dynamic_sweep(
    assets: &SweepAssets,
    settings: &DynamicSettings,
    mut progress: impl FnMut(&DynamicEpisodeReport, &DynamicTally),
) -> DynamicSummary {
    let t0 = std::time::Instant::now();
    let mut tally = DynamicTally::new(*settings, BrakingHorizon::of(&assets.cfg));
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel::<DynamicEpisodeReport>();
    std::thread::scope(|s| {
        for _ in 0..settings.jobs.max(1) {
            let tx = tx.clone();
            let (next, stop) = (&next, &stop);
            s.spawn(move || {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed) as u64;
                    if i >= settings.episodes || stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let r = run_dynamic_episode(assets, settings, settings.first_episode + i);
                    if tx.send(r).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for r in rx {
            tally.add(&r);
            progress(&r, &tally);
        }
        stop.store(true, Ordering::Relaxed);
    });
    tally.summary(assets, t0.elapsed().as_secs_f64())
}
