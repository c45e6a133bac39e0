//! ROS 2 frame source through `ros2-client`: colour image, depth image and camera info,
//! by default on the ZED ROS 2 wrapper's topics (configurable in TOML, [`Ros2Topics`]).
//!
//! **Closed by default.** DDS is restricted to loopback (`networks = ["127.0.0.1"]`, through
//! `DomainParticipantBuilder::with_only_networks`): a host on the LAN cannot inject camera
//! images, which would become obstacles and goals for the real arm. Using another address
//! (the camera PC's network) or every interface (`networks = []`) needs
//! [`NetworkAccess::Open`], which only `perception run --ros2-open-network` gives; without
//! it such a configuration is refused at start, naming `networks`. rustdds also announces
//! itself to same-host peers over unicast, so a camera driver on this machine is found on
//! loopback; discovery over `lo` multicast needs the `MULTICAST` flag on `lo`
//! (`ip link set lo multicast on`), which the system test sets inside its own network
//! namespace.
//!
//! **Own DDS domain.** The camera subscription joins DDS domain [`DEFAULT_DOMAIN_ID`] (42)
//! unless the topics file says otherwise (`domain_id`, 0..=101, the ids whose DDS ports
//! stay clear of Linux's ephemeral range): a ROS 2 node on the default domain 0 on this
//! machine is not heard. The camera driver must be started with `ROS_DOMAIN_ID=42` (or the
//! file's id). A domain is a filter, not a lock: any process of this machine that joins it
//! can publish images; see docs/real-arm.md for what remains trusted.
//!
//! **ROS 2 security (SROS2) is not available in this build**: `ros2-client` 0.12 and
//! `rustdds` 0.15 read none of the `ROS_SECURITY_*` variables (`ROS_SECURITY_ENABLE`,
//! `ROS_SECURITY_KEYSTORE`, `ROS_SECURITY_STRATEGY`, `ROS_SECURITY_ENCLAVE_OVERRIDE`) nor
//! `ROS_DOMAIN_ID`; DDS Security exists in rustdds only behind its `security` cargo feature
//! (OpenSSL, configured in code), which the workspace does not enable. So a user who asks
//! for security (`ROS_SECURITY_ENABLE=true`) is refused at start ([`check_ros_security`])
//! rather than given an unsecured subscription silently.
//!
//! **Depth paired by stamp.** A colour image is paired with the depth image whose
//! `header.stamp` is nearest to its own, within `max_depth_skew_ms` (default 10 ms; the
//! ZED wrapper stamps a registered depth image with its colour image's stamp). Without
//! one — no depth yet, or only depth images from another time (a stalled depth topic) —
//! the frame is refused ([`SourceError::Depth`], counted as `unpaired_depth` by the run
//! loop) and the tracker's settled state starts over ([`crate::tracker::Tracker::interrupt`]):
//! a new box is never measured against the table's old depth (a tall box published as a
//! 1 mm footprint in a settled frame).
//!
//! **One camera** (issue 30 item 2). The source is opened with the calibration's camera
//! frame id ([`crate::camera_id`]); a colour image whose `header.frame_id` differs is
//! refused ([`SourceError::WrongCamera`], counted as `wrong_camera` by the run loop, which
//! logs it naming both ids and starts the tracker's settled state over), and a depth image
//! whose `header.frame_id` differs is never paired (dropped at receipt, logged at most every
//! 5 s). A camera whose images carry another id than its calibration never yields a frame:
//! perception publishes nothing and says why, rather than measuring one camera's pixels with
//! another camera's pose. `perception run` refuses the synthetic camera's calibration with
//! this source, and starting it without `--calibration`, before DDS is touched.
//!
//! **Stamps.** A frame's `capture_time_ns` is the colour image's `header.stamp` (the
//! camera's capture time, on the ROS/system clock) converted to `CLOCK_MONOTONIC` with the
//! clock offset measured when the image was received ([`crate::stamp`]); an image whose
//! stamp is zero, in the future beyond `stamp.max_ahead_s`, or older than `stamp.max_age_s`
//! is refused ([`SourceError::Stamp`], counted as `bad_stamps` by the run loop).

use std::collections::VecDeque;
use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use opencv::core::{CV_8UC3, CV_8UC4, CV_16UC1, CV_32FC1, Mat};
use opencv::prelude::*;
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    Subscription,
};
use serde::{Deserialize, Serialize};

