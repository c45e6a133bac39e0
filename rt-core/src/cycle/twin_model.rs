//! The shield's model on the real twin: [`TwinModel`] gives the shield the twin's forward
//! kinematics and its capsule clearance to the live scene (boxes and table).

use twin::{Joints, LinkPoses, RobotGeometry, RobotModel, Scene};

use crate::cycle::shield::ShieldModel;

/// The shield model on the twin: FK and capsule distances to the scene's boxes and to the
/// table (links 2–5, as in the task's contact rule). Allocation-free.
#[derive(Debug, Clone)]
pub struct TwinModel {
    model: RobotModel,
    geometry: RobotGeometry,
    poses: LinkPoses,
}

impl TwinModel {
    /// Over a loaded robot model.
    pub fn new(model: RobotModel) -> Self {
        let geometry = RobotGeometry::new(&model);
        Self {
            model,
            geometry,
            poses: LinkPoses::default(),
        }
    }
}

impl ShieldModel for TwinModel {
    type Scene = Scene;

    fn tcp_position_m(&mut self, q_rad: &Joints) -> [f64; 3] {
        let p = self.model.tcp_m(q_rad);
        [p.x, p.y, p.z]
    }

    fn min_distance_m(&mut self, q_rad: &Joints, scene: &Scene) -> f64 {
        self.model.fk_into(q_rad, &mut self.poses);
        // The boxes and the table (links 2–5): the TCP workspace box alone does not keep
        // the wrist off the table.
        self.geometry.distance(&self.poses, scene).distance_m
    }
}
