//! The dynamic sweep's tally and summary: contacts while moving (avoidable, unavoidable) and
//! at rest, separations, reaction latency, goals reached after the intruder left, and time
//! lost — overall, per speed band, per kind, and per kind and band.

use std::collections::BTreeMap;

use serde::Serialize;

use super::DynamicSettings;
use super::intruder::IntruderKind;
use super::outcome::{MovingWorldTargets, OutcomeFigures, OutcomeLine};
use super::report::{Contact, DynamicEpisodeReport, Onset, Reaction, SPEED_BANDS, speed_band};
use crate::sweep::{BrakingHorizon, HardCounts, HardFailure, PolicyKind, SweepAssets};
use twin::Joints;

/// Most onset records kept in a summary.
const MAX_ONSET_RECORDS: usize = 5000;

/// Most failures kept in a summary.
const MAX_FAILURES: usize = 50;

/// Most contact examples of each class kept in a summary.
const MAX_EXAMPLES: usize = 12;

/// 50th, 99th percentile and the largest of some samples.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Spread {
    /// Samples.
    pub samples: u64,
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    pub(crate) fn of(mut v: Vec<f64>) -> Self {
        v.sort_by(f64::total_cmp);
        let pct = |q: f64| {
            if v.is_empty() {
                0.0
            } else {
                v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1]
            }
        };
        Self {
            samples: v.len() as u64,
            p50: pct(0.5),
            p90: pct(0.9),
            p99: pct(0.99),
            max: v.last().copied().unwrap_or(0.0),
        }
    }
}

/// The reaction to intruders near the path.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ReactionFigures {
    /// Episodes whose intruder came near the rest of the arm's path.
    pub near_path: u64,
    /// Of those, the command changed (a latency sample).
    pub changed: u64,
    /// Of those, changed before the near frame was delivered (reacting to an earlier frame,
    /// e.g. the predicted occupancy of a moving intruder).
    pub anticipated: u64,
    /// Near, but no change seen while the rehearsal lasted.
    pub unchanged: u64,
    /// Near frame's delivery (acceptance) → changed command, cycles, the anticipated ones
    /// counted as 0 (the target: at most 1 at p99).
    pub from_delivery_cycles: Spread,
    /// The same without the anticipated ones, cycles.
    pub reactive_from_delivery_cycles: Spread,
    /// Near frame's capture → changed command without the anticipated ones, ms (the
    /// frame's way to the intake included).
    pub reactive_from_capture_ms: Spread,
}

/// The figures of a group of episodes.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct GroupFigures {
    /// Episodes run with an intruder.
    pub episodes: u64,
    /// Of those, with an unavoidable onset.
    pub unavoidable_intrusions: u64,
    /// Episodes with a contact while the arm moved.
    pub contacts_while_moving: u64,
    /// Of those, with an avoidable contact (failures).
    pub contacts_while_moving_avoidable: u64,
    /// Of those, every contact within an unavoidable window.
    pub contacts_while_moving_unavoidable: u64,
    /// Episodes with a contact while moving that would be avoidable if the intruder's travel
    /// counted during the reaction only (not during the stop as well).
    pub contacts_while_moving_avoidable_reaction_only_rule: u64,
    /// Episodes with an onset unavoidable by the reaction-only rule.
    pub unavoidable_intrusions_reaction_only_rule: u64,
    /// Episodes where the intruder walked into the arm at rest.
    pub contacts_at_rest: u64,
    /// Smallest clearance arm–intruder over every pose, m (negative: contact depth).
    pub min_separation_m: f64,
    /// The same over moving poses outside unavoidable windows, m.
    pub min_separation_avoidable_m: f64,
    /// Episodes whose intruder left (or came to rest out of the way).
    pub intruder_cleared: u64,
    /// Of those, the arm reached its goal within the limit after it.
    pub reached_after_clear: u64,
    /// `reached_after_clear / intruder_cleared` (1 when none).
    pub reach_after_clear_fraction: f64,
    /// Reaction to intruders near the path.
    pub reaction: ReactionFigures,
    /// Reach time lost against the rehearsal (episodes reaching in both), s.
    pub time_lost_s: Spread,
    /// How the intrusions ended: without a stop, the start delayed, the goal while the
    /// intruder stayed in the way.
    pub outcome: OutcomeFigures,
}

