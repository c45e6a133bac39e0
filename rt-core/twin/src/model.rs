//! The robot model: the xArm5 URDF loaded once into fixed arrays (joint origins and axes,
//! limits, the TCP offset, per-link collision capsules).
//!
//! Loading checks the file strictly: exactly five revolute joints named `joint1`…`joint5`
//! forming a chain from the root link, finite limits, and supported collision shapes
//! (cylinder, capsule, sphere; a cylinder becomes the capsule around it).
//!
//! The model is trusted only after its collision checks: **every moving link** (the child
//! of `joint1`…`joint5`) must carry at least one `<collision>` shape, or the file is refused
//! with [`UrdfLoadError::MissingCollision`] naming the link; a file without any collision
//! shape is refused with [`UrdfLoadError::NoCollisionShapes`]. Either gap would make the
//! clearance of that link (or of the whole arm) infinite, i.e. the shield silently off.
//! Shapes of links hung on a moving link (or on the base) by fixed joints, such as a
//! gripper link, are folded into that link's frame rather than ignored.
//!
//! An optional tool capsule (the gripper, from `assets/task.toml`'s `[tool]`) is fixed to
//! link5's frame with [`RobotModel::set_tool`]; [`super::TwinEnv::new`] installs the task's.

use std::path::Path;

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use super::{DOF, Joints};

/// Number of link frames: `link_base` plus link1..link5.
pub const N_FRAMES: usize = DOF + 1;

/// Most collision capsules in a model.
pub const MAX_CAPSULES: usize = 8;

/// One collision capsule: a segment in its link frame plus a radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkCapsule {
    /// Link frame index (`0` = base, `1..=5` = link1..link5).
    pub frame: usize,
    /// First end of the axis in the link frame (m).
    pub a_m: [f64; 3],
    /// Second end of the axis in the link frame (m).
    pub b_m: [f64; 3],
    /// Radius (m).
    pub radius_m: f64,
}

/// Joint acceleration limit of every xArm5 joint (rad/s²) — not expressible in URDF.
pub const ACCELERATION_LIMIT_RAD_S2: f64 = 20.0;

/// Joint jerk limit of every xArm5 joint (rad/s³) — not expressible in URDF.
pub const JERK_LIMIT_RAD_S3: f64 = 500.0;

/// Margin by which the collision radii in `assets/xarm5.urdf` exceed the nominal link
/// radii (m). The capsules additionally extend one radius past each cylinder end.
pub const COLLISION_MARGIN_M: f64 = 0.010;

/// Home posture used when nothing else is configured (rad): TCP about 0.30 m in front of
/// the base and 0.25 m above the table, flange pointing down.
pub const DEFAULT_HOME_RAD: Joints = [0.0, -0.383, -0.371, 0.855, 0.0];

/// Longest link name kept (bytes).
const NAME_CAPACITY: usize = 32;

/// Pseudo frame index of the tool capsule in reports ([`RobotModel::link_name`] gives
/// `"tool"`); the tool itself moves with link5.
pub const TOOL_FRAME: usize = N_FRAMES + 1;

/// Most links reached from one frame through fixed joints (the link itself included).
const MAX_FIXED_LINKS: usize = 8;

/// A link name in fixed capacity (`Copy`, for error values).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct LinkName {
    bytes: [u8; NAME_CAPACITY],
    len: u8,
}

impl LinkName {
    fn new(s: &str) -> Self {
        let mut bytes = [0; NAME_CAPACITY];
        // Names are checked against the capacity before any error names them; cut at a
        // character boundary all the same.
        let mut len = s.len().min(NAME_CAPACITY);
        while !s.is_char_boundary(len) {
            len -= 1;
        }
        bytes[..len].copy_from_slice(&s.as_bytes()[..len]);
        Self {
            bytes,
            len: len as u8,
        }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("?")
    }
}

