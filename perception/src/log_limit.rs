//! Rate limiting of repeated warnings: a camera with a wrong clock or a crowded table would
//! otherwise log one line per frame. The caller passes the time, so the limiter is tested
//! without waiting.
//!
//! ```
//! use std::time::{Duration, Instant};
//! use perception::log_limit::LogLimiter;
//! let mut l = LogLimiter::new(Duration::from_secs(5));
//! let t0 = Instant::now();
//! assert_eq!(l.allow(t0), Some(0)); // the first occurrence is logged
//! assert_eq!(l.allow(t0 + Duration::from_secs(1)), None); // then held back…
//! assert_eq!(l.allow(t0 + Duration::from_secs(6)), Some(1)); // …and reported as suppressed
//! ```

use std::time::{Duration, Instant};

/// At most one log line per `interval`; counts the occurrences held back in between.
#[derive(Debug, Clone)]
pub struct LogLimiter {
    interval: Duration,
    last: Option<Instant>,
    suppressed: u64,
}

impl LogLimiter {
    /// A limiter allowing one line per `interval`.
    pub fn new(interval: Duration) -> Self {
        Self {
            interval,
            last: None,
            suppressed: 0,
        }
    }

    /// One occurrence at `now`: `Some(n)` when it should be logged (`n` occurrences were
    /// held back since the last line), `None` when it is held back.
    pub fn allow(&mut self, now: Instant) -> Option<u64> {
        match self.last {
            Some(t) if now.saturating_duration_since(t) < self.interval => {
                self.suppressed += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.suppressed))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_per_interval_with_the_held_back_count() {
        let mut l = LogLimiter::new(Duration::from_secs(2));
        let t0 = Instant::now();
        assert_eq!(l.allow(t0), Some(0));
        for i in 1..=5 {
            assert_eq!(l.allow(t0 + Duration::from_millis(300 * i)), None);
        }
        assert_eq!(l.allow(t0 + Duration::from_secs(2)), Some(5));
        assert_eq!(l.allow(t0 + Duration::from_secs(3)), None);
        assert_eq!(l.allow(t0 + Duration::from_secs(10)), Some(1));
    }
}
