//! The `Reach` action server (`/foresight/reach`, `foresight_msgs/action/Reach`,
//! [`crate::reach_msgs`]): a ROS 2 program gives the arm a goal on the table over real DDS.
//!
//! - A goal is checked against the workspace and the table ([`ReachSettings::check`], the
//!   bounds of rt-core's `assets/runtime.toml`); one out of bounds, or any goal while rt-core's
//!   goal source is the camera, is rejected, and its result (`GetResult` for its id) says
//!   why, naming the bound ([`ReachOutcome::Refused`]).
//! - An accepted goal goes to rt-core as an iceoryx2 [`GoalRequest`]; rt-core's intake makes
//!   it the scene's goal (the camera's obstacles still count) if the request is young and was
//!   made since rt-core started ([`GoalRequest::check_age`]: the service replays its last
//!   sample to a restarted rt-core). A request rt-core refuses (by age, or any other check)
//!   comes back as a [`GoalRefusal`], and the goal ends at once [`ReachOutcome::Refused`]
//!   (status aborted) naming why, e.g. "refused by rt-core: the request is 2.500 s old, over
//!   the 2.000 s bound" (before, a goal without a deadline waited forever). A newer goal pre-empts it explicitly: the old goal ends
//!   [`ReachOutcome::Preempted`], naming the new one, and rt-core is sent a cancel of the old
//!   goal before the new reach (the plan toward the old target is revoked, as for a cancel).
//! - Who may send goals: DDS (rustdds, without DDS Security) carries no user identity or key
//!   to check, so the rule is the machine: goals are taken only while the bridge's DDS
//!   participant is loopback-only (`--ros-network 127.0.0.1`, the default;
//!   [`loopback_only`]); with any other interface every goal is refused, naming the rule.
//!   The participant's sockets still listen on every interface, so the robot PC's firewall
//!   must keep outside RTPS traffic (UDP 7400 and up) off it; any local user on the DDS
//!   domain can send a goal, which rt-core checks like every other (bounds, lookahead,
//!   shield).
//! - Result requests waiting for the active goal are bounded ([`RESULT_WAITERS`]): the
//!   oldest is answered "too many result requests" to make room for a new one.
//! - Feedback at 10 Hz: the twin worker's phase and executor (from the latest
//!   [`TwinVerdict`]), the TCP's distance to the target, the verdict in words.
//! - It ends [`ReachOutcome::Reached`] when the reported TCP is within the task's
//!   `success.tolerance_m` of the target (the one truth for "reached"), or
//!   [`ReachOutcome::Infeasible`] with the learner's feasibility reason when the retrain
//!   request for its scene is answered infeasible or rt-core says a box has taken the goal
//!   (`infeasible: <reason>`, on the frame that shows it), or [`ReachOutcome::Stopped`] when the arm
//!   stays stopped for a fault (link lost, arm error, model mismatch, shutdown) or the
//!   deadline passes, or [`ReachOutcome::Cancelled`] once a cancelled goal's arm is at rest
//!   for good (rt-core revokes the plan under way: the arm stops along its checked path and,
//!   with `return_home`, goes back to its start posture along its own path).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher as ShmPublisher;
use iceoryx2::prelude::*;
use ros2_client::action::{
    ActionServerQosPolicies, GetResultRequest, GetResultResponse, SendGoalRequest, SendGoalResponse,
};
use ros2_client::action_msgs::{
    CancelGoalRequest, CancelGoalResponse, CancelGoalResponseEnum, GoalId, GoalInfo, GoalStatus,
    GoalStatusArray, GoalStatusEnum,
};
use ros2_client::qos::{Durability, History};
use ros2_client::{
    ActionServer, ActionTypeName, Name, Node, QosProfile, RmwRequestId, ServiceMapping,
    builtin_interfaces,
};
use serde::{Deserialize, Serialize};
use shm_schemas::goal_request::{REQUESTED_GOAL_SIZE_M, requested_tcp_target_m};
use shm_schemas::runtime_view::{GoalSource, RuntimeView};
use shm_schemas::{
    GoalBounds, GoalCommand, GoalRefusal, GoalRequest, RetrainPhase, RetrainProgress,
    RetrainRequest, RobotState, StopReason, TwinVerdict,
};
use twin::{BoxObstacle, InfeasibleReason};

use crate::RosBridgeError;
use crate::reach_msgs::{
    REACH_NAME, REACH_NAMESPACE, REACH_PACKAGE, REACH_TYPE, ReachFeedback, ReachGoal, ReachOutcome,
    ReachResult,
};

/// How often feedback is published.
const FEEDBACK_PERIOD: Duration = Duration::from_millis(100);
/// A fault stop lasting this long ends the goal [`ReachOutcome::Stopped`].
const STOP_GRACE: Duration = Duration::from_secs(2);
/// Joint speed below which the arm counts as at rest, rad/s.
const AT_REST_RAD_S: f64 = 0.01;
/// How long a cancelled goal's arm must stay at rest before the goal ends: longer than the
/// pause between the stop of the revoked plan and the return home that rt-core then starts
/// (`return_home`), so the goal ends with the arm at rest for good.
const AT_REST_FOR: Duration = Duration::from_millis(1500);
/// Finished goals kept for late result requests and the status array.
const FINISHED_KEPT: usize = 32;
/// Result requests that may wait for the active goal's end.
pub const RESULT_WAITERS: usize = 16;

