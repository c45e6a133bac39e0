//! An independent check of every command the sweep sees sent ([`crate::run_sweep`]): its own
//! signed distances in `f64` — segment to axis-aligned box, segment to the table plane —
//! between the arm's *nominal* collision capsules and the *ground-truth* boxes, and the
//! motion limits (joint range, joint step per period, TCP speed, finiteness).
//!
//! Independent of what it checks: no parry3d, no `twin::RobotGeometry`, no shield code. The
//! link segments come from the forward kinematics of the twin's [`RobotModel`] and the
//! capsule definitions it read from the URDF; each radius is the URDF's collision radius
//! *minus* the twin's padding ([`twin::COLLISION_MARGIN_M`]), so a negative distance here
//! is real penetration of the arm's surface, not of the safety margin.
//!
//! The segment–box distance minimises the box's signed distance function along the segment:
//! that function is convex (the signed distance of a convex set is convex, and so is its
//! restriction to a line), so a golden-section search finds its minimum to machine
//! precision; the function is 1-Lipschitz, so a far segment is settled by one evaluation at
//! its midpoint.
//!
//! ```
//! use sweep::oracle::{OracleBox, segment_box_distance_m};
//! let unit = OracleBox::new([0.0; 3], [1.0; 3]);
//! // A vertical segment ending 0.25 m above the top face.
//! let d = segment_box_distance_m(&[0.0, 0.0, 0.75], &[0.0, 0.0, 2.0], &unit);
//! assert!((d - 0.25).abs() < 1e-12);
//! ```

use nalgebra::Point3;
use twin::{DOF, Joints, LinkCapsule, RobotModel};

use rt_core::cycle::shield::STEP_TOLERANCE;

/// A point in the base frame, m.
pub type Point = [f64; 3];

/// An axis-aligned box of the ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OracleBox {
    /// Centre, m.
    pub center_m: Point,
    /// Half extents, m.
    pub half_m: Point,
}

impl OracleBox {
    /// A box from its centre and full extents, m.
    pub fn new(center_m: Point, size_m: Point) -> Self {
        Self {
            center_m,
            half_m: [size_m[0] / 2.0, size_m[1] / 2.0, size_m[2] / 2.0],
        }
    }

    /// Signed distance of `p` to the box, m: positive outside, negative inside (minus the
    /// distance to the nearest face).
    pub fn signed_distance_m(&self, p: &Point) -> f64 {
        let mut outside_sq = 0.0;
        let mut inside = f64::NEG_INFINITY;
        for ((x, c), h) in p.iter().zip(&self.center_m).zip(&self.half_m) {
            let q = (x - c).abs() - h;
            if q > 0.0 {
                outside_sq += q * q;
            }
            inside = inside.max(q);
        }
        if outside_sq > 0.0 {
            outside_sq.sqrt()
        } else {
            inside.min(0.0)
        }
    }
}

/// Golden-section iterations: the bracket shrinks to 0.618¹⁰⁰ ≈ 1e-21 of the segment.
const GOLDEN_ITERATIONS: usize = 100;

/// A segment whose midpoint lies this much farther from a box than its half length is
/// reported by that lower bound (exact values matter near contact only), m.
const FAR_M: f64 = 0.10;

fn lerp(a: &Point, b: &Point, t: f64) -> Point {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn norm(v: &Point) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The smallest signed distance between the segment `a`–`b` and the box, m: positive is
/// the gap, negative the depth of the deepest segment point inside the box. Exact to
/// ~1e-15 m within `FAR_M` of the box; beyond it a lower bound that is still beyond it.
pub fn segment_box_distance_m(a: &Point, b: &Point, bx: &OracleBox) -> f64 {
    let half_len = norm(&[b[0] - a[0], b[1] - a[1], b[2] - a[2]]) / 2.0;
    let mid = lerp(a, b, 0.5);
    let lower = bx.signed_distance_m(&mid) - half_len;
    if lower > FAR_M {
        return lower;
    }
    let f = |t: f64| bx.signed_distance_m(&lerp(a, b, t));
    let inv_phi = (5f64.sqrt() - 1.0) / 2.0;
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    let mut x1 = hi - inv_phi * (hi - lo);
    let mut x2 = lo + inv_phi * (hi - lo);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..GOLDEN_ITERATIONS {
        if f1 <= f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - inv_phi * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + inv_phi * (hi - lo);
            f2 = f(x2);
        }
    }
    f1.min(f2).min(f(0.0)).min(f(1.0))
}

/// Signed distance of the segment `a`–`b` to the half-space below the horizontal plane
/// `z = plane_z_m`, m (negative: the lower end lies below the plane by that much).
pub fn segment_plane_distance_m(a: &Point, b: &Point, plane_z_m: f64) -> f64 {
    a[2].min(b[2]) - plane_z_m
}

