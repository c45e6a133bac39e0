//! The perception pipeline: frame → detector → confidence floors → tracker → published
//! `DetectionFrame`, and the paced loop `perception run` drives. A bad frame is logged and
//! skipped; the loop keeps serving the next ones.
//!
//! What the loop counts ([`RunStats`], printed as JSON by `perception run` at the end):
//! frames published with objects left out (`truncated_frames`, `dropped_objects`: the frame
//! carries `dropped_count`, so rt-core refuses it and stops), images refused for their stamp
//! (`bad_stamps`), detections below the confidence floors (`goals_demoted`,
//! `low_confidence_dropped`) and goal tracks beyond the one goal (`extra_goals`). Repeated
//! warnings (truncation, refused stamps) are rate-limited ([`crate::log_limit`]).

use std::time::{Duration, Instant};

use serde::Serialize;
use shm_schemas::{DetectionFrame, MAX_DETECTIONS};

use crate::calibration::Calibration;
use crate::color_detector::{ColourDetector, DetectError};
use crate::detection::Detection;
use crate::frame::Frame;
use crate::log_limit::LogLimiter;
use crate::publisher::{DetectionPublisher, PublishError};
use crate::selection::{FloorTally, SelectionConfig, apply_confidence_floors};
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

/// Detector + calibration + confidence floors + tracker + publisher.
pub struct Pipeline {
    /// The detector.
    pub detector: Detector,
    /// The calibration.
    pub calibration: Calibration,
    /// The confidence floors (validate before use: [`SelectionConfig::validate`]).
    pub selection: SelectionConfig,
    /// The tracker.
    pub tracker: Tracker,
    /// The publisher.
    pub publisher: DetectionPublisher,
}

/// What one processed frame gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Processed {
    /// The frame sent (`dropped_count` > 0 when objects did not fit).
    pub sent: DetectionFrame,
    /// Whether the reported set changed.
    pub changed: bool,
    /// What the confidence floors did to this frame's detections.
    pub floors: FloorTally,
    /// Goal tracks beyond the chosen goal (merged or published as obstacles).
    pub extra_goals: u32,
}

impl Pipeline {
    /// Processes one frame and publishes the resulting `DetectionFrame`.
    ///
    /// # Errors
    /// [`PipelineError`]; the tracker is not updated when detection fails.
    pub fn process(&mut self, frame: &Frame) -> Result<Processed, PipelineError> {
        let mut dets = self.detector.detect(frame, Some(&self.calibration))?;
        let floors = apply_confidence_floors(&self.selection, &mut dets);
        let changed = self.tracker.update(&dets);
        let objects = self.tracker.objects();
        let built = self.publisher.publish(frame.capture_time_ns, &objects)?;
        Ok(Processed {
            sent: built.frame,
            changed,
            floors,
            extra_goals: built.goals_merged + built.goals_as_obstacles,
        })
    }
}

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct RunStats {
    /// Frames taken from the source (good or bad).
    pub frames: u64,
    /// Frames published.
    pub published: u64,
    /// Frames the source could not deliver (including `bad_stamps`).
    pub bad_frames: u64,
    /// Frames whose detection or publishing failed.
    pub failed: u64,
    /// Images refused for their capture stamp (zero, in the future, too old).
    pub bad_stamps: u64,
    /// Frames published with more objects seen than fit (`dropped_count` > 0: rt-core
    /// refuses them and stops).
    pub truncated_frames: u64,
    /// Objects left out of those frames, summed.
    pub dropped_objects: u64,
    /// Goal detections below `min_goal_confidence` reported as obstacles.
    pub goals_demoted: u64,
    /// Detections below `min_obstacle_confidence` left out.
    pub low_confidence_dropped: u64,
    /// Goal tracks beyond the one goal a frame carries, per frame, summed.
    pub extra_goals: u64,
}

impl RunStats {
    /// Counts one processed frame.
    pub fn count(&mut self, p: &Processed) {
        self.published += 1;
        if p.sent.dropped_count > 0 {
            self.truncated_frames += 1;
            self.dropped_objects += u64::from(p.sent.dropped_count);
        }
        self.goals_demoted += u64::from(p.floors.goals_demoted);
        self.low_confidence_dropped += u64::from(p.floors.dropped);
        self.extra_goals += u64::from(p.extra_goals);
    }
}

