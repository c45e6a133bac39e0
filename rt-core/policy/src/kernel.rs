//! The numeric kernels of [`super::MlpPolicy`]: a blocked matrix–vector product and a fast
//! `tanh`, allocation-free and deterministic.
//!
//! Every output is a dot product summed in one fixed order (eight lane accumulators, then a
//! fixed pairwise combine, then the tail), so the plain and the AVX2 builds of the kernel —
//! chosen once at start-up by CPU detection — give bit-identical results (no FMA is used;
//! Rust never contracts `a * b + c` on its own).

/// Which build of the kernel to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Simd {
    /// Portable code (SSE2 on x86-64).
    Portable,
    /// Compiled with AVX2 enabled; only constructed after runtime detection.
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Simd {
    /// The best kernel this CPU supports.
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self::Avx2;
        }
        Self::Portable
    }
}

const LANES: usize = 8;

#[inline(always)]
fn combine(acc: &[f32; LANES], tail: f32) -> f32 {
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

#[inline(always)]
fn tail_dot(w: &[f32], x: &[f32]) -> f32 {
    let mut s = 0.0f32;
    for (a, b) in w.iter().zip(x) {
        s += a * b;
    }
    s
}

/// One row: `w · x` in the fixed order.
#[inline(always)]
pub(crate) fn dot(w: &[f32], x: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let (wc, wr) = w.as_chunks::<LANES>();
    let (xc, xr) = x.as_chunks::<LANES>();
    let tail = tail_dot(wr, xr);
    for (wa, xa) in wc.iter().zip(xc) {
        for i in 0..LANES {
            acc[i] += wa[i] * xa[i];
        }
    }
    combine(&acc, tail)
}

/// Output columns computed together by the column kernel; column-layout strides are
/// multiples of this.
pub(crate) const COLUMN_BLOCK: usize = 64;

/// `y = W x + b` for a row-major `W` (`[y.len(), x.len()]`): one [`dot`] per output. Used
/// for narrow layers (the action head).
pub(crate) fn rows(w: &[f32], x: &[f32], bias: &[f32], y: &mut [f32]) {
    let n = x.len();
    if n == 0 {
        for (o, b) in y.iter_mut().zip(bias) {
            *o = *b;
        }
        return;
    }
    for ((row, o), b) in w.chunks_exact(n).zip(y.iter_mut()).zip(bias) {
        *o = dot(row, x) + b;
    }
}

/// `y = W x + b` with `W` stored transposed, `wt[j * stride + o] = W[o][j]` (`stride` a
/// multiple of [`COLUMN_BLOCK`], padding columns zero). Each output is accumulated in input
/// order `((x0 w0 + x1 w1) + …) + b`, independent of `OB`, so every build agrees bit for bit.
#[inline(always)]
fn columns_body<const OB: usize>(
    wt: &[f32],
    stride: usize,
    x: &[f32],
    bias: &[f32],
    y: &mut [f32],
) {
    let out = y.len().min(bias.len());
    for blk in 0..out.div_ceil(OB) {
        let o0 = blk * OB;
        let mut acc = [0.0f32; OB];
        for (j, &xj) in x.iter().enumerate() {
            let start = j * stride + o0;
            let Some(Ok(w)) = wt.get(start..start + OB).map(<&[f32; OB]>::try_from) else {
                return;
            };
            for k in 0..OB {
                acc[k] += xj * w[k];
            }
        }
        for ((o, a), b) in y[o0..out].iter_mut().zip(acc).zip(&bias[o0..out]) {
            *o = a + b;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn columns_avx2(wt: &[f32], stride: usize, x: &[f32], bias: &[f32], y: &mut [f32]) {
    columns_body::<COLUMN_BLOCK>(wt, stride, x, bias, y);
}

/// The column kernel (see [`columns_body`]) with the chosen build.
pub(crate) fn columns(
    simd: Simd,
    wt: &[f32],
    stride: usize,
    x: &[f32],
    bias: &[f32],
    y: &mut [f32],
) {
    match simd {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Simd::Avx2` is only constructed by `Simd::detect` after
        // `is_x86_feature_detected!("avx2")` returned true on this CPU.
        Simd::Avx2 => unsafe { columns_avx2(wt, stride, x, bias, y) },
        Simd::Portable => columns_body::<32>(wt, stride, x, bias, y),
    }
}

/// `2^t` for `t` in about [-27, 0]: round to the nearest integer `k` with the 1.5·2²³
/// trick, a degree-7 Taylor polynomial of `2^r` on r ∈ [-0.5, 0.5] (truncation < 6e-9),
/// and `2^k` built from the exponent bits. Branch-free and call-free, so loops vectorise.
#[inline(always)]
fn exp2_neg(t: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2^23
    const C: [f32; 8] = [
        1.0,
        core::f32::consts::LN_2,
        0.240_226_5,      // ln2^2 / 2
        0.055_504_11,     // ln2^3 / 6
        0.009_618_129,    // ln2^4 / 24
        0.001_333_355_8,  // ln2^5 / 120
        0.000_154_035_3,  // ln2^6 / 720
        0.000_015_252_73, // ln2^7 / 5040
    ];
    let k = (t + ROUND) - ROUND;
    let r = t - k;
    let p = C[0]
        + r * (C[1] + r * (C[2] + r * (C[3] + r * (C[4] + r * (C[5] + r * (C[6] + r * C[7]))))));
    let scale = f32::from_bits(((k as i32 + 127) as u32) << 23);
    p * scale
}

/// `tanh` for `f32`, within 4 ulp of the exact value, branch-free so that applying it to
/// a layer vectorises (several times faster than glibc's `tanhf`): an odd Taylor
/// polynomial below |x| = 0.125 (error < 2e-10), `(1 − e) / (1 + e)` with `e = e^{−2|x|}`
/// from `exp2_neg` above, saturating at |x| = 9 (tanh 9 rounds to 1 in `f32`). NaN stays NaN.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    const LOG2_E: f32 = core::f32::consts::LOG2_E;
    let a = x.abs().min(9.0);
    let a2 = a * a;
    let small = a * (1.0 + a2 * (-1.0 / 3.0 + a2 * (2.0 / 15.0 + a2 * (-17.0 / 315.0))));
    let e = exp2_neg(-2.0 * LOG2_E * a);
    let large = (1.0 - e) / (1.0 + e);
    let r = if a < 0.125 { small } else { large };
    let r = r.copysign(x);
    if x.is_nan() { x } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) % 2001) as f32 / 1000.0
                    - 1.0
            })
            .collect()
    }

    #[test]
    fn column_kernel_matches_the_exact_product_and_all_builds_agree() {
        for (out, cols) in [(16, 1), (17, 17), (64, 17), (70, 13), (256, 256)] {
            let w = data(out * cols, 1);
            let x = data(cols, 2);
            let b = data(out, 3);
            let stride = out.div_ceil(COLUMN_BLOCK) * COLUMN_BLOCK;
            let mut wt = vec![0.0f32; cols * stride];
            for o in 0..out {
                for j in 0..cols {
                    wt[j * stride + o] = w[o * cols + j];
                }
            }
            let mut y = vec![0.0; out];
            columns(Simd::Portable, &wt, stride, &x, &b, &mut y);
            let mut y_row = vec![0.0; out];
            rows(&w, &x, &b, &mut y_row);
            for o in 0..out {
                let exact: f64 = (0..cols)
                    .map(|j| f64::from(w[o * cols + j]) * f64::from(x[j]))
                    .sum::<f64>()
                    + f64::from(b[o]);
                assert!(
                    (f64::from(y[o]) - exact).abs() < 1e-4,
                    "{out}x{cols} col {o}"
                );
                assert!(
                    (f64::from(y_row[o]) - exact).abs() < 1e-4,
                    "{out}x{cols} row {o}"
                );
            }
            let mut y_best = vec![0.0; out];
            columns(Simd::detect(), &wt, stride, &x, &b, &mut y_best);
            assert_eq!(y, y_best, "kernel builds differ");
        }
    }

    #[test]
    fn dot_is_close_to_the_exact_sum() {
        let w = data(256, 5);
        let x = data(256, 6);
        let exact: f64 = w
            .iter()
            .zip(&x)
            .map(|(a, b)| f64::from(*a) * f64::from(*b))
            .sum();
        assert!((f64::from(dot(&w, &x)) - exact).abs() < 1e-4);
    }

    #[test]
    fn fast_tanh_is_within_4_ulp() {
        let mut worst_ulp = 0i64;
        let mut x = -12.0f32;
        while x <= 12.0 {
            let exact = f64::from(x).tanh() as f32;
            let got = tanh(x);
            let ulp = (i64::from(got.to_bits() as i32) - i64::from(exact.to_bits() as i32)).abs();
            worst_ulp = worst_ulp.max(ulp);
            x += 0.000_37;
        }
        println!("fast tanh: worst error {worst_ulp} ulp");
        assert!(worst_ulp <= 4, "worst error {worst_ulp} ulp");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(tanh(20.0), 1.0);
        assert_eq!(tanh(-20.0), -1.0);
        assert!(tanh(f32::NAN).is_nan());
        assert_eq!(tanh(1e-30), 1e-30);
    }
}
