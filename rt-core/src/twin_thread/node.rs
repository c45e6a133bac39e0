//! The twin thread's iceoryx2 ends: detections and policies in; robot state, verdicts and
//! retrain requests out. [`TwinNode`] holds the ports and the counters of what crossed
//! them; every incoming sample is validated before the worker sees it.

// The twin thread's iceoryx2 ends (not real-time): publish periods and rate limits in wall time.
#![allow(clippy::disallowed_methods)]

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::node::CleanupState;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{LoanError, ReceiveError, SendError};
use iceoryx2::prelude::*;
use policy::{ActionSpaceRefusal, MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
use shm_schemas::services::{
    NodeCreateError, ShmOpenError, create_node, loan_zeroed, open_publisher, open_subscriber,
};
use shm_schemas::{
    EpisodeEnd, ObstacleBox, PolicyBlob, RetrainRequest, RobotState, SchemaError, TwinVerdict,
};
use twin::Scene;

use crate::cycle::shield::ShieldModel;
use crate::cycle::twin_model::TwinModel;
use crate::cycle::{CycleReport, LoopShared, Mode, StopReason};
use crate::twin_thread::intake::FrameNote;
use crate::twin_thread::lookahead::TwinLookahead;
use crate::twin_thread::{TwinEvent, TwinWorker, Verdict, VerdictSource};

/// The production twin worker.
pub type ProductionWorker = TwinWorker<TwinLookahead, TwinModel>;

/// Robot state is published at most this often (the cycle reports every period).
const STATE_PERIOD_NS: u64 = 4_000_000;

/// Why an iceoryx2 operation of the twin thread failed.
#[derive(Debug, thiserror::Error)]
pub enum TwinNodeError {
    /// The node could not be created.
    #[error("creating the iceoryx2 node")]
    NodeCreate(#[from] NodeCreateError),
    /// A service could not be opened.
    #[error("opening the {service} service: {cause}")]
    Open {
        /// The service.
        service: &'static str,
        /// iceoryx2's reason.
        cause: ShmOpenError,
    },
    /// Receiving from a subscriber failed.
    #[error("receiving {service}: {cause:?}")]
    Receive {
        /// The service.
        service: &'static str,
        /// iceoryx2's reason.
        cause: ReceiveError,
    },
    /// Loaning a sample failed.
    #[error("loaning a {service} sample: {cause:?}")]
    Loan {
        /// The service.
        service: &'static str,
        /// iceoryx2's reason.
        cause: LoanError,
    },
    /// Sending a sample failed.
    #[error("sending a {service} sample: {cause:?}")]
    Send {
        /// The service.
        service: &'static str,
        /// iceoryx2's reason.
        cause: SendError,
    },
    /// The start policy file could not be read.
    #[error("reading policy {}: {cause}", path.display())]
    PolicyRead {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        cause: std::io::Error,
    },
    /// The start policy file is not a valid blob.
    #[error("policy {} is invalid: {cause}", path.display())]
    PolicyInvalid {
        /// The file.
        path: PathBuf,
        /// The first schema error.
        cause: SchemaError,
    },
    /// The intake thread could not be started.
    #[error("starting the intake thread: {0}")]
    IntakeSpawn(std::io::ErrorKind),
    /// The intake thread ended without opening its ports (its error was returned at start).
    #[error("the intake thread did not start")]
    IntakeNotStarted,
    /// The intake thread panicked.
    #[error("the intake thread panicked")]
    IntakePanicked,
    /// The start policy acts in a space this rt-core does not know.
    #[error("policy {} refused: {refusal}", path.display())]
    PolicySpace {
        /// The file.
        path: PathBuf,
        /// The space, named.
        refusal: ActionSpaceRefusal,
    },
    /// The start policy is valid but not for this task.
    #[error("policy {} rejected: {reason:?}", path.display())]
    PolicyRejected {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: PolicyRejectReason,
    },
}

/// Reads the start policy file at `path` and checks it with `loader`: a policy in a space
/// this rt-core does not run is refused first, naming the space; then the blob's own
/// validation (the field-level reason), then the loader's check (counted).
///
/// # Errors
/// [`TwinNodeError::PolicyRead`], [`TwinNodeError::PolicySpace`],
/// [`TwinNodeError::PolicyInvalid`], [`TwinNodeError::PolicyRejected`].
fn read_start_policy(loader: &PolicyLoader, path: &Path) -> Result<MlpPolicy, TwinNodeError> {
    let blob = policy::read_policy_file(path).map_err(|e| TwinNodeError::PolicyRead {
        path: path.to_path_buf(),
        cause: e.into(),
    })?;
    // A space this rt-core does not run, named, before anything else is said of it.
    if let Some(refusal) = ActionSpaceRefusal::of(&blob) {
        return Err(TwinNodeError::PolicySpace {
            path: path.to_path_buf(),
            refusal,
        });
    }
    // The field-level reason for the operator; the loader checks again and counts.
    blob.validate()
        .map_err(|cause| TwinNodeError::PolicyInvalid {
            path: path.to_path_buf(),
            cause,
        })?;
    loader
        .prepare(&blob)
        .map_err(|reason| TwinNodeError::PolicyRejected {
            path: path.to_path_buf(),
            reason,
        })
}

/// The twin thread's ports and what crossed them.
pub struct TwinNode {
    _node: Node<ipc::Service>,
    /// What the intake thread has handed to the cycle and the plan guard, for planning.
    frames: mpsc::Receiver<FrameNote>,
    pol_sub: Subscriber<ipc::Service, PolicyBlob, ()>,
    state_pub: Publisher<ipc::Service, RobotState, ()>,
    verdict_pub: Publisher<ipc::Service, TwinVerdict, ()>,
    retrain_pub: Publisher<ipc::Service, RetrainRequest, ()>,
    loader: PolicyLoader,
    task_hash: u64,
    /// `false` with `--no-lookahead`: every verdict reads approved.
    gate: bool,
    scene_seq: u64,
    verdict_id: u64,
    last_verdict: Option<TwinVerdict>,
    last_state_ns: u64,
    last_cycles: u64,
    last_connections_update: Instant,
}

impl TwinNode {
    /// Creates the node and opens every service under `prefix` but the detections (the
    /// intake thread's, `twin_thread::intake_thread`, which sends what it handled to
    /// `frames`); policies must meet `expected` (the task hash and observation length).
    ///
    /// # Errors
    /// [`TwinNodeError::NodeCreate`], [`TwinNodeError::Open`].
    pub fn open(
        prefix: &str,
        expected: PolicyExpectation,
        frames: mpsc::Receiver<FrameNote>,
        gate: bool,
    ) -> Result<(Self, CleanupState), TwinNodeError> {
        let (node, cleanup) = create_node::<ipc::Service>("rt-core")?;
        let open = |service| move |cause| TwinNodeError::Open { service, cause };
        let pol_sub = open_subscriber::<PolicyBlob, _>(&node, prefix).map_err(open("policies"))?;
        let state_pub =
            open_publisher::<RobotState, _>(&node, prefix).map_err(open("robot state"))?;
        let verdict_pub =
            open_publisher::<TwinVerdict, _>(&node, prefix).map_err(open("verdicts"))?;
        let retrain_pub =
            open_publisher::<RetrainRequest, _>(&node, prefix).map_err(open("retrain requests"))?;
        let node_ends = Self {
            _node: node,
            frames,
            pol_sub,
            state_pub,
            verdict_pub,
            retrain_pub,
            loader: PolicyLoader::new(expected),
            task_hash: expected.task_config_hash,
            gate,
            scene_seq: 0,
            verdict_id: 0,
            last_verdict: None,
            last_state_ns: 0,
            last_cycles: 0,
            last_connections_update: Instant::now(),
        };
        Ok((node_ends, cleanup))
    }

    /// Loads a start policy from a file; like any policy, it must pass the lookahead.
    ///
    /// The file is read straight into a private blob, at most its size + 1 bytes
    /// ([`policy::read_policy_file`]): a file of another length (`--policy /dev/zero`
    /// included) is refused at once, naming the file and both sizes.
    ///
    /// # Errors
    /// [`TwinNodeError::PolicyRead`], [`TwinNodeError::PolicySpace`] (an unknown action
    /// space, named), [`TwinNodeError::PolicyInvalid`],
    /// [`TwinNodeError::PolicyRejected`].
    pub fn load_policy_file(
        &self,
        path: &Path,
        twin: &mut ProductionWorker,
        events: &mut Vec<TwinEvent<Scene>>,
    ) -> Result<(), TwinNodeError> {
        let policy = read_start_policy(&self.loader, path)?;
        tracing::info!(policy_id = policy.policy_id(), path = %path.display(), "start policy loaded; it must pass the lookahead");
        twin.on_policy(Box::new(policy), events);
        Ok(())
    }

    /// Notes every frame the intake thread handled (already with the cycle and the plan
    /// guard) and hands every policy blob (validated; bad ones are logged, counted and
    /// dropped) to the worker.
    ///
    /// # Errors
    /// [`TwinNodeError::Receive`].
    pub fn receive(
        &mut self,
        twin: &mut ProductionWorker,
        events: &mut Vec<TwinEvent<Scene>>,
    ) -> Result<(), TwinNodeError> {
        let recv_err = |service| move |cause| TwinNodeError::Receive { service, cause };
        while let Ok(note) = self.frames.try_recv() {
            match note {
                FrameNote::Accepted { frame, sequence } => {
                    self.scene_seq = sequence;
                    twin.note_frame(&frame, events);
                }
                FrameNote::Refused => twin.note_refused(),
            }
        }
        while let Some(sample) = self.pol_sub.receive().map_err(recv_err("policies"))? {
            // Copied into private memory before anything is checked: the publisher's process
            // can still write the shared sample, and a value changed between its check and
            // its use (e.g. a clip bound) would bypass validation. The loader only takes
            // the copy (`&Box<PolicyBlob>`).
            let blob = sample.payload().to_boxed();
            drop(sample);
            match self.loader.prepare(&blob) {
                Ok(p) => {
                    tracing::info!(
                        policy_id = p.policy_id(),
                        "policy accepted; re-running the lookahead"
                    );
                    twin.on_policy(Box::new(p), events);
                }
                Err(reason) => tracing::warn!(
                    policy_id = blob.policy_id,
                    ?reason,
                    detail = ?blob.validate().err(),
                    space = ActionSpaceRefusal::of(&blob).map(|r| r.to_string()),
                    rejected_total = self.loader.counters().total_rejected(),
                    "policy blob rejected; the running policy stays"
                ),
            }
        }
        Ok(())
    }

    /// Publishes (verdicts, retrain requests) and logs every event, leaving `events` empty.
    ///
    /// # Errors
    /// [`TwinNodeError::Loan`], [`TwinNodeError::Send`].
    pub fn publish_events(
        &mut self,
        events: &mut Vec<TwinEvent<Scene>>,
        now_ns: u64,
        rate_hz: f64,
    ) -> Result<(), TwinNodeError> {
        for e in events.drain(..) {
            match e {
                TwinEvent::Verdict {
                    verdict,
                    elapsed_s,
                    source,
                    ..
                } => self.publish_verdict(&verdict, elapsed_s, source, now_ns)?,
                TwinEvent::Retrain {
                    request_id,
                    verdict,
                    scene,
                } => self.publish_retrain(request_id, &verdict, &scene, now_ns)?,
                TwinEvent::NoGoal { policy_id } => self.publish_no_goal(policy_id, now_ns)?,
                TwinEvent::NotLearned {
                    verdict, refusals, ..
                } => self.publish_not_learned(&verdict, refusals, now_ns)?,
                TwinEvent::GoalTaken {
                    reason, policy_id, ..
                } => self.publish_goal_taken(&reason, policy_id, now_ns)?,
                other => log_event(&other, rate_hz),
            }
        }
        Ok(())
    }

    fn publish_verdict(
        &mut self,
        verdict: &Verdict,
        elapsed_s: f64,
        source: VerdictSource,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        self.verdict_id += 1;
        let mut v = twin_verdict(
            verdict,
            self.verdict_id,
            self.scene_seq,
            now_ns,
            elapsed_s,
            self.gate,
        );
        v.phase = source.phase as u8;
        v.executor = source.executor as u8;
        tracing::info!(
            policy_id = verdict.policy_id,
            phase = source.phase.name(),
            executor = source.executor.name(),
            task_ok = verdict.task_ok,
            safe = verdict.safe,
            steps = verdict.steps,
            min_distance_m = verdict.min_distance_m,
            lookahead_ms = elapsed_s * 1e3,
            sample = ?source.sample.map(|t| format!("sample {} of {}", t.index, t.of)),
            "lookahead"
        );
        self.last_verdict = Some(v);
        let mut s = loan_zeroed(&self.verdict_pub).map_err(|cause| TwinNodeError::Loan {
            service: "verdicts",
            cause,
        })?;
        *s.payload_mut() = v;
        s.send().map_err(|cause| TwinNodeError::Send {
            service: "verdicts",
            cause,
        })?;
        Ok(())
    }

    /// A verdict saying why nothing is planned: a box has taken the goal
    /// ([`EpisodeEnd::GoalTaken`], the reason in `taken_blocker`, `taken_link` and minus the
    /// shortfall in `min_distance_m`: [`TwinVerdict::goal_taken_wire`]).
    fn publish_goal_taken(
        &mut self,
        reason: &twin::InfeasibleReason,
        policy_id: u64,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        self.verdict_id += 1;
        let (_, blocker, link, by_m) = reason.wire();
        let mut v = TwinVerdict {
            verdict_id: self.verdict_id,
            scene_sequence: self.scene_seq,
            policy_id,
            computed_time_ns: now_ns,
            min_distance_m: -f64::from(by_m),
            episode_end: EpisodeEnd::GoalTaken as u8,
            taken_blocker: blocker,
            taken_link: link,
            ..TwinVerdict::default()
        };
        v.set_flags(false, true, false);
        tracing::warn!(
            policy_id,
            "infeasible: {reason}: the arm holds until the box leaves"
        );
        self.send_verdict(v)
    }

    /// A verdict saying why nothing is planned: no goal in the latest frame.
    fn publish_no_goal(&mut self, policy_id: u64, now_ns: u64) -> Result<(), TwinNodeError> {
        self.verdict_id += 1;
        let mut v = TwinVerdict {
            verdict_id: self.verdict_id,
            scene_sequence: self.scene_seq,
            policy_id,
            computed_time_ns: now_ns,
            episode_end: EpisodeEnd::NoGoal as u8,
            ..TwinVerdict::default()
        };
        v.set_flags(false, true, false);
        tracing::warn!(
            policy_id,
            "no goal in the latest detection frame (none, or below the confidence floor): \
             nothing is planned, the arm holds"
        );
        self.send_verdict(v)
    }

    /// A verdict saying the scene is not learned: `refusals` retrained policies were
    /// refused in it; the last one's figures.
    fn publish_not_learned(
        &mut self,
        verdict: &Verdict,
        refusals: u32,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        self.verdict_id += 1;
        let mut v = twin_verdict(
            verdict,
            self.verdict_id,
            self.scene_seq,
            now_ns,
            0.0,
            self.gate,
        );
        v.episode_end = EpisodeEnd::NotLearned as u8;
        v.set_flags(false, verdict.safe, false);
        tracing::warn!(
            policy_id = verdict.policy_id,
            refusals,
            min_distance_m = verdict.min_distance_m,
            goal_reached = verdict.task_ok,
            "not learned: every retrained policy for this scene was refused (the last one: \
             {}); no more retraining is asked for it",
            refusal_reason(verdict)
        );
        self.send_verdict(v)
    }

    /// Publishes `v` (and keeps it as the last verdict).
    fn send_verdict(&mut self, v: TwinVerdict) -> Result<(), TwinNodeError> {
        self.last_verdict = Some(v);
        let mut s = loan_zeroed(&self.verdict_pub).map_err(|cause| TwinNodeError::Loan {
            service: "verdicts",
            cause,
        })?;
        *s.payload_mut() = v;
        s.send().map_err(|cause| TwinNodeError::Send {
            service: "verdicts",
            cause,
        })?;
        Ok(())
    }

    fn publish_retrain(
        &mut self,
        request_id: u64,
        verdict: &Verdict,
        scene: &Scene,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        let mut s = loan_zeroed(&self.retrain_pub).map_err(|cause| TwinNodeError::Loan {
            service: "retrain requests",
            cause,
        })?;
        let r = s.payload_mut();
        r.request_id = request_id;
        r.request_time_ns = now_ns;
        r.task_config_hash = self.task_hash;
        r.failed_policy_id = verdict.policy_id;
        r.scene_sequence = self.scene_seq;
        r.table_height_m = scene.table_height_m;
        r.goal_center_m = scene.goal.center_m;
        r.goal_size_m = scene.goal.size_m;
        r.obstacle_count = scene.obstacles.len() as u32;
        for (slot, b) in r.obstacles.iter_mut().zip(scene.obstacles.iter()) {
            *slot = ObstacleBox {
                center_m: b.center_m,
                size_m: b.size_m,
            };
        }
        r.verdict = self.last_verdict.unwrap_or_default();
        tracing::warn!(
            request_id,
            policy_id = verdict.policy_id,
            "lookahead failed: retrain requested"
        );
        s.send().map_err(|cause| TwinNodeError::Send {
            service: "retrain requests",
            cause,
        })?;
        Ok(())
    }

    /// Publishes the cycle's last report at once (at shutdown), whatever the rate limit.
    ///
    /// # Errors
    /// [`TwinNodeError::Loan`], [`TwinNodeError::Send`].
    pub fn publish_final_state(
        &mut self,
        report: Option<&CycleReport>,
        shared: &LoopShared,
        fk: &mut TwinModel,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        self.last_state_ns = 0;
        self.publish_state(report, shared, fk, now_ns)
    }

    /// Publishes the robot state from the cycle's latest report (at most every 4 ms and
    /// once per cycle), and now and then lets the retrain publisher see new subscribers: a
    /// learner that (re)connects gets the last retrain request from the service's history,
    /// so a learner restarted mid-retraining picks the request up again.
    ///
    /// # Errors
    /// [`TwinNodeError::Loan`], [`TwinNodeError::Send`].
    pub fn publish_state(
        &mut self,
        report: Option<&CycleReport>,
        shared: &LoopShared,
        fk: &mut TwinModel,
        now_ns: u64,
    ) -> Result<(), TwinNodeError> {
        if self.last_connections_update.elapsed() >= Duration::from_millis(100) {
            self.last_connections_update = Instant::now();
            if let Err(e) = self.retrain_pub.update_connections() {
                tracing::debug!("retrain request connections: {e:?}");
            }
        }
        let Some(r) = report else { return Ok(()) };
        if now_ns.saturating_sub(self.last_state_ns) < STATE_PERIOD_NS
            || r.cycles == self.last_cycles
        {
            return Ok(());
        }
        self.last_cycles = r.cycles;
        self.last_state_ns = now_ns;
        let mut s = loan_zeroed(&self.state_pub).map_err(|cause| TwinNodeError::Loan {
            service: "robot state",
            cause,
        })?;
        fill_robot_state(s.payload_mut(), r, shared, fk);
        s.send().map_err(|cause| TwinNodeError::Send {
            service: "robot state",
            cause,
        })?;
        Ok(())
    }
}

fn fill_robot_state(st: &mut RobotState, r: &CycleReport, shared: &LoopShared, fk: &mut TwinModel) {
    st.time_ns = r.t_ns;
    st.cycle_count = r.cycles;
    st.missed_deadlines = shared.missed_deadlines.load(Ordering::Relaxed);
    st.active_policy_id = r.policy_id;
    st.joints_rad = r.measured_q_rad;
    st.joint_velocities_rad_s = r.cmd.dq_rad_s;
    st.command_joints_rad = r.cmd.q_rad;
    st.tcp_m = fk.tcp_position_m(&r.measured_q_rad);
    st.last_compute_us = shared.last_compute_ns.load(Ordering::Relaxed) as f32 / 1000.0;
    st.controlled_stop = u8::from(matches!(r.mode, Mode::Stopping | Mode::Stopped));
    st.stop_reason = stop_code(r.stop_reason) as u8;
    st.arm_mode = r.arm_mode;
    st.arm_state = r.arm_state;
    st.arm_error_code = u8::try_from(r.arm_error_code).unwrap_or(u8::MAX);
    st.link_ok = u8::from(r.stop_reason != StopReason::LinkLost || r.mode == Mode::Following);
}

/// Logs the events that are not published.
fn log_event(e: &TwinEvent<Scene>, rate_hz: f64) {
    match e {
        TwinEvent::PlanApproved {
            plan_id,
            policy_id,
            joins,
        } => tracing::info!(plan_id, policy_id, joins, "plan approved"),
        TwinEvent::PlanRejected { policy_id, why } => {
            tracing::warn!(policy_id, ?why, "plan rejected after the lookahead");
        }
        TwinEvent::AwaitingSettledScene { stamp_ns } => tracing::info!(
            stamp_ns,
            "scene not settled (perception still confirming a change): planning waits"
        ),
        TwinEvent::Revoked { plan_id, at_index } => tracing::warn!(
            plan_id,
            at_index,
            "scene change: running plan unsafe, controlled stop"
        ),
        TwinEvent::StopScheduled {
            plan_id,
            at_index,
            stop_due_index,
        } => tracing::info!(
            plan_id,
            at_index,
            stop_due_index,
            "scene change: running plan unsafe ahead, stop scheduled unless a joining plan takes over"
        ),
        TwinEvent::PolicySwapped { policy_id } => tracing::info!(policy_id, "policy swapped in"),
        TwinEvent::BackingOut {
            plan_id,
            samples,
            clearance_m,
        } => tracing::info!(
            plan_id,
            duration_s = *samples as f64 / rate_hz,
            clearance_m,
            "too close to a box at rest: backing out along the path it came"
        ),
        TwinEvent::ReturningHome { plan_id, samples } => tracing::info!(
            plan_id,
            duration_s = *samples as f64 / rate_hz,
            "goal reached: returning home along the executed path"
        ),
        TwinEvent::ReturnHomeRefused { why } => tracing::warn!(
            ?why,
            "the way home is unsafe in the current scene: holding; the lookahead takes over"
        ),
        TwinEvent::RetrainingRefused { verdict, refusals } => tracing::warn!(
            policy_id = verdict.policy_id,
            refusals,
            min_distance_m = verdict.min_distance_m,
            "retraining refused: the retrained policy fails in the scene it was trained for ({}); \
             retraining is asked for again with this verdict",
            refusal_reason(verdict)
        ),
        TwinEvent::Verdict { .. }
        | TwinEvent::Retrain { .. }
        | TwinEvent::NoGoal { .. }
        | TwinEvent::NotLearned { .. }
        | TwinEvent::GoalTaken { .. } => {}
    }
}

/// Why a verdict failed, in words (the refused retraining's reason; the smoothed plan's
/// own rejection, which sample and check, is logged just before it).
fn refusal_reason(v: &Verdict) -> &'static str {
    match (v.task_ok, v.safe) {
        (_, false) => "its plan comes closer to an obstacle than the clearance",
        (false, true) => "its plan does not reach the goal",
        (true, true) => "its plan passes",
    }
}

/// The stop reason as the contract spells it.
pub fn stop_code(reason: StopReason) -> shm_schemas::StopReason {
    use shm_schemas::StopReason as S;
    match reason {
        StopReason::None => S::None,
        StopReason::Shield(_) | StopReason::Revoked => S::ShieldViolation,
        StopReason::StaleDetection => S::StaleDetections,
        StopReason::StaleRobotState => S::StaleRobotState,
        StopReason::LinkLost => S::LinkLost,
        StopReason::ArmError(_) => S::ArmError,
        StopReason::Shutdown => S::Requested,
        StopReason::DetectionRefused => S::DetectionRefused,
        StopReason::ModelMismatch => S::ModelMismatch,
        // The contract's nearest codes (no schema change): a stop the controller made on
        // its own, and measured joints that disagree with the commands.
        StopReason::ControllerStopped { .. } => S::ArmError,
        StopReason::TrackingLost => S::ModelMismatch,
        // The cycle itself went stale (a stopped process): the nearest contract code.
        StopReason::Frozen => S::StaleRobotState,
    }
}

/// The published verdict; with the lookahead gate off (`--no-lookahead`) every plan goes
/// to the arm, so every verdict reads approved.
pub fn twin_verdict(
    v: &Verdict,
    id: u64,
    seq: u64,
    now_ns: u64,
    elapsed_s: f64,
    gate: bool,
) -> TwinVerdict {
    let mut t = TwinVerdict {
        verdict_id: id,
        scene_sequence: seq,
        policy_id: v.policy_id,
        computed_time_ns: now_ns,
        min_distance_m: v.min_distance_m.clamp(-10.0, 10.0),
        episode_return: 0.0,
        steps: v.steps,
        lookahead_compute_us: (elapsed_s * 1e6).min(f64::from(u32::MAX)) as u32,
        episode_end: if v.task_ok {
            EpisodeEnd::Success as u8
        } else if !v.safe {
            EpisodeEnd::Collision as u8
        } else {
            EpisodeEnd::Timeout as u8
        },
        ..TwinVerdict::default()
    };
    t.set_flags(v.task_ok, v.safe, (v.task_ok && v.safe) || !gate);
    t
}

#[cfg(test)]
mod tests {
    use shm_schemas::{
        ACT_DIM, ActionSpace, JOINT_ACT_DIM, JOINT_OBS_DIM, OBS_DIM, PolicyBlob, PolicyBlobBuilder,
    };

    use super::*;

    const TASK: u64 = 0x40_0003;

    fn file_of(name: &str, blob: &PolicyBlob) -> PathBuf {
        let path = std::env::temp_dir().join(format!(
            "foresight-start-policy-{}-{name}.blob",
            std::process::id()
        ));
        std::fs::write(&path, blob.as_bytes()).expect("temp file");
        path
    }

    /// Issue 40 item 3: a start policy in a space rt-core runs is loaded (the Cartesian step,
    /// the joint step); one in a space it does not know is refused, and the error names it.
    #[test]
    fn a_start_policy_is_run_or_refused_naming_its_action_space() {
        let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
        let cartesian = PolicyBlobBuilder::random(3, TASK, OBS_DIM, &[16], ACT_DIM, 1)
            .build()
            .expect("cartesian blob");
        let path = file_of("cartesian", &cartesian);
        let loaded = read_start_policy(&loader, &path);
        let _ = std::fs::remove_file(&path);
        assert_eq!(loaded.expect("run").policy_id(), 3);

        let joint = PolicyBlobBuilder::random(4, TASK, JOINT_OBS_DIM, &[16], JOINT_ACT_DIM, 1)
            .action_space(ActionSpace::JointStep)
            .build()
            .expect("joint blob");
        let path = file_of("joint", &joint);
        let loaded = read_start_policy(&loader, &path);
        let _ = std::fs::remove_file(&path);
        assert_eq!(loaded.expect("run").action_space(), ActionSpace::JointStep);

        let mut unknown = PolicyBlob::new_boxed();
        unknown.copy_from(&cartesian);
        unknown.action_space = 5;
        unknown.seal();
        let path = file_of("unknown", &unknown);
        let refused = read_start_policy(&loader, &path);
        let _ = std::fs::remove_file(&path);
        let Err(err) = refused else {
            panic!("accepted");
        };
        assert!(err.to_string().contains("action space byte 5"), "{err}");
    }
}
