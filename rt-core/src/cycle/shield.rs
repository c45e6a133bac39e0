//! The safety shield: every command the cycle is about to send is re-checked against the
//! joint limits, the TCP workspace box, the TCP speed limit and the minimum distance to the
//! *live* scene. The same checks verify a whole plan on the twin thread before approval.
//! Checks are allocation-free; the model (kinematics + clearance) is injected through
//! [`ShieldModel`] so the twin's geometry or a stand-in can serve.

use crate::config::{MotionLimits, ShieldConfig};
use twin::{DOF, Joints};

/// Kinematics and clearance of the arm in a scene.
pub trait ShieldModel: Send + 'static {
    /// The scene snapshot the clearance is measured against (obstacles, goal).
    type Scene: Copy + Send + PartialEq + 'static;

    /// TCP position in the base frame, m.
    fn tcp_position_m(&mut self, q_rad: &Joints) -> [f64; 3];

    /// Minimum distance between the robot at `q_rad` and the obstacles of `scene`, m
    /// (negative when penetrating, `f64::INFINITY` without obstacles).
    fn min_distance_m(&mut self, q_rad: &Joints, scene: &Self::Scene) -> f64;
}

/// Why a command was refused (`Copy`; it travels through the cycle).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ShieldViolation {
    /// A position is NaN or infinite.
    #[error("non-finite command")]
    NonFinite,
    /// A joint is outside its limits (minus the margin).
    #[error("joint {joint} outside its limits")]
    JointLimit {
        /// The joint index.
        joint: u8,
    },
    /// The TCP is outside the workspace box.
    #[error("TCP outside the workspace box")]
    Workspace,
    /// The TCP would move faster than allowed.
    #[error("TCP speed {speed_m_s} m/s over the limit")]
    TcpSpeed {
        /// The speed, m/s.
        speed_m_s: f64,
    },
    /// The robot would come closer to an obstacle than allowed.
    #[error("clearance {distance_m} m below the minimum")]
    Clearance {
        /// The distance, m.
        distance_m: f64,
    },
}

impl ShieldViolation {
    /// A numeric code for the log ring and telemetry.
    pub fn code(self) -> u8 {
        match self {
            ShieldViolation::NonFinite => 1,
            ShieldViolation::JointLimit { .. } => 2,
            ShieldViolation::Workspace => 3,
            ShieldViolation::TcpSpeed { .. } => 4,
            ShieldViolation::Clearance { .. } => 5,
        }
    }
}

/// The shield's fixed limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShieldLimits {
    /// Lower joint limits incl. margin, rad.
    pub joint_min_rad: Joints,
    /// Upper joint limits incl. margin, rad.
    pub joint_max_rad: Joints,
    /// Workspace box, lower corner, m.
    pub workspace_min_m: [f64; 3],
    /// Workspace box, upper corner, m.
    pub workspace_max_m: [f64; 3],
    /// Maximum TCP speed, m/s.
    pub max_tcp_speed_m_s: f64,
    /// Minimum clearance, m.
    pub min_distance_m: f64,
}

impl ShieldLimits {
    /// From the runtime configuration.
    pub fn from_config(limits: &MotionLimits, shield: &ShieldConfig) -> Self {
        let mut joint_min_rad = limits.joint_min_rad;
        let mut joint_max_rad = limits.joint_max_rad;
        for j in 0..DOF {
            joint_min_rad[j] += shield.joint_margin_rad;
            joint_max_rad[j] -= shield.joint_margin_rad;
        }
        Self {
            joint_min_rad,
            joint_max_rad,
            workspace_min_m: shield.workspace_min_m,
            workspace_max_m: shield.workspace_max_m,
            max_tcp_speed_m_s: limits.max_tcp_speed_m_s,
            min_distance_m: shield.min_distance_m,
        }
    }
}

/// The shield: limits plus a model.
pub struct Shield<M: ShieldModel> {
    model: M,
    limits: ShieldLimits,
}

impl<M: ShieldModel> Shield<M> {
    /// A shield over `model`.
    pub fn new(model: M, limits: ShieldLimits) -> Self {
        Self { model, limits }
    }

    /// The limits.
    pub fn limits(&self) -> &ShieldLimits {
        &self.limits
    }

    /// The model.
    pub fn model_mut(&mut self) -> &mut M {
        &mut self.model
    }

