//! Process-wide requests for a controlled stop that do not come from the runtime's own
//! threads: every signal whose default action would end the process ([`install_signal_handlers`])
//! and, in a `panic = "abort"` build, a panic anywhere but the cycle thread
//! ([`install_panic_hook`]).
//!
//! Both only set a static flag ([`stop_requested`]); the cycle reads it through
//! [`crate::cycle::CycleControl::shutdown_requested`] every period, brakes the arm to rest
//! along its plan, leaves its loop and puts the controller in its stop state (`SET_STATE 4`
//! on an xArm). A handler does nothing else (setting an atomic is async-signal-safe).
//!
//! Signals: SIGHUP, SIGINT, SIGQUIT, SIGTERM, SIGUSR2, SIGALRM, SIGXCPU, SIGXFSZ, SIGVTALRM,
//! SIGPROF, SIGIO, SIGPWR, SIGSTKFLT, the job-control stops SIGTSTP, SIGTTIN and SIGTTOU (a
//! stopped process would leave the arm mid-plan) and the real-time signals request the stop.
//! SIGSTOP cannot be caught: after it (or a paused VM) the cycle sees the gap and stops at
//! the measured joints ([`crate::cycle::StopReason::Frozen`]). SIGPIPE is
//! counted and otherwise ignored (a broken socket is an error of the write, never the end of
//! the process). SIGUSR1, the operator's acknowledgement, is caught from the start so that
//! one sent before the runtime listens for it does not kill the process (it is dropped: an
//! acknowledgement counts only while a protective stop is latched). SIGKILL and SIGSTOP
//! cannot be caught; the fault signals (SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGTRAP, SIGSYS)
//! and SIGABRT keep their default action: the process state cannot be trusted to brake.
//!
//! Panics under `panic = "abort"` (the `deploy` profile): unwinding is gone, so the
//! runtime's `catch_unwind` cannot turn a twin-thread panic into a controlled stop. The hook
//! sets the flag and waits, bounded, until every cycle thread has ended (after its stop and
//! `SET_STATE 4`; see [`CycleRunning`]), after the default hook has printed the panic; then
//! the process aborts.
//! A panic *on* the cycle thread cannot brake (the cycle is the one that brakes): the hook
//! returns at once, the process aborts, and the controller holds the last target it got.
//! The cycle's code is written not to panic (no `unwrap`, no indexing past fixed bounds).

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// The last stop signal received (0: none).
static STOP_SIGNAL: AtomicUsize = AtomicUsize::new(0);
/// SIGPIPE deliveries (ignored otherwise).
static PIPE_SIGNALS: AtomicUsize = AtomicUsize::new(0);
/// SIGUSR1 deliveries before the runtime's own handler (dropped).
static EARLY_ACKS: AtomicUsize = AtomicUsize::new(0);
/// A panic asked for the stop (abort builds only).
static PANICKED: AtomicBool = AtomicBool::new(false);
/// Cycle threads running (see [`CycleRunning`]).
static CYCLES_RUNNING: AtomicUsize = AtomicUsize::new(0);
static SIGNALS_INSTALLED: AtomicBool = AtomicBool::new(false);
static PANIC_HOOK_INSTALLED: AtomicBool = AtomicBool::new(false);

