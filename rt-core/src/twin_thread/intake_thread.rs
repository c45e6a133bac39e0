//! The intake thread of `rt-core run`: detection frames in, through the scene intake, and
//! out on the [`ScenePath`] — the cycle's shield has an accepted frame's scene within one
//! cycle, and the plan guard has re-verified every live plan against it — whatever the twin
//! thread is doing meanwhile (a planner search, a lookahead, a policy hand-over). The twin
//! thread learns of each frame afterwards through a channel ([`FrameNote`]), for planning.
//!
//! The thread has an iceoryx2 node of its own (ports stay on the thread that made them). It
//! polls its subscriber every [`POLL_PERIOD`] and ends when `stop` is set, returning what it
//! counted ([`IntakeFigures`]).
//!
//! With the goal source `action` it also takes the bridge's [`GoalRequest`]s (the ROS 2
//! `Reach` action) into the intake before each poll's frames, so the next accepted frame
//! carries the requested goal; a cancel or a pre-emption is handed to the plan guard here at
//! once ([`ScenePath::goal_withdrawn`]), not through the twin thread. A request refused (by
//! age: a replay to a restarted rt-core, or one that waited too long) is answered to the
//! bridge as a [`GoalRefusal`], so that the action goal behind it ends at once, naming why.

// A non-real-time thread: it polls its subscriber with a relative sleep and reads wall time
// for the logs' throttling only.
#![allow(clippy::disallowed_methods)]

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use shm_schemas::services::{
    ShmOpenError, create_node, open_publisher, open_service, open_subscriber,
};
use shm_schemas::{DetectionFrame, GoalRefusal, GoalRequest};

use crate::cycle::twin_model::TwinModel;
use crate::rt::histogram::{Histogram, Summary};
use crate::twin_thread::intake::{AcceptedFrame, FrameNote, IntakeCounters, SceneIntake};
use crate::twin_thread::node::TwinNodeError;
use crate::twin_thread::scene_path::ScenePath;

/// How often the thread looks for new frames.
pub const POLL_PERIOD: Duration = Duration::from_micros(100);

/// What the intake thread counted.
#[derive(Debug, Clone, Copy)]
pub struct IntakeFigures {
    /// Frames accepted and refused (per reason).
    pub counters: IntakeCounters,
    /// Capture → checked and handed to the cycle, µs.
    pub detection_age: Summary,
}

/// The running intake thread.
pub struct IntakeThread {
    handle: JoinHandle<Result<IntakeFigures, TwinNodeError>>,
}

impl IntakeThread {
    /// Waits for the thread to end (set its `stop` first) and returns its figures.
    ///
    /// # Errors
    /// The thread's iceoryx2 error; a panic of the thread is returned as
    /// [`TwinNodeError::IntakePanicked`].
    pub fn join(self) -> Result<IntakeFigures, TwinNodeError> {
        self.handle
            .join()
            .unwrap_or(Err(TwinNodeError::IntakePanicked))
    }

    /// Whether the thread has ended (an error, a panic, or `stop`).
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }
}

/// Starts the intake thread on the detection service under `prefix`: every frame through
/// `intake`, accepted scenes and refusals onto `path`, then a [`FrameNote`] to `notes`.
/// Returns once the thread's subscriber is open.
///
/// # Errors
/// [`TwinNodeError::NodeCreate`] / [`TwinNodeError::Open`] when the node or the service
/// cannot be opened; [`TwinNodeError::IntakeSpawn`] when the thread cannot start.
pub fn spawn_intake_thread(
    prefix: &str,
    intake: SceneIntake,
    path: ScenePath<TwinModel>,
    notes: mpsc::Sender<FrameNote>,
    stop: Arc<AtomicBool>,
) -> Result<IntakeThread, TwinNodeError> {
    let prefix = prefix.to_owned();
    let (ready_tx, ready_rx) = mpsc::sync_channel::<Result<(), TwinNodeError>>(1);
    let handle = std::thread::Builder::new()
        .name("rt-intake".into())
        .spawn(move || run(&prefix, intake, path, &notes, &stop, &ready_tx))
        .map_err(|e| TwinNodeError::IntakeSpawn(e.kind()))?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(IntakeThread { handle }),
        Ok(Err(e)) => Err(e),
        // The thread ended before it said anything: its own result says why.
        Err(_) => Err(IntakeThread { handle }
            .join()
            .err()
            .unwrap_or(TwinNodeError::IntakePanicked)),
    }
}

