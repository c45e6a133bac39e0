//! [`RetrainRequest`] (rt-core → learner: "this scene failed, learn it") and
//! [`RetrainProgress`] (learner → anyone: how the retraining goes).

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, count_within, finite_f64};
use crate::scene_file::{
    BoxSpec, GoalSpec, MAX_OBSTACLES, MAX_SCENE_EXTENT_M, SceneFile, TableSpec,
};
use crate::verdict::TwinVerdict;

/// One axis-aligned obstacle box in the base frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::ObstacleBox.v1")]
pub struct ObstacleBox {
    /// Box centre (m).
    pub center_m: [f64; 3],
    /// Full extents along x, y, z (m), each > 0.
    pub size_m: [f64; 3],
}

const _: () = assert!(size_of::<ObstacleBox>() == 48);

fn check_box(
    center_m: &[f64; 3],
    size_m: &[f64],
    center_field: &'static str,
    size_field: &'static str,
) -> Result<(), SchemaError> {
    finite_f64(center_field, center_m)?;
    finite_f64(size_field, size_m)?;
    if center_m.iter().any(|c| c.abs() > MAX_SCENE_EXTENT_M) {
        return Err(SchemaError::OutOfRange {
            field: center_field,
        });
    }
    if size_m.iter().any(|s| *s <= 0.0 || *s > MAX_SCENE_EXTENT_M) {
        return Err(SchemaError::OutOfRange { field: size_field });
    }
    Ok(())
}

/// A scene the current policy failed in the lookahead, sent to the learner for retraining.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::RetrainRequest.v2")]
pub struct RetrainRequest {
    /// Increases by one per request of one rt-core process.
    pub request_id: u64,
    /// When the request was made, `CLOCK_MONOTONIC` (ns).
    pub request_time_ns: u64,
    /// Hash of the task configuration rt-core runs (the learner must train for the same).
    pub task_config_hash: u64,
    /// The policy that failed.
    pub failed_policy_id: u64,
    /// `DetectionFrame::sequence` the scene was built from (0 = scene file).
    pub scene_sequence: u64,
    /// Table-top height (m).
    pub table_height_m: f64,
    /// Goal cube centre (m).
    pub goal_center_m: [f64; 3],
    /// Goal cube edge (m).
    pub goal_size_m: f64,
    /// Number of valid entries at the front of `obstacles`.
    pub obstacle_count: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// The obstacles; entries at and beyond `obstacle_count` are ignored.
    pub obstacles: [ObstacleBox; MAX_OBSTACLES],
    /// The verdict that failed.
    pub verdict: TwinVerdict,
}

const _: () = assert!(size_of::<RetrainRequest>() == 40 + 40 + 8 + 48 * MAX_OBSTACLES + 64);

impl RetrainRequest {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 2;

    /// The valid obstacles.
    pub fn obstacles(&self) -> &[ObstacleBox] {
        &self.obstacles[..(self.obstacle_count as usize).min(MAX_OBSTACLES)]
    }

    /// Fills the scene fields from a scene (the first [`MAX_OBSTACLES`] obstacles).
    pub fn set_scene(&mut self, scene: &SceneFile) {
        self.table_height_m = scene.table.height_m;
        self.goal_center_m = scene.goal.center_m;
        self.goal_size_m = scene.goal.size_m;
        self.obstacles = [ObstacleBox::default(); MAX_OBSTACLES];
        let n = scene.obstacles.len().min(MAX_OBSTACLES);
        for (slot, b) in self.obstacles.iter_mut().zip(&scene.obstacles[..n]) {
            *slot = ObstacleBox {
                center_m: b.center_m,
                size_m: b.size_m,
            };
        }
        self.obstacle_count = n as u32;
    }

    /// The scene as a [`SceneFile`] (named `retrain-<request_id>`), for the learner.
    pub fn scene(&self) -> SceneFile {
        SceneFile {
            name: format!("retrain-{}", self.request_id),
            table: TableSpec {
                height_m: self.table_height_m,
            },
            goal: GoalSpec {
                center_m: self.goal_center_m,
                size_m: self.goal_size_m,
            },
            obstacles: self
                .obstacles()
                .iter()
                .map(|o| BoxSpec {
                    center_m: o.center_m,
                    size_m: o.size_m,
                    path: Default::default(),
                })
                .collect(),
        }
    }

    /// Checks the obstacle count, finite numbers, positive sizes and the verdict.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        count_within("obstacle_count", self.obstacle_count, MAX_OBSTACLES)?;
        finite_f64("table_height_m", &[self.table_height_m])?;
        if self.table_height_m.abs() > MAX_SCENE_EXTENT_M {
            return Err(SchemaError::OutOfRange {
                field: "table_height_m",
            });
        }
        check_box(
            &self.goal_center_m,
            &[self.goal_size_m],
            "goal_center_m",
            "goal_size_m",
        )?;
        for o in self.obstacles() {
            check_box(
                &o.center_m,
                &o.size_m,
                "obstacles.center_m",
                "obstacles.size_m",
            )?;
        }
        self.verdict.validate()
    }
}

/// Phase of a retraining run. Stored as a `u8`; convert with `try_from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RetrainPhase {
    /// PPO updates are running.
    Training = 1,
    /// The candidate is being evaluated in the twin.
    Evaluating = 2,
    /// A passing policy was published (`published_policy_id`).
    Published = 3,
    /// The step or time budget ran out without a passing policy.
    BudgetExhausted = 4,
    /// The learner's feasibility check found no safe way to the goal (final): see
    /// [`RetrainProgress::infeasible_kind`] for the reason. Nothing is trained.
    Infeasible = 5,
}

