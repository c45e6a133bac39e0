//! The safety shield: the one check every command passes before it leaves the process
//! ([`Shield::check_step`]): finite, within the joint limits, a joint step of at most one
//! period at the velocity limit (plus [`STEP_TOLERANCE`]), the TCP in the workspace box, the
//! elbow, wrist and TCP slower than the TCP speed limit, no self-collision (checked link
//! pairs of the arm and the tool, [`ShieldModel::self_collision`]), and the minimum
//! distance to the *live* scene. Plan samples, brake steps, holds and the first command
//! after a reconnect all go through it; the same check verifies a whole plan on the twin
//! thread before approval. Checks are allocation-free; the model (kinematics, clearance,
//! self-collision) is injected through [`ShieldModel`] so the twin's geometry or a
//! stand-in can serve.
//!
//! It lives in the twin crate because "would rt-core approve this plan" is one function
//! ([`super::smooth_and_check`]) that rt-core's twin thread and the learner both run; the
//! cycle uses the same [`Shield`] for every command it sends. Real-time code: no
//! allocation, no lock, no panic.

use super::settings::{MotionLimits, ShieldConfig};
use crate::{DOF, Joints};

/// How many points [`ShieldModel::watched_points_m`] returns (elbow, wrist, TCP).
pub const WATCHED_POINTS: usize = 3;

/// Stated tolerance on the per-joint step: a command may move a joint at most
/// `(1 + STEP_TOLERANCE) × max_velocity × period` from the last command sent. Jerk-limited
/// plans and brakes stay within the velocity limit; 5 % absorbs rounding of the samples and
/// of the time-scaled stop's interpolation, and is far below the controller's fault margin.
pub const STEP_TOLERANCE: f64 = 0.05;

/// Rounding the backing-out rule forgives (a distance recomputed at a pose a smoother
/// reproduced to the last bits), m: a micrometre, far below any clearance.
pub const BACK_OUT_TOLERANCE_M: f64 = 1e-6;

/// Box slots the backing-out rule compares one by one ([`Shield::backs_out`]): the bits of
/// [`ShieldModel::intruder_distance_m`]'s mask.
pub const BOX_SLOTS: u32 = crate::MAX_OBSTACLES as u32;

/// Kinematics and clearance of the arm in a scene.
pub trait ShieldModel: Send + 'static {
    /// The scene snapshot the clearance is measured against (obstacles, goal).
    type Scene: Copy + Send + PartialEq + 'static;

    /// The points whose speed is limited, in the base frame, m: the elbow and wrist link
    /// origins and the TCP (last).
    fn watched_points_m(&mut self, q_rad: &Joints) -> [[f64; 3]; WATCHED_POINTS];

    /// TCP position in the base frame, m.
    fn tcp_position_m(&mut self, q_rad: &Joints) -> [f64; 3] {
        self.watched_points_m(q_rad)[WATCHED_POINTS - 1]
    }

    /// Minimum distance between the robot at `q_rad` and the obstacles of `scene`, m
    /// (negative when penetrating, `f64::INFINITY` without obstacles).
    fn min_distance_m(&mut self, q_rad: &Joints, scene: &Self::Scene) -> f64;

    /// Minimum distance between the robot at `q_rad` and what moves towards it (the
    /// obstacles whose bit is set in `moving_mask`, never the table), m: the separation of
    /// the speed and separation monitor (rt-core's `cycle::separation`); infinite when none
    /// moves. The default is [`ShieldModel::min_distance_m`] over every obstacle when any
    /// moves (a model whose scene holds obstacles only; conservative).
    fn intruder_distance_m(
        &mut self,
        q_rad: &Joints,
        scene: &Self::Scene,
        moving_mask: u32,
    ) -> f64 {
        if moving_mask == 0 {
            return f64::INFINITY;
        }
        self.min_distance_m(q_rad, scene)
    }

    /// The arm's self-collision at `q_rad`, if any: the two links (frame indices; the tool
    /// is [`crate::TOOL_FRAME`]) and the distance of their padded capsules, m. Independent of
    /// the scene, so it holds in blind mode too. The default (a model without link
    /// geometry, such as a test stand-in) reports none.
    fn self_collision(&mut self, q_rad: &Joints) -> Option<([u8; 2], f64)> {
        let _ = q_rad;
        None
    }
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
    /// A joint would move more than one period at its velocity limit.
    #[error("joint {joint} step over one period at its velocity limit")]
    JointStep {
        /// The joint index.
        joint: u8,
    },
    /// A moving command without a scene to check its clearance against.
    #[error("no scene to check the command against")]
    NoScene,
    /// The TCP would move farther in one target than the controller executes in its own
    /// servo period ([`MAX_TCP_STEP_M`]), whatever the cycle's period.
    #[error("TCP step {step_m} m over the controller's {MAX_TCP_STEP_M} m per target")]
    TcpStep {
        /// The step, m.
        step_m: f64,
    },
    /// The elbow (0) or wrist (1) link origin would move faster than the TCP limit.
    #[error("link point {point} speed {speed_m_s} m/s over the limit")]
    LinkSpeed {
        /// 0 = elbow, 1 = wrist.
        point: u8,
        /// The speed, m/s.
        speed_m_s: f64,
    },
    /// The robot would come closer to an obstacle than allowed.
    #[error("clearance {distance_m} m below the minimum")]
    Clearance {
        /// The distance, m.
        distance_m: f64,
    },
    /// Two of the arm's own links (or a link and the tool) would come too close.
    #[error("self-collision between links {} and {} ({distance_m} m)", links[0], links[1])]
    SelfCollision {
        /// The two link frames (`0` = base … `5` = link5, [`crate::TOOL_FRAME`] = the tool).
        links: [u8; 2],
        /// The distance between their padded capsules, m.
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
            // One code for both bounds on the TCP's motion (10 + 10 would be another
            // stop's code, `StopReason::code`).
            ShieldViolation::TcpSpeed { .. } | ShieldViolation::TcpStep { .. } => 4,
            ShieldViolation::Clearance { .. } => 5,
            ShieldViolation::JointStep { .. } => 6,
            ShieldViolation::LinkSpeed { .. } => 7,
            ShieldViolation::NoScene => 8,
            ShieldViolation::SelfCollision { .. } => 9,
        }
    }
}