fn run(
    prefix: &str,
    mut intake: SceneIntake,
    mut path: ScenePath<TwinModel>,
    notes: &mpsc::Sender<FrameNote>,
    stop: &AtomicBool,
    ready: &mpsc::SyncSender<Result<(), TwinNodeError>>,
) -> Result<IntakeFigures, TwinNodeError> {
    let ends = match open_ends(prefix, intake.takes_requests()) {
        Ok(ends) => {
            let _ = ready.send(Ok(()));
            ends
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(TwinNodeError::IntakeNotStarted);
        }
    };
    let IntakeEnds {
        _node,
        service,
        sub,
        goals,
    } = ends;
    let mut frames = FramePoll {
        sub,
        service,
        drain: FrameDrain::default(),
        refusals_in_a_row: 0,
        age: Histogram::new(),
    };
    while !stop.load(Ordering::Acquire) {
        if let Some(goals) = &goals {
            take_goal_requests(goals, &mut intake, &mut path)?;
        }
        frames.take(&mut intake, &mut path, notes)?;
        std::thread::sleep(POLL_PERIOD);
    }
    if frames.drain.superseded > 0 {
        tracing::info!(
            superseded = frames.drain.superseded,
            "accepted frames superseded by a newer one in the same poll (checked and counted, not re-verified against)"
        );
    }
    Ok(IntakeFigures {
        counters: *intake.counters(),
        detection_age: frames.age.summary(),
    })
}

/// The detection frames' end of the intake thread: its subscriber, what one poll keeps and
/// what the thread measures.
struct FramePoll {
    sub: Subscriber<ipc::Service, DetectionFrame, ()>,
    service: PubSubFactory<ipc::Service, DetectionFrame, ()>,
    drain: FrameDrain,
    refusals_in_a_row: u64,
    /// Capture → handed to the cycle, of the frames handed on.
    age: Histogram,
}

impl FramePoll {
    /// One poll: every waiting frame is checked and counted, in order (a refused one stops
    /// the arm at once); only the newest accepted one goes on to the plan guard, the cycle
    /// and the twin thread (issue 42 item 6: a starved thread catching up re-verifies the
    /// plans once, against the world as it is now, not once per stale frame).
    fn take(
        &mut self,
        intake: &mut SceneIntake,
        path: &mut ScenePath<TwinModel>,
        notes: &mpsc::Sender<FrameNote>,
    ) -> Result<(), TwinNodeError> {
        while let Some(sample) = self.sub.receive().map_err(|cause| TwinNodeError::Receive {
            service: "detections",
            cause,
        })? {
            // Copied out of shared memory before it is checked (the publisher can still
            // write the sample).
            let frame = *sample.payload();
            drop(sample);
            let publishers = self.service.dynamic_config().number_of_publishers();
            let mono_now_ns = shm_schemas::clock::monotonic_now_ns();
            match intake.accept(&frame, mono_now_ns, publishers) {
                Ok(accepted) => {
                    self.drain
                        .accepted(accepted, frame.sequence, frame.capture_time_ns);
                    self.refusals_in_a_row = 0;
                }
                Err(refusal) => {
                    self.drain.refused();
                    path.refused();
                    if self.refusals_in_a_row.is_multiple_of(100) {
                        tracing::warn!(
                            sequence = frame.sequence,
                            camera_id = frame.camera_id,
                            refused_total = intake.counters().total_refused(),
                            "detection frame refused, the arm stops: {refusal}"
                        );
                    }
                    self.refusals_in_a_row += 1;
                    let _ = notes.send(FrameNote::Refused);
                }
            }
        }
        if let Some(newest) = self.drain.take() {
            path.accepted(
                newest.frame.scene,
                newest.frame.stamp_ns,
                newest.frame.intruders,
            );
            self.age.record_ns(
                shm_schemas::clock::monotonic_now_ns().saturating_sub(newest.capture_time_ns),
            );
            let _ = notes.send(FrameNote::Accepted {
                frame: newest.frame,
                sequence: newest.sequence,
            });
        }
        Ok(())
    }
}

