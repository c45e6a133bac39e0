//! [`GoalRequest`]: a goal given by a program rather than seen by the camera (the ROS 2
//! `Reach` action served by `ros-bridge` → rt-core), and [`GoalBounds`]: the one check of a
//! requested goal against the workspace and the table, shared by the bridge (which refuses
//! the action goal naming the bound) and rt-core's intake (which checks again on arrival).
//!
//! rt-core uses requested goals only when its goal source is `action` (`[goal] source` in
//! `assets/runtime.toml`, `foresight --goal-source`); the camera's obstacles count either way.
//!
//! The goal service keeps its last sample for late subscribers, so a restarted rt-core
//! would find the previous run's last reach waiting; rt-core takes a reach only when
//! [`GoalRequest::check_age`] passes: made after it started and at most
//! [`MAX_REACH_AGE_NS`] old.

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, finite_f64};

/// What a [`GoalRequest`] asks. Stored as a `u8`; convert with `try_from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum GoalCommand {
    /// Reach `target_m` (replaces any earlier goal: the arm joins a plan toward the new one).
    Reach = 1,
    /// Withdraw goal `goal_id` and stop the arm (a cancelled or timed-out action goal).
    Cancel = 2,
    /// Withdraw goal `goal_id` without stopping the arm (the goal was reached or has ended;
    /// a return home under way goes on).
    Release = 3,
}

impl TryFrom<u8> for GoalCommand {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            1 => Ok(Self::Reach),
            2 => Ok(Self::Cancel),
            3 => Ok(Self::Release),
            _ => Err(SchemaError::BadEnum {
                field: "command",
                value: u32::from(value),
            }),
        }
    }
}

/// The cube rt-core puts at a requested goal, m: the same edge as the bundled goal cube, so
/// a requested goal is reached exactly as a seen one (`success.goal_hover_m` above its top).
pub const REQUESTED_GOAL_SIZE_M: f64 = 0.05;

/// Lowest approach height a request may ask, m above the table.
pub const MIN_APPROACH_HEIGHT_M: f64 = 0.05;
/// Highest approach height a request may ask, m above the table.
pub const MAX_APPROACH_HEIGHT_M: f64 = 0.5;

/// A goal request, bridge → rt-core ([`crate::services::GOAL_REQUESTS`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::GoalRequest.v1")]
pub struct GoalRequest {
    /// The requester's id of the goal (> 0; a new goal has a larger id than the one before).
    pub goal_id: u64,
    /// When the request was made, `CLOCK_MONOTONIC` (ns).
    pub request_time_ns: u64,
    /// Target on the table, x and y in the base (world) frame, m.
    pub target_m: [f64; 2],
    /// Height above the table the TCP reaches over the target, m; 0 = the task's default
    /// (as over a goal cube on the table: its edge plus `success.goal_hover_m`).
    pub approach_height_m: f64,
    /// [`GoalCommand`] as a byte.
    pub command: u8,
    /// Reserved, zero.
    pub reserved: [u8; 7],
}

const _: () = assert!(size_of::<GoalRequest>() == 48);

/// The oldest a reach request may be when rt-core takes it, ns (2 s): the bridge sends it
/// when it accepts the action goal, and rt-core's intake takes it within a few periods.
pub const MAX_REACH_AGE_NS: u64 = 2_000_000_000;

/// Why a reach request is too old (or too new) to take ([`GoalRequest::check_age`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum GoalRequestAgeError {
    /// Made before this rt-core started: a request of an earlier run, replayed to it.
    #[error(
        "made {:.3} s before this rt-core started (an earlier run's request, replayed)",
        *before_ns as f64 / 1e9
    )]
    BeforeStart {
        /// How long before the start, ns.
        before_ns: u64,
    },
    /// Older than [`MAX_REACH_AGE_NS`].
    #[error(
        "{:.3} s old, above the limit of {:.3} s (goal_request::MAX_REACH_AGE_NS)",
        *age_ns as f64 / 1e9,
        MAX_REACH_AGE_NS as f64 / 1e9
    )]
    TooOld {
        /// Its age, ns.
        age_ns: u64,
    },
    /// Stamped after `now` (no process on this machine can have made it yet).
    #[error("stamped {:.3} s in the future", *ahead_ns as f64 / 1e9)]
    InTheFuture {
        /// How far ahead, ns.
        ahead_ns: u64,
    },
}

impl GoalRequest {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 1;

    /// A request to reach `target_m` (approach height 0 = the default).
    pub fn reach(goal_id: u64, target_m: [f64; 2], approach_height_m: f64) -> Self {
        Self {
            goal_id,
            request_time_ns: crate::clock::monotonic_now_ns(),
            target_m,
            approach_height_m,
            command: GoalCommand::Reach as u8,
            reserved: [0; 7],
        }
    }

