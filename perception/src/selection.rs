//! What a `DetectionFrame` carries, and in what order: the confidence floors applied to
//! detections, the one goal chosen among the goal tracks, and the obstacles ordered nearest
//! the robot base first, so that when more objects are seen than a frame holds
//! ([`shm_schemas::MAX_DETECTIONS`]) the ones left out are the farthest.
//!
//! Decisions (safety first: a false obstacle costs a detour, a missed one a collision):
//!
//! - **Confidence floors** ([`SelectionConfig`]). A goal detection below
//!   `min_goal_confidence` is not reported as the goal; if it still reaches
//!   `min_obstacle_confidence` it is reported as an *obstacle* (something is there, we are
//!   just not sure it is the cube), else it is left out. An obstacle detection is kept down
//!   to `min_obstacle_confidence`, which may not exceed `min_goal_confidence` nor
//!   [`SelectionConfig::MAX_MIN_OBSTACLE_CONFIDENCE`]. A non-finite confidence counts as 0.
//!   The floors apply to detections *before* the tracker, so its debouncing also covers a
//!   confidence that hovers around a floor.
//! - **One goal** ([`select`]): the most confident goal track is the goal (the oldest track,
//!   lowest id, on a tie). Another goal track whose box overlaps the chosen goal's is the
//!   same cube seen twice and is left out; one that does not overlap is a second physical
//!   object the arm must not hit, and is published as an obstacle.
//! - **Order**: the goal first, then obstacles by the distance from the robot base (the
//!   origin of the twin's frame) to the nearest point of their box, nearest first (id on a
//!   tie). When they do not all fit, the publisher keeps that prefix and says how many were
//!   left out in `dropped_count`, which makes rt-core refuse the frame and stop.
//!
//! ```
//! use perception::selection::{SelectionConfig, apply_confidence_floors};
//! use perception::detection::{Detection, ObjectKind};
//! let cfg = SelectionConfig::default();
//! let mut dets = vec![Detection {
//!     kind: ObjectKind::Goal,
//!     confidence: 0.3,
//!     bbox_px: [0, 0, 10, 10],
//!     position_m: [0.4, 0.0, 0.025],
//!     size_m: [0.05; 3],
//! }];
//! let tally = apply_confidence_floors(&cfg, &mut dets);
//! assert_eq!(dets[0].kind, ObjectKind::Obstacle); // not sure it is the goal: kept as an obstacle
//! assert_eq!(tally.goals_demoted, 1);
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::detection::{Detection, ObjectKind};
use crate::tracker::TrackedObject;

/// The confidence floors of what perception reports (TOML, `perception run
/// --selection-config`; each floor also has a command-line flag).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SelectionConfig {
    /// A goal detection below this confidence is not reported as the goal (it is reported
    /// as an obstacle if it reaches `min_obstacle_confidence`). Allowed
    /// [`SelectionConfig::MIN_GOAL_CONFIDENCE_RANGE`]; default 0.5, as rt-core's
    /// `[intake] min_goal_confidence`.
    pub min_goal_confidence: f32,
    /// An obstacle detection below this confidence is left out. Kept low on purpose: a
    /// doubtful obstacle is still reported. Allowed 0 ..= `min_goal_confidence` and at most
    /// [`SelectionConfig::MAX_MIN_OBSTACLE_CONFIDENCE`]; default 0.05.
    pub min_obstacle_confidence: f32,
}

impl Default for SelectionConfig {
    fn default() -> Self {
        Self {
            min_goal_confidence: 0.5,
            min_obstacle_confidence: 0.05,
        }
    }
}

/// Why a [`SelectionConfig`] was refused; each message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SelectionConfigError {
    /// The file could not be read.
    #[error("cannot read selection config {path}: {message}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The file is not valid TOML for this struct.
    #[error("malformed selection config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (names the field).
        message: String,
    },
    /// A value in the file is out of bounds.
    #[error("selection config {path}: {error}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// The bound broken (names the field).
        error: Box<SelectionConfigError>,
    },
    /// `min_goal_confidence` is outside its range.
    #[error("min_goal_confidence = {value} must be within {min} ..= {max}")]
    GoalFloor {
        /// The value given.
        value: f32,
        /// Smallest allowed.
        min: f32,
        /// Largest allowed.
        max: f32,
    },
    /// `min_obstacle_confidence` is outside its range.
    #[error(
        "min_obstacle_confidence = {value} must be within 0 ..= {max} (and not above min_goal_confidence): a doubtful obstacle must still be reported"
    )]
    ObstacleFloor {
        /// The value given.
        value: f32,
        /// Largest allowed here: the smaller of the fixed bound and `min_goal_confidence`.
        max: f32,
    },
}

