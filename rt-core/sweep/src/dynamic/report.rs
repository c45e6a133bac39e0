//! What a dynamic episode reports: its intruder's onsets (judged avoidable or not), its
//! contacts, the reaction, the goal, and its counters; and the speed bands of the reports.

use std::collections::BTreeMap;

use serde::Serialize;

use super::intruder::{Intruder, IntruderKind};
use crate::oracle::Point;
use crate::sweep::{HardCounts, HardFailure, PolicyKind};

/// The speed bands of the reports, m/s (lower bound inclusive).
pub const SPEED_BANDS: [(f64, f64, &str); 3] = [
    (0.0, 0.5, "0.1-0.5"),
    (0.5, 1.0, "0.5-1.0"),
    (1.0, f64::INFINITY, "1.0-1.6"),
];

/// The band label of `speed_m_s`.
pub fn speed_band(speed_m_s: f64) -> &'static str {
    SPEED_BANDS
        .iter()
        .find(|(lo, hi, _)| speed_m_s >= *lo && speed_m_s < *hi)
        .map_or("1.0-1.6", |b| b.2)
}

/// One moment the intruder starts to threaten (it appears, or moves off after standing),
/// judged at the capture of the first frame that shows it: is it closer to the arm than the
/// arm can stop?
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Onset {
    /// `appears` or `moves_off`.
    pub what: &'static str,
    /// When it happened (ground truth), s.
    pub at_s: f64,
    /// Capture time of the first frame that shows it, s.
    pub capture_s: f64,
    /// Nominal clearance between the arm and the intruder's true box then, m.
    pub distance_m: f64,
    /// The arm's fastest point then, m/s.
    pub arm_speed_m_s: f64,
    /// The intruder's speed then, m/s.
    pub intruder_speed_m_s: f64,
    /// Reaction time: that frame's capture to delivery, plus one period, s.
    pub reaction_s: f64,
    /// The path stop's duration from the arm's joint speeds then
    /// ([`PathStop::duration_s`](rt_core::cycle::brake::PathStop::duration_s) with the cycle's acceleration limits), s.
    pub arm_stop_s: f64,
    /// The stopping distance: the arm's travel during the reaction and its stop
    /// (`v_arm·(T_r + T_s/2)`, the path stop's smoothstep covering half the distance at full
    /// speed) plus the intruder's travel during the reaction *and* the stop
    /// (`v_intruder·(T_r + T_s)`, as ISO/TS 15066's protective separation distance), m.
    pub stopping_distance_m: f64,
    /// The same with the intruder's travel during the reaction only, m.
    pub stopping_distance_reaction_only_m: f64,
    /// `distance_m < stopping_distance_m`.
    pub unavoidable: bool,
    /// Until when a contact counts against this onset: capture + reaction + stop + slack, s.
    pub window_end_s: f64,
}

/// A contact of the arm with the intruder.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Contact {
    /// Its time, s.
    pub at_s: f64,
    /// Depth, m.
    pub depth_m: f64,
    /// A capsule in contact moved with this command (a contact while the arm moves).
    pub moving: bool,
    /// Within the window of an unavoidable onset (or part of a contact that began in one).
    pub unavoidable: bool,
}

/// The reaction to the intruder.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Reaction {
    /// Capture time of the first frame in which the intruder was near the path, s.
    pub near_capture_s: f64,
    /// The cycle that frame was delivered (accepted or refused) in.
    pub near_delivery_cycle: u64,
    /// The first cycle whose command differs from the rehearsal's (the running plan's), if
    /// seen while the rehearsal lasts.
    pub changed_cycle: Option<u64>,
    /// Changed command − near frame's capture, s (negative: changed before it).
    pub from_capture_s: Option<f64>,
    /// Changed command − near frame's delivery, cycles (negative: before it).
    pub from_delivery_cycles: Option<i64>,
}