    /// Checks a static pose: finiteness, joint limits, workspace, clearance. Returns the
    /// clearance, m.
    ///
    /// # Errors
    /// The first [`ShieldViolation`] found.
    pub fn check_pose(&mut self, q_rad: &Joints, scene: &M::Scene) -> Result<f64, ShieldViolation> {
        if q_rad.iter().any(|x| !x.is_finite()) {
            return Err(ShieldViolation::NonFinite);
        }
        for (j, q) in q_rad.iter().enumerate() {
            if *q < self.limits.joint_min_rad[j] || *q > self.limits.joint_max_rad[j] {
                return Err(ShieldViolation::JointLimit { joint: j as u8 });
            }
        }
        let tcp = self.model.tcp_position_m(q_rad);
        for (k, p) in tcp.iter().enumerate() {
            if *p < self.limits.workspace_min_m[k] || *p > self.limits.workspace_max_m[k] {
                return Err(ShieldViolation::Workspace);
            }
        }
        let d = self.model.min_distance_m(q_rad, scene);
        if d < self.limits.min_distance_m {
            return Err(ShieldViolation::Clearance { distance_m: d });
        }
        Ok(d)
    }

    /// Checks a command `q_rad` following `prev_q_rad` after `dt_s`: the pose checks plus the
    /// TCP speed. Returns the clearance, m.
    ///
    /// # Errors
    /// The first [`ShieldViolation`] found.
    pub fn check_step(
        &mut self,
        prev_q_rad: &Joints,
        q_rad: &Joints,
        dt_s: f64,
        scene: &M::Scene,
    ) -> Result<f64, ShieldViolation> {
        let d = self.check_pose(q_rad, scene)?;
        if dt_s > 0.0 {
            let a = self.model.tcp_position_m(prev_q_rad);
            let b = self.model.tcp_position_m(q_rad);
            let dist =
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            let speed_m_s = dist / dt_s;
            if speed_m_s > self.limits.max_tcp_speed_m_s {
                return Err(ShieldViolation::TcpSpeed { speed_m_s });
            }
        }
        Ok(d)
    }

    /// Checks a sequence of samples `qs` spaced `dt_s` apart, starting after `prev`. Returns
    /// the smallest clearance, m, or the index and kind of the first violation.
    ///
    /// # Errors
    /// `(index, violation)` of the first refused sample.
    pub fn check_path(
        &mut self,
        prev: &Joints,
        qs: &[Joints],
        dt_s: f64,
        scene: &M::Scene,
    ) -> Result<f64, (usize, ShieldViolation)> {
        let mut min_d = f64::INFINITY;
        let mut p = *prev;
        for (i, q) in qs.iter().enumerate() {
            let d = self.check_step(&p, q, dt_s, scene).map_err(|v| (i, v))?;
            min_d = min_d.min(d);
            p = *q;
        }
        Ok(min_d)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::testing::toy::{ToyArm, ToyScene};

    fn shield() -> Shield<ToyArm> {
        let cfg = RuntimeConfig::xarm5_default();
        Shield::new(ToyArm, ShieldLimits::from_config(&cfg.limits, &cfg.shield))
    }

    const HOME: Joints = [0.0, -0.5, -1.0, 0.5, 0.0];

    #[test]
    fn a_free_pose_passes_and_reports_its_clearance() {
        let mut s = shield();
        let d = s.check_pose(&HOME, &ToyScene::empty()).unwrap();
        assert!(d.is_infinite());
        let tcp = ToyArm.tcp_position_m(&HOME);
        let mut scene = ToyScene::empty();
        scene.push_obstacle([tcp[0], tcp[1] + 0.3, tcp[2]], [0.05; 3]);
        let d = s.check_pose(&HOME, &scene).unwrap();
        assert!(d > 0.1 && d < 0.3, "{d}");
    }

    #[test]
    fn each_kind_of_violation_is_detected() {
        let mut s = shield();
        let empty = ToyScene::empty();
        let mut q = HOME;
        q[1] = 3.0;
        assert_eq!(
            s.check_pose(&q, &empty),
            Err(ShieldViolation::JointLimit { joint: 1 })
        );
        q = HOME;
        q[2] = f64::NAN;
        assert_eq!(s.check_pose(&q, &empty), Err(ShieldViolation::NonFinite));
        let tcp = ToyArm.tcp_position_m(&HOME);
        let mut blocked = ToyScene::empty();
        blocked.push_obstacle(tcp, [0.05; 3]);
        assert!(matches!(
            s.check_pose(&HOME, &blocked),
            Err(ShieldViolation::Clearance { .. })
        ));
        let mut fast = HOME;
        fast[0] += 0.2;
        assert!(matches!(
            s.check_step(&HOME, &fast, 0.004, &empty),
            Err(ShieldViolation::TcpSpeed { .. })
        ));
        let below_table = [0.0, 2.0, 0.15, 0.5, 0.0];
        assert_eq!(
            s.check_pose(&below_table, &empty),
            Err(ShieldViolation::Workspace)
        );
    }
}
