//! An independent check of every command the sweep sees sent ([`crate::run_sweep`]): its own
//! signed distances in `f64` — segment to axis-aligned box, segment to the table plane —
//! between the arm's *nominal* collision capsules and the *ground-truth* boxes, and the
//! motion limits (joint range, joint step per period, TCP speed, the controller's TCP step
//! per target [`CONTROLLER_TCP_STEP_M`], finiteness).
//!
//! Independent of what it checks: no parry3d, no `twin::RobotGeometry`, no shield code, and
//! not the twin's kinematics either (issue 30 item 7). The arm's pose comes from UFactory's
//! published Denavit–Hartenberg table and its body from one unpadded capsule per link, the
//! shapes of the referee (`xarm_referee`, the crate `xarm-sim` judges with, written apart
//! from the twin and checked against the published dimension drawing), so a model error
//! shared by the twin's URDF and everything built on it shows here as penetration. A negative distance is real
//! penetration of the arm's surface, not of the twin's safety padding. The twin's model
//! serves only to mount the task's tool (given in the URDF's flange frame) on the datasheet
//! flange, and to place the sweep's injected boxes (never a check).
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

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion};
use twin::{DOF, Joints, LinkCapsule, RobotModel};
use xarm_referee::kinematics::{Frame, forward};
use xarm_referee::{ArmCapsules, LINKS, N_LINKS};

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

/// One nominal capsule of the arm: a link body of the datasheet arm, or the tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalCapsule {
    /// Link body (`0` = base … `5` = link5, as `xarm_referee::LINKS`); the tool is
    /// carried by the flange (5).
    pub frame: usize,
    /// Whether it is the tool's capsule.
    pub tool: bool,
    /// Axis ends: in the flange frame for the tool (as the task gives it); unused for link
    /// bodies, whose ends come from the datasheet kinematics at each pose.
    pub a_m: Point,
    /// Second axis end, m.
    pub b_m: Point,
    /// Nominal radius (the arm's surface, no padding), m.
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

/// The arm's nominal capsules over the datasheet's forward kinematics (see the module docs).
#[derive(Debug, Clone)]
pub struct DistanceOracle {
    /// The twin's model: where injected boxes go ([`DistanceOracle::frame_origins_m`]);
    /// never used by a check.
    model: RobotModel,
    /// The tool, in the flange frame of the URDF, and that frame in the datasheet's flange
    /// frame (a constant: both are rigidly the flange).
    tool: Option<(NominalCapsule, Isometry3<f64>)>,
}

/// A datasheet frame as an isometry.
fn isometry(f: &Frame) -> Isometry3<f64> {
    let r = Matrix3::from_fn(|i, j| f.rot[i][j]);
    Isometry3::from_parts(
        Translation3::new(f.origin_m[0], f.origin_m[1], f.origin_m[2]),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    )
}

impl DistanceOracle {
    /// The datasheet arm, with `model`'s tool (if any) mounted on its flange; the tool's
    /// radius is reduced by `padding_m` (the twin's padding: [`twin::COLLISION_MARGIN_M`]).
    ///
    /// # Errors
    /// [`OracleBuildError::RadiusBelowPadding`].
    pub fn new(model: &RobotModel, padding_m: f64) -> Result<Self, OracleBuildError> {
        let tool = match model.tool() {
            None => None,
            Some(c) => {
                let c: &LinkCapsule = c;
                let radius_m = c.radius_m - padding_m;
                if radius_m <= 0.0 {
                    return Err(OracleBuildError::RadiusBelowPadding {
                        frame: c.frame,
                        radius_m: c.radius_m,
                        padding_m,
                    });
                }
                // The URDF's flange frame in the datasheet's, at the zero pose.
                let q0 = [0.0; DOF];
                let urdf_flange = model.fk(&q0).links[c.frame];
                let dh_flange = isometry(forward(&q0).flange());
                let mount = dh_flange.inverse() * urdf_flange;
                Some((
                    NominalCapsule {
                        frame: c.frame,
                        tool: true,
                        a_m: c.a_m,
                        b_m: c.b_m,
                        radius_m,
                    },
                    mount,
                ))
            }
        };
        Ok(Self {
            model: model.clone(),
            tool,
        })
    }