impl std::fmt::Debug for LinkName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl std::fmt::Display for LinkName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a URDF was rejected. Indices are 1-based joint numbers (`joint3` → 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum UrdfLoadError {
    /// The file could not be read.
    #[error("cannot read the URDF file: {0}")]
    Io(std::io::ErrorKind),
    /// The XML was malformed or not a URDF robot.
    #[error("malformed URDF (not a well-formed <robot> description)")]
    Parse,
    /// A required joint `joint<N>` is missing.
    #[error("URDF lacks the required joint `joint{0}`")]
    MissingJoint(usize),
    /// `joint<N>` has a type other than revolute.
    #[error("joint{0} has an unsupported type (only revolute joints are supported)")]
    UnsupportedJointType(usize),
    /// The URDF has a number of movable joints other than 5.
    #[error("URDF has {0} movable joints; the xArm5 model needs exactly 5")]
    WrongJointCount(usize),
    /// `joint<N>`'s parent link is not `joint<N-1>`'s child (or, for joint1, not the root).
    #[error("joint{0} does not continue the kinematic chain")]
    BrokenChain(usize),
    /// `joint<N>` has a zero axis or non-finite origin.
    #[error("joint{0} has a zero axis or a non-finite origin")]
    BadJoint(usize),
    /// `joint<N>` has non-finite, empty or non-positive limits.
    #[error("joint{0} has invalid limits (need lower < upper, velocity > 0)")]
    BadLimits(usize),
    /// A link (index in `link_base, link1..link5`) has an unsupported or invalid collision
    /// shape (meshes and boxes are not supported).
    #[error("link frame {0} has an unsupported or invalid collision shape")]
    BadCollision(usize),
    /// More collision shapes than the fixed capacity.
    #[error("more than {MAX_CAPSULES} collision shapes")]
    TooManyShapes,
    /// A link name is longer than the fixed capacity.
    #[error("a link name is longer than 32 bytes")]
    NameTooLong,
    /// A moving link (the child of `joint1`…`joint5`) has no `<collision>` shape: its
    /// clearance would be infinite.
    #[error("moving link `{0}` has no <collision> shape (its clearance would be unchecked)")]
    MissingCollision(LinkName),
    /// The file has no collision shape at all: the clearance would be infinite.
    #[error("the URDF has no <collision> shapes (the clearance would be unchecked)")]
    NoCollisionShapes,
}

/// Joint limits (rad, rad/s, rad/s², rad/s³), joint 1 first.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    /// Lower position limits (rad).
    pub lower_rad: Joints,
    /// Upper position limits (rad).
    pub upper_rad: Joints,
    /// Velocity limits (rad/s).
    pub velocity_rad_s: Joints,
    /// Acceleration limits (rad/s²).
    pub acceleration_rad_s2: Joints,
    /// Jerk limits (rad/s³).
    pub jerk_rad_s3: Joints,
}

impl JointLimits {
    /// Clamps `q` into the position limits.
    pub fn clamp(&self, q: &mut Joints) {
        for ((v, lo), hi) in q.iter_mut().zip(&self.lower_rad).zip(&self.upper_rad) {
            *v = v.clamp(*lo, *hi);
        }
    }

    /// Whether every joint is within its position limits (inclusive).
    pub fn contains(&self, q: &Joints) -> bool {
        q.iter()
            .zip(&self.lower_rad)
            .zip(&self.upper_rad)
            .all(|((v, lo), hi)| *v >= *lo && *v <= *hi)
    }
}

/// The loaded robot: fixed arrays only, cheap to clone, `Send + Sync`.
#[derive(Debug, Clone)]
pub struct RobotModel {
    /// Origin of joint i in its parent link's frame.
    pub(crate) joint_origin: [Isometry3<f64>; DOF],
    /// Axis of joint i in its child link's frame (unit).
    pub(crate) joint_axis: [Unit<Vector3<f64>>; DOF],
    /// TCP in link5's frame.
    pub(crate) tcp_offset: Isometry3<f64>,
    limits: JointLimits,
    home: Joints,
    names: [heapless::String<NAME_CAPACITY>; N_FRAMES],
    pub(crate) capsules: heapless::Vec<LinkCapsule, MAX_CAPSULES>,
    tool: Option<LinkCapsule>,
}