/// Whether a DDS participant restricted to `networks` is reachable only from this machine
/// (every address a loopback one; empty means every interface).
pub fn loopback_only(networks: &[std::net::IpAddr]) -> bool {
    !networks.is_empty() && networks.iter().all(std::net::IpAddr::is_loopback)
}

/// At most `N` items waiting, first in first out: a push onto a full queue returns the
/// oldest, to be answered and dropped.
#[derive(Debug)]
struct Bounded<T, const N: usize> {
    queue: VecDeque<T>,
}

impl<T, const N: usize> Bounded<T, N> {
    fn new() -> Self {
        Self {
            queue: VecDeque::with_capacity(N),
        }
    }

    /// Queues `item`; returns the oldest one when the queue was full.
    fn push(&mut self, item: T) -> Option<T> {
        let evicted = (self.queue.len() >= N)
            .then(|| self.queue.pop_front())
            .flatten();
        self.queue.push_back(item);
        evicted
    }

    fn drain(&mut self) -> impl Iterator<Item = T> + '_ {
        self.queue.drain(..)
    }
}

/// What the server needs to know of the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReachSettings {
    /// rt-core takes action goals (`[goal] source = "action"`); otherwise every goal is
    /// refused.
    pub goal_source_action: bool,
    /// rt-core's bounds for a requested goal.
    pub bounds: GoalBounds,
    /// Table-top height, m (the task's `sampling.table_height_m`).
    pub table_height_m: f64,
    /// The task's `success.goal_hover_m`, m.
    pub goal_hover_m: f64,
    /// The task's `success.tolerance_m`, m.
    pub tolerance_m: f64,
    /// The bridge's DDS participant is reachable only from this machine
    /// ([`loopback_only`]); otherwise every goal is refused.
    pub dds_loopback_only: bool,
}

impl ReachSettings {
    /// Why `goal` cannot be accepted, naming the bound.
    ///
    /// # Errors
    /// The reason in words.
    pub fn check(&self, goal: &ReachGoal) -> Result<(), String> {
        if !self.goal_source_action {
            return Err(
                "the goal source is the camera ([goal] source = \"camera\"); \
                 start with `foresight --ros --goal-source action`"
                    .into(),
            );
        }
        if !self.dds_loopback_only {
            return Err(
                "the Reach action takes goals only from programs on the robot PC, and DDS \
                 carries no user or key to check: run ros-bridge loopback-only \
                 (--ros-network 127.0.0.1, the default) to serve goals"
                    .into(),
            );
        }
        if !(goal.deadline_s.is_finite() && (0.0..=86_400.0).contains(&goal.deadline_s)) {
            return Err(format!(
                "deadline_s = {} breaks the bound 0..=86400 s",
                goal.deadline_s
            ));
        }
        let default_height_m = REQUESTED_GOAL_SIZE_M + self.goal_hover_m;
        self.bounds
            .check(
                [goal.x_m, goal.y_m],
                goal.approach_height_m,
                default_height_m,
                self.table_height_m,
            )
            .map_err(|e| e.to_string())
    }

    /// The TCP target of `goal` (as rt-core plans toward it).
    pub fn target_m(&self, goal: &ReachGoal) -> [f64; 3] {
        requested_tcp_target_m(
            [goal.x_m, goal.y_m],
            goal.approach_height_m,
            self.table_height_m,
            self.goal_hover_m,
        )
    }
}

/// The goal bounds and whether the goal source is `action`, from the text of rt-core's
/// runtime configuration, read through the one view of it that rt-core itself holds
/// ([`shm_schemas::runtime_view`]: its sections and defaults; rt-core validates the whole file
/// when it starts).
///
/// # Errors
/// The TOML error in words (an unknown `goal.source` is named as such).
pub fn runtime_goal_settings(text: &str) -> Result<(GoalBounds, bool), String> {
    let view = RuntimeView::from_toml(text).map_err(|e| e.to_string())?;
    let bounds = view.goal_bounds().ok_or("missing table `[shield]`")?;
    Ok((bounds, view.goal.source == GoalSource::Action))
}

/// What the server counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ReachStats {
    /// Goals accepted.
    pub goals_accepted: u64,
    /// Goals refused: at acceptance, or afterwards by rt-core ([`GoalRefusal`]).
    pub goals_refused: u64,
    /// Ended reached.
    pub reached: u64,
    /// Ended infeasible.
    pub infeasible: u64,
    /// Ended stopped.
    pub stopped: u64,
    /// Ended cancelled.
    pub cancelled: u64,
    /// Ended pre-empted.
    pub preempted: u64,
}

/// The newest inputs of one bridge iteration.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReachInputs<'a> {
    /// The latest robot state, and whether it is new this iteration.
    pub state: Option<(&'a RobotState, bool)>,
    /// The latest verdict.
    pub verdict: Option<&'a TwinVerdict>,
    /// Retrain requests received this iteration.
    pub retrain_requests: &'a [RetrainRequest],
    /// Retrain progress received this iteration.
    pub retrain_progress: &'a [RetrainProgress],
    /// Goal requests rt-core refused, received this iteration.
    pub goal_refusals: &'a [GoalRefusal],
}

