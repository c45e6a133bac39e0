//! The shield's model on the real twin: [`TwinModel`] gives the shield the twin's forward
//! kinematics, its capsule clearance to the live scene (boxes and table; in blind mode,
//! `--no-lookahead`, the table alone: [`TwinModel::with_boxes_ignored`]) and its
//! self-collision check. The tool is the model's ([`crate::RobotModel::set_tool`]): give
//! `TwinModel::new` the model with the task's tool installed.

use crate::{Joints, LinkPoses, RobotGeometry, RobotModel, Scene};

use super::shield::{ShieldModel, WATCHED_POINTS};

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