use crate::frame::{Frame, FrameError, ImageDefect, ImageMsgConvertError};
use crate::log_limit::LogLimiter;
use crate::source::{DepthPairError, FrameSource, SourceError, SourceFailure, WrongCameraError};
use crate::stamp::{ClockPair, StampLimits, StampLimitsError, ros_stamp_to_monotonic_ns};

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Capture time.
    pub stamp: Time,
    /// Frame id.
    pub frame_id: String,
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Image {
    /// Header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `bgr8`, `rgb8`, `bgra8`, `rgba8`, `32FC1` or `16UC1`.
    pub encoding: String,
    /// 1 if big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// Pixels.
    pub data: Vec<u8>,
}
impl ros2_client::Message for Image {}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// x offset.
    pub x_offset: u32,
    /// y offset.
    pub y_offset: u32,
    /// height.
    pub height: u32,
    /// width.
    pub width: u32,
    /// rectify flag.
    pub do_rectify: bool,
}

/// `sensor_msgs/CameraInfo`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Distortion model name.
    pub distortion_model: String,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation.
    pub r: [f64; 9],
    /// Projection matrix.
    pub p: [f64; 12],
    /// Binning x.
    pub binning_x: u32,
    /// Binning y.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}
impl ros2_client::Message for CameraInfo {}

/// Topic names, DDS settings and stamp limits (TOML; unknown fields are refused).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Topics {
    /// DDS domain of the camera subscription (0..=[`MAX_DOMAIN_ID`]). Default:
    /// [`DEFAULT_DOMAIN_ID`], a domain of our own, not ROS 2's default 0.
    #[serde(default = "default_domain_id")]
    pub domain_id: u16,
    /// Local addresses DDS may use. Default: loopback only (`["127.0.0.1"]`). A
    /// non-loopback address, or an empty list (every interface), is accepted only with
    /// [`NetworkAccess::Open`].
    #[serde(default = "loopback_only")]
    pub networks: Vec<IpAddr>,
    /// Colour image topic.
    pub colour: String,
    /// Depth image topic (32FC1 metres or 16UC1 millimetres, registered to colour).
    pub depth: String,
    /// Camera info topic of the colour image.
    pub camera_info: String,
    /// Longest wait for a new colour image (s).
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
    /// How old or how far ahead a colour image's `header.stamp` may be (`[stamp]`).
    #[serde(default)]
    pub stamp: StampLimits,
    /// Largest difference between the stamps of a colour image and the depth image paired
    /// with it (ms, 0..=[`MAX_DEPTH_SKEW_MS`]); a colour image without such a depth image
    /// is refused.
    #[serde(default = "default_max_depth_skew_ms")]
    pub max_depth_skew_ms: f64,
}

/// The camera subscription's DDS domain unless configured: ours, not ROS 2's default 0.
pub const DEFAULT_DOMAIN_ID: u16 = 42;

/// Largest `domain_id`: ROS 2's limit for Linux (higher ids put DDS ports in the ephemeral
/// range).
pub const MAX_DOMAIN_ID: u16 = 101;

/// Largest `max_depth_skew_ms`: beyond it, a depth image of an earlier frame (60 Hz: 17 ms
/// apart) could be paired with a new colour image.
pub const MAX_DEPTH_SKEW_MS: f64 = 100.0;

fn default_domain_id() -> u16 {
    DEFAULT_DOMAIN_ID
}

fn default_max_depth_skew_ms() -> f64 {
    10.0
}

fn default_timeout_s() -> f64 {
    2.0
}

/// `["127.0.0.1"]`: the default of [`Ros2Topics::networks`].
pub fn loopback_only() -> Vec<IpAddr> {
    vec![IpAddr::V4(Ipv4Addr::LOCALHOST)]
}

impl Default for Ros2Topics {
    /// The ZED ROS 2 wrapper's topics for a camera named `zed`, loopback only.
    fn default() -> Self {
        Self {
            domain_id: DEFAULT_DOMAIN_ID,
            networks: loopback_only(),
            colour: "/zed/zed_node/rgb/image_rect_color".into(),
            depth: "/zed/zed_node/depth/depth_registered".into(),
            camera_info: "/zed/zed_node/rgb/camera_info".into(),
            timeout_s: default_timeout_s(),
            stamp: StampLimits::default(),
            max_depth_skew_ms: default_max_depth_skew_ms(),
        }
    }
}

/// Whether the ROS 2 source may listen beyond loopback.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum NetworkAccess {
    /// Only loopback addresses (the default): no other host can send camera images.
    #[default]
    LoopbackOnly,
    /// The addresses in [`Ros2Topics::networks`] whatever they are; every interface when
    /// the list is empty (`perception run --ros2-open-network`).
    Open,
}

