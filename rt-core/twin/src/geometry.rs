//! Robot–scene geometry: collision capsules per link (from the URDF), minimum distance and
//! closest points to the obstacle boxes (parry3d) and to the table plane (analytic), and a
//! contact test.
//!
//! **The table** counts for links 2–5 only: `link_base` and link1 stand on the table (the
//! base capsule reaches into it by construction), so they are never tested against it.
//! Every link is tested against every box. The goal cube is not an obstacle, and links are
//! not tested against each other (no self-collision check: the task's workspace and joint
//! limits keep the arm clear of itself).
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
use super::model::{LinkCapsule, MAX_CAPSULES, RobotModel};
use super::scene::{BoxObstacle, Scene};

/// Links below this frame index are not tested against the table.
const FIRST_TABLE_FRAME: usize = 2;

/// Search radius of parry's closest-points query (m): beyond it boxes are "far".
const FAR_M: f32 = 10.0;

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

/// The robot's collision geometry (fixed capacity, cheap to clone).
#[derive(Debug, Clone)]
pub struct RobotGeometry {
    capsules: heapless::Vec<LinkCapsule, MAX_CAPSULES>,
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
    /// The geometry of `model` (its URDF collision shapes).
    pub fn new(model: &RobotModel) -> Self {
        let mut capsules = heapless::Vec::new();
        for c in model.capsules() {
            // Capacity is the same as the model's.
            let _ = capsules.push(*c);
        }
        Self { capsules }
    }

    /// The capsules, in their link frames.
    pub fn capsules(&self) -> &[LinkCapsule] {
        &self.capsules
    }

    fn world(&self, poses: &LinkPoses) -> heapless::Vec<WorldCapsule, MAX_CAPSULES> {
        let mut out = heapless::Vec::new();
        for c in &self.capsules {
            let frame = c.frame.min(poses.links.len() - 1);
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

    /// Minimum distance between links 2–5 and the table plane.
    pub fn distance_to_table(&self, poses: &LinkPoses, scene: &Scene) -> DistanceReport {
        self.table_from(&self.world(poses), scene)
    }

    /// Both the box report (if any boxes) and the table report, in one pass.
    pub fn distances(
        &self,
        poses: &LinkPoses,
        scene: &Scene,
    ) -> (Option<DistanceReport>, DistanceReport) {
        let world = self.world(poses);
        let boxes = if scene.obstacles.is_empty() {
            None
        } else {
            Some(Self::boxes_from(&world, scene))
        };
        (boxes, self.table_from(&world, scene))
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

    /// Whether any link is within `margin_m` of a box, or links 2–5 within `margin_m` of
    /// the table (`margin_m = 0` is the contact test).
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