impl RetrainPhase {
    /// The learner is done with the request (no more progress will follow).
    pub fn is_final(self) -> bool {
        matches!(
            self,
            Self::Published | Self::BudgetExhausted | Self::Infeasible
        )
    }
}

/// Why a world is infeasible ([`RetrainProgress::infeasible_kind`]). Stored as a `u8`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum InfeasibleKind {
    /// Not infeasible (every phase but [`RetrainPhase::Infeasible`]).
    None = 0,
    /// The goal target point is out of the arm's reach at any posture.
    OutOfReach = 1,
    /// Every goal posture found collides: `blocker` blocks `link` by `deficit_m`.
    NoGoalPosture = 2,
    /// Safe goal postures exist but the planner found no collision-free path to any of
    /// them within its budget.
    NoPath = 3,
}

impl TryFrom<u8> for InfeasibleKind {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            0 => Ok(Self::None),
            1 => Ok(Self::OutOfReach),
            2 => Ok(Self::NoGoalPosture),
            3 => Ok(Self::NoPath),
            _ => Err(SchemaError::BadEnum {
                field: "infeasible_kind",
                value: u32::from(value),
            }),
        }
    }
}

/// `RetrainProgress::infeasible_blocker` for the table.
pub const BLOCKER_TABLE: u8 = 0xFE;
/// `RetrainProgress::infeasible_blocker` for the arm itself (self-collision).
pub const BLOCKER_SELF: u8 = 0xFD;
/// `RetrainProgress::infeasible_blocker` when nothing in particular blocks.
pub const BLOCKER_NONE: u8 = 0xFF;

impl TryFrom<u8> for RetrainPhase {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            1 => Ok(Self::Training),
            2 => Ok(Self::Evaluating),
            3 => Ok(Self::Published),
            4 => Ok(Self::BudgetExhausted),
            5 => Ok(Self::Infeasible),
            _ => Err(SchemaError::BadEnum {
                field: "phase",
                value: u32::from(value),
            }),
        }
    }
}

/// Progress of the learner on one [`RetrainRequest`].
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::RetrainProgress.v2")]
pub struct RetrainProgress {
    /// The request being served (`RetrainRequest::request_id`; 0 = pre-training).
    pub request_id: u64,
    /// Environment steps trained so far on this request.
    pub steps_done: u64,
    /// The policy published (0 until [`RetrainPhase::Published`]).
    pub published_policy_id: u64,
    /// Mean episode return of the latest evaluation or rollout batch.
    pub mean_return: f64,
    /// Success rate of the latest evaluation, in [0, 1].
    pub success_rate: f64,
    /// Wall time since the request arrived (s).
    pub wall_time_s: f64,
    /// [`RetrainPhase`] as a byte.
    pub phase: u8,
    /// [`InfeasibleKind`] as a byte (0 unless the phase is [`RetrainPhase::Infeasible`]).
    pub infeasible_kind: u8,
    /// With [`InfeasibleKind::NoGoalPosture`]: the obstacle index in the request's scene
    /// that blocks, or [`BLOCKER_TABLE`], [`BLOCKER_SELF`], [`BLOCKER_NONE`].
    pub infeasible_blocker: u8,
    /// With [`InfeasibleKind::NoGoalPosture`]: the robot link blocked (1–5 for link1–link5,
    /// 6 for the tool, 0 for none).
    pub infeasible_link: u8,
    /// How far the best goal posture found misses (m): the clearance deficit for
    /// `NoGoalPosture`, the distance beyond reach for `OutOfReach`; 0 otherwise.
    pub infeasible_by_m: f32,
}

const _: () = assert!(size_of::<RetrainProgress>() == 56);

impl RetrainProgress {
    /// Schema version carried as a service attribute.
    pub const SCHEMA_VERSION: u32 = 2;

    /// The phase, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn phase(&self) -> Result<RetrainPhase, SchemaError> {
        RetrainPhase::try_from(self.phase)
    }

    /// The infeasibility reason's kind, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown byte.
    pub fn infeasible_kind(&self) -> Result<InfeasibleKind, SchemaError> {
        InfeasibleKind::try_from(self.infeasible_kind)
    }

    /// Checks the phase byte, finite numbers and ranges.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        let phase = self.phase()?;
        let kind = self.infeasible_kind()?;
        if (phase == RetrainPhase::Infeasible) != (kind != InfeasibleKind::None) {
            return Err(SchemaError::OutOfRange {
                field: "infeasible_kind",
            });
        }
        if !self.infeasible_by_m.is_finite() || self.infeasible_by_m < 0.0 {
            return Err(SchemaError::OutOfRange {
                field: "infeasible_by_m",
            });
        }
        finite_f64("mean_return", &[self.mean_return])?;
        finite_f64("success_rate", &[self.success_rate])?;
        finite_f64("wall_time_s", &[self.wall_time_s])?;
        if !(0.0..=1.0).contains(&self.success_rate) {
            return Err(SchemaError::OutOfRange {
                field: "success_rate",
            });
        }
        if self.wall_time_s < 0.0 {
            return Err(SchemaError::OutOfRange {
                field: "wall_time_s",
            });
        }
        Ok(())
    }
}