/// What one dynamic episode did.
#[derive(Debug, Clone, Serialize)]
pub struct DynamicEpisodeReport {
    /// Its index.
    pub episode: u64,
    /// Still worlds drawn until one was reached in rehearsal (0: none was).
    pub world_attempts: u32,
    /// The policy.
    pub policy: PolicyKind,
    /// The intruder's kind.
    pub kind: IntruderKind,
    /// Its speed, m/s.
    pub speed_m_s: f64,
    /// Its size, m.
    pub size_m: Point,
    /// The placed intruder (none: no world was reached in rehearsal).
    pub intruder: Option<Intruder>,
    /// Cycles run (with the intruder).
    pub cycles: u64,
    /// Commands checked.
    pub commands: u64,
    /// The static hard counts (table, static boxes, limits).
    pub hard: HardCounts,
    /// The first hard failures.
    pub failures: Vec<HardFailure>,
    /// The intruder's onsets.
    pub onsets: Vec<Onset>,
    /// Contacts with the intruder (the first pose of each, and the deepest), at most a few.
    pub contacts: Vec<Contact>,
    /// Poses in contact while moving, avoidable.
    pub moving_contact_poses_avoidable: u64,
    /// Poses in contact while moving, within an unavoidable window.
    pub moving_contact_poses_unavoidable: u64,
    /// Poses in contact while moving that would be avoidable if the intruder's travel
    /// counted during the reaction only ([`Onset::stopping_distance_reaction_only_m`]).
    pub moving_contact_poses_avoidable_reaction_only_rule: u64,
    /// Poses in contact at rest.
    pub rest_contact_poses: u64,
    /// Deepest contact while moving, m.
    pub max_moving_depth_m: f64,
    /// Smallest nominal clearance arm–intruder, m (negative: contact depth).
    pub min_separation_m: f64,
    /// The same outside every unavoidable window, poses at rest excluded (moving poses only).
    pub min_separation_avoidable_m: f64,
    /// The reaction, when the intruder came near the path.
    pub reaction: Option<Reaction>,
    /// The cycle the first frame carrying the intruder was delivered in.
    pub first_intruder_frame_cycle: Option<u64>,
    /// The first cycle whose command differs from the rehearsal's (while it lasts).
    pub changed_cycle: Option<u64>,
    /// The rehearsal reached the goal, s.
    pub rehearsal_reach_s: Option<f64>,
    /// This run reached the goal, s.
    pub reach_s: Option<f64>,
    /// The intruder left, or came to rest out of the way, s (none: it stays on the path).
    pub cleared_s: Option<f64>,
    /// The rehearsal's arm started to move, s.
    pub rehearsal_start_s: Option<f64>,
    /// This run's arm started to move, s.
    pub start_s: Option<f64>,
    /// Stops the cycle began in the rehearsal (protective stops of any reason).
    pub rehearsal_stops: u64,
    /// Stops the cycle began in this run.
    pub stops: u64,
    /// rt-core said the goal is infeasible: a box has taken it (`TwinEvent::GoalTaken`, issue
    /// 42 item 4), at any time in the run.
    pub infeasible_reported: bool,
    /// The first "goal taken" said, s after the intruder came to rest (negative: said
    /// while it was still arriving, its box already over the goal; none: never said, or an
    /// intruder that never comes to rest).
    pub infeasible_report_delay_s: Option<f64>,
    /// Counters (frames, events, stops).
    pub counts: BTreeMap<String, u64>,
}

impl DynamicEpisodeReport {
    /// The report of episode `episode` before it ran: its intruder drawn, nothing else.
    pub fn new(episode: u64, kind: IntruderKind, speed_m_s: f64, size_m: Point) -> Self {
        Self {
            episode,
            world_attempts: 0,
            policy: PolicyKind::GoalSeeking,
            kind,
            speed_m_s,
            size_m,
            intruder: None,
            cycles: 0,
            commands: 0,
            hard: HardCounts::default(),
            failures: Vec::new(),
            onsets: Vec::new(),
            contacts: Vec::new(),
            moving_contact_poses_avoidable: 0,
            moving_contact_poses_unavoidable: 0,
            moving_contact_poses_avoidable_reaction_only_rule: 0,
            rest_contact_poses: 0,
            max_moving_depth_m: 0.0,
            min_separation_m: f64::INFINITY,
            min_separation_avoidable_m: f64::INFINITY,
            reaction: None,
            first_intruder_frame_cycle: None,
            changed_cycle: None,
            rehearsal_reach_s: None,
            reach_s: None,
            cleared_s: None,
            rehearsal_start_s: None,
            start_s: None,
            rehearsal_stops: 0,
            stops: 0,
            infeasible_reported: false,
            infeasible_report_delay_s: None,
            counts: BTreeMap::new(),
        }
    }

    /// A contact while moving outside every unavoidable window.
    pub fn avoidable_moving_contact(&self) -> bool {
        self.moving_contact_poses_avoidable > 0
    }

    /// A contact while moving, all of it within unavoidable windows.
    pub fn unavoidable_moving_contact_only(&self) -> bool {
        self.moving_contact_poses_avoidable == 0 && self.moving_contact_poses_unavoidable > 0
    }

    /// Any onset was unavoidable.
    pub fn unavoidable(&self) -> bool {
        self.onsets.iter().any(|o| o.unavoidable)
    }

    /// A contact while moving that would be avoidable under the reaction-only rule.
    pub fn avoidable_moving_contact_reaction_only_rule(&self) -> bool {
        self.moving_contact_poses_avoidable_reaction_only_rule > 0
    }

    /// Reached the goal within `limit_s` of the intruder clearing (none: it never cleared).
    pub fn reached_after_clear(&self, limit_s: f64) -> Option<bool> {
        self.cleared_s
            .map(|c| self.reach_s.is_some_and(|r| r <= c + limit_s))
    }

    /// Reach time lost against the rehearsal, s.
    pub fn time_lost_s(&self) -> Option<f64> {
        Some(self.reach_s? - self.rehearsal_reach_s?)
    }

    /// The intrusion cost no protective stop: the arm moved and the cycle began no more
    /// stops than in the rehearsal.
    pub fn handled_without_stop(&self) -> bool {
        self.start_s.is_some() && self.stops <= self.rehearsal_stops
    }

    /// The start of motion later than the rehearsal's, s (negative: earlier; none: either
    /// did not start).
    pub fn start_delay_s(&self) -> Option<f64> {
        Some(self.start_s? - self.rehearsal_start_s?)
    }
}