impl SelectionConfig {
    /// Allowed `min_goal_confidence`, as rt-core's `[intake] min_goal_confidence`.
    pub const MIN_GOAL_CONFIDENCE_RANGE: std::ops::RangeInclusive<f32> = 0.05..=1.0;
    /// Largest allowed `min_obstacle_confidence`: a higher floor would hide real obstacles.
    pub const MAX_MIN_OBSTACLE_CONFIDENCE: f32 = 0.25;

    /// Checks the bounds.
    ///
    /// # Errors
    /// [`SelectionConfigError`] naming the first bad field.
    pub fn validate(&self) -> Result<(), SelectionConfigError> {
        let g = self.min_goal_confidence;
        if !Self::MIN_GOAL_CONFIDENCE_RANGE.contains(&g) {
            return Err(SelectionConfigError::GoalFloor {
                value: g,
                min: *Self::MIN_GOAL_CONFIDENCE_RANGE.start(),
                max: *Self::MIN_GOAL_CONFIDENCE_RANGE.end(),
            });
        }
        let o = self.min_obstacle_confidence;
        let max = Self::MAX_MIN_OBSTACLE_CONFIDENCE.min(g);
        if !(0.0..=max).contains(&o) {
            return Err(SelectionConfigError::ObstacleFloor { value: o, max });
        }
        Ok(())
    }

    /// Loads and validates a TOML file (missing fields take their defaults).
    ///
    /// # Errors
    /// [`SelectionConfigError`] naming the file or the field.
    pub fn load(path: &Path) -> Result<Self, SelectionConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| SelectionConfigError::Read {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let cfg: Self = toml::from_str(&text).map_err(|e| SelectionConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate().map_err(|e| SelectionConfigError::InFile {
            path: path.to_path_buf(),
            error: Box::new(e),
        })?;
        Ok(cfg)
    }
}

/// What [`apply_confidence_floors`] did to one frame's detections.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FloorTally {
    /// Goal detections below `min_goal_confidence` kept as obstacles.
    pub goals_demoted: u32,
    /// Detections below `min_obstacle_confidence` left out (goals and obstacles).
    pub dropped: u32,
}

/// Applies the confidence floors in place (see the module doc): low goals become obstacles,
/// anything below the obstacle floor is removed.
pub fn apply_confidence_floors(cfg: &SelectionConfig, dets: &mut Vec<Detection>) -> FloorTally {
    let mut tally = FloorTally::default();
    dets.retain_mut(|d| {
        let c = if d.confidence.is_finite() {
            d.confidence
        } else {
            0.0
        };
        d.confidence = c.clamp(0.0, 1.0);
        if c < cfg.min_obstacle_confidence {
            tally.dropped += 1;
            return false;
        }
        if d.kind == ObjectKind::Goal && c < cfg.min_goal_confidence {
            d.kind = ObjectKind::Obstacle;
            tally.goals_demoted += 1;
        }
        true
    });
    tally
}

/// The objects of one frame, in publishing order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Selection {
    /// The goal (if any) first, then obstacles nearest the robot base first. Goals other
    /// than the chosen one appear here as obstacles, or not at all (merged).
    pub objects: Vec<TrackedObject>,
    /// Goal tracks overlapping the chosen goal, left out as the same cube.
    pub goals_merged: u32,
    /// Goal tracks apart from the chosen goal, published as obstacles.
    pub goals_as_obstacles: u32,
}

/// Distance from the robot base (the twin's origin) to the nearest point of the object's
/// box (m); 0 when the box contains the origin.
pub fn distance_to_base_m(o: &TrackedObject) -> f64 {
    (0..3)
        .map(|i| {
            let half = o.size_m[i].abs() / 2.0;
            let gap = o.position_m[i].abs() - half;
            gap.max(0.0).powi(2)
        })
        .sum::<f64>()
        .sqrt()
}

