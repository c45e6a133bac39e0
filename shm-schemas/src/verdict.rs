//! [`TwinVerdict`]: the result of one lookahead — the whole next episode run in the twin
//! with the current policy (rt-core → anyone).

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, finite_f64, flag, flag_byte};

/// How the lookahead episode ended. Stored as a `u8`; convert with `try_from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum EpisodeEnd {
    /// The goal was reached within tolerance.
    Success = 1,
    /// The arm touched an obstacle or the table.
    Collision = 2,
    /// The step budget ran out before the goal was reached.
    Timeout = 3,
    /// A joint limit or the workspace box was violated.
    LimitViolation = 4,
    /// The episode ended for another reason (e.g. clearance below the safety margin).
    Other = 5,
    /// No lookahead ran: the latest detection frame has no goal (none seen, or below the
    /// confidence floor), so there is nothing to plan toward and the arm holds.
    NoGoal = 6,
    /// No lookahead ran: the scene is "not learned". Retrained policies for it were refused
    /// by rt-core `runtime.toml`'s `[twin] max_refused_retrainings` times; no more retraining
    /// is asked for it. `policy_id` and `min_distance_m` are the last refused policy's, and
    /// the reason is its refusal's (logged by rt-core, listed in the run's report).
    NotLearned = 7,
    /// No plan is made: the goal is taken — a box overlaps the goal cube or blocks every
    /// goal posture (`twin::InfeasibleReason::NoGoalPosture`, carried by
    /// [`TwinVerdict::goal_taken_wire`]). Said on the frame that shows it; the arm holds,
    /// and the goal is live again once the box has gone.
    GoalTaken = 8,
}

impl TryFrom<u8> for EpisodeEnd {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            1 => Ok(Self::Success),
            2 => Ok(Self::Collision),
            3 => Ok(Self::Timeout),
            4 => Ok(Self::LimitViolation),
            5 => Ok(Self::Other),
            6 => Ok(Self::NoGoal),
            7 => Ok(Self::NotLearned),
            8 => Ok(Self::GoalTaken),
            _ => Err(SchemaError::BadEnum {
                field: "episode_end",
                value: u32::from(value),
            }),
        }
    }
}

/// The twin worker's phase when a verdict was produced (diagnostics: why the arm moves or
/// holds). Stored as a `u8`; convert with `try_from`. 0 is "not told" (a producer without a
/// worker, e.g. a test stand-in).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u8)]
pub enum PhaseCode {
    /// Not told.
    #[default]
    Unknown = 0,
    /// An episode: the arm follows (or waits for) an episode plan.
    Episode = 1,
    /// The controller refused a plan; planning waits out a pause.
    BackOff = 2,
    /// The episode ended at its goal; the arm rests there before returning home.
    DwellAtGoal = 3,
    /// The arm returns home along its executed path.
    ReturningHome = 4,
    /// The way home was unsafe in the scene then in force; the arm holds.
    HoldingAfterRefusedReturn = 5,
    /// The scene's goal was reached already: a newly received policy is judged from the
    /// task's start posture (its verdict is rt-core's acceptance or refusal of it) and its
    /// plan is not sent — the arm rests until the goal or the scene changes.
    Verification = 6,
    /// The arm rested too close to a box that came to it and backs out along the path it
    /// came, re-verified against the current scene; then it plans as usual.
    BackingOut = 7,
}

impl PhaseCode {
    /// Lower-case name (reports, timelines).
    pub fn name(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::Episode => "episode",
            Self::BackOff => "back-off",
            Self::DwellAtGoal => "dwell-at-goal",
            Self::ReturningHome => "returning-home",
            Self::HoldingAfterRefusedReturn => "holding-after-refused-return",
            Self::Verification => "verification",
            Self::BackingOut => "backing-out",
        }
    }
}

impl TryFrom<u8> for PhaseCode {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            0 => Ok(Self::Unknown),
            1 => Ok(Self::Episode),
            2 => Ok(Self::BackOff),
            3 => Ok(Self::DwellAtGoal),
            4 => Ok(Self::ReturningHome),
            5 => Ok(Self::HoldingAfterRefusedReturn),
            6 => Ok(Self::Verification),
            7 => Ok(Self::BackingOut),
            _ => Err(SchemaError::BadEnum {
                field: "phase",
                value: u32::from(value),
            }),
        }
    }
}

/// What would move the arm on the verdict's plan. Stored as a `u8`; convert with
/// `try_from`. 0 is "not told".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u8)]
pub enum Executor {
    /// Not told.
    #[default]
    Unknown = 0,
    /// A learned policy (its lookahead episode).
    Policy = 1,
    /// The feasibility planner's collision-free path (the fallback when no policy passes).
    Planner = 2,
}

impl Executor {
    /// Lower-case name (reports, summaries).
    pub fn name(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::Policy => "policy",
            Self::Planner => "planner",
        }
    }
}