    /// A request to withdraw goal `goal_id` ([`GoalCommand::Cancel`] or
    /// [`GoalCommand::Release`]).
    pub fn withdraw(goal_id: u64, command: GoalCommand) -> Self {
        Self {
            goal_id,
            request_time_ns: crate::clock::monotonic_now_ns(),
            command: command as u8,
            ..Self::default()
        }
    }

    /// The command, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn command(&self) -> Result<GoalCommand, SchemaError> {
        GoalCommand::try_from(self.command)
    }

    /// Whether the request may be taken at `now_ns` by an rt-core that started at
    /// `started_ns` (both `CLOCK_MONOTONIC`, as `request_time_ns`): made after the start and
    /// at most [`MAX_REACH_AGE_NS`] before `now_ns`.
    ///
    /// # Errors
    /// The [`GoalRequestAgeError`].
    pub fn check_age(&self, now_ns: u64, started_ns: u64) -> Result<(), GoalRequestAgeError> {
        let made = self.request_time_ns;
        if made < started_ns {
            return Err(GoalRequestAgeError::BeforeStart {
                before_ns: started_ns - made,
            });
        }
        if made > now_ns {
            return Err(GoalRequestAgeError::InTheFuture {
                ahead_ns: made - now_ns,
            });
        }
        if now_ns - made > MAX_REACH_AGE_NS {
            return Err(GoalRequestAgeError::TooOld {
                age_ns: now_ns - made,
            });
        }
        Ok(())
    }

    /// Checks the id, the command byte, finite numbers, the approach height's range and the
    /// reserved bytes (the workspace is [`GoalBounds::check`]'s, which needs the runtime's
    /// configuration).
    ///
    /// # Errors
    /// The first [`SchemaError`] found, naming its field.
    pub fn validate(&self) -> Result<(), SchemaError> {
        if self.goal_id == 0 {
            return Err(SchemaError::OutOfRange { field: "goal_id" });
        }
        self.command()?;
        finite_f64("target_m", &self.target_m)?;
        finite_f64("approach_height_m", &[self.approach_height_m])?;
        let h = self.approach_height_m;
        if h != 0.0 && !(MIN_APPROACH_HEIGHT_M..=MAX_APPROACH_HEIGHT_M).contains(&h) {
            return Err(SchemaError::OutOfRange {
                field: "approach_height_m",
            });
        }
        if self.reserved != [0; 7] {
            return Err(SchemaError::OutOfRange { field: "reserved" });
        }
        Ok(())
    }
}

/// Where a requested goal may lie: rt-core's configuration (`[intake]` and `[shield]` of
/// `assets/runtime.toml`) as the bridge and the intake both read it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalBounds {
    /// `[intake] goal_min_radius_m`: nearest to the base axis, m.
    pub min_radius_m: f64,
    /// `[intake] goal_max_radius_m`: farthest from the base axis, m.
    pub max_radius_m: f64,
    /// `[intake] calibrated_min_m`: the table area the camera sees, lower corner, m.
    pub table_min_m: [f64; 3],
    /// `[intake] calibrated_max_m`: upper corner, m.
    pub table_max_m: [f64; 3],
    /// `[shield] workspace_min_m`: the TCP's workspace, lower corner, m.
    pub workspace_min_m: [f64; 3],
    /// `[shield] workspace_max_m`: upper corner, m.
    pub workspace_max_m: [f64; 3],
}

/// Why a requested goal is refused: the bound it breaks, named as in
/// `assets/runtime.toml`, with the value and the limit.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{what} = {value:.3} m breaks the bound {bound} = {limit:.3} m")]
pub struct GoalBoundError {
    /// The bound (`intake.goal_max_radius_m`, `shield.workspace_min_m[0]`, …).
    pub bound: &'static str,
    /// What was measured (`distance from the base axis`, `x`, `approach height`, …).
    pub what: &'static str,
    /// The request's value, m.
    pub value: f64,
    /// The bound's value, m.
    pub limit: f64,
}

