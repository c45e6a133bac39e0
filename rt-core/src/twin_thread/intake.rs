//! Scene intake: what rt-core accepts from perception. A [`DetectionFrame`] becomes the
//! twin's [`Scene`] only when nothing in it is hidden, stale or implausible; otherwise the
//! whole frame is refused with a [`FrameRefusal`] naming the reason, counted, and the cycle
//! stops the arm (a refused frame is never half-used).
//!
//! Refused:
//! - an invalid frame, or one that does not fit (`dropped_count` > 0: perception saw more
//!   objects than a frame and the twin hold) — see [`DetectionFrame::validate`];
//! - a stamp that is zero, in the future, older than the configured age, or from before
//!   rt-core's clock began (stamps are `CLOCK_MONOTONIC`, shared by every process; a frame
//!   that cannot be dated on the cycle's clock is not made to look younger);
//! - an object centred outside the calibrated workspace, or a goal out of reach;
//! - a frame from a second publisher, another camera, or with a sequence that did not
//!   increase (someone else is writing the detection service).
//!
//! A frame without a goal (none, or one below the confidence floor) is accepted — its
//! obstacles count — but nothing is planned until a goal is seen again. Likewise a frame not
//! marked settled (`DetectionFrame::FRAME_SETTLED`: perception is still confirming a
//! changing world) is accepted and re-verified against, but no plan is approved on it: the
//! worker waits for a settled frame.
//!
//! With the goal source `action` ([`SceneIntake::with_requested_goals`]), the goal is the one
//! the ROS 2 `Reach` action asks for ([`GoalRequest`]s from `ros-bridge`, checked here again
//! against the same bounds the bridge checked, [`SceneIntake::request`]): the camera's goal
//! cube is not the goal but an obstacle like any other, and a frame has a goal only while an
//! action goal is active. With the goal source `camera` a goal-class detection below the
//! confidence floor is an obstacle too (issue 41 item 2: a cube in view that is not the goal
//! is a physical object the arm must not hit).

use shm_schemas::goal_request::{REQUESTED_GOAL_SIZE_M, requested_goal_center_m};
use shm_schemas::{
    DetectedObject, DetectionFrame, GoalBoundError, GoalBounds, GoalCommand, GoalRefusal,
    GoalRefusalKind, GoalRequest, GoalRequestAgeError, ObjectClass, SchemaError,
};
use twin::{BoxObstacle, Goal, Scene};

use crate::config::IntakeConfig;
use crate::cycle::Intruders;

/// Grid every detected position and size is snapped to, m: sensor noise below it does not
/// count as a scene change (a change re-runs the lookahead).
pub const SNAP_GRID_M: f64 = 0.005;

/// Why a detection frame was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum FrameRefusal {
    /// The frame failed its schema validation.
    #[error("invalid frame: {0}")]
    Invalid(SchemaError),
    /// Perception saw more objects than fit: some obstacle would be hidden.
    #[error(
        "frame does not fit: {dropped} object(s) left out beyond the {kept} carried (capacity {})",
        shm_schemas::MAX_DETECTIONS
    )]
    Overfull {
        /// Objects carried.
        kept: u32,
        /// Objects left out.
        dropped: u32,
    },
    /// `capture_time_ns` is 0.
    #[error("capture_time_ns is 0 (no stamp)")]
    NoStamp,
    /// `capture_time_ns` lies in the future.
    #[error("capture_time_ns is {ahead_ns} ns in the future")]
    FutureStamp {
        /// How far ahead, ns.
        ahead_ns: u64,
    },
    /// The frame is older than the configured age.
    #[error("capture_time_ns is {age_ns} ns old (at most {max_age_ns} ns allowed)")]
    Stale {
        /// Its age, ns.
        age_ns: u64,
        /// The configured maximum, ns.
        max_age_ns: u64,
    },
    /// The frame was captured before rt-core's clock began.
    #[error("captured {before_ns} ns before rt-core started")]
    BeforeStart {
        /// How long before, ns.
        before_ns: u64,
    },
    /// An object's centre lies outside the calibrated workspace.
    #[error(
        "object {index} ({class:?}) centred at {center_m:?} m lies outside the calibrated workspace"
    )]
    OutsideWorkspace {
        /// Its index in the frame.
        index: usize,
        /// Its class.
        class: ObjectClass,
        /// Its centre, m.
        center_m: [f32; 3],
    },
    /// The goal lies out of reach (too near or too far from the base axis).
    #[error("goal at {radius_m:.3} m from the base axis is out of reach ({min_m}..={max_m} m)")]
    GoalOutOfReach {
        /// Its distance from the base axis, m.
        radius_m: f64,
        /// Nearest allowed, m.
        min_m: f64,
        /// Farthest allowed, m.
        max_m: f64,
    },
    /// More than one publisher is connected to the detection service.
    #[error("{publishers} publishers on the detection service (one expected)")]
    SecondPublisher {
        /// Publishers seen.
        publishers: usize,
    },
    /// The frame comes from another camera than the frames before it.
    #[error("camera_id {found} after frames from camera {expected}")]
    CameraChanged {
        /// The camera so far.
        expected: u32,
        /// The camera of this frame.
        found: u32,
    },
    /// The sequence did not increase.
    #[error("sequence {found} does not follow {last}")]
    SequenceRegressed {
        /// The last sequence accepted.
        last: u64,
        /// This frame's.
        found: u64,
    },
}

impl FrameRefusal {
    /// Number of refusal kinds (size of [`IntakeCounters::refused`]).
    pub const KINDS: usize = 11;

    /// A stable index for counting.
    pub fn index(&self) -> usize {
        match self {
            FrameRefusal::Invalid(_) => 0,
            FrameRefusal::Overfull { .. } => 1,
            FrameRefusal::NoStamp => 2,
            FrameRefusal::FutureStamp { .. } => 3,
            FrameRefusal::Stale { .. } => 4,
            FrameRefusal::BeforeStart { .. } => 5,
            FrameRefusal::OutsideWorkspace { .. } => 6,
            FrameRefusal::GoalOutOfReach { .. } => 7,
            FrameRefusal::SecondPublisher { .. } => 8,
            FrameRefusal::CameraChanged { .. } => 9,
            FrameRefusal::SequenceRegressed { .. } => 10,
        }
    }

    /// A short name per kind (for counters and reports).
    pub const NAMES: [&'static str; Self::KINDS] = [
        "invalid",
        "overfull",
        "no_stamp",
        "future_stamp",
        "stale",
        "before_start",
        "outside_workspace",
        "goal_out_of_reach",
        "second_publisher",
        "camera_changed",
        "sequence_regressed",
    ];
}

/// What the intake counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IntakeCounters {
    /// Frames accepted.
    pub accepted: u64,
    /// Of those, frames without a (confident enough) goal.
    pub without_goal: u64,
    /// Frames refused, per [`FrameRefusal::index`].
    pub refused: [u64; FrameRefusal::KINDS],
    /// Goal requests taken (goal source `action`).
    pub goal_requests: u64,
    /// Goal requests refused (malformed, out of bounds, stale id, or while the source is
    /// the camera).
    pub goal_requests_refused: u64,
}

impl IntakeCounters {
    /// Frames refused, all reasons.
    pub fn total_refused(&self) -> u64 {
        self.refused.iter().sum()
    }
}

/// An obstacle of a frame that is not settled whose measured speed plus one standard
/// deviation reaches this counts as moving (an intruder for speed and separation
/// monitoring), m/s: below it, the jitter of a still box's estimate.
pub const MOVING_SPEED_M_S: f64 = 0.05;

