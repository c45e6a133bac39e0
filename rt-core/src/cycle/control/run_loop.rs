//! The loop that drives a [`Cycle`] at its period on a [`Clock`] ([`run_loop`]), with its
//! timing figures ([`LoopStats`], [`LoopSummary`]) and the counters other threads watch
//! ([`LoopShared`]). The thread that runs it is [`crate::cycle::thread`].

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use super::Cycle;
use crate::cycle::link::RobotLink;
use crate::cycle::shield::ShieldModel;
use crate::rt::clock::Clock;
use crate::rt::histogram::{Histogram, Summary};

/// Timing figures of a loop run.
#[derive(Default)]
pub struct LoopStats {
    /// Wake-up latency (actual wake − deadline).
    pub wake: Histogram,
    /// Compute time of `process`.
    pub compute: Histogram,
    /// Deadlines missed (a cycle that ended after the next deadline), whatever the cause:
    /// a late wake-up (the OS) or a long compute (the cycle).
    pub missed_deadlines: u64,
    /// Cycles whose own compute took longer than the period: the part of the missed
    /// deadlines that the cycle's code answers for, whatever the OS did to the wake-up.
    pub compute_overruns: u64,
    /// Cycles run.
    pub cycles: u64,
}

/// Summary of a loop run (JSON for the bench).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct LoopSummary {
    /// Cycles run.
    pub cycles: u64,
    /// Deadlines missed.
    pub missed_deadlines: u64,
    /// Cycles whose compute alone exceeded the period.
    pub compute_overruns: u64,
    /// Wake-up latency, µs.
    pub wakeup_latency_us: Summary,
    /// Compute time, µs.
    pub cycle_compute_us: Summary,
}

impl LoopStats {
    /// The summary.
    pub fn summary(&self) -> LoopSummary {
        LoopSummary {
            cycles: self.cycles,
            missed_deadlines: self.missed_deadlines,
            compute_overruns: self.compute_overruns,
            wakeup_latency_us: self.wake.summary(),
            cycle_compute_us: self.compute.summary(),
        }
    }
}

/// Counters of a running loop that other threads may read (relaxed atomics).
#[derive(Debug, Default)]
pub struct LoopShared {
    /// Cycles run (a watchdog checks that it moves).
    pub heartbeat: AtomicU64,
    /// Deadlines missed so far.
    pub missed_deadlines: AtomicU64,
    /// Compute time of the last cycle, ns.
    pub last_compute_ns: AtomicU64,
    /// The cycle thread has ended (normally or by a panic) and the controller was put in
    /// its stop state.
    pub finished: AtomicBool,
}

/// Drives `cycle` every `period_ns` on `clock` until `stop` is set or, after a shutdown
/// request ([`CycleControl::request_shutdown`](super::CycleControl::request_shutdown)), until the arm is at rest, recording timing
/// into `stats` and publishing counters in `shared`. Allocation-free.
pub fn run_loop<M: ShieldModel, L: RobotLink, C: Clock>(
    cycle: &mut Cycle<M, L>,
    clock: &C,
    stop: &AtomicBool,
    shared: &LoopShared,
    stats: &mut LoopStats,
) {
    let period = cycle.cfg.period_ns;
    let mut deadline = clock.now_ns() + period;
    while !stop.load(Ordering::Acquire) {
        clock.sleep_until_ns(deadline);
        let wake = clock.now_ns();
        stats.wake.record_ns(wake.saturating_sub(deadline));
        cycle.process(wake);
        let done = clock.now_ns();
        let compute = done.saturating_sub(wake);
        stats.compute.record_ns(compute);
        stats.cycles += 1;
        if compute > period {
            stats.compute_overruns += 1;
        }
        shared.last_compute_ns.store(compute, Ordering::Relaxed);
        shared.heartbeat.fetch_add(1, Ordering::Release);
        if cycle.report.shutdown_complete {
            break;
        }
        deadline += period;
        if done > deadline {
            let behind = (done - deadline) / period + 1;
            stats.missed_deadlines += behind;
            shared.missed_deadlines.fetch_add(behind, Ordering::Relaxed);
            deadline += behind * period;
        }
    }
}