impl GoalBounds {
    /// Checks a target `(x, y)` and approach height (0 = the default, `default_height_m`)
    /// over a table at `table_height_m`.
    ///
    /// # Errors
    /// The first [`GoalBoundError`]: the reach (radius), the table area, the workspace box,
    /// then the approach height.
    pub fn check(
        &self,
        target_m: [f64; 2],
        approach_height_m: f64,
        default_height_m: f64,
        table_height_m: f64,
    ) -> Result<(), GoalBoundError> {
        let err = |bound, what, value, limit| {
            Err(GoalBoundError {
                bound,
                what,
                value,
                limit,
            })
        };
        if !(target_m[0].is_finite() && target_m[1].is_finite() && approach_height_m.is_finite()) {
            return err("finite numbers", "target", f64::NAN, f64::NAN);
        }
        let r = target_m[0].hypot(target_m[1]);
        let axis = "distance from the base axis";
        if r < self.min_radius_m {
            return err("intake.goal_min_radius_m", axis, r, self.min_radius_m);
        }
        if r > self.max_radius_m {
            return err("intake.goal_max_radius_m", axis, r, self.max_radius_m);
        }
        const TABLE_MIN: [&str; 2] = ["intake.calibrated_min_m[0]", "intake.calibrated_min_m[1]"];
        const TABLE_MAX: [&str; 2] = ["intake.calibrated_max_m[0]", "intake.calibrated_max_m[1]"];
        const WS_MIN: [&str; 3] = [
            "shield.workspace_min_m[0]",
            "shield.workspace_min_m[1]",
            "shield.workspace_min_m[2]",
        ];
        const WS_MAX: [&str; 3] = [
            "shield.workspace_max_m[0]",
            "shield.workspace_max_m[1]",
            "shield.workspace_max_m[2]",
        ];
        const AXIS: [&str; 3] = ["x", "y", "target height"];
        for k in 0..2 {
            let v = target_m[k];
            if v < self.table_min_m[k] {
                return err(TABLE_MIN[k], AXIS[k], v, self.table_min_m[k]);
            }
            if v > self.table_max_m[k] {
                return err(TABLE_MAX[k], AXIS[k], v, self.table_max_m[k]);
            }
            if v < self.workspace_min_m[k] {
                return err(WS_MIN[k], AXIS[k], v, self.workspace_min_m[k]);
            }
            if v > self.workspace_max_m[k] {
                return err(WS_MAX[k], AXIS[k], v, self.workspace_max_m[k]);
            }
        }
        let h = approach_height_m;
        if h != 0.0 {
            if h < MIN_APPROACH_HEIGHT_M {
                return err(
                    "goal_request::MIN_APPROACH_HEIGHT_M",
                    "approach height",
                    h,
                    MIN_APPROACH_HEIGHT_M,
                );
            }
            if h > MAX_APPROACH_HEIGHT_M {
                return err(
                    "goal_request::MAX_APPROACH_HEIGHT_M",
                    "approach height",
                    h,
                    MAX_APPROACH_HEIGHT_M,
                );
            }
        }
        let z = table_height_m + if h == 0.0 { default_height_m } else { h };
        if z < self.workspace_min_m[2] {
            return err(WS_MIN[2], AXIS[2], z, self.workspace_min_m[2]);
        }
        if z > self.workspace_max_m[2] {
            return err(WS_MAX[2], AXIS[2], z, self.workspace_max_m[2]);
        }
        Ok(())
    }
}

/// The grid a requested goal's centre is snapped to, m (rt-core's detection grid: the
/// bridge and rt-core then agree on the TCP target to the bit).
pub const REQUESTED_GOAL_GRID_M: f64 = 0.005;

/// The centre of the goal cube rt-core puts at a requested target: on the table for the
/// default approach height (0), raised so that the TCP target (`goal_hover_m` above its top)
/// lies `approach_height_m` above the table otherwise; snapped to
/// [`REQUESTED_GOAL_GRID_M`].
pub fn requested_goal_center_m(
    target_m: [f64; 2],
    approach_height_m: f64,
    table_height_m: f64,
    goal_hover_m: f64,
) -> [f64; 3] {
    let half = REQUESTED_GOAL_SIZE_M / 2.0;
    let z = if approach_height_m == 0.0 {
        table_height_m + half
    } else {
        table_height_m + approach_height_m - goal_hover_m - half
    };
    let snap = |v: f64| (v / REQUESTED_GOAL_GRID_M).round() * REQUESTED_GOAL_GRID_M;
    [snap(target_m[0]), snap(target_m[1]), snap(z)]
}

