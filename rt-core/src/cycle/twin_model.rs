//! The shield's model on the real twin: [`TwinModel`] gives the shield the twin's forward
//! kinematics, its capsule clearance to the live scene (boxes and table; in blind mode,
//! `--no-lookahead`, the table alone: [`TwinModel::with_boxes_ignored`]) and its
//! self-collision check. The tool is the model's ([`twin::RobotModel::set_tool`]): give
//! `TwinModel::new` the model with the task's tool installed.

use twin::{Joints, LinkPoses, RobotGeometry, RobotModel, Scene};

use crate::cycle::shield::{ShieldModel, WATCHED_POINTS};

/// The link frames whose origins the shield watches: the elbow (after joint 3) and the
/// wrist (after joint 4).
const ELBOW_FRAME: usize = 3;
const WRIST_FRAME: usize = 4;

/// The shield model on the twin: FK and capsule distances to the scene's boxes and to the
/// table (links 2–5, as in the task's contact rule). Allocation-free.
#[derive(Debug, Clone)]
pub struct TwinModel {
    model: RobotModel,
    geometry: RobotGeometry,
    /// The last two FK results and their joints: a command's FK serves its speed,
    /// workspace and clearance checks, and the next cycle's speed check (as the previous
    /// command), even with the look-ahead pose checked in between.
    cache: [(Option<Joints>, LinkPoses); 2],
    /// The slot of the newest entry.
    newest: usize,
    /// Blind mode: the clearance is the table's alone.
    boxes_ignored: bool,
}

impl TwinModel {
    /// Over a loaded robot model.
    pub fn new(model: RobotModel) -> Self {
        let geometry = RobotGeometry::new(&model);
        Self {
            model,
            geometry,
            cache: [(None, LinkPoses::default()); 2],
            newest: 0,
            boxes_ignored: false,
        }
    }

    /// With `ignored`, the clearance leaves the obstacle boxes out and measures the table
    /// alone: blind mode (`rt-core run --no-lookahead`), the demonstration of plans driving
    /// into boxes the lookahead would have refused. The table, and every limit the shield
    /// checks besides clearance, still hold.
    #[must_use]
    pub fn with_boxes_ignored(mut self, ignored: bool) -> Self {
        self.boxes_ignored = ignored;
        self
    }

    /// Whether the obstacle boxes are left out of the clearance (blind mode).
    pub fn boxes_ignored(&self) -> bool {
        self.boxes_ignored
    }

    /// The link poses at `q_rad` (from the cache when computed lately).
    fn fk(&mut self, q_rad: &Joints) -> &LinkPoses {
        let other = 1 - self.newest;
        if self.cache[self.newest].0.as_ref() == Some(q_rad) {
            return &self.cache[self.newest].1;
        }
        if self.cache[other].0.as_ref() != Some(q_rad) {
            self.model.fk_into(q_rad, &mut self.cache[other].1);
            self.cache[other].0 = Some(*q_rad);
        }
        self.newest = other;
        &self.cache[other].1
    }
}

impl ShieldModel for TwinModel {
    type Scene = Scene;

    fn watched_points_m(&mut self, q_rad: &Joints) -> [[f64; 3]; WATCHED_POINTS] {
        let poses = self.fk(q_rad);
        let at = |v: nalgebra::Vector3<f64>| [v.x, v.y, v.z];
        [
            at(poses.links[ELBOW_FRAME].translation.vector),
            at(poses.links[WRIST_FRAME].translation.vector),
            at(poses.tcp_m()),
        ]
    }

    fn min_distance_m(&mut self, q_rad: &Joints, scene: &Scene) -> f64 {
        let poses = *self.fk(q_rad);
        // The boxes and the table (links 2–5): the TCP workspace box alone does not keep
        // the wrist off the table. Blind mode drops the boxes, never the table.
        if self.boxes_ignored {
            self.geometry.distance_to_table(&poses, scene).distance_m
        } else {
            self.geometry.distance(&poses, scene).distance_m
        }
    }

    fn intruder_distance_m(&mut self, q_rad: &Joints, scene: &Scene, moving_mask: u32) -> f64 {
        // The moving boxes alone: the table does not move towards the arm, a still box is
        // verified against. Blind mode has none.
        if self.boxes_ignored || moving_mask == 0 {
            return f64::INFINITY;
        }
        // The moving ones in a copy on the stack (a `Scene` is `Copy`, fixed capacity).
        let mut moving = *scene;
        moving.obstacles.clear();
        for (i, b) in scene.obstacles.iter().enumerate() {
            if i < 32 && moving_mask & (1 << i) != 0 {
                // Cannot fail: at most as many as the scene held.
                let _ = moving.obstacles.push(*b);
            }
        }
        let poses = *self.fk(q_rad);
        self.geometry
            .distance_to_boxes(&poses, &moving)
            .map_or(f64::INFINITY, |r| r.distance_m)
    }