/// An accepted frame (over the twin's [`Scene`]; the runtime's tests use a toy scene).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AcceptedFrame<S = Scene> {
    /// The twin's scene (positions snapped to [`SNAP_GRID_M`]). Without a goal in the
    /// frame, its goal is the last one seen (or the start default) and must not be planned
    /// toward: see `goal_seen`.
    pub scene: S,
    /// The frame carries a goal at or above the confidence floor.
    pub goal_seen: bool,
    /// The frame is marked settled (`DetectionFrame::FRAME_SETTLED`): plans may be
    /// approved on its scene.
    pub settled: bool,
    /// Capture time on the cycle's clock (since its origin), ns.
    pub stamp_ns: u64,
    /// The obstacles seen moving (bit `i` for obstacle `i` of `scene`) and the fastest one's
    /// measured speed: none in a settled frame; in one that is not, each obstacle whose
    /// measured speed plus one standard deviation reaches [`MOVING_SPEED_M_S`].
    pub intruders: Intruders,
    /// An action goal was cancelled since the last accepted frame: the plan under way is to
    /// be revoked (the arm stops along its checked path).
    pub stop_requested: bool,
    /// How many action goals had been withdrawn (cancelled or pre-empted) when this frame
    /// was accepted ([`SceneIntake::goal_epoch`]): a plan approved on this frame's scene is
    /// refused by the plan guard once a later withdrawal is known to it (issue 41 item 1).
    pub goal_epoch: u64,
}

impl<S> AcceptedFrame<S> {
    /// A frame of `scene` captured at `stamp_ns` (cycle clock), with a goal, settled, no
    /// obstacle moving and no stop requested (the tests' and the sweep's usual frame).
    pub fn settled(scene: S, stamp_ns: u64) -> Self {
        Self {
            scene,
            goal_seen: true,
            settled: true,
            stamp_ns,
            intruders: Intruders::NONE,
            stop_requested: false,
            goal_epoch: 0,
        }
    }
}

/// What the twin thread is told of each frame, after the scene path
/// ([`crate::twin_thread::scene_path::ScenePath`]) has handed it to the cycle and the plan
/// guard: the intake thread sends it, the twin node passes it on to
/// [`crate::twin_thread::TwinWorker::note_frame`] / [`crate::twin_thread::TwinWorker::note_refused`].
// Sent by value (a scene is a few hundred bytes): boxing would allocate once per frame.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub enum FrameNote {
    /// Accepted: its scene is with the cycle and the plan guard already.
    Accepted {
        /// The checked frame.
        frame: AcceptedFrame,
        /// Its sequence number (verdicts name the scene they were computed on).
        sequence: u64,
    },
    /// Refused: the cycle has been told (it stops the arm).
    Refused,
}

/// Why a [`GoalRequest`] was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum GoalRequestRefusal {
    /// The goal source is the camera: requests are not taken.
    #[error("the goal source is the camera ([goal] source = \"camera\")")]
    SourceIsCamera,
    /// The request failed its schema validation.
    #[error("invalid goal request: {0}")]
    Invalid(SchemaError),
    /// The target breaks a bound of the workspace or the table.
    #[error("goal out of bounds: {0}")]
    OutOfBounds(GoalBoundError),
    /// A reach request made before this rt-core started (a replay) or too old
    /// ([`GoalRequest::check_age`]).
    #[error("goal request refused by age: {0}")]
    TooOld(GoalRequestAgeError),
    /// A reach request whose id is not above the last one taken.
    #[error("goal id {found} does not follow {last}")]
    StaleId {
        /// The last id taken.
        last: u64,
        /// This request's.
        found: u64,
    },
}

impl GoalRequestRefusal {
    /// This refusal of `req` at `now_ns` as the bridge is told it ([`GoalRefusal`]): the
    /// action goal behind a refused reach ends at once, naming why.
    pub fn wire(&self, req: &GoalRequest, now_ns: u64) -> GoalRefusal {
        let kind = match self {
            Self::TooOld(e) => return GoalRefusal::by_age(req.goal_id, req.command, e, now_ns),
            Self::SourceIsCamera => GoalRefusalKind::SourceIsCamera,
            Self::Invalid(_) => GoalRefusalKind::Invalid,
            Self::OutOfBounds(_) => GoalRefusalKind::OutOfBounds,
            Self::StaleId { .. } => GoalRefusalKind::StaleId,
        };
        GoalRefusal::new(req.goal_id, req.command, kind, now_ns)
    }
}

/// The goals the `Reach` action asks for (goal source `action`).
#[derive(Debug, Clone, Copy)]
struct RequestedGoals {
    bounds: GoalBounds,
    goal_hover_m: f64,
    /// The active goal: its id and cube.
    active: Option<(u64, Goal)>,
    last_id: u64,
    /// A cancel arrived since the last accepted frame.
    stop_pending: bool,
    /// Active goals withdrawn so far: cancelled, or pre-empted by a newer goal.
    withdrawals: u64,
}

/// Turns detection frames into scenes, refusing what cannot be trusted.
#[derive(Debug, Clone)]
pub struct SceneIntake {
    cfg: IntakeConfig,
    max_age_ns: u64,
    table_height_m: f64,
    /// `CLOCK_MONOTONIC` at the cycle clock's origin, ns.
    clock_origin_ns: u64,
    last_goal: Goal,
    /// Camera and sequence of the last frame that passed the source checks.
    last_source: Option<(u32, u64)>,
    counters: IntakeCounters,
    /// `Some` with the goal source `action`.
    requested: Option<RequestedGoals>,
    /// A frame's age the prediction horizon already covers, ns (the reaction time it was
    /// derived with, `RuntimeConfig::prediction_floor_s`): a moving obstacle of an older
    /// frame is predicted over the horizon plus the excess (`with_covered_age_s`).
    covered_age_ns: u64,
}

impl SceneIntake {
    /// An intake for frames whose age may be at most `max_age_ns`, over a table at
    /// `table_height_m`, for a cycle clock whose origin is `clock_origin_ns`
    /// (`CLOCK_MONOTONIC`).
    pub fn new(
        cfg: IntakeConfig,
        max_age_ns: u64,
        table_height_m: f64,
        clock_origin_ns: u64,
    ) -> Self {
        Self {
            cfg,
            max_age_ns,
            table_height_m,
            clock_origin_ns,
            last_goal: Goal {
                center_m: [0.35, 0.0, table_height_m + 0.025],
                size_m: 0.05,
            },
            last_source: None,
            counters: IntakeCounters::default(),
            requested: None,
            covered_age_ns: 0,
        }
    }

    /// The prediction horizon covers frames up to `covered_s` old (its reaction time): a
    /// moving obstacle of a frame older than that is predicted over the horizon plus the
    /// excess age, so the volume still reaches past the arm's stop from now. Without it
    /// every frame's whole age is added (safe, more conservative).
    #[must_use]
    pub fn with_covered_age_s(mut self, covered_s: f64) -> Self {
        self.covered_age_ns = (covered_s.max(0.0) * 1e9) as u64;
        self
    }

    /// The goal source `action`: goals come from [`SceneIntake::request`] within `bounds`
    /// (the TCP target is `goal_hover_m` above the requested goal cube's top, as for a seen
    /// one); the camera's goal cube is an obstacle like any other detected object.
    pub fn with_requested_goals(mut self, bounds: GoalBounds, goal_hover_m: f64) -> Self {
        self.requested = Some(RequestedGoals {
            bounds,
            goal_hover_m,
            active: None,
            last_id: 0,
            stop_pending: false,
            withdrawals: 0,
        });
        self
    }

