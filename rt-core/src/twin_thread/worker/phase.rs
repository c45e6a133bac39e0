//! The worker's state. [`Excursion`]: where the worker is in an excursion — its [`Phase`]
//! (an episode, a continuation after a pause, the dwell at the goal, a pause after a
//! controlled stop, the way home, a hold after a refused way home) and whether a stop sent
//! the arm home during it (then the episode runs again once home). [`Planning`]: whether a
//! new plan is wanted, now or after a back-off. The phase changes only through
//! [`Excursion::next`] / [`Phase::next`], one `match` over named [`Transition`]s.
//!
//! "Why is the arm holding?" is answered by these values and the cycle's state
//! ([`crate::cycle::CycleReport`]: its mode and stop reason; a stop the plan guard scheduled
//! on the running plan, [`crate::cycle::CycleControl::stop_due`]): a pause waits out a
//! back-off and then a continuation or the way home, a hold after a refused way home waits
//! for the ordinary lookahead, the dwell waits `dwell_at_goal_s`, and a scene with no goal,
//! refused or still changing holds everything ([`super::Hold`]).
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
    /// The episode goes on from where a pause left the arm: plan `plan_id`, made from
    /// there (`continue_after_pause`), runs to the goal like any episode plan.
    Continuing {
        /// The continuation.
        plan_id: u64,
    },
    /// The episode plan `plan_id` ended at its goal; the arm rests there since `since_ns`
    /// (cycle clock) and returns home once `dwell_at_goal_s` has passed.
    DwellAtGoal {
        /// The plan that ended at the goal.
        plan_id: u64,
        /// Start of the rest, ns.
        since_ns: u64,
    },
    /// A controlled stop (a revocation, a scheduled stop reached, a stale or refused frame,
    /// a lost link) left the arm at rest partway along plan `plan_id`, seen first at
    /// `since_ns` (cycle clock), during `during`. Once no back-off holds planning, a
    /// continuation from there is tried (`continue_after_pause`), else the way home along
    /// the executed path (off it, the ordinary planning).
    Paused {
        /// The plan the stop cut short.
        plan_id: u64,
        /// When the worker first saw the arm stopped, ns.
        since_ns: u64,
        /// What the stop interrupted.
        during: Leg,
    },
    /// The arm returns to where the excursion began along its executed path (and stays in
    /// this phase once home, until the next episode plan). After a goal, or after a stop
    /// ([`Excursion::episode_owed`]).
    ReturningHome,
    /// The way home after plan `plan_id` was unsafe in the scene then in force: the arm
    /// holds and the ordinary lookahead takes over (the way home is not retried).
    HoldingAfterRefusedReturn {
        /// The plan whose return was refused.
        plan_id: u64,
    },
    /// The arm rested too close to a box and backs out along the path it came: retreat
    /// `plan_id` (`done` once the arm rests at its end; then it plans as usual from there,
    /// [`super::retreat`]). An episode plan sent ends it.
    BackingOut {
        /// The retreat.
        plan_id: u64,
        /// The retreat has ended (planning was asked for).
        done: bool,
    },
}

/// What a pause interrupted (its diagnostics code stays that of the leg: a pause is not a
/// phase of its own in `TwinVerdict`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Leg {
    /// An episode plan (or a continuation).
    Episode,
    /// The dwell at the goal.
    DwellAtGoal,
    /// The way home.
    ReturningHome,
}

impl Phase {
    /// The plan sent last is a way home.
    pub fn returning(&self) -> bool {
        matches!(
            self,
            Self::ReturningHome
                | Self::Paused {
                    during: Leg::ReturningHome,
                    ..
                }
        )
    }

    /// The return after plan `plan_id` was refused.
    pub fn return_refused_for(&self, plan_id: u64) -> bool {
        matches!(self, Self::HoldingAfterRefusedReturn { plan_id: p } if *p == plan_id)
    }

    /// The leg of the excursion this phase belongs to (a pause: the one it interrupted).
    pub fn leg(&self) -> Leg {
        match self {
            Self::Episode
            | Self::Continuing { .. }
            | Self::HoldingAfterRefusedReturn { .. }
            | Self::BackingOut { .. } => Leg::Episode,
            Self::DwellAtGoal { .. } => Leg::DwellAtGoal,
            Self::ReturningHome => Leg::ReturningHome,
            Self::Paused { during, .. } => *during,
        }
    }

    /// The phase after `t`.
    pub fn next(self, t: Transition) -> Phase {
        match (self, t) {
            (_, Transition::EpisodePlanSent) => Phase::Episode,
            (_, Transition::ContinuationSent { plan_id }) => Phase::Continuing { plan_id },
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
            // Still stopped on the same plan: the pause goes on.
            (Phase::Paused { plan_id: p, .. }, Transition::Stopped { plan_id, .. })
                if p == plan_id =>
            {
                self
            }
            (_, Transition::Stopped { plan_id, now_ns }) => Phase::Paused {
                plan_id,
                since_ns: now_ns,
                during: self.leg(),
            },
            (_, Transition::ReturnSent { .. }) => Phase::ReturningHome,
            (_, Transition::ReturnRefused { plan_id }) => {
                Phase::HoldingAfterRefusedReturn { plan_id }
            }
            (_, Transition::BackOutSent { plan_id }) => Phase::BackingOut {
                plan_id,
                done: false,
            },
            (Phase::BackingOut { plan_id, .. }, Transition::BackedOut) => Phase::BackingOut {
                plan_id,
                done: true,
            },
            (_, Transition::BackedOut) => self,
        }
    }
}

