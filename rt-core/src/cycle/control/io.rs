//! The cycle's hand-overs with the rest of the process: the [`SceneUpdate`]s and plans it
//! takes, the [`CycleControl`] flags it shares (revocation, progress, shutdown,
//! acknowledgement), the two ends [`CycleIo`] (the cycle's) and [`TwinIo`] (the twin's), and
//! [`wire`], which makes them with the cycle's log ring. Everything here is lock-free.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use super::{CycleEvent, CycleReport};
use crate::cycle::plan::Plan;
use crate::rt::handoff::{self, BoxReceiver, BoxSender, LatestReceiver, LatestSender};
use crate::rt::process_stop;
use crate::rt::rt_log::{self, RtLogDrain, RtLogger};

/// The obstacles of a scene seen moving (perception's tracked velocities, issue 33 item 3):
/// what speed and separation monitoring watches ([`crate::cycle::separation`]). A still
/// scene has none: a box standing on the table does not approach the arm, and the plans
/// are verified against it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Intruders {
    /// Bit `i` set: obstacle `i` of the scene is moving.
    pub mask: u32,
    /// The fastest moving obstacle's measured speed, m/s (0 when none).
    pub speed_m_s: f64,
}

impl Intruders {
    /// None moving.
    pub const NONE: Self = Self {
        mask: 0,
        speed_m_s: 0.0,
    };

    /// Every obstacle of a scene moving at an unknown speed (the configured intruder speed
    /// counts): a source that cannot tell still boxes from moving ones.
    pub const ALL_UNKNOWN: Self = Self {
        mask: u32::MAX,
        speed_m_s: 0.0,
    };

    /// Whether any obstacle moves.
    pub fn any(&self) -> bool {
        self.mask != 0
    }
}

/// A scene snapshot handed to the cycle with the capture time of its detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneUpdate<S> {
    /// The scene.
    pub scene: S,
    /// Capture time of the detection, on the cycle's clock, ns.
    pub stamp_ns: u64,
    /// The latest frame was refused: `scene` is the last trusted one (kept for the
    /// shield's clearance while stopping), but it is not fresh — the cycle stops.
    pub refused: bool,
    /// Its obstacles seen moving.
    pub intruders: Intruders,
}

/// Control flags shared by the cycle, the twin thread and the process (relaxed atomics).
#[derive(Debug, Default)]
pub struct CycleControl {
    /// Every plan with an id up to this one is revoked (0 = none).
    revoked_up_to: AtomicU64,
    /// The newest revocation's cause: the capture time of the scene that made it, on the
    /// cycle's clock (0 = not known), ns.
    revoke_capture_ns: AtomicU64,
    /// … and when that scene was accepted (0 = not known), ns.
    revoke_accepted_ns: AtomicU64,
    /// The cycle's adoption and progress in one word, so that no reader can see one new
    /// and the other old (issue 41 item 3; see [`Adoption`]): plan id (upper 40 bits) and
    /// next sample index (lower 24 bits) of the plan the cycle is following, or, with the
    /// index [`NOT_FOLLOWING`], the newest plan id adopted while it follows none (0: none
    /// adopted, not following). Written at adoption and every cycle.
    adoption: AtomicU64,
    /// The newest plan id the cycle has adopted (started from rest or switched to at its
    /// join point): the cycle's own record, which it republishes in [`Self::adoption`]
    /// when it stops following.
    adopted_up_to: AtomicU64,
    /// A controlled stop of the whole process was requested.
    shutdown: Arc<AtomicBool>,
    /// The latched protective stop an operator's acknowledgement names (its
    /// [`CycleReport::latch_seq`](super::CycleReport::latch_seq)), 0 for none: taken (and
    /// zeroed) by the cycle at its next period.
    ack_request: AtomicU64,
    /// The stop latched now, written by the cycle every period: its sequence number (upper
    /// 56 bits) and [`StopReason::code`](super::StopReason::code) (lower 8), 0 when none.
    latched: AtomicU64,
    /// A stop the plan guard scheduled on the running plan (issue 33 item 5): plan id
    /// (upper 40 bits) and the sample index (lower 24 bits) from which the cycle stops
    /// along it unless a joining plan has taken over first; 0 for none.
    stop_due: AtomicU64,
}

/// Bits of the sample index in [`CycleControl`]'s progress word.
const PROGRESS_INDEX_BITS: u32 = 24;

/// The sample index that says "not following" in the adoption word.
const NOT_FOLLOWING: u64 = (1 << PROGRESS_INDEX_BITS) - 1;

