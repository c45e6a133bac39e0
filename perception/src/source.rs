//! Frame sources: the synthetic camera playing a world script, image files / folders /
//! videos, and ROS 2 topics ([`crate::ros2_source`]). A source hands out one [`Frame`] per
//! call; a bad frame is an error for that frame only — the next call moves on.

use shm_schemas::error_chain::error_chain;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use opencv::prelude::*;
use shm_schemas::scene_file::live::seconds_since;
use shm_schemas::scene_file::{LiveScene, WorldScript};

use crate::camera_id::CameraKind;
use crate::frame::{Frame, FrameError, read_colour, read_depth};
use crate::synthetic::{ScriptedCamera, SyntheticCamera};
use shm_schemas::clock::monotonic_now_ns;

/// Where frames come from, as given on the command line.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceSpec {
    /// `synthetic:WORLD.toml` (a world script, or a single scene file).
    Synthetic(PathBuf),
    /// `file:PATH` (an image, a folder of images, or a video).
    File(PathBuf),
    /// `ros2` (ZED wrapper topics by default).
    Ros2,
}

impl SourceSpec {
    /// What kind of camera this is, for the calibration it may use
    /// ([`crate::camera_id::CalibrationCamera::check_use`]).
    pub fn camera_kind(&self) -> CameraKind {
        match self {
            Self::Synthetic(_) => CameraKind::Synthetic,
            Self::File(_) => CameraKind::Recording,
            Self::Ros2 => CameraKind::Live,
        }
    }
}

impl FromStr for SourceSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(p) = s.strip_prefix("synthetic:") {
            return Ok(Self::Synthetic(p.into()));
        }
        if let Some(p) = s.strip_prefix("file:") {
            return Ok(Self::File(p.into()));
        }
        if s == "ros2" {
            return Ok(Self::Ros2);
        }
        Err(format!(
            "unknown source {s:?}: use synthetic:WORLD.toml, file:PATH or ros2"
        ))
    }
}