struct Active {
    id: GoalId,
    stamp: builtin_interfaces::Time,
    seq: u64,
    goal: ReachGoal,
    target_m: [f64; 3],
    accepted_at: Instant,
    cancelling: bool,
    /// Where the TCP was when the cancel took effect (the first state read after the
    /// cancel went to rt-core, which takes it within one cycle), m.
    cancelled_at_tcp_m: Option<[f64; 3]>,
    /// The TCP's closest approach to the target since the cancel took effect, m.
    closest_after_cancel_m: f64,
    at_rest_since: Option<Instant>,
    fault_since: Option<(Instant, StopReason)>,
    result_requests: Bounded<RmwRequestId, RESULT_WAITERS>,
    /// Retrain requests made for this goal's scene: id and obstacles.
    retrains: Vec<(u64, Vec<BoxObstacle>)>,
    distance_m: f64,
    /// The id of the latest verdict when the goal was accepted: feedback says `waiting`
    /// until a newer one comes.
    verdict_at_accept: Option<u64>,
}

struct Finished {
    id: GoalId,
    stamp: builtin_interfaces::Time,
    status: GoalStatusEnum,
    result: ReachResult,
}

/// `CancelGoalRequest` mirrored (ros2-client keeps its field private; the wire form is
/// the same).
#[derive(Deserialize)]
struct CancelMirror {
    goal_info: GoalInfo,
}

/// The action server and its goals.
pub struct ReachServer {
    server: ActionServer<ReachGoal, ReachResult, ReachFeedback>,
    goals: ShmPublisher<ipc::Service, GoalRequest, ()>,
    settings: ReachSettings,
    active: Option<Active>,
    finished: VecDeque<Finished>,
    last_seq: u64,
    next_feedback: Instant,
    stats: ReachStats,
}

pub(crate) fn dds(e: impl std::fmt::Debug) -> RosBridgeError {
    RosBridgeError::Dds(format!("{e:?}"))
}

/// The action's two QoS profiles, for both ends: volatile services and feedback (keep the
/// last 10), transient-local status (keep the last one) — what ROS 2 action clients ask for.
pub(crate) fn action_qos_profiles() -> (QosProfile, QosProfile) {
    let service = QosProfile::publisher_default()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 });
    let status = QosProfile::publisher_default()
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 });
    (service, status)
}

/// The action server's QoS (`action_qos_profiles`).
pub fn reach_server_qos() -> ActionServerQosPolicies {
    let (service, status) = action_qos_profiles();
    ActionServerQosPolicies {
        goal_service: service.clone(),
        result_service: service.clone(),
        cancel_service: service.clone(),
        feedback_publisher: service,
        status_publisher: status,
    }
}

/// The action's name, `/foresight/reach`.
///
/// # Errors
/// Never for the fixed name.
pub fn reach_action_name() -> Result<Name, RosBridgeError> {
    Name::new(REACH_NAMESPACE, REACH_NAME).map_err(dds)
}

/// The action's type, `foresight_msgs/action/Reach`.
pub fn reach_action_type() -> ActionTypeName {
    ActionTypeName::new(REACH_PACKAGE, REACH_TYPE)
}

fn status_of(outcome: ReachOutcome) -> GoalStatusEnum {
    match outcome {
        ReachOutcome::Reached => GoalStatusEnum::Succeeded,
        ReachOutcome::Cancelled => GoalStatusEnum::Canceled,
        _ => GoalStatusEnum::Aborted,
    }
}

/// A cancelled goal's result: where the arm was when the cancel took effect, how close it
/// came to the target afterwards, and where it rests.
fn cancelled_words(a: &Active) -> String {
    let at = |p: &[f64; 3]| format!("({:.3}, {:.3}, {:.3}) m", p[0], p[1], p[2]);
    match a.cancelled_at_tcp_m {
        Some(p) => format!(
            "cancelled with the TCP at {}, {:.3} m from the target; closest to the target \
             afterwards {:.3} m; the arm is at rest {:.3} m from the target",
            at(&p),
            distance_m(&p, &a.target_m),
            a.closest_after_cancel_m,
            a.distance_m
        ),
        None => format!(
            "cancelled; the arm is at rest {:.3} m from the target (no state read after the \
             cancel)",
            a.distance_m
        ),
    }
}