/// The speed up to which no avoidable contact while moving happened.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Envelope {
    /// The slowest intruder with an avoidable contact while moving, m/s (none: none had).
    pub slowest_avoidable_contact_m_s: Option<f64>,
    /// No avoidable contact while moving for intruders below this, m/s (the fastest drawn
    /// when none had).
    pub zero_avoidable_contacts_below_m_s: f64,
}

/// The targets, as measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Targets {
    /// No contact while moving (avoidable) for intruders up to 1.0 m/s.
    pub no_avoidable_moving_contact_up_to_1_m_s: bool,
    /// At least 95 % reach the goal after the intruder left.
    pub reach_after_clear_at_least_95_percent: bool,
    /// Accepted frame → changed command within 1 cycle at p99.
    pub reaction_p99_at_most_1_cycle: bool,
}

/// An episode whose taken goal was said more than 1 s after its box came to rest (issue 42
/// item 4's target), for debugging.
#[derive(Debug, Clone, Serialize)]
pub struct LateInfeasibleExample {
    /// The episode.
    pub episode: u64,
    /// How to replay it.
    pub replay: String,
    /// The intruder.
    pub kind: IntruderKind,
    /// The box coming to rest → the goal said taken, s.
    pub delay_s: f64,
    /// Protective stops the cycle began in the run.
    pub stops: u64,
    /// Retreats the worker began (`TwinEvent::BackingOut`).
    pub backing_out: u64,
}

/// An episode with a contact, for debugging.
#[derive(Debug, Clone, Serialize)]
pub struct ContactExample {
    /// The episode.
    pub episode: u64,
    /// How to replay it.
    pub replay: String,
    /// The intruder.
    pub kind: IntruderKind,
    /// Its speed, m/s.
    pub speed_m_s: f64,
    /// Its size, m.
    pub size_m: [f64; 3],
    /// The policy.
    pub policy: PolicyKind,
    /// It appeared, s.
    pub appear_s: f64,
    /// Its target point, and when the rehearsal's arm was there, s.
    pub target_m: [f64; 3],
    /// When the rehearsal's arm was at the target point, s.
    pub target_arm_s: f64,
    /// The first contact (while moving when there is one).
    pub contact: Contact,
    /// The last onset before it.
    pub onset: Option<Onset>,
    /// The reaction.
    pub reaction: Option<Reaction>,
}

/// One onset with its episode, for the summary's list.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OnsetRecord {
    /// The episode.
    pub episode: u64,
    /// The intruder's kind.
    pub kind: IntruderKind,
    /// Its speed, m/s.
    pub speed_m_s: f64,
    /// The onset.
    pub onset: Onset,
    /// The episode had a contact while moving.
    pub contact_while_moving: bool,
}

/// The cycle's brake limits the stopping distances come from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BrakeFigures {
    /// Joint velocity limits, rad/s.
    pub max_velocity_rad_s: Joints,
    /// Joint acceleration limits (the path stop uses 80 %), rad/s².
    pub max_acceleration_rad_s2: Joints,
    /// Joint jerk limits (the per-joint brake), rad/s³.
    pub max_jerk_rad_s3: Joints,
    /// The stop from the velocity limit.
    pub braking_horizon: BrakingHorizon,
}