    /// Whether the goal source is `action` (goal requests are taken).
    pub fn takes_requests(&self) -> bool {
        self.requested.is_some()
    }

    /// The active requested goal's id (0 = none, or the source is the camera).
    pub fn requested_goal_id(&self) -> u64 {
        self.requested
            .and_then(|r| r.active)
            .map_or(0, |(id, _)| id)
    }

    /// Takes one goal request (validated, checked against the bounds; counted): a reach
    /// replaces the active goal (from the next accepted frame on); a cancel or a release of
    /// the active goal withdraws it (a cancel also stops the arm: the next accepted frame
    /// carries [`AcceptedFrame::stop_requested`]). A withdrawal of another goal changes
    /// nothing. A reach is taken at `mono_now_ns` (`CLOCK_MONOTONIC`) only when made since
    /// the cycle clock's origin and young enough ([`GoalRequest::check_age`]).
    ///
    /// # Errors
    /// The [`GoalRequestRefusal`] (counted); the active goal stays as it was.
    pub fn request(
        &mut self,
        req: &GoalRequest,
        mono_now_ns: u64,
    ) -> Result<(), GoalRequestRefusal> {
        let table_height_m = self.table_height_m;
        let started_ns = self.clock_origin_ns;
        let outcome = match self.requested.as_mut() {
            None => Err(GoalRequestRefusal::SourceIsCamera),
            Some(r) => r.take(req, table_height_m, mono_now_ns, started_ns),
        };
        match outcome {
            Ok(()) => self.counters.goal_requests += 1,
            Err(_) => self.counters.goal_requests_refused += 1,
        }
        outcome
    }

    /// How many active goals were withdrawn so far: cancelled, or pre-empted by a newer
    /// goal (0 with the goal source `camera`). Each withdrawal is for the plan guard to
    /// revoke every plan toward the withdrawn goal (`ScenePath::goal_withdrawn`), and every
    /// frame carries the count it was accepted under ([`AcceptedFrame::goal_epoch`]).
    pub fn goal_epoch(&self) -> u64 {
        self.requested.map_or(0, |r| r.withdrawals)
    }

    /// What was counted so far.
    pub fn counters(&self) -> &IntakeCounters {
        &self.counters
    }

    /// Checks one frame received at `mono_now_ns` (`CLOCK_MONOTONIC`) while `publishers`
    /// publishers are connected to the detection service; counts the outcome.
    ///
    /// # Errors
    /// The [`FrameRefusal`] (already counted).
    pub fn accept(
        &mut self,
        frame: &DetectionFrame,
        mono_now_ns: u64,
        publishers: usize,
    ) -> Result<AcceptedFrame, FrameRefusal> {
        let result = self.check(frame, mono_now_ns, publishers);
        match &result {
            Ok(a) => {
                self.counters.accepted += 1;
                if !a.goal_seen {
                    self.counters.without_goal += 1;
                }
            }
            Err(r) => self.counters.refused[r.index()] += 1,
        }
        result
    }

    fn check(
        &mut self,
        frame: &DetectionFrame,
        mono_now_ns: u64,
        publishers: usize,
    ) -> Result<AcceptedFrame, FrameRefusal> {
        if publishers > 1 {
            return Err(FrameRefusal::SecondPublisher { publishers });
        }
        self.check_source(frame)?;
        if frame.dropped_count != 0 {
            return Err(FrameRefusal::Overfull {
                kept: frame.count,
                dropped: frame.dropped_count,
            });
        }
        frame.validate().map_err(FrameRefusal::Invalid)?;
        let stamp_ns = self.check_stamp(frame.capture_time_ns, mono_now_ns)?;
        self.check_places(frame)?;
        // The horizon runs from capture; a frame that took longer than the horizon's
        // reaction time to arrive is predicted that much further (issue 42 item 5).
        let late_s = mono_now_ns
            .saturating_sub(frame.capture_time_ns)
            .saturating_sub(self.covered_age_ns) as f64
            * 1e-9;
        let (scene, goal_seen, intruders) = self.scene_of(frame, late_s);
        let stop_requested = self
            .requested
            .as_mut()
            .is_some_and(|r| std::mem::take(&mut r.stop_pending));
        Ok(AcceptedFrame {
            scene,
            goal_seen,
            settled: frame.settled(),
            stamp_ns,
            intruders,
            stop_requested,
            goal_epoch: self.goal_epoch(),
        })
    }

    /// One camera, increasing sequences. A regression is refused once and becomes the new
    /// baseline (a restarted perception resumes after one refused frame, i.e. one stop);
    /// two publishers interleaving keep being refused.
    fn check_source(&mut self, frame: &DetectionFrame) -> Result<(), FrameRefusal> {
        let last = self.last_source.replace((frame.camera_id, frame.sequence));
        match last {
            Some((camera, _)) if camera != frame.camera_id => Err(FrameRefusal::CameraChanged {
                expected: camera,
                found: frame.camera_id,
            }),
            Some((_, seq)) if frame.sequence <= seq => Err(FrameRefusal::SequenceRegressed {
                last: seq,
                found: frame.sequence,
            }),
            _ => Ok(()),
        }
    }

    fn check_stamp(&self, capture_ns: u64, mono_now_ns: u64) -> Result<u64, FrameRefusal> {
        if capture_ns == 0 {
            return Err(FrameRefusal::NoStamp);
        }
        if capture_ns > mono_now_ns {
            return Err(FrameRefusal::FutureStamp {
                ahead_ns: capture_ns - mono_now_ns,
            });
        }
        let age_ns = mono_now_ns - capture_ns;
        if age_ns > self.max_age_ns {
            return Err(FrameRefusal::Stale {
                age_ns,
                max_age_ns: self.max_age_ns,
            });
        }
        if capture_ns < self.clock_origin_ns {
            return Err(FrameRefusal::BeforeStart {
                before_ns: self.clock_origin_ns - capture_ns,
            });
        }
        Ok(capture_ns - self.clock_origin_ns)
    }

    fn check_places(&self, frame: &DetectionFrame) -> Result<(), FrameRefusal> {
        let (lo, hi) = (self.cfg.calibrated_min_m, self.cfg.calibrated_max_m);
        for (index, o) in frame.objects().iter().enumerate() {
            let class = o.class().map_err(FrameRefusal::Invalid)?;
            let inside = (0..3).all(|k| (lo[k]..=hi[k]).contains(&f64::from(o.center_m[k])));
            if !inside {
                return Err(FrameRefusal::OutsideWorkspace {
                    index,
                    class,
                    center_m: o.center_m,
                });
            }
        }
        // Only the goal's reach is checked: every other goal-class object is an obstacle
        // (and with requested goals the request's reach was checked).
        if let Some(o) = self.goal_index(frame).map(|i| frame.objects()[i]) {
            let radius_m = f64::from(o.center_m[0]).hypot(f64::from(o.center_m[1]));
            let (min_m, max_m) = (self.cfg.goal_min_radius_m, self.cfg.goal_max_radius_m);
            if !(min_m..=max_m).contains(&radius_m) {
                return Err(FrameRefusal::GoalOutOfReach {
                    radius_m,
                    min_m,
                    max_m,
                });
            }
        }
        Ok(())
    }

