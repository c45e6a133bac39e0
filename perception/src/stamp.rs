//! Camera stamps → `CLOCK_MONOTONIC`, the clock every `DetectionFrame` carries.
//!
//! A ROS 2 camera stamps its images (`header.stamp`) on the ROS clock, which is the system
//! clock (`CLOCK_REALTIME`, ns since the Unix epoch) unless a simulator drives `/clock`. The
//! stamp is converted with the offset between the two clocks measured when the message was
//! received ([`ClockPair::now`]): `monotonic = stamp − (realtime − monotonic)`. The offset
//! changes only when the system clock is stepped (NTP, an operator), so an image received
//! just after a step may look too old or in the future, and is refused: never guessed.
//!
//! An image is refused, with a message naming `header.stamp`, when its stamp is zero (a
//! driver that does not stamp), malformed (negative seconds, `nanosec` ≥ 10⁹), more than
//! [`StampLimits::max_ahead_s`] in the future (a camera clock not synchronised with this
//! machine's), or more than [`StampLimits::max_age_s`] old. A stamp ahead by less than the
//! tolerance is clamped to the receipt time, so no consumer ever sees a future stamp.
//!
//! ```
//! use perception::stamp::{ClockPair, StampLimits, StampError, ros_stamp_to_monotonic_ns};
//! let clocks = ClockPair { realtime_ns: 1_700_000_000_000_000_000, monotonic_ns: 5_000_000_000 };
//! let limits = StampLimits::default();
//! // Captured 100 ms before it was received.
//! let t = ros_stamp_to_monotonic_ns(1_699_999_999, 900_000_000, clocks, &limits).unwrap();
//! assert_eq!(t, 4_900_000_000);
//! assert!(matches!(ros_stamp_to_monotonic_ns(0, 0, clocks, &limits), Err(StampError::Zero)));
//! ```

use serde::{Deserialize, Serialize};

use shm_schemas::clock::{monotonic_now_ns, realtime_now_ns};

const NS_PER_S: i128 = 1_000_000_000;

/// `CLOCK_REALTIME` and `CLOCK_MONOTONIC` read together (ns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockPair {
    /// `CLOCK_REALTIME` (ns since the Unix epoch).
    pub realtime_ns: u64,
    /// `CLOCK_MONOTONIC` (ns).
    pub monotonic_ns: u64,
}

impl ClockPair {
    /// Both clocks now: the real-time clock read between two monotonic reads, paired with
    /// their midpoint.
    pub fn now() -> Self {
        let m0 = monotonic_now_ns();
        let realtime_ns = realtime_now_ns();
        let m1 = monotonic_now_ns();
        Self {
            realtime_ns,
            monotonic_ns: m0 + m1.saturating_sub(m0) / 2,
        }
    }
}

/// How old or how far in the future a camera stamp may be (the `[stamp]` table of the ROS 2
/// topics file; missing fields take their defaults).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StampLimits {
    /// Oldest accepted stamp at receipt (s). Allowed (0, [`StampLimits::MAX_AGE_S`]];
    /// default 0.5 s, rt-core's default `max_detection_age_s`: an older image would reach
    /// rt-core already stale.
    pub max_age_s: f64,
    /// How far in the future a stamp may be (s), for clock jitter between the camera driver
    /// and this process; such a stamp is clamped to the receipt time. Allowed
    /// 0 ..= [`StampLimits::MAX_AHEAD_S`]; default 0.02 s.
    pub max_ahead_s: f64,
}

impl Default for StampLimits {
    fn default() -> Self {
        Self {
            max_age_s: 0.5,
            max_ahead_s: 0.02,
        }
    }
}

/// Why [`StampLimits`] were refused; each message names the field.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum StampLimitsError {
    /// `max_age_s` is not in (0, `MAX_AGE_S`].
    #[error("stamp.max_age_s = {0} must be within (0, {max}] s", max = StampLimits::MAX_AGE_S)]
    MaxAge(f64),
    /// `max_ahead_s` is not in [0, `MAX_AHEAD_S`].
    #[error("stamp.max_ahead_s = {0} must be within 0 ..= {max} s", max = StampLimits::MAX_AHEAD_S)]
    MaxAhead(f64),
}

impl StampLimits {
    /// Largest `max_age_s`: rt-core's largest `max_detection_age_s`.
    pub const MAX_AGE_S: f64 = 1.0;
    /// Largest `max_ahead_s`.
    pub const MAX_AHEAD_S: f64 = 0.2;

    /// Checks the bounds.
    ///
    /// # Errors
    /// [`StampLimitsError`] naming the field as spelled in the ROS 2 topics file
    /// (`stamp.max_age_s`, `stamp.max_ahead_s`).
    pub fn validate(&self) -> Result<(), StampLimitsError> {
        if !(self.max_age_s > 0.0 && self.max_age_s <= Self::MAX_AGE_S) {
            return Err(StampLimitsError::MaxAge(self.max_age_s));
        }
        if !(0.0..=Self::MAX_AHEAD_S).contains(&self.max_ahead_s) {
            return Err(StampLimitsError::MaxAhead(self.max_ahead_s));
        }
        Ok(())
    }
}

