//! An approved plan: joint positions and velocities sampled at the cycle period, produced
//! off the cycle (lookahead + Ruckig smoothing) and handed to it in a `Box` that the cycle
//! only reads and later returns for freeing.

use twin::Joints;
use twin::approval::PlanSamples;

/// Position, velocity and acceleration of the arm (the twin's: the smoother starts from it).
pub use twin::approval::MotionState;

/// Where a replacement plan joins the running one: its first sample equals sample
/// `index` of plan `plan_id`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JoinPoint {
    /// The plan being replaced.
    pub plan_id: u64,
    /// The sample of that plan this plan starts from.
    pub index: usize,
}

/// A jerk-limited joint trajectory sampled at the cycle period.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Unique, increasing id.
    pub id: u64,
    /// The policy whose lookahead approved it.
    pub policy_id: u64,
    /// `None`: starts at rest from the arm's current command; `Some`: continues a running plan.
    pub join: Option<JoinPoint>,
    /// Sample period, s (the cycle period).
    pub period_s: f64,
    /// Joint positions, rad, one per cycle.
    pub q_rad: Vec<Joints>,
    /// Joint velocities, rad/s, one per cycle.
    pub dq_rad_s: Vec<Joints>,
    /// Joint accelerations, rad/s², one per cycle.
    pub ddq_rad_s2: Vec<Joints>,
}

impl Plan {
    /// An empty plan with room for `capacity` samples.
    pub fn with_capacity(id: u64, policy_id: u64, period_s: f64, capacity: usize) -> Self {
        Self {
            id,
            policy_id,
            join: None,
            period_s,
            q_rad: Vec::with_capacity(capacity),
            dq_rad_s: Vec::with_capacity(capacity),
            ddq_rad_s2: Vec::with_capacity(capacity),
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.q_rad.len()
    }

    /// Whether the plan has no samples.
    pub fn is_empty(&self) -> bool {
        self.q_rad.is_empty()
    }

    /// Appends one sample.
    pub fn push(&mut self, q: Joints, dq: Joints, ddq: Joints) {
        self.q_rad.push(q);
        self.dq_rad_s.push(dq);
        self.ddq_rad_s2.push(ddq);
    }

    /// Sample `k` as a motion state (position, velocity, acceleration): where a plan
    /// joining this one at `k` starts.
    ///
    /// # Panics
    /// When `k >= self.len()`.
    pub fn sample(&self, k: usize) -> MotionState {
        MotionState {
            q_rad: self.q_rad[k],
            dq_rad_s: self.dq_rad_s[k],
            ddq_rad_s2: self.ddq_rad_s2[k],
        }
    }

    /// Duration, s.
    pub fn duration_s(&self) -> f64 {
        self.len() as f64 * self.period_s
    }
}

/// The smoother writes a plan's samples in place (`twin::approval::PlanSmoother`).
impl PlanSamples for Plan {
    fn restart(&mut self, period_s: f64) {
        self.period_s = period_s;
        self.q_rad.clear();
        self.dq_rad_s.clear();
        self.ddq_rad_s2.clear();
    }

    fn push_sample(&mut self, q_rad: Joints, dq_rad_s: Joints, ddq_rad_s2: Joints) {
        self.push(q_rad, dq_rad_s, ddq_rad_s2);
    }

    fn positions(&self) -> &[Joints] {
        &self.q_rad
    }
}