fn iso(pose: &urdf_rs::Pose) -> Option<Isometry3<f64>> {
    let [x, y, z] = pose.xyz.0;
    let [r, p, yaw] = pose.rpy.0;
    if ![x, y, z, r, p, yaw].iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(r, p, yaw),
    ))
}

/// The collision capsule of one URDF shape, `origin` mapping the shape into `frame`.
fn capsule(
    frame: usize,
    origin: &Isometry3<f64>,
    geometry: &urdf_rs::Geometry,
) -> Result<LinkCapsule, UrdfLoadError> {
    let (half_len, radius) = match *geometry {
        urdf_rs::Geometry::Cylinder { radius, length }
        | urdf_rs::Geometry::Capsule { radius, length } => (length / 2.0, radius),
        urdf_rs::Geometry::Sphere { radius } => (0.0, radius),
        _ => return Err(UrdfLoadError::BadCollision(frame)),
    };
    if !(half_len.is_finite() && half_len >= 0.0 && radius.is_finite() && radius > 0.0) {
        return Err(UrdfLoadError::BadCollision(frame));
    }
    let a = origin * Point3::new(0.0, 0.0, -half_len);
    let b = origin * Point3::new(0.0, 0.0, half_len);
    Ok(LinkCapsule {
        frame,
        a_m: a.coords.into(),
        b_m: b.coords.into(),
        radius_m: radius,
    })
}

