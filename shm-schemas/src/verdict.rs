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
            _ => Err(SchemaError::BadEnum {
                field: "episode_end",
                value: u32::from(value),
            }),
        }
    }
}

/// The outcome of one lookahead. Flags are `u8` 0/1 (a `bool` in shared memory would make
/// any other byte undefined behaviour); use the `is_*` accessors.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::TwinVerdict.v2")]
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
    /// Reserved, zero.
    pub reserved: [u8; 4],
}

const _: () = assert!(size_of::<TwinVerdict>() == 64);

impl TwinVerdict {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 2;

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

    /// Checks flags, the episode-end byte and finite numbers.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        flag("task_ok", self.task_ok)?;
        flag("safe", self.safe)?;
        flag("plan_approved", self.plan_approved)?;
        self.episode_end()?;
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
