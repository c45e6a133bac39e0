//! The velocity of a tracked object's centre, estimated from its recent measurements.
//!
//! **Fit**: a least-squares line through the newest `velocity_samples` measured centres
//! against their capture times (`CLOCK_MONOTONIC`, never frame counts: a jittering camera or
//! a dropped frame does not bias the estimate), each axis on its own; the velocity is the
//! slope. Measurements older than `velocity_window_ms` before the newest are left out, and a
//! capture time not after the previous one (a repeated frame, a clock step back) starts the
//! history over.
//!
//! **Uncertainty** (1 sigma, the same along each axis): the slope's standard error,
//! `sigma_p / sqrt(sum (t - t_mean)^2)`, where `sigma_p` is the larger of the detector's
//! position noise (`position_noise_m`) and the fit's residual RMS pooled over the three axes.
//! It shrinks as the track ages (more measurements over a longer time: ≈ 0.042 m/s with 3
//! measurements at 60 Hz and 1 mm noise, ≈ 0.009 m/s with 8) and grows when the motion is not
//! a line (an acceleration, a wrong match).
//!
//! **Unknown**: with fewer than [`MIN_SAMPLES`] measurements the velocity is not known:
//! zero, with sigma [`UNKNOWN_VELOCITY_SIGMA_M_S`] (the assumed maximum intruder speed).
//! A sigma above that is no better than unknown and is capped to it. A speed above
//! [`MAX_OBJECT_SPEED_M_S`] is not physical (a wrong match, stamps a microsecond apart): it is
//! published in its direction at (just under) that bound, with the unknown sigma, and counts
//! as moving.
//!
//! **Moving** ([`Velocity::moving`]): the speed exceeds both `still_speed_m_s` and
//! [`MOTION_SIGMAS`] sigmas. Three sigmas, not two: the speed is the length of a 3-D vector,
//! and a still object whose measurements have exactly the assumed noise gives an estimate
//! beyond 2 per-axis sigmas in about a quarter of the frames, beyond 3 in about 3 % (a
//! quieter detector, like the colour one on a still render, far less often).

use std::collections::VecDeque;

use shm_schemas::detection::{MAX_OBJECT_SPEED_M_S, UNKNOWN_VELOCITY_SIGMA_M_S};

/// Fewest measurements a velocity is estimated from (one more than a line needs, so the
/// residuals say whether the measurements lie on one).
pub const MIN_SAMPLES: u32 = 3;

/// Sigmas of its own uncertainty a speed must exceed to count as motion.
pub const MOTION_SIGMAS: f64 = 3.0;

/// The largest speed an estimate is published with: the contract's bound, less a margin so
/// the `f32` it is stored in never rounds above it (m/s).
fn published_speed_max_m_s() -> f64 {
    f64::from(MAX_OBJECT_SPEED_M_S) * (1.0 - 1e-6)
}

/// A velocity estimate of one track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Velocity {
    /// Velocity of the centre in the base frame (m/s).
    pub velocity_m_s: [f64; 3],
    /// 1-sigma uncertainty, along each axis (m/s); in 0 ..= [`UNKNOWN_VELOCITY_SIGMA_M_S`].
    pub sigma_m_s: f64,
    /// The speed is beyond the noise: the object moves (see the module docs).
    pub moving: bool,
}

impl Velocity {
    /// Not known yet: zero, with sigma [`UNKNOWN_VELOCITY_SIGMA_M_S`], not moving.
    pub const UNKNOWN: Self = Self {
        velocity_m_s: [0.0; 3],
        sigma_m_s: UNKNOWN_VELOCITY_SIGMA_M_S as f64,
        moving: false,
    };

    /// Speed, |`velocity_m_s`| (m/s).
    pub fn speed_m_s(&self) -> f64 {
        norm(&self.velocity_m_s)
    }

    /// Whether this is [`Velocity::UNKNOWN`].
    pub fn is_unknown(&self) -> bool {
        *self == Self::UNKNOWN
    }
}

fn norm(v: &[f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// What the estimate depends on (from the tracker's settings).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocitySettings {
    /// The detector's frame-to-frame position noise, 1 sigma per axis (m); > 0.
    pub position_noise_m: f64,
    /// Speeds up to this are still, whatever the sigma (m/s).
    pub still_speed_m_s: f64,
}

/// One measured centre.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    capture_time_ns: u64,
    position_m: [f64; 3],
}