/// Whether two boxes overlap or touch (m).
fn boxes_touch(a: &TrackedObject, b: &TrackedObject) -> bool {
    (0..3).all(|i| {
        (a.position_m[i] - b.position_m[i]).abs() <= (a.size_m[i].abs() + b.size_m[i].abs()) / 2.0
    })
}

/// Chooses the goal and orders the objects (see the module doc).
pub fn select(objects: &[TrackedObject]) -> Selection {
    let goal = objects
        .iter()
        .filter(|o| o.kind == ObjectKind::Goal)
        .max_by(|a, b| {
            let ca = if a.confidence.is_finite() {
                a.confidence
            } else {
                0.0
            };
            let cb = if b.confidence.is_finite() {
                b.confidence
            } else {
                0.0
            };
            ca.total_cmp(&cb).then(b.id.cmp(&a.id))
        })
        .copied();
    let mut out = Selection::default();
    let mut obstacles: Vec<TrackedObject> = Vec::with_capacity(objects.len());
    for o in objects {
        match (o.kind, &goal) {
            (ObjectKind::Obstacle, _) => obstacles.push(*o),
            (ObjectKind::Goal, Some(g)) if g.id == o.id => {}
            (ObjectKind::Goal, Some(g)) if boxes_touch(g, o) => out.goals_merged += 1,
            (ObjectKind::Goal, _) => {
                out.goals_as_obstacles += 1;
                obstacles.push(TrackedObject {
                    kind: ObjectKind::Obstacle,
                    ..*o
                });
            }
        }
    }
    obstacles.sort_by(|a, b| {
        distance_to_base_m(a)
            .total_cmp(&distance_to_base_m(b))
            .then(a.id.cmp(&b.id))
    });
    out.objects.extend(goal);
    out.objects.extend(obstacles);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(id: u32, kind: ObjectKind, confidence: f32, p: [f64; 3]) -> TrackedObject {
        TrackedObject {
            id,
            kind,
            confidence,
            position_m: p,
            size_m: [0.05, 0.05, 0.05],
            velocity_m_s: [0.0; 3],
            velocity_sigma_m_s: 0.0,
        }
    }

    fn det(kind: ObjectKind, confidence: f32) -> Detection {
        Detection {
            kind,
            confidence,
            bbox_px: [0, 0, 1, 1],
            position_m: [0.4, 0.0, 0.025],
            size_m: [0.05; 3],
        }
    }

    #[test]
    fn the_most_confident_goal_comes_first_and_obstacles_nearest_first() {
        let objs = [
            obj(1, ObjectKind::Obstacle, 0.9, [0.60, 0.30, 0.05]),
            obj(2, ObjectKind::Goal, 0.6, [0.45, -0.30, 0.025]),
            obj(3, ObjectKind::Obstacle, 0.9, [0.25, 0.00, 0.05]),
            obj(4, ObjectKind::Goal, 0.9, [0.45, 0.20, 0.025]),
            obj(5, ObjectKind::Obstacle, 0.9, [0.40, -0.10, 0.05]),
            // Overlaps goal 4: the same cube seen twice.
            obj(6, ObjectKind::Goal, 0.7, [0.46, 0.21, 0.025]),
        ];
        let s = select(&objs);
        let ids: Vec<u32> = s.objects.iter().map(|o| o.id).collect();
        // Goal 4 (most confident), then by distance: 3 (0.23 m), 5 (0.39 m), 2 (0.52 m,
        // a second goal apart from the chosen one: an obstacle), 1 (0.64 m).
        assert_eq!(ids, [4, 3, 5, 2, 1]);
        assert_eq!(s.objects[0].kind, ObjectKind::Goal);
        assert!(
            s.objects[1..]
                .iter()
                .all(|o| o.kind == ObjectKind::Obstacle)
        );
        assert_eq!((s.goals_merged, s.goals_as_obstacles), (1, 1));
        // Equal confidence: the oldest track (lowest id) is the goal.
        let tie = [
            obj(8, ObjectKind::Goal, 0.9, [0.3, 0.0, 0.0]),
            obj(7, ObjectKind::Goal, 0.9, [0.5, 0.3, 0.0]),
        ];
        assert_eq!(select(&tie).objects[0].id, 7);
    }

    #[test]
    fn distance_is_to_the_nearest_point_of_the_box() {
        let mut o = obj(1, ObjectKind::Obstacle, 1.0, [0.3, -0.4, 0.0]);
        o.size_m = [0.2, 0.2, 0.1];
        assert!((distance_to_base_m(&o) - (0.2f64.powi(2) + 0.3f64.powi(2)).sqrt()).abs() < 1e-12);
        o.position_m = [0.05, 0.0, 0.0];
        assert_eq!(distance_to_base_m(&o), 0.0);
        // A big box whose centre is far but whose near face is close comes before a small
        // box whose centre is nearer.
        let mut wide = obj(1, ObjectKind::Obstacle, 1.0, [0.5, 0.0, 0.05]);
        wide.size_m = [0.6, 0.1, 0.1];
        let small = obj(2, ObjectKind::Obstacle, 1.0, [0.35, 0.0, 0.05]);
        assert_eq!(select(&[small, wide]).objects[0].id, 1);
    }

    #[test]
    fn low_confidence_goals_become_obstacles_and_only_very_low_ones_are_dropped() {
        let cfg = SelectionConfig {
            min_goal_confidence: 0.6,
            min_obstacle_confidence: 0.1,
        };
        let mut dets = vec![
            det(ObjectKind::Goal, 0.9),
            det(ObjectKind::Goal, 0.3),
            det(ObjectKind::Goal, 0.05),
            det(ObjectKind::Obstacle, 0.3),
            det(ObjectKind::Obstacle, 0.05),
            det(ObjectKind::Obstacle, f32::NAN),
        ];
        let t = apply_confidence_floors(&cfg, &mut dets);
        let kinds: Vec<(ObjectKind, f32)> = dets.iter().map(|d| (d.kind, d.confidence)).collect();
        assert_eq!(
            kinds,
            [
                (ObjectKind::Goal, 0.9),
                (ObjectKind::Obstacle, 0.3),
                (ObjectKind::Obstacle, 0.3)
            ]
        );
        assert_eq!(
            t,
            FloorTally {
                goals_demoted: 1,
                dropped: 3
            }
        );
    }

    #[test]
    fn floors_are_validated_with_the_field_named() {
        SelectionConfig::default().validate().unwrap();
        let bad_goal = SelectionConfig {
            min_goal_confidence: 1.5,
            ..Default::default()
        };
        let e = bad_goal.validate().unwrap_err();
        assert!(e.to_string().contains("min_goal_confidence"), "{e}");
        let nan_goal = SelectionConfig {
            min_goal_confidence: f32::NAN,
            ..Default::default()
        };
        assert!(matches!(
            nan_goal.validate(),
            Err(SelectionConfigError::GoalFloor { .. })
        ));
        for o in [-0.1, 0.3, f32::NAN] {
            let e = SelectionConfig {
                min_obstacle_confidence: o,
                ..Default::default()
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("min_obstacle_confidence"), "{e}");
        }
        // The obstacle floor may not exceed the goal floor.
        let e = SelectionConfig {
            min_goal_confidence: 0.1,
            min_obstacle_confidence: 0.2,
        }
        .validate()
        .unwrap_err();
        assert_eq!(
            e,
            SelectionConfigError::ObstacleFloor {
                value: 0.2,
                max: 0.1
            }
        );
    }

    #[test]
    fn config_files_load_with_defaults_and_errors_name_the_field() {
        let dir = std::env::temp_dir().join(format!("foresight-selection-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("sel.toml");
        std::fs::write(&p, "min_goal_confidence = 0.7\n").unwrap();
        let c = SelectionConfig::load(&p).unwrap();
        assert_eq!(c.min_goal_confidence, 0.7);
        assert_eq!(
            c.min_obstacle_confidence,
            SelectionConfig::default().min_obstacle_confidence
        );
        std::fs::write(&p, "min_obstacle_confidence = 0.9\n").unwrap();
        let e = SelectionConfig::load(&p).unwrap_err().to_string();
        assert!(
            e.contains("min_obstacle_confidence") && e.contains("sel.toml"),
            "{e}"
        );
        std::fs::write(&p, "min_goal_confidense = 0.7\n").unwrap();
        let e = SelectionConfig::load(&p).unwrap_err().to_string();
        assert!(
            e.contains("min_goal_confidense") && e.contains("sel.toml"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
