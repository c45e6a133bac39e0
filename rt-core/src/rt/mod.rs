//! The real-time toolkit beneath the two threads: lock-free hand-overs ([`handoff`]), the
//! cycle's log ring ([`rt_log`]), injected time ([`clock`]), the thread's real-time set-up
//! ([`rt_setup`]), latency histograms ([`histogram`]), the counting allocator of the
//! zero-allocation checks ([`alloc_count`]) and the process-wide stop requests of signals and
//! panics ([`process_stop`]).

pub mod alloc_count;
pub mod clock;
pub mod handoff;
pub mod histogram;
pub mod process_stop;
pub mod rt_log;
pub mod rt_setup;