/// Why ROS 2 topic settings were refused; each message names the file or the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Ros2TopicsError {
    /// The file could not be read.
    #[error("cannot read ROS 2 topics file {path}: {message}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The file is not valid TOML for [`Ros2Topics`].
    #[error("malformed ROS 2 topics file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (names the field).
        message: String,
    },
    /// A value in the file is out of bounds.
    #[error("ROS 2 topics file {path}: {error}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// The bound broken (names the field).
        error: Box<Ros2TopicsError>,
    },
    /// `networks` would open DDS beyond loopback without [`NetworkAccess::Open`].
    #[error(
        "networks = {networks:?}: the ROS 2 camera source is loopback-only unless opened with --ros2-open-network ({why})"
    )]
    NotLoopback {
        /// The addresses given.
        networks: Vec<IpAddr>,
        /// What is not loopback.
        why: &'static str,
    },
    /// `timeout_s` is not a positive number of seconds up to 600.
    #[error("timeout_s = {0} must be within (0, 600] s")]
    Timeout(f64),
    /// A `[stamp]` limit is out of bounds.
    #[error(transparent)]
    Stamp(#[from] StampLimitsError),
    /// `domain_id` is above [`MAX_DOMAIN_ID`].
    #[error("domain_id = {0} must be within 0..={MAX_DOMAIN_ID}")]
    DomainId(u16),
    /// `ROS_SECURITY_ENABLE=true` (SROS2 asked for), which this build cannot honour.
    #[error(
        "ROS_SECURITY_ENABLE={0}: ROS 2 security (SROS2) was asked for, but this build's DDS \
         (rustdds without its `security` feature) cannot join a secured domain; unset it to run \
         unsecured on loopback and perception's own domain, or keep the camera off this host's \
         reach (docs/real-arm.md, the real-arm checklist)"
    )]
    SecurityUnsupported(String),
    /// `max_depth_skew_ms` is not within 0..=[`MAX_DEPTH_SKEW_MS`].
    #[error("max_depth_skew_ms = {0} must be within 0..={MAX_DEPTH_SKEW_MS} ms")]
    DepthSkew(f64),
}

