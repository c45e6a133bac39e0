//! Process ties: how Foresight's processes are bound to the one that started them, so none
//! outlives it whatever the way out (`kill -9` included) — the parent-death signal
//! (`PR_SET_PDEATHSIG`), own process groups, and signalling a process or a group.
//!
//! Why here: the launcher, `rt-core`, `zenoh-relay` (and its learner child) all need the
//! same few calls, and `shm-schemas` is the lowest crate every one of those processes links
//! (it already holds the contract's clock, [`crate::clock`], and the crate already needs
//! `unsafe` for zero-copy payloads). A crate of its own for five functions would be one
//! more member to keep; with the calls here, the binaries and the launcher need no
//! `unsafe` and forbid it. `xarm` stays a leaf with its own `geteuid`, and rt-core's
//! real-time set-up (`rt_setup`: pinning, `SCHED_FIFO`, `mlockall`) stays with the runtime.
//!
//! Every call takes plain integers and touches no memory of ours; the one that runs in a
//! child between `fork` and `exec` ([`tie_child`]) makes only async-signal-safe calls and
//! allocates nothing.

use std::os::unix::process::CommandExt;
use std::process::Command;

/// How a child started through [`tie_child`] is bound to this process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChildTies {
    /// The child leads a process group of its own (which [`signal_process_group`] stops as
    /// a whole, and which a terminal's Ctrl-C does not reach).
    pub own_process_group: bool,
    /// The child refuses to run (its spawn fails with `ESRCH`) when this process died
    /// between the fork and the parent-death request (it was re-parented and would never
    /// get the signal).
    pub refuse_if_orphaned: bool,
}

/// Asks the kernel to send this process `SIGTERM` when its parent dies (the parent thread,
/// strictly: prctl(2) ties it to the thread that started the process).
///
/// # Errors
/// The OS error of `prctl(PR_SET_PDEATHSIG)`.
pub fn stop_with_parent() -> std::io::Result<()> {
    if set_parent_death_signal(libc::SIGTERM) != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Ties the child `cmd` will start to this process: `SIGTERM` to the child when this
/// process (the thread calling `spawn`) dies, and the [`ChildTies`] asked for. The ties
/// are made in the child before it runs; a failure makes `spawn` fail.
pub fn tie_child(cmd: &mut Command, ties: ChildTies) {
    let parent_pid = std::process::id();
    // SAFETY: the closure runs in the child between fork and exec, where only
    // async-signal-safe calls are allowed: `tie_in_child` makes only setpgid, prctl and
    // getppid calls and allocates nothing (its errors are raw OS errors).
    unsafe {
        cmd.pre_exec(move || tie_in_child(parent_pid, ties));
    }
}

/// In the child, before exec (see [`tie_child`]).
fn tie_in_child(parent_pid: u32, ties: ChildTies) -> std::io::Result<()> {
    if ties.own_process_group {
        // SAFETY: setpgid(0, 0) makes the calling process the leader of a new group; it
        // takes plain integers and touches no memory.
        if unsafe { libc::setpgid(0, 0) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    if set_parent_death_signal(libc::SIGTERM) != 0 {
        return Err(std::io::Error::last_os_error());
    }
    if ties.refuse_if_orphaned && std::os::unix::process::parent_id() != parent_pid {
        return Err(std::io::Error::from_raw_os_error(libc::ESRCH));
    }
    Ok(())
}

/// `prctl(PR_SET_PDEATHSIG, signal)`; its return code.
fn set_parent_death_signal(signal: libc::c_int) -> libc::c_int {
    // SAFETY: PR_SET_PDEATHSIG takes one integer argument (a signal number) and touches no
    // memory of ours; the unused arguments are zero as prctl(2) asks.
    unsafe {
        libc::prctl(
            libc::PR_SET_PDEATHSIG,
            signal as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
        )
    }
}

/// Sends `signal` to the process `pid`.
///
/// # Errors
/// `EINVAL` for pid 0 or a pid beyond `pid_t` (which would name a group or no process);
/// the OS error of kill(2) otherwise.
pub fn signal_process(pid: u32, signal: libc::c_int) -> std::io::Result<()> {
    let pid = match libc::pid_t::try_from(pid) {
        Ok(pid) if pid > 0 => pid,
        _ => return Err(std::io::Error::from_raw_os_error(libc::EINVAL)),
    };
    // SAFETY: kill(2) takes two integers and touches no memory of ours.
    if unsafe { libc::kill(pid, signal) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Sends `signal` to the process group `pgid` (a child started with
/// [`ChildTies::own_process_group`] and whatever it started).
///
/// # Errors
/// `EINVAL` for a group id of 0 or 1 or beyond `pid_t` (this process's own group or every
/// process); the OS error of kill(2) otherwise.
pub fn signal_process_group(pgid: u32, signal: libc::c_int) -> std::io::Result<()> {
    let pgid = match libc::pid_t::try_from(pgid) {
        Ok(pgid) if pgid > 1 => pgid,
        _ => return Err(std::io::Error::from_raw_os_error(libc::EINVAL)),
    };
    // SAFETY: kill(2) with a negative pid signals that process group; it takes plain
    // integers and touches no memory.
    if unsafe { libc::kill(-pgid, signal) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pid_zero_and_the_first_groups_are_refused() {
        let einval = Some(libc::EINVAL);
        assert_eq!(
            signal_process(0, 0).err().and_then(|e| e.raw_os_error()),
            einval
        );
        assert_eq!(
            signal_process_group(0, 0)
                .err()
                .and_then(|e| e.raw_os_error()),
            einval
        );
        assert_eq!(
            signal_process_group(1, 0)
                .err()
                .and_then(|e| e.raw_os_error()),
            einval
        );
        assert_eq!(
            signal_process(u32::MAX, 0)
                .err()
                .and_then(|e| e.raw_os_error()),
            einval
        );
    }

    #[test]
    fn signal_zero_finds_this_process() {
        assert!(signal_process(std::process::id(), 0).is_ok());
    }

    #[test]
    fn a_tied_child_leads_its_own_group() {
        let mut cmd = Command::new("sh");
        cmd.args(["-c", "cut -d' ' -f5 /proc/$$/stat"])
            .stdout(std::process::Stdio::piped());
        tie_child(
            &mut cmd,
            ChildTies {
                own_process_group: true,
                refuse_if_orphaned: true,
            },
        );
        let child = cmd.spawn().unwrap();
        let pid = child.id();
        let out = child.wait_with_output().unwrap();
        let pgid: u32 = String::from_utf8_lossy(&out.stdout).trim().parse().unwrap();
        assert_eq!(pgid, pid);
    }
}
