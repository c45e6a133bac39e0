//! Every act of a run (issue 40 item 2): per scene of the world, the self-improving loop as
//! the outside sees it — the retrain requests rt-core made, the policies the learner
//! published for them, which rt-core accepted (a verdict approving a plan of that policy in
//! the scene) and which it refused (a retrain request naming it as the failed policy, or a
//! "not learned" verdict), with the reasons, and the time from the world change to the goal.
//!
//! An act's loop is closed once nothing is owed: no request was made, or a published policy
//! was accepted after the last request, or the scene is not learned or infeasible. The
//! director ends an act only then (with the goal reached), so a slow learner cannot end it
//! on the planner's path while the retrained policy is still on its way.

use serde::{Deserialize, Serialize};
use shm_schemas::{EpisodeEnd, RetrainRequest, TwinVerdict};

/// One act as it happens (the director's per-scene record).
#[derive(Debug, Clone, Default)]
pub struct ActRecord {
    /// Retrain request ids made in the act.
    pub requests: Vec<u64>,
    /// Policies the learner published for the act's requests.
    pub published: Vec<u64>,
    /// Published policies rt-core approved a plan of in the act's scene.
    pub accepted: Vec<u64>,
    /// Refused retrainings: the policy and the reason, in words.
    pub refused: Vec<String>,
    /// Policies a verdict approved in the act's scene, with when (s): an approval read in
    /// the same poll as the publication that makes it an acceptance still counts.
    approved_seen: Vec<(u64, f64)>,
    /// The scene is not learned: why, in words.
    pub not_learned: Option<String>,
    /// Launcher time of the last request and of the last acceptance (s).
    last_request_s: Option<f64>,
    last_accept_s: Option<f64>,
    /// Launcher time of the learner's last answer that publishes nothing ("no safe way",
    /// also for now while boxes move), s: nothing more will come for that request.
    last_unpublished_answer_s: Option<f64>,
    /// World change → goal reached (s).
    pub change_to_goal_s: Option<f64>,
}

/// What a verdict or request meant for the act (a timeline line).
#[derive(Debug, Clone, PartialEq)]
pub enum ActMark {
    /// A published policy was accepted.
    Accepted(u64),
    /// A published policy was refused, with the reason.
    Refused(String),
    /// The scene is not learned, with the reason.
    NotLearned(String),
}

/// The reason a verdict failed, in words.
pub fn failed_verdict_words(v: &TwinVerdict) -> String {
    let why = if !v.is_safe() {
        "its plan comes closer to an obstacle than the clearance"
    } else if !v.is_task_ok() {
        "its plan does not reach the goal"
    } else {
        "its smoothed plan was not approved"
    };
    format!("{why} (min distance {:.3} m)", v.min_distance_m)
}

impl ActRecord {
    /// A retrain request of the act. A request naming a policy published for this act as
    /// the failed one is a refused retraining.
    pub fn on_request(&mut self, t_s: f64, r: &RetrainRequest) -> Option<ActMark> {
        if !self.requests.contains(&r.request_id) {
            self.requests.push(r.request_id);
            self.last_request_s = Some(t_s);
        }
        if self.published.contains(&r.failed_policy_id) {
            let words = format!(
                "policy {}: {}",
                r.failed_policy_id,
                failed_verdict_words(&r.verdict)
            );
            if !self.refused.contains(&words) {
                self.refused.push(words.clone());
                return Some(ActMark::Refused(words));
            }
        }
        None
    }

    /// The learner published `policy_id` for one of the act's requests (an approval of it
    /// seen already makes it accepted now).
    pub fn on_published(&mut self, policy_id: u64) -> Option<ActMark> {
        if policy_id == 0 || self.published.contains(&policy_id) {
            return None;
        }
        self.published.push(policy_id);
        let (_, t_s) = *self.approved_seen.iter().find(|(id, _)| *id == policy_id)?;
        self.accept(t_s, policy_id)
    }

    fn accept(&mut self, t_s: f64, policy_id: u64) -> Option<ActMark> {
        self.last_accept_s = Some(self.last_accept_s.map_or(t_s, |s| s.max(t_s)));
        if self.accepted.contains(&policy_id) {
            return None;
        }
        self.accepted.push(policy_id);
        Some(ActMark::Accepted(policy_id))
    }

    /// A verdict in the act's scene.
    pub fn on_verdict(&mut self, t_s: f64, v: &TwinVerdict) -> Option<ActMark> {
        if v.episode_end == EpisodeEnd::NotLearned as u8 && self.not_learned.is_none() {
            let words = format!(
                "the retrained policies were refused; the last, policy {}: {}",
                v.policy_id,
                failed_verdict_words(v)
            );
            self.not_learned = Some(words.clone());
            return Some(ActMark::NotLearned(words));
        }
        if !v.is_plan_approved() || v.policy_id == 0 {
            return None;
        }
        if !self.approved_seen.iter().any(|(id, _)| *id == v.policy_id) {
            self.approved_seen.push((v.policy_id, t_s));
        }
        if self.published.contains(&v.policy_id) {
            return self.accept(t_s, v.policy_id);
        }
        None
    }

    /// The learner answered the act's request without a policy ("no safe way", final or
    /// for now).
    pub fn on_unpublished_answer(&mut self, t_s: f64) {
        self.last_unpublished_answer_s = Some(t_s);
    }

