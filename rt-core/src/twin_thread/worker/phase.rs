//! [`Phase`]: where the worker is in an excursion (an episode, the dwell at its goal, the
//! way home, a hold after a refused way home), and [`Planning`]: whether a new plan is
//! wanted, now or after a back-off. Together they are the worker's state: "why is the arm
//! holding?" is answered by two values. The phase changes only through [`Phase::next`], one
//! `match` over named [`Transition`]s.
//!
//! The two are independent on purpose: a scene change during the dwell asks for a plan
//! while the dwell goes on, and a refusal backs off whatever the excursion's phase.

use shm_schemas::PhaseCode;

/// Where the worker is in an excursion (start → goal → home).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Phase {
    /// An episode: the arm follows (or rests after) an episode plan, or waits for one.
    #[default]
    Episode,
    /// The episode plan `plan_id` ended at its goal; the arm rests there since `since_ns`
    /// (cycle clock) and returns home once `dwell_at_goal_s` has passed.
    DwellAtGoal {
        /// The plan that ended at the goal.
        plan_id: u64,
        /// Start of the rest, ns.
        since_ns: u64,
    },
    /// The arm returns to where the excursion began along its executed path (and stays in
    /// this phase once home, until the next episode plan).
    ReturningHome,
    /// The way home after plan `plan_id` was unsafe in the scene then in force: the arm
    /// holds and the ordinary lookahead takes over (the way home is not retried).
    HoldingAfterRefusedReturn {
        /// The plan whose return was refused.
        plan_id: u64,
    },
}

impl Phase {
    /// The plan sent last is a way home.
    pub fn returning(&self) -> bool {
        matches!(self, Self::ReturningHome)
    }

    /// The return after plan `plan_id` was refused.
    pub fn return_refused_for(&self, plan_id: u64) -> bool {
        matches!(self, Self::HoldingAfterRefusedReturn { plan_id: p } if *p == plan_id)
    }

    /// The phase after `t`.
    pub fn next(self, t: Transition) -> Phase {
        match (self, t) {
            (_, Transition::EpisodePlanSent) => Phase::Episode,
            // Still resting after the same plan: the dwell goes on.
            (Phase::DwellAtGoal { plan_id: p, .. }, Transition::RestingAtGoal { plan_id, .. })
                if p == plan_id =>
            {
                self
            }
            (_, Transition::RestingAtGoal { plan_id, now_ns }) => Phase::DwellAtGoal {
                plan_id,
                since_ns: now_ns,
            },
            (_, Transition::ReturnSent) => Phase::ReturningHome,
            (_, Transition::ReturnRefused { plan_id }) => {
                Phase::HoldingAfterRefusedReturn { plan_id }
            }
        }
    }
}

/// What moves the worker from one [`Phase`] to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transition {
    /// An episode plan was sent to the cycle.
    EpisodePlanSent,
    /// The arm rests at the end of episode plan `plan_id` (seen at `now_ns`, cycle clock).
    RestingAtGoal {
        /// The plan.
        plan_id: u64,
        /// When, ns.
        now_ns: u64,
    },
    /// The way home was sent to the cycle.
    ReturnSent,
    /// The way home after plan `plan_id` was unsafe in the scene in force.
    ReturnRefused {
        /// The plan.
        plan_id: u64,
    },
}

/// Whether a new plan is wanted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Planning {
    /// Nothing asks for a plan.
    Idle,
    /// A plan is wanted as soon as the scene's gates allow.
    Due,
    /// The cycle refused a plan (it cannot move: a link error, a stop under way): a plan is
    /// wanted, not before `until_ns` (cycle clock).
    BackOff {
        /// End of the back-off, ns.
        until_ns: u64,
    },
}

impl Planning {
    /// A plan is wanted (now or after the back-off).
    pub fn is_due(&self) -> bool {
        !matches!(self, Self::Idle)
    }

    /// Still backing off at `now_ns`.
    pub fn backing_off(&self, now_ns: u64) -> bool {
        matches!(self, Self::BackOff { until_ns } if now_ns < *until_ns)
    }

    /// Something asks for a plan; a back-off under way stays in force.
    pub fn request(&mut self) {
        if *self == Self::Idle {
            *self = Self::Due;
        }
    }

    /// The cycle refused a plan at `now_ns`: plan again after `backoff_ns`.
    pub fn refused(&mut self, now_ns: u64, backoff_ns: u64) {
        *self = Self::BackOff {
            until_ns: now_ns.saturating_add(backoff_ns),
        };
    }

    /// The wanted plan is in hand (made, or given up on until something changes).
    pub fn taken(&mut self) {
        *self = Self::Idle;
    }
}

/// The compact code of the worker's state in `TwinVerdict` diagnostics: a back-off under
/// way first, then the excursion's phase.
pub fn phase_code(phase: &Phase, planning: &Planning, now_ns: u64) -> PhaseCode {
    if planning.backing_off(now_ns) {
        return PhaseCode::BackOff;
    }
    match phase {
        Phase::Episode => PhaseCode::Episode,
        Phase::DwellAtGoal { .. } => PhaseCode::DwellAtGoal,
        Phase::ReturningHome => PhaseCode::ReturningHome,
        Phase::HoldingAfterRefusedReturn { .. } => PhaseCode::HoldingAfterRefusedReturn,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_keeps_a_back_off_under_way() {
        let mut p = Planning::Idle;
        p.refused(100, 50);
        p.request();
        assert!(p.backing_off(149));
        assert!(!p.backing_off(150));
        assert!(p.is_due());
        p.taken();
        p.request();
        assert_eq!(p, Planning::Due);
    }

    #[test]
    fn the_dwell_goes_on_for_the_same_plan_and_restarts_for_another() {
        let rest = |plan_id, now_ns| Transition::RestingAtGoal { plan_id, now_ns };
        let dwell = |plan_id, since_ns| Phase::DwellAtGoal { plan_id, since_ns };
        let ph = Phase::Episode.next(rest(7, 10));
        assert_eq!(ph, dwell(7, 10));
        assert_eq!(ph.next(rest(7, 20)), dwell(7, 10));
        assert_eq!(ph.next(rest(8, 30)), dwell(8, 30));
        let held = ph.next(Transition::ReturnRefused { plan_id: 7 });
        assert!(held.return_refused_for(7) && !held.return_refused_for(8));
        assert_eq!(held.next(Transition::EpisodePlanSent), Phase::Episode);
    }
}
