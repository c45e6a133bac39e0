//! The `perception` binary: `render`, `calibrate`, `detect` and `run` (see the crate docs
//! and perception/README.md). Thin: parses arguments and wires the library together.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use perception::annotate::{annotate, write_image};
use perception::calibration::{
    Calibration, CalibrationFile, DEFAULT_TAPE_HSV, HsvRange, find_workspace_corners,
};
use perception::color_detector::{ColourDetector, ColourDetectorConfig};
use perception::detection::DetectionReport;
use perception::frame::{Frame, read_colour, read_depth, write_depth};
use perception::geometry::Intrinsics;
use perception::pipeline::{Detector, Pipeline};
use perception::publisher::DetectionPublisher;
use perception::source::{FileSource, FrameSource, SourceSpec, SyntheticSource};
use perception::synthetic::SyntheticCamera;
use perception::tracker::{Tracker, TrackerConfig};
use perception::workspace::WorkspaceRect;
use perception::yolo::{YoloConfig, YoloDetector};
use shm_schemas::scene_file::{SceneFile, WorldScript};

/// A bundled perception asset: `$FORESIGHT_ASSETS/perception`, else `./assets/perception`
/// (the repository root is the working directory of `make demo`), else the source tree's
/// copy (a binary run from elsewhere on the build machine).
fn asset(name: &str) -> PathBuf {
    if let Some(dir) = std::env::var_os("FORESIGHT_ASSETS") {
        return Path::new(&dir).join("perception").join(name);
    }
    let local = Path::new("assets/perception").join(name);
    if local.exists() {
        return local;
    }
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/perception")).join(name)
}

#[derive(Parser)]
#[command(
    name = "perception",
    about = "Foresight perception: camera frames to goal/obstacle boxes in the twin's frame"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene (or a world script at a time) with the synthetic camera: colour PNG,
    /// depth TIFF (m), exact calibration and ground truth.
    Render {
        /// Scene file or world script.
        #[arg(long)]
        scene: PathBuf,
        /// Time into the world script (s).
        #[arg(long, default_value_t = 0.0)]
        at_s: f64,
        /// Synthetic camera description.
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
    /// Calibrate from the four workspace corners (given, or found from the tape): writes the
    /// calibration TOML and the rectified top view PNG.
    Calibrate {
        /// Colour image of the table.
        #[arg(long)]
        image: PathBuf,
        /// Corner pixels "u,v u,v u,v u,v" in the order (xmin,ymin) (xmin,ymax) (xmax,ymax)
        /// (xmax,ymin); found from the tape when absent.
        #[arg(long)]
        corners: Option<String>,
        /// TOML with an [intrinsics] table (and optionally [workspace]): a synthetic camera
        /// file or an earlier calibration.
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Workspace corner with the smallest x and y, "x,y" (m).
        #[arg(long)]
        workspace_min: Option<String>,
        /// Workspace size "dx,dy" (m).
        #[arg(long)]
        workspace_size: Option<String>,
        /// Table height (m).
        #[arg(long)]
        table_height: Option<f64>,
        /// Tape colour range "h,s,v-h,s,v" (OpenCV HSV scale).
        #[arg(long)]
        tape_hsv: Option<String>,
        /// Output calibration file.
        #[arg(long, default_value = "calibration.toml")]
        out: PathBuf,
        /// Output rectified view.
        #[arg(long, default_value = "rectified.png")]
        rectified: PathBuf,
    },
    /// Detect objects in one image; prints JSON and writes an annotated PNG.
    Detect {
        /// Colour image.
        #[arg(long)]
        image: PathBuf,
        /// Depth image (32-bit float TIFF in m, or 16-bit PNG in mm).
        #[arg(long)]
        depth: Option<PathBuf>,
        /// YOLOv8 ONNX model (else the colour detector).
        #[arg(long, requires = "labels")]
        model: Option<PathBuf>,
        /// Labels file of the model.
        #[arg(long)]
        labels: Option<PathBuf>,
        /// Calibration file.
        #[arg(long)]
        calibration: Option<PathBuf>,
        /// Colour detector configuration.
        #[arg(long)]
        detector: Option<PathBuf>,
        /// Annotated output image (default: IMAGE.annotated.png).
        #[arg(long)]
        annotated: Option<PathBuf>,
    },
    /// Run: frames from a source → detections → DetectionFrames over iceoryx2.
    Run {
        /// synthetic:WORLD.toml | file:PATH | ros2
        #[arg(long)]
        source: SourceSpec,
        /// Calibration file (synthetic source: derived exactly from the camera when absent).
        #[arg(long)]
        calibration: Option<PathBuf>,
        /// Service-name prefix.
        #[arg(long, default_value = "")]
        prefix: String,
        /// Frame rate (Hz).
        #[arg(long, default_value_t = 15.0)]
        rate: f64,
        /// Synthetic camera description.
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Stop after this many frames.
        #[arg(long)]
        frames: Option<u64>,
        /// Script time advances by 1/rate per frame instead of by wall-clock time.
        #[arg(long)]
        fixed_step: bool,
        /// Colour detector configuration.
        #[arg(long)]
        detector: Option<PathBuf>,
        /// YOLOv8 ONNX model (else the colour detector).
        #[arg(long, requires = "labels")]
        model: Option<PathBuf>,
        /// Labels file of the model.
        #[arg(long)]
        labels: Option<PathBuf>,
        /// Frames a change must persist before it is published.
        #[arg(long, default_value_t = 3)]
        persist_frames: u32,
        /// ROS 2 topics config (TOML); ZED wrapper names by default.
        #[arg(long)]
        ros2_topics: Option<PathBuf>,
        /// Camera id written into each DetectionFrame.
        #[arg(long, default_value_t = 0)]
        camera_id: u32,
    },
}