/// The dynamic sweep's figures.
#[derive(Debug, Clone, Serialize)]
pub struct DynamicSummary {
    /// The settings.
    pub settings: DynamicSettings,
    /// Episodes.
    pub episodes: u64,
    /// Of those, run with an intruder.
    pub episodes_run: u64,
    /// Episodes none of whose still worlds was reached in rehearsal (not run).
    pub episodes_without_a_reached_world: u64,
    /// Still worlds drawn again because the rehearsal did not reach the goal.
    pub world_redraws: u64,
    /// Cycles run with intruders.
    pub cycles: u64,
    /// Commands checked.
    pub commands_checked: u64,
    /// The brake limits.
    pub brake: BrakeFigures,
    /// The static hard counts (table, still boxes, limits): must be 0.
    pub hard: HardCounts,
    /// The first hard failures.
    pub failures: Vec<HardFailure>,
    /// All episodes.
    pub all: GroupFigures,
    /// Per speed band.
    pub by_speed_band: BTreeMap<String, GroupFigures>,
    /// Per kind.
    pub by_kind: BTreeMap<String, GroupFigures>,
    /// Per kind and speed band (`kind/band`).
    pub by_kind_and_band: BTreeMap<String, GroupFigures>,
    /// Where 0 avoidable contacts while moving holds, overall and per kind.
    pub envelope: Envelope,
    /// The same per kind.
    pub envelope_by_kind: BTreeMap<String, Envelope>,
    /// The targets.
    pub targets: Targets,
    /// Issue 42's targets.
    pub moving_world_targets: MovingWorldTargets,
    /// Episodes with an avoidable contact while moving (the first few).
    pub avoidable_contact_examples: Vec<ContactExample>,
    /// Episodes with an unavoidable contact while moving (the first few).
    pub unavoidable_contact_examples: Vec<ContactExample>,
    /// Episodes whose taken goal was said more than 1 s after its box came to rest (the
    /// first few).
    pub late_infeasible_examples: Vec<LateInfeasibleExample>,
    /// The onsets (the first few thousand), by episode.
    pub onsets: Vec<OnsetRecord>,
    /// Named counters summed over the episodes.
    pub counts: BTreeMap<String, u64>,
    /// Why the bundled policy was not used, if it was not.
    pub bundled_problem: Option<String>,
    /// Wall time, s.
    pub wall_s: f64,
    /// Episodes per second.
    pub episodes_per_s: f64,
}

impl DynamicSummary {
    /// Avoidable contacts while moving plus the static hard counts: 0 or a failed sweep.
    pub fn failures_total(&self) -> u64 {
        self.all.contacts_while_moving_avoidable + self.hard.total()
    }
}

/// One episode, as the groups need it.
#[derive(Debug, Clone, Copy)]
struct Line {
    episode: u64,
    kind: IntruderKind,
    speed_m_s: f64,
    unavoidable: bool,
    moving_avoidable: bool,
    moving_unavoidable_only: bool,
    moving_avoidable_narrow: bool,
    unavoidable_narrow: bool,
    at_rest: bool,
    min_separation_m: f64,
    min_separation_avoidable_m: f64,
    cleared: bool,
    reached_after_clear: bool,
    near: bool,
    /// (capture → change s, delivery → change cycles).
    reaction: Option<(f64, i64)>,
    time_lost_s: Option<f64>,
    outcome: OutcomeLine,
}

/// Sums dynamic episode reports (independent of their order).
#[derive(Debug, Clone)]
pub struct DynamicTally {
    settings: DynamicSettings,
    horizon: BrakingHorizon,
    episodes: u64,
    without_world: u64,
    redraws: u64,
    cycles: u64,
    commands: u64,
    hard: HardCounts,
    failures: Vec<HardFailure>,
    lines: Vec<Line>,
    avoidable_examples: Vec<ContactExample>,
    unavoidable_examples: Vec<ContactExample>,
    late_infeasible: Vec<LateInfeasibleExample>,
    onsets: Vec<OnsetRecord>,
    counts: BTreeMap<String, u64>,
}

