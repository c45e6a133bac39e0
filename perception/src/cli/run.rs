//! `perception run`: the long-running process. Frames from a source (the synthetic camera
//! playing a world script, image files, or ROS 2 topics) go through the detector, the
//! calibration and the tracker; changes are published as `DetectionFrame`s over iceoryx2.
//! At the end (`--frames`, or a finite source) prints
//! `{"frames","published","bad_frames","failed"}`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use perception::calibration::Calibration;
use perception::pipeline::Pipeline;
use perception::publisher::DetectionPublisher;
use perception::ros2_source::{Ros2Source, Ros2Topics};
use perception::source::{FileSource, FrameSource, SourceSpec, SyntheticSource};
use perception::tracker::{Tracker, TrackerConfig};

use super::shared::{asset, load_detector, synthetic_calibration};

/// `perception run`
#[derive(Debug, Args)]
pub struct RunArgs {
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
}

/// Builds the pipeline, runs it until the source ends or `--frames` frames, prints stats.
pub fn run(args: RunArgs) -> Result<()> {
    let rate = args.rate;
    if !(rate.is_finite() && rate > 0.0 && rate <= 1000.0) {
        bail!("--rate {rate}: must be in (0, 1000] Hz");
    }
    let detector = load_detector(
        args.detector.as_deref(),
        args.model.as_deref(),
        args.labels.as_deref(),
    )?;
    let (mut src, default_cal) = open_source(&args)?;
    let calibration = calibration(&args, default_cal)?;
    tracing::info!(
        "calibration: camera at {:?} m, corner reprojection error {:.3} px",
        calibration.model.pose.eye_m().as_slice(),
        calibration.reprojection_error_px
    );
    let tracker = Tracker::new(TrackerConfig {
        persist_frames: args.persist_frames,
        ..TrackerConfig::default()
    })?;
    let publisher = DetectionPublisher::open(&args.prefix, args.camera_id)?;
    let mut pipeline = Pipeline {
        detector,
        calibration,
        tracker,
        publisher,
    };
    tracing::info!(source = ?args.source, prefix = args.prefix, rate, "publishing DetectionFrames");
    let stats =
        perception::pipeline::run(src.as_mut(), &mut pipeline, rate, args.frames, &|| false)?;
    tracing::info!(?stats, "done");
    println!(
        "{{\"frames\":{},\"published\":{},\"bad_frames\":{},\"failed\":{}}}",
        stats.frames, stats.published, stats.bad_frames, stats.failed
    );
    Ok(())
}

/// The frame source; for the synthetic camera also its exact calibration.
fn open_source(args: &RunArgs) -> Result<(Box<dyn FrameSource>, Option<Calibration>)> {
    Ok(match &args.source {
        SourceSpec::Synthetic(world) => {
            let camera = args
                .camera
                .clone()
                .unwrap_or_else(|| asset("synthetic_camera.toml"));
            let mut s = SyntheticSource::open(&camera, world)?;
            if args.fixed_step {
                s.fixed_step_s = Some(1.0 / args.rate);
            }
            let cal = synthetic_calibration(&s.scripted.camera, &s.scripted.script.steps[0].1)?;
            (Box::new(s), Some(cal))
        }
        SourceSpec::File(p) => (Box::new(FileSource::open(p)?), None),
        SourceSpec::Ros2 => {
            let topics = match &args.ros2_topics {
                Some(p) => Ros2Topics::load(p)?,
                None => Ros2Topics::default(),
            };
            (Box::new(Ros2Source::open(&topics)?), None)
        }
    })
}

/// `--calibration`, else the source's own, else the bundled one.
fn calibration(args: &RunArgs, from_source: Option<Calibration>) -> Result<Calibration> {
    Ok(match (&args.calibration, from_source) {
        (Some(p), _) => Calibration::load(p)?,
        (None, Some(c)) => c,
        (None, None) => Calibration::load(&asset("calibration.toml")).context(
            "no --calibration given and the default assets/perception/calibration.toml is unusable",
        )?,
    })
}