impl TryFrom<u8> for Executor {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            0 => Ok(Self::Unknown),
            1 => Ok(Self::Policy),
            2 => Ok(Self::Planner),
            _ => Err(SchemaError::BadEnum {
                field: "executor",
                value: u32::from(value),
            }),
        }
    }
}

/// The outcome of one lookahead. Flags are `u8` 0/1 (a `bool` in shared memory would make
/// any other byte undefined behaviour); use the `is_*` accessors.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::TwinVerdict.v3")]
pub struct TwinVerdict {
    /// Increases by one per verdict of one rt-core process.
    pub verdict_id: u64,
    /// `DetectionFrame::sequence` of the scene the lookahead ran on (0 = scene file).
    pub scene_sequence: u64,
    /// The policy evaluated.
    pub policy_id: u64,
    /// When the verdict was produced, `CLOCK_MONOTONIC` (ns).
    pub computed_time_ns: u64,
    /// Smallest robot–obstacle clearance over the episode (m; finite, may be ≤ 0 on
    /// contact).
    pub min_distance_m: f64,
    /// Undiscounted episode return.
    pub episode_return: f64,
    /// Steps the episode ran.
    pub steps: u32,
    /// Wall time the lookahead took (µs).
    pub lookahead_compute_us: u32,
    /// 1 when the goal was reached.
    pub task_ok: u8,
    /// 1 when no contact and no limit violation occurred.
    pub safe: u8,
    /// 1 when the plan was approved for execution (`task_ok && safe` and not superseded).
    pub plan_approved: u8,
    /// [`EpisodeEnd`] as a byte.
    pub episode_end: u8,
    /// The worker's [`PhaseCode`] as a byte.
    pub phase: u8,
    /// The [`Executor`] of the verdict's plan as a byte.
    pub executor: u8,
    /// With [`EpisodeEnd::GoalTaken`]: the blocking box (`twin::Blocker::wire`); else 0.
    pub taken_blocker: u8,
    /// With [`EpisodeEnd::GoalTaken`]: the robot part blocked (1–5 links, 6 the tool); else 0.
    pub taken_link: u8,
}

const _: () = assert!(size_of::<TwinVerdict>() == 64);

impl TwinVerdict {
    /// Schema version carried as a service attribute (3: `phase` and `executor` took two
    /// reserved bytes; 4: `episode_end` `NotLearned`, `phase` `Verification`, and one
    /// verdict per plan tried, published after its smoothed plan was checked, so that
    /// `plan_approved` is rt-core's final word on it; 5: `episode_end` [`EpisodeEnd::GoalTaken`],
    /// its blocker and link took the last two reserved bytes, and `phase` `BackingOut`).
    pub const SCHEMA_VERSION: u32 = 5;

    /// Sets the three flags from bools.
    pub fn set_flags(&mut self, task_ok: bool, safe: bool, plan_approved: bool) {
        self.task_ok = flag_byte(task_ok);
        self.safe = flag_byte(safe);
        self.plan_approved = flag_byte(plan_approved);
    }

    /// `task_ok == 1`.
    pub fn is_task_ok(&self) -> bool {
        self.task_ok == 1
    }

    /// `safe == 1`.
    pub fn is_safe(&self) -> bool {
        self.safe == 1
    }

    /// `plan_approved == 1`.
    pub fn is_plan_approved(&self) -> bool {
        self.plan_approved == 1
    }

    /// The episode end, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn episode_end(&self) -> Result<EpisodeEnd, SchemaError> {
        EpisodeEnd::try_from(self.episode_end)
    }

    /// The worker's phase, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn phase(&self) -> Result<PhaseCode, SchemaError> {
        PhaseCode::try_from(self.phase)
    }

    /// The reason of a [`EpisodeEnd::GoalTaken`] verdict as `twin::InfeasibleReason::wire`'s
    /// bytes `(kind, blocker, link, by_m)` (kind `NoGoalPosture`; `by_m` is minus
    /// `min_distance_m`, the best goal posture's shortfall); `None` for any other verdict.
    pub fn goal_taken_wire(&self) -> Option<(u8, u8, u8, f32)> {
        (self.episode_end == EpisodeEnd::GoalTaken as u8).then(|| {
            (
                crate::InfeasibleKind::NoGoalPosture as u8,
                self.taken_blocker,
                self.taken_link,
                (-self.min_distance_m).max(0.0) as f32,
            )
        })
    }

    /// The executor, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn executor(&self) -> Result<Executor, SchemaError> {
        Executor::try_from(self.executor)
    }

    /// Checks flags, the episode-end, phase and executor bytes, and finite numbers.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        flag("task_ok", self.task_ok)?;
        flag("safe", self.safe)?;
        flag("plan_approved", self.plan_approved)?;
        self.episode_end()?;
        self.phase()?;
        self.executor()?;
        finite_f64("min_distance_m", &[self.min_distance_m])?;
        finite_f64("episode_return", &[self.episode_return])?;
        if self.is_plan_approved() && !(self.is_task_ok() && self.is_safe()) {
            return Err(SchemaError::OutOfRange {
                field: "plan_approved",
            });
        }
        Ok(())
    }
}
