//! A fixed-bucket latency histogram (1 µs buckets up to 20 ms, then an overflow bucket that
//! keeps the exact maximum): recording is allocation-free and O(1), so the loop driver can
//! record every wake-up and every cycle.

/// Number of 1 µs buckets.
pub const BUCKETS: usize = 20_000;

/// Percentile summary in microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Samples recorded.
    pub count: u64,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// 99.9th percentile, µs.
    pub p999_us: f64,
    /// Maximum, µs.
    pub max_us: f64,
}

/// A histogram of durations.
#[derive(Clone)]
pub struct Histogram {
    buckets: Box<[u64; BUCKETS]>,
    overflow: u64,
    count: u64,
    max_ns: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// An empty histogram (allocates its buckets once).
    pub fn new() -> Self {
        let buckets: Box<[u64; BUCKETS]> = vec![0u64; BUCKETS]
            .into_boxed_slice()
            .try_into()
            .unwrap_or_else(|_| Box::new([0; BUCKETS]));
        Self {
            buckets,
            overflow: 0,
            count: 0,
            max_ns: 0,
        }
    }

    /// Records one duration.
    #[inline]
    pub fn record_ns(&mut self, d_ns: u64) {
        let us = (d_ns / 1000) as usize;
        match self.buckets.get_mut(us) {
            Some(b) => *b += 1,
            None => self.overflow += 1,
        }
        self.count += 1;
        self.max_ns = self.max_ns.max(d_ns);
    }

    /// Samples recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The `q`-quantile (0..=1) in µs, bucket upper edge (the maximum for the overflow).
    pub fn quantile_us(&self, q: f64) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let rank = ((q * self.count as f64).ceil() as u64).clamp(1, self.count);
        let mut seen = 0;
        for (i, b) in self.buckets.iter().enumerate() {
            seen += b;
            if seen >= rank {
                return ((i + 1) as f64).min(self.max_ns as f64 / 1000.0);
            }
        }
        self.max_ns as f64 / 1000.0
    }

    /// p50, p99, p99.9 and max.
    pub fn summary(&self) -> Summary {
        Summary {
            count: self.count,
            p50_us: self.quantile_us(0.5),
            p99_us: self.quantile_us(0.99),
            p999_us: self.quantile_us(0.999),
            max_us: self.max_ns as f64 / 1000.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_follow_the_recorded_distribution() {
        let mut h = Histogram::new();
        for i in 0..1000u64 {
            h.record_ns(i * 1000 + 500);
        }
        h.record_ns(50_000_000);
        let s = h.summary();
        assert_eq!(s.count, 1001);
        assert!((s.p50_us - 501.0).abs() <= 1.0, "{s:?}");
        assert!((s.p99_us - 991.0).abs() <= 1.0, "{s:?}");
        assert_eq!(s.max_us, 50_000.0);
    }
}
