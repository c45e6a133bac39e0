//! The referee's distance code, in `f64`, exact (no iteration, no tolerance): segment–box
//! (axis-aligned), segment–segment and segment–plane distances. A capsule's clearance is the
//! distance of its axis segment minus its radius.
//!
//! Segment–box: the squared distance from `p(t) = a + t·(b − a)` to a box is a piecewise
//! quadratic in `t` whose pieces change where `p(t)` crosses one of the six face planes; each
//! piece is minimised in closed form. Segment–segment: the closest points of two segments
//! (Ericson, *Real-Time Collision Detection*, 5.1.9), with degenerate segments handled.

/// A point or vector (m).
pub type V3 = [f64; 3];

fn sub(a: &V3, b: &V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: &V3, b: &V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn along(a: &V3, d: &V3, t: f64) -> V3 {
    [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]]
}

/// Euclidean distance between two points (m).
pub fn point_distance_m(a: &V3, b: &V3) -> f64 {
    let d = sub(a, b);
    dot(&d, &d).sqrt()
}

/// An axis-aligned box by its corners (m), `lo ≤ hi` on every axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner (m).
    pub lo_m: V3,
    /// Upper corner (m).
    pub hi_m: V3,
}

impl Aabb {
    /// The box with centre `center_m` and full extents `size_m`.
    pub fn from_center_size(center_m: &V3, size_m: &V3) -> Self {
        let mut lo_m = [0.0; 3];
        let mut hi_m = [0.0; 3];
        for k in 0..3 {
            lo_m[k] = center_m[k] - 0.5 * size_m[k];
            hi_m[k] = center_m[k] + 0.5 * size_m[k];
        }
        Self { lo_m, hi_m }
    }

    /// Lower bound of the distance from any point of segment `a`–`b` to the box (m): the gap
    /// between the segment's bounding box and this box. Cheap; used to skip far boxes.
    pub fn gap_to_segment_bounds_m(&self, a: &V3, b: &V3) -> f64 {
        let mut s = 0.0;
        for k in 0..3 {
            let (lo, hi) = (a[k].min(b[k]), a[k].max(b[k]));
            let g = (self.lo_m[k] - hi).max(lo - self.hi_m[k]).max(0.0);
            s += g * g;
        }
        s.sqrt()
    }
}

/// Distance (m) between segment `a`–`b` and box `bx`; 0 when they touch or overlap.
pub fn segment_box_m(a: &V3, b: &V3, bx: &Aabb) -> f64 {
    let d = sub(b, a);
    // Breakpoints: 0, 1 and where the segment crosses a face plane, sorted.
    let mut ts = [0.0f64; 8];
    let mut n = 0;
    ts[n] = 0.0;
    n += 1;
    for k in 0..3 {
        if d[k] != 0.0 {
            for plane in [bx.lo_m[k], bx.hi_m[k]] {
                let t = (plane - a[k]) / d[k];
                if t > 0.0 && t < 1.0 {
                    ts[n] = t;
                    n += 1;
                }
            }
        }
    }
    ts[n] = 1.0;
    n += 1;
    let ts = &mut ts[..n];
    ts.sort_by(f64::total_cmp);
    let mut best = f64::INFINITY;
    for w in ts.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        let tm = 0.5 * (t0 + t1);
        // f(t) = qa·t² + qb·t + qc on [t0, t1]: each axis outside the slab adds (p_k(t) − face)².
        let (mut qa, mut qb, mut qc) = (0.0, 0.0, 0.0);
        for k in 0..3 {
            let v = a[k] + tm * d[k];
            let face = if v < bx.lo_m[k] {
                bx.lo_m[k]
            } else if v > bx.hi_m[k] {
                bx.hi_m[k]
            } else {
                continue;
            };
            let e = a[k] - face;
            qa += d[k] * d[k];
            qb += 2.0 * d[k] * e;
            qc += e * e;
        }
        let t = if qa > 0.0 {
            (-qb / (2.0 * qa)).clamp(t0, t1)
        } else {
            t0
        };
        best = best.min(qa * t * t + qb * t + qc);
    }
    best.max(0.0).sqrt()
}