/// What moves the worker from one [`Phase`] to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transition {
    /// An episode plan was sent to the cycle.
    EpisodePlanSent,
    /// A continuation from where a pause left the arm was sent (plan `plan_id`).
    ContinuationSent {
        /// The plan.
        plan_id: u64,
    },
    /// The arm rests at the end of episode plan `plan_id` (seen at `now_ns`, cycle clock).
    RestingAtGoal {
        /// The plan.
        plan_id: u64,
        /// When, ns.
        now_ns: u64,
    },
    /// A controlled stop left the arm at rest on plan `plan_id` (seen at `now_ns`).
    Stopped {
        /// The plan.
        plan_id: u64,
        /// When, ns.
        now_ns: u64,
    },
    /// The way home was sent to the cycle, `after_stop` (a pause) or after the goal.
    ReturnSent {
        /// Sent after a controlled stop: the episode runs again once home.
        after_stop: bool,
    },
    /// The way home after plan `plan_id` was unsafe in the scene in force.
    ReturnRefused {
        /// The plan.
        plan_id: u64,
    },
    /// A retreat (plan `plan_id`) from too close to a box was sent.
    BackOutSent {
        /// The plan.
        plan_id: u64,
    },
    /// The arm rests at the end of the retreat.
    BackedOut,
}

/// The worker's excursion: its [`Phase`], and whether a stop sent the arm home during it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Excursion {
    phase: Phase,
    /// A controlled stop sent the arm home during this excursion: once home, the episode
    /// runs again. It stands until home, whatever plan takes over the way home meanwhile.
    episode_owed: bool,
}

impl Excursion {
    /// The phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Whether the episode runs again once home (a stop sent the arm home).
    pub fn episode_owed(&self) -> bool {
        self.episode_owed
    }

    /// Moves on by `t`.
    pub fn next(&mut self, t: Transition) {
        if let Transition::ReturnSent { after_stop: true } = t {
            self.episode_owed = true;
        }
        self.phase = self.phase.next(t);
    }

    /// Home: the next excursion starts here. Returns whether the episode is owed (it then
    /// runs again); the phase stays [`Phase::ReturningHome`] until the next plan.
    pub fn arrive_home(&mut self) -> bool {
        std::mem::take(&mut self.episode_owed)
    }
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
/// way first, then the excursion's phase (a continuation counts as an episode, a pause as
/// the leg it interrupted).
pub fn phase_code(phase: &Phase, planning: &Planning, now_ns: u64) -> PhaseCode {
    if planning.backing_off(now_ns) {
        return PhaseCode::BackOff;
    }
    match phase {
        Phase::HoldingAfterRefusedReturn { .. } => PhaseCode::HoldingAfterRefusedReturn,
        Phase::BackingOut { done: false, .. } => PhaseCode::BackingOut,
        _ => match phase.leg() {
            Leg::Episode => PhaseCode::Episode,
            Leg::DwellAtGoal => PhaseCode::DwellAtGoal,
            Leg::ReturningHome => PhaseCode::ReturningHome,
        },
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

    #[test]
    fn a_pause_keeps_its_start_and_the_leg_it_interrupted() {
        let stopped = |plan_id, now_ns| Transition::Stopped { plan_id, now_ns };
        let home = Phase::Episode.next(Transition::ReturnSent { after_stop: false });
        let paused = home.next(stopped(3, 100));
        assert_eq!(
            paused,
            Phase::Paused {
                plan_id: 3,
                since_ns: 100,
                during: Leg::ReturningHome
            }
        );
        assert_eq!(paused.next(stopped(3, 200)), paused);
        assert!(paused.returning());
        assert_eq!(
            phase_code(&paused, &Planning::Due, 0),
            PhaseCode::ReturningHome
        );
        let on = paused.next(Transition::ContinuationSent { plan_id: 4 });
        assert_eq!(on, Phase::Continuing { plan_id: 4 });
        assert_eq!(phase_code(&on, &Planning::Idle, 0), PhaseCode::Episode);
    }

    #[test]
    fn a_retreat_ends_once_and_an_episode_plan_ends_the_backing_out() {
        let out = Phase::Paused {
            plan_id: 3,
            since_ns: 100,
            during: Leg::Episode,
        }
        .next(Transition::BackOutSent { plan_id: 4 });
        assert_eq!(
            out,
            Phase::BackingOut {
                plan_id: 4,
                done: false
            }
        );
        assert_eq!(phase_code(&out, &Planning::Idle, 0), PhaseCode::BackingOut);
        let ended = out.next(Transition::BackedOut);
        assert_eq!(
            ended,
            Phase::BackingOut {
                plan_id: 4,
                done: true
            }
        );
        assert_eq!(phase_code(&ended, &Planning::Idle, 0), PhaseCode::Episode);
        assert_eq!(ended.next(Transition::BackedOut), ended);
        assert_eq!(Phase::Episode.next(Transition::BackedOut), Phase::Episode);
        assert_eq!(ended.next(Transition::EpisodePlanSent), Phase::Episode);
    }

    #[test]
    fn a_stop_on_the_way_out_owes_the_episode_until_home() {
        let mut x = Excursion::default();
        x.next(Transition::ReturnSent { after_stop: true });
        // A joining episode plan takes over the way home: the episode is still owed.
        x.next(Transition::EpisodePlanSent);
        x.next(Transition::ReturnSent { after_stop: false });
        assert!(x.episode_owed());
        assert!(x.arrive_home());
        assert!(!x.arrive_home());
    }
}