    /// Which object of a frame is the goal (issue 41 item 2). With the goal source `camera`:
    /// the goal-class detection at or above the confidence floor (a valid frame carries at
    /// most one; the highest confidence would win). With requested goals: none, the action
    /// gives the goal. Every other object,
    /// goal-class ones included, is an obstacle: a cube in view that is not the goal is a
    /// physical object the arm must not hit.
    fn goal_index(&self, frame: &DetectionFrame) -> Option<usize> {
        if self.requested.is_some() {
            return None;
        }
        let mut best: Option<(usize, f32)> = None;
        for (index, o) in frame.objects().iter().enumerate() {
            let is_goal = matches!(o.class(), Ok(ObjectClass::Goal));
            if is_goal
                && o.confidence >= self.cfg.min_goal_confidence
                && best.is_none_or(|(_, c)| o.confidence > c)
            {
                best = Some((index, o.confidence));
            }
        }
        best.map(|(index, _)| index)
    }

    /// The scene of a checked frame that arrived `late_s` past what the prediction horizon
    /// covers; whether it has a goal; its obstacles seen moving.
    fn scene_of(&mut self, frame: &DetectionFrame, late_s: f64) -> (Scene, bool, Intruders) {
        let mut intruders = Intruders::NONE;
        let table_height_m = self.table_height_m;
        let mut scene = Scene::empty(table_height_m, self.last_goal);
        let mut goal_seen = false;
        let requested = self.requested.map(|r| r.active);
        let settled = frame.settled();
        let goal_index = self.goal_index(frame);
        for (index, o) in frame.objects().iter().enumerate() {
            let (o_center_m, o_size_m) = if settled {
                (o.center_m, o.size_m)
            } else {
                predicted_occupancy(o, &self.cfg, late_s)
            };
            if goal_index == Some(index) {
                let size_m = snap(o_size_m[0]);
                self.last_goal = Goal {
                    center_m: o_center_m.map(snap),
                    size_m: size_m.max(SNAP_GRID_M),
                };
                scene.goal = self.last_goal;
                goal_seen = true;
            } else if o.class().is_ok() {
                let moving = !settled && moving_speed_m_s(o, &self.cfg) >= MOVING_SPEED_M_S;
                let obstacle = snapped_obstacle(o_center_m, o_size_m, table_height_m);
                // Cannot fail: a valid frame carries at most MAX_DETECTIONS objects and the
                // scene holds as many obstacles (one capacity, asserted in shm-schemas).
                let slot = scene.obstacles.len();
                let pushed = scene.obstacles.push(obstacle);
                debug_assert!(pushed.is_ok(), "scene capacity below frame capacity");
                if moving && pushed.is_ok() && slot < 32 {
                    intruders.mask |= 1 << slot;
                    intruders.speed_m_s = intruders.speed_m_s.max(speed_m_s(o));
                }
            }
        }
        if let Some(Some((_, goal))) = requested {
            self.last_goal = goal;
            scene.goal = goal;
            goal_seen = true;
        }
        (scene, goal_seen, intruders)
    }
}

/// A position or size on the snapping grid.
fn snap(v: f32) -> f64 {
    (f64::from(v) / SNAP_GRID_M).round() * SNAP_GRID_M
}

/// An obstacle box from a detection's (possibly predicted) centre and size. The top and the
/// bottom are snapped (not the centre and the height): a box standing on the table must not
/// reach below it after rounding, or the learner would refuse the scene of a retrain request.
fn snapped_obstacle(center_m: [f32; 3], size_m: [f32; 3], table_height_m: f64) -> BoxObstacle {
    let top = snap(center_m[2] + size_m[2] / 2.0);
    let bottom = snap(center_m[2] - size_m[2] / 2.0).max(table_height_m);
    let height = (top - bottom).max(SNAP_GRID_M);
    BoxObstacle {
        center_m: [snap(center_m[0]), snap(center_m[1]), bottom + height / 2.0],
        size_m: [
            snap(size_m[0]).max(SNAP_GRID_M),
            snap(size_m[1]).max(SNAP_GRID_M),
            height,
        ],
    }
}

/// A detection's measured speed, m/s.
fn speed_m_s(o: &DetectedObject) -> f64 {
    let v = o.velocity_m_s;
    f64::from((v[0].powi(2) + v[1].powi(2) + v[2].powi(2)).sqrt())
}

/// A detection's speed plus its velocity's uncertainty (capped at the configured intruder
/// speed), m/s: what decides whether it is seen moving.
fn moving_speed_m_s(o: &DetectedObject, cfg: &IntakeConfig) -> f64 {
    let sigma_m_s = f64::from(o.velocity_sigma_m_s.max(0.0)).min(cfg.intruder_speed_m_s);
    speed_m_s(o) + sigma_m_s
}

impl RequestedGoals {
    fn take(
        &mut self,
        req: &GoalRequest,
        table_height_m: f64,
        mono_now_ns: u64,
        started_ns: u64,
    ) -> Result<(), GoalRequestRefusal> {
        req.validate().map_err(GoalRequestRefusal::Invalid)?;
        let command = req.command().map_err(GoalRequestRefusal::Invalid)?;
        match command {
            GoalCommand::Reach => {
                req.check_age(mono_now_ns, started_ns)
                    .map_err(GoalRequestRefusal::TooOld)?;
                if req.goal_id <= self.last_id {
                    return Err(GoalRequestRefusal::StaleId {
                        last: self.last_id,
                        found: req.goal_id,
                    });
                }
                let default_height_m = REQUESTED_GOAL_SIZE_M + self.goal_hover_m;
                self.bounds
                    .check(
                        req.target_m,
                        req.approach_height_m,
                        default_height_m,
                        table_height_m,
                    )
                    .map_err(GoalRequestRefusal::OutOfBounds)?;
                let center_m = requested_goal_center_m(
                    req.target_m,
                    req.approach_height_m,
                    table_height_m,
                    self.goal_hover_m,
                );
                // (On the intake's grid already, as a seen goal.)
                self.last_id = req.goal_id;
                // A newer goal pre-empts the active one: plans toward it are withdrawn.
                if self.active.is_some() {
                    self.withdrawals += 1;
                }
                self.active = Some((
                    req.goal_id,
                    Goal {
                        center_m,
                        size_m: REQUESTED_GOAL_SIZE_M,
                    },
                ));
            }
            GoalCommand::Cancel | GoalCommand::Release => {
                if self.active.is_some_and(|(id, _)| id == req.goal_id) {
                    self.active = None;
                    if command == GoalCommand::Cancel {
                        self.stop_pending = true;
                        self.withdrawals += 1;
                    }
                }
            }
        }
        Ok(())
    }
}

