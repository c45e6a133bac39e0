//! Robot–scene geometry: collision capsules per link (from the URDF) plus the optional tool
//! capsule, minimum distance and closest points to the obstacle boxes (parry3d) and to the
//! table plane (analytic), a contact test, and the self-collision check.
//!
//! **The table** counts for links 2–5 and the tool: `link_base` and link1 stand on the
//! table (the base capsule reaches into it by construction), so they are never tested
//! against it. Every link and the tool are tested against every box. The goal cube is not
//! an obstacle.
//!
//! **Self-collision** ([`RobotGeometry::self_distance`], analytic segment–segment distances
//! in `f64`) is checked between the capsules of these frame pairs only ([`SELF_PAIRS`]):
//! base–link3, base–link4, base–link5, link1–link3, link1–link4, link1–link5, link2–link4,
//! link2–link5, and the tool against the base, link1, link2 and link3. Left out: adjacent
//! links (they share a joint and overlap by construction); base–link2 (the base's padded
//! cap reaches above the shoulder: −33 mm in every posture); link3–link5 (joined through
//! the 0.12 m wrist link, their padded capsules touch at the wrist in every posture, and
//! joint 4's range keeps them within −42 mm); the tool against link4 and link5, which hold
//! it. A checked pair is a self-collision when its padded capsules come closer than
//! [`SELF_COLLISION_MIN_DISTANCE_M`]; see that constant for the margin and the postures
//! it was measured on.
//!
//! parry3d 0.31 works in `f32` (glam); capsule axes are expressed relative to each box's
//! centre before the query, so the `f32` error stays ~1e-5 m. A capsule whose axis enters a
//! box (deep penetration, where parry's GJK gives no closest points) is reported with
//! `distance_m = −radius` and both points at the axis point nearest the box centre.

use nalgebra::Vector3;
use parry3d::math::{Pose, Vector};
use parry3d::query::{ClosestPoints, closest_points};
use parry3d::shape::{Cuboid, Segment};

use super::kinematics::LinkPoses;
use super::model::{
    COLLISION_MARGIN_M, LinkCapsule, MAX_CAPSULES, N_FRAMES, RobotModel, TOOL_FRAME,
};
use super::scene::{BoxObstacle, Scene};

/// Links below this frame index are not tested against the table.
const FIRST_TABLE_FRAME: usize = 2;

/// Most capsules of a geometry: the model's plus the tool.
const MAX_GEOMETRY_CAPSULES: usize = MAX_CAPSULES + 1;

/// Most capsule pairs of the self-collision check.
const MAX_SELF_PAIRS: usize = MAX_GEOMETRY_CAPSULES * (MAX_GEOMETRY_CAPSULES - 1) / 2;

/// The frame pairs checked for self-collision (`0` = base, `1..=5` = link1..link5,
/// [`TOOL_FRAME`] = the tool); see the module docs for why these and no others.
pub const SELF_PAIRS: [(usize, usize); 12] = [
    (0, 3),
    (0, 4),
    (0, 5),
    (1, 3),
    (1, 4),
    (1, 5),
    (2, 4),
    (2, 5),
    (0, TOOL_FRAME),
    (1, TOOL_FRAME),
    (2, TOOL_FRAME),
    (3, TOOL_FRAME),
];