/// How often a repeated warning is logged.
const WARN_INTERVAL: Duration = Duration::from_secs(5);

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
    let mut truncation_log = LogLimiter::new(WARN_INTERVAL);
    let mut stamp_log = LogLimiter::new(WARN_INTERVAL);
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
            Err(SourceError::Stamp(e)) => {
                failures_in_row = 0;
                stats.bad_frames += 1;
                stats.bad_stamps += 1;
                if let Some(held_back) = stamp_log.allow(Instant::now()) {
                    tracing::warn!(
                        bad_stamps = stats.bad_stamps,
                        "image refused: {e} ({held_back} more refused since the last warning)"
                    );
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
            Ok(p) => {
                stats.count(&p);
                let sent = p.sent;
                if sent.dropped_count > 0
                    && let Some(held_back) = truncation_log.allow(Instant::now())
                {
                    tracing::warn!(
                        sequence = sent.sequence,
                        truncated_frames = stats.truncated_frames,
                        "{} objects seen, a frame holds {MAX_DETECTIONS}: published the nearest with dropped_count = {} (rt-core refuses it and stops) ({held_back} more such frames since the last warning)",
                        sent.count + sent.dropped_count,
                        sent.dropped_count
                    );
                }
                if p.changed {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::CalibrationFile;
    use crate::color_detector::ColourDetectorConfig;
    use crate::stamp::StampError;
    use crate::synthetic::SyntheticCamera;
    use crate::tracker::TrackerConfig;
    use shm_schemas::scene_file::SceneFile;

    /// Hands out the given results in order, then ends.
    struct Scripted(Vec<Result<Option<Frame>, SourceError>>);

    impl FrameSource for Scripted {
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            if self.0.is_empty() {
                return Ok(None);
            }
            self.0.remove(0)
        }
    }

    /// The goal and a 4 × 4 grid of low boxes: one object more than a frame holds.
    fn crowded() -> SceneFile {
        let mut s = String::from("[goal]\ncenter_m = [0.45, 0.27, 0.025]\nsize_m = 0.05\n");
        for x in [0.22, 0.33, 0.44, 0.55] {
            for y in [-0.28, -0.14, 0.0, 0.14] {
                s += &format!(
                    "[[obstacle]]\ncenter_m = [{x}, {y}, 0.015]\nsize_m = [0.04, 0.04, 0.03]\n"
                );
            }
        }
        SceneFile::from_toml_str(&s, std::path::Path::new("<crowded>")).unwrap()
    }

    #[test]
    fn refused_stamps_and_truncated_frames_are_counted() {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let cam = SyntheticCamera::load(&assets.join("perception/synthetic_camera.toml")).unwrap();
        let scene = crowded();
        let calibration = Calibration::new(CalibrationFile {
            intrinsics: cam.config.intrinsics,
            workspace: cam.workspace_for(&scene),
            corners_px: cam.workspace_corners_px(&scene).unwrap(),
            rectified_px_per_m: 1000.0,
        })
        .unwrap();
        let detector = ColourDetector::new(
            ColourDetectorConfig::load(&assets.join("perception/colour_detector.toml")).unwrap(),
        )
        .unwrap();
        let prefix = format!("percpipetest{}", std::process::id());
        let mut pipeline = Pipeline {
            detector: Detector::Colour(Box::new(detector)),
            calibration,
            selection: SelectionConfig::default(),
            tracker: Tracker::new(TrackerConfig {
                persist_frames: 1,
                ..TrackerConfig::default()
            })
            .unwrap(),
            publisher: DetectionPublisher::open(&prefix, 0).unwrap(),
        };
        let rendered = cam.render(&scene);
        let frame = |seq| Frame::from_rendered(&rendered, seq, crate::frame::monotonic_now_ns());
        let mut source = Scripted(vec![
            Err(SourceError::Stamp(StampError::Zero)),
            Ok(Some(frame(1).unwrap())),
            Err(SourceError::Stamp(StampError::TooOld {
                age_ms: 900.0,
                max_age_ms: 500.0,
            })),
            Ok(Some(frame(2).unwrap())),
        ]);
        let stats = run(&mut source, &mut pipeline, 1000.0, None, &|| false).unwrap();
        assert_eq!(
            stats,
            RunStats {
                frames: 5,
                published: 2,
                bad_frames: 2,
                failed: 0,
                bad_stamps: 2,
                truncated_frames: 2,
                dropped_objects: 2,
                goals_demoted: 0,
                low_confidence_dropped: 0,
                extra_goals: 0,
            }
        );
    }
}
