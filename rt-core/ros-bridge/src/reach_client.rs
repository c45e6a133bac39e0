//! A `Reach` action client over DDS (what `foresight reach` runs; any ROS 2 action client
//! does the same): sends one goal to `/foresight/reach`, reports feedback, optionally
//! cancels, and waits for the result.
//!
//! DDS services drop a request sent before discovery has matched the server, so the goal is
//! re-sent (with a fresh goal id) until the server answers, and the result and cancel
//! requests are repeated until answered. A goal the server did take whose answer was lost is
//! then pre-empted by the re-sent one, which the server reports as such.

use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ros2_client::action::{ActionClientQosPolicies, GoalStatusEnum};
use ros2_client::action_msgs::GoalId;
use ros2_client::{ActionClient, NodeName, NodeOptions, RmwRequestId, ServiceMapping};

use crate::reach::{action_qos_profiles, dds, reach_action_name, reach_action_type};
use crate::reach_msgs::{ReachFeedback, ReachGoal, ReachResult};
use crate::{RosBridgeError, ros_context};

/// How long one goal request waits for its answer before it is sent again.
const GOAL_RESEND: Duration = Duration::from_secs(2);
/// How often an unanswered result or cancel request is repeated.
const REQUEST_REPEAT: Duration = Duration::from_secs(3);
const POLL: Duration = Duration::from_millis(10);

/// Client settings.
#[derive(Debug, Clone)]
pub struct ReachClientOptions {
    /// DDS domain id.
    pub domain_id: u16,
    /// Interfaces DDS may use (empty: all).
    pub networks: Vec<IpAddr>,
    /// Give up when no server answers the goal within this long.
    pub connect_timeout: Duration,
    /// Cancel the goal this long after it was accepted.
    pub cancel_after: Option<Duration>,
}

/// What happened, as it happens.
#[derive(Debug, Clone, PartialEq)]
pub enum ReachEvent {
    /// The server accepted the goal.
    Accepted,
    /// The server rejected the goal (its result says why).
    Rejected,
    /// Feedback.
    Feedback(ReachFeedback),
    /// A cancel was asked.
    Cancelling,
}

/// How the goal ended.
#[derive(Debug, Clone, PartialEq)]
pub struct ReachEnd {
    /// Whether the server accepted the goal.
    pub accepted: bool,
    /// The goal's final status.
    pub status: GoalStatusEnum,
    /// The result (for a rejected goal: the refusal, naming the bound).
    pub result: ReachResult,
}

/// The client QoS, the server's (`crate::reach::action_qos_profiles`).
pub fn reach_client_qos() -> ActionClientQosPolicies {
    let (service, status) = action_qos_profiles();
    ActionClientQosPolicies {
        goal_service: service.clone(),
        result_service: service.clone(),
        cancel_service: service.clone(),
        feedback_subscription: service,
        status_subscription: status,
    }
}

/// Sends `goal` and waits for its end; `interrupt` (e.g. SIGINT) cancels it like
/// `cancel_after`. Calls `on_event` for each [`ReachEvent`].
///
/// # Errors
/// [`RosBridgeError::Dds`] when DDS cannot be set up or no server answers within
/// `connect_timeout`.
pub fn reach(
    goal: ReachGoal,
    opts: &ReachClientOptions,
    interrupt: &AtomicBool,
    mut on_event: impl FnMut(&ReachEvent),
) -> Result<ReachEnd, RosBridgeError> {
    let context = ros_context(opts.domain_id, &opts.networks)?;
    let mut node = context
        .new_node(
            NodeName::new("/foresight", "reach_client").map_err(dds)?,
            NodeOptions::new().enable_rosout(false),
        )
        .map_err(dds)?;
    let client: ActionClient<ReachGoal, ReachResult, ReachFeedback> = node
        .create_action_client(
            ServiceMapping::Enhanced,
            &reach_action_name()?,
            &reach_action_type(),
            reach_client_qos(),
        )
        .map_err(dds)?;

    // The goal, re-sent until answered.
    let started = Instant::now();
    let (goal_id, accepted) = loop {
        if started.elapsed() > opts.connect_timeout {
            return Err(RosBridgeError::NoReachServer(opts.connect_timeout));
        }
        let (req_id, goal_id) = client.send_goal(goal).map_err(dds)?;
        let sent = Instant::now();
        let mut answer = None;
        while sent.elapsed() < GOAL_RESEND {
            if let Some(r) = client.receive_goal_response(req_id).map_err(dds)? {
                answer = Some(r);
                break;
            }
            std::thread::sleep(POLL);
        }
        if let Some(r) = answer {
            break (goal_id, r.accepted);
        }
    };
    on_event(if accepted {
        &ReachEvent::Accepted
    } else {
        &ReachEvent::Rejected
    });
    let accepted_at = Instant::now();

    let mut result_req: Option<(RmwRequestId, Instant)> = None;
    let mut cancel_req: Option<(RmwRequestId, Instant)> = None;
    let mut cancel_answered = false;
    loop {
        if result_req.is_none_or(|(_, at)| at.elapsed() > REQUEST_REPEAT) {
            result_req = Some((client.request_result(goal_id).map_err(dds)?, Instant::now()));
        }
        if let Some((req_id, _)) = result_req
            && let Some((status, result)) = client.receive_result(req_id).map_err(dds)?
        {
            return Ok(ReachEnd {
                accepted,
                status,
                result,
            });
        }
        if accepted {
            while let Some(f) = client.receive_feedback(goal_id).map_err(dds)? {
                on_event(&ReachEvent::Feedback(f));
            }
            let cancel_due = interrupt.load(Ordering::Relaxed)
                || opts
                    .cancel_after
                    .is_some_and(|d| accepted_at.elapsed() >= d);
            if cancel_due && !cancel_answered {
                if cancel_req.is_none() {
                    on_event(&ReachEvent::Cancelling);
                }
                if cancel_req.is_none_or(|(_, at)| at.elapsed() > REQUEST_REPEAT) {
                    cancel_req = Some((cancel(&client, goal_id)?, Instant::now()));
                }
                if let Some((req_id, _)) = cancel_req
                    && client
                        .receive_cancel_response(req_id)
                        .map_err(dds)?
                        .is_some()
                {
                    cancel_answered = true;
                }
            }
        }
        std::thread::sleep(POLL);
    }
}

fn cancel(
    client: &ActionClient<ReachGoal, ReachResult, ReachFeedback>,
    goal_id: GoalId,
) -> Result<RmwRequestId, RosBridgeError> {
    client.cancel_goal(goal_id).map_err(dds)
}
