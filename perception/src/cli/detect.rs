//! `perception detect`: one colour image (optionally with depth and a calibration) through
//! the colour detector or a YOLO model. Prints `{"objects":[…]}` (a [`DetectionReport`]) and
//! writes the image with the detections drawn on it. With `--repeat N` the detection runs N
//! times in the same process (after one warm-up run) and the JSON gains `timing`: the engine,
//! the model's input size and the per-frame time (median, p95, min, max in ms) — letterbox,
//! inference, decoding, NMS and the 3D measurement, i.e. everything `detect` does per frame.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use clap::Args;
use perception::annotate::{annotate, write_image};
use perception::calibration::Calibration;
use perception::detection::Detection;
use perception::frame::{Frame, read_colour, read_depth};
use perception::pipeline::Detector;
use serde::Serialize;
use shm_schemas::cli_bounds::int_within;
use shm_schemas::clock::monotonic_now_ns;

use super::shared::{YoloArgs, load_detector};

/// `perception detect`
#[derive(Debug, Args)]
pub struct DetectArgs {
    /// Colour image.
    #[arg(long)]
    image: PathBuf,
    /// Depth image (32-bit float TIFF in m, or 16-bit PNG in mm).
    #[arg(long)]
    depth: Option<PathBuf>,
    /// The YOLO model and engine (else the colour detector).
    #[command(flatten)]
    yolo: YoloArgs,
    /// Calibration file.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Colour detector configuration.
    #[arg(long)]
    detector: Option<PathBuf>,
    /// Annotated output image (default: IMAGE.annotated.png).
    #[arg(long)]
    annotated: Option<PathBuf>,
    /// Run the detection this many times (after one warm-up) and print the per-frame timing.
    #[arg(long, default_value_t = 1, value_parser = int_within(0u32, 1_000_000), allow_negative_numbers = true)]
    repeat: u32,
}

/// Per-frame timing of `--repeat`.
#[derive(Debug, Serialize)]
struct Timing {
    /// `colour`, `ort` or `opencv`.
    backend: &'static str,
    /// The network's input size (px); 0 for the colour detector.
    input_px: i32,
    /// Timed runs.
    runs: u32,
    median_ms: f64,
    p95_ms: f64,
    min_ms: f64,
    max_ms: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    objects: Vec<Detection>,
    #[serde(skip_serializing_if = "Option::is_none")]
    timing: Option<Timing>,
}

/// The `q`-quantile of sorted values (nearest rank).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Detects, writes the annotated image and prints the report.
pub fn run(args: DetectArgs) -> Result<()> {
    if args.repeat == 0 || args.repeat > 100_000 {
        bail!("--repeat = {} must be in 1..=100000", args.repeat);
    }
    let mut det = load_detector(args.detector.as_deref(), &args.yolo)?;
    let cal = args
        .calibration
        .as_deref()
        .map(Calibration::load)
        .transpose()?;
    let frame = Frame {
        sequence: 1,
        capture_time_ns: monotonic_now_ns(),
        bgr: read_colour(&args.image)?,
        depth_m: args.depth.as_deref().map(read_depth).transpose()?,
    };
    let objects = det.detect(&frame, cal.as_ref())?;
    let timing = if args.repeat > 1 {
        let mut ms = Vec::with_capacity(args.repeat as usize);
        for _ in 0..args.repeat {
            let t = Instant::now();
            let again = det.detect(&frame, cal.as_ref())?;
            ms.push(t.elapsed().as_secs_f64() * 1e3);
            if again.len() != objects.len() {
                bail!(
                    "the detector is not deterministic: {} objects, then {}",
                    objects.len(),
                    again.len()
                );
            }
        }
        ms.sort_by(f64::total_cmp);
        let (backend, input_px) = match &det {
            Detector::Colour(_) => ("colour", 0),
            Detector::Yolo(y) => (y.backend_name(), y.input_px()),
        };
        Some(Timing {
            backend,
            input_px,
            runs: args.repeat,
            median_ms: quantile(&ms, 0.5),
            p95_ms: quantile(&ms, 0.95),
            min_ms: ms[0],
            max_ms: ms[ms.len() - 1],
        })
    } else {
        None
    };
    let out = args
        .annotated
        .unwrap_or_else(|| args.image.with_extension("annotated.png"));
    write_image(&out, &annotate(&frame.bgr, &objects)?)?;
    println!("{}", serde_json::to_string(&Report { objects, timing })?);
    Ok(())
}
