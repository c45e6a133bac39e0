//! The scene as markers (`visualization_msgs/MarkerArray`): the goal and obstacle boxes of
//! the latest detection frame, the TCP path the arm has been commanded along since the
//! last approved plan, and the last verdict as text above the goal — the shared view of
//! [`crate::ros_view`] in the recorder's messages.

use shm_schemas::{DetectionFrame, TwinVerdict};

use crate::msgs::{Color, Header, Marker, MarkerArray, Vec3};
use crate::ros_view::scene_view;

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

/// The marker array of the scene ([`crate::ros_view::scene_view`], the picture `ros-bridge`
/// publishes too, with the commanded path as the `plan_path` line), in the recorder's
/// messages: a DELETEALL first, so each message replaces the last.
pub fn scene_markers(
    header: &Header,
    detections: Option<&DetectionFrame>,
    path: &PlanPath,
    verdict: Option<&TwinVerdict>,
) -> MarkerArray {
    let view = scene_view(
        detections,
        "plan_path",
        path.points_m.iter().copied(),
        verdict,
    );
    MarkerArray {
        markers: view
            .into_iter()
            .map(|m| Marker {
                header: header.clone(),
                ns: m.ns.to_owned(),
                id: m.id,
                kind: m.shape.ros_type(),
                action: m.action.ros_action(),
                position: Vec3::from_array(m.position_m),
                scale: Vec3::from_array(m.scale_m),
                color: Color {
                    r: m.rgba[0],
                    g: m.rgba[1],
                    b: m.rgba[2],
                    a: m.rgba[3],
                },
                points: m.points_m.into_iter().map(Vec3::from_array).collect(),
                text: m.text,
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::{DetectedObject, ObjectClass};

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
