//! The scene as markers (`visualization_msgs/MarkerArray`): the goal and obstacle boxes of
//! the latest detection frame, the TCP path the arm has been commanded along since the
//! last approved plan, and the last verdict as text above the goal.

use shm_schemas::{DetectionFrame, ObjectClass, TwinVerdict};

use crate::msgs::{Color, Header, Marker, MarkerArray, Vec3};

/// Points kept of the commanded path (2 mm apart at least).
pub const MAX_PATH_POINTS: usize = 4000;
/// Least distance between two kept path points (m).
pub const PATH_STEP_M: f64 = 0.002;

/// The commanded TCP path of the plan in force.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlanPath {
    /// Points (m).
    pub points_m: Vec<[f64; 3]>,
    /// Policy of the approved verdict that started the path.
    pub policy_id: u64,
}

impl PlanPath {
    /// Starts a new path (a new plan was approved).
    pub fn restart(&mut self, policy_id: u64) {
        self.points_m.clear();
        self.policy_id = policy_id;
    }

    /// Adds a point if it is [`PATH_STEP_M`] from the last one and there is room; true
    /// when added.
    pub fn push(&mut self, p: [f64; 3]) -> bool {
        let far = self.points_m.last().is_none_or(|q| {
            let d2: f64 = (0..3).map(|i| (p[i] - q[i]).powi(2)).sum();
            d2 >= PATH_STEP_M * PATH_STEP_M
        });
        if far && self.points_m.len() < MAX_PATH_POINTS {
            self.points_m.push(p);
            true
        } else {
            false
        }
    }
}

const GOAL: Color = Color {
    r: 0.1,
    g: 0.8,
    b: 0.2,
    a: 0.8,
};
const OBSTACLE: Color = Color {
    r: 0.85,
    g: 0.15,
    b: 0.1,
    a: 0.7,
};
const PATH: Color = Color {
    r: 0.2,
    g: 0.4,
    b: 1.0,
    a: 1.0,
};

/// The marker array of the scene: a DELETEALL first, so each message replaces the last.
pub fn scene_markers(
    header: &Header,
    detections: Option<&DetectionFrame>,
    path: &PlanPath,
    verdict: Option<&TwinVerdict>,
) -> MarkerArray {
    let marker = |ns: &str, id: i32, kind: i32| Marker {
        header: header.clone(),
        ns: ns.to_owned(),
        id,
        kind,
        action: Marker::ADD,
        ..Marker::default()
    };
    let mut markers = vec![Marker {
        action: Marker::DELETE_ALL,
        ..marker("foresight", 0, 0)
    }];
    let mut text_at = Vec3 {
        x: 0.4,
        y: 0.0,
        z: 0.4,
    };
    if let Some(frame) = detections {
        for (i, o) in frame.objects().iter().enumerate() {
            let (ns, color) = match o.class() {
                Ok(ObjectClass::Goal) => {
                    text_at = Vec3 {
                        x: f64::from(o.center_m[0]),
                        y: f64::from(o.center_m[1]),
                        z: f64::from(o.center_m[2] + o.size_m[2] / 2.0) + 0.12,
                    };
                    ("goal", GOAL)
                }
                Ok(ObjectClass::Obstacle) => ("obstacles", OBSTACLE),
                Err(_) => continue,
            };
            markers.push(Marker {
                position: Vec3::from_array(o.center_m.map(f64::from)),
                scale: Vec3::from_array(o.size_m.map(f64::from)),
                color,
                ..marker(ns, i as i32, Marker::CUBE)
            });
        }
    }
    if path.points_m.len() >= 2 {
        markers.push(Marker {
            scale: Vec3 {
                x: 0.006,
                ..Vec3::default()
            },
            color: PATH,
            points: path
                .points_m
                .iter()
                .copied()
                .map(Vec3::from_array)
                .collect(),
            ..marker("plan_path", 0, Marker::LINE_STRIP)
        });
    }
    if let Some(v) = verdict {
        let approved = v.is_plan_approved();
        markers.push(Marker {
            position: text_at,
            scale: Vec3 {
                z: 0.03,
                ..Vec3::default()
            },
            color: if approved { GOAL } else { OBSTACLE },
            text: format!(
                "verdict {} (policy {}): {}, {}, min distance {:.1} mm{}",
                v.verdict_id,
                v.policy_id,
                if v.is_task_ok() {
                    "reaches the goal"
                } else {
                    "misses the goal"
                },
                if v.is_safe() { "safe" } else { "CONTACT" },
                v.min_distance_m * 1e3,
                if approved { ", approved" } else { "" }
            ),
            ..marker("verdict", 0, Marker::TEXT_VIEW_FACING)
        });
    }
    MarkerArray { markers }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::DetectedObject;

    #[test]
    fn the_markers_show_boxes_path_and_verdict() {
        let mut frame = DetectionFrame::default();
        frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.9,
            [0.4, 0.1, 0.05],
            [0.05; 3],
        ));
        frame.push(DetectedObject::new(
            2,
            ObjectClass::Obstacle,
            0.9,
            [0.3, 0.0, 0.1],
            [0.1, 0.1, 0.2],
        ));
        let mut path = PlanPath::default();
        path.restart(7);
        assert!(path.push([0.2, 0.0, 0.3]));
        assert!(!path.push([0.2005, 0.0, 0.3]), "closer than 2 mm");
        assert!(path.push([0.25, 0.0, 0.3]));
        let mut v = TwinVerdict {
            policy_id: 7,
            ..TwinVerdict::default()
        };
        v.set_flags(true, true, true);
        let m = scene_markers(&Header::default(), Some(&frame), &path, Some(&v));
        let ns: Vec<&str> = m.markers.iter().map(|m| m.ns.as_str()).collect();
        assert_eq!(
            ns,
            ["foresight", "goal", "obstacles", "plan_path", "verdict"]
        );
        assert_eq!(m.markers[0].action, Marker::DELETE_ALL);
        assert_eq!(m.markers[3].points.len(), 2);
        assert!(
            m.markers[4].text.contains("approved"),
            "{}",
            m.markers[4].text
        );
    }
}
