//! Forward kinematics: all link frames and the TCP for a joint configuration, with
//! nalgebra's static types (no allocation).

use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use super::model::{N_FRAMES, RobotModel};
use super::{DOF, Joints};

/// Poses of every link frame and of the TCP in the base frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkPoses {
    /// `links[0]` is the base (identity), `links[i]` the frame of link i (after joint i).
    pub links: [Isometry3<f64>; N_FRAMES],
    /// The TCP frame.
    pub tcp: Isometry3<f64>,
}

impl Default for LinkPoses {
    fn default() -> Self {
        Self {
            links: [Isometry3::identity(); N_FRAMES],
            tcp: Isometry3::identity(),
        }
    }
}

impl LinkPoses {
    /// TCP position (m).
    pub fn tcp_m(&self) -> Vector3<f64> {
        self.tcp.translation.vector
    }
}

impl RobotModel {
    /// Forward kinematics: every link frame and the TCP.
    ///
    /// # Performance
    /// Five isometry products and rotations; no allocation.
    pub fn fk(&self, q: &Joints) -> LinkPoses {
        let mut out = LinkPoses::default();
        self.fk_into(q, &mut out);
        out
    }

    /// [`RobotModel::fk`] writing into an existing buffer.
    pub fn fk_into(&self, q: &Joints, out: &mut LinkPoses) {
        let mut t = Isometry3::identity();
        out.links[0] = t;
        for (i, angle) in q.iter().enumerate() {
            t *= self.joint_origin[i];
            t.rotation *= UnitQuaternion::from_axis_angle(&self.joint_axis[i], *angle);
            out.links[i + 1] = t;
        }
        out.tcp = t * self.tcp_offset;
    }

    /// TCP position (m) for `q`.
    pub fn tcp_m(&self, q: &Joints) -> Vector3<f64> {
        self.fk(q).tcp_m()
    }

    /// World axes of every joint and the TCP position, for the Jacobian.
    pub(crate) fn jacobian_pos(&self, poses: &LinkPoses) -> nalgebra::Matrix3x5<f64> {
        let p = poses.tcp_m();
        let mut j = nalgebra::Matrix3x5::zeros();
        for i in 0..DOF {
            let frame = &poses.links[i + 1];
            let axis = frame.rotation * self.joint_axis[i].into_inner();
            let col = axis.cross(&(p - frame.translation.vector));
            j.set_column(i, &col);
        }
        j
    }
}