/// The newest accepted frame of one poll, and what the older ones it supersedes carried
/// that must not be lost: a cancel's stop request rides on the next frame delivered.
#[derive(Debug)]
struct FrameDrain<S = twin::Scene> {
    newest: Option<Newest<S>>,
    /// A stop was requested by a frame not delivered yet.
    stop_requested: bool,
    /// Accepted frames superseded before delivery, since start.
    superseded: u64,
}

/// An accepted frame waiting for delivery.
#[derive(Debug, Clone, Copy)]
struct Newest<S> {
    frame: AcceptedFrame<S>,
    sequence: u64,
    capture_time_ns: u64,
}

impl<S> Default for FrameDrain<S> {
    fn default() -> Self {
        Self {
            newest: None,
            stop_requested: false,
            superseded: 0,
        }
    }
}

impl<S> FrameDrain<S> {
    /// An accepted frame: it supersedes an older one not delivered yet.
    fn accepted(&mut self, frame: AcceptedFrame<S>, sequence: u64, capture_time_ns: u64) {
        self.stop_requested |= frame.stop_requested;
        if self.newest.is_some() {
            self.superseded += 1;
        }
        self.newest = Some(Newest {
            frame,
            sequence,
            capture_time_ns,
        });
    }

    /// A refused frame (delivered at once by the caller): an accepted frame older than it
    /// is stale and never delivered; a stop it requested waits for the next accepted one.
    fn refused(&mut self) {
        if self.newest.take().is_some() {
            self.superseded += 1;
        }
    }

    /// The frame to deliver, carrying every stop requested since the last delivery.
    fn take(&mut self) -> Option<Newest<S>> {
        let mut newest = self.newest.take()?;
        newest.frame.stop_requested |= std::mem::take(&mut self.stop_requested);
        Some(newest)
    }
}

/// The intake thread's iceoryx2 ends (made on the thread: ports stay where they were made).
struct IntakeEnds {
    _node: Node<ipc::Service>,
    service: PubSubFactory<ipc::Service, DetectionFrame, ()>,
    sub: Subscriber<ipc::Service, DetectionFrame, ()>,
    /// The bridge's goal requests, and the answer to those refused (goal source `action`
    /// only).
    goals: Option<GoalEnds>,
}

/// The goal requests' subscriber and the refusals' publisher.
struct GoalEnds {
    requests: Subscriber<ipc::Service, GoalRequest, ()>,
    refusals: Publisher<ipc::Service, GoalRefusal, ()>,
}

/// Opens the node, the detection service and its subscriber under `prefix`, and the goal
/// requests' subscriber and the refusals' publisher when the intake `takes_requests`.
fn open_ends(prefix: &str, takes_requests: bool) -> Result<IntakeEnds, TwinNodeError> {
    let (node, _) = create_node::<ipc::Service>("rt-core-intake")?;
    let service =
        open_service::<DetectionFrame, _>(&node, prefix).map_err(|cause| TwinNodeError::Open {
            service: "detections",
            cause,
        })?;
    let sub = service
        .subscriber_builder()
        .create()
        .map_err(|error| TwinNodeError::Open {
            service: "detections",
            cause: ShmOpenError::Subscriber {
                service: "detections",
                error,
            },
        })?;
    let goals = if takes_requests {
        Some(GoalEnds {
            requests: open_subscriber::<GoalRequest, _>(&node, prefix).map_err(|cause| {
                TwinNodeError::Open {
                    service: "goal requests",
                    cause,
                }
            })?,
            refusals: open_publisher::<GoalRefusal, _>(&node, prefix).map_err(|cause| {
                TwinNodeError::Open {
                    service: "goal refusals",
                    cause,
                }
            })?,
        })
    } else {
        None
    };
    Ok(IntakeEnds {
        _node: node,
        service,
        sub,
        goals,
    })
}

