//! One ROS view of the scene and of the arm, shared by the recorder (its MCAP messages,
//! [`crate::markers`]) and `ros-bridge` (its DDS messages): the markers that show the scene —
//! goal and obstacle boxes, a TCP line, the verdict as text above the goal — with their
//! namespaces, shapes, colours and texts, and the transforms of the arm's links. A recording
//! and a live rviz thus show the same picture; each side only converts these values into its
//! own message types (CDR-encoded here, `ros2-client`'s serde types in the bridge).
//!
//! ```
//! use recorder::ros_view::{MarkerAction, Shape, scene_view};
//!
//! let view = scene_view(None, "plan_path", [[0.2, 0.0, 0.3], [0.25, 0.0, 0.3]], None);
//! assert_eq!(view[0].action, MarkerAction::DeleteAll);
//! assert_eq!(view[1].shape, Shape::LineStrip);
//! ```

use nalgebra::Isometry3;
use shm_schemas::{DetectionFrame, ObjectClass, TwinVerdict};
use twin::{LinkPoses, RobotModel};

/// The namespace of the first marker of every array, a DELETEALL, so that each array
/// replaces the last.
pub const CLEAR_NS: &str = "foresight";
/// Colour of the goal box (and of an approved verdict's text), RGBA 0–1.
pub const GOAL_RGBA: [f32; 4] = [0.1, 0.8, 0.2, 0.9];
/// Colour of an obstacle box.
pub const OBSTACLE_RGBA: [f32; 4] = [0.85, 0.15, 0.1, 0.8];
/// Colour of the TCP line.
pub const LINE_RGBA: [f32; 4] = [0.2, 0.4, 1.0, 1.0];
/// Colour of a verdict's text: approved, refused.
pub const VERDICT_RGBA: [[f32; 4]; 2] = [[0.1, 0.8, 0.2, 1.0], [0.9, 0.2, 0.1, 1.0]];
/// Width of the TCP line, m.
pub const LINE_WIDTH_M: f64 = 0.005;
/// Height of the verdict's text, m.
pub const TEXT_HEIGHT_M: f64 = 0.03;
/// The verdict's text stands this far above the goal box's top, m.
pub const TEXT_ABOVE_GOAL_M: f64 = 0.1;
/// Where the verdict's text stands when no goal is seen, m.
pub const TEXT_WITHOUT_GOAL_M: [f64; 3] = [0.4, 0.0, 0.3];

/// A marker's shape (`visualization_msgs/Marker` `type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// `CUBE`: a box, `scale_m` its full extents.
    Cube,
    /// `LINE_STRIP`: `points_m`, `scale_m[0]` the line's width.
    LineStrip,
    /// `TEXT_VIEW_FACING`: `text`, `scale_m[2]` its height.
    Text,
}

impl Shape {
    /// The message's `type` value.
    pub const fn ros_type(self) -> i32 {
        match self {
            Self::Cube => 1,
            Self::LineStrip => 4,
            Self::Text => 9,
        }
    }
}

/// A marker's `action`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkerAction {
    /// `ADD`.
    Add,
    /// `DELETEALL`.
    DeleteAll,
}

impl MarkerAction {
    /// The message's `action` value.
    pub const fn ros_action(self) -> i32 {
        match self {
            Self::Add => 0,
            Self::DeleteAll => 3,
        }
    }
}

/// One marker of the scene, in the fixed frame (orientation identity).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerView {
    /// Namespace.
    pub ns: &'static str,
    /// Id within the namespace.
    pub id: i32,
    /// Add or delete all.
    pub action: MarkerAction,
    /// Shape.
    pub shape: Shape,
    /// Position, m.
    pub position_m: [f64; 3],
    /// Extents (boxes), line width in `[0]`, text height in `[2]`, m.
    pub scale_m: [f64; 3],
    /// Colour, RGBA 0–1.
    pub rgba: [f32; 4],
    /// Points of a line, m.
    pub points_m: Vec<[f64; 3]>,
    /// Text of a text marker.
    pub text: String,
}

impl MarkerView {
    fn add(ns: &'static str, id: i32, shape: Shape) -> Self {
        Self {
            ns,
            id,
            action: MarkerAction::Add,
            shape,
            position_m: [0.0; 3],
            scale_m: [0.0; 3],
            rgba: [0.0; 4],
            points_m: Vec::new(),
            text: String::new(),
        }
    }
}