/// The most the TCP may move between two targets, m: what the xArm controller executes in
/// its 4 ms servo period (its 1 m/s TCP limit with its 25 % slack; `xarm-sim`'s protective
/// check). At 250 Hz and the configured 0.8 m/s a target moves 3.2 mm; at 100 Hz the speed
/// limit alone would allow 8 mm, which the controller faults on (issue 41 item 5).
pub const MAX_TCP_STEP_M: f64 = 0.005;

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
    /// Maximum TCP speed (and elbow/wrist origin speed), m/s.
    pub max_tcp_speed_m_s: f64,
    /// Maximum TCP step between two targets, m ([`MAX_TCP_STEP_M`]).
    pub max_tcp_step_m: f64,
    /// Maximum joint velocities, rad/s (the step limit is one period of these).
    pub max_velocity_rad_s: Joints,
    /// Minimum clearance, m.
    pub min_distance_m: f64,
}

impl ShieldLimits {
    /// The most one joint may move between two commands sent one period apart: one
    /// period at the fastest joint's velocity limit plus [`STEP_TOLERANCE`] (also the
    /// driver's limit on the first target after a reconnect), rad.
    pub fn max_step_rad(&self, period_s: f64) -> f64 {
        let v = self.max_velocity_rad_s.iter().copied().fold(0.0, f64::max);
        v * period_s * (1.0 + STEP_TOLERANCE)
    }

    /// The TCP speed a plan sampled every `period_s` may reach: the speed limit, or less
    /// where one period at it would step farther than [`ShieldLimits::max_tcp_step_m`].
    pub fn tcp_speed_limit_m_s(&self, period_s: f64) -> f64 {
        if period_s > 0.0 {
            self.max_tcp_speed_m_s.min(self.max_tcp_step_m / period_s)
        } else {
            self.max_tcp_speed_m_s
        }
    }

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
            max_tcp_step_m: MAX_TCP_STEP_M,
            max_velocity_rad_s: limits.max_velocity_rad_s,
            min_distance_m: shield.min_distance_m,
        }
    }
}

