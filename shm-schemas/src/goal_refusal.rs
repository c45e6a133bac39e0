//! [`GoalRefusal`]: rt-core's answer to a [`crate::GoalRequest`] it did not take (rt-core →
//! ros-bridge), so that the `Reach` action goal behind it ends at once, aborted, naming why,
//! instead of waiting for a motion that will never come (a goal without a deadline waited
//! forever). The typical case is a request refused by age ([`crate::GoalRequest::check_age`]):
//! made before this rt-core started, or older than
//! [`crate::goal_request::MAX_REACH_AGE_NS`] when rt-core came to it.

use iceoryx2::prelude::ZeroCopySend;

use crate::error::SchemaError;
use crate::goal_request::GoalRequestAgeError;

/// Why rt-core refused a goal request. Stored as a `u8`; convert with `try_from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum GoalRefusalKind {
    /// Older than the bound when rt-core came to it: `value_ns` is its age, `bound_ns` the
    /// bound.
    TooOld = 1,
    /// Made before this rt-core started (an earlier run's request, replayed): `value_ns` is
    /// how long before.
    BeforeStart = 2,
    /// Stamped in the future: `value_ns` is how far ahead.
    InTheFuture = 3,
    /// Its id does not follow the last one taken.
    StaleId = 4,
    /// Out of the workspace or the table bounds.
    OutOfBounds = 5,
    /// It failed its schema validation.
    Invalid = 6,
    /// rt-core's goal source is the camera.
    SourceIsCamera = 7,
}

impl TryFrom<u8> for GoalRefusalKind {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        Ok(match value {
            1 => Self::TooOld,
            2 => Self::BeforeStart,
            3 => Self::InTheFuture,
            4 => Self::StaleId,
            5 => Self::OutOfBounds,
            6 => Self::Invalid,
            7 => Self::SourceIsCamera,
            _ => {
                return Err(SchemaError::BadEnum {
                    field: "kind",
                    value: u32::from(value),
                });
            }
        })
    }
}

/// A goal request rt-core refused, rt-core → ros-bridge ([`crate::services::GOAL_REFUSALS`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::GoalRefusal.v1")]
pub struct GoalRefusal {
    /// The refused request's `goal_id`.
    pub goal_id: u64,
    /// When rt-core refused it, `CLOCK_MONOTONIC` (ns).
    pub refused_time_ns: u64,
    /// The measure of the refusal, ns: the age ([`GoalRefusalKind::TooOld`]), how long
    /// before the start ([`GoalRefusalKind::BeforeStart`]), how far ahead
    /// ([`GoalRefusalKind::InTheFuture`]); 0 otherwise.
    pub value_ns: u64,
    /// The bound broken, ns ([`GoalRefusalKind::TooOld`]); 0 otherwise.
    pub bound_ns: u64,
    /// [`GoalRefusalKind`] as a byte.
    pub kind: u8,
    /// The refused request's [`crate::GoalCommand`] byte.
    pub command: u8,
    /// Reserved, zero.
    pub reserved: [u8; 6],
}

const _: () = assert!(size_of::<GoalRefusal>() == 40);

impl GoalRefusal {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 1;

    /// A refusal of request `goal_id` (command byte `command`) for `kind`, at `now_ns`.
    pub fn new(goal_id: u64, command: u8, kind: GoalRefusalKind, now_ns: u64) -> Self {
        Self {
            goal_id,
            refused_time_ns: now_ns,
            command,
            kind: kind as u8,
            ..Self::default()
        }
    }

    /// A refusal by age ([`crate::GoalRequest::check_age`]'s error), with its measure.
    pub fn by_age(goal_id: u64, command: u8, e: &GoalRequestAgeError, now_ns: u64) -> Self {
        let (kind, value_ns, bound_ns) = match *e {
            GoalRequestAgeError::TooOld { age_ns } => (
                GoalRefusalKind::TooOld,
                age_ns,
                crate::goal_request::MAX_REACH_AGE_NS,
            ),
            GoalRequestAgeError::BeforeStart { before_ns } => {
                (GoalRefusalKind::BeforeStart, before_ns, 0)
            }
            GoalRequestAgeError::InTheFuture { ahead_ns } => {
                (GoalRefusalKind::InTheFuture, ahead_ns, 0)
            }
        };
        Self {
            value_ns,
            bound_ns,
            ..Self::new(goal_id, command, kind, now_ns)
        }
    }

    /// The kind, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn kind(&self) -> Result<GoalRefusalKind, SchemaError> {
        GoalRefusalKind::try_from(self.kind)
    }

    /// Checks the kind, the command byte and the reserved bytes.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        self.kind()?;
        crate::GoalCommand::try_from(self.command)?;
        if self.reserved != [0; 6] {
            return Err(SchemaError::OutOfRange { field: "reserved" });
        }
        Ok(())
    }

    /// Why, in words: "the request is 2.500 s old, over the 2.000 s bound" and the like.
    pub fn words(&self) -> String {
        let s = |ns: u64| ns as f64 / 1e9;
        match self.kind() {
            Ok(GoalRefusalKind::TooOld) => format!(
                "the request is {:.3} s old, over the {:.3} s bound",
                s(self.value_ns),
                s(self.bound_ns)
            ),
            Ok(GoalRefusalKind::BeforeStart) => format!(
                "the request was made {:.3} s before rt-core started (an earlier run's, \
                 replayed)",
                s(self.value_ns)
            ),
            Ok(GoalRefusalKind::InTheFuture) => {
                format!(
                    "the request is stamped {:.3} s in the future",
                    s(self.value_ns)
                )
            }
            Ok(GoalRefusalKind::StaleId) => {
                "its id does not follow the last goal rt-core took".into()
            }
            Ok(GoalRefusalKind::OutOfBounds) => "out of rt-core's goal bounds".into(),
            Ok(GoalRefusalKind::Invalid) => "the request is invalid".into(),
            Ok(GoalRefusalKind::SourceIsCamera) => "rt-core's goal source is the camera".into(),
            Err(e) => format!("{e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::GoalCommand;

    #[test]
    fn a_refusal_by_age_names_the_age_and_the_bound_and_validates() {
        let e = GoalRequestAgeError::TooOld {
            age_ns: 2_500_000_000,
        };
        let r = GoalRefusal::by_age(7, GoalCommand::Reach as u8, &e, 99);
        r.validate().unwrap();
        assert_eq!(r.kind(), Ok(GoalRefusalKind::TooOld));
        assert_eq!((r.goal_id, r.refused_time_ns), (7, 99));
        assert_eq!(
            r.words(),
            "the request is 2.500 s old, over the 2.000 s bound"
        );
        let replayed = GoalRefusal::by_age(
            7,
            GoalCommand::Reach as u8,
            &GoalRequestAgeError::BeforeStart { before_ns: 1 },
            99,
        );
        assert!(replayed.words().contains("before rt-core started"));
        let bad = GoalRefusal { kind: 0, ..r };
        assert!(bad.validate().is_err());
        let bad = GoalRefusal { command: 9, ..r };
        assert!(bad.validate().is_err());
    }
}