    /// Whether nothing is owed: no request, an acceptance or an answer without a policy
    /// since the last one, or the scene not learned (`infeasible`: the learner proved it
    /// has no safe way).
    pub fn loop_closed(&self, infeasible: bool) -> bool {
        let since_request = |t: Option<f64>| match (self.last_request_s, t) {
            (Some(req), Some(t)) => t >= req,
            _ => false,
        };
        infeasible
            || self.not_learned.is_some()
            || self.last_request_s.is_none()
            || since_request(self.last_accept_s)
            || since_request(self.last_unpublished_answer_s)
    }
}

/// One act in `summary.json` and `report.md`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct ActSummary {
    /// Scene index in the world.
    pub scene: usize,
    /// Scene name.
    pub name: String,
    /// The goal was reached.
    pub goal_reached: bool,
    /// World change → goal reached (s; the first act: start → goal).
    pub change_to_goal_s: Option<f64>,
    /// Retrain requests rt-core made in the act.
    pub retrain_requests: usize,
    /// Policies the learner published for them.
    pub policies_published: usize,
    /// Published policies rt-core accepted in the scene.
    pub policies_accepted: usize,
    /// Refused retrainings, each with its reason.
    pub retrainings_refused: Vec<String>,
    /// What moved the arm ("policy", "planner, then policy", …; empty: nothing).
    pub executor: String,
    /// The scene is not learned: why.
    pub not_learned: Option<String>,
    /// The learner proved the goal has no safe way: why.
    pub infeasible: Option<String>,
}

impl ActSummary {
    /// One row of the report's table.
    pub fn markdown_row(&self) -> String {
        let end = match (&self.infeasible, &self.not_learned, self.goal_reached) {
            (Some(w), _, _) => format!("infeasible: {w}"),
            (None, Some(w), _) => format!("not learned: {w}"),
            (None, None, true) => "reached".to_owned(),
            (None, None, false) => "not reached".to_owned(),
        };
        let refused = if self.retrainings_refused.is_empty() {
            "—".to_owned()
        } else {
            self.retrainings_refused.join("; ")
        };
        format!(
            "| {} {} | {} | {} | {} | {} | {} | {} | {} |",
            self.scene,
            self.name,
            end,
            self.change_to_goal_s
                .map_or("—".to_owned(), |s| format!("{s:.1} s")),
            self.retrain_requests,
            self.policies_published,
            self.policies_accepted,
            refused,
            if self.executor.is_empty() {
                "—"
            } else {
                &self.executor
            },
        )
    }

    /// The report table's header.
    pub const MARKDOWN_HEADER: &'static str = "| act (scene) | end | world change → goal | \
         retrain requests | policies published | accepted | refused (why) | moved by |\n\
         |---|---|---|---|---|---|---|---|";
}

#[cfg(test)]
mod tests {
    use super::*;

    fn verdict(policy_id: u64, approved: bool) -> TwinVerdict {
        let mut v = TwinVerdict {
            policy_id,
            min_distance_m: 0.01,
            ..TwinVerdict::default()
        };
        v.set_flags(approved, approved, approved);
        v
    }

    fn request(id: u64, failed: u64) -> RetrainRequest {
        let mut r = RetrainRequest {
            request_id: id,
            failed_policy_id: failed,
            ..RetrainRequest::default()
        };
        r.verdict = verdict(failed, false);
        r
    }

    #[test]
    fn a_request_is_owed_until_a_published_policy_is_accepted() {
        let mut a = ActRecord::default();
        assert!(a.loop_closed(false), "no request: nothing owed");
        assert_eq!(a.on_request(1.0, &request(1, 7)), None);
        assert!(!a.loop_closed(false));
        // The base policy approved again is no acceptance of a retrained one.
        assert_eq!(a.on_verdict(2.0, &verdict(7, true)), None);
        assert!(!a.loop_closed(false));
        a.on_published(9);
        assert_eq!(a.on_verdict(3.0, &verdict(9, false)), None);
        assert!(!a.loop_closed(false));
        assert_eq!(
            a.on_verdict(4.0, &verdict(9, true)),
            Some(ActMark::Accepted(9))
        );
        assert!(a.loop_closed(false));
        assert!(a.loop_closed(true));
        // A later request is owed again; "no safe way for now" answers it.
        a.on_request(5.0, &request(2, 9));
        assert!(!a.loop_closed(false));
        a.on_unpublished_answer(6.0);
        assert!(a.loop_closed(false));
    }

    #[test]
    fn an_approval_read_before_its_publication_in_the_same_poll_is_an_acceptance() {
        let mut a = ActRecord::default();
        a.on_request(1.0, &request(1, 7));
        assert_eq!(a.on_verdict(2.0, &verdict(9, true)), None);
        assert!(!a.loop_closed(false));
        assert_eq!(a.on_published(9), Some(ActMark::Accepted(9)));
        assert!(a.loop_closed(false));
    }

    #[test]
    fn a_request_naming_a_published_policy_is_a_refusal_and_not_learned_closes_the_loop() {
        let mut a = ActRecord::default();
        a.on_request(1.0, &request(1, 7));
        a.on_published(9);
        match a.on_request(2.0, &request(2, 9)) {
            Some(ActMark::Refused(w)) => {
                assert!(w.contains("policy 9") && w.contains("clearance"), "{w}")
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(a.refused.len(), 1);
        assert!(!a.loop_closed(false));
        let mut nl = verdict(9, false);
        nl.episode_end = EpisodeEnd::NotLearned as u8;
        assert!(matches!(
            a.on_verdict(3.0, &nl),
            Some(ActMark::NotLearned(_))
        ));
        assert!(a.loop_closed(false));
    }
}
