//! Foresight's perception: camera frames to goal and obstacle positions in the twin's frame,
//! published over iceoryx2 as `DetectionFrame`s.
//!
//! - [`synthetic`]: a synthetic camera rendering scene files (colour, depth, exact ground truth);
//! - [`calibration`]: the taped workspace rectangle → homography and camera pose;
//! - [`color_detector`]: per-class HSV thresholds + depth → boxes in the twin's frame;
//! - [`measure`]: a blob of pixels with depth → position, footprint and height.
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

pub mod annotate;
pub mod calibration;
pub mod color_detector;
pub mod detection;
pub mod frame;
pub mod geometry;
pub mod measure;
pub mod onnx_patch;
pub mod pipeline;
pub mod publisher;
pub mod ros2_source;
pub mod runs;
pub mod source;
pub mod synthetic;
pub mod tracker;
pub mod workspace;
pub mod yolo;