/// Takes every goal request waiting into `intake` (each copied out of shared memory before
/// it is checked), logging what was taken or refused. A cancel or a pre-emption among them
/// revokes every plan toward the withdrawn goal through `path`, here on the intake thread,
/// before the next frame and whatever the twin thread is doing (a planner search may be
/// about to hand over a plan toward it: the plan guard refuses it). A refused request is
/// answered on the refusals' service.
fn take_goal_requests(
    goals: &GoalEnds,
    intake: &mut SceneIntake,
    path: &mut ScenePath<TwinModel>,
) -> Result<(), TwinNodeError> {
    let goal_epoch = intake.goal_epoch();
    while let Some(sample) = goals
        .requests
        .receive()
        .map_err(|cause| TwinNodeError::Receive {
            service: "goal requests",
            cause,
        })?
    {
        // Copied out of shared memory before it is checked.
        let request = *sample.payload();
        drop(sample);
        let now_ns = shm_schemas::clock::monotonic_now_ns();
        match intake.request(&request, now_ns) {
            Ok(()) => tracing::info!(
                goal_id = request.goal_id,
                command = request.command,
                target_m = ?request.target_m,
                approach_height_m = request.approach_height_m,
                "goal request taken"
            ),
            Err(refusal) => {
                tracing::warn!(
                    goal_id = request.goal_id,
                    refused_total = intake.counters().goal_requests_refused,
                    "goal request refused: {refusal}"
                );
                if let Err(e) = goals.refusals.send_copy(refusal.wire(&request, now_ns)) {
                    tracing::warn!(
                        goal_id = request.goal_id,
                        "the bridge could not be told of the refusal: {e:?}"
                    );
                }
            }
        }
    }
    if intake.goal_epoch() != goal_epoch {
        path.goal_withdrawn(intake.goal_epoch());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame over a stand-in scene (the drain never looks at the scene).
    fn frame(stamp_ns: u64, stop_requested: bool) -> AcceptedFrame<u32> {
        let mut f = AcceptedFrame::settled(7, stamp_ns);
        f.stop_requested = stop_requested;
        f
    }

    #[test]
    fn only_the_newest_accepted_frame_of_a_poll_goes_on_and_a_stop_request_is_never_lost() {
        let mut drain = FrameDrain::<u32>::default();
        assert!(drain.take().is_none(), "nothing waiting");
        // Three frames waited (a starved thread): the newest goes on, with the older
        // frame's stop request.
        drain.accepted(frame(1, false), 1, 10);
        drain.accepted(frame(2, true), 2, 20);
        drain.accepted(frame(3, false), 3, 30);
        let newest = drain.take().unwrap();
        assert_eq!((newest.sequence, newest.frame.stamp_ns), (3, 3));
        assert!(
            newest.frame.stop_requested,
            "the cancel's stop rides on the newest"
        );
        assert_eq!(drain.superseded, 2);
        assert!(drain.take().is_none());
        // An accepted frame older than a refusal is stale: not delivered; its stop request
        // waits for the next accepted frame.
        drain.accepted(frame(4, true), 4, 40);
        drain.refused();
        assert!(drain.take().is_none());
        drain.accepted(frame(5, false), 5, 50);
        let next = drain.take().unwrap();
        assert_eq!(next.sequence, 5);
        assert!(next.frame.stop_requested);
        // Delivered once: the next frame carries no stale request.
        drain.accepted(frame(6, false), 6, 60);
        assert!(!drain.take().unwrap().frame.stop_requested);
    }
}
