//! [`Approver`]: from waypoints to a plan the cycle may follow — the lookahead of a policy,
//! Ruckig smoothing, the shield on every sample in the scene in force and, for an episode,
//! the smoothed path reaching the goal. Whatever fails is a [`PlanRejection`]. The smoothing
//! and the per-sample check are the twin's (`twin::approval::smooth_and_check`), the one
//! verification the learner runs too.
//!
//! "Goal reached" is checked on the smoothed path the arm will follow
//! ([`Lookahead::goal_approach`]), not only on the lookahead's waypoints.

use twin::Joints;

use crate::config::RuntimeConfig;
use crate::cycle::plan::MotionState;
use crate::cycle::plan::{JoinPoint, Plan};
use crate::cycle::shield::{Shield, ShieldModel, ShieldViolation};
use crate::twin_thread::smoother::PlanSmoother;

use super::policy_library::FallbackPlanner;
use super::{Lookahead, Verdict};

/// Why a smoothed plan was not approved (the twin's verification's reasons).
pub use twin::approval::PlanRejection;

/// The verdict a passed lookahead becomes once its plan is rejected.
pub trait FailedVerdict {
    /// The verdict `verdict` (a passed lookahead) becomes once its plan is rejected: a path
    /// that misses the goal fails the task; a smoothing or shield failure fails safety
    /// (with the shield's clearance when smaller).
    fn failed_verdict(&self, verdict: Verdict) -> Verdict;
}

impl FailedVerdict for PlanRejection {
    fn failed_verdict(&self, verdict: Verdict) -> Verdict {
        match *self {
            Self::MissesGoal(_) => Verdict {
                task_ok: false,
                ..verdict
            },
            Self::Shield {
                violation: ShieldViolation::Clearance { distance_m },
                ..
            } => Verdict {
                safe: false,
                min_distance_m: distance_m.min(verdict.min_distance_m),
                ..verdict
            },
            Self::Shield { .. } | Self::Smoothing(_) => Verdict {
                safe: false,
                ..verdict
            },
        }
    }
}

/// Who judges whether the smoothed path reaches the goal.
pub enum GoalCheck<'a, L: Lookahead> {
    /// A policy's episode plan (lookahead gate on): the lookahead, for that policy.
    Policy(&'a L::Policy),
    /// The planner fallback's plan: the planner, by the same rule.
    Planner(&'a mut dyn FallbackPlanner<L::Scene>),
    /// The way home, or no gate: no goal check.
    None,
}

/// The lookahead, the smoother and the plan-check shield, with the waypoint buffer they
/// share.
pub struct Approver<L: Lookahead, M: ShieldModel<Scene = L::Scene>> {
    la: L,
    shield: Shield<M>,
    smoother: PlanSmoother,
    period_s: f64,
    /// The waypoints of the last lookahead (or the way home).
    pub waypoints: Vec<Joints>,
    next_plan_id: u64,
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> Approver<L, M> {
    /// Over a lookahead and the plan-check shield.
    pub fn new(cfg: &RuntimeConfig, la: L, shield: Shield<M>) -> Self {
        let period_s = 1.0 / cfg.rate_hz;
        Self {
            la,
            shield,
            smoother: PlanSmoother::new(period_s, cfg.limits, (60.0 * cfg.rate_hz) as usize),
            period_s,
            waypoints: Vec::new(),
            next_plan_id: 1,
        }
    }

    /// The cycle period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// The plan-check shield.
    pub fn shield_mut(&mut self) -> &mut Shield<M> {
        &mut self.shield
    }

    /// The lookahead.
    pub fn lookahead_mut(&mut self) -> &mut L {
        &mut self.la
    }

    /// Cycle samples per twin step (at least 1).
    pub fn samples_per_step(&self) -> usize {
        ((self.la.step_s() / self.period_s).round() as usize).max(1)
    }

    /// Rolls `policy` out from `start_q_rad` in `scene` into [`Self::waypoints`].
    pub fn lookahead(
        &mut self,
        policy: &L::Policy,
        scene: &L::Scene,
        start_q_rad: &Joints,
    ) -> Verdict {
        self.la
            .lookahead(policy, scene, start_q_rad, &mut self.waypoints)
    }

    /// The plan of sampled candidate `index` (of the lookahead's last sampling of `policy`
    /// in `scene`) from `start_q_rad` into [`Self::waypoints`], with its verdict.
    pub fn sampled_plan(
        &mut self,
        policy: &L::Policy,
        scene: &L::Scene,
        start_q_rad: &Joints,
        index: usize,
    ) -> Option<Verdict> {
        self.la
            .sampled_plan(policy, scene, start_q_rad, index, &mut self.waypoints)
    }

    /// Smooths [`Self::waypoints`] from `start` into a new plan and checks every sample with
    /// the shield in `scene` (what every plan passes before it reaches the cycle); unless
    /// [`GoalCheck::None`], also that the smoothed path's TCP comes within the task's
    /// tolerance of the goal target — the plan the arm follows must reach the goal the
    /// lookahead (or planner) declared reached, not only its waypoints.
    ///
    /// # Errors
    /// The [`PlanRejection`].
    pub fn smoothed_checked_plan(
        &mut self,
        start: &MotionState,
        join: Option<JoinPoint>,
        policy_id: u64,
        scene: &L::Scene,
        goal: GoalCheck<'_, L>,
    ) -> Result<Plan, PlanRejection> {
        let id = self.next_plan_id;
        self.next_plan_id += 1;
        let mut plan = Plan::with_capacity(id, policy_id, self.period_s, 0);
        plan.join = join;
        // The twin's one verification: smoothing and the shield on every sample.
        twin::approval::smooth_and_check(
            &mut self.smoother,
            &mut self.shield,
            start,
            &self.waypoints,
            self.la.step_s(),
            scene,
            &mut plan,
        )?;
        let approach = match goal {
            GoalCheck::Policy(policy) => self.la.goal_approach(policy, scene, &plan.q_rad),
            GoalCheck::Planner(planner) => planner.goal_approach(scene, &plan.q_rad),
            GoalCheck::None => return Ok(plan),
        };
        if !approach.reached() {
            return Err(PlanRejection::MissesGoal(approach));
        }
        Ok(plan)
    }

    /// A plan of the given samples (`q`, `dq`, `ddq` at the cycle's period) from `start`, with
    /// a new id, checked by the shield on every sample in `scene` (a retreat: its samples are
    /// the path it came, re-timed, not smoothed anew).
    ///
    /// # Errors
    /// [`PlanRejection::Shield`] with the first refused sample.
    pub fn checked_samples(
        &mut self,
        start: &Joints,
        samples: &[(Joints, Joints, Joints)],
        policy_id: u64,
        scene: &L::Scene,
    ) -> Result<Plan, PlanRejection> {
        let id = self.next_plan_id;
        self.next_plan_id += 1;
        let mut plan = Plan::with_capacity(id, policy_id, self.period_s, samples.len());
        for (q, dq, ddq) in samples {
            plan.push(*q, *dq, *ddq);
        }
        self.shield
            .check_path(start, &plan.q_rad, self.period_s, scene)
            .map_err(|(index, violation)| PlanRejection::Shield { index, violation })?;
        Ok(plan)
    }

    /// The first sample of `path` (after `prev`) that fails the shield in `scene`.
    pub fn first_unsafe(
        &mut self,
        prev: &Joints,
        path: &[Joints],
        scene: &L::Scene,
    ) -> Option<usize> {
        self.shield
            .check_path(prev, path, self.period_s, scene)
            .err()
            .map(|(i, _)| i)
    }
}