    fn self_collision(&mut self, q_rad: &Joints) -> Option<([u8; 2], f64)> {
        let poses = *self.fk(q_rad);
        self.geometry
            .self_collision(&poses)
            .map(|s| (s.links.map(|l| l as u8), s.distance_m))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::cycle::shield::{Shield, ShieldLimits, ShieldViolation};
    use twin::{BoxObstacle, Goal, TaskConfig, ToolConfig};

    fn assets() -> std::path::PathBuf {
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    fn model() -> RobotModel {
        RobotModel::load(&assets().join("xarm5.urdf")).unwrap()
    }

    fn start() -> Joints {
        TaskConfig::load(&assets().join("task.toml"))
            .unwrap()
            .start
            .joints_rad
    }

    fn shield(model: RobotModel) -> Shield<TwinModel> {
        let cfg = RuntimeConfig::xarm5_default();
        Shield::new(
            TwinModel::new(model),
            ShieldLimits::from_config(&cfg.limits, &cfg.shield),
        )
    }

    fn empty() -> Scene {
        Scene::empty(
            0.0,
            Goal {
                center_m: [0.40, 0.25, 0.025],
                size_m: 0.05,
            },
        )
    }

    /// The wrist driven down into the base: joints and TCP within their limits, the table
    /// clear, the links in each other.
    const FOLDED: Joints = [0.0, 0.5, 0.0, 1.0, 0.0];

    /// The shield refuses a posture folding the wrist into the base, in blind mode too, and
    /// passes the start posture and normal reaches (near the base and far out).
    #[test]
    fn a_self_colliding_posture_is_refused() {
        let mut s = shield(model());
        assert!(s.check_pose(&start(), &empty()).is_ok());
        let m = model();
        let ik = twin::IkSolver::new(&m, twin::IkConfig::default());
        for goal in [[0.20, 0.0, 0.10], [0.45, 0.35, 0.10], [0.30, -0.30, 0.25]] {
            let r = ik.solve(&m, &nalgebra::Vector3::from(goal), &start());
            assert!(r.reached, "{goal:?}");
            let verdict = s.check_pose(&r.joints, &empty());
            assert!(verdict.is_ok(), "{goal:?}: {verdict:?}");
        }
        let refused = s.check_pose(&FOLDED, &empty());
        assert!(
            matches!(refused, Err(ShieldViolation::SelfCollision { links, distance_m })
                if links[0] < links[1] && distance_m < twin::SELF_COLLISION_MIN_DISTANCE_M),
            "{refused:?}"
        );
        assert_eq!(refused.unwrap_err().code(), 9);
        let mut blind = Shield::new(
            TwinModel::new(model()).with_boxes_ignored(true),
            *s.limits(),
        );
        assert!(matches!(
            blind.check_pose(&FOLDED, &empty()),
            Err(ShieldViolation::SelfCollision { .. })
        ));
    }

    /// The tool on the model counts in the shield's clearance: the start posture with a
    /// box 5 mm into the gripper's reach is refused with the tool and passes without it.
    #[test]
    fn the_tool_counts_in_the_clearance() {
        let tcp = model().tcp_m(&start());
        let mut scene = empty();
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y, 0.0625],
                size_m: [0.10, 0.10, 0.125],
            })
            .unwrap();
        let bare = shield(model()).check_pose(&start(), &scene);
        assert!(matches!(bare, Ok(d) if d > 0.03), "{bare:?}");
        let tool = ToolConfig {
            from_m: [0.0, 0.0, 0.0],
            to_m: [0.0, 0.0, 0.10],
            radius_m: 0.03,
        };
        let armed = shield(model().with_tool(Some(tool.capsule()))).check_pose(&start(), &scene);
        assert!(
            matches!(armed, Err(ShieldViolation::Clearance { distance_m }) if distance_m < 0.0),
            "{armed:?}"
        );
    }

    /// The separation monitor's distance is to the moving boxes alone: the table, near the
    /// arm at every goal, does not count (it would slow every reach), nor does a still box
    /// (the plans are verified against it); blind mode has none.
    #[test]
    fn the_intruder_distance_counts_only_the_moving_boxes() {
        let mut m = TwinModel::new(model());
        let q = start();
        assert!(m.min_distance_m(&q, &empty()).is_finite());
        assert_eq!(m.intruder_distance_m(&q, &empty(), u32::MAX), f64::INFINITY);
        let tcp = model().tcp_m(&q);
        let mut scene = empty();
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y + 0.3, tcp.z],
                size_m: [0.05; 3],
            })
            .unwrap();
        let d = m.intruder_distance_m(&q, &scene, 0b1);
        assert!(d > 0.1 && d < 0.3, "{d}");
        assert!(m.min_distance_m(&q, &scene) <= d);
        // A still box nearer than the moving one: the moving one's distance still.
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y - 0.15, tcp.z],
                size_m: [0.05; 3],
            })
            .unwrap();
        assert!(m.min_distance_m(&q, &scene) < d - 0.05);
        assert_eq!(m.intruder_distance_m(&q, &scene, 0b1), d);
        assert!(m.intruder_distance_m(&q, &scene, 0b11) < d - 0.05);
        assert_eq!(m.intruder_distance_m(&q, &scene, 0), f64::INFINITY);
        let mut blind = TwinModel::new(model()).with_boxes_ignored(true);
        assert_eq!(blind.intruder_distance_m(&q, &scene, 0b1), f64::INFINITY);
    }
}
