//! The ROS 2 messages a recording holds: each type's name, its full `ros2msg` definition
//! (its own fields, then every type it uses after a separator line, as `ros2 bag` stores
//! them in MCAP schemas) and its CDR encoding ([`crate::cdr`]).
//!
//! The standard types follow ROS 2 Jazzy's `common_interfaces` (the layouts `ros-bridge`
//! publishes); Foresight's own (`foresight_msgs/msg/*`) are the `.msg` files under
//! `rt-core/recorder/msg/`, so a ROS 2 workspace can build them as a package to replay
//! those topics with `ros2 bag play` (Foxglove reads them from the schemas alone).

use crate::cdr::CdrWriter;

/// A ROS 2 message the recorder can write.
pub trait RosMessage {
    /// Type name as `ros2 bag` writes it (`sensor_msgs/msg/JointState`).
    const TYPE_NAME: &'static str;
    /// The full definition text (schema encoding `ros2msg`).
    fn definition() -> String;
    /// Appends the message's fields to `w` (after its encapsulation header).
    fn encode(&self, w: &mut CdrWriter);
}

const SEPARATOR: &str =
    "================================================================================";

/// `own`, then each dependency as `MSG: pkg/Type` and its fields, separated as `ros2 bag`
/// separates them.
fn full_definition(own: &str, deps: &[(&str, &str)]) -> String {
    let mut text = own.trim_end().to_owned();
    for (name, def) in deps {
        text.push('\n');
        text.push_str(SEPARATOR);
        text.push_str("\nMSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(def.trim_end());
    }
    text.push('\n');
    text
}

const TIME_DEF: &str = "int32 sec\nuint32 nanosec";
const DURATION_DEF: &str = "int32 sec\nuint32 nanosec";
const HEADER_DEF: &str = "builtin_interfaces/Time stamp\nstring frame_id";
const VECTOR3_DEF: &str = "float64 x\nfloat64 y\nfloat64 z";
const POINT_DEF: &str = "float64 x\nfloat64 y\nfloat64 z";
const QUATERNION_DEF: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1";
const POSE_DEF: &str = "Point position\nQuaternion orientation";
const TRANSFORM_DEF: &str = "Vector3 translation\nQuaternion rotation";
const TRANSFORM_STAMPED_DEF: &str =
    "std_msgs/Header header\nstring child_frame_id\nTransform transform";
const COLOR_DEF: &str = "float32 r\nfloat32 g\nfloat32 b\nfloat32 a";
const COMPRESSED_IMAGE_DEF: &str = "std_msgs/Header header\nstring format\nuint8[] data";
const UV_DEF: &str = "float32 u\nfloat32 v";
const MESH_FILE_DEF: &str = "string filename\nuint8[] data";
const MARKER_DEF: &str = "\
int32 ARROW=0
int32 CUBE=1
int32 SPHERE=2
int32 CYLINDER=3
int32 LINE_STRIP=4
int32 LINE_LIST=5
int32 CUBE_LIST=6
int32 SPHERE_LIST=7
int32 POINTS=8
int32 TEXT_VIEW_FACING=9
int32 MESH_RESOURCE=10
int32 TRIANGLE_LIST=11
int32 ARROW_STRIP=12
int32 ADD=0
int32 MODIFY=0
int32 DELETE=2
int32 DELETEALL=3
std_msgs/Header header
string ns
int32 id
int32 type
int32 action
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
std_msgs/ColorRGBA color
builtin_interfaces/Duration lifetime
bool frame_locked
geometry_msgs/Point[] points
std_msgs/ColorRGBA[] colors
string texture_resource
sensor_msgs/CompressedImage texture
UVCoordinate[] uv_coordinates
string text
string mesh_resource
MeshFile mesh_file
bool mesh_use_embedded_materials";

const HEADER_DEPS: [(&str, &str); 2] = [
    ("std_msgs/Header", HEADER_DEF),
    ("builtin_interfaces/Time", TIME_DEF),
];

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// A stamp from nanoseconds since the Unix epoch.
    pub fn from_unix_ns(ns: u64) -> Self {
        Self {
            sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }

    fn encode(&self, w: &mut CdrWriter) {
        w.i32(self.sec);
        w.u32(self.nanosec);
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    /// Stamp.
    pub stamp: Time,
    /// Coordinate frame.
    pub frame_id: String,
}

impl Header {
    fn encode(&self, w: &mut CdrWriter) {
        self.stamp.encode(w);
        w.string(&self.frame_id);
    }
}

/// `sensor_msgs/msg/JointState`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Angles (rad).
    pub position: Vec<f64>,
    /// Velocities (rad/s).
    pub velocity: Vec<f64>,
    /// Efforts (empty here).
    pub effort: Vec<f64>,
}

impl RosMessage for JointState {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/JointState";
    fn definition() -> String {
        full_definition(
            "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort",
            &HEADER_DEPS,
        )
    }
    fn encode(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string_sequence(&self.name);
        w.f64_sequence(&self.position);
        w.f64_sequence(&self.velocity);
        w.f64_sequence(&self.effort);
    }
}

/// `geometry_msgs/Vector3` and `geometry_msgs/Point` (the same layout).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Vec3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

impl Vec3 {
    /// From an array.
    pub fn from_array(v: [f64; 3]) -> Self {
        Self {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }

    fn encode(&self, w: &mut CdrWriter) {
        w.f64(self.x);
        w.f64(self.y);
        w.f64(self.z);
    }
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

impl Quaternion {
    fn encode(&self, w: &mut CdrWriter) {
        w.f64(self.x);
        w.f64(self.y);
        w.f64(self.z);
        w.f64(self.w);
    }
}

/// `geometry_msgs/TransformStamped` (its `Transform` inlined).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Translation (m).
    pub translation: Vec3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

impl RosMessage for TfMessage {
    const TYPE_NAME: &'static str = "tf2_msgs/msg/TFMessage";
    fn definition() -> String {
        full_definition(
            "geometry_msgs/TransformStamped[] transforms",
            &[
                ("geometry_msgs/TransformStamped", TRANSFORM_STAMPED_DEF),
                HEADER_DEPS[0],
                HEADER_DEPS[1],
                ("geometry_msgs/Transform", TRANSFORM_DEF),
                ("geometry_msgs/Vector3", VECTOR3_DEF),
                ("geometry_msgs/Quaternion", QUATERNION_DEF),
            ],
        )
    }
    fn encode(&self, w: &mut CdrWriter) {
        w.sequence_len(self.transforms.len());
        for t in &self.transforms {
            t.header.encode(w);
            w.string(&t.child_frame_id);
            t.translation.encode(w);
            t.rotation.encode(w);
        }
    }
}

/// `std_msgs/msg/String`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}

impl RosMessage for StringMsg {
    const TYPE_NAME: &'static str = "std_msgs/msg/String";
    fn definition() -> String {
        full_definition("string data", &[])
    }
    fn encode(&self, w: &mut CdrWriter) {
        w.string(&self.data);
    }
}

/// `std_msgs/ColorRGBA`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Color {
    /// Red, 0–1.
    pub r: f32,
    /// Green, 0–1.
    pub g: f32,
    /// Blue, 0–1.
    pub b: f32,
    /// Opacity, 0–1.
    pub a: f32,
}

/// `visualization_msgs/Marker` (the fields the recorder uses; texture and mesh empty).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// Shape ([`Marker::CUBE`], [`Marker::LINE_STRIP`], …).
    pub kind: i32,
    /// [`Marker::ADD`] or [`Marker::DELETE_ALL`].
    pub action: i32,
    /// Position of the shape (m); orientation identity.
    pub position: Vec3,
    /// Full extents (m) for boxes; line width in `x` for lines; text height in `z`.
    pub scale: Vec3,
    /// Colour.
    pub color: Color,
    /// Points of line markers (m).
    pub points: Vec<Vec3>,
    /// Text of text markers.
    pub text: String,
}

impl Marker {
    /// `CUBE`.
    pub const CUBE: i32 = 1;
    /// `LINE_STRIP`.
    pub const LINE_STRIP: i32 = 4;
    /// `TEXT_VIEW_FACING`.
    pub const TEXT_VIEW_FACING: i32 = 9;
    /// `ADD`.
    pub const ADD: i32 = 0;
    /// `DELETEALL`.
    pub const DELETE_ALL: i32 = 3;

    fn encode(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(&self.ns);
        w.i32(self.id);
        w.i32(self.kind);
        w.i32(self.action);
        self.position.encode(w);
        Quaternion::default().encode(w);
        self.scale.encode(w);
        w.f32_array(&[self.color.r, self.color.g, self.color.b, self.color.a]);
        Time::default().encode(w); // lifetime: forever
        w.bool(false); // frame_locked
        w.sequence_len(self.points.len());
        for p in &self.points {
            p.encode(w);
        }
        w.sequence_len(0); // colors
        w.string(""); // texture_resource
        Header::default().encode(w); // texture.header
        w.string(""); // texture.format
        w.sequence_len(0); // texture.data
        w.sequence_len(0); // uv_coordinates
        w.string(&self.text);
        w.string(""); // mesh_resource
        w.string(""); // mesh_file.filename
        w.sequence_len(0); // mesh_file.data
        w.bool(false); // mesh_use_embedded_materials
    }
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}

impl RosMessage for MarkerArray {
    const TYPE_NAME: &'static str = "visualization_msgs/msg/MarkerArray";
    fn definition() -> String {
        full_definition(
            "Marker[] markers",
            &[
                ("visualization_msgs/Marker", MARKER_DEF),
                HEADER_DEPS[0],
                HEADER_DEPS[1],
                ("geometry_msgs/Pose", POSE_DEF),
                ("geometry_msgs/Point", POINT_DEF),
                ("geometry_msgs/Quaternion", QUATERNION_DEF),
                ("geometry_msgs/Vector3", VECTOR3_DEF),
                ("std_msgs/ColorRGBA", COLOR_DEF),
                ("builtin_interfaces/Duration", DURATION_DEF),
                ("sensor_msgs/CompressedImage", COMPRESSED_IMAGE_DEF),
                ("visualization_msgs/UVCoordinate", UV_DEF),
                ("visualization_msgs/MeshFile", MESH_FILE_DEF),
            ],
        )
    }
    fn encode(&self, w: &mut CdrWriter) {
        w.sequence_len(self.markers.len());
        for m in &self.markers {
            m.encode(w);
        }
    }
}

/// `foresight_msgs/msg/TwinVerdict` (`msg/TwinVerdict.msg`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TwinVerdictMsg {
    /// Receive stamp.
    pub header: Header,
    /// The verdict as published.
    pub verdict: shm_schemas::TwinVerdict,
}

