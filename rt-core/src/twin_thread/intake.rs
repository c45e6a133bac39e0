//! Scene intake: a validated [`DetectionFrame`] becomes the twin's [`Scene`], and its
//! capture stamp an age on the machine's monotonic clock.

use shm_schemas::{DetectionFrame, ObjectClass};
use twin::{BoxObstacle, Goal, Scene};

/// Grid every detected position and size is snapped to, m: sensor noise below it does not
/// count as a scene change (a change re-runs the lookahead).
pub const SNAP_GRID_M: f64 = 0.005;

/// The twin scene of a detection frame: goal and obstacles, positions snapped to
/// [`SNAP_GRID_M`]. Without a goal in the frame, `last_goal` (the last one seen) stays.
pub fn scene_from_detection(
    frame: &DetectionFrame,
    table_height_m: f64,
    last_goal: &mut Goal,
) -> Scene {
    let snap = |v: f32| (f64::from(v) / SNAP_GRID_M).round() * SNAP_GRID_M;
    let mut scene = Scene::empty(table_height_m, *last_goal);
    for o in frame.objects() {
        let center_m = [
            snap(o.center_m[0]),
            snap(o.center_m[1]),
            snap(o.center_m[2]),
        ];
        let size_m = [snap(o.size_m[0]), snap(o.size_m[1]), snap(o.size_m[2])];
        match o.class() {
            Ok(ObjectClass::Goal) => {
                *last_goal = Goal {
                    center_m,
                    size_m: size_m[0].max(SNAP_GRID_M),
                };
                scene.goal = *last_goal;
            }
            Ok(ObjectClass::Obstacle) => {
                // Snap the top and the bottom (not the centre and the height): a box
                // standing on the table must not reach below it after rounding, or the
                // learner would refuse the scene of a retrain request.
                let top = snap(o.center_m[2] + o.size_m[2] / 2.0);
                let bottom = snap(o.center_m[2] - o.size_m[2] / 2.0).max(table_height_m);
                let height = (top - bottom).max(SNAP_GRID_M);
                let _ = scene.obstacles.push(BoxObstacle {
                    center_m: [center_m[0], center_m[1], bottom + height / 2.0],
                    size_m: [
                        size_m[0].max(SNAP_GRID_M),
                        size_m[1].max(SNAP_GRID_M),
                        height,
                    ],
                });
            }
            Err(_) => {}
        }
    }
    scene
}

/// Age of a frame captured at `capture_ns` (CLOCK_MONOTONIC of this machine) at `now_ns`;
/// an absent (0) or future stamp counts as age 0 (receipt time).
pub fn detection_age_ns(capture_ns: u64, now_ns: u64) -> u64 {
    if capture_ns == 0 || capture_ns > now_ns {
        0
    } else {
        now_ns - capture_ns
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use shm_schemas::DetectedObject;
    use shm_schemas::scene_file::SceneFile;

    /// A tall box on the table whose centre and height both round up (0.1614 → 0.160 and
    /// 0.3227 → 0.325 on the 5 mm grid) once made a box reaching 2.5 mm below the table:
    /// a scene the learner refused, leaving the arm waiting for a policy that never came.
    #[test]
    fn a_detected_box_on_the_table_stays_on_it_after_snapping() {
        let mut frame = DetectionFrame::default();
        assert!(frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.9,
            [0.28, -0.32, 0.025],
            [0.05, 0.05, 0.05]
        )));
        assert!(frame.push(DetectedObject::new(
            2,
            ObjectClass::Obstacle,
            0.9,
            [0.2887, -0.1333, 0.16136],
            [0.053, 0.0518, 0.32272]
        )));
        let mut goal = Goal {
            center_m: [0.3, 0.0, 0.025],
            size_m: 0.05,
        };
        let scene = scene_from_detection(&frame, 0.0, &mut goal);
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
            }],
        };
        file.validate().unwrap();
    }
}