impl Ros2Topics {
    /// Loads topic settings from TOML and checks the values that do not depend on the
    /// network access ([`Ros2Topics::validate`] checks all).
    ///
    /// # Errors
    /// [`Ros2TopicsError`] naming the file or the field.
    pub fn load(path: &Path) -> Result<Self, Ros2TopicsError> {
        let text = std::fs::read_to_string(path).map_err(|e| Ros2TopicsError::Read {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let t: Self = toml::from_str(&text).map_err(|e| Ros2TopicsError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        t.validate(NetworkAccess::Open)
            .map_err(|e| Ros2TopicsError::InFile {
                path: path.to_path_buf(),
                error: Box::new(e),
            })?;
        Ok(t)
    }

    /// Checks the values: with [`NetworkAccess::LoopbackOnly`], `networks` must list only
    /// loopback addresses (and at least one); `timeout_s`, `domain_id`,
    /// `max_depth_skew_ms` and the stamp limits in bounds.
    ///
    /// # Errors
    /// [`Ros2TopicsError`] naming the field.
    pub fn validate(&self, access: NetworkAccess) -> Result<(), Ros2TopicsError> {
        if access == NetworkAccess::LoopbackOnly {
            let why = if self.networks.is_empty() {
                Some("an empty list means every interface")
            } else if self.networks.iter().any(|a| !a.is_loopback()) {
                Some("an address is not loopback")
            } else {
                None
            };
            if let Some(why) = why {
                return Err(Ros2TopicsError::NotLoopback {
                    networks: self.networks.clone(),
                    why,
                });
            }
        }
        if !(self.timeout_s > 0.0 && self.timeout_s <= 600.0) {
            return Err(Ros2TopicsError::Timeout(self.timeout_s));
        }
        if self.domain_id > MAX_DOMAIN_ID {
            return Err(Ros2TopicsError::DomainId(self.domain_id));
        }
        if !(self.max_depth_skew_ms.is_finite()
            && (0.0..=MAX_DEPTH_SKEW_MS).contains(&self.max_depth_skew_ms))
        {
            return Err(Ros2TopicsError::DepthSkew(self.max_depth_skew_ms));
        }
        self.stamp.validate()?;
        Ok(())
    }
}

/// Refuses a request for ROS 2 security (`ROS_SECURITY_ENABLE`, given as `enable`; only
/// `true`, as rcl reads it, asks for it): this build cannot provide it.
///
/// # Errors
/// [`Ros2TopicsError::SecurityUnsupported`].
pub fn check_ros_security(enable: Option<&str>) -> Result<(), Ros2TopicsError> {
    match enable {
        Some(v) if v == "true" => Err(Ros2TopicsError::SecurityUnsupported(v.to_owned())),
        _ => Ok(()),
    }
}

fn qos() -> QosProfile {
    use ros2_client::qos::{Durability, History};
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 2 })
}

impl From<Ros2TopicsError> for SourceError {
    fn from(e: Ros2TopicsError) -> Self {
        SourceError::Open(e.to_string())
    }
}

/// Creates a ROS 2 context, restricted to `networks` when not empty (every interface when
/// empty: [`Ros2Source::open`] allows that only with [`NetworkAccess::Open`]).
///
/// # Errors
/// [`SourceError::Open`].
pub fn context(domain_id: u16, networks: &[IpAddr]) -> Result<Context, SourceError> {
    let open = |e: String| SourceError::Open(format!("ROS 2: {e}"));
    if networks.is_empty() {
        let opts = ros2_client::ContextOptions::new().domain_id(domain_id);
        return Context::with_options(opts).map_err(|e| open(format!("{e:?}")));
    }
    let dp = DomainParticipantBuilder::new(domain_id)
        .with_only_networks(networks.iter().copied())
        .build()
        .map_err(|e| open(format!("{e:?}")))?;
    Context::from_domain_participant(dp).map_err(|e| open(format!("{e:?}")))
}

/// Creates a node in `context`.
///
/// # Errors
/// [`SourceError::Open`].
pub fn node(context: &Context, name: &str) -> Result<Node, SourceError> {
    let n = NodeName::new("/foresight", name).map_err(|e| SourceError::Open(format!("{e:?}")))?;
    context
        .new_node(n, NodeOptions::new().enable_rosout(false))
        .map_err(|e| SourceError::Open(format!("ROS 2 node: {e:?}")))
}

fn topic(
    node: &mut Node,
    name: &str,
    pkg: &str,
    ty: &str,
) -> Result<ros2_client::dds::rustdds::Topic, SourceError> {
    let n = Name::parse(name).map_err(|e| SourceError::Open(format!("topic {name:?}: {e:?}")))?;
    node.create_topic(&n, MessageTypeName::new(pkg, ty), &qos())
        .map_err(|e| SourceError::Open(format!("topic {name:?}: {e:?}")))
}

/// Creates a publisher of images (used by tests and simulators to play a camera).
///
/// # Errors
/// [`SourceError::Open`].
pub fn image_publisher(node: &mut Node, name: &str) -> Result<Publisher<Image>, SourceError> {
    let t = topic(node, name, "sensor_msgs", "Image")?;
    node.create_publisher(&t, None)
        .map_err(|e| SourceError::Open(format!("{e:?}")))
}

/// Creates a publisher of camera info.
///
/// # Errors
/// [`SourceError::Open`].
pub fn camera_info_publisher(
    node: &mut Node,
    name: &str,
) -> Result<Publisher<CameraInfo>, SourceError> {
    let t = topic(node, name, "sensor_msgs", "CameraInfo")?;
    node.create_publisher(&t, None)
        .map_err(|e| SourceError::Open(format!("{e:?}")))
}

/// Converts a `sensor_msgs/Image` to a BGR `Mat`.
///
/// # Errors
/// [`FrameError::BadColour`] for an unsupported encoding or inconsistent sizes.
pub fn colour_from_msg(msg: &Image) -> Result<Mat, FrameError> {
    let (channels, cv_type, code) = match msg.encoding.as_str() {
        "bgr8" => (3, CV_8UC3, None),
        "rgb8" => (3, CV_8UC3, Some(opencv::imgproc::COLOR_RGB2BGR)),
        "bgra8" => (4, CV_8UC4, Some(opencv::imgproc::COLOR_BGRA2BGR)),
        "rgba8" => (4, CV_8UC4, Some(opencv::imgproc::COLOR_RGBA2BGR)),
        e => {
            return Err(FrameError::BadColour(ImageDefect::Encoding(e.to_owned())));
        }
    };
    let m = image_mat(msg, channels, 1, cv_type).map_err(|e| FrameError::BadColour(e.into()))?;
    match code {
        None => Ok(m),
        Some(c) => {
            let mut out = Mat::default();
            opencv::imgproc::cvt_color(&m, &mut out, c, 0)?;
            Ok(out)
        }
    }
}

/// Converts a depth `sensor_msgs/Image` (32FC1 m or 16UC1 mm) to `CV_32FC1` metres.
///
/// # Errors
/// [`FrameError::BadDepth`].
pub fn depth_from_msg(msg: &Image) -> Result<Mat, FrameError> {
    match msg.encoding.as_str() {
        "32FC1" => image_mat(msg, 1, 4, CV_32FC1).map_err(|e| FrameError::BadDepth(e.into())),
        "16UC1" | "mono16" => {
            let m = image_mat(msg, 1, 2, CV_16UC1).map_err(|e| FrameError::BadDepth(e.into()))?;
            let mut out = Mat::default();
            m.convert_to(&mut out, CV_32FC1, 1e-3, 0.0)?;
            for d in out.data_typed_mut::<f32>()?.iter_mut() {
                if *d <= 0.0 {
                    *d = f32::NAN;
                }
            }
            Ok(out)
        }
        e => Err(FrameError::BadDepth(ImageDefect::Encoding(e.to_owned()))),
    }
}

fn image_mat(
    msg: &Image,
    channels: usize,
    bytes_per: usize,
    cv_type: i32,
) -> Result<Mat, ImageMsgConvertError> {
    if msg.is_bigendian != 0 && bytes_per > 1 {
        return Err(ImageMsgConvertError::BigEndian {
            is_bigendian: msg.is_bigendian,
            encoding: msg.encoding.clone(),
        });
    }
    let (w, h) = (msg.width as usize, msg.height as usize);
    if w == 0 || h == 0 {
        return Err(ImageMsgConvertError::Empty {
            width: msg.width,
            height: msg.height,
        });
    }
    let row = w * channels * bytes_per;
    let step = msg.step as usize;
    if step < row || msg.data.len() < step * (h - 1) + row {
        return Err(ImageMsgConvertError::TooShort {
            width: msg.width,
            height: msg.height,
            encoding: msg.encoding.clone(),
            row_bytes: row,
            step: msg.step,
            data_len: msg.data.len(),
        });
    }
    let mut m = Mat::new_rows_cols_with_default(
        h as i32,
        w as i32,
        cv_type,
        opencv::core::Scalar::all(0.0),
    )?;
    let dst = m.data_bytes_mut()?;
    for y in 0..h {
        dst[y * row..(y + 1) * row].copy_from_slice(&msg.data[y * step..y * step + row]);
    }
    Ok(m)
}

/// Checks an image's `header.frame_id` against the calibration's camera `expected`.
///
/// # Errors
/// [`WrongCameraError`] naming both ids and `topic`.
pub fn check_frame_id(
    topic: &str,
    header: &Header,
    expected: &str,
) -> Result<(), WrongCameraError> {
    if header.frame_id == expected {
        return Ok(());
    }
    Err(WrongCameraError {
        topic: topic.to_owned(),
        got: header.frame_id.clone(),
        expected: expected.to_owned(),
    })
}

/// A ROS stamp in ns since the epoch (`sec` may be negative in a malformed message; the
/// colour image's stamp is checked by [`ros_stamp_to_monotonic_ns`]).
pub fn stamp_ns(t: Time) -> i128 {
    i128::from(t.sec) * 1_000_000_000 + i128::from(t.nanosec)
}

/// The pairing rule: the index of the depth stamp nearest to `colour_ns` (ns), if it lies
/// within `max_skew_ns`; else `Err` with the nearest difference in ns (`None`: no depth
/// stamp at all).
///
/// # Errors
/// `Err(None)` without depth stamps, `Err(Some(skew_ns))` when the nearest is too far.
pub fn pair_depth(
    colour_ns: i128,
    depth_ns: impl IntoIterator<Item = i128>,
    max_skew_ns: i128,
) -> Result<usize, Option<i128>> {
    let nearest = depth_ns
        .into_iter()
        .enumerate()
        .map(|(i, d)| (i, (d - colour_ns).abs()))
        .min_by_key(|&(_, skew)| skew);
    match nearest {
        Some((i, skew)) if skew <= max_skew_ns => Ok(i),
        Some((_, skew)) => Err(Some(skew)),
        None => Err(None),
    }
}

/// Depth images kept for pairing (the newest; 8 frames are 130 ms at 60 Hz).
const DEPTH_HISTORY: usize = 8;

/// Frames from ROS 2 topics.
pub struct Ros2Source {
    _context: Context,
    _node: Node,
    colour: Subscription<Image>,
    depth: Subscription<Image>,
    info: Subscription<CameraInfo>,
    /// The newest depth images, oldest first.
    depths: VecDeque<Image>,
    /// Latest camera info received.
    pub latest_info: Option<CameraInfo>,
    timeout: Duration,
    sequence: u64,
    /// Topic names in use.
    pub topics: Ros2Topics,
    /// The calibration's camera: images with another `header.frame_id` are refused.
    frame_id: String,
    /// Depth images dropped for another `header.frame_id`.
    pub foreign_depth: u64,
    foreign_depth_log: LogLimiter,
}

impl Ros2Source {
    /// Checks the settings against `access` ([`Ros2Topics::validate`]: loopback only
    /// unless [`NetworkAccess::Open`]) and subscribes to the three topics; only images whose
    /// `header.frame_id` is `frame_id` (the calibration's camera) are used.
    ///
    /// # Errors
    /// [`SourceError::Open`], naming the field for refused settings.
    pub fn open(
        topics: &Ros2Topics,
        access: NetworkAccess,
        frame_id: &str,
    ) -> Result<Self, SourceError> {
        topics.validate(access)?;
        check_ros_security(std::env::var("ROS_SECURITY_ENABLE").ok().as_deref())?;
        if topics.networks.is_empty() {
            tracing::warn!(
                "ROS 2 camera source open on every interface (--ros2-open-network, networks = []): any host on the LAN can send camera images"
            );
        } else if topics.networks.iter().any(|a| !a.is_loopback()) {
            tracing::warn!(networks = ?topics.networks, "ROS 2 camera source open beyond loopback (--ros2-open-network)");
        }
        let ctx = context(topics.domain_id, &topics.networks)?;
        let mut node = node(&ctx, "perception")?;
        let t_colour = topic(&mut node, &topics.colour, "sensor_msgs", "Image")?;
        let t_depth = topic(&mut node, &topics.depth, "sensor_msgs", "Image")?;
        let t_info = topic(&mut node, &topics.camera_info, "sensor_msgs", "CameraInfo")?;
        let sub_err = |e| SourceError::Open(format!("ROS 2 subscription: {e:?}"));
        let colour = node
            .create_subscription::<Image>(&t_colour, None)
            .map_err(sub_err)?;
        let depth = node
            .create_subscription::<Image>(&t_depth, None)
            .map_err(sub_err)?;
        let info = node
            .create_subscription::<CameraInfo>(&t_info, None)
            .map_err(sub_err)?;
        Ok(Self {
            _context: ctx,
            _node: node,
            colour,
            depth,
            info,
            depths: VecDeque::with_capacity(DEPTH_HISTORY),
            latest_info: None,
            timeout: Duration::from_secs_f64(topics.timeout_s.clamp(0.01, 600.0)),
            sequence: 0,
            topics: topics.clone(),
            frame_id: frame_id.to_owned(),
            foreign_depth: 0,
            foreign_depth_log: LogLimiter::new(Duration::from_secs(5)),
        })
    }