fn pair(s: &str, what: &str) -> Result<[f64; 2]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what}: expected \"a,b\", got {s:?}"))?;
    match v.as_slice() {
        [a, b] => Ok([*a, *b]),
        _ => bail!("{what}: expected two numbers, got {s:?}"),
    }
}

fn triple_u8(s: &str, what: &str) -> Result<[u8; 3]> {
    let v: Vec<u8> = s
        .split(',')
        .map(|x| x.trim().parse::<u8>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what}: expected \"h,s,v\", got {s:?}"))?;
    match v.as_slice() {
        [a, b, c] => Ok([*a, *b, *c]),
        _ => bail!("{what}: expected three numbers, got {s:?}"),
    }
}

fn load_world(path: &Path) -> Result<WorldScript> {
    match WorldScript::load(path) {
        Ok(w) => Ok(w),
        Err(e) => SceneFile::load(path)
            .map(WorldScript::single)
            .map_err(|_| anyhow::anyhow!("{e}"))
            .with_context(|| {
                format!(
                    "{} is neither a world script nor a scene file",
                    path.display()
                )
            }),
    }
}

/// The exact calibration of a synthetic camera for a scene's table.
fn synthetic_calibration(cam: &SyntheticCamera, scene: &SceneFile) -> Result<Calibration> {
    let corners = cam
        .workspace_corners_px(scene)
        .context("a workspace corner lies behind the synthetic camera")?;
    Ok(Calibration::new(CalibrationFile {
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(scene),
        corners_px: corners,
        rectified_px_per_m: 1000.0,
    })?)
}