/// The newest measurements of one track (a fixed capacity, reused: nothing is allocated after
/// [`VelocityHistory::new`]).
#[derive(Debug, Clone)]
pub struct VelocityHistory {
    samples: VecDeque<Sample>,
    capacity: usize,
    window_ns: u64,
}

impl VelocityHistory {
    /// An empty history keeping the newest `capacity` measurements (at least
    /// [`MIN_SAMPLES`]) no older than `window_ms` before the newest.
    pub fn new(capacity: usize, window_ms: u32) -> Self {
        let capacity = capacity.max(MIN_SAMPLES as usize);
        Self {
            samples: VecDeque::with_capacity(capacity),
            capacity,
            window_ns: u64::from(window_ms) * 1_000_000,
        }
    }

    /// Forgets every measurement (the velocity is unknown again).
    pub fn clear(&mut self) {
        self.samples.clear();
    }

    /// Measurements held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether no measurement is held.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Adds a measured centre captured at `capture_time_ns`. A capture time not after the
    /// newest held starts the history over with this measurement.
    pub fn push(&mut self, capture_time_ns: u64, position_m: [f64; 3]) {
        if self
            .samples
            .back()
            .is_some_and(|s| s.capture_time_ns >= capture_time_ns)
        {
            self.samples.clear();
        }
        if self.samples.len() >= self.capacity {
            self.samples.pop_front();
        }
        self.samples.push_back(Sample {
            capture_time_ns,
            position_m,
        });
        while self
            .samples
            .front()
            .is_some_and(|s| capture_time_ns - s.capture_time_ns > self.window_ns)
        {
            self.samples.pop_front();
        }
    }