    /// Every nominal capsule at `q_rad`, in the base frame: `(capsule, a, b)` — the six
    /// link bodies of the datasheet arm, then the tool.
    pub fn world_capsules(&self, q_rad: &Joints) -> Vec<(NominalCapsule, Point, Point)> {
        let frames = forward(q_rad);
        let bodies = ArmCapsules::from_frames(&frames);
        let mut out = Vec::with_capacity(N_LINKS + 1);
        for (i, (seg, link)) in bodies.segments_m.iter().zip(LINKS).enumerate() {
            let capsule = NominalCapsule {
                frame: i,
                tool: false,
                a_m: seg[0],
                b_m: seg[1],
                radius_m: link.radius_m,
            };
            out.push((capsule, seg[0], seg[1]));
        }
        if let Some((c, mount)) = &self.tool {
            let iso = isometry(frames.flange()) * mount;
            let a = iso * Point3::from(c.a_m);
            let b = iso * Point3::from(c.b_m);
            out.push((*c, [a.x, a.y, a.z], [b.x, b.y, b.z]));
        }
        out
    }

    /// The TCP (the datasheet's flange centre) at `q_rad`, m.
    pub fn tcp_m(&self, q_rad: &Joints) -> Point {
        forward(q_rad).flange().origin_m
    }

    /// The twin's link frame origins at `q_rad` (base, link1 … link5), m: where the sweep
    /// injects boxes (never a check).
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

/// The xArm controller's largest TCP step from one servo target to the next, m (5 mm,
/// whatever the servo period): stated here, apart from the shield's own bound
/// (`twin::approval::shield::MAX_TCP_STEP_M`, asserted equal in this module's tests).
pub const CONTROLLER_TCP_STEP_M: f64 = 0.005;

/// What the oracle allows over [`CONTROLLER_TCP_STEP_M`], m: the shield measures the step on
/// the twin's URDF, the oracle on the datasheet arm; the two TCPs agree within 10 µm
/// anywhere, and their difference varies far less over one step (< 0.1 µm for a 5 mm
/// step), so 1 µm absorbs the models' difference and no real excess.
pub const TCP_STEP_TOLERANCE_M: f64 = 1e-6;

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
    /// The TCP step over the controller's [`CONTROLLER_TCP_STEP_M`] (+
    /// [`TCP_STEP_TOLERANCE_M`]), m.
    pub tcp_step_m: Option<f64>,
}

impl MotionFindings {
    /// Whether anything was found.
    pub fn any(&self) -> bool {
        self.non_finite
            || self.joint_limit.is_some()
            || self.joint_step.is_some()
            || self.tcp_speed_m_s.is_some()
            || self.tcp_step_m.is_some()
    }
}

impl CommandLimits {
    /// Checks command `q_rad` sent one period after `prev_q_rad` (the previous command
    /// sent, or the arm's start pose), with TCPs `tcp_prev_m` and `tcp_m`. The step is
    /// measured against one period whatever time passed between the two (as the shield
    /// does: after a gap the controller still sees one jump), and the TCP's step against
    /// the controller's [`CONTROLLER_TCP_STEP_M`] (a bound of its own: at 100 Hz the speed
    /// limit of 0.8 m/s would allow 8 mm).
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
        if d > CONTROLLER_TCP_STEP_M + TCP_STEP_TOLERANCE_M {
            f.tcp_step_m = Some(d);
        }
        f
    }
}

/// The padding the oracle takes off the URDF radii: the twin's.
pub const TWIN_PADDING_M: f64 = twin::COLLISION_MARGIN_M;

#[cfg(test)]
mod tests {
    use super::*;

    fn urdf() -> RobotModel {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/xarm5.urdf");
        RobotModel::load(&p).unwrap()
    }