fn example(r: &DynamicEpisodeReport, settings: &DynamicSettings) -> Option<ContactExample> {
    let i = r.intruder?;
    let contact = r
        .contacts
        .iter()
        .find(|c| c.moving)
        .or(r.contacts.first())
        .copied()?;
    Some(ContactExample {
        episode: r.episode,
        replay: format!(
            "sweep --dynamic --seed {} --first-episode {} --episodes 1",
            settings.seed, r.episode
        ),
        kind: r.kind,
        speed_m_s: r.speed_m_s,
        size_m: r.size_m,
        policy: r.policy,
        appear_s: i.appear_s,
        target_m: i.target_m,
        target_arm_s: i.target_arm_s,
        contact,
        onset: r
            .onsets
            .iter()
            .rev()
            .find(|o| o.at_s <= contact.at_s)
            .copied(),
        reaction: r.reaction,
    })
}

impl DynamicTally {
    /// An empty tally.
    pub fn new(settings: DynamicSettings, horizon: BrakingHorizon) -> Self {
        Self {
            settings,
            horizon,
            episodes: 0,
            without_world: 0,
            redraws: 0,
            cycles: 0,
            commands: 0,
            hard: HardCounts::default(),
            failures: Vec::new(),
            lines: Vec::new(),
            avoidable_examples: Vec::new(),
            unavoidable_examples: Vec::new(),
            late_infeasible: Vec::new(),
            onsets: Vec::new(),
            counts: BTreeMap::new(),
        }
    }

    /// Adds one episode.
    pub fn add(&mut self, r: &DynamicEpisodeReport) {
        self.episodes += 1;
        if r.intruder.is_none() {
            self.without_world += 1;
            return;
        }
        self.redraws += u64::from(r.world_attempts.saturating_sub(1));
        self.cycles += r.cycles;
        self.commands += r.commands;
        self.hard.add(&r.hard);
        self.failures.extend_from_slice(&r.failures);
        for (k, v) in &r.counts {
            *self.counts.entry(k.clone()).or_insert(0) += v;
        }
        let limit = self.settings.reach_limit_s;
        let reached = r.reached_after_clear(limit);
        let line = Line {
            episode: r.episode,
            kind: r.kind,
            speed_m_s: r.speed_m_s,
            unavoidable: r.unavoidable(),
            moving_avoidable: r.avoidable_moving_contact(),
            moving_unavoidable_only: r.unavoidable_moving_contact_only(),
            moving_avoidable_narrow: r.avoidable_moving_contact_reaction_only_rule(),
            unavoidable_narrow: r
                .onsets
                .iter()
                .any(|o| o.distance_m < o.stopping_distance_reaction_only_m),
            at_rest: r.rest_contact_poses > 0,
            min_separation_m: r.min_separation_m,
            min_separation_avoidable_m: r.min_separation_avoidable_m,
            cleared: reached.is_some(),
            reached_after_clear: reached == Some(true),
            near: r.reaction.is_some(),
            reaction: r
                .reaction
                .and_then(|x| Some((x.from_capture_s?, x.from_delivery_cycles?))),
            time_lost_s: r.time_lost_s(),
            outcome: OutcomeLine::of(r),
        };
        self.lines.push(line);
        if line.moving_avoidable {
            self.avoidable_examples.extend(example(r, &self.settings));
        } else if line.moving_unavoidable_only {
            self.unavoidable_examples.extend(example(r, &self.settings));
        }
        if let Some(delay_s) = r.infeasible_report_delay_s.filter(|d| *d > 1.0) {
            self.late_infeasible.push(LateInfeasibleExample {
                episode: r.episode,
                replay: format!(
                    "sweep --dynamic --seed {} --first-episode {} --episodes 1",
                    self.settings.seed, r.episode
                ),
                kind: r.kind,
                delay_s,
                stops: r.stops,
                backing_out: r.counts.get("twin_backing_out").copied().unwrap_or(0),
            });
        }
        for o in &r.onsets {
            self.onsets.push(OnsetRecord {
                episode: r.episode,
                kind: r.kind,
                speed_m_s: r.speed_m_s,
                onset: *o,
                contact_while_moving: line.moving_avoidable || line.moving_unavoidable_only,
            });
        }
    }

