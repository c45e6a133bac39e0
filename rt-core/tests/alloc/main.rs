//! Zero-allocation tests with the one counting allocator (`rt_core::rt::alloc_count`): the
//! cycle over 100 000 cycles with policy swaps, the twin's per-step work, policy inference
//! and hot swaps, the xArm driver on the cycle path, and the production cycle (twin model, xArm driver)
//! moving on `xarm-sim`. One test binary, so the allocator
//! is global only here; measurements are serialised, since the counter is process-wide.

#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used)]
// The tests drive the runtime from threads of their own and wait in wall time; the bans of
// rt-core/clippy.toml (Instant::now, thread::sleep, Mutex) are for the runtime's own code.
#![allow(clippy::disallowed_methods, clippy::disallowed_types)]

#[path = "../common/rig.rs"]
mod common;
#[path = "../common/twin.rs"]
mod twin_fixtures;
#[path = "../common/xarm_rig.rs"]
mod xarm_rig;

mod cycle;
mod policy;
mod production_cycle;
mod twin_step;
mod xarm_driver;

use std::sync::{Mutex, MutexGuard};

use rt_core::rt::alloc_count::{self, CountingAlloc};

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// Holds off every other measurement of this binary while held.
pub fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs `f` on this thread with counting on; returns its result and the allocations,
/// reallocations and frees it made.
pub fn count_allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let serial = serial();
    count_allocations_holding(&serial, f)
}

/// [`count_allocations`] for a test that holds [`serial`] already, from before its set-up:
/// one whose cycle runs in real time must not wait for the lock between two of its cycles
/// (the production cycle test waited there, for the other tests' measurements, longer than
/// the freeze bound under the suite's load, and its cycle latched `Frozen`).
pub fn count_allocations_holding<T>(
    _serial: &MutexGuard<'static, ()>,
    f: impl FnOnce() -> T,
) -> (T, u64) {
    alloc_count::count_this_thread(true);
    let before = alloc_count::counted();
    let out = f();
    let after = alloc_count::counted();
    alloc_count::count_this_thread(false);
    (out, after - before)
}
