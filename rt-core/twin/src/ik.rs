//! Inverse kinematics on the TCP position: damped least squares with joint limits and a
//! null-space pull toward the home posture (the xArm5 has 5 joints for a 3-D target, so
//! two directions are free; the pull keeps the solution near home and joint 5 still).

use nalgebra::{Matrix3, Matrix5, Vector3, Vector5};
use serde::{Deserialize, Serialize};

use super::model::RobotModel;
use super::{DOF, Joints};

/// Damping² of the pseudo-inverse inside the null-space projector (m²).
const PROJECTOR_DAMPING2: f64 = 1e-8;

/// Settings of the IK solver.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IkConfig {
    /// Most iterations per solve.
    pub max_iterations: u32,
    /// Position error below which the target counts as reached (m).
    pub tolerance_m: f64,
    /// Damping λ of the damped least squares (m).
    pub damping_m: f64,
    /// Gain of the null-space pull toward home, per iteration (0 = off, ≤ 1).
    pub nullspace_gain: f64,
    /// Largest change of any joint in one iteration (rad).
    pub max_iteration_step_rad: f64,
}

impl Default for IkConfig {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tolerance_m: 1e-4,
            damping_m: 0.02,
            nullspace_gain: 0.05,
            max_iteration_step_rad: 0.4,
        }
    }
}

impl IkConfig {
    /// Checks ranges.
    ///
    /// # Errors
    /// The name of the first bad field.
    pub fn validate(&self) -> Result<(), &'static str> {
        if self.max_iterations == 0 || self.max_iterations > 10_000 {
            return Err("ik.max_iterations must be in 1..=10000");
        }
        if !(self.tolerance_m.is_finite() && self.tolerance_m > 0.0 && self.tolerance_m < 0.1) {
            return Err("ik.tolerance_m must be in (0, 0.1)");
        }
        if !(self.damping_m.is_finite() && self.damping_m >= 0.0 && self.damping_m < 1.0) {
            return Err("ik.damping_m must be in [0, 1)");
        }
        if !(self.nullspace_gain.is_finite() && (0.0..=1.0).contains(&self.nullspace_gain)) {
            return Err("ik.nullspace_gain must be in [0, 1]");
        }
        if !(self.max_iteration_step_rad.is_finite() && self.max_iteration_step_rad > 0.0) {
            return Err("ik.max_iteration_step_rad must be positive");
        }
        Ok(())
    }
}

/// Outcome of one IK solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkResult {
    /// Best joints found (within the limits).
    pub joints: Joints,
    /// Whether the residual is within the tolerance.
    pub reached: bool,
    /// Remaining TCP position error (m).
    pub error_m: f64,
    /// Iterations used.
    pub iterations: u32,
}

/// Damped-least-squares IK solver (holds only its settings and the home posture).
#[derive(Debug, Clone, Copy)]
pub struct IkSolver {
    cfg: IkConfig,
    home: Joints,
}

impl IkSolver {
    /// A solver for `model` (pulls toward `model.home()`).
    pub fn new(model: &RobotModel, cfg: IkConfig) -> Self {
        Self {
            cfg,
            home: model.home(),
        }
    }

    /// The same solver with its null-space pull toward `home` instead of the model's home:
    /// solved from `home` as the start, it keeps the solution near that seed.
    #[must_use]
    pub fn with_home(mut self, home: Joints) -> Self {
        self.home = home;
        self
    }

    /// The settings.
    pub fn config(&self) -> &IkConfig {
        &self.cfg
    }

    /// Solves for the TCP at `target_m`, starting from `q_start`, with the configured
    /// iteration budget.
    pub fn solve(&self, model: &RobotModel, target_m: &Vector3<f64>, q_start: &Joints) -> IkResult {
        self.solve_with(model, target_m, q_start, self.cfg.max_iterations)
    }

    /// [`IkSolver::solve`] with an explicit iteration budget.
    ///
    /// # Performance
    /// Per iteration: one FK, a 3×5 Jacobian and a 3×3 inverse; no allocation.
    pub fn solve_with(
        &self,
        model: &RobotModel,
        target_m: &Vector3<f64>,
        q_start: &Joints,
        max_iterations: u32,
    ) -> IkResult {
        let limits = model.limits();
        let mut q = *q_start;
        limits.clamp(&mut q);
        let lambda2 = self.cfg.damping_m * self.cfg.damping_m;
        let mut poses = model.fk(&q);
        let mut err = target_m - poses.tcp_m();
        let mut iterations = 0;
        while iterations < max_iterations && err.norm() > self.cfg.tolerance_m {
            iterations += 1;
            let j = model.jacobian_pos(&poses);
            let jjt = j * j.transpose() + Matrix3::identity() * lambda2;
            let Some(inv) = jjt.try_inverse() else {
                break;
            };
            let j_pinv = j.transpose() * inv; // 5×3
            let mut dq: Vector5<f64> = j_pinv * err;
            if self.cfg.nullspace_gain > 0.0 {
                // The projector uses a nearly undamped pseudo-inverse, so the pull does not
                // leak into the task space (with the damped one it leaves a residual error).
                let jjt_exact = j * j.transpose() + Matrix3::identity() * PROJECTOR_DAMPING2;
                let Some(inv_exact) = jjt_exact.try_inverse() else {
                    break;
                };
                let null = Matrix5::identity() - j.transpose() * inv_exact * j;
                let pull = Vector5::from_fn(|i, _| self.home[i] - q[i]) * self.cfg.nullspace_gain;
                dq += null * pull;
            }
            let biggest = dq.amax();
            if biggest > self.cfg.max_iteration_step_rad {
                dq *= self.cfg.max_iteration_step_rad / biggest;
            }
            for i in 0..DOF {
                q[i] += dq[i];
            }
            limits.clamp(&mut q);
            model.fk_into(&q, &mut poses);
            err = target_m - poses.tcp_m();
        }
        let error_m = err.norm();
        IkResult {
            joints: q,
            reached: error_m <= self.cfg.tolerance_m,
            error_m,
            iterations,
        }
    }
}