/// The TCP target of a requested goal: `goal_hover_m` above the top of the cube
/// [`requested_goal_center_m`] places (what rt-core plans toward and checks "reached" at).
pub fn requested_tcp_target_m(
    target_m: [f64; 2],
    approach_height_m: f64,
    table_height_m: f64,
    goal_hover_m: f64,
) -> [f64; 3] {
    let c = requested_goal_center_m(target_m, approach_height_m, table_height_m, goal_hover_m);
    [
        c[0],
        c[1],
        c[2] + REQUESTED_GOAL_SIZE_M / 2.0 + goal_hover_m,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bounds() -> GoalBounds {
        GoalBounds {
            min_radius_m: 0.15,
            max_radius_m: 0.65,
            table_min_m: [-0.8, -0.8, -0.05],
            table_max_m: [0.8, 0.8, 1.0],
            workspace_min_m: [-0.8, -0.8, 0.0],
            workspace_max_m: [0.8, 0.8, 1.0],
        }
    }

    /// Issue 41 item 5: a request made before rt-core started (the service's history
    /// replays the last one to a restarted rt-core), one older than the limit and one from
    /// the future are refused; one made since the start and young enough is taken.
    #[test]
    fn a_reach_request_is_taken_only_when_made_since_the_start_and_young() {
        let started = 5_000_000_000;
        let at = |t| GoalRequest {
            request_time_ns: t,
            ..GoalRequest::reach(1, [0.4, 0.0], 0.0)
        };
        at(started).check_age(started + 1, started).unwrap();
        at(started + 1)
            .check_age(started + 1 + MAX_REACH_AGE_NS, started)
            .unwrap();
        assert_eq!(
            at(started - 1).check_age(started + 1, started),
            Err(GoalRequestAgeError::BeforeStart { before_ns: 1 })
        );
        assert_eq!(
            at(started).check_age(started + MAX_REACH_AGE_NS + 1, started),
            Err(GoalRequestAgeError::TooOld {
                age_ns: MAX_REACH_AGE_NS + 1
            })
        );
        let e = at(started + 10)
            .check_age(started + 5, started)
            .unwrap_err();
        assert_eq!(e, GoalRequestAgeError::InTheFuture { ahead_ns: 5 });
        let e = at(1_000_000_000).check_age(started, started).unwrap_err();
        assert!(e.to_string().contains("4.000 s before"), "{e}");
    }

    #[test]
    fn a_goal_out_of_bounds_is_refused_naming_the_bound() {
        let b = bounds();
        b.check([0.4, 0.1], 0.0, 0.1, 0.0).unwrap();
        b.check([0.4, 0.1], 0.3, 0.1, 0.0).unwrap();
        let e = b.check([0.9, 0.0], 0.0, 0.1, 0.0).unwrap_err();
        assert_eq!(e.bound, "intake.goal_max_radius_m");
        assert!(e.to_string().contains("intake.goal_max_radius_m"), "{e}");
        let e = b.check([0.05, 0.0], 0.0, 0.1, 0.0).unwrap_err();
        assert_eq!(e.bound, "intake.goal_min_radius_m");
        let narrow = GoalBounds {
            table_max_m: [0.3, 0.8, 1.0],
            ..b
        };
        let e = narrow.check([0.4, 0.0], 0.0, 0.1, 0.0).unwrap_err();
        assert_eq!(e.bound, "intake.calibrated_max_m[0]");
        let e = b.check([0.4, 0.0], 0.9, 0.1, 0.0).unwrap_err();
        assert_eq!(e.bound, "goal_request::MAX_APPROACH_HEIGHT_M");
        let low = GoalBounds {
            workspace_max_m: [0.8, 0.8, 0.2],
            ..b
        };
        let e = low.check([0.4, 0.0], 0.3, 0.1, 0.0).unwrap_err();
        assert_eq!(e.bound, "shield.workspace_max_m[2]");
    }

    #[test]
    fn a_malformed_request_is_rejected_naming_the_field() {
        let ok = GoalRequest::reach(1, [0.4, 0.1], 0.0);
        ok.validate().unwrap();
        let field = |r: GoalRequest| match r.validate().unwrap_err() {
            SchemaError::OutOfRange { field }
            | SchemaError::NonFinite { field }
            | SchemaError::BadEnum { field, .. } => field,
            e => panic!("{e:?}"),
        };
        assert_eq!(field(GoalRequest { goal_id: 0, ..ok }), "goal_id");
        assert_eq!(field(GoalRequest { command: 9, ..ok }), "command");
        assert_eq!(
            field(GoalRequest {
                target_m: [f64::NAN, 0.0],
                ..ok
            }),
            "target_m"
        );
        assert_eq!(
            field(GoalRequest {
                approach_height_m: 2.0,
                ..ok
            }),
            "approach_height_m"
        );
        assert_eq!(
            field(GoalRequest {
                reserved: [1, 0, 0, 0, 0, 0, 0],
                ..ok
            }),
            "reserved"
        );
        GoalRequest::withdraw(3, GoalCommand::Cancel)
            .validate()
            .unwrap();
    }

    #[test]
    fn the_requested_goal_puts_the_tcp_target_at_the_approach_height() {
        let hover = 0.05;
        let c = requested_goal_center_m([0.4, 0.1], 0.0, 0.0, hover);
        assert!((c[2] - REQUESTED_GOAL_SIZE_M / 2.0).abs() < 1e-12);
        let t = requested_tcp_target_m([0.4, 0.1], 0.3, 0.0, hover);
        assert!(
            (t[2] - 0.3).abs() <= REQUESTED_GOAL_GRID_M / 2.0 + 1e-12,
            "{t:?}"
        );
        let c = requested_goal_center_m([0.4031, 0.1], 0.0, 0.0, hover);
        assert!((c[0] - 0.405).abs() < 1e-12, "snapped to the grid: {c:?}");
    }
}