impl RosMessage for TwinVerdictMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/TwinVerdict";
    fn definition() -> String {
        full_definition(include_str!("../msg/TwinVerdict.msg"), &HEADER_DEPS)
    }
    fn encode(&self, w: &mut CdrWriter) {
        let v = &self.verdict;
        self.header.encode(w);
        w.u64(v.verdict_id);
        w.u64(v.scene_sequence);
        w.u64(v.policy_id);
        w.f64(v.min_distance_m);
        w.f64(v.episode_return);
        w.u32(v.steps);
        w.u32(v.lookahead_compute_us);
        w.bool(v.is_task_ok());
        w.bool(v.is_safe());
        w.bool(v.is_plan_approved());
        w.u8(v.episode_end);
        w.string(
            &v.episode_end()
                .map_or_else(|_| "unknown".to_owned(), |e| format!("{e:?}")),
        );
        w.u8(v.phase);
        w.string(v.phase().map_or("invalid", |p| p.name()));
        w.u8(v.executor);
        w.string(v.executor().map_or("invalid", |e| e.name()));
    }
}

/// `foresight_msgs/msg/RetrainProgress` (`msg/RetrainProgress.msg`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RetrainProgressMsg {
    /// Receive stamp.
    pub header: Header,
    /// The progress as published.
    pub progress: shm_schemas::RetrainProgress,
}