/// One nominal capsule of the arm, in its link frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalCapsule {
    /// Link frame (`0` = base … `5` = link5); the tool is carried by frame 5.
    pub frame: usize,
    /// Whether it is the tool's capsule.
    pub tool: bool,
    /// Axis ends in the link frame, m.
    pub a_m: Point,
    /// Second axis end, m.
    pub b_m: Point,
    /// Nominal radius (the URDF's minus the padding), m.
    pub radius_m: f64,
}

impl NominalCapsule {
    /// Whether the table counts for it (links 2–5 and the tool: the base and link 1
    /// stand on the table).
    pub fn meets_table(&self) -> bool {
        self.tool || self.frame >= 2
    }
}

/// Why the oracle could not be built.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum OracleBuildError {
    /// A collision radius is not larger than the padding taken off it.
    #[error("capsule of frame {frame}: radius {radius_m} m is not above the padding {padding_m} m")]
    RadiusBelowPadding {
        /// The link frame.
        frame: usize,
        /// The URDF radius, m.
        radius_m: f64,
        /// The padding, m.
        padding_m: f64,
    },
}

/// The closest approach of one pose to a set of boxes and to the table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseClearance {
    /// Smallest nominal-capsule distance to any box, m (`INFINITY` without boxes).
    pub box_m: f64,
    /// Index (in the iteration given) of that box, if any.
    pub box_index: Option<usize>,
    /// Smallest nominal-capsule distance to the table (links 2–5, tool), m.
    pub table_m: f64,
}

/// The arm's nominal capsules over the twin's forward kinematics.
#[derive(Debug, Clone)]
pub struct DistanceOracle {
    model: RobotModel,
    capsules: Vec<NominalCapsule>,
}

impl DistanceOracle {
    /// From `model`'s collision capsules and its tool (if any), each radius reduced by
    /// `padding_m` (the twin's padding: [`twin::COLLISION_MARGIN_M`]).
    ///
    /// # Errors
    /// [`OracleBuildError::RadiusBelowPadding`].
    pub fn new(model: &RobotModel, padding_m: f64) -> Result<Self, OracleBuildError> {
        let mut capsules = Vec::new();
        let with_tool = model.tool().map(|t| (t, true));
        for (c, tool) in model.capsules().iter().map(|c| (c, false)).chain(with_tool) {
            let c: &LinkCapsule = c;
            let radius_m = c.radius_m - padding_m;
            if radius_m <= 0.0 {
                return Err(OracleBuildError::RadiusBelowPadding {
                    frame: c.frame,
                    radius_m: c.radius_m,
                    padding_m,
                });
            }
            capsules.push(NominalCapsule {
                frame: c.frame,
                tool,
                a_m: c.a_m,
                b_m: c.b_m,
                radius_m,
            });
        }
        Ok(Self {
            model: model.clone(),
            capsules,
        })
    }

    /// The nominal capsules, in their link frames.
    pub fn capsules(&self) -> &[NominalCapsule] {
        &self.capsules
    }

    /// Every nominal capsule at `q_rad`, in the base frame: `(capsule, a, b)`.
    pub fn world_capsules(&self, q_rad: &Joints) -> Vec<(NominalCapsule, Point, Point)> {
        let poses = self.model.fk(q_rad);
        self.capsules
            .iter()
            .map(|c| {
                let iso = &poses.links[c.frame];
                let a = iso * Point3::from(c.a_m);
                let b = iso * Point3::from(c.b_m);
                (*c, [a.x, a.y, a.z], [b.x, b.y, b.z])
            })
            .collect()
    }

    /// The TCP at `q_rad`, m.
    pub fn tcp_m(&self, q_rad: &Joints) -> Point {
        let t = self.model.tcp_m(q_rad);
        [t.x, t.y, t.z]
    }

    /// The link frame origins at `q_rad` (base, link1 … link5), m.
    pub fn frame_origins_m(&self, q_rad: &Joints) -> [Point; DOF + 1] {
        let poses = self.model.fk(q_rad);
        let mut out = [[0.0; 3]; DOF + 1];
        for (o, l) in out.iter_mut().zip(&poses.links) {
            let v = l.translation.vector;
            *o = [v.x, v.y, v.z];
        }
        out
    }

    /// The closest approach of the arm at `q_rad` to `boxes` and to the table at
    /// `table_z_m`.
    pub fn clearance<'a>(
        &self,
        q_rad: &Joints,
        boxes: impl IntoIterator<Item = &'a OracleBox>,
        table_z_m: f64,
    ) -> PoseClearance {
        let world = self.world_capsules(q_rad);
        let mut out = PoseClearance {
            box_m: f64::INFINITY,
            box_index: None,
            table_m: f64::INFINITY,
        };
        for (c, a, b) in &world {
            if c.meets_table() {
                out.table_m = out
                    .table_m
                    .min(segment_plane_distance_m(a, b, table_z_m) - c.radius_m);
            }
        }
        for (i, bx) in boxes.into_iter().enumerate() {
            for (c, a, b) in &world {
                let d = segment_box_distance_m(a, b, bx) - c.radius_m;
                if d < out.box_m {
                    out.box_m = d;
                    out.box_index = Some(i);
                }
            }
        }
        out
    }
}

