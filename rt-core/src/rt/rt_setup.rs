//! Real-time set-up of the process and the cycle thread, and the few OS calls the runtime
//! needs: pinning (`sched_setaffinity`), `SCHED_FIFO` (`sched_setscheduler`), memory locking
//! (`mlockall`) with a pre-faulted stack, and absolute sleeps on the monotonic clock (read
//! with the contract's [`shm_schemas::clock::monotonic_now_ns`]).
//!
//! Every refusal of the OS (no privilege, a container, a CPU that does not exist) is
//! reported once, clearly, through `tracing::warn!` and in the returned [`RtSetupReport`],
//! and the program runs on without it. This is the runtime's module of `unsafe` OS calls
//! for real-time set-up (the others: the counting allocator of [`super::alloc_count`] and the
//! signal counters of [`super::process_stop`]; the clock is read with
//! [`shm_schemas::clock`], process ties are [`shm_schemas::process_ties`]).

use std::hint::black_box;

/// What the real-time set-up asked for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RtRequest {
    /// Pin the calling thread to this CPU.
    pub cpu: Option<usize>,
    /// Ask for `SCHED_FIFO` at this priority (1..=99).
    pub rt_priority: Option<i32>,
    /// Lock current and future memory (`mlockall`) and pre-fault the stack.
    pub lock_memory: bool,
}

