//! The reaction time, measured off the cycle from its log: from the capture (and the
//! acceptance) of the scene that made the running plan unsafe to the cycle's first changed
//! command. Two ways the command changes: the twin (its plan guard) revokes the plan and the
//! cycle begins the stop along it in the period it sees the revocation — the cycle logs the
//! revocation's cause with it ([`CycleEvent::PlanRevoked`]) — or the cycle's own shield
//! refuses the next plan sample against the scene it holds and brakes at once
//! ([`CycleEvent::CommandRefused`] with that scene's capture time; no acceptance time). The
//! log drain feeds every record here (not real-time; it may allocate).

// Shared by the log drain's thread and the twin thread's summary (both non-real-time);
// the cycle never takes this lock (it only writes its log ring).
#![allow(clippy::disallowed_types)]

use std::sync::{Arc, Mutex, PoisonError};

use crate::cycle::shield::ShieldViolation;
use crate::cycle::{CycleEvent, StopReason};
use crate::rt::histogram::Summary;
use crate::rt::rt_log::LogRecord;

/// Most reactions kept (a run of hours keeps its first ones; the count goes on).
const MAX_SAMPLES: usize = 100_000;

/// The reactions of a run.
#[derive(Debug, Default, Clone)]
pub struct ReactionMeter {
    /// The last revocation logged: its time and cause (capture, acceptance), ns.
    last_revoked: Option<(u64, u64, u64)>,
    /// The last clearance refusal logged: its time and its scene's capture, ns.
    last_refused: Option<(u64, u64)>,
    capture_to_command_ns: Vec<u64>,
    accepted_to_command_ns: Vec<u64>,
    /// Reactions seen (also those past [`MAX_SAMPLES`]).
    reactions: u64,
}

/// The meter, shared by the log drain and the run's summary.
#[derive(Debug, Clone, Default)]
pub struct SharedReactionMeter(Arc<Mutex<ReactionMeter>>);

impl SharedReactionMeter {
    /// Takes one record of the cycle's log.
    pub fn observe(&self, r: &LogRecord<CycleEvent>) {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .observe(r);
    }

    /// The percentiles so far and the number of reactions.
    pub fn summary(&self) -> (ReactionSummary, u64) {
        let m = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        (m.summary(), m.reactions())
    }
}

/// A reaction's figures, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ReactionSummary {
    /// Capture of the causing frame → first changed command.
    pub capture_to_command: Summary,
    /// Acceptance of the causing frame (the intake thread handed it to the cycle and the
    /// plan guard) → first changed command.
    pub accepted_to_command: Summary,
}

impl ReactionMeter {
    /// Takes one record of the cycle's log.
    pub fn observe(&mut self, r: &LogRecord<CycleEvent>) {
        match r.event {
            CycleEvent::PlanRevoked {
                capture_ns,
                accepted_ns,
                ..
            } => self.last_revoked = Some((r.t_ns, capture_ns, accepted_ns)),
            CycleEvent::CommandRefused {
                violation: ShieldViolation::Clearance { .. },
                scene_capture_ns,
            } => self.last_refused = Some((r.t_ns, scene_capture_ns)),
            // The shield refused a plan sample for clearance and the cycle brakes.
            CycleEvent::StopBegun {
                reason: StopReason::Shield(ShieldViolation::Clearance { .. }),
            } => {
                if let Some((t, capture_ns)) = self.last_refused.take()
                    && t == r.t_ns
                {
                    self.record(t, capture_ns, 0);
                }
            }
            // The running plan's revocation: logged in the same period as the stop it
            // begins (a pending plan's revocation changes no command and is not followed).
            CycleEvent::StopBegun {
                reason: StopReason::Revoked,
            } => {
                if let Some((t, capture_ns, accepted_ns)) = self.last_revoked.take()
                    && t == r.t_ns
                {
                    self.record(t, capture_ns, accepted_ns);
                }
            }
            _ => {}
        }
    }

