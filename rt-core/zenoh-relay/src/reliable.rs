//! Delivery rules on top of Zenoh, kept free of I/O so they are tested on their own.
//!
//! A network drops, delays and repeats messages, and either host can restart. Zenoh's
//! reliable TCP link covers a healthy connection; these rules cover the rest:
//!
//! - [`RequestOutbox`] (controller side): the latest retrain request is re-sent every
//!   [`RESEND_INTERVAL`] of silence until the learner answers it for good (a `Published`,
//!   `BudgetExhausted` or `Infeasible` progress for it) or a newer request supersedes it.
//!   Progress counts only when the learner relay bound it to this very request (its id *and*
//!   its time, [`RequestRef`]): a late answer to an older request, or to an earlier rt-core's
//!   request with the same id, is not forwarded and cannot end the current one.
//! - [`RequestInbox`] (learner side): a request is handed to the local learner once; a repeat
//!   is answered with the final progress when there is one (so a lost answer is recovered)
//!   and otherwise dropped; an older request of the same controller is dropped.
//! - [`PolicyOutbox`] (learner side): the latest policy is re-sent until the controller
//!   acknowledges it (a newer policy replaces it), after 1, 2, 4, then every 8 s of silence.
//! - [`PolicyInbox`] (controller side): a policy is handed to rt-core once; a repeat is only
//!   acknowledged again (one that could not be published is not acknowledged, so it comes again).
//! - [`SequenceGuard`] (both sides): a message is accepted only with a sequence above the
//!   last one accepted on its channel (replays and reordered old messages are refused).

use std::time::{Duration, Instant};

use std::collections::BTreeMap;

use shm_schemas::{RetrainPhase, RetrainProgress, RetrainRequest};

use crate::wire::{Channel, RequestRef};

/// Silence after which an unanswered message is sent again.
pub const RESEND_INTERVAL: Duration = Duration::from_secs(1);

/// The longest silence between two re-sends of a policy: its interval doubles from
/// [`RESEND_INTERVAL`] up to this. A policy is large (≈ 330 kB) and a cut link delivers what
/// was sent into it in a burst when it returns: at one copy a second, a 5 s cut overflowed
/// the controller side's policy queue (`relay::queue_len`, 4) and the surplus copy was
/// counted as a flood.
pub const MAX_POLICY_RESEND_INTERVAL: Duration = Duration::from_secs(8);

/// Whether a progress message is a final answer to its request.
pub fn is_final(p: &RetrainProgress) -> bool {
    p.phase().is_ok_and(RetrainPhase::is_final)
}

/// The controller side's retrain request in flight.
#[derive(Debug, Clone)]
pub struct RequestOutbox {
    pending: Option<Pending>,
    /// Requests re-sent (all requests).
    pub resends: u64,
}

#[derive(Debug, Clone)]
struct Pending {
    request: RetrainRequest,
    /// The last time anything was heard about it or it was sent.
    last_activity: Instant,
    answered: bool,
}

/// What to do with a progress message that came over the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressAction {
    /// Publish it locally (it is about the current request).
    Forward {
        /// It is the final answer of the current request.
        answered: bool,
    },
    /// It is about an older request (a late or repeated message): dropped.
    Stale,
}

impl Default for RequestOutbox {
    fn default() -> Self {
        Self::new()
    }
}

impl RequestOutbox {
    /// Nothing in flight.
    pub fn new() -> Self {
        Self {
            pending: None,
            resends: 0,
        }
    }

    /// A new local request: it supersedes any in flight. Send it now.
    pub fn submit(&mut self, request: RetrainRequest, now: Instant) {
        self.pending = Some(Pending {
            request,
            last_activity: now,
            answered: false,
        });
    }

    /// The request in flight (answered or not).
    pub fn current(&self) -> Option<&RetrainRequest> {
        self.pending.as_ref().map(|p| &p.request)
    }

