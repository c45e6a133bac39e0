//! ROS 2 frame source through `ros2-client`: colour image, depth image and camera info,
//! by default on the ZED ROS 2 wrapper's topics (configurable in TOML).
//!
//! DDS can be restricted to given local addresses (`networks = ["127.0.0.1"]`), through
//! `DomainParticipantBuilder::with_only_networks`, so tests and single-machine setups never
//! send multicast out of the machine's real interface. Discovery on loopback needs the
//! `MULTICAST` flag on `lo` (`ip link set lo multicast on`), which the test sets inside its
//! own network namespace.

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

use crate::frame::{Frame, FrameError, monotonic_now_ns};
use crate::source::{FrameSource, SourceError};

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

/// Topic names and DDS settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Topics {
    /// DDS domain.
    #[serde(default)]
    pub domain_id: u16,
    /// Local addresses DDS may use (empty: all, the rustdds default).
    #[serde(default)]
    pub networks: Vec<std::net::IpAddr>,
    /// Colour image topic.
    pub colour: String,
    /// Depth image topic (32FC1 metres or 16UC1 millimetres, registered to colour).
    pub depth: String,
    /// Camera info topic of the colour image.
    pub camera_info: String,
    /// Longest wait for a new colour image (s).
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
}

fn default_timeout_s() -> f64 {
    2.0
}

impl Default for Ros2Topics {
    /// The ZED ROS 2 wrapper's topics for a camera named `zed`.
    fn default() -> Self {
        Self {
            domain_id: 0,
            networks: Vec::new(),
            colour: "/zed/zed_node/rgb/image_rect_color".into(),
            depth: "/zed/zed_node/depth/depth_registered".into(),
            camera_info: "/zed/zed_node/rgb/camera_info".into(),
            timeout_s: default_timeout_s(),
        }
    }
}

impl Ros2Topics {
    /// Loads topic settings from TOML.
    ///
    /// # Errors
    /// [`SourceError::Open`].
    pub fn load(path: &Path) -> Result<Self, SourceError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SourceError::Open(format!("{}: {e}", path.display())))?;
        toml::from_str(&text).map_err(|e| SourceError::Open(format!("{}: {e}", path.display())))
    }
}

fn qos() -> QosProfile {
    use ros2_client::qos::{Durability, History};
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 2 })
}

/// Creates a ROS 2 context, restricted to `networks` when not empty.
///
/// # Errors
/// [`SourceError::Open`].
pub fn context(domain_id: u16, networks: &[std::net::IpAddr]) -> Result<Context, SourceError> {
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
            return Err(FrameError::BadColour(format!(
                "unsupported colour encoding {e:?}"
            )));
        }
    };
    let m =
        image_mat(msg, channels, 1, cv_type).map_err(|e| FrameError::BadColour(e.to_string()))?;
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
        "32FC1" => image_mat(msg, 1, 4, CV_32FC1).map_err(|e| FrameError::BadDepth(e.to_string())),
        "16UC1" | "mono16" => {
            let m =
                image_mat(msg, 1, 2, CV_16UC1).map_err(|e| FrameError::BadDepth(e.to_string()))?;
            let mut out = Mat::default();
            m.convert_to(&mut out, CV_32FC1, 1e-3, 0.0)?;
            for d in out.data_typed_mut::<f32>()?.iter_mut() {
                if *d <= 0.0 {
                    *d = f32::NAN;
                }
            }
            Ok(out)
        }
        e => Err(FrameError::BadDepth(format!(
            "unsupported depth encoding {e:?}"
        ))),
    }
}

/// Why a `sensor_msgs/Image` could not be copied into a `Mat`; each message names the field.
#[derive(Debug, thiserror::Error)]
pub enum ImageMsgConvertError {
    /// `is_bigendian` is set on a multi-byte encoding.
    #[error("is_bigendian = {is_bigendian}: big-endian {encoding} images are not supported")]
    BigEndian {
        /// The flag as received.
        is_bigendian: u8,
        /// The encoding.
        encoding: String,
    },
    /// `width` or `height` is 0.
    #[error("empty image (0 rows or columns): width = {width}, height = {height}")]
    Empty {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
    },
    /// `step` is shorter than a row or `data` shorter than the image.
    #[error(
        "{width}x{height} {encoding} image needs {row_bytes} bytes per row, got step {step} and {data_len} bytes"
    )]
    TooShort {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
        /// The encoding.
        encoding: String,
        /// Bytes one row needs.
        row_bytes: usize,
        /// `step` as received.
        step: u32,
        /// `data.len()` as received.
        data_len: usize,
    },
    /// OpenCV could not allocate or expose the `Mat`.
    #[error("OpenCV: {}", .0.message)]
    OpenCv(#[from] opencv::Error),
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

/// Frames from ROS 2 topics.
pub struct Ros2Source {
    _context: Context,
    _node: Node,
    colour: Subscription<Image>,
    depth: Subscription<Image>,
    info: Subscription<CameraInfo>,
    latest_depth: Option<Image>,
    /// Latest camera info received.
    pub latest_info: Option<CameraInfo>,
    timeout: Duration,
    sequence: u64,
    /// Topic names in use.
    pub topics: Ros2Topics,
    _path: Option<PathBuf>,
}

impl Ros2Source {
    /// Subscribes to the three topics.
    ///
    /// # Errors
    /// [`SourceError::Open`].
    pub fn open(topics: &Ros2Topics) -> Result<Self, SourceError> {
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
            latest_depth: None,
            latest_info: None,
            timeout: Duration::from_secs_f64(topics.timeout_s.clamp(0.01, 600.0)),
            sequence: 0,
            topics: topics.clone(),
            _path: None,
        })
    }

    fn drain_side_topics(&mut self) {
        while let Ok(Some((m, _))) = self.depth.take() {
            self.latest_depth = Some(m);
        }
        while let Ok(Some((m, _))) = self.info.take() {
            self.latest_info = Some(m);
        }
    }
}

impl FrameSource for Ros2Source {
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        let deadline = Instant::now() + self.timeout;
        let mut colour = None;
        loop {
            self.drain_side_topics();
            loop {
                match self.colour.take() {
                    Ok(Some((m, _))) => colour = Some(m),
                    Ok(None) => break,
                    Err(e) => return Err(SourceError::Failed(format!("colour topic: {e:?}"))),
                }
            }
            if colour.is_some() {
                break;
            }
            if Instant::now() >= deadline {
                return Err(SourceError::Failed(format!(
                    "no image on {} within {:.1} s",
                    self.topics.colour,
                    self.timeout.as_secs_f64()
                )));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let capture = monotonic_now_ns();
        // Give a depth image of the same stamp a moment to arrive.
        let Some(colour) = colour else {
            return Ok(None);
        };
        let wait_depth = Instant::now() + Duration::from_millis(50);
        while self
            .latest_depth
            .as_ref()
            .is_none_or(|d| d.header.stamp != colour.header.stamp)
            && Instant::now() < wait_depth
        {
            std::thread::sleep(Duration::from_millis(1));
            self.drain_side_topics();
        }
        self.sequence += 1;
        let bgr = colour_from_msg(&colour)?;
        let depth_m = match &self.latest_depth {
            Some(d) => Some(depth_from_msg(d)?),
            None => None,
        };
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
            colour_from_msg(&short)
                .unwrap_err()
                .to_string()
                .contains("bytes")
        );
        let odd = Image {
            encoding: "yuv422".into(),
            ..img
        };
        assert!(
            colour_from_msg(&odd)
                .unwrap_err()
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
