//! Running mean and variance (Welford / Chan's parallel update), used to normalise
//! observations and to scale rewards by the spread of the discounted return, as SB3's
//! `VecNormalize` does.

/// Running per-component mean and (population) variance.
#[derive(Debug, Clone, PartialEq)]
pub struct RunningMeanStd {
    /// Per-component mean.
    pub mean: Vec<f64>,
    /// Per-component variance.
    pub var: Vec<f64>,
    /// Number of samples seen (starts at a tiny epsilon as in SB3, so the first batch dominates).
    pub count: f64,
}

impl RunningMeanStd {
    /// Zero mean, unit variance, `count = 1e-4`.
    pub fn new(dim: usize) -> Self {
        Self {
            mean: vec![0.0; dim],
            var: vec![1.0; dim],
            count: 1e-4,
        }
    }

    /// Components per sample.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Merges a batch of samples (`data.len()` a multiple of `dim`) into the statistics.
    pub fn update(&mut self, data: &[f32]) {
        let d = self.dim();
        if d == 0 || data.len() < d {
            return;
        }
        let n = data.len() / d;
        let nf = n as f64;
        let mut bmean = vec![0.0f64; d];
        for row in data.chunks_exact(d) {
            for (m, x) in bmean.iter_mut().zip(row) {
                *m += f64::from(*x);
            }
        }
        bmean.iter_mut().for_each(|m| *m /= nf);
        let mut bvar = vec![0.0f64; d];
        for row in data.chunks_exact(d) {
            for ((v, x), m) in bvar.iter_mut().zip(row).zip(&bmean) {
                let e = f64::from(*x) - m;
                *v += e * e;
            }
        }
        bvar.iter_mut().for_each(|v| *v /= nf);
        let tot = self.count + nf;
        for i in 0..d {
            let delta = bmean[i] - self.mean[i];
            let m2 =
                self.var[i] * self.count + bvar[i] * nf + delta * delta * self.count * nf / tot;
            self.mean[i] += delta * nf / tot;
            self.var[i] = m2 / tot;
        }
        self.count = tot;
    }

    /// `1 / sqrt(var + eps)` per component, as f32.
    pub fn inv_std(&self, eps: f64) -> Vec<f32> {
        self.var
            .iter()
            .map(|v| (1.0 / (v + eps).sqrt()) as f32)
            .collect()
    }

    /// The mean as f32.
    pub fn mean_f32(&self) -> Vec<f32> {
        self.mean.iter().map(|m| *m as f32).collect()
    }
}

/// Frozen normalisation parameters applied to observations: `clip((x - mean) * inv_std)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsNormalizer {
    /// Mean per component.
    pub mean: Vec<f32>,
    /// `1 / sqrt(var + eps)` per component.
    pub inv_std: Vec<f32>,
    /// Symmetric clip applied after normalising.
    pub clip: f32,
}

impl ObsNormalizer {
    /// Epsilon added to the variance.
    pub const EPS: f64 = 1e-8;

    /// Freezes `stats` with clip `clip`.
    pub fn from_stats(stats: &RunningMeanStd, clip: f32) -> Self {
        Self {
            mean: stats.mean_f32(),
            inv_std: stats.inv_std(Self::EPS),
            clip,
        }
    }

    /// Normalises `raw` into `out` (same length).
    pub fn apply(&self, raw: &[f32], out: &mut [f32]) {
        for (i, (o, x)) in out.iter_mut().zip(raw).enumerate() {
            *o = ((x - self.mean[i]) * self.inv_std[i]).clamp(-self.clip, self.clip);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batched_welford_matches_two_pass_statistics() {
        let data: Vec<f32> = (0..300)
            .map(|i| ((i * 37) % 101) as f32 * 0.1 - 3.0)
            .collect();
        let mut rms = RunningMeanStd::new(3);
        rms.count = 0.0;
        // Feed in uneven batches.
        rms.update(&data[..30]);
        rms.update(&data[30..33]);
        rms.update(&data[33..]);
        for c in 0..3 {
            let col: Vec<f64> = data
                .iter()
                .skip(c)
                .step_by(3)
                .map(|x| f64::from(*x))
                .collect();
            let n = col.len() as f64;
            let mean = col.iter().sum::<f64>() / n;
            let var = col.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
            assert!((rms.mean[c] - mean).abs() < 1e-9, "mean {c}");
            assert!((rms.var[c] - var).abs() < 1e-9, "var {c}");
        }
        assert_eq!(rms.count, 100.0);
    }

    #[test]
    fn normaliser_centres_scales_and_clips() {
        let mut rms = RunningMeanStd::new(2);
        rms.update(&[1.0, 10.0, 3.0, 30.0]);
        let n = ObsNormalizer::from_stats(&rms, 5.0);
        let mut out = [0.0; 2];
        n.apply(&[3.0, 30.0], &mut out);
        assert!(
            (out[0] - 1.0).abs() < 1e-3 && (out[1] - 1.0).abs() < 1e-3,
            "{out:?}"
        );
        n.apply(&[1000.0, -1000.0], &mut out);
        assert_eq!(out, [5.0, -5.0]);
    }
}