    /// Episodes so far.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// Episodes with an avoidable contact while moving so far.
    pub fn avoidable_moving_contacts(&self) -> u64 {
        self.lines.iter().filter(|l| l.moving_avoidable).count() as u64
    }

    /// Episodes with an unavoidable contact while moving so far.
    pub fn unavoidable_moving_contacts(&self) -> u64 {
        self.lines
            .iter()
            .filter(|l| l.moving_unavoidable_only)
            .count() as u64
    }

    /// The static hard counts so far.
    pub fn hard(&self) -> &HardCounts {
        &self.hard
    }

    fn group<'l>(lines: impl Iterator<Item = &'l Line> + Clone) -> GroupFigures {
        let mut g = GroupFigures {
            min_separation_m: f64::INFINITY,
            min_separation_avoidable_m: f64::INFINITY,
            outcome: OutcomeFigures::of(lines.clone().map(|l| &l.outcome)),
            ..GroupFigures::default()
        };
        let (mut capture_ms, mut cycles, mut reactive, mut lost) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for l in lines {
            g.episodes += 1;
            g.unavoidable_intrusions += u64::from(l.unavoidable);
            g.contacts_while_moving_avoidable += u64::from(l.moving_avoidable);
            g.contacts_while_moving_unavoidable += u64::from(l.moving_unavoidable_only);
            g.contacts_at_rest += u64::from(l.at_rest);
            g.contacts_while_moving_avoidable_reaction_only_rule +=
                u64::from(l.moving_avoidable_narrow);
            g.unavoidable_intrusions_reaction_only_rule += u64::from(l.unavoidable_narrow);
            g.min_separation_m = g.min_separation_m.min(l.min_separation_m);
            g.min_separation_avoidable_m = g
                .min_separation_avoidable_m
                .min(l.min_separation_avoidable_m);
            g.intruder_cleared += u64::from(l.cleared);
            g.reached_after_clear += u64::from(l.reached_after_clear);
            if l.near {
                g.reaction.near_path += 1;
                match l.reaction {
                    Some((s, c)) => {
                        g.reaction.changed += 1;
                        if c < 0 {
                            g.reaction.anticipated += 1;
                        } else {
                            reactive.push(c as f64);
                            capture_ms.push(s * 1e3);
                        }
                        cycles.push(c.max(0) as f64);
                    }
                    None => g.reaction.unchanged += 1,
                }
            }
            lost.extend(l.time_lost_s);
        }
        g.contacts_while_moving =
            g.contacts_while_moving_avoidable + g.contacts_while_moving_unavoidable;
        g.reach_after_clear_fraction = if g.intruder_cleared == 0 {
            1.0
        } else {
            g.reached_after_clear as f64 / g.intruder_cleared as f64
        };
        g.reaction.reactive_from_capture_ms = Spread::of(capture_ms);
        g.reaction.from_delivery_cycles = Spread::of(cycles);
        g.reaction.reactive_from_delivery_cycles = Spread::of(reactive);
        g.time_lost_s = Spread::of(lost);
        g
    }

    fn envelope<'l>(lines: impl Iterator<Item = &'l Line> + Clone) -> Envelope {
        let slowest = lines
            .clone()
            .filter(|l| l.moving_avoidable)
            .map(|l| l.speed_m_s)
            .fold(None, |m: Option<f64>, s| Some(m.map_or(s, |m| m.min(s))));
        let fastest = lines.map(|l| l.speed_m_s).fold(0.0, f64::max);
        Envelope {
            slowest_avoidable_contact_m_s: slowest,
            zero_avoidable_contacts_below_m_s: slowest.unwrap_or(fastest),
        }
    }

    /// The summary (`assets` for the brake limits and the bundled policy's state).
    pub fn summary(&self, assets: &SweepAssets, wall_s: f64) -> DynamicSummary {
        let mut lines = self.lines.clone();
        lines.sort_by_key(|l| l.episode);
        let all = Self::group(lines.iter());
        let mut by_speed_band = BTreeMap::new();
        let mut by_kind = BTreeMap::new();
        let mut by_kind_and_band = BTreeMap::new();
        let mut envelope_by_kind = BTreeMap::new();
        for (_, _, band) in SPEED_BANDS {
            let in_band = |l: &&Line| speed_band(l.speed_m_s) == band;
            by_speed_band.insert(band.to_owned(), Self::group(lines.iter().filter(in_band)));
            for kind in self.settings.kinds.kinds() {
                by_kind_and_band.insert(
                    format!("{}/{band}", kind.name()),
                    Self::group(lines.iter().filter(in_band).filter(|l| l.kind == kind)),
                );
            }
        }
        for kind in self.settings.kinds.kinds() {
            let of_kind = |l: &&Line| l.kind == kind;
            by_kind.insert(
                kind.name().to_owned(),
                Self::group(lines.iter().filter(of_kind)),
            );
            envelope_by_kind.insert(
                kind.name().to_owned(),
                Self::envelope(lines.iter().filter(of_kind)),
            );
        }
        let envelope = Self::envelope(lines.iter());
        let up_to_1 = lines
            .iter()
            .filter(|l| l.speed_m_s <= 1.0)
            .all(|l| !l.moving_avoidable);
        let targets = Targets {
            no_avoidable_moving_contact_up_to_1_m_s: up_to_1,
            reach_after_clear_at_least_95_percent: all.reach_after_clear_fraction >= 0.95,
            reaction_p99_at_most_1_cycle: all.reaction.from_delivery_cycles.p99 <= 1.0,
        };
        let moving_world_targets = MovingWorldTargets::of(&all, up_to_1);
        let sorted = |v: &[ContactExample]| {
            let mut v = v.to_vec();
            v.sort_by_key(|e| e.episode);
            v.truncate(MAX_EXAMPLES);
            v
        };
        let mut onsets = self.onsets.clone();
        onsets.sort_by(|a, b| {
            a.episode
                .cmp(&b.episode)
                .then(a.onset.at_s.total_cmp(&b.onset.at_s))
        });
        onsets.truncate(MAX_ONSET_RECORDS);
        let mut failures = self.failures.clone();
        failures.sort_by_key(|f| (f.episode, f.cycle));
        failures.truncate(MAX_FAILURES);
        let l = &assets.cfg.limits;
        DynamicSummary {
            settings: self.settings,
            episodes: self.episodes,
            episodes_run: self.lines.len() as u64,
            episodes_without_a_reached_world: self.without_world,
            world_redraws: self.redraws,
            cycles: self.cycles,
            commands_checked: self.commands,
            brake: BrakeFigures {
                max_velocity_rad_s: l.max_velocity_rad_s,
                max_acceleration_rad_s2: l.max_acceleration_rad_s2,
                max_jerk_rad_s3: l.max_jerk_rad_s3,
                braking_horizon: self.horizon,
            },
            hard: self.hard,
            failures,
            all,
            by_speed_band,
            by_kind,
            by_kind_and_band,
            envelope,
            envelope_by_kind,
            targets,
            moving_world_targets,
            avoidable_contact_examples: sorted(&self.avoidable_examples),
            unavoidable_contact_examples: sorted(&self.unavoidable_examples),
            late_infeasible_examples: {
                let mut v = self.late_infeasible.clone();
                v.sort_by_key(|e| e.episode);
                v.truncate(MAX_EXAMPLES);
                v
            },
            onsets,
            counts: self.counts.clone(),
            bundled_problem: assets.bundled_problem.map(|b| format!("{b:?}")),
            wall_s,
            episodes_per_s: if wall_s > 0.0 {
                self.episodes as f64 / wall_s
            } else {
                0.0
            },
        }
    }
}
