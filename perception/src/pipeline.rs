//! The perception pipeline: frame → detector → tracker → published `DetectionFrame`, and
//! the paced loop `perception run` drives. A bad frame is logged and skipped; the loop keeps
//! serving the next ones.

use std::time::{Duration, Instant};

use shm_schemas::DetectionFrame;

use crate::calibration::Calibration;
use crate::color_detector::{ColourDetector, DetectError};
use crate::detection::Detection;
use crate::frame::Frame;
use crate::publisher::{DetectionPublisher, PublishError};
use crate::source::{FrameSource, SourceError};
use crate::tracker::Tracker;
use crate::yolo::YoloDetector;

/// Either detector.
pub enum Detector {
    /// Per-class HSV thresholds.
    Colour(Box<ColourDetector>),
    /// A YOLOv8 ONNX model.
    Yolo(Box<YoloDetector>),
}

impl Detector {
    /// Runs the detector.
    ///
    /// # Errors
    /// [`DetectError`].
    pub fn detect(
        &mut self,
        frame: &Frame,
        calibration: Option<&Calibration>,
    ) -> Result<Vec<Detection>, DetectError> {
        match self {
            Self::Colour(d) => d.detect(frame, calibration),
            Self::Yolo(d) => d.detect(frame, calibration),
        }
    }
}

/// Why one frame could not be processed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Detection failed.
    #[error(transparent)]
    Detect(#[from] DetectError),
    /// Publishing failed.
    #[error(transparent)]
    Publish(#[from] PublishError),
}

/// Detector + calibration + tracker + publisher.
pub struct Pipeline {
    /// The detector.
    pub detector: Detector,
    /// The calibration.
    pub calibration: Calibration,
    /// The tracker.
    pub tracker: Tracker,
    /// The publisher.
    pub publisher: DetectionPublisher,
}

impl Pipeline {
    /// Processes one frame and publishes the resulting `DetectionFrame`.
    ///
    /// # Errors
    /// [`PipelineError`]; the tracker is not updated when detection fails.
    pub fn process(&mut self, frame: &Frame) -> Result<(DetectionFrame, bool), PipelineError> {
        let dets = self.detector.detect(frame, Some(&self.calibration))?;
        let changed = self.tracker.update(&dets);
        let objects = self.tracker.objects();
        let sent = self.publisher.publish(frame.capture_time_ns, &objects)?;
        Ok((sent, changed))
    }
}

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RunStats {
    /// Frames taken from the source (good or bad).
    pub frames: u64,
    /// Frames published.
    pub published: u64,
    /// Frames the source could not deliver.
    pub bad_frames: u64,
    /// Frames whose detection or publishing failed.
    pub failed: u64,
}

/// Runs the pipeline at `rate_hz` until the source ends, `max_frames` frames were taken,
/// or `stop()` returns true.
///
/// # Errors
/// Only when the source fails for good ([`SourceError::Failed`] ten times in a row).
pub fn run(
    source: &mut dyn FrameSource,
    pipeline: &mut Pipeline,
    rate_hz: f64,
    max_frames: Option<u64>,
    stop: &dyn Fn() -> bool,
) -> Result<RunStats, SourceError> {
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(0.01));
    let mut stats = RunStats::default();
    let mut next = Instant::now();
    let mut failures_in_row = 0;
    while !stop() && max_frames.is_none_or(|m| stats.frames < m) {
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
        next += period;
        if Instant::now() > next + period * 4 {
            next = Instant::now(); // fell far behind: do not burst
        }
        stats.frames += 1;
        let frame = match source.next_frame() {
            Ok(Some(f)) => {
                failures_in_row = 0;
                f
            }
            Ok(None) => break,
            Err(SourceError::Failed(m)) => {
                stats.bad_frames += 1;
                failures_in_row += 1;
                tracing::warn!("source failed: {m}");
                if failures_in_row >= 10 {
                    return Err(SourceError::Failed(m));
                }
                continue;
            }
            Err(e) => {
                stats.bad_frames += 1;
                tracing::warn!("skipping a bad frame: {e}");
                continue;
            }
        };
        match pipeline.process(&frame) {
            Ok((sent, changed)) => {
                stats.published += 1;
                if changed {
                    tracing::info!(
                        sequence = sent.sequence,
                        objects = sent.count,
                        "scene changed: {}",
                        sent.objects()
                            .iter()
                            .map(|o| format!(
                                "#{} class {} at ({:.3}, {:.3}, {:.3}) size ({:.3}, {:.3}, {:.3})",
                                o.object_id,
                                o.class,
                                o.center_m[0],
                                o.center_m[1],
                                o.center_m[2],
                                o.size_m[0],
                                o.size_m[1],
                                o.size_m[2]
                            ))
                            .collect::<Vec<_>>()
                            .join("; ")
                    );
                }
            }
            Err(e) => {
                stats.failed += 1;
                tracing::warn!(sequence = frame.sequence, "frame not processed: {e}");
            }
        }
    }
    Ok(stats)
}