impl RosMessage for RetrainProgressMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/RetrainProgress";
    fn definition() -> String {
        full_definition(include_str!("../msg/RetrainProgress.msg"), &HEADER_DEPS)
    }
    fn encode(&self, w: &mut CdrWriter) {
        let p = &self.progress;
        self.header.encode(w);
        w.u64(p.request_id);
        w.u64(p.steps_done);
        w.u64(p.published_policy_id);
        w.f64(p.mean_return);
        w.f64(p.success_rate);
        w.f64(p.wall_time_s);
        w.u8(p.phase);
        w.string(
            &p.phase()
                .map_or_else(|_| "unknown".to_owned(), |e| format!("{e:?}")),
        );
    }
}

/// `foresight_msgs/msg/RetrainRequest` (`msg/RetrainRequest.msg`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RetrainRequestMsg {
    /// Receive stamp.
    pub header: Header,
    /// The request as published.
    pub request: shm_schemas::RetrainRequest,
}

impl RosMessage for RetrainRequestMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/RetrainRequest";
    fn definition() -> String {
        full_definition(include_str!("../msg/RetrainRequest.msg"), &HEADER_DEPS)
    }
    fn encode(&self, w: &mut CdrWriter) {
        let r = &self.request;
        self.header.encode(w);
        w.u64(r.request_id);
        w.u64(r.failed_policy_id);
        w.u64(r.scene_sequence);
        w.f64_array(&r.goal_center_m);
        w.u32(r.obstacle_count);
    }
}