/// How the cycle stands with its plans, read in one load ([`CycleControl::adoption`]).
///
/// The cycle adopts a plan, sends its command through the link (which may take a while on
/// a real controller) and then publishes its progress. When adoption and progress were two
/// words, a reader between the two saw "not following" together with "adopted up to the
/// new plan", and the plan guard took a just-adopted plan for one that can no longer move
/// the arm: it went unverified against that frame (issue 41 item 3). In one word a reader
/// sees either the state before the adoption (the plan not adopted: verified whole) or
/// the one after (the plan followed from its first sample: verified from there).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Adoption {
    /// The plan the cycle follows and its next sample (`None` when following none).
    pub following: Option<(u64, usize)>,
    /// The newest plan id adopted (0 for none): at least the followed plan's.
    pub adopted_up_to: u64,
}

impl CycleControl {
    /// Revokes every plan with an id up to `plan_id` (running and pending).
    pub fn revoke_up_to(&self, plan_id: u64) {
        self.revoked_up_to.fetch_max(plan_id, Ordering::AcqRel);
    }

    /// [`CycleControl::revoke_up_to`] because of the scene captured at `capture_ns` and
    /// accepted at `accepted_ns` (the cycle's clock; 0 where not known): the cycle logs the
    /// cause with the revocation it acts on, so the reaction time can be measured off the
    /// cycle ([`crate::twin_thread::reaction`]).
    pub fn revoke_up_to_because(&self, plan_id: u64, capture_ns: u64, accepted_ns: u64) {
        self.revoke_capture_ns.store(capture_ns, Ordering::Release);
        self.revoke_accepted_ns
            .store(accepted_ns, Ordering::Release);
        self.revoke_up_to(plan_id);
    }

    /// The newest revocation's cause: capture and acceptance times of its scene, ns.
    pub fn revoke_cause(&self) -> (u64, u64) {
        (
            self.revoke_capture_ns.load(Ordering::Acquire),
            self.revoke_accepted_ns.load(Ordering::Acquire),
        )
    }

    /// The highest revoked plan id.
    pub fn revoked_up_to(&self) -> u64 {
        self.revoked_up_to.load(Ordering::Acquire)
    }

    /// The cycle's adoption and progress as of one instant (one load; see [`Adoption`]).
    pub fn adoption(&self) -> Adoption {
        let w = self.adoption.load(Ordering::Acquire);
        let (id, index) = (w >> PROGRESS_INDEX_BITS, w & NOT_FOLLOWING);
        if w == 0 || index == NOT_FOLLOWING {
            Adoption {
                following: None,
                adopted_up_to: id,
            }
        } else {
            Adoption {
                following: Some((id, index as usize)),
                adopted_up_to: id,
            }
        }
    }

    /// The newest plan id the cycle has adopted (0 for none); with
    /// [`CycleControl::progress`], read both at once through [`CycleControl::adoption`].
    pub fn adopted_up_to(&self) -> u64 {
        self.adoption().adopted_up_to
    }

    /// Plan `plan_id` adopted: followed from its first sample from now on, published at
    /// once (before the link's send, so a frame read meanwhile verifies it).
    pub(super) fn note_adopted(&self, plan_id: u64) {
        self.adopted_up_to.fetch_max(plan_id, Ordering::AcqRel);
        self.set_progress(plan_id, 0);
    }

    /// The plan the cycle follows and its next sample, as of the last cycle (`None` when
    /// not following).
    pub fn progress(&self) -> Option<(u64, usize)> {
        self.adoption().following
    }

    pub(super) fn set_progress(&self, plan_id: u64, next_index: usize) {
        let index = (next_index as u64).min(NOT_FOLLOWING - 1);
        self.adoption
            .store((plan_id << PROGRESS_INDEX_BITS) | index, Ordering::Release);
    }

    /// Following no plan: publishes the newest plan adopted with the "not following" mark.
    pub(super) fn set_not_following(&self) {
        let adopted = self.adopted_up_to.load(Ordering::Acquire);
        self.adoption.store(
            (adopted << PROGRESS_INDEX_BITS) | NOT_FOLLOWING,
            Ordering::Release,
        );
    }