/// The outcome of each step: `None` when not asked, `Some(Ok)` when granted, `Some(Err(errno))`
/// when the OS refused.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct RtSetupReport {
    /// Pinning to the requested CPU.
    pub pinned: Option<Result<usize, i32>>,
    /// `SCHED_FIFO` at the requested priority.
    pub fifo: Option<Result<i32, i32>>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`.
    pub memory_locked: Option<Result<(), i32>>,
    /// The thread's timer slack was set to 1 ns.
    pub timer_slack_1ns: bool,
}

/// Bytes of stack pre-faulted after `mlockall` so the cycle never page-faults on it.
pub const PREFAULT_STACK_BYTES: usize = 256 * 1024;

fn last_errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

/// Applies `req` to the calling thread (and, for memory, the process). Reports each refusal
/// once with `tracing::warn!` and carries on.
pub fn apply(req: &RtRequest) -> RtSetupReport {
    // A 1 ns timer slack for this thread: SCHED_OTHER sleeps otherwise wake up to 50 µs late.
    let mut report = RtSetupReport {
        timer_slack_1ns: set_timer_slack_ns(1).is_ok(),
        ..RtSetupReport::default()
    };
    if req.lock_memory {
        let r = lock_memory();
        if let Err(e) = r {
            tracing::warn!(
                errno = e,
                "mlockall refused ({}); memory is not locked — raise `ulimit -l` or grant CAP_IPC_LOCK; running on",
                std::io::Error::from_raw_os_error(e)
            );
        }
        prefault_stack();
        report.memory_locked = Some(r);
    }
    if let Some(cpu) = req.cpu {
        let r = pin_current_thread(cpu).map(|()| cpu);
        if let Err(e) = r {
            tracing::warn!(
                cpu,
                errno = e,
                "pinning to CPU {cpu} refused ({}); the cycle thread floats — running on",
                std::io::Error::from_raw_os_error(e)
            );
        }
        report.pinned = Some(r);
    }
    if let Some(prio) = req.rt_priority {
        let r = set_fifo(prio).map(|()| prio);
        if let Err(e) = r {
            tracing::warn!(
                priority = prio,
                errno = e,
                "SCHED_FIFO priority {prio} refused ({}); the cycle runs SCHED_OTHER — raise `ulimit -r` or grant CAP_SYS_NICE; running on",
                std::io::Error::from_raw_os_error(e)
            );
        }
        report.fifo = Some(r);
    }
    report
}

/// Pins the calling thread to `cpu`.
///
/// # Errors
/// The errno of `sched_setaffinity` (`EINVAL` for a CPU outside the allowed set).
pub fn pin_current_thread(cpu: usize) -> Result<(), i32> {
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(libc::EINVAL);
    }
    // SAFETY: `cpu_set_t` is a plain bit array for which all-zero is a valid value.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: `cpu` was checked against CPU_SETSIZE above, so CPU_SET stays in bounds.
    unsafe { libc::CPU_SET(cpu, &mut set) };
    // SAFETY: pid 0 is the calling thread; `set` is a valid, initialised cpu_set_t and the
    // size passed is its exact size.
    let rc = unsafe { libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set) };
    if rc == 0 { Ok(()) } else { Err(last_errno()) }
}

/// Sets the calling thread's timer slack (`PR_SET_TIMERSLACK`), ns.
///
/// # Errors
/// The errno of `prctl`.
pub fn set_timer_slack_ns(slack_ns: u64) -> Result<(), i32> {
    // SAFETY: PR_SET_TIMERSLACK takes one integer argument and touches no memory of ours.
    let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, slack_ns as libc::c_ulong, 0, 0, 0) };
    if rc == 0 { Ok(()) } else { Err(last_errno()) }
}

/// Switches the calling thread to `SCHED_FIFO` at `priority`.
///
/// # Errors
/// The errno of `sched_setscheduler` (`EPERM` without CAP_SYS_NICE / `ulimit -r`).
pub fn set_fifo(priority: i32) -> Result<(), i32> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pid 0 is the calling thread and `param` is a valid sched_param that outlives
    // the call.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 { Ok(()) } else { Err(last_errno()) }
}

/// Locks current and future pages of the process in RAM.
///
/// # Errors
/// The errno of `mlockall` (`EPERM`/`ENOMEM` under a small `ulimit -l`).
///
/// `MCL_FUTURE` is only asked for when the memlock limit is unlimited or the process runs as
/// root (CAP_IPC_LOCK): under a finite limit it would make later allocations fail once the
/// limit is reached, so only the current pages are locked then.
pub fn lock_memory() -> Result<(), i32> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `lim` is a valid, writable rlimit.
    let got = unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut lim) } == 0;
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    let future = root || (got && lim.rlim_cur == libc::RLIM_INFINITY);
    let flags = if future {
        libc::MCL_CURRENT | libc::MCL_FUTURE
    } else {
        libc::MCL_CURRENT
    };
    // SAFETY: mlockall takes only flags and touches no memory of ours.
    let rc = unsafe { libc::mlockall(flags) };
    if rc == 0 { Ok(()) } else { Err(last_errno()) }
}

/// Touches [`PREFAULT_STACK_BYTES`] of the calling thread's stack so later use does not fault.
#[inline(never)]
pub fn prefault_stack() {
    let buf = [0u8; PREFAULT_STACK_BYTES];
    black_box(&buf);
}

/// Sleeps until the absolute `CLOCK_MONOTONIC` time `deadline_ns` (retries on EINTR).
pub fn sleep_until_monotonic_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; the remainder pointer may be null with
        // TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != libc::EINTR {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cpu_that_does_not_exist_is_refused_not_fatal() {
        let report = apply(&RtRequest {
            cpu: Some(100_000),
            rt_priority: None,
            lock_memory: false,
        });
        assert_eq!(report.pinned, Some(Err(libc::EINVAL)));
        assert_eq!(report.fifo, None);
    }

    #[test]
    fn pinning_to_cpu_zero_is_granted_on_linux() {
        let handle = std::thread::spawn(|| pin_current_thread(0));
        assert_eq!(handle.join().ok(), Some(Ok(())));
    }

    #[test]
    fn monotonic_time_advances() {
        let a = shm_schemas::clock::monotonic_now_ns();
        sleep_until_monotonic_ns(a + 1_000_000);
        assert!(shm_schemas::clock::monotonic_now_ns() >= a + 1_000_000);
    }
}