/// Distance between the padded capsules of a checked pair ([`SELF_PAIRS`]) below which the
/// posture is a self-collision (m): −10 mm. Every link capsule is padded by
/// [`COLLISION_MARGIN_M`] (10 mm) beyond the nominal link radius, so −10 mm between padded
/// capsules leaves 10 mm between the nominal surfaces.
///
/// Measured on the bundled model (capsule distances, smallest checked pair):
/// - the home posture: +88 mm (link1–link3); with a 9 cm, r 4.5 cm tool +28 mm (link3–tool);
/// - the zero posture (the arm folded in its standard rest pose): 0 mm (link1–link3);
/// - IK reaches to every goal of the task's sampling ranges (x 0.20–0.45 m, y ±0.35 m, TCP
///   0.08–0.38 m above the table, 2 cm grid): ≥ +23 mm (link1–link3), tool–base ≥ +29 mm;
///   straight-line episodes to 200 sampled scenes: ≥ +79 mm;
/// - refused: the wrist driven into the base (`[0, 0.5, 0, 1.0, 0]`: base–link4 −125 mm),
///   the forearm folded onto the shoulder (joint 3 at its upper limit, 0.19 rad:
///   link1–link3 −52 mm), reaches right against the base (goals at x = 0.15 m, outside the
///   sampling ranges: down to −12 mm, the tool into the base −27 mm).
///
/// The capsules are conservative (round caps past each joint), so the check refuses
/// joint 3 above about 0.04 rad (the forearm within 10 mm of the shoulder's capsule), short
/// of the controller's limit of 0.19 rad.
pub const SELF_COLLISION_MIN_DISTANCE_M: f64 = -COLLISION_MARGIN_M;

/// The closest checked pair of the robot's own capsules.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelfDistance {
    /// Distance between the padded capsules (m): negative when they overlap.
    pub distance_m: f64,
    /// The two frames (`0` = base … `5` = link5, [`TOOL_FRAME`] = the tool), lower first.
    pub links: [usize; 2],
}

impl SelfDistance {
    /// No checked pair (infinite distance).
    pub const FAR: SelfDistance = SelfDistance {
        distance_m: f64::INFINITY,
        links: [0, 0],
    };

    /// Whether this is a self-collision (closer than [`SELF_COLLISION_MIN_DISTANCE_M`]).
    pub fn colliding(&self) -> bool {
        self.distance_m < SELF_COLLISION_MIN_DISTANCE_M
    }
}

/// Search radius of parry's closest-points query (m): beyond it boxes are "far".
const FAR_M: f32 = 10.0;

/// Every distance of one posture: [`RobotGeometry::all_distances`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distances {
    /// The nearest box; `None` without boxes.
    pub boxes: Option<DistanceReport>,
    /// Links 2–5 and the tool to the table.
    pub table: DistanceReport,
    /// The closest checked pair of the robot's own capsules.
    pub own: SelfDistance,
}

/// Minimum distance between the robot and (part of) the scene, with the closest points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceReport {
    /// Signed distance (m): negative when penetrating.
    pub distance_m: f64,
    /// Closest point on the robot (m, base frame).
    pub robot_point_m: [f64; 3],
    /// Closest point on the obstacle or table (m, base frame).
    pub obstacle_point_m: [f64; 3],
    /// Link frame of the robot point (`0` = base … `5` = link5).
    pub link: usize,
    /// Index of the box in `Scene::obstacles`; `None` = the table.
    pub obstacle: Option<usize>,
    /// Whether the shapes touch (`distance_m <= 0`).
    pub colliding: bool,
}

impl DistanceReport {
    /// A report meaning "nothing nearby" (infinite distance).
    pub const FAR: DistanceReport = DistanceReport {
        distance_m: f64::INFINITY,
        robot_point_m: [0.0; 3],
        obstacle_point_m: [0.0; 3],
        link: 0,
        obstacle: None,
        colliding: false,
    };

