//! `perception run`: the long-running process. Frames from a source (the synthetic camera
//! playing a world script, image files, or ROS 2 topics) go through the detector, the
//! calibration and the tracker; changes are published as `DetectionFrame`s over iceoryx2.
//! At the end (`--frames`, or a finite source) prints its counters as one JSON object
//! ([`perception::pipeline::RunStats`]: `frames`, `published`, `bad_frames`, `failed`,
//! `bad_stamps`, `unpaired_depth`, `wrong_camera`, `truncated_frames`, `dropped_objects`,
//! `goals_demoted`, `low_confidence_dropped`, `extra_goals`,
//! `frames_dropped_behind_detector`).
//!
//! Frames are taken by a capture thread at `--rate`; the detector works on the newest one
//! (a live source drops the oldest waiting frame when the detector is slower than the
//! camera; files and `--fixed-step` are played without loss, the capture waiting for the
//! detector): see [`perception::pipeline::run`].
//!
//! The ROS 2 source listens on loopback only unless `--ros2-open-network` is given (see
//! [`perception::ros2_source`]).
//!
//! A calibration belongs to one camera ([`perception::camera_id`]): `--source ros2` needs an
//! explicit `--calibration` made for that camera (never the bundled one, the synthetic
//! camera's, which is refused with it), and every colour image whose `header.frame_id` is
//! not the calibration's is refused and counted (`wrong_camera`). Both start-up refusals
//! come before DDS is touched. The synthetic source takes only the synthetic camera's
//! calibration (derived exactly when `--calibration` is left out); a `file:` recording takes
//! any, the bundled one when none is given.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use perception::calibration::Calibration;
use perception::camera_id::CameraKind;
use perception::pipeline::Pipeline;
use perception::publisher::DetectionPublisher;
use perception::ros2_source::{NetworkAccess, Ros2Source, Ros2Topics};
use perception::selection::SelectionConfig;
use perception::source::{FileSource, FrameSource, SourceSpec, SyntheticSource};
use perception::tracker::{Tracker, TrackerConfig};
use shm_schemas::cli_bounds::{f32_within, f64_within, int_within};

use super::shared::{YoloArgs, asset, load_detector, synthetic_calibration};