/// A verdict in words: the policy, whether it reaches the goal, whether safely, its smallest
/// clearance and length.
pub fn verdict_text(v: &TwinVerdict) -> String {
    format!(
        "policy {}: {} {} (min {:.3} m, {} steps)",
        v.policy_id,
        if v.is_task_ok() {
            "reaches goal"
        } else {
            "misses goal"
        },
        if v.is_safe() {
            "safely"
        } else {
            "WITH CONTACT"
        },
        v.min_distance_m,
        v.steps
    )
}

/// [`verdict_text`] and whether its plan was approved (the scene's text marker, the `Reach`
/// action's feedback).
pub fn verdict_line(v: &TwinVerdict) -> String {
    let approved = if v.is_plan_approved() {
        ", approved"
    } else {
        ""
    };
    format!("{}{approved}", verdict_text(v))
}

/// The scene's markers: a DELETEALL ([`CLEAR_NS`]), the goal (`goal`) and obstacle
/// (`obstacles`) boxes of the latest detections, the TCP line `line_ns` through `line_m`
/// (when it has two points or more), and the verdict as text above the goal (`verdict`).
pub fn scene_view(
    detections: Option<&DetectionFrame>,
    line_ns: &'static str,
    line_m: impl IntoIterator<Item = [f64; 3]>,
    verdict: Option<&TwinVerdict>,
) -> Vec<MarkerView> {
    let mut markers = vec![MarkerView {
        action: MarkerAction::DeleteAll,
        ..MarkerView::add(CLEAR_NS, 0, Shape::Cube)
    }];
    let mut text_at_m = TEXT_WITHOUT_GOAL_M;
    if let Some(frame) = detections {
        for (i, o) in frame.objects().iter().enumerate() {
            let (ns, rgba) = match o.class() {
                Ok(ObjectClass::Goal) => {
                    text_at_m = [
                        f64::from(o.center_m[0]),
                        f64::from(o.center_m[1]),
                        f64::from(o.center_m[2] + o.size_m[2] / 2.0) + TEXT_ABOVE_GOAL_M,
                    ];
                    ("goal", GOAL_RGBA)
                }
                Ok(ObjectClass::Obstacle) => ("obstacles", OBSTACLE_RGBA),
                Err(_) => continue,
            };
            markers.push(MarkerView {
                position_m: o.center_m.map(f64::from),
                scale_m: o.size_m.map(f64::from),
                rgba,
                ..MarkerView::add(ns, i as i32, Shape::Cube)
            });
        }
    }
    let points_m: Vec<[f64; 3]> = line_m.into_iter().collect();
    if points_m.len() >= 2 {
        markers.push(MarkerView {
            scale_m: [LINE_WIDTH_M, 0.0, 0.0],
            rgba: LINE_RGBA,
            points_m,
            ..MarkerView::add(line_ns, 0, Shape::LineStrip)
        });
    }
    if let Some(v) = verdict {
        markers.push(MarkerView {
            position_m: text_at_m,
            scale_m: [0.0, 0.0, TEXT_HEIGHT_M],
            rgba: VERDICT_RGBA[usize::from(!v.is_plan_approved())],
            text: verdict_line(v),
            ..MarkerView::add("verdict", 0, Shape::Text)
        });
    }
    markers
}

/// One link's transform in the fixed frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransformView<'a> {
    /// The link's frame (`link1`, …, `link_tcp`).
    pub child_frame_id: &'a str,
    /// Translation, m.
    pub translation_m: [f64; 3],
    /// Rotation as a unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

fn transform<'a>(child_frame_id: &'a str, iso: &Isometry3<f64>) -> TransformView<'a> {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    TransformView {
        child_frame_id,
        translation_m: [t.x, t.y, t.z],
        rotation_xyzw: [q.i, q.j, q.k, q.w],
    }
}

/// Every link frame of the twin's FK, then the TCP (`link_tcp`), as children of
/// `parent_frame`; a link named as the parent itself (`link_base` under `link_base`) is left
/// out, since a frame cannot be its own child.
pub fn link_transforms<'a>(
    model: &'a RobotModel,
    poses: &LinkPoses,
    parent_frame: &str,
) -> Vec<TransformView<'a>> {
    let mut out: Vec<TransformView<'a>> = poses
        .links
        .iter()
        .enumerate()
        .map(|(i, iso)| transform(model.link_name(i), iso))
        .filter(|t| t.child_frame_id != parent_frame)
        .collect();
    out.push(transform("link_tcp", &poses.tcp));
    out
}