    fn closer(self, other: DistanceReport) -> DistanceReport {
        if other.distance_m < self.distance_m {
            other
        } else {
            self
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct WorldCapsule {
    a: Vector3<f64>,
    b: Vector3<f64>,
    r: f64,
    frame: usize,
}

type World = heapless::Vec<WorldCapsule, MAX_GEOMETRY_CAPSULES>;

/// The robot's collision geometry (fixed capacity, cheap to clone): the model's capsules,
/// the tool's (last, if any) and the capsule pairs of the self-collision check.
#[derive(Debug, Clone)]
pub struct RobotGeometry {
    capsules: heapless::Vec<LinkCapsule, MAX_GEOMETRY_CAPSULES>,
    /// Whether the last capsule is the tool.
    has_tool: bool,
    /// Index pairs into `capsules` checked for self-collision.
    self_pairs: heapless::Vec<(u8, u8), MAX_SELF_PAIRS>,
}

/// Closest points of segments `p1 q1` and `p2 q2` (Ericson, *Real-Time Collision
/// Detection* §5.1.9); the distance between them.
fn segment_segment(
    p1: &Vector3<f64>,
    q1: &Vector3<f64>,
    p2: &Vector3<f64>,
    q2: &Vector3<f64>,
) -> f64 {
    const EPS: f64 = 1e-12;
    let d1 = q1 - p1;
    let d2 = q2 - p2;
    let r = p1 - p2;
    let a = d1.norm_squared();
    let e = d2.norm_squared();
    let f = d2.dot(&r);
    let (s, t) = if a <= EPS && e <= EPS {
        (0.0, 0.0)
    } else if a <= EPS {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(&r);
        if e <= EPS {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let mut s = if denom > EPS {
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
    ((p1 + d1 * s) - (p2 + d2 * t)).norm()
}

fn v32(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x as f32, v.y as f32, v.z as f32)
}

fn v64(v: Vector) -> Vector3<f64> {
    Vector3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z))
}

/// Lower bound on the distance between a capsule axis and a box (m), via AABBs.
fn aabb_gap(c: &WorldCapsule, b: &BoxObstacle) -> f64 {
    let center = b.center();
    let half = b.half_extents();
    let mut gap2 = 0.0;
    for k in 0..3 {
        let lo = c.a[k].min(c.b[k]);
        let hi = c.a[k].max(c.b[k]);
        let blo = center[k] - half[k];
        let bhi = center[k] + half[k];
        let g = (blo - hi).max(lo - bhi).max(0.0);
        gap2 += g * g;
    }
    gap2.sqrt()
}

fn capsule_box(c: &WorldCapsule, b: &BoxObstacle, index: usize) -> DistanceReport {
    let center = b.center();
    let seg = Segment::new(v32(&(c.a - center)), v32(&(c.b - center)));
    let cuboid = Cuboid::new(v32(&b.half_extents()));
    let result = closest_points(&Pose::IDENTITY, &seg, &Pose::IDENTITY, &cuboid, FAR_M);
    match result {
        Ok(ClosestPoints::WithinMargin(p_seg, p_box)) => {
            let p_seg = v64(p_seg) + center;
            let p_box = v64(p_box) + center;
            let delta = p_box - p_seg;
            let d_axis = delta.norm();
            let robot = if d_axis > 1e-12 {
                p_seg + delta * (c.r.min(d_axis) / d_axis)
            } else {
                p_seg
            };
            let distance_m = d_axis - c.r;
            DistanceReport {
                distance_m,
                robot_point_m: if distance_m >= 0.0 {
                    robot.into()
                } else {
                    p_box.into()
                },
                obstacle_point_m: p_box.into(),
                link: c.frame,
                obstacle: Some(index),
                colliding: distance_m <= 0.0,
            }
        }
        Ok(ClosestPoints::Disjoint) => DistanceReport::FAR,
        // Intersecting (the axis enters the box) or an unsupported pair.
        _ => {
            let ab = c.b - c.a;
            let len2 = ab.norm_squared();
            let t = if len2 > 0.0 {
                ((center - c.a).dot(&ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let p: [f64; 3] = (c.a + ab * t).into();
            DistanceReport {
                distance_m: -c.r,
                robot_point_m: p,
                obstacle_point_m: p,
                link: c.frame,
                obstacle: Some(index),
                colliding: true,
            }
        }
    }
}

fn capsule_table(c: &WorldCapsule, table_height_m: f64) -> DistanceReport {
    let low = if c.a.z < c.b.z {
        c.a
    } else if c.b.z < c.a.z {
        c.b
    } else {
        (c.a + c.b) * 0.5
    };
    let distance_m = low.z - c.r - table_height_m;
    DistanceReport {
        distance_m,
        robot_point_m: [low.x, low.y, low.z - c.r],
        obstacle_point_m: [low.x, low.y, table_height_m],
        link: c.frame,
        obstacle: None,
        colliding: distance_m <= 0.0,
    }
}

impl RobotGeometry {
    /// The geometry of `model`: its URDF collision shapes and its tool
    /// ([`RobotModel::tool`]), with the self-collision pairs of [`SELF_PAIRS`].
    pub fn new(model: &RobotModel) -> Self {
        let mut capsules = heapless::Vec::new();
        for c in model.capsules() {
            // The capacity is the model's plus one for the tool.
            let _ = capsules.push(*c);
        }
        let has_tool = model.tool().is_some_and(|t| capsules.push(*t).is_ok());
        let tool_index = if has_tool {
            capsules.len() - 1
        } else {
            usize::MAX
        };
        let pair_frame = |i: usize| {
            if i == tool_index {
                TOOL_FRAME
            } else {
                capsules[i].frame
            }
        };
        let mut self_pairs = heapless::Vec::new();
        for i in 0..capsules.len() {
            for j in i + 1..capsules.len() {
                let (fi, fj) = (pair_frame(i), pair_frame(j));
                let key = (fi.min(fj), fi.max(fj));
                if SELF_PAIRS.contains(&key) {
                    // i, j < MAX_GEOMETRY_CAPSULES; the capacity holds every pair.
                    let _ = self_pairs.push((i as u8, j as u8));
                }
            }
        }
        Self {
            capsules,
            has_tool,
            self_pairs,
        }
    }

    /// The capsules, in their link frames (the tool's last, in link5's frame).
    pub fn capsules(&self) -> &[LinkCapsule] {
        &self.capsules
    }

    /// Whether a tool capsule is part of the geometry.
    pub fn has_tool(&self) -> bool {
        self.has_tool
    }

    fn world(&self, poses: &LinkPoses) -> World {
        let mut out = heapless::Vec::new();
        for c in &self.capsules {
            let frame = c.frame.min(N_FRAMES - 1);
            let iso = &poses.links[frame];
            let a = iso * nalgebra::Point3::from(c.a_m);
            let b = iso * nalgebra::Point3::from(c.b_m);
            let _ = out.push(WorldCapsule {
                a: a.coords,
                b: b.coords,
                r: c.radius_m,
                frame: c.frame,
            });
        }
        out
    }

    fn pair_frame(&self, i: usize) -> usize {
        if self.has_tool && i == self.capsules.len() - 1 {
            TOOL_FRAME
        } else {
            self.capsules[i].frame
        }
    }

    fn self_from(&self, world: &[WorldCapsule]) -> SelfDistance {
        let mut best = SelfDistance::FAR;
        for &(i, j) in &self.self_pairs {
            let (i, j) = (usize::from(i), usize::from(j));
            let (ci, cj) = (&world[i], &world[j]);
            let d = segment_segment(&ci.a, &ci.b, &cj.a, &cj.b) - ci.r - cj.r;
            if d < best.distance_m {
                let (fi, fj) = (self.pair_frame(i), self.pair_frame(j));
                best = SelfDistance {
                    distance_m: d,
                    links: [fi.min(fj), fi.max(fj)],
                };
            }
        }
        best
    }

    /// The closest checked pair of the robot's own capsules ([`SELF_PAIRS`]).
    ///
    /// # Performance
    /// One segment–segment distance per checked capsule pair (12 on the bundled model
    /// with a tool); no allocation.
    pub fn self_distance(&self, poses: &LinkPoses) -> SelfDistance {
        self.self_from(&self.world(poses))
    }

    /// The self-collision at `poses`, if any (a checked pair closer than
    /// [`SELF_COLLISION_MIN_DISTANCE_M`]).
    pub fn self_collision(&self, poses: &LinkPoses) -> Option<SelfDistance> {
        Some(self.self_distance(poses)).filter(SelfDistance::colliding)
    }

    /// Minimum distance between the robot and the whole scene (boxes and table).
    pub fn distance(&self, poses: &LinkPoses, scene: &Scene) -> DistanceReport {
        let world = self.world(poses);
        let table = self.table_from(&world, scene);
        let boxes = Self::boxes_from(&world, scene);
        table.closer(boxes)
    }

    /// Minimum distance between the robot and the obstacle boxes; `None` without boxes.
    pub fn distance_to_boxes(&self, poses: &LinkPoses, scene: &Scene) -> Option<DistanceReport> {
        if scene.obstacles.is_empty() {
            return None;
        }
        Some(Self::boxes_from(&self.world(poses), scene))
    }

    /// Minimum distance between links 2–5 (and the tool) and the table plane.
    pub fn distance_to_table(&self, poses: &LinkPoses, scene: &Scene) -> DistanceReport {
        self.table_from(&self.world(poses), scene)
    }

    /// Both the box report (if any boxes) and the table report, in one pass.
    pub fn distances(
        &self,
        poses: &LinkPoses,
        scene: &Scene,
    ) -> (Option<DistanceReport>, DistanceReport) {
        let all = self.all_distances(poses, scene);
        (all.boxes, all.table)
    }

    /// The box report (if any boxes), the table report and the self-distance, in one pass
    /// (one set of world capsules): what a task step needs.
    pub fn all_distances(&self, poses: &LinkPoses, scene: &Scene) -> Distances {
        let world = self.world(poses);
        let boxes = if scene.obstacles.is_empty() {
            None
        } else {
            Some(Self::boxes_from(&world, scene))
        };
        Distances {
            boxes,
            table: self.table_from(&world, scene),
            own: self.self_from(&world),
        }
    }

    /// [`RobotGeometry::all_distances`], and each box's own report in `per_box` (index `i`
    /// for `scene.obstacles[i]`, as many as there are boxes and `per_box` holds): what a
    /// task step with the `nearest_boxes` observation needs.
    ///
    /// # Performance
    /// One set of world capsules; every capsule–box pair within the pruning bound of that
    /// box's best so far; no allocation.
    pub fn all_distances_per_box(
        &self,
        poses: &LinkPoses,
        scene: &Scene,
        per_box: &mut [DistanceReport],
    ) -> Distances {
        let world = self.world(poses);
        let mut boxes: Option<DistanceReport> = None;
        for (i, b) in scene.obstacles.iter().enumerate() {
            let mut best = DistanceReport::FAR;
            for c in &world {
                if aabb_gap(c, b) - c.r >= best.distance_m {
                    continue;
                }
                best = best.closer(capsule_box(c, b, i));
            }
            if let Some(slot) = per_box.get_mut(i) {
                *slot = best;
            }
            boxes = Some(boxes.map_or(best, |all| all.closer(best)));
        }
        Distances {
            boxes,
            table: self.table_from(&world, scene),
            own: self.self_from(&world),
        }
    }

    fn table_from(&self, world: &[WorldCapsule], scene: &Scene) -> DistanceReport {
        world
            .iter()
            .filter(|c| c.frame >= FIRST_TABLE_FRAME)
            .map(|c| capsule_table(c, scene.table_height_m))
            .fold(DistanceReport::FAR, DistanceReport::closer)
    }

    fn boxes_from(world: &[WorldCapsule], scene: &Scene) -> DistanceReport {
        let mut best = DistanceReport::FAR;
        for (i, b) in scene.obstacles.iter().enumerate() {
            for c in world {
                if aabb_gap(c, b) - c.r >= best.distance_m {
                    continue;
                }
                best = best.closer(capsule_box(c, b, i));
            }
        }
        best
    }

    /// Whether any link or the tool is within `margin_m` of a box, or links 2–5 or the tool
    /// within `margin_m` of the table (`margin_m = 0` is the contact test). Self-collision
    /// is separate: [`RobotGeometry::self_collision`].
    pub fn in_contact(&self, poses: &LinkPoses, scene: &Scene, margin_m: f64) -> bool {
        let world = self.world(poses);
        for c in &world {
            if c.frame >= FIRST_TABLE_FRAME
                && capsule_table(c, scene.table_height_m).distance_m <= margin_m
            {
                return true;
            }
            for (i, b) in scene.obstacles.iter().enumerate() {
                if aabb_gap(c, b) - c.r > margin_m {
                    continue;
                }
                if capsule_box(c, b, i).distance_m <= margin_m {
                    return true;
                }
            }
        }
        false
    }
}