    /// Whether the request in flight has its final answer.
    pub fn answered(&self) -> bool {
        self.pending.as_ref().is_some_and(|p| p.answered)
    }

    /// A progress message from the learner host, bound by the learner relay to request
    /// `bound` (the signed header's [`RequestRef`]).
    pub fn on_progress(
        &mut self,
        p: &RetrainProgress,
        bound: RequestRef,
        now: Instant,
    ) -> ProgressAction {
        let Some(pending) = self.pending.as_mut() else {
            // No request from this process yet: a learner host reporting on an earlier
            // controller's request. Nothing here is waiting for it.
            return ProgressAction::Stale;
        };
        // Ids are per rt-core process: the same id of an earlier rt-core, or an older or
        // newer id, is not ours. The request time tells them apart.
        if bound != RequestRef::of(&pending.request) || p.request_id != bound.request_id {
            return ProgressAction::Stale;
        }
        pending.last_activity = now;
        let answered = is_final(p);
        if answered {
            pending.answered = true;
        }
        ProgressAction::Forward { answered }
    }

    /// The request to send again now, if it is unanswered and has been silent for
    /// [`RESEND_INTERVAL`].
    pub fn due(&mut self, now: Instant) -> Option<RetrainRequest> {
        let p = self.pending.as_mut()?;
        if p.answered || now.duration_since(p.last_activity) < RESEND_INTERVAL {
            return None;
        }
        p.last_activity = now;
        self.resends += 1;
        Some(p.request)
    }
}

/// The learner side's record of requests handed to the local learner.
#[derive(Debug, Clone, Default)]
pub struct RequestInbox {
    /// (controller relay instance, request id, request time) of the last request handed on.
    last: Option<(u64, u64, u64)>,
    /// The final progress of that request, once the learner gave it.
    final_progress: Option<RetrainProgress>,
    /// Repeats and stale requests dropped.
    pub dropped: u64,
}

/// What to do with a request that came over the link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RequestAction {
    /// New: publish it to the local learner.
    Forward,
    /// A repeat of a request already answered: send this final progress back again.
    Reanswer(RetrainProgress),
    /// A repeat of the request in training, or an older one: dropped.
    Drop,
}

impl RequestInbox {
    /// A request from `sender_instance` (the controller relay's instance).
    pub fn on_request(&mut self, sender_instance: u64, r: &RetrainRequest) -> RequestAction {
        let key = (sender_instance, r.request_id, r.request_time_ns);
        match self.last {
            Some(last) if last == key => {
                self.dropped += 1;
                self.final_progress
                    .map_or(RequestAction::Drop, RequestAction::Reanswer)
            }
            Some((inst, id, _)) if inst == sender_instance && r.request_id < id => {
                self.dropped += 1;
                RequestAction::Drop
            }
            _ => {
                self.last = Some(key);
                self.final_progress = None;
                RequestAction::Forward
            }
        }
    }

    /// The request a progress message of the local learner is about: the one handed on
    /// when the ids match (time 0 otherwise: the robot side will not take it as an answer).
    pub fn binding(&self, request_id: u64) -> RequestRef {
        match self.last {
            Some((_, id, t)) if id == request_id => RequestRef {
                request_id,
                request_time_ns: t,
            },
            _ => RequestRef {
                request_id,
                request_time_ns: 0,
            },
        }
    }

    /// The request last handed to the local learner (a policy it publishes answers it).
    pub fn current(&self) -> RequestRef {
        self.last
            .map(|(_, id, t)| RequestRef {
                request_id: id,
                request_time_ns: t,
            })
            .unwrap_or_default()
    }

    /// Progress from the local learner (remembered when final for the current request).
    pub fn on_local_progress(&mut self, p: &RetrainProgress) {
        if is_final(p) && self.last.is_some_and(|(_, id, _)| id == p.request_id) {
            self.final_progress = Some(*p);
        }
    }
}