fn distance_m(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// A goal-taken verdict's reason ([`TwinVerdict::goal_taken_wire`]) as the `Reach` result
/// says it: `infeasible: <reason>`.
pub fn goal_taken_words((kind, blocker, link, by_m): (u8, u8, u8, f32)) -> String {
    InfeasibleReason::from_wire(kind, blocker, link, by_m).map_or_else(
        || "infeasible: a box has taken the goal".to_owned(),
        |r| format!("infeasible: {r}"),
    )
}

/// The verdict in words, with whether its plan was approved (the action's feedback; the
/// scene's text marker, [`recorder::ros_view::verdict_line`]).
pub fn verdict_words(v: &TwinVerdict) -> String {
    recorder::ros_view::verdict_line(v)
}

/// Whether a stop reason ends a goal when it lasts: faults, not the pauses of normal
/// operation (no plan yet, a box in the way, a stale or refused frame).
fn is_fault(reason: StopReason) -> bool {
    matches!(
        reason,
        StopReason::LinkLost
            | StopReason::ArmError
            | StopReason::ModelMismatch
            | StopReason::Requested
    )
}

/// Takes this iteration's `inputs` into the active goal `a` (retrain requests for its
/// scene, the arm's distance, rest and faults) and says how it ends, if it does now: a
/// refusal by rt-core, infeasible (the learner's answer, or a box that has taken the goal),
/// cancelled at rest, reached, stopped for a fault or the deadline.
fn ending(
    a: &mut Active,
    inputs: &ReachInputs<'_>,
    settings: &ReachSettings,
    now: Instant,
) -> Option<(ReachOutcome, String)> {
    // Retrain requests for this goal's scene (received while it is active, goal at its
    // target), and their answers.
    for r in inputs.retrain_requests {
        let goal_top = r.goal_center_m[2] + r.goal_size_m / 2.0 + settings.goal_hover_m;
        let at_target = (r.goal_center_m[0] - a.target_m[0]).abs() < 1e-6
            && (r.goal_center_m[1] - a.target_m[1]).abs() < 1e-6
            && (goal_top - a.target_m[2]).abs() < 1e-6;
        // Received while this goal is active (the request's own stamp is on rt-core's
        // cycle clock, not comparable here).
        if at_target {
            let obstacles = r
                .obstacles()
                .iter()
                .map(|o| BoxObstacle {
                    center_m: o.center_m,
                    size_m: o.size_m,
                })
                .collect();
            a.retrains.push((r.request_id, obstacles));
        }
    }
    if let Some((state, fresh)) = inputs.state {
        observe_state(a, state, fresh, now);
    }
    refused_by_rt_core(a, inputs.goal_refusals)
        .or_else(|| infeasible(a, inputs.retrain_progress))
        .or_else(|| goal_taken(a, inputs.verdict))
        .or_else(|| ended_by_the_arm(a, settings, now))
}

/// The goal's end when rt-core says, on the frame that showed it, that a box has taken the
/// goal (a goal-taken verdict since the goal was accepted).
fn goal_taken(a: &Active, verdict: Option<&TwinVerdict>) -> Option<(ReachOutcome, String)> {
    verdict
        .filter(|v| Some(v.verdict_id) != a.verdict_at_accept)
        .and_then(TwinVerdict::goal_taken_wire)
        .map(|wire| (ReachOutcome::Infeasible, goal_taken_words(wire)))
}

/// The goal's end when rt-core refused its reach request (by age, above all: a request
/// that reached it too late, or an earlier run's replayed to a restarted rt-core): it will
/// never drive toward the target, so the goal ends refused (aborted), naming why.
fn refused_by_rt_core(a: &Active, refusals: &[GoalRefusal]) -> Option<(ReachOutcome, String)> {
    refusals
        .iter()
        .find(|r| r.goal_id == a.seq && r.command == GoalCommand::Reach as u8)
        .map(|r| {
            (
                ReachOutcome::Refused,
                format!("refused by rt-core: {}", r.words()),
            )
        })
}

/// The goal's end when the retrain request for its scene was answered infeasible.
fn infeasible(a: &Active, progress: &[RetrainProgress]) -> Option<(ReachOutcome, String)> {
    let mut end = None;
    for p in progress {
        if p.phase() != Ok(RetrainPhase::Infeasible) {
            continue;
        }
        if let Some((_, obstacles)) = a.retrains.iter().find(|(id, _)| *id == p.request_id) {
            let reason = InfeasibleReason::from_wire(
                p.infeasible_kind,
                p.infeasible_blocker,
                p.infeasible_link,
                p.infeasible_by_m,
            )
            .map_or_else(
                || "no safe way to the goal (no reason given)".to_owned(),
                |r| r.display_with(obstacles).to_string(),
            );
            end = Some((ReachOutcome::Infeasible, reason));
        }
    }
    end
}

/// The arm's state into the goal: its distance to the target, where a cancel took effect,
/// since when it rests, since when it is stopped for a fault.
fn observe_state(a: &mut Active, state: &RobotState, fresh: bool, now: Instant) {
    a.distance_m = distance_m(&state.tcp_m, &a.target_m);
    if a.cancelling && fresh {
        a.cancelled_at_tcp_m.get_or_insert(state.tcp_m);
        a.closest_after_cancel_m = a.closest_after_cancel_m.min(a.distance_m);
    }
    if fresh {
        let moving = state
            .joint_velocities_rad_s
            .iter()
            .any(|v| v.abs() > AT_REST_RAD_S);
        a.at_rest_since = match (moving, a.at_rest_since) {
            (true, _) => None,
            (false, Some(since)) => Some(since),
            (false, None) => Some(now),
        };
    }
    let stop = state
        .stop_reason()
        .ok()
        .filter(|r| state.is_stopped() && is_fault(*r));
    a.fault_since = match (stop, a.fault_since) {
        (Some(r), Some((since, _))) => Some((since, r)),
        (Some(r), None) => Some((now, r)),
        (None, _) => None,
    };
}

/// The goal's end from the arm and the clock: cancelled and at rest for good, reached,
/// stopped for a fault that lasts, or past its deadline.
fn ended_by_the_arm(
    a: &Active,
    settings: &ReachSettings,
    now: Instant,
) -> Option<(ReachOutcome, String)> {
    if a.cancelling {
        a.at_rest_since
            .is_some_and(|since| now - since >= AT_REST_FOR)
            .then(|| (ReachOutcome::Cancelled, cancelled_words(a)))
    } else if a.distance_m <= settings.tolerance_m {
        Some((
            ReachOutcome::Reached,
            format!(
                "the TCP is {:.4} m from the target (tolerance {} m)",
                a.distance_m, settings.tolerance_m
            ),
        ))
    } else if let Some((_, reason)) = a
        .fault_since
        .filter(|(since, _)| now - *since >= STOP_GRACE)
    {
        Some((
            ReachOutcome::Stopped,
            format!("the arm stopped: {reason:?}"),
        ))
    } else if a.goal.deadline_s > 0.0
        && now - a.accepted_at >= Duration::from_secs_f64(a.goal.deadline_s)
    {
        Some((
            ReachOutcome::Stopped,
            format!("the deadline of {} s passed", a.goal.deadline_s),
        ))
    } else {
        None
    }
}

/// The active goal's feedback: the worker's phase and executor from the first verdict
/// since the goal was accepted, the TCP's distance, the verdict in words.
fn feedback(a: &Active, inputs: &ReachInputs<'_>) -> ReachFeedback {
    let new_verdict = inputs
        .verdict
        .filter(|v| Some(v.verdict_id) != a.verdict_at_accept);
    let (phase, executor, verdict) = match new_verdict {
        Some(v) => (
            v.phase().map_or("unknown", |p| p.name()).to_owned(),
            v.executor().map_or("unknown", |e| e.name()).to_owned(),
            verdict_words(v),
        ),
        None => ("waiting".into(), "unknown".into(), String::new()),
    };
    ReachFeedback {
        phase: if a.cancelling {
            "cancelling".into()
        } else {
            phase
        },
        executor,
        distance_m: a.distance_m,
        verdict,
    }
}

impl ReachServer {
    /// Creates the action server on `node` and the goal-request publisher on `shm_node`.
    ///
    /// # Errors
    /// [`RosBridgeError`] when either cannot be created.
    pub fn new(
        node: &mut Node,
        shm_node: &iceoryx2::node::Node<ipc::Service>,
        prefix: &str,
        settings: ReachSettings,
    ) -> Result<Self, RosBridgeError> {
        let server = node
            .create_action_server::<ReachGoal, ReachResult, ReachFeedback>(
                ServiceMapping::Enhanced,
                &reach_action_name()?,
                &reach_action_type(),
                reach_server_qos(),
            )
            .map_err(dds)?;
        let goals = shm_schemas::services::open_publisher::<GoalRequest, _>(shm_node, prefix)
            .map_err(RosBridgeError::Shm)?;
        Ok(Self {
            server,
            goals,
            settings,
            active: None,
            finished: VecDeque::with_capacity(FINISHED_KEPT),
            last_seq: 0,
            next_feedback: Instant::now(),
            stats: ReachStats::default(),
        })
    }

    /// What was counted.
    pub fn stats(&self) -> ReachStats {
        self.stats
    }

    fn send(&self, req: GoalRequest) {
        if let Err(e) = self.goals.send_copy(req) {
            eprintln!("ros-bridge: goal request {} not sent: {e:?}", req.goal_id);
        }
    }

    /// One iteration: new goals, cancels and result requests, then the active goal's
    /// progress against `inputs`.
    pub fn poll(&mut self, inputs: &ReachInputs<'_>) {
        self.take_goals(inputs.verdict.map(|v| v.verdict_id));
        self.take_cancels();
        self.take_result_requests();
        self.track(inputs);
    }

    /// Ends the active goal (the bridge is stopping).
    pub fn shut_down(&mut self) {
        if self.active.is_some() {
            self.finish(ReachOutcome::Stopped, "the ROS 2 bridge stopped".into());
        }
    }

    fn take_goals(&mut self, latest_verdict: Option<u64>) {
        while let Ok(Some((req_id, SendGoalRequest { goal_id, goal }))) = self.server.receive_goal()
        {
            let stamp = builtin_interfaces::Time::now();
            match self.settings.check(&goal) {
                Err(reason) => {
                    let _ = self.server.send_goal_response(
                        req_id,
                        SendGoalResponse {
                            accepted: false,
                            stamp,
                        },
                    );
                    self.stats.goals_refused += 1;
                    eprintln!("ros-bridge: reach goal {goal_id:?} refused: {reason}");
                    self.remember(Finished {
                        id: goal_id,
                        stamp,
                        status: GoalStatusEnum::Aborted,
                        result: ReachResult::new(ReachOutcome::Refused, reason, f64::NAN),
                    });
                }
                Ok(()) => {
                    if self.active.is_some() {
                        self.finish(
                            ReachOutcome::Preempted,
                            format!("pre-empted by the newer goal {goal_id:?}"),
                        );
                    }
                    let seq = shm_schemas::clock::monotonic_now_ns().max(self.last_seq + 1);
                    self.last_seq = seq;
                    let target_m = self.settings.target_m(&goal);
                    self.send(GoalRequest::reach(
                        seq,
                        [goal.x_m, goal.y_m],
                        goal.approach_height_m,
                    ));
                    let _ = self.server.send_goal_response(
                        req_id,
                        SendGoalResponse {
                            accepted: true,
                            stamp,
                        },
                    );
                    self.stats.goals_accepted += 1;
                    eprintln!(
                        "ros-bridge: reach goal {goal_id:?} accepted: target {target_m:?} m, deadline {} s",
                        goal.deadline_s
                    );
                    self.active = Some(Active {
                        id: goal_id,
                        stamp,
                        seq,
                        goal,
                        target_m,
                        accepted_at: Instant::now(),
                        cancelling: false,
                        cancelled_at_tcp_m: None,
                        closest_after_cancel_m: f64::INFINITY,
                        at_rest_since: None,
                        fault_since: None,
                        result_requests: Bounded::new(),
                        retrains: Vec::new(),
                        distance_m: f64::NAN,
                        verdict_at_accept: latest_verdict,
                    });
                    self.publish_statuses();
                }
            }
        }
    }

    fn take_cancels(&mut self) {
        while let Ok(Some((req_id, request))) = self.server.receive_cancel_request() {
            let info = mirror(&request);
            let wanted = |id: &GoalId, stamp: &builtin_interfaces::Time| match &info {
                None => false,
                Some(i) => {
                    let all = i.goal_id == GoalId::ZERO;
                    let by_time = i.stamp != builtin_interfaces::Time::ZERO
                        && stamp.to_nanos() <= i.stamp.to_nanos();
                    (all && i.stamp == builtin_interfaces::Time::ZERO)
                        || i.goal_id == *id
                        || by_time
                }
            };
            let response = match self.active.as_mut() {
                Some(a) if wanted(&a.id, &a.stamp) => {
                    let first = !a.cancelling;
                    a.cancelling = true;
                    a.at_rest_since = None;
                    let (seq, id, stamp) = (a.seq, a.id, a.stamp);
                    if first {
                        self.send(GoalRequest::withdraw(seq, GoalCommand::Cancel));
                        eprintln!("ros-bridge: reach goal {id:?} cancelling");
                    }
                    CancelGoalResponse {
                        return_code: CancelGoalResponseEnum::None,
                        goals_canceling: vec![GoalInfo { goal_id: id, stamp }],
                    }
                }
                _ => {
                    let terminated = self
                        .finished
                        .iter()
                        .any(|f| info.as_ref().is_some_and(|i| i.goal_id == f.id));
                    CancelGoalResponse {
                        return_code: if terminated {
                            CancelGoalResponseEnum::GoalTerminated
                        } else {
                            CancelGoalResponseEnum::UnknownGoal
                        },
                        goals_canceling: Vec::new(),
                    }
                }
            };
            let _ = self.server.send_cancel_response(req_id, response);
            self.publish_statuses();
        }
    }

    fn take_result_requests(&mut self) {
        while let Ok(Some((req_id, GetResultRequest { goal_id }))) =
            self.server.receive_result_request()
        {
            if let Some(a) = self.active.as_mut().filter(|a| a.id == goal_id) {
                if let Some(oldest) = a.result_requests.push(req_id) {
                    let _ = self.server.send_result(
                        oldest,
                        GetResultResponse {
                            status: GoalStatusEnum::Unknown,
                            result: ReachResult {
                                outcome: 0,
                                reason: format!(
                                    "too many result requests wait for this goal (at most \
                                     {RESULT_WAITERS}); ask again"
                                ),
                                distance_m: f64::NAN,
                            },
                        },
                    );
                }
                continue;
            }
            let response = match self.finished.iter().find(|f| f.id == goal_id) {
                Some(f) => GetResultResponse {
                    status: f.status,
                    result: f.result.clone(),
                },
                None => GetResultResponse {
                    status: GoalStatusEnum::Unknown,
                    result: ReachResult {
                        outcome: 0,
                        reason: "unknown goal".into(),
                        distance_m: f64::NAN,
                    },
                },
            };
            let _ = self.server.send_result(req_id, response);
        }
    }

    fn track(&mut self, inputs: &ReachInputs<'_>) {
        let settings = self.settings;
        let Some(a) = self.active.as_mut() else {
            return;
        };
        let now = Instant::now();
        if let Some((outcome, reason)) = ending(a, inputs, &settings, now) {
            self.finish(outcome, reason);
            return;
        }
        if now >= self.next_feedback {
            self.next_feedback = now + FEEDBACK_PERIOD;
            let _ = self.server.send_feedback(a.id, feedback(a, inputs));
        }
    }
    /// Ends the active goal with `outcome`: rt-core is told (a release after reaching, a
    /// cancel otherwise — a pre-emption too, sent before the newer goal's reach so that the
    /// plan toward the old target is revoked; nothing for a cancel, already sent when it
    /// came), waiting result requests are answered, the status array is published.
    fn finish(&mut self, outcome: ReachOutcome, reason: String) {
        let Some(mut a) = self.active.take() else {
            return;
        };
        match outcome {
            ReachOutcome::Reached => self.send(GoalRequest::withdraw(a.seq, GoalCommand::Release)),
            ReachOutcome::Cancelled | ReachOutcome::Refused => {}
            ReachOutcome::Preempted | ReachOutcome::Infeasible | ReachOutcome::Stopped => {
                self.send(GoalRequest::withdraw(a.seq, GoalCommand::Cancel));
            }
        }
        match outcome {
            ReachOutcome::Reached => self.stats.reached += 1,
            ReachOutcome::Infeasible => self.stats.infeasible += 1,
            ReachOutcome::Stopped => self.stats.stopped += 1,
            ReachOutcome::Cancelled => self.stats.cancelled += 1,
            ReachOutcome::Preempted => self.stats.preempted += 1,
            ReachOutcome::Refused => self.stats.goals_refused += 1,
        }
        eprintln!(
            "ros-bridge: reach goal {:?} ended {}: {reason}",
            a.id,
            outcome.name()
        );
        let result = ReachResult::new(outcome, reason, a.distance_m);
        let status = status_of(outcome);
        for req_id in a.result_requests.drain() {
            let _ = self.server.send_result(
                req_id,
                GetResultResponse {
                    status,
                    result: result.clone(),
                },
            );
        }
        self.remember(Finished {
            id: a.id,
            stamp: a.stamp,
            status,
            result,
        });
        self.publish_statuses();
    }

    fn remember(&mut self, f: Finished) {
        if self.finished.len() == FINISHED_KEPT {
            self.finished.pop_front();
        }
        self.finished.push_back(f);
    }

    fn publish_statuses(&self) {
        let mut status_list: Vec<GoalStatus> = self
            .finished
            .iter()
            .map(|f| GoalStatus {
                goal_info: GoalInfo {
                    goal_id: f.id,
                    stamp: f.stamp,
                },
                status: f.status,
            })
            .collect();
        if let Some(a) = &self.active {
            status_list.push(GoalStatus {
                goal_info: GoalInfo {
                    goal_id: a.id,
                    stamp: a.stamp,
                },
                status: if a.cancelling {
                    GoalStatusEnum::Canceling
                } else {
                    GoalStatusEnum::Executing
                },
            });
        }
        let _ = self
            .server
            .send_goal_statuses(GoalStatusArray { status_list });
    }
}

/// The goal info of a cancel request (its field is private in ros2-client; the serde form
/// is public).
fn mirror(request: &CancelGoalRequest) -> Option<GoalInfo> {
    let value = serde_json::to_value(request).ok()?;
    serde_json::from_value::<CancelMirror>(value)
        .ok()
        .map(|m| m.goal_info)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> ReachSettings {
        ReachSettings {
            goal_source_action: true,
            bounds: GoalBounds {
                min_radius_m: 0.15,
                max_radius_m: 0.65,
                table_min_m: [-0.8, -0.8, -0.05],
                table_max_m: [0.8, 0.8, 1.0],
                workspace_min_m: [-0.8, -0.8, 0.0],
                workspace_max_m: [0.8, 0.8, 1.0],
            },
            table_height_m: 0.0,
            goal_hover_m: 0.05,
            tolerance_m: 0.02,
            dds_loopback_only: true,
        }
    }

    /// An accepted goal, as `take_goals` makes it: rt-core was sent reach `seq`.
    fn active(seq: u64, deadline_s: f64) -> Active {
        let goal = ReachGoal {
            x_m: 0.4,
            y_m: 0.1,
            deadline_s,
            ..ReachGoal::default()
        };
        Active {
            id: GoalId::new_random(),
            stamp: builtin_interfaces::Time::now(),
            seq,
            goal,
            target_m: settings().target_m(&goal),
            accepted_at: Instant::now(),
            cancelling: false,
            cancelled_at_tcp_m: None,
            closest_after_cancel_m: f64::INFINITY,
            at_rest_since: None,
            fault_since: None,
            result_requests: Bounded::new(),
            retrains: Vec::new(),
            distance_m: f64::NAN,
            verdict_at_accept: None,
        }
    }

    /// Issue 41 item 5 (leftover): rt-core refuses a reach request that reaches it too old
    /// (or made before it started), and the bridge was never told: a goal without a
    /// deadline waited forever, the arm at rest away from the target. Now rt-core's
    /// refusal ends the goal at once, refused (status aborted), naming the age and the
    /// bound; a refusal of another goal's request, or of a cancel, changes nothing.
    #[test]
    fn a_goal_whose_reach_rt_core_refused_by_age_ends_aborted_naming_the_refusal() {
        let s = settings();
        let mut a = active(41, 0.0);
        let resting = RobotState {
            tcp_m: [0.2, -0.2, 0.3],
            link_ok: 1,
            ..RobotState::default()
        };
        let too_old = GoalRefusal::by_age(
            41,
            GoalCommand::Reach as u8,
            &shm_schemas::GoalRequestAgeError::TooOld {
                age_ns: 2_500_000_000,
            },
            1,
        );
        let others = [
            GoalRefusal {
                goal_id: 40,
                ..too_old
            },
            GoalRefusal {
                command: GoalCommand::Cancel as u8,
                ..too_old
            },
        ];
        let inputs = |refusals| ReachInputs {
            state: Some((&resting, true)),
            goal_refusals: refusals,
            ..ReachInputs::default()
        };
        let later = Instant::now() + Duration::from_secs(3600);
        assert_eq!(ending(&mut a, &inputs(&others), &s, later), None);
        let (outcome, reason) =
            ending(&mut a, &inputs(&[too_old]), &s, later).expect("the refused goal ends");
        assert_eq!(outcome, ReachOutcome::Refused);
        assert_eq!(status_of(outcome), GoalStatusEnum::Aborted);
        assert_eq!(
            reason,
            "refused by rt-core: the request is 2.500 s old, over the 2.000 s bound"
        );
    }

    /// Issue 41 item 5: the action had no access control. DDS gives no identity to check,
    /// so goals are taken only on a loopback-only participant; otherwise every goal is
    /// refused, naming the rule.
    #[test]
    fn goals_are_refused_unless_the_dds_participant_is_loopback_only() {
        use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
        let lo = IpAddr::V4(Ipv4Addr::LOCALHOST);
        let lan = IpAddr::V4(Ipv4Addr::new(192, 168, 1, 20));
        assert!(loopback_only(&[lo]));
        assert!(loopback_only(&[lo, IpAddr::V6(Ipv6Addr::LOCALHOST)]));
        assert!(!loopback_only(&[]), "no restriction: every interface");
        assert!(!loopback_only(&[lo, lan]));
        let ok = ReachGoal {
            x_m: 0.4,
            y_m: 0.1,
            ..ReachGoal::default()
        };
        settings().check(&ok).unwrap();
        let open = ReachSettings {
            dds_loopback_only: false,
            ..settings()
        };
        let e = open.check(&ok).unwrap_err();
        assert!(e.contains("--ros-network 127.0.0.1"), "{e}");
    }

    /// Issue 41 item 5: result requests for the active goal piled up without bound; now
    /// at most `RESULT_WAITERS` wait, the oldest handed back to be answered.
    #[test]
    fn result_requests_waiting_for_a_goal_are_bounded() {
        let mut w: Bounded<u32, RESULT_WAITERS> = Bounded::new();
        let mut evicted = Vec::new();
        for i in 0..1000u32 {
            evicted.extend(w.push(i));
        }
        assert_eq!(w.queue.len(), RESULT_WAITERS);
        assert_eq!(evicted.len(), 1000 - RESULT_WAITERS);
        assert_eq!(evicted[..3], [0, 1, 2], "the oldest leave first");
        let waiting: Vec<u32> = w.drain().collect();
        assert_eq!(waiting[0], 1000 - RESULT_WAITERS as u32);
        assert_eq!(w.queue.len(), 0);
    }

    #[test]
    fn goals_are_refused_naming_the_bound_or_the_camera_source() {
        let s = settings();
        let ok = ReachGoal {
            x_m: 0.4,
            y_m: 0.1,
            ..ReachGoal::default()
        };
        s.check(&ok).unwrap();
        let far = ReachGoal { x_m: 0.9, ..ok };
        assert!(
            s.check(&far)
                .unwrap_err()
                .contains("intake.goal_max_radius_m"),
            "{:?}",
            s.check(&far)
        );
        let late = ReachGoal {
            deadline_s: -1.0,
            ..ok
        };
        assert!(s.check(&late).unwrap_err().contains("deadline_s"));
        let camera = ReachSettings {
            goal_source_action: false,
            ..s
        };
        assert!(camera.check(&ok).unwrap_err().contains("goal source"));
        let t = s.target_m(&ok);
        assert!((t[2] - 0.10).abs() < 1e-9, "{t:?}");
    }

    #[test]
    fn the_bounds_and_the_source_are_read_from_the_shipped_runtime_config() {
        let text = include_str!("../../../assets/runtime.toml");
        let (bounds, action) = runtime_goal_settings(text).unwrap();
        assert!(!action, "the shipped source is the camera");
        assert_eq!(bounds, settings().bounds);
        let action_text = text.replace("source = \"camera\"", "source = \"action\"");
        assert!(runtime_goal_settings(&action_text).unwrap().1);
        let bad = text.replace("source = \"camera\"", "source = \"both\"");
        assert!(
            runtime_goal_settings(&bad)
                .unwrap_err()
                .contains("goal.source")
        );
    }

    #[test]
    fn a_cancel_request_s_goal_is_read_through_its_wire_form() {
        let id = GoalId::new_random();
        // The client's request, built the way ros2-client builds it.
        let json = serde_json::json!({
            "goal_info": serde_json::to_value(GoalInfo {
                goal_id: id,
                stamp: builtin_interfaces::Time::ZERO,
            })
            .unwrap()
        });
        let request: CancelGoalRequest = serde_json::from_value(json).unwrap();
        let info = mirror(&request).unwrap();
        assert_eq!(info.goal_id, id);
        assert_eq!(info.stamp, builtin_interfaces::Time::ZERO);
    }

    /// Issue 42 item 4: rt-core's goal-taken verdict is read into the `Reach` result's words;
    /// any other verdict carries no such reason.
    #[test]
    fn a_goal_taken_verdict_ends_the_goal_infeasible_with_its_reason() {
        let v = TwinVerdict {
            episode_end: shm_schemas::EpisodeEnd::GoalTaken as u8,
            taken_blocker: 0,
            taken_link: twin::LINK_TOOL,
            min_distance_m: -0.045,
            ..TwinVerdict::default()
        };
        v.validate().unwrap();
        let words = goal_taken_words(v.goal_taken_wire().unwrap());
        assert_eq!(
            words,
            "infeasible: no safe goal posture: box 0 blocks the tool by 45 mm"
        );
        let other = TwinVerdict {
            episode_end: shm_schemas::EpisodeEnd::Collision as u8,
            ..v
        };
        assert_eq!(other.goal_taken_wire(), None);
    }
}