    /// One reaction at `t` to a scene captured at `capture_ns` and accepted at
    /// `accepted_ns` (0: not known).
    fn record(&mut self, t: u64, capture_ns: u64, accepted_ns: u64) {
        self.reactions += 1;
        if self.reactions > MAX_SAMPLES as u64 {
            return;
        }
        if capture_ns > 0 && capture_ns <= t {
            self.capture_to_command_ns.push(t - capture_ns);
        }
        if accepted_ns > 0 && accepted_ns <= t {
            self.accepted_to_command_ns.push(t - accepted_ns);
        }
    }

    /// Reactions seen.
    pub fn reactions(&self) -> u64 {
        self.reactions
    }

    /// The percentiles so far.
    pub fn summary(&self) -> ReactionSummary {
        ReactionSummary {
            capture_to_command: summarize(&self.capture_to_command_ns),
            accepted_to_command: summarize(&self.accepted_to_command_ns),
        }
    }
}

/// Exact percentiles (nearest rank) of `samples_ns`, µs.
fn summarize(samples_ns: &[u64]) -> Summary {
    if samples_ns.is_empty() {
        return Summary::default();
    }
    let mut v = samples_ns.to_vec();
    v.sort_unstable();
    let at = |q: f64| {
        let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
        v[rank - 1] as f64 * 1e-3
    };
    Summary {
        count: v.len() as u64,
        p50_us: at(0.5),
        p99_us: at(0.99),
        p999_us: at(0.999),
        max_us: at(1.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(t_ns: u64, event: CycleEvent) -> LogRecord<CycleEvent> {
        LogRecord { t_ns, event }
    }

    #[test]
    fn a_revocation_that_stops_the_arm_is_one_reaction_from_its_frames_capture() {
        let mut m = ReactionMeter::default();
        let revoked = |plan_id, capture_ns, accepted_ns| CycleEvent::PlanRevoked {
            plan_id,
            capture_ns,
            accepted_ns,
        };
        let stop = CycleEvent::StopBegun {
            reason: StopReason::Revoked,
        };
        // A pending plan revoked: no command changed, no reaction.
        m.observe(&rec(5_000_000, revoked(3, 1_000_000, 2_000_000)));
        m.observe(&rec(
            9_000_000,
            CycleEvent::StopBegun {
                reason: StopReason::StaleDetection,
            },
        ));
        assert_eq!(m.reactions(), 0);
        // The running plan revoked 30 ms after the frame's capture, 2 ms after acceptance.
        m.observe(&rec(40_000_000, revoked(4, 10_000_000, 38_000_000)));
        m.observe(&rec(40_000_000, stop));
        // A revocation whose cause is not known (0) counts, without figures.
        m.observe(&rec(50_000_000, revoked(5, 0, 0)));
        m.observe(&rec(50_000_000, stop));
        assert_eq!(m.reactions(), 2);
        let s = m.summary();
        assert_eq!(s.capture_to_command.count, 1);
        assert!(
            (s.capture_to_command.p50_us - 30_000.0).abs() < 1e-6,
            "{s:?}"
        );
        assert!(
            (s.accepted_to_command.max_us - 2_000.0).abs() < 1e-6,
            "{s:?}"
        );
        // A stop logged in a later period than the revocation is not its reaction.
        m.observe(&rec(60_000_000, revoked(6, 55_000_000, 59_000_000)));
        m.observe(&rec(64_000_000, stop));
        assert_eq!(m.reactions(), 2);
        // The cycle's shield refusing a plan sample for clearance: a reaction from the
        // capture of the scene it checked against; a refusal of another kind is not one.
        let clearance = ShieldViolation::Clearance { distance_m: 0.001 };
        for (violation, capture_ns) in [
            (ShieldViolation::JointStep { joint: 1 }, 65_000_000),
            (clearance, 70_000_000),
        ] {
            m.observe(&rec(
                80_000_000,
                CycleEvent::CommandRefused {
                    violation,
                    scene_capture_ns: capture_ns,
                },
            ));
            m.observe(&rec(
                80_000_000,
                CycleEvent::StopBegun {
                    reason: StopReason::Shield(violation),
                },
            ));
        }
        assert_eq!(m.reactions(), 3);
        assert!((m.summary().capture_to_command.max_us - 30_000.0).abs() < 1e-6);
        assert!((m.summary().capture_to_command.p50_us - 10_000.0).abs() < 1e-6);
    }
}
