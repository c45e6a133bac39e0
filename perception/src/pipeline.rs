//! The perception pipeline: frame → detector → confidence floors → tracker → published
//! `DetectionFrame`, and the loop `perception run` drives ([`run`]). A bad frame is logged
//! and skipped; the loop keeps serving the next ones. Each frame carries the tracker's
//! settled state (`FRAME_SETTLED`, see [`crate::tracker`]: never while an object moves), and
//! each object the tracker's velocity estimate of its centre with its 1-sigma uncertainty
//! (`velocity_m_s`, `velocity_sigma_m_s`; zero with 2 m/s for an object just confirmed); the
//! moment a scene settles is logged.
//!
//! The detector is off the capture path: a capture thread takes frames from the source at
//! the frame rate and hands them to the detector through a one-frame hand-off
//! ([`crate::handoff`]). A YOLO detector (30–120 ms a frame) is slower than a 60 Hz camera;
//! for a live source the oldest waiting frame is then dropped, so the detector always works
//! on the newest frame and the published scene lags the world by one detection, not by a
//! growing backlog. A finite source (files, `--fixed-step`) is played losslessly: its capture
//! waits for the detector ([`crate::source::WhenBusy`]).
//!
//! What the loop counts ([`RunStats`], printed as JSON by `perception run` at the end):
//! frames taken from the source (`frames`) and published (`published`), frames the source
//! could not deliver (`bad_frames`) or the detector/publisher failed on (`failed`), images
//! refused for their stamp (`bad_stamps`), colour images without a depth image of the same
//! moment (`unpaired_depth`: a stalled depth topic; the tracker's settled state then starts
//! over, [`Tracker::interrupt`], so no settled frame is published until depth is fresh
//! again and the quiet time has passed), colour images of another camera than the
//! calibration's (`wrong_camera`: their `header.frame_id` differs, [`crate::camera_id`];
//! logged as an error naming both ids, and the settled state starts over too), frames published with objects left out
//! (`truncated_frames`, `dropped_objects`: the frame carries `dropped_count`, so rt-core
//! refuses it and stops), detections below the confidence floors (`goals_demoted`,
//! `low_confidence_dropped`), goal tracks beyond the one goal (`extra_goals`) and good
//! frames dropped unseen because a newer one arrived while the detector was busy
//! (`frames_dropped_behind_detector`, live sources only). Repeated warnings (truncation,
//! refused stamps) are rate-limited ([`crate::log_limit`]); dropped frames are reported in an
//! info line at most every 10 s.

use shm_schemas::error_chain::error_chain;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use shm_schemas::{DetectionFrame, MAX_DETECTIONS};

use crate::calibration::Calibration;
use crate::color_detector::{ColourDetector, DetectError};
use crate::detection::Detection;
use crate::frame::Frame;
use crate::handoff::{ConsumerGuard, Handoff, Popped, ProducerGuard};
use crate::log_limit::LogLimiter;
use crate::publisher::{DetectionPublisher, PublishError};
use crate::selection::{FloorTally, SelectionConfig, apply_confidence_floors};
use crate::source::{FrameSource, SourceError, SourceFailure};
use crate::tracker::Tracker;
use crate::yolo::YoloDetector;
use shm_schemas::clock::monotonic_now_ns;

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
        let changed = self.tracker.update(&dets, frame.capture_time_ns);
        let objects = self.tracker.objects();
        let built =
            self.publisher
                .publish(frame.capture_time_ns, &objects, self.tracker.settled())?;
        Ok(Processed {
            sent: built.frame,
            changed,
            floors,
            extra_goals: built.goals_merged + built.goals_as_obstacles,
        })
    }
}

