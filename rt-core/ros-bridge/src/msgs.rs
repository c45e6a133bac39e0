//! The ROS 2 message types the bridge publishes, as serde structs whose field order is the
//! ROS 2 IDL order (CDR encodes fields in declaration order, so order is the wire format).
//!
//! Layouts follow ROS 2 Jazzy (ros2-client's default distribution): `sensor_msgs/JointState`,
//! `visualization_msgs/MarkerArray` (with the Iron/Jazzy texture and mesh-file fields).

use ros2_client::Message;
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
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
            sec: (ns / 1_000_000_000).min(i32::MAX as u64) as i32,
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// `builtin_interfaces/Duration`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Duration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Capture or publish time.
    pub stamp: Time,
    /// Coordinate frame.
    pub frame_id: String,
}

/// `sensor_msgs/JointState`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// Joint names (`joint1` … `joint5`, as in `assets/xarm5.urdf`).
    pub name: Vec<String>,
    /// Joint angles (rad).
    pub position: Vec<f64>,
    /// Joint velocities (rad/s).
    pub velocity: Vec<f64>,
    /// Joint efforts (empty: the xArm reports currents, not published here).
    pub effort: Vec<f64>,
}
impl Message for JointState {}

/// `geometry_msgs/Point`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
    /// z (m).
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
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

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position (m).
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `std_msgs/ColorRGBA`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRgba {
    /// Red, 0–1.
    pub r: f32,
    /// Green, 0–1.
    pub g: f32,
    /// Blue, 0–1.
    pub b: f32,
    /// Opacity, 0–1.
    pub a: f32,
}

/// `sensor_msgs/CompressedImage` (only present in `Marker`, left empty).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame.
    pub header: Header,
    /// Encoding.
    pub format: String,
    /// Bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/UVCoordinate`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/MeshFile`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name.
    pub filename: String,
    /// File bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/Marker`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// Shape ([`Marker::CUBE`], [`Marker::LINE_STRIP`], …).
    #[serde(rename = "type")]
    pub kind: i32,
    /// [`Marker::ADD`] or [`Marker::DELETE_ALL`].
    pub action: i32,
    /// Pose of the shape.
    pub pose: Pose,
    /// Full extents (m) for boxes; line width in `x` for lines.
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRgba,
    /// Lifetime (0 = forever).
    pub lifetime: Duration,
    /// Whether the marker moves with its frame.
    pub frame_locked: bool,
    /// Points of line/point markers (m).
    pub points: Vec<Point>,
    /// Per-point colours.
    pub colors: Vec<ColorRgba>,
    /// Texture resource (unused).
    pub texture_resource: String,
    /// Texture (unused).
    pub texture: CompressedImage,
    /// Texture coordinates (unused).
    pub uv_coordinates: Vec<UvCoordinate>,
    /// Text of text markers.
    pub text: String,
    /// Mesh resource (unused).
    pub mesh_resource: String,
    /// Mesh file (unused).
    pub mesh_file: MeshFile,
    /// Mesh materials flag (unused).
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    /// `visualization_msgs/Marker.CUBE`.
    pub const CUBE: i32 = 1;
    /// `visualization_msgs/Marker.LINE_STRIP`.
    pub const LINE_STRIP: i32 = 4;
    /// `visualization_msgs/Marker.TEXT_VIEW_FACING`.
    pub const TEXT_VIEW_FACING: i32 = 9;
    /// `visualization_msgs/Marker.ADD`.
    pub const ADD: i32 = 0;
    /// `visualization_msgs/Marker.DELETEALL`.
    pub const DELETE_ALL: i32 = 3;
}

/// `visualization_msgs/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}
impl Message for MarkerArray {}
