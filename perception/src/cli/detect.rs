//! `perception detect`: one colour image (optionally with depth and a calibration) through
//! the colour detector or a YOLOv8 model. Prints `{"objects":[…]}` (a
//! [`DetectionReport`]) and writes the image with the detections drawn on it.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use perception::annotate::{annotate, write_image};
use perception::calibration::Calibration;
use perception::detection::DetectionReport;
use perception::frame::{Frame, monotonic_now_ns, read_colour, read_depth};

use super::shared::load_detector;

/// `perception detect`
#[derive(Debug, Args)]
pub struct DetectArgs {
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
}

/// Detects, writes the annotated image and prints the report.
pub fn run(args: DetectArgs) -> Result<()> {
    let mut det = load_detector(
        args.detector.as_deref(),
        args.model.as_deref(),
        args.labels.as_deref(),
    )?;
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
    let out = args
        .annotated
        .unwrap_or_else(|| args.image.with_extension("annotated.png"));
    write_image(&out, &annotate(&frame.bgr, &objects)?)?;
    println!("{}", serde_json::to_string(&DetectionReport { objects })?);
    Ok(())
}