impl Pipeline {
    /// [`Pipeline::process`] after frames were refused at `interrupted_at_ns`
    /// (`CLOCK_MONOTONIC`; `None`: none since the last frame): the tracker's settled state
    /// starts over from then ([`Tracker::interrupt`]).
    ///
    /// # Errors
    /// As [`Pipeline::process`].
    pub fn process_after(
        &mut self,
        frame: &Frame,
        interrupted_at_ns: Option<u64>,
    ) -> Result<Processed, PipelineError> {
        if let Some(t) = interrupted_at_ns {
            self.tracker.interrupt(t);
        }
        self.process(frame)
    }
}

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct RunStats {
    /// Frames taken from the source (good or bad; the call that finds a finite source's
    /// end included). Every good frame is published, failed or dropped behind the
    /// detector; only a `stop()` may leave one waiting frame unprocessed.
    pub frames: u64,
    /// Frames published.
    pub published: u64,
    /// Frames the source could not deliver (including `bad_stamps`).
    pub bad_frames: u64,
    /// Frames whose detection or publishing failed.
    pub failed: u64,
    /// Images refused for their capture stamp (zero, in the future, too old).
    pub bad_stamps: u64,
    /// Colour images refused for want of a depth image of the same moment (none, or only
    /// stale ones: a stalled depth topic).
    pub unpaired_depth: u64,
    /// Images refused because they come from another camera than the calibration's (their
    /// `header.frame_id` is not its `[camera] frame_id`).
    pub wrong_camera: u64,
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
    /// Good frames never detected because a newer one arrived while they waited for the
    /// busy detector (live sources only: the oldest waiting frame is dropped, the detector
    /// works on the newest). 0 for finite sources, whose capture waits instead.
    pub frames_dropped_behind_detector: u64,
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

/// How often the frames dropped behind the detector are reported (an info line: a detector
/// slower than the camera drops frames all the time, by design).
const DROP_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// Frames the hand-off holds: one, the newest (or, for a finite source, the next).
const HANDOFF_CAPACITY: usize = 1;

/// How long the detector side waits for a frame before it looks at `stop()` again.
const POLL: Duration = Duration::from_millis(20);

/// Failures of the source in a row that end the run.
const MAX_FAILURES_IN_ROW: u32 = 10;

/// What the capture thread counts.
#[derive(Debug, Default)]
struct CaptureCounts {
    frames: u64,
    bad_frames: u64,
    bad_stamps: u64,
    unpaired_depth: u64,
    wrong_camera: u64,
}

/// Runs the pipeline until the source ends, `max_frames` frames were taken, or `stop()`
/// returns true.
///
/// Frames are taken from `source` by a capture thread of their own, paced at `rate_hz`, and
/// handed to the detector (this thread) through a one-frame hand-off ([`crate::handoff`]);
/// the source's [`when_busy`](FrameSource::when_busy) decides what a full hand-off does:
/// - a live source (`DropOldest`: ROS 2, the synthetic camera on wall-clock time) never
///   waits for the detector: a frame arriving while the previous one still waits replaces
///   it, the replaced one is counted in [`RunStats::frames_dropped_behind_detector`], and
///   the detector always starts on the newest frame there is;
/// - a finite source (`Wait`: files, a folder, a video, `--fixed-step`) makes the capture
///   wait instead, so every frame is processed (a slow detector makes the run longer, as a
///   single loop would). Dropping there would lose frames of a recording or of a
///   deterministic replay for nothing: nobody waits on them in real time.
///
/// The published frame carries the capture stamp of the frame that was detected. The
/// publisher, tracker and detector stay on the calling thread (iceoryx2's `ipc` publishers
/// are not `Send`); only the source moves. When this side stops (`max_frames`, `stop()`,
/// the source's end or failure) the capture thread is told, ends and is joined before
/// `run` returns (a source blocked in `next_frame` ends at its own time-out).
///
/// # Errors
/// Only when the source fails for good ([`SourceError::Failed`] ten times in a row); the
/// frames captured before are still processed.
pub fn run(
    source: &mut dyn FrameSource,
    pipeline: &mut Pipeline,
    rate_hz: f64,
    max_frames: Option<u64>,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<RunStats, SourceError> {
    run_with(
        source,
        &mut |f, interrupted_at_ns| pipeline.process_after(f, interrupted_at_ns),
        rate_hz,
        max_frames,
        stop,
    )
}

/// What processes one frame: the frame, and when frames were refused since the last one
/// (`CLOCK_MONOTONIC` ns of the latest refusal, for [`Tracker::interrupt`]).
type ProcessFn<'a> = dyn FnMut(&Frame, Option<u64>) -> Result<Processed, PipelineError> + 'a;

/// [`run`] with the processing of one frame given as a closure (tests slow it down).
fn run_with(
    source: &mut dyn FrameSource,
    process: &mut ProcessFn<'_>,
    rate_hz: f64,
    max_frames: Option<u64>,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<RunStats, SourceError> {
    let handoff = Handoff::new(HANDOFF_CAPACITY, source.when_busy());
    // When the capture last refused a frame for its depth (0: never).
    let interrupted_at_ns = AtomicU64::new(0);
    let mut stats = RunStats::default();
    let captured = std::thread::scope(|scope| {
        let capture = std::thread::Builder::new()
            .name("perception-capture".into())
            .spawn_scoped(scope, || {
                let _closes = ProducerGuard(&handoff);
                capture_loop(
                    source,
                    &handoff,
                    &interrupted_at_ns,
                    rate_hz,
                    max_frames,
                    stop,
                )
            })
            .map_err(|e| SourceError::Failed(SourceFailure::CaptureThread(e)))?;
        {
            let _closes = ConsumerGuard(&handoff);
            detect_loop(&handoff, &interrupted_at_ns, process, &mut stats, stop);
        }
        capture
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })?;
    stats.frames = captured.frames;
    stats.bad_frames = captured.bad_frames;
    stats.bad_stamps = captured.bad_stamps;
    stats.unpaired_depth = captured.unpaired_depth;
    stats.wrong_camera = captured.wrong_camera;
    stats.frames_dropped_behind_detector = handoff.dropped();
    Ok(stats)
}

/// The capture thread: takes frames from the source at `rate_hz` and hands them over until
/// the source ends, `max_frames` were taken, `stop()`, or the detector side has gone.
fn capture_loop(
    source: &mut dyn FrameSource,
    handoff: &Handoff<Frame>,
    interrupted_at_ns: &AtomicU64,
    rate_hz: f64,
    max_frames: Option<u64>,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<CaptureCounts, SourceError> {
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(0.01));
    let mut counts = CaptureCounts::default();
    let mut next = Instant::now();
    let mut failures_in_row = 0;
    let mut logs = RefusalLogs::new();
    let mut drop_log = LogLimiter::new(DROP_LOG_INTERVAL);
    while !stop() && max_frames.is_none_or(|m| counts.frames < m) {
        if !handoff.sleep_until(next) {
            break; // the detector side has stopped
        }
        next += period;
        if Instant::now() > next + period * 4 {
            next = Instant::now(); // fell far behind (or waited for the detector): do not burst
        }
        counts.frames += 1;
        let frame = match source.next_frame() {
            Ok(Some(f)) => {
                failures_in_row = 0;
                f
            }
            Ok(None) => break,
            Err(SourceError::Failed(m)) => {
                counts.bad_frames += 1;
                failures_in_row += 1;
                tracing::warn!("source failed: {}", error_chain(&m));
                if failures_in_row >= MAX_FAILURES_IN_ROW {
                    return Err(SourceError::Failed(m));
                }
                continue;
            }
            Err(e) => {
                logs.refused(e, &mut counts, &mut failures_in_row, interrupted_at_ns);
                continue;
            }
        };
        match handoff.push(frame) {
            Ok(0) => {}
            Ok(_) => {
                if let Some(held_back) = drop_log.allow(Instant::now()) {
                    tracing::info!(
                        frames_dropped_behind_detector = handoff.dropped(),
                        "the detector is slower than the camera: the oldest waiting frame is dropped, the newest detected ({held_back} more since the last report)"
                    );
                }
            }
            Err(_) => break, // the detector side has stopped
        }
    }
    Ok(counts)
}

/// The capture's rate-limited logs of refused frames, one per reason.
struct RefusalLogs {
    stamp: LogLimiter,
    depth: LogLimiter,
    camera: LogLimiter,
}

impl RefusalLogs {
    fn new() -> Self {
        Self {
            stamp: LogLimiter::new(WARN_INTERVAL),
            depth: LogLimiter::new(WARN_INTERVAL),
            camera: LogLimiter::new(WARN_INTERVAL),
        }
    }

    /// Counts and logs a frame the source refused (a bad stamp, depth not fresh, another
    /// camera's image, a bad frame); the capture goes on. A refused stamp, depth or camera
    /// ends a run of source failures (the source delivers); a stale depth or another camera
    /// also marks the stream interrupted now (no settled frame until it is quiet again).
    fn refused(
        &mut self,
        e: SourceError,
        counts: &mut CaptureCounts,
        failures_in_row: &mut u32,
        interrupted_at_ns: &AtomicU64,
    ) {
        match e {
            SourceError::Stamp(e) => {
                *failures_in_row = 0;
                counts.bad_frames += 1;
                counts.bad_stamps += 1;
                if let Some(held_back) = self.stamp.allow(Instant::now()) {
                    tracing::warn!(
                        bad_stamps = counts.bad_stamps,
                        "image refused: {} ({held_back} more refused since the last warning)",
                        error_chain(&e)
                    );
                }
            }
            SourceError::Depth(e) => {
                *failures_in_row = 0;
                counts.bad_frames += 1;
                counts.unpaired_depth += 1;
                interrupted_at_ns.fetch_max(monotonic_now_ns(), Ordering::AcqRel);
                if let Some(held_back) = self.depth.allow(Instant::now()) {
                    tracing::warn!(
                        unpaired_depth = counts.unpaired_depth,
                        "frame refused, no settled frame until depth is fresh again: {} ({held_back} more refused since the last warning)",
                        error_chain(&e)
                    );
                }
            }
            SourceError::WrongCamera(e) => {
                // Another camera publishes on our topic, or the calibration is not this
                // camera's: nothing it shows is measured, and no settled frame is published
                // until the calibrated camera's frames have been quiet again.
                *failures_in_row = 0;
                counts.bad_frames += 1;
                counts.wrong_camera += 1;
                interrupted_at_ns.fetch_max(monotonic_now_ns(), Ordering::AcqRel);
                if let Some(held_back) = self.camera.allow(Instant::now()) {
                    tracing::error!(
                        wrong_camera = counts.wrong_camera,
                        "image refused: {} ({held_back} more refused since the last error)",
                        error_chain(&e)
                    );
                }
            }
            e => {
                counts.bad_frames += 1;
                tracing::warn!("skipping a bad frame: {}", error_chain(&e));
            }
        }
    }
}

/// The detector side: processes and publishes the frames handed over until the capture
/// has ended and nothing is left, or `stop()`.
fn detect_loop(
    handoff: &Handoff<Frame>,
    interrupted_at_ns: &AtomicU64,
    process: &mut ProcessFn<'_>,
    stats: &mut RunStats,
    stop: &(dyn Fn() -> bool + Sync),
) {
    let mut truncation_log = LogLimiter::new(WARN_INTERVAL);
    let mut was_settled = false;
    let mut interruption_seen_ns = 0;
    while !stop() {
        let frame = match handoff.pop(POLL) {
            Popped::Item(f) => f,
            Popped::Empty => continue,
            Popped::Ended => break,
        };
        let interrupted = interrupted_at_ns.load(Ordering::Acquire);
        let since_last = (interrupted > interruption_seen_ns).then_some(interrupted);
        interruption_seen_ns = interrupted;
        match process(&frame, since_last) {
            Ok(p) => {
                stats.count(&p);
                let sent = p.sent;
                if sent.settled() != was_settled {
                    was_settled = sent.settled();
                    if was_settled {
                        tracing::info!(
                            sequence = sent.sequence,
                            objects = sent.count,
                            "scene settled (rt-core may approve a plan on it)"
                        );
                    } else {
                        tracing::debug!(sequence = sent.sequence, "scene no longer settled");
                    }
                }
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
                tracing::warn!(
                    sequence = frame.sequence,
                    "frame not processed: {}",
                    error_chain(&e)
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::CalibrationFile;
    use crate::color_detector::ColourDetectorConfig;
    use crate::source::WhenBusy;
    use crate::stamp::StampError;
    use crate::synthetic::SyntheticCamera;
    use crate::tracker::TrackerConfig;
    use iceoryx2::prelude::ipc;
    use shm_schemas::scene_file::SceneFile;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

    /// Hands out the given results in order, then ends. Finite: played losslessly.
    struct Scripted(Vec<Result<Option<Frame>, SourceError>>);

    impl FrameSource for Scripted {
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            if self.0.is_empty() {
                return Ok(None);
            }
            self.0.remove(0)
        }

        fn when_busy(&self) -> WhenBusy {
            WhenBusy::Wait
        }
    }

    /// A camera far faster than the detector: frames 1..=`n` of one rendered scene, frame
    /// `k` stamped `stamp(k)`; then the end (`ended` is set at that call, after frame `n`
    /// was handed over).
    struct FastCamera {
        rendered: crate::synthetic::RenderedFrame,
        n: u64,
        next: u64,
        when_busy: WhenBusy,
        ended: Arc<AtomicBool>,
    }

    fn stamp(k: u64) -> u64 {
        1_000_000_000 + 1_000 * k
    }

    impl FrameSource for FastCamera {
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            if self.next >= self.n {
                self.ended.store(true, Ordering::SeqCst);
                return Ok(None);
            }
            self.next += 1;
            Ok(Some(Frame::from_rendered(
                &self.rendered,
                self.next,
                stamp(self.next),
            )?))
        }

        fn when_busy(&self) -> WhenBusy {
            self.when_busy
        }
    }

    /// The synthetic camera, a goal and a box, the exact calibration and a colour pipeline
    /// publishing under `prefix`.
    fn small_scene_pipeline(prefix: &str) -> (crate::synthetic::RenderedFrame, Pipeline) {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        scene_pipeline(
            &SceneFile::load(&assets.join("scenes/small_box.toml")).unwrap(),
            prefix,
        )
    }

    /// `scene` rendered by the synthetic camera, with its exact calibration and a colour
    /// pipeline (new objects published after one frame) publishing under `prefix`.
    fn scene_pipeline(
        scene: &SceneFile,
        prefix: &str,
    ) -> (crate::synthetic::RenderedFrame, Pipeline) {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let cam = SyntheticCamera::load(&assets.join("perception/synthetic_camera.toml")).unwrap();
        let calibration = Calibration::new(CalibrationFile {
            camera: crate::camera_id::CalibrationCamera::synthetic(
                crate::camera_id::CalibratedAt::now(),
            ),
            intrinsics: cam.config.intrinsics,
            workspace: cam.workspace_for(scene),
            corners_px: cam.workspace_corners_px(scene).unwrap(),
            rectified_px_per_m: 1000.0,
        })
        .unwrap();
        let detector = ColourDetector::new(
            ColourDetectorConfig::load(&assets.join("perception/colour_detector.toml")).unwrap(),
        )
        .unwrap();
        let pipeline = Pipeline {
            detector: Detector::Colour(Box::new(detector)),
            calibration,
            selection: SelectionConfig::default(),
            tracker: Tracker::new(TrackerConfig {
                persist_frames: 1,
                ..TrackerConfig::default()
            })
            .unwrap(),
            publisher: DetectionPublisher::open(prefix, 0).unwrap(),
        };
        (cam.render(scene), pipeline)
    }

    #[test]
    fn a_slow_detector_gets_the_newest_frame_and_older_waiting_frames_are_dropped() {
        let prefix = format!("percslowdet{}", std::process::id());
        let (rendered, mut pipeline) = small_scene_pipeline(&prefix);
        let (node, _) =
            shm_schemas::services::create_node::<ipc::Service>("pipeline-test").unwrap();
        let sub =
            shm_schemas::services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
        let n = 30;
        let ended = Arc::new(AtomicBool::new(false));
        let mut camera = FastCamera {
            rendered,
            n,
            next: 0,
            when_busy: WhenBusy::DropOldest,
            ended: ended.clone(),
        };
        // (frame sequence, frame capture stamp, published capture stamp) per detection.
        let mut detected: Vec<(u64, u64, u64)> = Vec::new();
        let stats = run_with(
            &mut camera,
            &mut |f, _| {
                if detected.is_empty() {
                    // A detector busy on its first frame until the camera has delivered
                    // every frame and found its end: all but the newest must be dropped.
                    let t = Instant::now();
                    while !ended.load(Ordering::SeqCst) && t.elapsed() < Duration::from_secs(20) {
                        std::thread::sleep(Duration::from_millis(1));
                    }
                }
                let p = pipeline.process(f)?;
                detected.push((f.sequence, f.capture_time_ns, p.sent.capture_time_ns));
                Ok(p)
            },
            1000.0,
            None,
            &|| false,
        )
        .unwrap();
        assert!(ended.load(Ordering::SeqCst));
        assert_eq!(detected.len(), 2, "{detected:?}");
        let (first, last) = (detected[0], detected[1]);
        assert!(first.0 < n, "{detected:?}");
        assert_eq!(last.0, n, "the newest frame is detected last: {detected:?}");
        for (seq, captured, published) in &detected {
            assert_eq!(*captured, stamp(*seq));
            assert_eq!(
                published, captured,
                "frame {seq}: the published stamp is the detected frame's"
            );
        }
        assert_eq!(
            stats,
            RunStats {
                frames: n + 1,
                published: 2,
                frames_dropped_behind_detector: n - 2,
                ..RunStats::default()
            }
        );
        // What a subscriber receives: the two detections, in order, with those stamps.
        let mut received = Vec::new();
        while let Ok(Some(s)) = sub.receive() {
            received.push(*s.payload());
        }
        assert_eq!(
            received
                .iter()
                .map(|f| (f.sequence, f.capture_time_ns, f.count))
                .collect::<Vec<_>>(),
            vec![(1, stamp(first.0), 2), (2, stamp(n), 2)]
        );
    }

    #[test]
    fn a_finite_source_waits_for_a_slow_detector_and_loses_nothing() {
        let prefix = format!("percslowfile{}", std::process::id());
        let (rendered, mut pipeline) = small_scene_pipeline(&prefix);
        let n = 8;
        let mut camera = FastCamera {
            rendered,
            n,
            next: 0,
            when_busy: WhenBusy::Wait,
            ended: Arc::new(AtomicBool::new(false)),
        };
        let mut detected = Vec::new();
        let stats = run_with(
            &mut camera,
            &mut |f, _| {
                std::thread::sleep(Duration::from_millis(15));
                detected.push(f.sequence);
                pipeline.process(f)
            },
            1000.0,
            None,
            &|| false,
        )
        .unwrap();
        assert_eq!(detected, (1..=n).collect::<Vec<_>>());
        assert_eq!(
            (
                stats.frames,
                stats.published,
                stats.frames_dropped_behind_detector
            ),
            (n + 1, n, 0)
        );
    }

    #[test]
    fn stop_and_the_frame_limit_end_the_capture_thread() {
        let prefix = format!("percslowstop{}", std::process::id());
        let (rendered, mut pipeline) = small_scene_pipeline(&prefix);
        for when_busy in [WhenBusy::DropOldest, WhenBusy::Wait] {
            // An endless camera, stopped by `stop()` after three detections; the capture
            // may be waiting for room (Wait) or pacing when the detector side stops.
            let mut camera = FastCamera {
                rendered: rendered.clone(),
                n: u64::MAX,
                next: 0,
                when_busy,
                ended: Arc::new(AtomicBool::new(false)),
            };
            let done = AtomicU64::new(0);
            let t = Instant::now();
            let stats = run_with(
                &mut camera,
                &mut |f, _| {
                    std::thread::sleep(Duration::from_millis(5));
                    let p = pipeline.process(f);
                    done.fetch_add(1, Ordering::SeqCst);
                    p
                },
                500.0,
                None,
                &|| done.load(Ordering::SeqCst) >= 3,
            )
            .unwrap();
            assert_eq!(stats.published, 3, "{when_busy:?}: {stats:?}");
            assert!(t.elapsed() < Duration::from_secs(20), "{when_busy:?}");
            // The frame limit counts frames taken from the source.
            let stats = run_with(
                &mut camera,
                &mut |f, _| pipeline.process(f),
                500.0,
                Some(4),
                &|| false,
            )
            .unwrap();
            assert_eq!(stats.frames, 4, "{when_busy:?}: {stats:?}");
            assert_eq!(
                stats.published + stats.frames_dropped_behind_detector,
                4,
                "{when_busy:?}: {stats:?}"
            );
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
        let prefix = format!("percpipetest{}", std::process::id());
        let (rendered, mut pipeline) = scene_pipeline(&crowded(), &prefix);
        let frame = |seq| Frame::from_rendered(&rendered, seq, monotonic_now_ns());
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
                frames_dropped_behind_detector: 0,
                unpaired_depth: 0,
                wrong_camera: 0,
            }
        );
    }

    /// Issue 33 item 3: the published objects carry the tracker's velocity over iceoryx2: a
    /// box moving at 0.5 m/s arrives unknown (zero, 2 m/s sigma) on its first confirmed
    /// frames, then with its velocity and a small sigma, in frames never settled; once it
    /// stops, with zero velocity in settled frames. Every frame validates.
    #[test]
    fn published_objects_carry_the_tracked_velocity_and_a_moving_box_never_settles() {
        use crate::detection::ObjectKind;
        use shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S;
        let prefix = format!("percvelocity{}", std::process::id());
        let (node, _) =
            shm_schemas::services::create_node::<ipc::Service>("pipeline-velocity").unwrap();
        let sub =
            shm_schemas::services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
        let mut publisher = DetectionPublisher::open(&prefix, 0).unwrap();
        let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
        let stamp_ns = |k: u64| 7_000_000_000 + k * 16_666_667;
        let mut received = Vec::new();
        for k in 0..70u64 {
            // Moving along +y at 0.5 m/s for 40 frames, then still.
            let t_s = (stamp_ns(k.min(39)) - stamp_ns(0)) as f64 * 1e-9;
            let box_at = Detection {
                kind: ObjectKind::Obstacle,
                confidence: 0.9,
                bbox_px: [0, 0, 1, 1],
                position_m: [0.35, -0.2 + 0.5 * t_s, 0.05],
                size_m: [0.06, 0.06, 0.1],
            };
            tracker.update(&[box_at], stamp_ns(k));
            publisher
                .publish(stamp_ns(k), &tracker.objects(), tracker.settled())
                .unwrap();
            let frame = *sub.receive().unwrap().expect("a frame").payload();
            frame.validate().unwrap();
            received.push(frame);
        }
        let unknown = [0.0, 0.0, 0.0, UNKNOWN_VELOCITY_SIGMA_M_S];
        let v = |f: &DetectionFrame| {
            let o = f.objects()[0];
            [
                o.velocity_m_s[0],
                o.velocity_m_s[1],
                o.velocity_m_s[2],
                o.velocity_sigma_m_s,
            ]
        };
        assert_eq!(received[1].count, 0, "not confirmed yet");
        assert_eq!((v(&received[2]), v(&received[3])), (unknown, unknown));
        for f in &received[7..40] {
            let [vx, vy, vz, sigma] = v(f);
            assert!(
                vx.abs() < 1e-3 && (vy - 0.5).abs() < 0.01 && vz.abs() < 1e-3,
                "{f:?}"
            );
            assert!(sigma > 0.0 && sigma < 0.02, "{f:?}");
        }
        assert!(received[..40].iter().all(|f| !f.settled()));
        let last = received[69];
        assert!(last.settled());
        assert_eq!(v(&last)[..3], [0.0; 3]);
    }

    /// A camera whose frames are stamped when taken, with colour images refused for want of
    /// depth (a stalled depth topic) where the script says `false`.
    struct StallingDepth {
        rendered: crate::synthetic::RenderedFrame,
        script: Vec<bool>,
        next: usize,
        /// `CLOCK_MONOTONIC` of the last refusal.
        last_refusal_ns: u64,
    }

    impl FrameSource for StallingDepth {
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            let Some(&good) = self.script.get(self.next) else {
                return Ok(None);
            };
            self.next += 1;
            if !good {
                self.last_refusal_ns = monotonic_now_ns();
                return Err(SourceError::Depth(crate::source::DepthPairError::Stale {
                    topic: "/depth".into(),
                    skew_ms: 2_000.0,
                    max_ms: 10.0,
                }));
            }
            let now = monotonic_now_ns();
            Ok(Some(Frame::from_rendered(
                &self.rendered,
                self.next as u64,
                now,
            )?))
        }

        fn when_busy(&self) -> WhenBusy {
            WhenBusy::Wait
        }
    }

    /// Issue 25 item 3: frames refused for stale depth are counted, and the frames after
    /// them are not settled until the quiet time (100 ms) of good frames has passed (the
    /// colour detector takes a few ms a frame, so the 30 good frames after the stall span
    /// more than that: the scene settles again).
    #[test]
    fn frames_refused_for_stale_depth_are_counted_and_unsettle_the_scene() {
        let prefix = format!("percstaledepth{}", std::process::id());
        let (rendered, mut pipeline) = small_scene_pipeline(&prefix);
        // 300 good frames, 20 refused, 30 good frames.
        let mut script = vec![true; 300];
        script.extend([false; 20]);
        script.extend([true; 30]);
        let mut source = StallingDepth {
            rendered,
            script,
            next: 0,
            last_refusal_ns: 0,
        };
        let mut settled = Vec::new();
        let stats = run_with(
            &mut source,
            &mut |f, interrupted| {
                let p = pipeline.process_after(f, interrupted)?;
                settled.push((p.sent.settled(), f.capture_time_ns));
                Ok(p)
            },
            1000.0,
            None,
            &|| false,
        )
        .unwrap();
        assert_eq!(
            (stats.unpaired_depth, stats.bad_frames),
            (20, 20),
            "{stats:?}"
        );
        assert_eq!(stats.published, 330, "{stats:?}");
        // Settled before the stall (the last frames before it may already see the
        // interruption: the capture runs a frame or two ahead of the detector).
        assert!(
            settled[250..298].iter().all(|s| s.0),
            "{:?}",
            &settled[..300]
        );
        let refused_ns = source.last_refusal_ns;
        assert!(refused_ns > 0);
        assert!(
            !settled[300].0,
            "the first frame after the stall is settled"
        );
        for (i, &(s, t)) in settled.iter().enumerate().skip(300) {
            assert!(
                !s || t >= refused_ns + 100_000_000,
                "frame {i} settled {} ms after the last refused one",
                t.saturating_sub(refused_ns) as f64 / 1e6
            );
        }
    }
}