thread_local! {
    static ON_CYCLE_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// The signals whose default action ends the process and that request a controlled stop
/// instead (the real-time signals are added at install time: their numbers are the C
/// library's).
pub const STOP_SIGNALS: [libc::c_int; 16] = [
    libc::SIGHUP,
    libc::SIGINT,
    libc::SIGQUIT,
    libc::SIGTERM,
    libc::SIGUSR2,
    libc::SIGALRM,
    libc::SIGXCPU,
    libc::SIGXFSZ,
    libc::SIGVTALRM,
    libc::SIGPROF,
    libc::SIGIO,
    libc::SIGPWR,
    libc::SIGSTKFLT,
    // A terminal's Ctrl-Z and background reads/writes would stop the process with the arm
    // mid-plan (issue 30 item 3): a controlled stop instead, then the process ends.
    libc::SIGTSTP,
    libc::SIGTTIN,
    libc::SIGTTOU,
];

/// A signal handler could not be installed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("installing the handler of signal {signal}: {kind}")]
pub struct SignalInstallError {
    /// The signal number.
    pub signal: libc::c_int,
    /// Why.
    pub kind: std::io::ErrorKind,
}

/// Installs the handlers described in the module docs (once; later calls do nothing).
/// Call it first thing, before any connection to the arm.
///
/// # Errors
/// [`SignalInstallError`] naming the signal whose handler was refused.
pub fn install_signal_handlers() -> Result<(), SignalInstallError> {
    if SIGNALS_INSTALLED.swap(true, Ordering::AcqRel) {
        return Ok(());
    }
    let err = |signal: libc::c_int| {
        move |e: std::io::Error| SignalInstallError {
            signal,
            kind: e.kind(),
        }
    };
    let realtime = libc::SIGRTMIN()..=libc::SIGRTMAX();
    for sig in STOP_SIGNALS.into_iter().chain(realtime) {
        let value = usize::try_from(sig).unwrap_or(usize::MAX);
        signal_hook::flag::register_usize(sig, &STOP_SIGNAL, value).map_err(err(sig))?;
    }
    count_on(libc::SIGPIPE, &PIPE_SIGNALS).map_err(err(libc::SIGPIPE))?;
    count_on(libc::SIGUSR1, &EARLY_ACKS).map_err(err(libc::SIGUSR1))?;
    Ok(())
}

fn count_on(signal: libc::c_int, counter: &'static AtomicUsize) -> std::io::Result<()> {
    // SAFETY: the action only increments a static atomic, which is async-signal-safe (no
    // allocation, no lock, no re-entrancy hazard).
    unsafe {
        signal_hook::low_level::register(signal, move || {
            counter.fetch_add(1, Ordering::SeqCst);
        })
    }
    .map(|_| ())
}

/// Whether a signal or a panic requested a controlled stop of the whole process.
pub fn stop_requested() -> bool {
    STOP_SIGNAL.load(Ordering::Acquire) != 0 || PANICKED.load(Ordering::Acquire)
}

/// The last stop signal received, if any.
pub fn stop_signal() -> Option<libc::c_int> {
    match STOP_SIGNAL.load(Ordering::Acquire) {
        0 => None,
        s => libc::c_int::try_from(s).ok(),
    }
}

/// The name of `signal` (`SIGHUP`), or its number.
pub fn signal_name(signal: libc::c_int) -> String {
    signal_hook::low_level::signal_name(signal)
        .map_or_else(|| format!("signal {signal}"), str::to_owned)
}

/// Marks the calling thread as a running cycle thread until dropped; the panic hook waits
/// for every one of them to end before the process aborts. Create it first thing on the
/// cycle thread and drop it after the controller was put in its stop state.
#[derive(Debug)]
pub struct CycleRunning(());

impl CycleRunning {
    /// Counts the calling thread in.
    #[must_use]
    pub fn enter() -> Self {
        CYCLES_RUNNING.fetch_add(1, Ordering::AcqRel);
        ON_CYCLE_THREAD.with(|c| c.set(true));
        Self(())
    }
}

impl Drop for CycleRunning {
    fn drop(&mut self) {
        let _ = ON_CYCLE_THREAD.try_with(|c| c.set(false));
        CYCLES_RUNNING.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Cycle threads running now.
pub fn cycles_running() -> usize {
    CYCLES_RUNNING.load(Ordering::Acquire)
}

/// Installs (once) a panic hook that, in a `panic = "abort"` build, requests the controlled
/// stop and waits up to `wait` for every cycle thread to end (after the default hook has
/// printed the panic) before the process aborts. In an unwinding build it only chains to the default
/// hook: the runtime's `catch_unwind` turns the panic into the same controlled stop.
pub fn install_panic_hook(wait: Duration) {
    if PANIC_HOOK_INSTALLED.swap(true, Ordering::AcqRel) {
        return;
    }
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if cfg!(panic = "abort") {
            // Brake first: nothing below may keep the cycle from seeing the request (issue
            // 30 item 4: printing to a full disk or a closed pipe once panicked in here,
            // which aborts at once, without the stop).
            PANICKED.store(true, Ordering::Release);
        }
        default(info);
        if cfg!(panic = "abort") {
            brake_before_abort(wait);
        }
    }));
}