/// Where an obstacle of a frame that is not settled may be over the prediction horizon
/// `h` = [`IntakeConfig::prediction_horizon_s`] from its capture, plus `late_s` (the part
/// of the frame's age the horizon does not cover: `SceneIntake::with_covered_age_s`): its
/// box swept along its velocity `v` (the box from `c` to `c + v·h`, per axis), grown on
/// every side by the distance its velocity's uncertainty allows, `k·σ·h` with `k` =
/// [`IntakeConfig::uncertainty_sigmas`] (σ capped at the assumed intruder speed
/// [`IntakeConfig::intruder_speed_m_s`]: an object of unknown velocity may be anywhere
/// a hand can reach in that time). Returns the centre and the full extents, m.
///
/// A settled frame (perception saw nothing move) is taken as measured. The goal is swept
/// too, but only obstacles count for clearance.
pub fn predicted_occupancy(
    o: &DetectedObject,
    cfg: &IntakeConfig,
    late_s: f64,
) -> ([f32; 3], [f32; 3]) {
    let h = (cfg.prediction_horizon_s + late_s.max(0.0)) as f32;
    let sigma = o
        .velocity_sigma_m_s
        .min(cfg.intruder_speed_m_s as f32)
        .max(0.0);
    let grow_m = cfg.uncertainty_sigmas as f32 * sigma * h;
    let mut center_m = o.center_m;
    let mut size_m = o.size_m;
    for k in 0..3 {
        let travel_m = o.velocity_m_s[k] * h;
        center_m[k] += travel_m / 2.0;
        size_m[k] += travel_m.abs() + 2.0 * grow_m;
    }
    (center_m, size_m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::MAX_DETECTIONS;
    use shm_schemas::scene_file::SceneFile;

    const ORIGIN_NS: u64 = 1_000_000_000_000;
    const MAX_AGE_NS: u64 = 500_000_000;
    /// When the tests' goal requests are made and taken.
    const REQUEST_NS: u64 = ORIGIN_NS + 2_000_000_000;

    /// `r` made at [`REQUEST_NS`].
    fn fresh(r: GoalRequest) -> GoalRequest {
        GoalRequest {
            request_time_ns: REQUEST_NS,
            ..r
        }
    }

    /// An intake whose horizon covers frames 0.1 s old (the shipped reaction time).
    fn intake() -> SceneIntake {
        SceneIntake::new(IntakeConfig::default(), MAX_AGE_NS, 0.0, ORIGIN_NS)
            .with_covered_age_s(0.1)
    }

    fn goal(center_m: [f32; 3]) -> DetectedObject {
        DetectedObject::new(1, ObjectClass::Goal, 0.9, center_m, [0.05, 0.05, 0.05])
    }

    fn obstacle(id: u32, center_m: [f32; 3], size_m: [f32; 3]) -> DetectedObject {
        DetectedObject::new(id, ObjectClass::Obstacle, 0.9, center_m, size_m)
    }

    /// A frame captured 10 ms before `now`.
    fn frame(sequence: u64, now_ns: u64, objects: &[DetectedObject]) -> DetectionFrame {
        let mut f = DetectionFrame {
            sequence,
            capture_time_ns: now_ns - 10_000_000,
            camera_id: 7,
            ..DetectionFrame::default()
        };
        for o in objects {
            f.push(*o);
        }
        f
    }

    /// A tall box on the table whose centre and height both round up (0.1614 → 0.160 and
    /// 0.3227 → 0.325 on the 5 mm grid) once made a box reaching 2.5 mm below the table:
    /// a scene the learner refused, leaving the arm waiting for a policy that never came.
    #[test]
    fn a_detected_box_on_the_table_stays_on_it_after_snapping() {
        let now = ORIGIN_NS + 1_000_000_000;
        let f = frame(
            1,
            now,
            &[
                goal([0.28, -0.32, 0.025]),
                obstacle(2, [0.2887, -0.1333, 0.16136], [0.053, 0.0518, 0.32272]),
            ],
        );
        let scene = intake().accept(&f, now, 1).unwrap().scene;
        let b = scene.obstacles[0];
        let bottom = b.center_m[2] - b.size_m[2] / 2.0;
        assert!(bottom >= -1e-12, "box bottom {bottom} below the table");
        assert!((b.center_m[2] + b.size_m[2] / 2.0 - 0.3227).abs() <= 0.0025);
        // The scene a retrain request carries validates like a scene file.
        let file = SceneFile {
            name: "detected".into(),
            table: shm_schemas::scene_file::TableSpec { height_m: 0.0 },
            goal: shm_schemas::scene_file::GoalSpec {
                center_m: scene.goal.center_m,
                size_m: scene.goal.size_m,
            },
            obstacles: vec![shm_schemas::scene_file::BoxSpec {
                center_m: b.center_m,
                size_m: b.size_m,
                path: Default::default(),
            }],
        };
        file.validate().unwrap();
    }

    /// Issue 14, item 1: a goal, 8 small boxes, then a tall box on the path. The twin
    /// held 8 obstacles and dropped the tall one silently. Now every obstacle of a valid
    /// frame reaches the scene, and a frame that does not fit is refused.
    #[test]
    fn every_obstacle_of_a_full_frame_reaches_the_scene_and_an_overfull_frame_is_refused() {
        let now = ORIGIN_NS + 1_000_000_000;
        let mut objects = vec![goal([0.3, 0.2, 0.025])];
        for i in 0..(MAX_DETECTIONS - 2) {
            let x = -0.5 + 0.05 * i as f32;
            objects.push(obstacle(10 + i as u32, [x, -0.6, 0.01], [0.01, 0.01, 0.02]));
        }
        objects.push(obstacle(99, [0.3, 0.0, 0.15], [0.05, 0.05, 0.3]));
        let mut k = intake();
        let a = k.accept(&frame(1, now, &objects), now, 1).unwrap();
        assert_eq!(a.scene.obstacles.len(), MAX_DETECTIONS - 1);
        let tall = a.scene.obstacles[MAX_DETECTIONS - 2];
        assert!(
            (tall.size_m[2] - 0.3).abs() < 1e-9,
            "the tall box is in the scene"
        );

        // One more object than fits: perception publishes the frame with dropped_count.
        objects.push(obstacle(100, [0.3, 0.1, 0.15], [0.05, 0.05, 0.3]));
        let f = frame(2, now, &objects);
        assert_eq!(f.dropped_count, 1);
        let r = k.accept(&f, now, 1).unwrap_err();
        assert_eq!(
            r,
            FrameRefusal::Overfull {
                kept: MAX_DETECTIONS as u32,
                dropped: 1
            }
        );
        assert_eq!(k.counters().refused[r.index()], 1);
    }

    /// Issue 14, item 2: frames without a goal gave a plan toward a default goal.
    #[test]
    fn a_frame_without_a_goal_or_with_a_doubtful_one_has_no_goal() {
        let now = ORIGIN_NS + 1_000_000_000;
        let mut k = intake();
        let a = k
            .accept(
                &frame(1, now, &[obstacle(2, [0.3, 0.0, 0.1], [0.05, 0.05, 0.2])]),
                now,
                1,
            )
            .unwrap();
        assert!(!a.goal_seen);
        assert_eq!(a.scene.obstacles.len(), 1, "its obstacles still count");
        let mut doubtful = goal([0.3, 0.2, 0.025]);
        doubtful.confidence = 0.2;
        let a = k.accept(&frame(2, now, &[doubtful]), now, 1).unwrap();
        assert!(!a.goal_seen, "a goal below the confidence floor is no goal");
        let a = k
            .accept(&frame(3, now, &[goal([0.3, 0.2, 0.025])]), now, 1)
            .unwrap();
        assert!(a.goal_seen);
        assert_eq!(k.counters().without_goal, 2);
    }

    /// Issue 15: the settled flag travels with the accepted scene (an unsettled frame is
    /// accepted: its obstacles count); an unknown flag bit is refused.
    #[test]
    fn the_settled_flag_travels_with_the_scene_and_unknown_flags_are_refused() {
        let now = ORIGIN_NS + 1_000_000_000;
        let mut k = intake();
        let mut f = frame(1, now, &[goal([0.3, 0.2, 0.025])]);
        let a = k.accept(&f, now, 1).unwrap();
        assert!(!a.settled && a.goal_seen);
        f.sequence = 2;
        f.set_settled(true);
        assert!(k.accept(&f, now, 1).unwrap().settled);
        f.sequence = 3;
        f.flags = DetectionFrame::FRAME_SETTLED | 0x100;
        assert_eq!(
            k.accept(&f, now, 1),
            Err(FrameRefusal::Invalid(SchemaError::BadEnum {
                field: "flags",
                value: 0x100
            }))
        );
    }

    /// Issue 42 item 5 (found under load): the horizon runs from capture and covers the
    /// reaction time; a frame that arrives later than that (up to the stale bound) is
    /// predicted further by the excess, so its volume still covers the stop from now.
    #[test]
    fn a_late_frame_counts_a_moving_obstacle_over_the_horizon_plus_its_excess_age() {
        let cfg = IntakeConfig::default();
        let h = cfg.prediction_horizon_s;
        let capture = ORIGIN_NS + 1_000_000_000;
        let moving =
            obstacle(2, [0.30, 0.00, 0.10], [0.10, 0.10, 0.20]).with_velocity([0.0, 1.0, 0.0], 0.0);
        let f = frame(1, capture, &[goal([0.3, 0.2, 0.025]), moving]);
        let swept_y = |age_ns: u64| {
            let mut k = intake();
            k.accept(&f, f.capture_time_ns + age_ns, 1)
                .unwrap()
                .scene
                .obstacles[0]
                .size_m[1]
        };
        // Within the covered 0.1 s: the horizon alone (swept 1 m/s · h).
        assert!((swept_y(50_000_000) - (0.10 + h)).abs() <= SNAP_GRID_M);
        // 0.4 s old: 0.3 s more of travel.
        let late = swept_y(400_000_000);
        assert!((late - (0.10 + h + 0.3)).abs() <= SNAP_GRID_M, "{late}");
    }

    /// Issue 33 item 4: a moving obstacle counts where it will be over the prediction
    /// horizon, grown by its velocity's uncertainty, in a frame that is not settled; a
    /// settled frame's boxes are taken as measured.
    #[test]
    fn an_unsettled_frame_counts_each_obstacle_where_it_may_be_over_the_horizon() {
        let now = ORIGIN_NS + 1_000_000_000;
        let cfg = IntakeConfig::default();
        let h = cfg.prediction_horizon_s;
        let moving = obstacle(2, [0.30, 0.00, 0.10], [0.10, 0.10, 0.20])
            .with_velocity([0.0, 1.0, 0.0], 0.05);
        let mut k = intake();
        let mut f = frame(1, now, &[goal([0.3, 0.2, 0.025]), moving]);
        let scene = k.accept(&f, now, 1).unwrap().scene;
        let b = scene.obstacles[0];
        let grow_m = 2.0 * cfg.uncertainty_sigmas * 0.05 * h;
        // Swept along +y by 1 m/s · h, grown by 2σh on both sides (to the 5 mm grid).
        assert!(
            (b.size_m[1] - (0.10 + h + grow_m)).abs() <= SNAP_GRID_M,
            "{b:?}"
        );
        assert!((b.center_m[1] - h / 2.0).abs() <= SNAP_GRID_M, "{b:?}");
        assert!(
            (b.size_m[0] - (0.10 + grow_m)).abs() <= SNAP_GRID_M,
            "{b:?}"
        );
        // An object whose velocity is unknown may be anywhere a hand reaches meanwhile (σ
        // capped at the assumed intruder speed).
        f.sequence = 2;
        f.objects[1] = obstacle(3, [0.30, 0.00, 0.10], [0.10, 0.10, 0.20])
            .with_velocity([0.0; 3], shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S);
        let b = k.accept(&f, now, 1).unwrap().scene.obstacles[0];
        let unknown_grow_m = 2.0 * cfg.uncertainty_sigmas * cfg.intruder_speed_m_s * h;
        assert!(
            (b.size_m[0] - (0.10 + unknown_grow_m)).abs() <= SNAP_GRID_M,
            "{b:?}"
        );
        // Settled: as measured.
        f.sequence = 3;
        f.objects[1] = moving;
        f.set_settled(true);
        let b = k.accept(&f, now, 1).unwrap().scene.obstacles[0];
        assert_eq!((b.center_m[1], b.size_m[1]), (0.0, 0.10));
    }

    /// Issue 33 item 5: the cycle's speed and separation monitoring watches the obstacles
    /// perception sees moving, never a still box (before: none was known, so every box
    /// would have counted as an intruder).
    #[test]
    fn the_obstacles_seen_moving_are_named_for_speed_and_separation_monitoring() {
        let now = ORIGIN_NS + 1_000_000_000;
        let still = obstacle(2, [0.40, -0.20, 0.10], [0.10, 0.10, 0.20]);
        let moving = obstacle(3, [0.30, 0.00, 0.10], [0.10, 0.10, 0.20])
            .with_velocity([0.0, 0.6, 0.8], 0.05);
        let unknown = obstacle(4, [0.20, 0.30, 0.10], [0.10, 0.10, 0.20])
            .with_velocity([0.0; 3], shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S);
        let mut k = intake();
        let mut f = frame(1, now, &[goal([0.3, 0.2, 0.025]), still, moving, unknown]);
        let a = k.accept(&f, now, 1).unwrap();
        // Obstacles 0 (still), 1 (moving at 1 m/s), 2 (velocity not known yet: moving).
        assert_eq!(a.intruders.mask, 0b110, "{:?}", a.intruders);
        assert!(
            (a.intruders.speed_m_s - 1.0).abs() < 1e-6,
            "{:?}",
            a.intruders
        );
        // A settled frame: nothing moves.
        f.sequence = 2;
        f.set_settled(true);
        assert_eq!(k.accept(&f, now, 1).unwrap().intruders, Intruders::NONE);
    }

    /// Issue 14, item 3: zero, future, old and pre-start stamps looked fresh.
    #[test]
    fn zero_future_stale_and_pre_start_stamps_are_refused() {
        let now = ORIGIN_NS + 100_000_000; // 0.1 s after rt-core's clock began
        let objects = [goal([0.3, 0.2, 0.025])];
        let mut k = intake();
        let mut f = frame(1, now, &objects);
        f.capture_time_ns = 0;
        assert_eq!(k.accept(&f, now, 1), Err(FrameRefusal::NoStamp));
        f.sequence = 2;
        f.capture_time_ns = now + 5;
        assert_eq!(
            k.accept(&f, now, 1),
            Err(FrameRefusal::FutureStamp { ahead_ns: 5 })
        );
        f.sequence = 3;
        f.capture_time_ns = now - 10_000_000_000; // 10 s old, published before the start
        assert!(matches!(
            k.accept(&f, now, 1),
            Err(FrameRefusal::Stale { .. })
        ));
        f.sequence = 4;
        f.capture_time_ns = ORIGIN_NS - 1_000; // young, but from before the clock began
        assert_eq!(
            k.accept(&f, now, 1),
            Err(FrameRefusal::BeforeStart { before_ns: 1_000 })
        );
        f.sequence = 5;
        f.capture_time_ns = now - 1_000_000;
        let a = k.accept(&f, now, 1).unwrap();
        assert_eq!(a.stamp_ns, 99_000_000, "stamped on the cycle's clock");
        assert_eq!(k.counters().total_refused(), 4);
    }

    /// Issue 14, item 3: goals 3 m away were accepted.
    #[test]
    fn objects_outside_the_calibrated_workspace_and_goals_out_of_reach_are_refused() {
        let now = ORIGIN_NS + 1_000_000_000;
        let mut k = intake();
        assert!(matches!(
            k.accept(&frame(1, now, &[goal([2.9, 0.0, 0.025])]), now, 1),
            Err(FrameRefusal::OutsideWorkspace {
                index: 0,
                class: ObjectClass::Goal,
                ..
            })
        ));
        assert!(matches!(
            k.accept(
                &frame(
                    2,
                    now,
                    &[
                        goal([0.3, 0.0, 0.025]),
                        obstacle(3, [0.0, 0.0, -1.0], [0.05, 0.05, 0.05])
                    ]
                ),
                now,
                1
            ),
            Err(FrameRefusal::OutsideWorkspace { index: 1, .. })
        ));
        assert!(matches!(
            k.accept(&frame(3, now, &[goal([0.05, 0.02, 0.025])]), now, 1),
            Err(FrameRefusal::GoalOutOfReach { .. })
        ));
        assert!(matches!(
            k.accept(&frame(4, now, &[goal([0.7, 0.0, 0.025])]), now, 1),
            Err(FrameRefusal::GoalOutOfReach { .. })
        ));
        k.accept(&frame(5, now, &[goal([0.3, 0.0, 0.025])]), now, 1)
            .unwrap();
    }

    fn bounds() -> GoalBounds {
        let cfg = IntakeConfig::default();
        GoalBounds {
            min_radius_m: cfg.goal_min_radius_m,
            max_radius_m: cfg.goal_max_radius_m,
            table_min_m: cfg.calibrated_min_m,
            table_max_m: cfg.calibrated_max_m,
            workspace_min_m: [-0.8, -0.8, 0.0],
            workspace_max_m: [0.8, 0.8, 1.0],
        }
    }

    /// Issue 32 item 1: with the goal source `action`, the action's goal overrides the
    /// camera's goal cube (whose obstacles still count); no action goal, no goal; a new goal
    /// replaces the old one; a cancel withdraws it and asks for a stop; the camera source
    /// takes no requests.
    #[test]
    fn the_action_goal_overrides_the_camera_goal_and_a_cancel_withdraws_it() {
        let now = ORIGIN_NS + 1_000_000_000;
        let seen = [
            goal([0.3, 0.2, 0.025]),
            obstacle(2, [0.3, -0.2, 0.1], [0.05, 0.05, 0.2]),
        ];
        let mut camera = intake();
        assert_eq!(
            camera.request(&fresh(GoalRequest::reach(1, [0.4, 0.0], 0.0)), REQUEST_NS),
            Err(GoalRequestRefusal::SourceIsCamera)
        );
        assert_eq!(camera.counters().goal_requests_refused, 1);

        let mut k = intake().with_requested_goals(bounds(), 0.05);
        let a = k.accept(&frame(1, now, &seen), now, 1).unwrap();
        assert!(
            !a.goal_seen,
            "no action goal yet: the camera's cube is not the goal"
        );
        // Issue 41 item 2: the camera's cube is an obstacle, beside the camera's box (this
        // asserted 1 before: the cube vanished from the scene).
        assert_eq!(a.scene.obstacles.len(), 2, "the camera's objects count");

        k.request(&fresh(GoalRequest::reach(1, [0.45, -0.1], 0.0)), REQUEST_NS)
            .unwrap();
        let a = k.accept(&frame(2, now, &seen), now, 1).unwrap();
        assert!(a.goal_seen && !a.stop_requested);
        assert_eq!(a.scene.goal.center_m, [0.45, -0.1, 0.025]);
        assert_eq!(a.scene.obstacles.len(), 2);
        assert_eq!(k.requested_goal_id(), 1);

        // A second goal pre-empts the first; an approach height raises the TCP target.
        k.request(&fresh(GoalRequest::reach(2, [0.35, 0.1], 0.3)), REQUEST_NS)
            .unwrap();
        let a = k.accept(&frame(3, now, &seen), now, 1).unwrap();
        let target = a.scene.goal_target_m(0.05);
        assert!((target.z - 0.3).abs() <= SNAP_GRID_M, "{target:?}");
        assert_eq!(k.requested_goal_id(), 2);
        // Withdrawing the old goal changes nothing; an old id is refused.
        k.request(
            &fresh(GoalRequest::withdraw(1, GoalCommand::Cancel)),
            REQUEST_NS,
        )
        .unwrap();
        assert_eq!(k.requested_goal_id(), 2);
        assert_eq!(
            k.request(&fresh(GoalRequest::reach(2, [0.4, 0.0], 0.0)), REQUEST_NS),
            Err(GoalRequestRefusal::StaleId { last: 2, found: 2 })
        );

        k.request(
            &fresh(GoalRequest::withdraw(2, GoalCommand::Cancel)),
            REQUEST_NS,
        )
        .unwrap();
        let a = k.accept(&frame(4, now, &seen), now, 1).unwrap();
        assert!(!a.goal_seen && a.stop_requested, "cancelled: no goal, stop");
        let a = k.accept(&frame(5, now, &seen), now, 1).unwrap();
        assert!(!a.stop_requested, "the stop is asked once");

        // A release withdraws without a stop.
        k.request(&fresh(GoalRequest::reach(3, [0.4, 0.0], 0.0)), REQUEST_NS)
            .unwrap();
        k.request(
            &fresh(GoalRequest::withdraw(3, GoalCommand::Release)),
            REQUEST_NS,
        )
        .unwrap();
        let a = k.accept(&frame(6, now, &seen), now, 1).unwrap();
        assert!(!a.goal_seen && !a.stop_requested);
    }

    /// Issue 32 item 1: a requested goal out of bounds or malformed is refused naming the
    /// bound or the field; the active goal stays.
    #[test]
    fn a_requested_goal_out_of_bounds_or_malformed_is_refused_naming_it() {
        let mut k = intake().with_requested_goals(bounds(), 0.05);
        k.request(&fresh(GoalRequest::reach(1, [0.4, 0.0], 0.0)), REQUEST_NS)
            .unwrap();
        match k.request(&fresh(GoalRequest::reach(2, [0.9, 0.0], 0.0)), REQUEST_NS) {
            Err(GoalRequestRefusal::OutOfBounds(e)) => {
                assert_eq!(e.bound, "intake.goal_max_radius_m");
            }
            other => panic!("{other:?}"),
        }
        let mut bad = GoalRequest::reach(3, [0.4, 0.0], 0.0);
        bad.command = 7;
        assert_eq!(
            k.request(&bad, REQUEST_NS),
            Err(GoalRequestRefusal::Invalid(SchemaError::BadEnum {
                field: "command",
                value: 7
            }))
        );
        assert_eq!(k.requested_goal_id(), 1);
        assert_eq!(k.counters().goal_requests_refused, 2);
    }

    /// Issue 41 item 5: the goal service replays its last sample to a new subscriber, so a
    /// restarted rt-core took the previous run's last reach and drove to it. A reach made
    /// before this rt-core's clock origin, or older than `MAX_REACH_AGE_NS`, is refused
    /// and counted; the active goal stays; a fresh one is taken.
    #[test]
    fn a_replayed_or_old_reach_request_is_refused_by_age() {
        let mut k = intake().with_requested_goals(bounds(), 0.05);
        let replayed = GoalRequest {
            request_time_ns: ORIGIN_NS - 3_000_000_000,
            ..GoalRequest::reach(7, [0.4, 0.0], 0.0)
        };
        assert!(matches!(
            k.request(&replayed, ORIGIN_NS + 1_000_000),
            Err(GoalRequestRefusal::TooOld(
                GoalRequestAgeError::BeforeStart { .. }
            ))
        ));
        assert_eq!(k.requested_goal_id(), 0, "the replay is not the goal");
        let late = fresh(GoalRequest::reach(8, [0.4, 0.0], 0.0));
        assert!(matches!(
            k.request(&late, REQUEST_NS + 5_000_000_000),
            Err(GoalRequestRefusal::TooOld(
                GoalRequestAgeError::TooOld { .. }
            ))
        ));
        assert_eq!(k.requested_goal_id(), 0);
        assert_eq!(k.counters().goal_requests_refused, 2);
        k.request(&late, REQUEST_NS + 1_000_000).unwrap();
        assert_eq!(k.requested_goal_id(), 8);
        // A cancel is taken whatever its age: stopping is never refused.
        let old_cancel = GoalRequest {
            request_time_ns: ORIGIN_NS - 1,
            ..GoalRequest::withdraw(8, GoalCommand::Cancel)
        };
        k.request(&old_cancel, REQUEST_NS + 9_000_000_000).unwrap();
        assert_eq!(k.requested_goal_id(), 0);
    }

    /// The bridge is told of a refusal by age with its measure and bound (the action goal
    /// behind it then ends at once instead of waiting forever), and of the others by kind.
    #[test]
    fn a_refusal_goes_to_the_bridge_with_its_age_and_bound() {
        let mut k = intake().with_requested_goals(bounds(), 0.05);
        let late = fresh(GoalRequest::reach(8, [0.4, 0.0], 0.0));
        let now = REQUEST_NS + 2_500_000_000;
        let refusal = k.request(&late, now).unwrap_err();
        let wire = refusal.wire(&late, now);
        wire.validate().unwrap();
        assert_eq!(wire.kind(), Ok(GoalRefusalKind::TooOld));
        assert_eq!((wire.goal_id, wire.command), (8, GoalCommand::Reach as u8));
        assert_eq!(
            (wire.value_ns, wire.bound_ns),
            (2_500_000_000, shm_schemas::goal_request::MAX_REACH_AGE_NS)
        );
        assert_eq!(
            wire.words(),
            "the request is 2.500 s old, over the 2.000 s bound"
        );
        k.request(&fresh(GoalRequest::reach(9, [0.4, 0.0], 0.0)), REQUEST_NS)
            .unwrap();
        let stale = fresh(GoalRequest::reach(9, [0.4, 0.0], 0.0));
        let refusal = k.request(&stale, REQUEST_NS).unwrap_err();
        assert_eq!(
            refusal.wire(&stale, REQUEST_NS).kind(),
            Ok(GoalRefusalKind::StaleId)
        );
    }

    /// Issue 14, item 7: a second publisher on the detection service went unnoticed.
    #[test]
    fn a_second_publisher_another_camera_and_a_sequence_regression_are_refused() {
        let now = ORIGIN_NS + 1_000_000_000;
        let objects = [goal([0.3, 0.0, 0.025])];
        let mut k = intake();
        k.accept(&frame(10, now, &objects), now, 1).unwrap();
        assert_eq!(
            k.accept(&frame(11, now, &objects), now, 2),
            Err(FrameRefusal::SecondPublisher { publishers: 2 })
        );
        let mut other = frame(12, now, &objects);
        other.camera_id = 8;
        assert_eq!(
            k.accept(&other, now, 1),
            Err(FrameRefusal::CameraChanged {
                expected: 7,
                found: 8
            })
        );
        // Back to camera 7 (a baseline switch is refused once more, then accepted).
        assert!(k.accept(&frame(13, now, &objects), now, 1).is_err());
        k.accept(&frame(14, now, &objects), now, 1).unwrap();
        assert_eq!(
            k.accept(&frame(3, now, &objects), now, 1),
            Err(FrameRefusal::SequenceRegressed { last: 14, found: 3 })
        );
        // A restarted perception (sequence from 3 on) resumes after that one refusal.
        k.accept(&frame(4, now, &objects), now, 1).unwrap();
    }

    /// Issue 41 item 2: with goals from the action, the goal cube the camera sees is an
    /// obstacle, snapped like the others: a requested target behind it gives no path through
    /// it. Before, the cube was dropped from the scene and a posture with the TCP inside it
    /// passed every check.
    #[test]
    fn with_requested_goals_the_seen_goal_cube_is_an_obstacle_a_path_through_it_is_refused() {
        use std::path::PathBuf;
        use twin::{IkSolver, RobotModel, TaskConfig, TwinEnv, is_safe_posture};

        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let env = TwinEnv::new(model.clone(), task);
        let now = ORIGIN_NS + 1_000_000_000;
        // A goal cube standing on a shelf, 0.25 m above the table, in front of the target.
        let cube = DetectedObject::new(1, ObjectClass::Goal, 0.9, [0.35, 0.0, 0.25], [0.05; 3]);
        let mut k = intake().with_requested_goals(bounds(), 0.05);
        k.request(&fresh(GoalRequest::reach(1, [0.5, 0.0], 0.0)), REQUEST_NS)
            .unwrap();
        let a = k.accept(&frame(1, now, &[cube]), now, 1).unwrap();
        assert!(a.goal_seen);
        assert_eq!(a.scene.goal.center_m[..2], [0.5, 0.0]);
        assert_eq!(a.scene.obstacles.len(), 1, "the cube is in the scene");
        let b = a.scene.obstacles[0];
        assert!((b.center_m[0] - 0.35).abs() < 1e-9 && (b.center_m[2] - 0.25).abs() < 1e-9);
        assert!((b.size_m[0] - 0.05).abs() < 1e-9);

        // A path toward the target through the cube: its posture with the TCP in the cube
        // is refused; the same posture with no cube in view is safe (well above the table).
        let ik = IkSolver::new(&model, task.ik);
        let through = nalgebra::Vector3::new(0.35, 0.0, 0.25);
        let q = ik.solve(&model, &through, &task.start.joints_rad).joints;
        assert!(
            (model.tcp_m(&q) - through).norm() < 0.005,
            "IK reached the cube"
        );
        assert!(
            !is_safe_posture(&env, &a.scene, &q),
            "a path through the cube"
        );
        let empty = k.accept(&frame(2, now, &[]), now, 1).unwrap();
        assert!(
            is_safe_posture(&env, &empty.scene, &q),
            "clear without the cube"
        );
    }

    /// Issue 41 item 2, camera goals: a valid frame carries at most one goal-class object
    /// (perception publishes every cube it did not choose as an obstacle); one below the
    /// confidence floor is not the goal, and is an obstacle (before: it vanished).
    #[test]
    fn with_camera_goals_a_doubtful_goal_class_object_is_an_obstacle() {
        let now = ORIGIN_NS + 1_000_000_000;
        let mut doubtful = goal([0.4, 0.1, 0.025]);
        doubtful.confidence = 0.2;
        let box_ = obstacle(2, [0.3, -0.2, 0.1], [0.05, 0.05, 0.2]);
        let mut k = intake();
        let a = k.accept(&frame(1, now, &[doubtful, box_]), now, 1).unwrap();
        assert!(!a.goal_seen);
        assert_eq!(a.scene.obstacles.len(), 2, "{:?}", a.scene.obstacles);
        assert!((a.scene.obstacles[0].center_m[0] - 0.4).abs() < 1e-9);
        let a = k
            .accept(&frame(2, now, &[goal([0.3, 0.2, 0.025]), box_]), now, 1)
            .unwrap();
        assert!(a.goal_seen);
        assert_eq!(a.scene.obstacles.len(), 1, "the goal is not an obstacle");
    }
}