fn load_detector(
    detector: Option<&Path>,
    model: Option<&Path>,
    labels: Option<&Path>,
) -> Result<Detector> {
    if let (Some(m), Some(l)) = (model, labels) {
        let y = YoloDetector::load(m, l, YoloConfig::default())?;
        if !y.rewritten_nodes.is_empty() {
            tracing::info!(
                "patched for OpenCV 4.6: {:?} (strides applied after inference)",
                y.rewritten_nodes
            );
        }
        return Ok(Detector::Yolo(Box::new(y)));
    }
    let cfg = match detector {
        Some(p) => ColourDetectorConfig::load(p)?,
        None => {
            let p = asset("colour_detector.toml");
            if p.is_file() {
                ColourDetectorConfig::load(&p)?
            } else {
                ColourDetectorConfig::default()
            }
        }
    };
    Ok(Detector::Colour(Box::new(
        ColourDetector::new(cfg).map_err(anyhow::Error::msg)?,
    )))
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,rustdds=warn,ros2_client=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Render {
            scene,
            at_s,
            camera,
            out,
        } => {
            let cam =
                SyntheticCamera::load(&camera.unwrap_or_else(|| asset("synthetic_camera.toml")))?;
            let world = load_world(&scene)?;
            let (_, s) = world.scene_at(at_s);
            let r = cam.render(s);
            let f = Frame::from_rendered(&r, 1, 0)?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            write_image(&out.join("colour.png"), &f.bgr).map_err(anyhow::Error::msg)?;
            if let Some(d) = &f.depth_m {
                write_depth(&out.join("colour.depth.tiff"), d)?;
            }
            std::fs::write(out.join("truth.toml"), s.to_toml_string())?;
            synthetic_calibration(&cam, s)?.save(&out.join("calibration.toml"))?;
            println!("{}", out.display());
        }
        Command::Calibrate {
            image,
            corners,
            camera,
            workspace_min,
            workspace_size,
            table_height,
            tape_hsv,
            out,
            rectified,
        } => {
            let cam_path = camera.unwrap_or_else(|| asset("synthetic_camera.toml"));
            let text = std::fs::read_to_string(&cam_path)
                .with_context(|| format!("reading {}", cam_path.display()))?;
            let value: toml::Table =
                toml::from_str(&text).with_context(|| format!("parsing {}", cam_path.display()))?;
            let intrinsics: Intrinsics = value
                .get("intrinsics")
                .cloned()
                .context("no [intrinsics] table")?
                .try_into()
                .with_context(|| format!("[intrinsics] of {}", cam_path.display()))?;
            let mut ws: Option<WorkspaceRect> = match value.get("workspace") {
                Some(w) => Some(
                    w.clone()
                        .try_into()
                        .with_context(|| format!("[workspace] of {}", cam_path.display()))?,
                ),
                None => None,
            };
            if let (Some(m), Some(s)) = (&workspace_min, &workspace_size) {
                ws = Some(WorkspaceRect {
                    min_xy_m: pair(m, "--workspace-min")?,
                    size_m: pair(s, "--workspace-size")?,
                    table_height_m: table_height.unwrap_or(0.0),
                });
            }
            let mut ws = ws.context(
                "no workspace: give --workspace-min and --workspace-size or a [workspace] table",
            )?;
            if let Some(t) = table_height {
                ws.table_height_m = t;
            }
            let bgr = read_colour(&image)?;
            let corners_px = match corners {
                Some(c) => {
                    let pts: Vec<[f64; 2]> = c
                        .split_whitespace()
                        .map(|p| pair(p, "--corners"))
                        .collect::<Result<_>>()?;
                    <[[f64; 2]; 4]>::try_from(pts).map_err(|v| {
                        anyhow::anyhow!("--corners: expected 4 points, got {}", v.len())
                    })?
                }
                None => {
                    let tape = match tape_hsv {
                        Some(s) => {
                            let (a, b) = s
                                .split_once('-')
                                .context("--tape-hsv: expected \"h,s,v-h,s,v\"")?;
                            HsvRange {
                                hsv_min: triple_u8(a, "--tape-hsv")?,
                                hsv_max: triple_u8(b, "--tape-hsv")?,
                            }
                        }
                        None => DEFAULT_TAPE_HSV,
                    };
                    find_workspace_corners(&bgr, tape)?
                }
            };
            let cal = Calibration::new(CalibrationFile {
                intrinsics,
                workspace: ws,
                corners_px,
                rectified_px_per_m: 1000.0,
            })?;
            cal.save(&out)?;
            write_image(&rectified, &cal.rectify(&bgr)?).map_err(anyhow::Error::msg)?;
            println!(
                "{{\"calibration\":{:?},\"rectified\":{:?},\"corners_px\":{:?},\"camera_eye_m\":{:?},\"reprojection_error_px\":{:.4}}}",
                out.display().to_string(),
                rectified.display().to_string(),
                cal.file.corners_px,
                cal.model.pose.eye_m().as_slice(),
                cal.reprojection_error_px
            );
        }
        Command::Detect {
            image,
            depth,
            model,
            labels,
            calibration,
            detector,
            annotated,
        } => {
            let mut det = load_detector(detector.as_deref(), model.as_deref(), labels.as_deref())?;
            let cal = calibration.map(|p| Calibration::load(&p)).transpose()?;
            let bgr = read_colour(&image)?;
            let depth_m = depth.map(|d| read_depth(&d)).transpose()?;
            let frame = Frame {
                sequence: 1,
                capture_time_ns: 0,
                bgr,
                depth_m,
            };
            let objects = det.detect(&frame, cal.as_ref())?;
            let out = annotated.unwrap_or_else(|| image.with_extension("annotated.png"));
            write_image(&out, &annotate(&frame.bgr, &objects)?).map_err(anyhow::Error::msg)?;
            println!("{}", serde_json::to_string(&DetectionReport { objects })?);
        }
        Command::Run {
            source,
            calibration,
            prefix,
            rate,
            camera,
            frames,
            fixed_step,
            detector,
            model,
            labels,
            persist_frames,
            ros2_topics,
            camera_id,
        } => {
            if !(rate.is_finite() && rate > 0.0 && rate <= 1000.0) {
                bail!("--rate {rate}: must be in (0, 1000] Hz");
            }
            let det = load_detector(detector.as_deref(), model.as_deref(), labels.as_deref())?;
            let (mut src, default_cal): (Box<dyn FrameSource>, Option<Calibration>) = match &source
            {
                SourceSpec::Synthetic(world) => {
                    let mut s = SyntheticSource::open(
                        &camera.unwrap_or_else(|| asset("synthetic_camera.toml")),
                        world,
                    )?;
                    if fixed_step {
                        s.fixed_step_s = Some(1.0 / rate);
                    }
                    let cal =
                        synthetic_calibration(&s.scripted.camera, &s.scripted.script.steps[0].1)?;
                    (Box::new(s), Some(cal))
                }
                SourceSpec::File(p) => (Box::new(FileSource::open(p)?), None),
                SourceSpec::Ros2 => {
                    let topics = match &ros2_topics {
                        Some(p) => perception::ros2_source::Ros2Topics::load(p)?,
                        None => perception::ros2_source::Ros2Topics::default(),
                    };
                    (
                        Box::new(perception::ros2_source::Ros2Source::open(&topics)?),
                        None,
                    )
                }
            };
            let calibration = match (calibration, default_cal) {
                (Some(p), _) => Calibration::load(&p)?,
                (None, Some(c)) => c,
                (None, None) => Calibration::load(&asset("calibration.toml"))
                    .context("no --calibration given and the default assets/perception/calibration.toml is unusable")?,
            };
            tracing::info!(
                "calibration: camera at {:?} m, corner reprojection error {:.3} px",
                calibration.model.pose.eye_m().as_slice(),
                calibration.reprojection_error_px
            );
            let tracker = Tracker::new(TrackerConfig {
                persist_frames,
                ..TrackerConfig::default()
            })
            .map_err(anyhow::Error::msg)?;
            let publisher = DetectionPublisher::open(&prefix, camera_id)?;
            let mut pipeline = Pipeline {
                detector: det,
                calibration,
                tracker,
                publisher,
            };
            tracing::info!(?source, prefix, rate, "publishing DetectionFrames");
            let stats =
                perception::pipeline::run(src.as_mut(), &mut pipeline, rate, frames, &|| false)?;
            tracing::info!(?stats, "done");
            println!(
                "{{\"frames\":{},\"published\":{},\"bad_frames\":{},\"failed\":{}}}",
                stats.frames, stats.published, stats.bad_frames, stats.failed
            );
        }
    }
    Ok(())
}