/// Why a source could not be opened or a frame obtained.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// A ROS 2 source could not open. (Text: the failures come from a dozen ros2_client
    /// and rustdds error types, several with only `Debug`.)
    #[error("cannot open source: {0}")]
    Open(String),
    /// The synthetic camera's description is refused.
    #[error("cannot open source")]
    Camera(#[source] crate::synthetic::SyntheticCameraLoadError),
    /// The synthetic camera's world (a script or a scene file) is refused.
    #[error("cannot open source")]
    World(#[source] shm_schemas::scene_file::SceneFileError),
    /// An image file, folder or video could not open.
    #[error("cannot open source: {}", .path.display())]
    Path {
        /// As given.
        path: PathBuf,
        /// What is wrong.
        #[source]
        problem: PathProblem,
    },
    /// This frame was bad; the source goes on.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// This frame's capture stamp was refused (zero, in the future, too old); the source
    /// goes on.
    #[error("image refused")]
    Stamp(#[from] crate::stamp::StampError),
    /// This colour image has no depth image of the same moment (none received, or only
    /// stale ones: [`crate::ros2_source::pair_depth`]); the source goes on.
    #[error("frame refused")]
    Depth(#[from] DepthPairError),
    /// This image comes from another camera than the calibration's (its `header.frame_id`
    /// differs: [`WrongCameraError`]); the source goes on.
    #[error("image refused")]
    WrongCamera(#[from] WrongCameraError),
    /// A transport failure.
    #[error("source failed")]
    Failed(#[source] SourceFailure),
}

/// What is wrong with an image file, folder or video given as a source.
#[derive(Debug, thiserror::Error)]
pub enum PathProblem {
    /// Neither a file nor a folder.
    #[error("no such file or folder")]
    Missing,
    /// The folder cannot be listed.
    #[error("the folder cannot be listed")]
    ReadDir(#[source] std::io::Error),
    /// The folder holds no image.
    #[error("no images in the folder")]
    NoImages,
    /// OpenCV refused the video.
    #[error("OpenCV refused the video")]
    Video(#[source] opencv::Error),
    /// OpenCV opened nothing.
    #[error("OpenCV cannot open this video")]
    VideoNotOpened,
}

/// Why a source gave no frame this time (the capture retries a few times in a row).
#[derive(Debug, thiserror::Error)]
pub enum SourceFailure {
    /// The synthetic camera has no render at hand.
    #[error("no render")]
    NoRender,
    /// A video frame could not be read.
    #[error("a video frame could not be read")]
    Video(#[source] opencv::Error),
    /// The colour topic could not be read.
    #[error("the colour topic could not be read")]
    ColourTopic(#[source] ros2_client::ReadError),
    /// No colour image arrived in time.
    #[error("no image on {topic} within {within_s:.1} s")]
    NoImage {
        /// The colour topic.
        topic: String,
        /// The wait (s).
        within_s: f64,
    },
    /// The capture thread could not start.
    #[error("cannot start the capture thread")]
    CaptureThread(#[source] std::io::Error),
}

/// A colour image from another camera than the calibration's: its `header.frame_id` is not
/// the calibration's `[camera] frame_id`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "the image on {topic} has header.frame_id {got:?}, but the calibration was made for camera \
     frame_id {expected:?}: a camera is measured only with its own calibration (calibrate this \
     camera with `perception calibrate --frame-id {got} …`, or publish the calibrated camera)"
)]
pub struct WrongCameraError {
    /// The colour topic.
    pub topic: String,
    /// The image's `header.frame_id`.
    pub got: String,
    /// The calibration's `[camera] frame_id`.
    pub expected: String,
}

/// Why a colour image has no depth image to be measured with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DepthPairError {
    /// No depth image has arrived (yet, or for longer than the kept history).
    #[error("no depth image received on {topic}")]
    NoDepth {
        /// The depth topic.
        topic: String,
    },
    /// The depth images at hand are from other times than the colour image (a stalled or
    /// lagging depth topic).
    #[error(
        "the depth image nearest in stamp on {topic} is {skew_ms:.1} ms from the colour image \
         (max_depth_skew_ms = {max_ms}): stale or unpaired depth"
    )]
    Stale {
        /// The depth topic.
        topic: String,
        /// The smallest stamp difference at hand (ms).
        skew_ms: f64,
        /// The bound (ms).
        max_ms: f64,
    },
}

fn open_path(path: &Path, problem: PathProblem) -> SourceError {
    SourceError::Path {
        path: path.to_path_buf(),
        problem,
    }
}

/// What the capture does with a new frame while the detector is still busy and the
/// hand-off to it is full ([`crate::handoff`], [`crate::pipeline::run`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WhenBusy {
    /// A live camera (ROS 2, the synthetic camera on wall-clock time): the oldest waiting
    /// frame is dropped and counted (`frames_dropped_behind_detector`), so the detector
    /// always works on the newest frame and the published scene is never stale by a backlog.
    DropOldest,
    /// A finite, replayable source (image files, a folder, a video, the synthetic camera
    /// with `--fixed-step`): the capture waits for the detector, every frame is processed
    /// (the run takes longer when the detector is slower than `--rate`).
    Wait,
}

/// Anything that yields frames. `perception run` takes frames on a capture thread of their
/// own, so a source must be `Send` (it is moved there, not shared).
pub trait FrameSource: Send {
    /// The next frame, `Ok(None)` at the end of a finite source, or an error for this
    /// frame only.
    ///
    /// # Errors
    /// [`SourceError`].
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError>;

    /// Drop the oldest frame or wait when the detector falls behind; a live camera by
    /// default.
    fn when_busy(&self) -> WhenBusy {
        WhenBusy::DropOldest
    }
}

/// The synthetic camera following a world script in real time (or frame-count time).
pub struct SyntheticSource {
    /// The camera and the script.
    pub scripted: ScriptedCamera,
    start: Option<Instant>,
    sequence: u64,
    /// When set, script time is `frame index / rate` instead of wall-clock time.
    pub fixed_step_s: Option<f64>,
    /// Index of the script step shown by the last frame.
    pub last_step: usize,
    /// The render of the step in force (a scene only changes at a script step), keyed by
    /// `(generation, step)`.
    cache: Option<((u64, usize), crate::synthetic::RenderedFrame)>,
    /// A single scene file watched for changes: path and last seen modification time. The
    /// launcher drives the world this way (it replaces the file atomically).
    live: Option<(PathBuf, Option<std::time::SystemTime>)>,
    /// When the live scene came into force (`CLOCK_MONOTONIC`, ns): the file's
    /// `in_force_since_monotonic_ns`, else when it was loaded. Its moving boxes are drawn at
    /// each frame's capture time counted from here, as the simulated arm places them.
    live_since_ns: u64,
    /// Bumped on every reload of the live scene file.
    generation: u64,
}

fn modified(path: &Path) -> Option<std::time::SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

impl SyntheticSource {
    /// Loads the camera and a world script (or a single scene file).
    ///
    /// # Errors
    /// [`SourceError::Camera`] / [`SourceError::World`].
    pub fn open(camera: &Path, world: &Path) -> Result<Self, SourceError> {
        let cam = SyntheticCamera::load(camera).map_err(SourceError::Camera)?;
        let mut live = None;
        let mut live_since_ns = 0;
        let script = match WorldScript::load(world) {
            Ok(s) => s,
            Err(script_err) => match LiveScene::load(world) {
                Ok(scene) => {
                    live = Some((world.to_path_buf(), modified(world)));
                    live_since_ns = scene.in_force_since_or(monotonic_now_ns());
                    WorldScript::single(scene.scene)
                }
                Err(_) => return Err(SourceError::World(script_err)),
            },
        };
        Ok(Self {
            scripted: ScriptedCamera {
                camera: cam,
                script,
            },
            start: None,
            sequence: 0,
            fixed_step_s: None,
            last_step: 0,
            cache: None,
            live,
            live_since_ns,
            generation: 0,
        })
    }

    /// For a single scene file: reloads it when its modification time changed. A file that
    /// is missing or invalid at that moment keeps the previous scene (logged once per
    /// change).
    fn reload_live_scene(&mut self) {
        let Some((path, seen)) = &mut self.live else {
            return;
        };
        let now = modified(path);
        if now == *seen {
            return;
        }
        *seen = now;
        match LiveScene::load(path) {
            Ok(live) => {
                tracing::info!(scene = %live.scene.name, "scene file changed; rendering the new scene");
                self.live_since_ns = live.in_force_since_or(monotonic_now_ns());
                self.scripted.script = WorldScript::single(live.scene);
                self.generation += 1;
            }
            Err(e) => {
                tracing::warn!(
                    "scene file changed but cannot be used, keeping the last scene: {}",
                    error_chain(&e)
                )
            }
        }
    }
}

impl FrameSource for SyntheticSource {
    /// With `fixed_step_s` script time is the frame index, so the frames form a fixed
    /// sequence: none is dropped ([`WhenBusy::Wait`]). On wall-clock time it is a live
    /// camera ([`WhenBusy::DropOldest`]).
    fn when_busy(&self) -> WhenBusy {
        if self.fixed_step_s.is_some() {
            WhenBusy::Wait
        } else {
            WhenBusy::DropOldest
        }
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        let start = *self.start.get_or_insert_with(Instant::now);
        let t_s = match self.fixed_step_s {
            Some(dt) => self.sequence as f64 * dt,
            None => start.elapsed().as_secs_f64(),
        };
        self.reload_live_scene();
        let capture = monotonic_now_ns();
        let (step, scene) = self.scripted.script.scene_at(t_s);
        let key = (self.generation, step);
        if scene.is_moving() {
            // Boxes on the move: every frame as the world stands at its capture time.
            let scene_t_s = match (&self.live, self.fixed_step_s) {
                (Some(_), None) => seconds_since(self.live_since_ns, capture),
                _ => t_s - self.scripted.script.steps.get(step).map_or(0.0, |s| s.0),
            };
            self.cache = Some((key, self.scripted.camera.render_at(scene, scene_t_s)));
        } else if self.cache.as_ref().is_none_or(|(k, _)| *k != key) {
            self.cache = Some((key, self.scripted.camera.render(scene)));
        }
        self.last_step = step;
        self.sequence += 1;
        let Some((_, rendered)) = &self.cache else {
            return Err(SourceError::Failed(SourceFailure::NoRender));
        };
        Ok(Some(Frame::from_rendered(
            rendered,
            self.sequence,
            capture,
        )?))
    }
}

const VIDEO_EXTENSIONS: [&str; 6] = ["mp4", "avi", "mkv", "mov", "webm", "m4v"];
const IMAGE_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "bmp", "tif", "tiff", "webp"];

/// The depth file that goes with colour image `X.ext`: `X.depth.tiff` or `X.depth.png`.
pub fn depth_companion(colour: &Path) -> Option<PathBuf> {
    let stem = colour.file_stem()?.to_string_lossy().into_owned();
    let dir = colour.parent().unwrap_or(Path::new("."));
    ["tiff", "tif", "png"]
        .iter()
        .map(|e| dir.join(format!("{stem}.depth.{e}")))
        .find(|p| p.is_file())
}

/// Images (with optional depth companions) or a video.
pub enum FileSource {
    /// A list of colour images played once in order.
    Images {
        /// The colour images.
        paths: Vec<PathBuf>,
        /// Next index.
        next: usize,
        /// Frames handed out.
        sequence: u64,
    },
    /// A video file.
    Video {
        /// OpenCV's reader.
        capture: opencv::videoio::VideoCapture,
        /// Frames handed out.
        sequence: u64,
    },
}

impl FileSource {
    /// Opens an image, a folder of images (sorted by name, depth companions skipped), or a
    /// video.
    ///
    /// # Errors
    /// [`SourceError::Path`].
    pub fn open(path: &Path) -> Result<Self, SourceError> {
        let ext = |p: &Path| {
            p.extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default()
        };
        if path.is_dir() {
            let mut paths: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| open_path(path, PathProblem::ReadDir(e)))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| IMAGE_EXTENSIONS.contains(&ext(p).as_str()))
                .filter(|p| {
                    !p.file_stem()
                        .is_some_and(|s| s.to_string_lossy().ends_with(".depth"))
                })
                .collect();
            paths.sort();
            if paths.is_empty() {
                return Err(open_path(path, PathProblem::NoImages));
            }
            return Ok(Self::Images {
                paths,
                next: 0,
                sequence: 0,
            });
        }
        if !path.is_file() {
            return Err(open_path(path, PathProblem::Missing));
        }
        if VIDEO_EXTENSIONS.contains(&ext(path).as_str()) {
            let capture = opencv::videoio::VideoCapture::from_file(path, opencv::videoio::CAP_ANY)
                .map_err(|e| open_path(path, PathProblem::Video(e)))?;
            if !capture.is_opened().unwrap_or(false) {
                return Err(open_path(path, PathProblem::VideoNotOpened));
            }
            return Ok(Self::Video {
                capture,
                sequence: 0,
            });
        }
        Ok(Self::Images {
            paths: vec![path.to_path_buf()],
            next: 0,
            sequence: 0,
        })
    }
}

impl FrameSource for FileSource {
    /// Files and videos are finite: every frame is processed ([`WhenBusy::Wait`]).
    fn when_busy(&self) -> WhenBusy {
        WhenBusy::Wait
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        match self {
            Self::Images {
                paths,
                next,
                sequence,
            } => {
                let Some(path) = paths.get(*next).cloned() else {
                    return Ok(None);
                };
                *next += 1;
                *sequence += 1;
                let capture = monotonic_now_ns();
                let bgr = read_colour(&path)?;
                let depth_m = match depth_companion(&path) {
                    Some(d) => Some(read_depth(&d)?),
                    None => None,
                };
                let f = Frame {
                    sequence: *sequence,
                    capture_time_ns: capture,
                    bgr,
                    depth_m,
                };
                f.validate()?;
                Ok(Some(f))
            }
            Self::Video { capture, sequence } => {
                let mut bgr = opencv::core::Mat::default();
                let ok = capture
                    .read(&mut bgr)
                    .map_err(|e| SourceError::Failed(SourceFailure::Video(e)))?;
                if !ok || bgr.empty() {
                    return Ok(None);
                }
                *sequence += 1;
                Ok(Some(Frame {
                    sequence: *sequence,
                    capture_time_ns: monotonic_now_ns(),
                    bgr,
                    depth_m: None,
                }))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::scene_file::SceneFile;

    /// The label the last frame's render gives the top face's centre of a 0.10 m box at `c`.
    fn label_at_top(src: &SyntheticSource, c: [f64; 3]) -> u8 {
        let cam = &src.scripted.camera;
        let (px, _) = cam.model.project([c[0], c[1], c[2] + 0.05]).unwrap();
        let (u, v) = (px[0].round() as usize, px[1].round() as usize);
        let f = &src.cache.as_ref().unwrap().1;
        f.label[v * f.width_px + u]
    }

    #[test]
    fn a_live_moving_box_is_drawn_at_the_capture_time_from_the_files_time_origin() {
        use crate::synthetic::{LABEL_OBSTACLE0, LABEL_TABLE};
        let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let dir = std::env::temp_dir().join(format!("foresight-moving-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let live = dir.join("live.toml");
        let scene = SceneFile::from_toml_str(
            "[goal]\ncenter_m = [0.40, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\n\
             center_m = [0.35, -0.2, 0.05]\nsize_m = [0.06, 0.06, 0.10]\n\
             path = [ { at_s = 30.0, center_m = [0.35, -0.2, 0.05] }, \
                      { at_s = 31.0, center_m = [0.35, 0.0, 0.05] } ]\n",
            Path::new("<inline>"),
        )
        .unwrap();
        let (start, end) = ([0.35, -0.2, 0.05], [0.35, 0.0, 0.05]);
        let camera = assets.join("perception/synthetic_camera.toml");
        // No time origin in the file: time counts from the load, the box has not set off.
        std::fs::write(&live, scene.to_toml_string()).unwrap();
        let mut src = SyntheticSource::open(&camera, &live).unwrap();
        src.next_frame().unwrap().unwrap();
        assert_eq!(label_at_top(&src, start), LABEL_OBSTACLE0);
        assert_eq!(label_at_top(&src, end), LABEL_TABLE);
        // In force since 100 s ago: every frame shows it at the end of its path.
        let since = monotonic_now_ns().saturating_sub(100_000_000_000);
        std::fs::write(&live, LiveScene::new(scene, since).to_toml_string()).unwrap();
        let mut src = SyntheticSource::open(&camera, &live).unwrap();
        for _ in 0..2 {
            src.next_frame().unwrap().unwrap();
            assert_eq!(label_at_top(&src, end), LABEL_OBSTACLE0);
            assert_eq!(label_at_top(&src, start), LABEL_TABLE);
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_live_scene_file_is_reloaded_when_it_changes() {
        let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let dir = std::env::temp_dir().join(format!("foresight-live-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let live = dir.join("live.toml");
        std::fs::copy(assets.join("scenes/small_box.toml"), &live).unwrap();
        let mut src =
            SyntheticSource::open(&assets.join("perception/synthetic_camera.toml"), &live).unwrap();
        let small = src.next_frame().unwrap().unwrap();
        let tall = SceneFile::load(&assets.join("scenes/tall_box.toml")).unwrap();
        // Replace atomically, as the launcher does, with a later modification time.
        let tmp = dir.join(".live.tmp");
        std::fs::write(&tmp, tall.to_toml_string()).unwrap();
        let later = std::time::SystemTime::now() + std::time::Duration::from_secs(2);
        std::fs::File::options()
            .write(true)
            .open(&tmp)
            .unwrap()
            .set_modified(later)
            .unwrap();
        std::fs::rename(&tmp, &live).unwrap();
        let after = src.next_frame().unwrap().unwrap();
        assert_eq!(
            src.scripted.script.steps[0].1, tall,
            "the new scene is in force"
        );
        let diff = opencv::core::norm2(
            &small.bgr,
            &after.bgr,
            opencv::core::NORM_L1,
            &opencv::core::no_array(),
        )
        .unwrap();
        assert!(diff > 0.0, "the frame shows the new scene");
        // A broken file keeps the last good scene.
        std::fs::write(&live, "not toml").unwrap();
        std::fs::File::options()
            .write(true)
            .open(&live)
            .unwrap()
            .set_modified(later + std::time::Duration::from_secs(2))
            .unwrap();
        assert!(src.next_frame().unwrap().is_some());
        assert_eq!(src.scripted.script.steps[0].1, tall);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn source_specs_parse() {
        assert_eq!(
            "synthetic:w.toml".parse::<SourceSpec>().unwrap(),
            SourceSpec::Synthetic("w.toml".into())
        );
        assert_eq!(
            "file:/a/b".parse::<SourceSpec>().unwrap(),
            SourceSpec::File("/a/b".into())
        );
        assert_eq!("ros2".parse::<SourceSpec>().unwrap(), SourceSpec::Ros2);
        assert!(
            "camera0"
                .parse::<SourceSpec>()
                .unwrap_err()
                .contains("unknown source")
        );
    }

    #[test]
    fn video_files_are_played_frame_by_frame() {
        use opencv::videoio::{VideoWriter, VideoWriterTrait};
        let dir = std::env::temp_dir().join(format!("foresight-video-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("clip.avi");
        let fourcc = VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap();
        let mut w = VideoWriter::new(
            path.to_str().unwrap(),
            fourcc,
            10.0,
            opencv::core::Size::new(64, 48),
            true,
        )
        .unwrap();
        assert!(w.is_opened().unwrap(), "OpenCV cannot write MJPG/AVI here");
        for i in 0..3 {
            let img = opencv::core::Mat::new_rows_cols_with_default(
                48,
                64,
                opencv::core::CV_8UC3,
                opencv::core::Scalar::all(f64::from(40 * i)),
            )
            .unwrap();
            w.write(&img).unwrap();
        }
        w.release().unwrap();
        let mut s = FileSource::open(&path).unwrap();
        for seq in 1..=3 {
            let f = s.next_frame().unwrap().unwrap();
            assert_eq!((f.bgr.cols(), f.bgr.rows(), f.sequence), (64, 48, seq));
            assert!(f.depth_m.is_none());
        }
        assert!(s.next_frame().unwrap().is_none());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_corrupt_image_fails_alone_and_the_folder_goes_on() {
        let dir = std::env::temp_dir().join(format!("foresight-src-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("a.png"), b"not a png").unwrap();
        let img = opencv::core::Mat::new_rows_cols_with_default(
            32,
            48,
            opencv::core::CV_8UC3,
            opencv::core::Scalar::all(9.0),
        )
        .unwrap();
        opencv::imgcodecs::imwrite(dir.join("b.png"), &img, &opencv::core::Vector::new()).unwrap();
        let mut s = FileSource::open(&dir).unwrap();
        let e = s.next_frame().unwrap_err();
        assert!(
            e.to_string().contains("a.png") && e.to_string().contains("corrupt"),
            "{e}"
        );
        let f = s.next_frame().unwrap().unwrap();
        assert_eq!((f.bgr.cols(), f.bgr.rows()), (48, 32));
        assert_eq!(f.sequence, 2);
        assert!(s.next_frame().unwrap().is_none());
        assert!(FileSource::open(&dir.join("nope")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
