//! How intrusions ended (issue 42): handled without a protective stop, the start delayed,
//! the goal reached after the intruder left or while it stayed in the way, or said to be
//! infeasible; and the targets over them.

use serde::Serialize;

use super::report::DynamicEpisodeReport;
use super::summary::{GroupFigures, Spread};

/// One episode's outcome, as the groups need it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct OutcomeLine {
    handled_without_stop: bool,
    stayed_in_the_way: bool,
    reached: bool,
    infeasible_reported: bool,
    infeasible_report_delay_s: Option<f64>,
    start_delay_s: Option<f64>,
}

impl OutcomeLine {
    pub(crate) fn of(r: &DynamicEpisodeReport) -> Self {
        Self {
            handled_without_stop: r.handled_without_stop(),
            stayed_in_the_way: r.cleared_s.is_none(),
            reached: r.reach_s.is_some(),
            infeasible_reported: r.infeasible_reported,
            infeasible_report_delay_s: r
                .infeasible_report_delay_s
                .filter(|_| r.cleared_s.is_none()),
            start_delay_s: r.start_delay_s(),
        }
    }
}

/// How a group's intrusions ended.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct OutcomeFigures {
    /// Intrusions during which the arm moved and the cycle began no more stops than without
    /// the intruder.
    pub handled_without_stop: u64,
    /// `handled_without_stop / episodes` (1 when none).
    pub handled_without_stop_fraction: f64,
    /// Intruders that never left nor came to rest out of the way (parked on the path, on
    /// the goal, or beside the rest of the way).
    pub stayed_in_the_way: u64,
    /// Of those, the arm reached its goal anyway (around it).
    pub reached_while_in_the_way: u64,
    /// Of those, rt-core said the goal is infeasible (a box took it: `TwinEvent::GoalTaken`).
    pub infeasible_reported: u64,
    /// Of those reported, the intruder coming to rest → the goal said taken, s (negative:
    /// said while it was still arriving over the goal). Target: ≤ 1 s.
    pub infeasible_report_delay_s: Spread,
    /// Start of motion against the rehearsal's, s (episodes starting in both).
    pub start_delay_s: Spread,
}

impl OutcomeFigures {
    pub(crate) fn of<'l>(lines: impl Iterator<Item = &'l OutcomeLine>) -> Self {
        let mut f = Self::default();
        let (mut n, mut delays, mut said) = (0u64, Vec::new(), Vec::new());
        for l in lines {
            n += 1;
            f.handled_without_stop += u64::from(l.handled_without_stop);
            if l.stayed_in_the_way {
                f.stayed_in_the_way += 1;
                f.reached_while_in_the_way += u64::from(l.reached);
                f.infeasible_reported += u64::from(l.infeasible_reported);
                said.extend(l.infeasible_report_delay_s);
            }
            delays.extend(l.start_delay_s);
        }
        f.handled_without_stop_fraction = if n == 0 {
            1.0
        } else {
            f.handled_without_stop as f64 / n as f64
        };
        f.start_delay_s = Spread::of(delays);
        f.infeasible_report_delay_s = Spread::of(said);
        f
    }
}

/// Issue 42's targets over the grown sweep, as measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MovingWorldTargets {
    /// At least 2 000 intrusions run.
    pub at_least_2000_intrusions: bool,
    /// No avoidable contact while moving for intruders up to 1.0 m/s.
    pub no_avoidable_moving_contact_up_to_1_m_s: bool,
    /// At least 90 % of intrusions handled without a protective stop.
    pub handled_without_stop_at_least_90_percent: bool,
    /// Time lost per intrusion at most 1.0 s at the median.
    pub time_lost_p50_at_most_1_s: bool,
    /// At least 99 % reach the goal after the intruder left.
    pub reach_after_clear_at_least_99_percent: bool,
    /// Every goal said taken within 1 s of its intruder coming to rest on it (true when
    /// none was said).
    pub infeasible_said_within_1_s: bool,
}

impl MovingWorldTargets {
    /// The targets over `all` (`up_to_1`: no avoidable contact while moving up to 1 m/s).
    pub(crate) fn of(all: &GroupFigures, up_to_1: bool) -> Self {
        Self {
            at_least_2000_intrusions: all.episodes >= 2000,
            no_avoidable_moving_contact_up_to_1_m_s: up_to_1,
            handled_without_stop_at_least_90_percent: all.outcome.handled_without_stop_fraction
                >= 0.9,
            time_lost_p50_at_most_1_s: all.time_lost_s.p50 <= 1.0,
            reach_after_clear_at_least_99_percent: all.reach_after_clear_fraction >= 0.99,
            infeasible_said_within_1_s: all.outcome.infeasible_report_delay_s.max <= 1.0,
        }
    }
}