    fn drain_side_topics(&mut self) {
        while let Ok(Some((m, _))) = self.depth.take() {
            if let Err(e) = check_frame_id(&self.topics.depth, &m.header, &self.frame_id) {
                self.foreign_depth += 1;
                if let Some(held_back) = self.foreign_depth_log.allow(Instant::now()) {
                    tracing::error!(
                        foreign_depth = self.foreign_depth,
                        "depth image dropped: {e} ({held_back} more since the last warning)"
                    );
                }
                continue;
            }
            if self.depths.len() == DEPTH_HISTORY {
                self.depths.pop_front();
            }
            self.depths.push_back(m);
        }
        while let Ok(Some((m, _))) = self.info.take() {
            self.latest_info = Some(m);
        }
    }
}

impl Ros2Source {
    /// The kept depth image paired with `colour` by [`pair_depth`].
    fn paired_depth(&self, colour: &Image) -> Result<&Image, DepthPairError> {
        let max_skew_ns = (self.topics.max_depth_skew_ms * 1e6).round() as i128;
        match pair_depth(
            stamp_ns(colour.header.stamp),
            self.depths.iter().map(|d| stamp_ns(d.header.stamp)),
            max_skew_ns,
        ) {
            Ok(i) => Ok(&self.depths[i]),
            Err(None) => Err(DepthPairError::NoDepth {
                topic: self.topics.depth.clone(),
            }),
            Err(Some(skew_ns)) => Err(DepthPairError::Stale {
                topic: self.topics.depth.clone(),
                skew_ms: skew_ns as f64 / 1e6,
                max_ms: self.topics.max_depth_skew_ms,
            }),
        }
    }
}

impl FrameSource for Ros2Source {
    /// The latest colour image with the depth image paired by stamp ([`pair_depth`],
    /// within `max_depth_skew_ms`; it is given 50 ms to arrive), stamped with its
    /// `header.stamp` on `CLOCK_MONOTONIC`.
    ///
    /// # Errors
    /// [`SourceError::WrongCamera`] for a colour image of another camera than the
    /// calibration's, [`SourceError::Stamp`] for a refused stamp and [`SourceError::Depth`]
    /// for a colour image without a paired depth image (these frames only), [`SourceError::Frame`] for a
    /// bad image, [`SourceError::Failed`] when no image came within `timeout_s`.
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        let deadline = Instant::now() + self.timeout;
        let mut colour = None;
        loop {
            self.drain_side_topics();
            loop {
                match self.colour.take() {
                    // The clocks are read as each image is taken, for its stamp's conversion.
                    Ok(Some((m, _))) => colour = Some((m, ClockPair::now())),
                    Ok(None) => break,
                    Err(e) => return Err(SourceError::Failed(SourceFailure::ColourTopic(e))),
                }
            }
            if colour.is_some() {
                break;
            }
            if Instant::now() >= deadline {
                return Err(SourceError::Failed(SourceFailure::NoImage {
                    topic: self.topics.colour.clone(),
                    within_s: self.timeout.as_secs_f64(),
                }));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let Some((colour, received)) = colour else {
            return Ok(None);
        };
        check_frame_id(&self.topics.colour, &colour.header, &self.frame_id)?;
        let stamp = colour.header.stamp;
        let capture =
            ros_stamp_to_monotonic_ns(stamp.sec, stamp.nanosec, received, &self.topics.stamp)?;
        // Give the depth image of this stamp a moment to arrive.
        let wait_depth = Instant::now() + Duration::from_millis(50);
        while self.paired_depth(&colour).is_err() && Instant::now() < wait_depth {
            std::thread::sleep(Duration::from_millis(1));
            self.drain_side_topics();
        }
        // Without depth of the same moment every new box would be measured against the
        // table's old depth, a flat footprint (a tall obstacle published 1 mm high): refuse
        // the frame until fresh depth arrives.
        let depth = self.paired_depth(&colour).map_err(SourceError::Depth)?;
        let depth_m = Some(depth_from_msg(depth)?);
        self.sequence += 1;
        let bgr = colour_from_msg(&colour)?;
        let f = Frame {
            sequence: self.sequence,
            capture_time_ns: capture,
            bgr,
            depth_m,
        };
        f.validate()?;
        Ok(Some(f))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::error_chain::error_chain;

    #[test]
    fn the_source_is_loopback_only_unless_opened() {
        let t = Ros2Topics::default();
        assert_eq!(t.networks, ["127.0.0.1".parse::<IpAddr>().unwrap()]);
        t.validate(NetworkAccess::LoopbackOnly).unwrap();
        // A file without `networks` stays on loopback too.
        let parsed: Ros2Topics =
            toml::from_str("colour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\n").unwrap();
        assert_eq!(parsed.networks, loopback_only());
        assert_eq!(parsed.stamp, StampLimits::default());
        for networks in [
            vec![],
            vec!["192.168.1.20".parse().unwrap()],
            vec!["127.0.0.1".parse().unwrap(), "0.0.0.0".parse().unwrap()],
        ] {
            let open = Ros2Topics {
                networks,
                ..Ros2Topics::default()
            };
            let e = open.validate(NetworkAccess::LoopbackOnly).unwrap_err();
            assert!(matches!(e, Ros2TopicsError::NotLoopback { .. }), "{e:?}");
            let m = e.to_string();
            assert!(
                m.contains("networks") && m.contains("--ros2-open-network"),
                "{m}"
            );
            open.validate(NetworkAccess::Open).unwrap();
            // Opening the source itself refuses before touching DDS.
            let Err(e) = Ros2Source::open(&open, NetworkAccess::LoopbackOnly, "zed") else {
                panic!("a source open beyond loopback was created without the flag");
            };
            assert!(e.to_string().contains("networks"), "{e}");
        }
        let v6 = Ros2Topics {
            networks: vec!["::1".parse().unwrap()],
            ..Ros2Topics::default()
        };
        v6.validate(NetworkAccess::LoopbackOnly).unwrap();
    }

    #[test]
    fn topics_files_are_checked_with_the_field_named() {
        let dir = std::env::temp_dir().join(format!("foresight-ros2topics-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.toml");
        let base = "colour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\n";
        std::fs::write(&p, format!("{base}[stamp]\nmax_age_s = 5.0\n")).unwrap();
        let e = Ros2Topics::load(&p).unwrap_err().to_string();
        assert!(e.contains("stamp.max_age_s") && e.contains("t.toml"), "{e}");
        std::fs::write(&p, format!("{base}[stamp]\nmax_ahead_s = 0.01\n")).unwrap();
        let t = Ros2Topics::load(&p).unwrap();
        assert_eq!(t.stamp.max_ahead_s, 0.01);
        assert_eq!(t.stamp.max_age_s, StampLimits::default().max_age_s);
        std::fs::write(&p, format!("{base}timeout_s = 0\n")).unwrap();
        let e = Ros2Topics::load(&p).unwrap_err().to_string();
        assert!(e.contains("timeout_s"), "{e}");
        std::fs::write(&p, format!("{base}max_age = 1\n")).unwrap();
        let e = Ros2Topics::load(&p).unwrap_err().to_string();
        assert!(e.contains("max_age") && e.contains("t.toml"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Issue 25 item 3: colour and depth are paired by stamp within the bound, never with
    /// a depth image of another time.
    #[test]
    fn colour_pairs_with_the_nearest_depth_stamp_within_the_bound() {
        let ms = 1_000_000i128;
        let t0 = 1_700_000_000_000_000_000i128;
        // The same stamp, and the nearest of several.
        assert_eq!(
            pair_depth(t0, [t0 - 33 * ms, t0, t0 + 17 * ms], 10 * ms),
            Ok(1)
        );
        assert_eq!(pair_depth(t0, [t0 - 8 * ms, t0 + 3 * ms], 10 * ms), Ok(1));
        assert_eq!(pair_depth(t0, [t0 + 10 * ms], 10 * ms), Ok(0));
        // A stalled depth topic: only depth from 2 s ago.
        assert_eq!(
            pair_depth(t0, [t0 - 2_100 * ms, t0 - 2_000 * ms], 10 * ms),
            Err(Some(2_000 * ms))
        );
        // Depth of the previous frame at 60 Hz is not this frame's.
        assert_eq!(pair_depth(t0, [t0 - 17 * ms], 10 * ms), Err(Some(17 * ms)));
        assert_eq!(pair_depth(t0, [], 10 * ms), Err(None));
        // 0 ms: exact stamps only.
        assert_eq!(pair_depth(t0, [t0 + 1], 0), Err(Some(1)));
        assert_eq!(pair_depth(t0, [t0], 0), Ok(0));
        assert_eq!(stamp_ns(Time { sec: 2, nanosec: 5 }), 2_000_000_005);
    }

    /// Issue 30 item 2: an image is used only when its `header.frame_id` is the
    /// calibration's camera.
    #[test]
    fn images_of_another_camera_are_refused_naming_both_frame_ids() {
        let header = |id: &str| Header {
            frame_id: id.to_owned(),
            ..Header::default()
        };
        check_frame_id("/c", &header("zed_left"), "zed_left").unwrap();
        for got in ["zed_right", "", "zed_left "] {
            let e = check_frame_id("/c", &header(got), "zed_left").unwrap_err();
            assert_eq!(
                e,
                WrongCameraError {
                    topic: "/c".into(),
                    got: got.into(),
                    expected: "zed_left".into()
                }
            );
            let m = error_chain(&SourceError::from(e)).to_string();
            assert!(
                m.contains("/c")
                    && m.contains(&format!("{got:?}"))
                    && m.contains("\"zed_left\"")
                    && m.contains("perception calibrate"),
                "{m}"
            );
        }
    }

    #[test]
    fn a_request_for_ros2_security_is_refused_not_ignored() {
        assert_eq!(check_ros_security(None), Ok(()));
        assert_eq!(check_ros_security(Some("false")), Ok(()));
        let e = check_ros_security(Some("true")).unwrap_err().to_string();
        assert!(
            e.contains("ROS_SECURITY_ENABLE=true") && e.contains("SROS2"),
            "{e}"
        );
    }

    #[test]
    fn domain_id_and_depth_skew_are_bounded() {
        let t = Ros2Topics::default();
        assert_eq!(t.domain_id, DEFAULT_DOMAIN_ID);
        assert_eq!(t.max_depth_skew_ms, 10.0);
        let parsed: Ros2Topics =
            toml::from_str("colour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\n").unwrap();
        assert_eq!(parsed.domain_id, DEFAULT_DOMAIN_ID);
        assert_eq!(parsed.max_depth_skew_ms, 10.0);
        for (field, value) in [
            ("domain_id", "102"),
            ("max_depth_skew_ms", "-1.0"),
            ("max_depth_skew_ms", "100.5"),
            ("max_depth_skew_ms", "nan"),
            ("max_depth_skew_ms", "inf"),
        ] {
            let e = toml::from_str::<Ros2Topics>(&format!(
                "colour = \"/c\"\ndepth = \"/d\"\ncamera_info = \"/i\"\n{field} = {value}\n"
            ))
            .unwrap()
            .validate(NetworkAccess::LoopbackOnly)
            .unwrap_err()
            .to_string();
            assert!(e.contains(field), "{field} = {value}: {e}");
        }
    }

    #[test]
    fn images_convert_and_bad_ones_are_refused() {
        let img = Image {
            height: 2,
            width: 3,
            encoding: "rgb8".into(),
            step: 10,
            data: (0..20).collect(),
            ..Default::default()
        };
        let m = colour_from_msg(&img).unwrap();
        assert_eq!((m.cols(), m.rows()), (3, 2));
        let px = m.at_2d::<opencv::core::Vec3b>(1, 0).unwrap();
        assert_eq!([px[0], px[1], px[2]], [12, 11, 10]);
        let short = Image {
            data: vec![0; 5],
            ..img.clone()
        };
        assert!(
            error_chain(&colour_from_msg(&short).unwrap_err())
                .to_string()
                .contains("bytes")
        );
        let odd = Image {
            encoding: "yuv422".into(),
            ..img
        };
        assert!(
            error_chain(&colour_from_msg(&odd).unwrap_err())
                .to_string()
                .contains("unsupported")
        );
        let depth = Image {
            height: 1,
            width: 2,
            encoding: "16UC1".into(),
            step: 4,
            data: vec![0xe8, 0x03, 0, 0],
            ..Default::default()
        };
        let d = depth_from_msg(&depth).unwrap();
        assert_eq!(*d.at_2d::<f32>(0, 0).unwrap(), 1.0);
        assert!(d.at_2d::<f32>(0, 1).unwrap().is_nan());
    }
}