/// The panic hook's stop: the flag, then a bounded wait for the cycle threads. Returns
/// whether every cycle thread ended in time (`true` too when none ran). On a cycle thread
/// it returns `false` at once (it cannot wait for itself).
pub fn brake_before_abort(wait: Duration) -> bool {
    PANICKED.store(true, Ordering::Release);
    wait_for_cycles(wait)
}

// The panic path, off the cycle: waits in wall time for the cycle to brake.
#[allow(clippy::disallowed_methods)]
fn wait_for_cycles(wait: Duration) -> bool {
    let mut stderr = std::io::stderr();
    if ON_CYCLE_THREAD.try_with(Cell::get).unwrap_or(false) {
        say(
            &mut stderr,
            format_args!(
                "rt-core: panic on the cycle thread: no controlled stop is possible; aborting"
            ),
        );
        return false;
    }
    if cycles_running() == 0 {
        return true;
    }
    say(
        &mut stderr,
        format_args!("rt-core: panic: braking the arm to rest before aborting"),
    );
    let deadline = Instant::now() + wait;
    while cycles_running() > 0 {
        if Instant::now() >= deadline {
            say(
                &mut stderr,
                format_args!("rt-core: the cycle did not end within {wait:?}; aborting anyway"),
            );
            return false;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    // The cycle's last events (the stop, at rest) sit in its log ring until the non-RT drain
    // thread (every 20 ms) writes them: give it a few periods before the abort, so the
    // operator's log tells how the arm stopped.
    std::thread::sleep(LOG_DRAIN_GRACE);
    true
}

/// One line to `out`, its error ignored: the panic path must never panic itself
/// (`eprintln!` panics when stderr cannot be written: a full disk, a closed pipe).
fn say(out: &mut impl std::io::Write, line: std::fmt::Arguments<'_>) {
    let _ = writeln!(out, "{line}");
}

/// How long the panic hook lets the cycle's log drain run after the cycle ended (several
/// of the drain's 20 ms periods).
const LOG_DRAIN_GRACE: Duration = Duration::from_millis(100);

#[cfg(test)]
// The tests wait in wall time (a helper thread ends after a sleep); they are not the cycle.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    /// Issue 30 item 4: the hook's lines go to a writer that fails (stderr on /dev/full or
    /// a closed pipe) without panicking.
    #[test]
    fn the_panic_path_prints_to_a_failing_stderr_without_panicking() {
        struct Full;
        impl std::io::Write for Full {
            fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
                Err(std::io::Error::from(std::io::ErrorKind::StorageFull))
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Err(std::io::Error::from(std::io::ErrorKind::BrokenPipe))
            }
        }
        say(&mut Full, format_args!("rt-core: panic: braking the arm"));
        let mut sink = Vec::new();
        say(&mut sink, format_args!("line {}", 1));
        assert_eq!(sink, b"line 1\n");
    }

    #[test]
    fn the_panic_wait_ends_with_the_cycle_threads_and_never_waits_for_itself() {
        // (The stop flag itself is process-wide and would stop every other test's cycle:
        // only the wait is tested here; the whole hook is tested on the deploy build.)
        let running = CycleRunning::enter();
        assert!(
            !wait_for_cycles(Duration::from_secs(5)),
            "on the cycle thread"
        );
        let t = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(50));
            drop(running);
        });
        let waited = std::thread::spawn(|| wait_for_cycles(Duration::from_secs(5)));
        assert!(waited.join().unwrap_or(false));
        t.join().ok();
        ON_CYCLE_THREAD.with(|c| c.set(false));
    }
}