/// Distance (m) between segments `p0`–`p1` and `q0`–`q1`.
pub fn segment_segment_m(p0: &V3, p1: &V3, q0: &V3, q1: &V3) -> f64 {
    const EPS: f64 = 1e-18;
    let d1 = sub(p1, p0);
    let d2 = sub(q1, q0);
    let r = sub(p0, q0);
    let a = dot(&d1, &d1);
    let e = dot(&d2, &d2);
    let f = dot(&d2, &r);
    let (s, t) = if a <= EPS && e <= EPS {
        (0.0, 0.0)
    } else if a <= EPS {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = dot(&d1, &r);
        if e <= EPS {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = dot(&d1, &d2);
            let denom = a * e - b * b;
            let mut s = if denom > EPS * a * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    point_distance_m(&along(p0, &d1, s), &along(q0, &d2, t))
}

/// Signed height (m) of segment `a`–`b` above the horizontal plane `z = height_m`: the lower
/// end's height, negative below the plane.
pub fn segment_plane_m(a: &V3, b: &V3, height_m: f64) -> f64 {
    a[2].min(b[2]) - height_m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: the distance at 20 001 points along the segment.
    fn sampled_segment_box(a: &V3, b: &V3, bx: &Aabb) -> f64 {
        let d = sub(b, a);
        (0..=20_000)
            .map(|i| {
                let p = along(a, &d, f64::from(i) / 20_000.0);
                let mut s = 0.0;
                for (k, v) in p.iter().enumerate() {
                    let g = (bx.lo_m[k] - v).max(v - bx.hi_m[k]).max(0.0);
                    s += g * g;
                }
                s.sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn segment_box_cases_by_hand() {
        let bx = Aabb::from_center_size(&[0.0, 0.0, 0.0], &[0.2, 0.2, 0.2]);
        // Parallel to a face, 0.05 above it.
        let d = segment_box_m(&[-1.0, 0.0, 0.15], &[1.0, 0.0, 0.15], &bx);
        assert!((d - 0.05).abs() < 1e-12, "{d}");
        // Passing by an edge: the edge x = 0.1, z = 0.1; the segment at x = z = 0.2.
        let d = segment_box_m(&[0.2, -1.0, 0.2], &[0.2, 1.0, 0.2], &bx);
        assert!((d - 0.1 * 2f64.sqrt()).abs() < 1e-12, "{d}");
        // Through the box.
        assert_eq!(segment_box_m(&[-1.0, 0.0, 0.0], &[1.0, 0.0, 0.0], &bx), 0.0);
        // A point (degenerate segment) off a corner.
        let d = segment_box_m(&[0.2, 0.2, 0.2], &[0.2, 0.2, 0.2], &bx);
        assert!((d - 0.1 * 3f64.sqrt()).abs() < 1e-12, "{d}");
        // Diagonal segment passing a corner: closest approach to (0.1, 0.1, 0.1).
        let d = segment_box_m(&[0.5, -0.2, 0.1], &[-0.2, 0.5, 0.1], &bx);
        assert!((d - 0.1 / 2f64.sqrt()).abs() < 1e-12, "{d}");
    }

    #[test]
    fn segment_box_agrees_with_brute_force() {
        let bx = Aabb::from_center_size(&[0.3, -0.1, 0.2], &[0.06, 0.2, 0.35]);
        let mut seed = 0x1234_5678_9abc_def1u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for _ in 0..200 {
            let a = [0.3 + rnd(), -0.1 + rnd(), 0.2 + rnd()];
            let b = [0.3 + rnd(), -0.1 + rnd(), 0.2 + rnd()];
            let exact = segment_box_m(&a, &b, &bx);
            let sampled = sampled_segment_box(&a, &b, &bx);
            // The sampled minimum is above the exact one by at most half a sample spacing.
            assert!(exact <= sampled + 1e-12, "{a:?} {b:?}: {exact} > {sampled}");
            assert!(sampled - exact < 1e-4, "{a:?} {b:?}: {exact} vs {sampled}");
            assert!(bx.gap_to_segment_bounds_m(&a, &b) <= exact + 1e-12);
        }
    }

    #[test]
    fn segment_segment_cases_by_hand() {
        // Skew perpendicular lines 0.3 apart.
        let d = segment_segment_m(
            &[-1.0, 0.0, 0.0],
            &[1.0, 0.0, 0.0],
            &[0.0, -1.0, 0.3],
            &[0.0, 1.0, 0.3],
        );
        assert!((d - 0.3).abs() < 1e-12, "{d}");
        // Parallel, overlapping, 0.1 apart.
        let d = segment_segment_m(
            &[0.0, 0.0, 0.0],
            &[1.0, 0.0, 0.0],
            &[0.5, 0.1, 0.0],
            &[1.5, 0.1, 0.0],
        );
        assert!((d - 0.1).abs() < 1e-12, "{d}");
        // Collinear, end to end with a 0.2 gap.
        let d = segment_segment_m(
            &[0.0, 0.0, 0.0],
            &[1.0, 0.0, 0.0],
            &[1.2, 0.0, 0.0],
            &[2.0, 0.0, 0.0],
        );
        assert!((d - 0.2).abs() < 1e-12, "{d}");
        // Endpoint to interior: (1, 0, 0) to the segment x = 1.3, y ∈ [−1, 1].
        let d = segment_segment_m(
            &[0.0, 0.0, 0.0],
            &[1.0, 0.0, 0.0],
            &[1.3, -1.0, 0.0],
            &[1.3, 1.0, 0.0],
        );
        assert!((d - 0.3).abs() < 1e-12, "{d}");
        // A point against a segment.
        let d = segment_segment_m(
            &[0.0, 0.5, 0.0],
            &[0.0, 0.5, 0.0],
            &[-1.0, 0.0, 0.0],
            &[1.0, 0.0, 0.0],
        );
        assert!((d - 0.5).abs() < 1e-12, "{d}");
        assert!((segment_plane_m(&[0.0, 0.0, 0.3], &[1.0, 0.0, 0.1], 0.05) - 0.05).abs() < 1e-12);
    }
}