/// `perception run`
#[derive(Debug, Args)]
pub struct RunArgs {
    /// synthetic:WORLD.toml | file:PATH | ros2 (the ROS 2 camera topics; DDS on loopback
    /// only unless --ros2-open-network)
    #[arg(long)]
    source: SourceSpec,
    /// Calibration file, made for this camera (`[camera] frame_id`). Required with
    /// `--source ros2`; synthetic source: derived exactly from the camera when absent; a
    /// `file:` recording: the bundled (synthetic camera's) calibration when absent.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Service-name prefix.
    #[arg(long, default_value = "")]
    prefix: String,
    /// Frame rate (Hz).
    #[arg(long, default_value_t = 15.0, value_parser = f64_within(0.1, 1000.0), allow_negative_numbers = true)]
    rate: f64,
    /// Synthetic camera description.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Stop after this many frames.
    #[arg(long, value_parser = int_within(1u64, u64::MAX), allow_negative_numbers = true)]
    frames: Option<u64>,
    /// Script time advances by 1/rate per frame instead of by wall-clock time.
    #[arg(long)]
    fixed_step: bool,
    /// Colour detector configuration.
    #[arg(long)]
    detector: Option<PathBuf>,
    /// The YOLO model and engine (else the colour detector).
    #[command(flatten)]
    yolo: YoloArgs,
    /// Frames a change must persist before it is published.
    #[arg(long, default_value_t = 3, value_parser = int_within(1u32, 1000), allow_negative_numbers = true)]
    persist_frames: u32,
    /// Settled frames (`FRAME_SETTLED`, the only ones rt-core plans on): frames every object
    /// must have been confirmed with its box (1..=120).
    #[arg(long, default_value_t = TrackerConfig::default().settle_frames, value_parser = int_within(1u32, 120), allow_negative_numbers = true)]
    settle_frames: u32,
    /// Settled frames: capture time with nothing appearing, disappearing or moving (ms,
    /// 0..=2000; the default 100 delays a plan after a world change by 100–117 ms at 60 Hz).
    #[arg(long, default_value_t = TrackerConfig::default().settle_quiet_ms, value_parser = int_within(0u32, 2000), allow_negative_numbers = true)]
    settle_quiet_ms: u32,
    /// Settled frames: a measurement this far from its object's reported box is motion (m,
    /// from the tracker's noise tolerance, 0.005, to its jump threshold, 0.05).
    #[arg(long, default_value_t = TrackerConfig::default().settle_motion_m, value_parser = f64_within(0.005, 0.05), allow_negative_numbers = true)]
    settle_motion_m: f64,
    /// ROS 2 topics config (TOML: topic names, `domain_id`, `networks`, `timeout_s`,
    /// `[stamp] max_age_s / max_ahead_s`); ZED wrapper names by default.
    #[arg(long)]
    ros2_topics: Option<PathBuf>,
    /// Local address the ROS 2 camera source's DDS may use (repeatable; replaces the topics
    /// file's `networks`). Default: loopback only (127.0.0.1). A non-loopback address needs
    /// --ros2-open-network.
    #[arg(long = "ros2-network", value_name = "ADDR")]
    ros2_networks: Vec<std::net::IpAddr>,
    /// Let the ROS 2 camera source listen beyond loopback: on the addresses given (the
    /// camera PC's network), or on every interface when `networks = []`. Without it the
    /// source is loopback-only and no other host can send it camera images.
    #[arg(long)]
    ros2_open_network: bool,
    /// Confidence floors (TOML: `min_goal_confidence`, `min_obstacle_confidence`); the flags
    /// below override it.
    #[arg(long)]
    selection_config: Option<PathBuf>,
    /// A goal detection below this confidence is reported as an obstacle, not the goal
    /// (0.05..=1; default 0.5).
    #[arg(long, value_parser = f32_within(0.05, 1.0), allow_negative_numbers = true)]
    min_goal_confidence: Option<f32>,
    /// An obstacle detection below this confidence is left out (0..=0.25 and not above the
    /// goal floor; default 0.05): a doubtful obstacle is still reported.
    #[arg(long, value_parser = f32_within(0.0, 0.25), allow_negative_numbers = true)]
    min_obstacle_confidence: Option<f32>,
    /// Camera id written into each DetectionFrame.
    #[arg(long, default_value_t = 0, value_parser = int_within(0u32, u32::MAX), allow_negative_numbers = true)]
    camera_id: u32,
}

/// Builds the pipeline, runs it until the source ends or `--frames` frames, prints stats.
pub fn run(args: RunArgs) -> Result<()> {
    let rate = args.rate;
    if !(rate.is_finite() && rate > 0.0 && rate <= 1000.0) {
        bail!("--rate {rate}: must be in (0, 1000] Hz");
    }
    let selection = selection(&args)?;
    // Before the detector is loaded and the source opened (no DDS for a refused camera).
    let given_cal = given_calibration(&args)?;
    let detector = load_detector(args.detector.as_deref(), &args.yolo)?;
    let (mut src, calibration) = open_source(&args, given_cal)?;
    tracing::info!(
        "calibration of camera {:?}{} made {}: camera at {:?} m, corner reprojection error {:.3} px",
        calibration.file.camera.frame_id,
        calibration
            .file
            .camera
            .serial
            .as_ref()
            .map_or(String::new(), |s| format!(" (serial {s})")),
        calibration.file.camera.calibrated_at,
        calibration.model.pose.eye_m().as_slice(),
        calibration.reprojection_error_px
    );
    let tracker = Tracker::new(TrackerConfig {
        persist_frames: args.persist_frames,
        settle_frames: args.settle_frames,
        settle_quiet_ms: args.settle_quiet_ms,
        settle_motion_m: args.settle_motion_m,
        ..TrackerConfig::default()
    })
    .context("tracker settings")?;
    let publisher = DetectionPublisher::open(&args.prefix, args.camera_id)?;
    let mut pipeline = Pipeline {
        detector,
        calibration,
        selection,
        tracker,
        publisher,
    };
    tracing::info!(source = ?args.source, prefix = args.prefix, rate, "publishing DetectionFrames");
    let stats =
        perception::pipeline::run(src.as_mut(), &mut pipeline, rate, args.frames, &|| false)?;
    tracing::info!(?stats, "done");
    println!("{}", serde_json::to_string(&stats)?);
    Ok(())
}