    /// The estimate from the measurements held (see the module docs).
    pub fn estimate(&self, settings: &VelocitySettings) -> Velocity {
        let n = self.samples.len();
        let Some(newest) = self.samples.back() else {
            return Velocity::UNKNOWN;
        };
        if n < MIN_SAMPLES as usize {
            return Velocity::UNKNOWN;
        }
        // Times (s) and positions (m) relative to the newest measurement, for precision.
        let rel = |s: &Sample| {
            let dt_s = -((newest.capture_time_ns - s.capture_time_ns) as f64) * 1e-9;
            let dp_m: [f64; 3] = std::array::from_fn(|a| s.position_m[a] - newest.position_m[a]);
            (dt_s, dp_m)
        };
        let nf = n as f64;
        let mut t_mean = 0.0;
        let mut p_mean = [0.0; 3];
        for s in &self.samples {
            let (t, p) = rel(s);
            t_mean += t / nf;
            for (m, x) in p_mean.iter_mut().zip(p) {
                *m += x / nf;
            }
        }
        let mut s_tt = 0.0;
        let mut s_tp = [0.0; 3];
        for s in &self.samples {
            let (t, p) = rel(s);
            let dt = t - t_mean;
            s_tt += dt * dt;
            for ((acc, x), m) in s_tp.iter_mut().zip(p).zip(p_mean) {
                *acc += dt * (x - m);
            }
        }
        if s_tt.is_nan() || s_tt <= 0.0 {
            return Velocity::UNKNOWN;
        }
        let velocity_m_s = s_tp.map(|acc| acc / s_tt);
        let mut rss = 0.0;
        for s in &self.samples {
            let (t, p) = rel(s);
            for ((x, m), v) in p.iter().zip(p_mean).zip(velocity_m_s) {
                let r = x - m - v * (t - t_mean);
                rss += r * r;
            }
        }
        let residual_m = (rss / (3.0 * (nf - 2.0))).sqrt();
        let noise_m = settings.position_noise_m.max(residual_m);
        let unknown_sigma = Velocity::UNKNOWN.sigma_m_s;
        let sigma_m_s = (noise_m / s_tt.sqrt()).min(unknown_sigma);
        let speed_m_s = norm(&velocity_m_s);
        if !(speed_m_s.is_finite() && sigma_m_s.is_finite()) {
            return Velocity::UNKNOWN;
        }
        let max = published_speed_max_m_s();
        if speed_m_s > max {
            return Velocity {
                velocity_m_s: velocity_m_s.map(|v| v * max / speed_m_s),
                sigma_m_s: unknown_sigma,
                moving: true,
            };
        }
        Velocity {
            velocity_m_s,
            sigma_m_s,
            moving: speed_m_s > settings.still_speed_m_s.max(MOTION_SIGMAS * sigma_m_s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETTINGS: VelocitySettings = VelocitySettings {
        position_noise_m: 0.001,
        still_speed_m_s: 0.02,
    };

    const DT_NS: u64 = 16_666_667;

    #[test]
    fn fewer_than_three_measurements_are_unknown_then_a_line_gives_its_slope() {
        let mut h = VelocityHistory::new(8, 500);
        assert!(h.estimate(&SETTINGS).is_unknown());
        let v = [0.3, -0.4, 0.0];
        let at = |k: u64| -> (u64, [f64; 3]) {
            let t_s = (k * DT_NS) as f64 * 1e-9;
            (k * DT_NS + 1, [0.4 + v[0] * t_s, v[1] * t_s, 0.05])
        };
        for k in 0..2 {
            let (t, p) = at(k);
            h.push(t, p);
            assert!(h.estimate(&SETTINGS).is_unknown(), "{k}");
        }
        let (t, p) = at(2);
        h.push(t, p);
        let e = h.estimate(&SETTINGS);
        assert!((e.speed_m_s() - 0.5).abs() < 1e-6, "{e:?}");
        assert!(e.moving);
        // 1 mm over two intervals: 1 mm / sqrt(2 · (1/60 s)²).
        assert!(
            (e.sigma_m_s - 0.001 / (2.0f64.sqrt() / 60.0)).abs() < 1e-4,
            "{e:?}"
        );
    }

    #[test]
    fn the_capacity_and_the_window_bound_the_history_and_a_step_back_restarts_it() {
        let mut h = VelocityHistory::new(4, 100);
        for k in 0..10 {
            h.push(k * DT_NS + 1, [0.0; 3]);
        }
        assert_eq!(h.len(), 4);
        // 150 ms later: the older ones are beyond the 100 ms window.
        h.push(9 * DT_NS + 150_000_001, [0.0; 3]);
        assert_eq!(h.len(), 1);
        // A repeated stamp (or a clock step back) starts over.
        h.push(9 * DT_NS + 150_000_001, [0.0; 3]);
        assert_eq!(h.len(), 1);
        assert!(h.estimate(&SETTINGS).is_unknown());
    }

    #[test]
    fn an_impossible_speed_is_clamped_uncertain_and_moving() {
        // Three measurements 1 µs apart, 1 cm apart: 10 km/s.
        let mut h = VelocityHistory::new(8, 500);
        for k in 0..3u64 {
            h.push(1_000 + k * 1_000, [0.01 * k as f64, 0.0, 0.0]);
        }
        let e = h.estimate(&SETTINGS);
        assert!(e.moving, "{e:?}");
        assert!(e.speed_m_s() <= f64::from(MAX_OBJECT_SPEED_M_S), "{e:?}");
        assert!(e.speed_m_s() > 0.99 * f64::from(MAX_OBJECT_SPEED_M_S));
        assert!(e.velocity_m_s[0] > 0.0);
        assert_eq!(e.sigma_m_s, f64::from(UNKNOWN_VELOCITY_SIGMA_M_S));
        // The same stamps, nothing moving: still, with the capped sigma.
        let mut h = VelocityHistory::new(8, 500);
        for k in 0..3u64 {
            h.push(1_000 + k * 1_000, [0.4, 0.0, 0.0]);
        }
        let e = h.estimate(&SETTINGS);
        assert_eq!(e.velocity_m_s, [0.0; 3]);
        assert_eq!(e.sigma_m_s, f64::from(UNKNOWN_VELOCITY_SIGMA_M_S));
        assert!(!e.moving);
    }

    /// Measurements that are not on a line (a wrong match, an acceleration) raise the sigma
    /// beyond what the position noise alone gives.
    #[test]
    fn residuals_raise_the_sigma() {
        let mut line = VelocityHistory::new(8, 500);
        let mut zigzag = VelocityHistory::new(8, 500);
        for k in 0..8u64 {
            line.push(k * DT_NS + 1, [0.4, 0.0, 0.05]);
            let off = if k % 2 == 0 { 0.01 } else { -0.01 };
            zigzag.push(k * DT_NS + 1, [0.4 + off, 0.0, 0.05]);
        }
        let (l, z) = (line.estimate(&SETTINGS), zigzag.estimate(&SETTINGS));
        assert!(z.sigma_m_s > 3.0 * l.sigma_m_s, "{l:?} {z:?}");
        assert!(!z.moving, "a zigzag about a point is not motion: {z:?}");
    }
}
