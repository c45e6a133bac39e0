//! The contract's clock: `CLOCK_MONOTONIC` in nanoseconds, the clock every Foresight process
//! on the machine shares. Every timestamp in a message (a detection's `capture_time_ns`, a
//! robot state's stamp) is read with [`monotonic_now_ns`], so stamps from two processes can
//! be compared. [`realtime_now_ns`] is only for converting outside stamps (ROS 2 headers)
//! to it.
//!
//! One of the two modules of this crate that make OS calls (the other is
//! [`crate::process_ties`]); the runtime's clock (`rt_core::rt::clock`) and perception's
//! frames both read time here.

/// `CLOCK_MONOTONIC` now (ns). 0 only if the clock cannot be read (never on Linux); a
/// publisher refuses such a stamp.
pub fn monotonic_now_ns() -> u64 {
    clock_now_ns(libc::CLOCK_MONOTONIC)
}

/// `CLOCK_REALTIME` now (ns since the Unix epoch): the clock ROS 2 header stamps use. Only
/// for converting such stamps to `CLOCK_MONOTONIC`.
pub fn realtime_now_ns() -> u64 {
    clock_now_ns(libc::CLOCK_REALTIME)
}

fn clock_now_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC and CLOCK_REALTIME are
    // always supported on Linux.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    if rc != 0 {
        return 0;
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_time_is_read_and_never_goes_back() {
        let a = monotonic_now_ns();
        let b = monotonic_now_ns();
        assert!(a > 0);
        assert!(b >= a);
    }

    #[test]
    fn realtime_is_after_2020() {
        assert!(realtime_now_ns() > 1_577_836_800_000_000_000);
    }
}