/// `foresight_msgs/msg/Detections` (`msg/Detections.msg`, `msg/DetectedObject.msg`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DetectionsMsg {
    /// Receive stamp.
    pub header: Header,
    /// The frame as published.
    pub frame: shm_schemas::DetectionFrame,
}

impl RosMessage for DetectionsMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/Detections";
    fn definition() -> String {
        full_definition(
            include_str!("../msg/Detections.msg"),
            &[
                HEADER_DEPS[0],
                HEADER_DEPS[1],
                (
                    "foresight_msgs/DetectedObject",
                    include_str!("../msg/DetectedObject.msg"),
                ),
            ],
        )
    }
    fn encode(&self, w: &mut CdrWriter) {
        let f = &self.frame;
        self.header.encode(w);
        w.u64(f.sequence);
        w.u64(f.capture_time_ns);
        w.bool(f.settled());
        w.u32(f.dropped_count);
        w.sequence_len(f.objects().len());
        for o in f.objects() {
            w.u32(o.object_id);
            w.string(match o.class() {
                Ok(shm_schemas::ObjectClass::Goal) => "goal",
                Ok(shm_schemas::ObjectClass::Obstacle) => "obstacle",
                Err(_) => "unknown",
            });
            w.f32(o.confidence);
            w.f32_array(&o.center_m);
            w.f32_array(&o.size_m);
        }
    }
}

/// `foresight_msgs/msg/RobotStatus` (`msg/RobotStatus.msg`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RobotStatusMsg {
    /// Receive stamp.
    pub header: Header,
    /// The state as published.
    pub state: shm_schemas::RobotState,
}

impl RosMessage for RobotStatusMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/RobotStatus";
    fn definition() -> String {
        full_definition(include_str!("../msg/RobotStatus.msg"), &HEADER_DEPS)
    }
    fn encode(&self, w: &mut CdrWriter) {
        let s = &self.state;
        self.header.encode(w);
        w.u64(s.cycle_count);
        w.u64(s.missed_deadlines);
        w.u64(s.active_policy_id);
        w.f64_array(&s.tcp_m);
        w.f32(s.last_compute_us);
        w.u8(s.arm_mode);
        w.u8(s.arm_state);
        w.u8(s.arm_error_code);
        w.u8(s.arm_warning_code);
        w.bool(s.controlled_stop != 0);
        w.u8(s.stop_reason);
        w.string(
            &s.stop_reason()
                .map_or_else(|_| "unknown".to_owned(), |e| format!("{e:?}")),
        );
        w.bool(s.link_ok != 0);
    }
}

/// The simulated arm's referee figures (`foresight_msgs/msg/RefereeClearance`), as the
/// launcher reads them from `xarm-sim`'s status.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RefereeClearance {
    /// Contacts called so far.
    pub contacts: u64,
    /// Motion steps judged so far.
    pub steps: u64,
    /// Smallest clearance so far (m); `None` before the first step.
    pub min_clearance_m: Option<f64>,
    /// Link of that clearance.
    pub min_link: String,
    /// What it was nearest to.
    pub min_other: String,
    /// Scene in force then.
    pub min_scene: String,
}

/// [`RefereeClearance`] with its stamp.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RefereeClearanceMsg {
    /// Receive stamp.
    pub header: Header,
    /// The figures.
    pub clearance: RefereeClearance,
}

impl RosMessage for RefereeClearanceMsg {
    const TYPE_NAME: &'static str = "foresight_msgs/msg/RefereeClearance";
    fn definition() -> String {
        full_definition(include_str!("../msg/RefereeClearance.msg"), &HEADER_DEPS)
    }
    fn encode(&self, w: &mut CdrWriter) {
        let c = &self.clearance;
        self.header.encode(w);
        w.u64(c.contacts);
        w.u64(c.steps);
        w.f64(c.min_clearance_m.unwrap_or(f64::NAN));
        w.string(&c.min_link);
        w.string(&c.min_other);
        w.string(&c.min_scene);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn definitions_name_every_dependency_once_after_a_separator() {
        let d = MarkerArray::definition();
        assert!(d.starts_with("Marker[] markers\n"));
        for dep in [
            "visualization_msgs/Marker",
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/Pose",
            "sensor_msgs/CompressedImage",
            "visualization_msgs/MeshFile",
        ] {
            assert_eq!(d.matches(&format!("\nMSG: {dep}\n")).count(), 1, "{dep}");
        }
        assert_eq!(d.matches(SEPARATOR).count(), 12);
        let v = TwinVerdictMsg::definition();
        assert!(v.contains("bool plan_approved\n"), "{v}");
        assert!(v.contains("\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"));
    }
}
