//! Foresight's perception: camera frames to goal and obstacle positions in the twin's frame,
//! published over iceoryx2 as `DetectionFrame`s.
//!
//! ```text
//! source → Frame (BGR + depth m) → detector (colour | YOLOv8) → measure → tracker → publisher
//! ```
//!
//! Where to start reading: [`pipeline`] (one frame end to end, and the loop of
//! `perception run`: a capture thread paced at the frame rate, [`handoff`] to the detector),
//! then [`color_detector`] and [`calibration`]. The binary
//! (`src/main.rs`, one file per subcommand under `src/cli/`) only parses arguments and wires
//! these modules together.
//!
//! - Frames in: [`frame`] (the [`frame::Frame`] type, image and depth file I/O); [`source`]
//!   (synthetic, file and ROS 2 sources behind [`source::FrameSource`]); [`ros2_source`]
//!   (`sensor_msgs` topics, ZED wrapper names by default); [`synthetic`] (a ray-cast camera
//!   rendering scene files with exact depth and ground truth).
//! - Geometry: [`geometry`] (intrinsics, camera pose, project / unproject); [`workspace`]
//!   (the taped rectangle on the table); [`calibration`] (that rectangle → homography and
//!   camera pose, TOML save/load); [`camera_id`] (the camera a calibration belongs to:
//!   `[camera] frame_id`, checked against the source).
//! - Detection: [`color_detector`] (per-class HSV thresholds + depth); [`runs`] (run-based
//!   connected components); [`measure`] (a blob with depth → position, footprint, height);
//!   [`yolo`] (YOLOv8 / YOLO11 / NMS-free ONNX exports on ONNX Runtime or OpenCV DNN) and
//!   [`onnx_patch`] (model metadata; the OpenCV 4.6 patch); [`detection`] (the
//!   [`detection::Detection`] every detector returns).
//! - Out: [`selection`] (confidence floors, the one goal, nearest obstacles first);
//!   [`tracker`] (stable ids, debouncing); [`publisher`] (`DetectionFrame`s over iceoryx2,
//!   `dropped_count` when objects did not fit); [`annotate`] (detections drawn on the image).
//! - Time: every frame carries its capture time on `CLOCK_MONOTONIC`, never 0; [`stamp`]
//!   converts a ROS 2 camera's `header.stamp` and refuses zero, future and stale stamps.
//!   [`log_limit`] rate-limits repeated warnings.
//!
//! Errors are typed per operation (`thiserror` enums such as
//! [`tracker::TrackerConfigError`] or [`calibration::CalibrationError`]), each message
//! naming the offending field or file; `anyhow` appears only in the binary.
//!
//! ```no_run
//! use perception::{calibration::Calibration, color_detector::*, frame::Frame, synthetic::SyntheticCamera};
//! let cam = SyntheticCamera::load("assets/perception/synthetic_camera.toml".as_ref())?;
//! let cal = Calibration::load("assets/perception/calibration.toml".as_ref())?;
//! let scene = shm_schemas::scene_file::SceneFile::load("assets/scenes/small_box.toml".as_ref())?;
//! let frame = Frame::from_rendered(&cam.render(&scene), 0, 0)?;
//! let mut det = ColourDetector::new(ColourDetectorConfig::default())?;
//! for d in det.detect(&frame, Some(&cal))? {
//!     println!("{} at {:?} m, size {:?} m", d.kind.name(), d.position_m, d.size_m);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![forbid(unsafe_code)]

pub mod annotate;
pub mod calibration;
pub mod camera_id;
pub mod color_detector;
pub mod detection;
pub mod frame;
pub mod geometry;
pub mod handoff;
pub mod log_limit;
pub mod measure;
pub mod onnx_patch;
pub mod pipeline;
pub mod publisher;
pub mod ros2_source;
pub mod runs;
pub mod selection;
pub mod source;
pub mod stamp;
pub mod synthetic;
pub mod tracker;
pub mod workspace;
pub mod yolo;