/// The confidence floors: `--selection-config`, else the defaults, then the flags; checked.
fn selection(args: &RunArgs) -> Result<SelectionConfig> {
    let mut cfg = match &args.selection_config {
        Some(p) => SelectionConfig::load(p)?,
        None => SelectionConfig::default(),
    };
    if let Some(v) = args.min_goal_confidence {
        cfg.min_goal_confidence = v;
    }
    if let Some(v) = args.min_obstacle_confidence {
        cfg.min_obstacle_confidence = v;
    }
    cfg.validate().context("confidence floors")?;
    Ok(cfg)
}

/// `--calibration`, loaded and checked against the kind of source
/// ([`perception::camera_id::CalibrationCamera::check_use`]); a live camera (`--source
/// ros2`) without it is refused.
fn given_calibration(args: &RunArgs) -> Result<Option<Calibration>> {
    let kind = args.source.camera_kind();
    let Some(path) = &args.calibration else {
        if kind == CameraKind::Live {
            bail!(
                "--source ros2 needs --calibration FILE: a live camera is measured only with a \
                 calibration made for it (`perception calibrate --frame-id FRAME_ID …`, its \
                 [camera] frame_id checked against every image); the bundled \
                 assets/perception/calibration.toml is the synthetic camera's and is never used \
                 for a live camera (docs/real-arm.md, checklist step 3)"
            );
        }
        return Ok(None);
    };
    let cal = Calibration::load(path)?;
    cal.file
        .camera
        .check_use(kind)
        .with_context(|| format!("--calibration {}", path.display()))?;
    Ok(Some(cal))
}

/// The frame source and the calibration to use with it: `given` (checked by
/// [`given_calibration`]), else the synthetic camera's exact one, else (a `file:`
/// recording) the bundled one. The ROS 2 source refuses images of any camera but the
/// calibration's.
fn open_source(
    args: &RunArgs,
    given: Option<Calibration>,
) -> Result<(Box<dyn FrameSource>, Calibration)> {
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
            let cal = match given {
                Some(c) => c,
                None => synthetic_calibration(&s.scripted.camera, &s.scripted.script.steps[0].1)?,
            };
            (Box::new(s), cal)
        }
        SourceSpec::File(p) => {
            let src = FileSource::open(p)?;
            let cal = match given {
                Some(c) => c,
                None => {
                    let bundled = asset("calibration.toml");
                    tracing::info!(
                        "no --calibration: the recording is measured with the bundled synthetic camera's calibration {}",
                        bundled.display()
                    );
                    Calibration::load(&bundled).with_context(|| {
                        format!(
                            "no --calibration given and the bundled {} is unusable",
                            bundled.display()
                        )
                    })?
                }
            };
            (Box::new(src), cal)
        }
        SourceSpec::Ros2 => {
            let cal = given.context("--source ros2 needs --calibration FILE")?;
            let mut topics = match &args.ros2_topics {
                Some(p) => Ros2Topics::load(p)?,
                None => Ros2Topics::default(),
            };
            if !args.ros2_networks.is_empty() {
                topics.networks = args.ros2_networks.clone();
            }
            let access = if args.ros2_open_network {
                NetworkAccess::Open
            } else {
                NetworkAccess::LoopbackOnly
            };
            let src = Ros2Source::open(&topics, access, &cal.file.camera.frame_id)?;
            (Box::new(src), cal)
        }
    })
}