/// The learner side's policy awaiting acknowledgement, by id and checksum.
#[derive(Debug, Clone, Default)]
pub struct PolicyOutbox {
    /// Policy id, checksum, last sent, silence before the next re-send.
    pending: Option<(u64, u64, Instant, Duration)>,
    /// Policies re-sent.
    pub resends: u64,
}

impl PolicyOutbox {
    /// A new local policy (sent now); replaces any unacknowledged one.
    pub fn submit(&mut self, policy_id: u64, checksum: u64, now: Instant) {
        self.pending = Some((policy_id, checksum, now, RESEND_INTERVAL));
    }

    /// An acknowledgement from the controller; true when it was for the pending policy.
    pub fn on_ack(&mut self, policy_id: u64, checksum: u64) -> bool {
        if self
            .pending
            .is_some_and(|(id, sum, _, _)| id == policy_id && sum == checksum)
        {
            self.pending = None;
            true
        } else {
            false
        }
    }

    /// Whether the pending policy is due for a re-send (and marks it sent; the next one
    /// waits twice as long, up to [`MAX_POLICY_RESEND_INTERVAL`]).
    pub fn due(&mut self, now: Instant) -> bool {
        match self.pending.as_mut() {
            Some((_, _, sent, interval)) if now.duration_since(*sent) >= *interval => {
                *sent = now;
                *interval = (*interval * 2).min(MAX_POLICY_RESEND_INTERVAL);
                self.resends += 1;
                true
            }
            _ => false,
        }
    }

    /// Whether a policy is waiting for its acknowledgement.
    pub fn waiting(&self) -> bool {
        self.pending.is_some()
    }
}

/// The controller side's record of the policy last handed to rt-core.
#[derive(Debug, Clone, Default)]
pub struct PolicyInbox {
    last: Option<(u64, u64)>,
}

impl PolicyInbox {
    /// Whether a valid policy that arrived is not the one last handed on (a repeat is only
    /// acknowledged again).
    pub fn is_new(&self, policy_id: u64, checksum: u64) -> bool {
        self.last != Some((policy_id, checksum))
    }

    /// The policy was published to rt-core.
    pub fn delivered(&mut self, policy_id: u64, checksum: u64) {
        self.last = Some((policy_id, checksum));
    }
}

/// The highest sequence accepted per channel from the other host's key.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SequenceGuard {
    seen: BTreeMap<Channel, u64>,
}

impl SequenceGuard {
    /// From marks remembered across a restart (by channel key suffix).
    pub fn from_marks(marks: &BTreeMap<String, u64>) -> Self {
        let seen = Channel::ALL
            .into_iter()
            .filter_map(|c| marks.get(c.key_suffix()).map(|s| (c, *s)))
            .collect();
        Self { seen }
    }

    /// The marks to remember (by channel key suffix).
    pub fn marks(&self) -> BTreeMap<String, u64> {
        self.seen
            .iter()
            .map(|(c, s)| (c.key_suffix().to_owned(), *s))
            .collect()
    }