/// The motion limits every sent command must keep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandLimits {
    /// Lower joint limits, rad.
    pub joint_min_rad: Joints,
    /// Upper joint limits, rad.
    pub joint_max_rad: Joints,
    /// Joint velocity limits, rad/s.
    pub max_velocity_rad_s: Joints,
    /// TCP speed limit, m/s.
    pub max_tcp_speed_m_s: f64,
    /// The cycle period, s.
    pub period_s: f64,
}

/// What the motion checks found for one command.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MotionFindings {
    /// A position is NaN or infinite.
    pub non_finite: bool,
    /// The first joint outside its limits.
    pub joint_limit: Option<usize>,
    /// The first joint stepping farther than one period at its velocity limit plus the
    /// shield's [`STEP_TOLERANCE`], and its step, rad.
    pub joint_step: Option<(usize, f64)>,
    /// The TCP speed over the limit, m/s.
    pub tcp_speed_m_s: Option<f64>,
}

impl MotionFindings {
    /// Whether anything was found.
    pub fn any(&self) -> bool {
        self.non_finite
            || self.joint_limit.is_some()
            || self.joint_step.is_some()
            || self.tcp_speed_m_s.is_some()
    }
}

impl CommandLimits {
    /// Checks command `q_rad` sent one period after `prev_q_rad` (the previous command
    /// sent, or the arm's start pose), with TCPs `tcp_prev_m` and `tcp_m`. The step is
    /// measured against one period whatever time passed between the two (as the shield
    /// does: after a gap the controller still sees one jump).
    pub fn check(
        &self,
        prev_q_rad: &Joints,
        q_rad: &Joints,
        tcp_prev_m: &Point,
        tcp_m: &Point,
    ) -> MotionFindings {
        let mut f = MotionFindings::default();
        if q_rad.iter().chain(tcp_m).any(|v| !v.is_finite()) {
            f.non_finite = true;
            return f;
        }
        f.joint_limit = (0..DOF)
            .find(|&j| q_rad[j] < self.joint_min_rad[j] || q_rad[j] > self.joint_max_rad[j]);
        f.joint_step = (0..DOF)
            .map(|j| (j, (q_rad[j] - prev_q_rad[j]).abs()))
            .find(|&(j, step)| {
                step > self.max_velocity_rad_s[j] * self.period_s * (1.0 + STEP_TOLERANCE)
            });
        let d = norm(&[
            tcp_m[0] - tcp_prev_m[0],
            tcp_m[1] - tcp_prev_m[1],
            tcp_m[2] - tcp_prev_m[2],
        ]);
        let speed = d / self.period_s;
        // The shield measures the same FK with no tolerance; 1e-9 absorbs rounding only.
        if speed > self.max_tcp_speed_m_s * (1.0 + 1e-9) {
            f.tcp_speed_m_s = Some(speed);
        }
        f
    }
}

/// The padding the oracle takes off the URDF radii: the twin's.
pub const TWIN_PADDING_M: f64 = twin::COLLISION_MARGIN_M;

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn point_and_segment_distances_match_hand_values() {
        let b = OracleBox::new([1.0, 2.0, 3.0], [0.2, 0.4, 0.6]);
        // Outside across a corner: (0.1, 0.1, 0) beyond the +x +y edge.
        let d = b.signed_distance_m(&[1.2, 2.3, 3.0]);
        assert!((d - 0.02f64.sqrt()).abs() < 1e-12);
        // Inside: 0.05 from the +x face, nearer than any other.
        assert!((b.signed_distance_m(&[1.05, 2.0, 3.0]) + 0.05).abs() < 1e-12);
        // A segment crossing the box through its centre: deepest point 0.1 inside.
        let d = segment_box_distance_m(&[0.0, 2.0, 3.0], &[2.0, 2.0, 3.0], &b);
        assert!((d + 0.1).abs() < 1e-12, "{d}");
        // A diagonal segment passing the +x +z edge (x = 1.1, z = 3.3) 0.05 away: its
        // closest point is the edge shifted out along (1, 0, 1)/√2 by 0.05.
        let off = 0.05 / 2f64.sqrt();
        let p = [1.1 + off, 2.0, 3.3 + off];
        let dir = [1.0, 0.0, -1.0];
        let a = [p[0] - dir[0], p[1], p[2] - dir[2]];
        let e = [p[0] + dir[0], p[1], p[2] + dir[2]];
        let d = segment_box_distance_m(&a, &e, &b);
        assert!((d - 0.05).abs() < 1e-12, "{d}");
        assert!(
            (segment_plane_distance_m(&[0.0, 0.0, 0.3], &[1.0, 0.0, 0.1], 0.05) - 0.05).abs()
                < 1e-12
        );
    }
}