/// The shield: limits plus a model.
#[derive(Debug, Clone)]
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
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The model, mutably.
    pub fn model_mut(&mut self) -> &mut M {
        &mut self.model
    }

    /// Checks a static pose: finiteness, joint limits, workspace, self-collision, clearance.
    /// Returns the clearance, m.
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
        if let Some((links, distance_m)) = self.model.self_collision(q_rad) {
            return Err(ShieldViolation::SelfCollision { links, distance_m });
        }
        let d = self.model.min_distance_m(q_rad, scene);
        if d < self.limits.min_distance_m {
            return Err(ShieldViolation::Clearance { distance_m: d });
        }
        Ok(d)
    }

    /// The one check of a command `q_rad` sent `dt_s` after `prev_q_rad` (the last command
    /// sent): the pose checks, each joint's step against one period at its velocity limit
    /// (plus [`STEP_TOLERANCE`]), the speed of the elbow, the wrist and the TCP, and the
    /// TCP's step against the controller's [`MAX_TCP_STEP_M`]. Returns the clearance, m.
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
        self.check_motion(prev_q_rad, q_rad, dt_s)?;
        self.check_pose_from(prev_q_rad, q_rad, scene)
    }

    /// [`Shield::check_pose`] of `q_rad` reached from `from_q_rad`, with the one exception to
    /// the clearance (issue 42 item 3, backing out): a pose closer than `min_distance_m` to
    /// the scene passes when it [backs out](Shield::backs_out) from `from_q_rad` — an arm
    /// already too close (stopped there, or a box came to it) may move away, and only away.
    /// Entering the clearance never passes (the box it enters is closer than before). Returns
    /// the clearance, m.
    ///
    /// # Errors
    /// The first [`ShieldViolation`] found.
    pub fn check_pose_from(
        &mut self,
        from_q_rad: &Joints,
        q_rad: &Joints,
        scene: &M::Scene,
    ) -> Result<f64, ShieldViolation> {
        match self.check_pose(q_rad, scene) {
            Err(ShieldViolation::Clearance { distance_m })
                if self.backs_out(from_q_rad, q_rad, distance_m, scene) =>
            {
                Ok(distance_m)
            }
            other => other,
        }
    }

    /// The backing-out rule: out of contact at both poses (the model's padded clearance above
    /// zero: an arm in contact is not moved), at `q_rad` (clearance `distance_m`) the arm is no
    /// closer to the scene than at `from_q_rad`, and no closer to any box (each box's distance,
    /// [`ShieldModel::intruder_distance_m`] with that box alone, at least what it was; a model
    /// without per-box distances answers for all boxes at once), up to
    /// [`BACK_OUT_TOLERANCE_M`] of rounding. Staying put passes; the clearance never shrinks,
    /// so a contact-free arm stays contact-free.
    ///
    /// # Performance
    /// Two distance queries per box slot ([`BOX_SLOTS`]); asked only below the clearance.
    pub fn backs_out(
        &mut self,
        from_q_rad: &Joints,
        q_rad: &Joints,
        distance_m: f64,
        scene: &M::Scene,
    ) -> bool {
        // Never in contact (the model's padded distance at or below zero: how deep the arm is
        // inside a box is not what its distance measures, so no motion there is "away").
        // NaN compares false: refused.
        let before_m = self.model.min_distance_m(from_q_rad, scene);
        if !(distance_m > 0.0 && before_m > 0.0)
            || distance_m
                .partial_cmp(&(before_m - BACK_OUT_TOLERANCE_M))
                .is_none_or(|o| o == std::cmp::Ordering::Less)
        {
            return false;
        }
        (0..BOX_SLOTS).all(|i| {
            let mask = 1u32 << i;
            let now_m = self.model.intruder_distance_m(q_rad, scene, mask);
            let before_m = self.model.intruder_distance_m(from_q_rad, scene, mask);
            now_m >= before_m - BACK_OUT_TOLERANCE_M
        })
    }

    /// The motion part of [`Shield::check_step`] (steps and speeds, no clearance).
    ///
    /// # Errors
    /// The first [`ShieldViolation`] found.
    pub fn check_motion(
        &mut self,
        prev_q_rad: &Joints,
        q_rad: &Joints,
        dt_s: f64,
    ) -> Result<(), ShieldViolation> {
        if prev_q_rad.iter().chain(q_rad).any(|x| !x.is_finite()) || !dt_s.is_finite() || dt_s < 0.0
        {
            return Err(ShieldViolation::NonFinite);
        }
        let scale = (1.0 + STEP_TOLERANCE) * dt_s;
        for j in 0..DOF {
            if (q_rad[j] - prev_q_rad[j]).abs() > self.limits.max_velocity_rad_s[j] * scale {
                return Err(ShieldViolation::JointStep { joint: j as u8 });
            }
        }
        if dt_s > 0.0 && prev_q_rad != q_rad {
            let a = self.model.watched_points_m(prev_q_rad);
            let b = self.model.watched_points_m(q_rad);
            for (k, (pa, pb)) in a.iter().zip(&b).enumerate() {
                let dist =
                    ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2))
                        .sqrt();
                if k == WATCHED_POINTS - 1 && dist > self.limits.max_tcp_step_m {
                    return Err(ShieldViolation::TcpStep { step_m: dist });
                }
                let speed_m_s = dist / dt_s;
                if speed_m_s > self.limits.max_tcp_speed_m_s {
                    return Err(if k == WATCHED_POINTS - 1 {
                        ShieldViolation::TcpSpeed { speed_m_s }
                    } else {
                        ShieldViolation::LinkSpeed {
                            point: k as u8,
                            speed_m_s,
                        }
                    });
                }
            }
        }
        Ok(())
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