    /// Schedules a stop of plan `plan_id` once its next sample reaches `index`, instead of
    /// revoking it now: its samples up to the stop envelope's far end from there were
    /// verified clear, and a re-verified plan joining it before then takes over without
    /// stopping. A later call for the same plan only moves the stop earlier; one for
    /// another plan replaces it.
    pub fn schedule_stop(&self, plan_id: u64, index: usize) {
        let index = (index as u64).min((1 << PROGRESS_INDEX_BITS) - 1);
        let word = (plan_id << PROGRESS_INDEX_BITS) | index;
        // Single writer (the plan guard, under its lock); the update keeps the rule in
        // one place all the same.
        let _ = self
            .stop_due
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |old| {
                let same_plan = old != 0 && old >> PROGRESS_INDEX_BITS == plan_id;
                (!same_plan || word < old).then_some(word)
            });
    }

    /// The scheduled stop: plan id and the sample index it stops from (`None`: none).
    pub fn stop_due(&self) -> Option<(u64, usize)> {
        let w = self.stop_due.load(Ordering::Acquire);
        (w != 0).then_some((
            w >> PROGRESS_INDEX_BITS,
            (w & ((1 << PROGRESS_INDEX_BITS) - 1)) as usize,
        ))
    }

    /// Asks for a controlled stop of the whole process: the cycle stops the arm, takes no
    /// plan, and reports `shutdown_complete` once at rest.
    pub fn request_shutdown(&self) {
        self.shutdown.store(true, Ordering::Release);
    }

    /// Whether a shutdown was requested: through [`CycleControl::request_shutdown`] or
    /// the shutdown flag, or process-wide by a signal or a panic
    /// ([`crate::rt::process_stop::stop_requested`]).
    pub fn shutdown_requested(&self) -> bool {
        self.shutdown.load(Ordering::Acquire) || process_stop::stop_requested()
    }

    /// The shutdown flag itself (for signal handlers).
    pub fn shutdown_flag(&self) -> Arc<AtomicBool> {
        self.shutdown.clone()
    }

    /// An operator acknowledges the protective stop number `latch_seq` (controller error,
    /// lost link, …), as named by [`CycleControl::latched`]. The cycle clears that stop and
    /// no other: an acknowledgement naming an earlier or later stop is refused
    /// ([`super::CycleEvent::AcknowledgementRefused`]), one given while the link is down or
    /// the arm still stopping is dropped. Only the operator's channel
    /// ([`crate::operator_ack`]) calls this in `rt-core run`.
    pub fn acknowledge(&self, latch_seq: u64) {
        self.ack_request.store(latch_seq, Ordering::Release);
    }

    /// Acknowledges whatever stop is latched now (tests and the in-process sweep, which
    /// play the operator themselves; `rt-core run` names the stop through
    /// [`crate::operator_ack`]). Does nothing when none is.
    pub fn acknowledge_latched(&self) {
        if let Some((seq, _)) = self.latched() {
            self.acknowledge(seq);
        }
    }

    /// The protective stop latched as of the last cycle: its sequence number and its
    /// [`StopReason::code`](super::StopReason::code); `None` when none is.
    pub fn latched(&self) -> Option<(u64, u8)> {
        let w = self.latched.load(Ordering::Acquire);
        (w != 0).then_some((w >> 8, (w & 0xff) as u8))
    }

    pub(super) fn set_latched(&self, latch: Option<(u64, u8)>) {
        let w = latch.map_or(0, |(seq, code)| (seq << 8) | u64::from(code));
        self.latched.store(w, Ordering::Release);
    }

    /// Takes the pending acknowledgement request (0 for none).
    pub(super) fn take_ack_request(&self) -> u64 {
        self.ack_request.swap(0, Ordering::AcqRel)
    }
}

/// The cycle's ends of the hand-overs.
pub struct CycleIo<S: Copy + Send + 'static> {
    pub(super) plans: BoxReceiver<Plan>,
    pub(super) scenes: LatestReceiver<SceneUpdate<S>>,
    pub(super) control: Arc<CycleControl>,
    pub(super) reports: LatestSender<CycleReport>,
    pub(super) log: RtLogger<CycleEvent>,
}

/// The twin's ends of the hand-overs.
pub struct TwinIo<S: Copy + Send + 'static> {
    /// Approved plans to the cycle (and back, for freeing).
    pub plans: BoxSender<Plan>,
    /// Scene snapshots to the cycle.
    pub scenes: LatestSender<SceneUpdate<S>>,
    /// Revocation, the cycle's progress, shutdown and acknowledgement.
    pub control: Arc<CycleControl>,
    /// The cycle's reports.
    pub reports: LatestReceiver<CycleReport>,
}

/// Makes the hand-overs between a twin worker and a cycle, and the cycle's log ring.
pub fn wire<S: Copy + Send + 'static>() -> (TwinIo<S>, CycleIo<S>, RtLogDrain<CycleEvent>) {
    let (plan_tx, plan_rx) = handoff::channel();
    let (scene_tx, scene_rx) = handoff::latest();
    let (rep_tx, rep_rx) = handoff::latest();
    let (log, drain) = rt_log::ring();
    let control = Arc::new(CycleControl::default());
    (
        TwinIo {
            plans: plan_tx,
            scenes: scene_tx,
            control: control.clone(),
            reports: rep_rx,
        },
        CycleIo {
            plans: plan_rx,
            scenes: scene_rx,
            control,
            reports: rep_tx,
            log,
        },
        drain,
    )
}