/// Why a camera image's stamp was refused; each message names `header.stamp`.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum StampError {
    /// Both fields are 0: the driver does not stamp its images.
    #[error("header.stamp is zero (sec = 0, nanosec = 0): the camera gives no capture time")]
    Zero,
    /// `sec` is negative.
    #[error("header.stamp.sec = {0} is negative")]
    NegativeSeconds(i32),
    /// `nanosec` is not below 10⁹.
    #[error("header.stamp.nanosec = {0} is not below 1000000000")]
    Nanoseconds(u32),
    /// The stamp is further in the future than the tolerance.
    #[error(
        "header.stamp is {ahead_ms:.1} ms in the future (tolerance {max_ahead_ms:.1} ms): is the camera's clock synchronised with this machine's?"
    )]
    Future {
        /// How far ahead of the receipt time (ms).
        ahead_ms: f64,
        /// The tolerance (ms).
        max_ahead_ms: f64,
    },
    /// The stamp is older than the bound (or before this machine booted).
    #[error("header.stamp is {age_ms:.1} ms old at receipt (max {max_age_ms:.1} ms)")]
    TooOld {
        /// Age at receipt (ms).
        age_ms: f64,
        /// The bound (ms).
        max_age_ms: f64,
    },
}

/// Converts a ROS `header.stamp` (`sec`, `nanosec` on `CLOCK_REALTIME`) to
/// `CLOCK_MONOTONIC` ns with the clocks read at receipt, and checks it (see the module doc).
/// The result is never 0 and never later than `clocks.monotonic_ns`.
///
/// # Errors
/// [`StampError`].
pub fn ros_stamp_to_monotonic_ns(
    sec: i32,
    nanosec: u32,
    clocks: ClockPair,
    limits: &StampLimits,
) -> Result<u64, StampError> {
    if sec == 0 && nanosec == 0 {
        return Err(StampError::Zero);
    }
    if sec < 0 {
        return Err(StampError::NegativeSeconds(sec));
    }
    if i128::from(nanosec) >= NS_PER_S {
        return Err(StampError::Nanoseconds(nanosec));
    }
    let stamp_realtime = i128::from(sec) * NS_PER_S + i128::from(nanosec);
    let offset = i128::from(clocks.realtime_ns) - i128::from(clocks.monotonic_ns);
    let stamp = stamp_realtime - offset;
    let now = i128::from(clocks.monotonic_ns);
    let age = now - stamp;
    let ms = |ns: i128| ns as f64 / 1e6;
    let max_ahead = (limits.max_ahead_s * 1e9) as i128;
    let max_age = (limits.max_age_s * 1e9) as i128;
    if -age > max_ahead {
        return Err(StampError::Future {
            ahead_ms: ms(-age),
            max_ahead_ms: ms(max_ahead),
        });
    }
    if age > max_age || stamp <= 0 {
        return Err(StampError::TooOld {
            age_ms: ms(age),
            max_age_ms: ms(max_age),
        });
    }
    // Ahead within the tolerance: the receipt time (a consumer refuses future stamps).
    Ok(stamp.min(now) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CLOCKS: ClockPair = ClockPair {
        realtime_ns: 1_700_000_000_250_000_000,
        monotonic_ns: 3_600_000_000_000,
    };

    /// `header.stamp` of an image captured `before_ns` before the receipt.
    fn stamp_before(before_ns: i64) -> (i32, u32) {
        let t = CLOCKS.realtime_ns as i64 - before_ns;
        ((t / 1_000_000_000) as i32, (t % 1_000_000_000) as u32)
    }

    #[test]
    fn a_ros_stamp_becomes_the_monotonic_time_of_capture() {
        let l = StampLimits::default();
        let (s, n) = stamp_before(80_000_000);
        assert_eq!(
            ros_stamp_to_monotonic_ns(s, n, CLOCKS, &l).unwrap(),
            CLOCKS.monotonic_ns - 80_000_000
        );
        // Slightly ahead (clock jitter): clamped to the receipt time.
        let (s, n) = stamp_before(-5_000_000);
        assert_eq!(
            ros_stamp_to_monotonic_ns(s, n, CLOCKS, &l).unwrap(),
            CLOCKS.monotonic_ns
        );
    }

    #[test]
    fn zero_future_old_and_malformed_stamps_are_refused_naming_the_field() {
        let l = StampLimits::default();
        let check = |s: i32, n: u32| ros_stamp_to_monotonic_ns(s, n, CLOCKS, &l).unwrap_err();
        assert_eq!(check(0, 0), StampError::Zero);
        let (s, n) = stamp_before(-500_000_000);
        assert!(
            matches!(check(s, n), StampError::Future { ahead_ms, .. } if (ahead_ms - 500.0).abs() < 1e-6)
        );
        let (s, n) = stamp_before(700_000_000);
        assert!(
            matches!(check(s, n), StampError::TooOld { age_ms, .. } if (age_ms - 700.0).abs() < 1e-6)
        );
        // A camera counting from 1 s (not the system clock): before this machine booted.
        assert!(matches!(check(1, 0), StampError::TooOld { .. }));
        assert_eq!(check(-3, 0), StampError::NegativeSeconds(-3));
        assert_eq!(
            check(5, 1_000_000_000),
            StampError::Nanoseconds(1_000_000_000)
        );
        for e in [
            check(0, 0),
            check(1, 0),
            check(-3, 0),
            check(5, 1_000_000_000),
            check(s, n),
        ] {
            assert!(e.to_string().contains("header.stamp"), "{e}");
        }
    }

    #[test]
    fn limits_are_bounded() {
        StampLimits::default().validate().unwrap();
        for age in [0.0, -1.0, 1.5, f64::NAN] {
            let e = StampLimits {
                max_age_s: age,
                ..Default::default()
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("stamp.max_age_s"), "{e}");
        }
        for ahead in [-0.1, 0.5, f64::NAN] {
            let e = StampLimits {
                max_ahead_s: ahead,
                ..Default::default()
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("stamp.max_ahead_s"), "{e}");
        }
    }

    #[test]
    fn the_clock_pair_is_consistent() {
        let a = ClockPair::now();
        let b = ClockPair::now();
        assert!(a.monotonic_ns > 0 && a.realtime_ns > 0);
        assert!(b.monotonic_ns >= a.monotonic_ns);
    }
}
