//! Time for the runtime, injected so that a run can be replayed deterministically: control
//! logic receives `now_ns` from its caller and never reads a clock itself. The loop driver
//! owns a [`Clock`]: [`MonotonicClock`] in production, [`ManualClock`] in tests and replays.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::rt::rt_setup;
use shm_schemas::clock::monotonic_now_ns;

/// A source of monotonic time in nanoseconds with an absolute sleep.
pub trait Clock: Send + Sync {
    /// The current time in nanoseconds since the clock's origin.
    fn now_ns(&self) -> u64;
    /// Blocks until `deadline_ns` (returns at once when it has passed).
    fn sleep_until_ns(&self, deadline_ns: u64);
}

/// `CLOCK_MONOTONIC`, with absolute sleeps through `clock_nanosleep(TIMER_ABSTIME)` (no
/// drift from relative sleeps). The origin is the moment of construction.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin_ns: u64,
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> Self {
        Self {
            origin_ns: monotonic_now_ns(),
        }
    }

    /// `CLOCK_MONOTONIC` at this clock's origin, ns: a stamp taken on the shared clock
    /// (a detection's capture time) minus this is a time on this clock.
    pub fn origin_ns(&self) -> u64 {
        self.origin_ns
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        monotonic_now_ns().saturating_sub(self.origin_ns)
    }

    fn sleep_until_ns(&self, deadline_ns: u64) {
        rt_setup::sleep_until_monotonic_ns(self.origin_ns.saturating_add(deadline_ns));
    }
}

/// A clock that only moves when told to: `sleep_until_ns` jumps to the deadline. Clones
/// share the same time.
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    now_ns: Arc<AtomicU64>,
}

impl ManualClock {
    /// A manual clock at `start_ns`.
    pub fn new(start_ns: u64) -> Self {
        Self {
            now_ns: Arc::new(AtomicU64::new(start_ns)),
        }
    }

    /// Moves the clock forward by `dt_ns`.
    pub fn advance_ns(&self, dt_ns: u64) {
        self.now_ns.fetch_add(dt_ns, Ordering::AcqRel);
    }

    /// Sets the clock (never backwards).
    pub fn set_ns(&self, t_ns: u64) {
        self.now_ns.fetch_max(t_ns, Ordering::AcqRel);
    }
}

impl Clock for ManualClock {
    fn now_ns(&self) -> u64 {
        self.now_ns.load(Ordering::Acquire)
    }

    fn sleep_until_ns(&self, deadline_ns: u64) {
        self.set_ns(deadline_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_jumps_to_deadlines_and_never_goes_back() {
        let c = ManualClock::new(10);
        c.sleep_until_ns(4_000);
        assert_eq!(c.now_ns(), 4_000);
        c.sleep_until_ns(1_000);
        assert_eq!(c.now_ns(), 4_000);
        let shared = c.clone();
        shared.advance_ns(6);
        assert_eq!(c.now_ns(), 4_006);
    }

    #[test]
    fn monotonic_clock_sleeps_at_least_until_the_deadline() {
        let c = MonotonicClock::new();
        let t0 = c.now_ns();
        c.sleep_until_ns(t0 + 2_000_000);
        assert!(c.now_ns() >= t0 + 2_000_000);
    }
}