    /// Poses spread over the joint ranges (a fixed pseudo-random walk, no RNG crate).
    fn poses() -> impl Iterator<Item = Joints> {
        (0..200u32).map(|i| {
            let f = |k: u32| ((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0 - 0.5;
            [2.0 * f(1), 1.2 * f(2), 1.5 * f(3), 2.0 * f(4), 3.0 * f(5)]
        })
    }

    /// The oracle's arm is the datasheet's, not the twin's, yet the two must describe the
    /// same arm: the TCP within 0.01 mm everywhere (the DH table's 2 µm digit slip; see
    /// `xarm_referee::kinematics`). A URDF that drifts from the datasheet fails here,
    /// and the sweep would count its poses against the real arm's shape.
    #[test]
    fn the_datasheet_arm_and_the_twins_urdf_put_the_tcp_in_the_same_place() {
        let model = urdf();
        let oracle = DistanceOracle::new(&model, 0.010).unwrap();
        for q in poses() {
            let dh = oracle.tcp_m(&q);
            let tw = model.tcp_m(&q);
            let gap =
                ((dh[0] - tw.x).powi(2) + (dh[1] - tw.y).powi(2) + (dh[2] - tw.z).powi(2)).sqrt();
            assert!(gap < 1e-5, "{q:?}: datasheet {dh:?}, URDF {tw:?} ({gap} m)");
        }
    }

    /// A tool given in the URDF's flange frame rides on the datasheet flange exactly where
    /// the twin puts it, radius less the padding.
    #[test]
    fn the_tool_rides_on_the_datasheet_flange_where_the_twin_puts_it() {
        let tool = LinkCapsule {
            frame: DOF,
            a_m: [0.0, 0.0, 0.0],
            b_m: [0.0, 0.0, 0.10],
            radius_m: 0.04,
        };
        let model = urdf().with_tool(Some(tool));
        let oracle = DistanceOracle::new(&model, 0.010).unwrap();
        for q in poses() {
            let caps = oracle.world_capsules(&q);
            let (c, a, b) = caps.iter().find(|(c, _, _)| c.tool).copied().unwrap();
            assert!((c.radius_m - 0.03).abs() < 1e-12);
            let flange = model.fk(&q).links[DOF];
            let (ta, tb) = (
                flange * Point3::from(tool.a_m),
                flange * Point3::from(tool.b_m),
            );
            for (got, want) in [(a, ta), (b, tb)] {
                let gap = ((got[0] - want.x).powi(2)
                    + (got[1] - want.y).powi(2)
                    + (got[2] - want.z).powi(2))
                .sqrt();
                assert!(gap < 1e-5, "{q:?}: {got:?} vs {want:?}");
            }
        }
        // Six datasheet link bodies and the tool.
        assert_eq!(oracle.world_capsules(&[0.0; DOF]).len(), N_LINKS + 1);
    }

    /// Issue 41 item 5: the controller takes at most 5 mm of TCP step per target, and the
    /// oracle did not check it (an 8 mm step at 100 Hz, 0.8 m/s, passed every check). Now
    /// such a step is found, on its own, at a speed the limit allows.
    #[test]
    fn a_tcp_step_over_the_controllers_5_mm_is_found_even_within_the_speed_limit() {
        assert_eq!(
            CONTROLLER_TCP_STEP_M,
            twin::approval::shield::MAX_TCP_STEP_M,
            "the oracle and the shield name the same controller bound"
        );
        let limits = CommandLimits {
            joint_min_rad: [-6.0; DOF],
            joint_max_rad: [6.0; DOF],
            max_velocity_rad_s: [3.0; DOF],
            max_tcp_speed_m_s: 0.8,
            period_s: 0.01,
        };
        let q = [0.0; DOF];
        let from = [0.30, 0.0, 0.20];
        // 8 mm in one 10 ms period: 0.8 m/s, within the speed limit.
        let eight_mm = limits.check(&q, &q, &from, &[0.308, 0.0, 0.20]);
        assert_eq!(eight_mm.tcp_speed_m_s, None, "{eight_mm:?}");
        let step = eight_mm.tcp_step_m.expect("an 8 mm TCP step is found");
        assert!((step - 0.008).abs() < 1e-12, "{step}");
        assert!(eight_mm.any());
        // 5 mm, the controller's bound, passes.
        let five_mm = limits.check(&q, &q, &from, &[0.305, 0.0, 0.20]);
        assert_eq!(five_mm, MotionFindings::default(), "{five_mm:?}");
    }

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