    /// Accepts `sequence` on `channel` when it is above the last accepted (and remembers
    /// it); `Err(last)` for a replay or an older message.
    ///
    /// # Errors
    /// The last accepted sequence, which this one does not exceed.
    pub fn accept(&mut self, channel: Channel, sequence: u64) -> Result<(), u64> {
        let last = self.seen.entry(channel).or_default();
        if sequence <= *last {
            return Err(*last);
        }
        *last = sequence;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(id: u64, t: u64) -> RetrainRequest {
        RetrainRequest {
            request_id: id,
            request_time_ns: t,
            ..RetrainRequest::default()
        }
    }

    fn at(request_id: u64, request_time_ns: u64) -> RequestRef {
        RequestRef {
            request_id,
            request_time_ns,
        }
    }

    fn progress(id: u64, phase: RetrainPhase) -> RetrainProgress {
        RetrainProgress {
            request_id: id,
            phase: phase as u8,
            ..RetrainProgress::default()
        }
    }

    #[test]
    fn a_request_is_resent_after_silence_until_its_final_answer() {
        let t0 = Instant::now();
        let mut out = RequestOutbox::new();
        assert_eq!(out.due(t0), None, "nothing in flight");
        out.submit(request(1, 100), t0);
        assert_eq!(out.due(t0 + Duration::from_millis(500)), None);
        // The link is down: every second of silence brings a re-send.
        let r = out.due(t0 + Duration::from_millis(1000)).unwrap();
        assert_eq!(r.request_id, 1);
        assert_eq!(out.due(t0 + Duration::from_millis(1500)), None);
        assert!(out.due(t0 + Duration::from_millis(2000)).is_some());
        assert_eq!(out.resends, 2);
        // Training progress keeps it quiet without answering it.
        let t = t0 + Duration::from_millis(2900);
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::Training), at(1, 100), t),
            ProgressAction::Forward { answered: false }
        );
        assert_eq!(out.due(t + Duration::from_millis(999)), None);
        assert!(out.due(t + Duration::from_millis(1000)).is_some());
        // The final answer ends the re-sending.
        let t = t + Duration::from_millis(1100);
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::BudgetExhausted), at(1, 100), t),
            ProgressAction::Forward { answered: true }
        );
        assert!(out.answered());
        assert_eq!(out.due(t + Duration::from_secs(60)), None);
    }

    #[test]
    fn a_newer_request_supersedes_and_progress_of_an_older_one_is_stale() {
        let t0 = Instant::now();
        let mut out = RequestOutbox::new();
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::Published), at(1, 100), t0),
            ProgressAction::Stale,
            "progress before any request of ours"
        );
        out.submit(request(1, 100), t0);
        out.submit(request(2, 200), t0);
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::Published), at(1, 100), t0),
            ProgressAction::Stale
        );
        assert!(
            !out.answered(),
            "an old request's answer does not answer the new one"
        );
        assert_eq!(out.due(t0 + RESEND_INTERVAL).map(|r| r.request_id), Some(2));
        assert_eq!(
            out.on_progress(&progress(3, RetrainPhase::Published), at(3, 0), t0),
            ProgressAction::Stale
        );
    }

    #[test]
    fn a_late_infeasible_answer_to_an_earlier_request_with_the_same_id_does_not_end_the_current_one()
     {
        let t0 = Instant::now();
        let mut out = RequestOutbox::new();
        out.submit(request(1, 500), t0);
        // An earlier rt-core's request 1 (time 100) answered "infeasible", arriving late.
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::Infeasible), at(1, 100), t0),
            ProgressAction::Stale
        );
        // Bound to this request but naming another id in the payload.
        assert_eq!(
            out.on_progress(&progress(2, RetrainPhase::Infeasible), at(1, 500), t0),
            ProgressAction::Stale
        );
        assert!(!out.answered(), "the current request is still open");
        assert_eq!(out.due(t0 + RESEND_INTERVAL).map(|r| r.request_id), Some(1));
        // Its own answer ends it.
        assert_eq!(
            out.on_progress(&progress(1, RetrainPhase::Infeasible), at(1, 500), t0),
            ProgressAction::Forward { answered: true }
        );
        assert!(out.answered());
    }

    #[test]
    fn the_learner_side_binds_progress_to_the_request_it_handed_on() {
        let mut inbox = RequestInbox::default();
        assert_eq!(inbox.current(), RequestRef::default());
        inbox.on_request(7, &request(3, 300));
        assert_eq!(inbox.binding(3), at(3, 300));
        assert_eq!(inbox.binding(2), at(2, 0), "not the request handed on");
        assert_eq!(inbox.current(), at(3, 300));
    }

    #[test]
    fn a_sequence_is_accepted_once_and_only_above_the_last_on_its_channel() {
        let mut g = SequenceGuard::default();
        assert_eq!(g.accept(Channel::Policy, 10), Ok(()));
        assert_eq!(g.accept(Channel::Policy, 10), Err(10), "a replay");
        assert_eq!(g.accept(Channel::Policy, 9), Err(10), "an older message");
        assert_eq!(g.accept(Channel::Hello, 5), Ok(()), "channels are separate");
        assert_eq!(g.accept(Channel::Policy, 11), Ok(()));
        // Remembered across a restart.
        let mut back = SequenceGuard::from_marks(&g.marks());
        assert_eq!(back, g);
        assert_eq!(back.accept(Channel::Policy, 11), Err(11));
    }

    #[test]
    fn the_learner_side_forwards_a_request_once_and_reanswers_repeats() {
        let mut inbox = RequestInbox::default();
        assert_eq!(
            inbox.on_request(7, &request(1, 100)),
            RequestAction::Forward
        );
        // Repeats while training: dropped (the learner is on it).
        assert_eq!(inbox.on_request(7, &request(1, 100)), RequestAction::Drop);
        inbox.on_local_progress(&progress(1, RetrainPhase::Training));
        assert_eq!(inbox.on_request(7, &request(1, 100)), RequestAction::Drop);
        // Answered: a repeat (the answer was lost on the way) gets the answer again.
        let done = progress(1, RetrainPhase::Published);
        inbox.on_local_progress(&done);
        assert_eq!(
            inbox.on_request(7, &request(1, 100)),
            RequestAction::Reanswer(done)
        );
        // A newer request is forwarded; a late older one dropped.
        assert_eq!(
            inbox.on_request(7, &request(2, 200)),
            RequestAction::Forward
        );
        assert_eq!(inbox.on_request(7, &request(1, 100)), RequestAction::Drop);
        // A restarted controller relay (another instance) starts its ids again.
        assert_eq!(
            inbox.on_request(8, &request(1, 300)),
            RequestAction::Forward
        );
        assert_eq!(inbox.dropped, 4);
    }

    #[test]
    fn a_policy_is_resent_until_acknowledged_and_forwarded_once() {
        let t0 = Instant::now();
        let mut out = PolicyOutbox::default();
        out.submit(10, 0xaa, t0);
        assert!(!out.due(t0 + Duration::from_millis(999)));
        assert!(out.due(t0 + RESEND_INTERVAL));
        // Then after 2, 4 and every 8 s of silence: a 5 s cut gathers the first copy and
        // two re-sends, within the controller side's queue of 4 (before: one a second).
        assert!(!out.due(t0 + Duration::from_millis(2999)));
        assert!(out.due(t0 + Duration::from_secs(3)));
        assert!(!out.due(t0 + Duration::from_millis(6999)));
        assert!(out.due(t0 + Duration::from_secs(7)));
        assert!(!out.due(t0 + Duration::from_millis(14_999)));
        assert!(out.due(t0 + Duration::from_secs(15)));
        assert!(out.due(t0 + Duration::from_secs(23)), "at most 8 s apart");
        assert_eq!(out.resends, 5);
        // A new policy starts again at 1 s.
        out.submit(10, 0xaa, t0 + Duration::from_secs(30));
        assert!(out.due(t0 + Duration::from_secs(31)));
        assert!(
            !out.on_ack(10, 0xbb),
            "an ack of another blob with the same id"
        );
        assert!(!out.on_ack(9, 0xaa));
        assert!(out.on_ack(10, 0xaa));
        assert!(!out.waiting());
        assert!(!out.due(t0 + Duration::from_secs(10)));

        let mut inbox = PolicyInbox::default();
        assert!(inbox.is_new(10, 0xaa));
        assert!(
            inbox.is_new(10, 0xaa),
            "not delivered (publishing failed): still new"
        );
        inbox.delivered(10, 0xaa);
        assert!(!inbox.is_new(10, 0xaa));
        assert!(inbox.is_new(10, 0xbb), "same id, other blob");
        assert!(inbox.is_new(11, 0xcc));
    }
}