/// The link `root` and every link hung on it through fixed joints (a gripper, a TCP
/// link), each with its pose in `root`'s frame. `frame` names the link in errors.
fn fixed_group<'a>(
    robot: &'a urdf_rs::Robot,
    root: &str,
    frame: usize,
) -> Result<Vec<(&'a urdf_rs::Link, Isometry3<f64>)>, UrdfLoadError> {
    let mut out: Vec<(&urdf_rs::Link, Isometry3<f64>)> = Vec::new();
    if let Some(link) = robot.links.iter().find(|l| l.name == root) {
        out.push((link, Isometry3::identity()));
    }
    let mut i = 0;
    while i < out.len() {
        let (link, pose): (&'a urdf_rs::Link, _) = out[i];
        let parent = link.name.as_str();
        for j in robot
            .joints
            .iter()
            .filter(|j| j.joint_type == urdf_rs::JointType::Fixed && j.parent.link == parent)
        {
            let Some(child) = robot.links.iter().find(|l| l.name == j.child.link) else {
                continue;
            };
            if out.len() >= MAX_FIXED_LINKS || out.iter().any(|(l, _)| l.name == child.name) {
                return Err(UrdfLoadError::BadCollision(frame));
            }
            let origin = iso(&j.origin).ok_or(UrdfLoadError::BadCollision(frame))?;
            out.push((child, pose * origin));
        }
        i += 1;
    }
    Ok(out)
}

/// `joint1`..`joint5`, checked to be the only movable joints, all revolute, and to form one
/// chain from a root link (a link that is no joint's child).
fn chain_joints(robot: &urdf_rs::Robot) -> Result<Vec<&urdf_rs::Joint>, UrdfLoadError> {
    let movable = robot
        .joints
        .iter()
        .filter(|j| j.joint_type != urdf_rs::JointType::Fixed)
        .count();
    let mut joints: Vec<&urdf_rs::Joint> = Vec::with_capacity(DOF);
    for i in 1..=DOF {
        let wanted = format!("joint{i}");
        let joint = robot
            .joints
            .iter()
            .find(|j| j.name == wanted)
            .ok_or(UrdfLoadError::MissingJoint(i))?;
        if joint.joint_type != urdf_rs::JointType::Revolute {
            return Err(UrdfLoadError::UnsupportedJointType(i));
        }
        joints.push(joint);
    }
    if movable != DOF {
        return Err(UrdfLoadError::WrongJointCount(movable));
    }
    // The root link: not the child of any joint.
    let root = &joints[0].parent.link;
    if robot.joints.iter().any(|j| &j.child.link == root) {
        return Err(UrdfLoadError::BrokenChain(1));
    }
    for i in 1..DOF {
        if joints[i].parent.link != joints[i - 1].child.link {
            return Err(UrdfLoadError::BrokenChain(i + 1));
        }
    }
    Ok(joints)
}

/// The collision capsules of every frame's links (each frame's link and the links fixed to
/// it), in the frame's coordinates; every moving link must have at least one.
fn collision_capsules(
    robot: &urdf_rs::Robot,
    link_names: &[&str; N_FRAMES],
) -> Result<heapless::Vec<LinkCapsule, MAX_CAPSULES>, UrdfLoadError> {
    let mut capsules = heapless::Vec::new();
    let mut missing = None;
    for (frame, link_name) in link_names.iter().enumerate() {
        let before = capsules.len();
        for (link, to_frame) in fixed_group(robot, link_name, frame)? {
            for c in &link.collision {
                let origin = iso(&c.origin).ok_or(UrdfLoadError::BadCollision(frame))?;
                capsules
                    .push(capsule(frame, &(to_frame * origin), &c.geometry)?)
                    .map_err(|_| UrdfLoadError::TooManyShapes)?;
            }
        }
        if frame > 0 && capsules.len() == before && missing.is_none() {
            missing = Some(LinkName::new(link_name));
        }
    }
    if capsules.is_empty() {
        return Err(UrdfLoadError::NoCollisionShapes);
    }
    if let Some(link) = missing {
        return Err(UrdfLoadError::MissingCollision(link));
    }
    Ok(capsules)
}

fn name(s: &str) -> Result<heapless::String<NAME_CAPACITY>, UrdfLoadError> {
    let mut out = heapless::String::new();
    out.push_str(s).map_err(|_| UrdfLoadError::NameTooLong)?;
    Ok(out)
}

impl RobotModel {
    /// Loads and validates a URDF file.
    ///
    /// # Errors
    /// [`UrdfLoadError`] naming what is wrong.
    pub fn load(path: &Path) -> Result<Self, UrdfLoadError> {
        let text = std::fs::read_to_string(path).map_err(|e| UrdfLoadError::Io(e.kind()))?;
        Self::from_urdf_str(&text)
    }

    /// Parses and validates URDF text.
    ///
    /// # Errors
    /// [`UrdfLoadError`] naming what is wrong.
    pub fn from_urdf_str(text: &str) -> Result<Self, UrdfLoadError> {
        let robot = urdf_rs::read_from_string(text).map_err(|_| UrdfLoadError::Parse)?;
        let joints = chain_joints(&robot)?;
        let root = &joints[0].parent.link;
        let mut joint_origin = [Isometry3::identity(); DOF];
        let mut joint_axis = [Vector3::z_axis(); DOF];
        let mut limits = JointLimits {
            lower_rad: [0.0; DOF],
            upper_rad: [0.0; DOF],
            velocity_rad_s: [0.0; DOF],
            acceleration_rad_s2: [ACCELERATION_LIMIT_RAD_S2; DOF],
            jerk_rad_s3: [JERK_LIMIT_RAD_S3; DOF],
        };
        for (i, j) in joints.iter().enumerate() {
            joint_origin[i] = iso(&j.origin).ok_or(UrdfLoadError::BadJoint(i + 1))?;
            let a = Vector3::from(j.axis.xyz.0);
            if !a.iter().all(|v| v.is_finite()) || a.norm() < 1e-9 {
                return Err(UrdfLoadError::BadJoint(i + 1));
            }
            joint_axis[i] = Unit::new_normalize(a);
            let l = &j.limit;
            let limits_ok = l.lower.is_finite() && l.upper.is_finite() && l.lower < l.upper;
            let velocity_ok = l.velocity.is_finite() && l.velocity > 0.0;
            if !(limits_ok && velocity_ok) {
                return Err(UrdfLoadError::BadLimits(i + 1));
            }
            limits.lower_rad[i] = l.lower;
            limits.upper_rad[i] = l.upper;
            limits.velocity_rad_s[i] = l.velocity;
        }
        // TCP: a fixed joint hanging off link5, if any.
        let last = &joints[DOF - 1].child.link;
        let tcp_offset = match robot
            .joints
            .iter()
            .find(|j| j.joint_type == urdf_rs::JointType::Fixed && &j.parent.link == last)
        {
            Some(j) => iso(&j.origin).ok_or(UrdfLoadError::BadJoint(DOF + 1))?,
            None => Isometry3::identity(),
        };
        let link_names: [&str; N_FRAMES] = [
            root,
            &joints[0].child.link,
            &joints[1].child.link,
            &joints[2].child.link,
            &joints[3].child.link,
            &joints[4].child.link,
        ];
        let mut names: [heapless::String<NAME_CAPACITY>; N_FRAMES] = Default::default();
        for (frame, link_name) in link_names.iter().enumerate() {
            names[frame] = name(link_name)?;
        }
        let capsules = collision_capsules(&robot, &link_names)?;
        let mut model = Self {
            joint_origin,
            joint_axis,
            tcp_offset,
            limits,
            home: DEFAULT_HOME_RAD,
            names,
            capsules,
            tool: None,
        };
        let mut home = DEFAULT_HOME_RAD;
        model.limits.clamp(&mut home);
        model.home = home;
        Ok(model)
    }

    /// The joint limits.
    pub fn limits(&self) -> &JointLimits {
        &self.limits
    }

    /// The home posture (rad): TCP above the table in front of the robot.
    pub fn home(&self) -> Joints {
        self.home
    }

    /// Replaces the home posture (clamped into the limits).
    pub fn set_home(&mut self, mut q: Joints) {
        self.limits.clamp(&mut q);
        self.home = q;
    }

    /// Name of link frame `i` (`0` = base, `1..=5` = link1..link5); `"tcp"` for `N_FRAMES`,
    /// `"tool"` for [`TOOL_FRAME`], `"?"` beyond.
    pub fn link_name(&self, i: usize) -> &str {
        match self.names.get(i) {
            Some(n) => n.as_str(),
            None if i == N_FRAMES => "tcp",
            None if i == TOOL_FRAME => "tool",
            None => "?",
        }
    }

    /// The collision capsules, in their link frames (the tool's not among them).
    pub fn capsules(&self) -> &[LinkCapsule] {
        &self.capsules
    }

    /// The tool capsule fixed to link5, if any (its `frame` is 5).
    pub fn tool(&self) -> Option<&LinkCapsule> {
        self.tool.as_ref()
    }

    /// Fixes a tool (gripper) to link5's frame, or removes it with `None`: from then on
    /// every distance query of a [`super::RobotGeometry`] built on this model includes it
    /// (boxes, table, self-collision). The task's `[tool]` ([`super::TaskConfig::tool`])
    /// gives it: `model.set_tool(task.tool.map(|t| t.capsule()))`.
    pub fn set_tool(&mut self, tool: Option<LinkCapsule>) {
        self.tool = tool.map(|t| LinkCapsule { frame: DOF, ..t });
    }

    /// [`RobotModel::set_tool`] by value.
    #[must_use]
    pub fn with_tool(mut self, tool: Option<LinkCapsule>) -> Self {
        self.set_tool(tool);
        self
    }
}
