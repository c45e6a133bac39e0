//! The cycle thread itself: applies the real-time set-up on the thread that will run the
//! cycle (pinning, SCHED_FIFO, locked memory), counts every allocation made on it, runs
//! [`run_loop`] until asked to stop (or, after a shutdown request, until the arm is at
//! rest), and then — also after a panic in the loop — puts the controller in its stop
//! state. `rt-core run` and `rt-core bench-loop` both start their
//! cycle this way, so the figures of the bench are those of the real runtime.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::thread::JoinHandle;

use crate::cycle::link::RobotLink;
use crate::cycle::shield::ShieldModel;
use crate::cycle::{Cycle, LoopShared, LoopStats, run_loop};
use crate::rt::alloc_count;
use crate::rt::clock::Clock;
use crate::rt::process_stop;
use crate::rt::rt_setup::{self, RtRequest, RtSetupReport};

/// What the cycle thread hands back when it stops.
pub struct CycleThreadResult<M: ShieldModel, L: RobotLink> {
    /// Wake-up and compute histograms, missed deadlines.
    pub stats: LoopStats,
    /// What the OS granted of the real-time request.
    pub rt: RtSetupReport,
    /// Allocations made on the cycle thread while it ran (must be 0).
    pub allocations: u64,
    /// The cycle, for its last report.
    pub cycle: Cycle<M, L>,
}

/// Starts the cycle thread (named `cycle`).
///
/// # Errors
/// The OS error if the thread cannot be spawned.
pub fn spawn_cycle_thread<M, L, C>(
    mut cycle: Cycle<M, L>,
    clock: C,
    request: RtRequest,
    stop: Arc<AtomicBool>,
    shared: Arc<LoopShared>,
) -> std::io::Result<JoinHandle<CycleThreadResult<M, L>>>
where
    M: ShieldModel + Send + 'static,
    L: RobotLink + Send + 'static,
    C: Clock + Send + 'static,
{
    std::thread::Builder::new()
        .name("cycle".into())
        .spawn(move || {
            // Counted until the controller is in its stop state: a panic elsewhere in a
            // `panic = "abort"` build waits for that before the process aborts.
            let running = process_stop::CycleRunning::enter();
            let rt = rt_setup::apply(&request);
            let mut stats = LoopStats::default();
            alloc_count::count_this_thread(true);
            let before = alloc_count::counted();
            // A panic inside the loop is caught here: the controller is still put in its
            // stop state (SET_STATE 4 on an xArm) before the thread ends.
            let looped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                run_loop(&mut cycle, &clock, &stop, &shared, &mut stats);
            }));
            let allocations = alloc_count::counted() - before;
            alloc_count::count_this_thread(false);
            cycle.link_mut().stop_controller(clock.now_ns());
            shared
                .finished
                .store(true, std::sync::atomic::Ordering::Release);
            drop(running);
            if let Err(panic) = looped {
                std::panic::resume_unwind(panic);
            }
            CycleThreadResult {
                stats,
                rt,
                allocations,
                cycle,
            }
        })
}
