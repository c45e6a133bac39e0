//! Stable object ids across frames and debouncing of what is reported.
//!
//! Detections are matched to tracks of the same class by nearest position on the table
//! (greedy, within `match_gate_m`). A new object is reported once it has been seen in `persist_frames`
//! consecutive frames; a lost one is dropped after `persist_frames` misses. A reported
//! object's position or size changes only when the new measurement differs from the
//! reported one by more than `noise_tolerance_m` for `persist_frames` consecutive frames, or
//! at once when it differs by more than `jump_m` (a box swapped for a taller one).
//!
//! **Settled** ([`Tracker::settled`], published as `DetectionFrame::FRAME_SETTLED`): the
//! reported set is complete and stable — every track is confirmed and has kept its reported
//! box for `settle_frames` frames, none is missing from the latest frame, none is measured
//! more than `settle_motion_m` from its reported box, and for `settle_quiet_ms` (capture time)
//! no object appeared (a new track, even one never confirmed), disappeared (a track dropped)
//! or moved (a reported box changed, or a measurement beyond `settle_motion_m`). rt-core plans
//! only on settled frames, so the intermediate views of a world change (the new goal with the
//! old box, the new boxes not yet confirmed) never get a plan approved. With the defaults at
//! the 60 Hz synthetic camera a plan waits 100–117 ms (the quiet time, rounded up to a frame)
//! longer after the last change than before.
//!
//! **Velocity** ([`TrackedObject::velocity_m_s`], [`TrackedObject::velocity_sigma_m_s`],
//! published in each `DetectedObject`): a least-squares line through the track's newest
//! `velocity_samples` measured centres against their capture times ([`velocity`]), from the
//! frame the track is confirmed on; its 1-sigma uncertainty comes from the detector's
//! position noise (`position_noise_m`, or the fit's residuals where larger) and shrinks as the
//! track ages. A newly confirmed track has too few measurements: zero velocity with
//! `UNKNOWN_VELOCITY_SIGMA_M_S` (2 m/s), for its first two frames. A box swapped for another
//! of a different size (a jump in size) starts its history over; a jump in position alone
//! does not (a fast object).
//!
//! **Settled** additionally needs every track still: a frame with a track whose speed
//! exceeds both `still_speed_m_s` (0.02 m/s) and 3 sigmas ([`velocity::MOTION_SIGMAS`]) is not
//! settled, so a moving object never lets the scene settle, even one too slow to leave
//! `settle_motion_m` within the quiet time. This rule restarts no quiet time (the position
//! rules above do): once the object stops, the scene settles when its speed estimate, over
//! the newest `velocity_samples` frames (the default 8 span 117 ms at 60 Hz), has fallen
//! below the threshold; a still scene settles as it did without it (a noisy still object may
//! cost a frame now and then: see [`velocity`]).

pub mod velocity;

use serde::{Deserialize, Serialize};
use shm_schemas::detection::MAX_OBJECT_SPEED_M_S;

use self::velocity::{Velocity, VelocityHistory, VelocitySettings};
use crate::detection::{Detection, ObjectKind};

/// Tracker settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// Largest distance on the table (x, y) between a detection and the track it continues (m).
    pub match_gate_m: f64,
    /// Frames a new object, a lost object or a small change must persist to count.
    pub persist_frames: u32,
    /// Changes of position or size up to this are measurement noise (m).
    pub noise_tolerance_m: f64,
    /// Changes beyond this count at once (m).
    pub jump_m: f64,
    /// Frames every object must have been confirmed with its reported box before a frame is
    /// settled ([`SETTLE_FRAMES_MAX`] at most).
    pub settle_frames: u32,
    /// Capture time with nothing appearing, disappearing or moving before a frame is settled
    /// (ms, [`SETTLE_QUIET_MS_MAX`] at most). The cost of settling: at 60 Hz the default
    /// 100 ms delays the first plan after a world change by 100–117 ms.
    pub settle_quiet_ms: u32,
    /// A measurement further than this from its object's reported box is motion: the frame
    /// is not settled and the quiet time starts again (m; from `noise_tolerance_m` to
    /// `jump_m`).
    pub settle_motion_m: f64,
    /// The detector's frame-to-frame position noise, 1 sigma per axis (m; > 0, at most
    /// `jump_m`): the least uncertainty of a measured centre the velocity estimate assumes
    /// (the fit's residuals raise it where the detector is noisier). Default 1 mm: the colour
    /// detector's position error is 0.36 mm median, 0.74 mm p95 on the accuracy set, YOLO's
    /// 0.66 mm median.
    pub position_noise_m: f64,
    /// Newest measurements the velocity is fitted through ([`velocity::MIN_SAMPLES`] ..=
    /// [`VELOCITY_SAMPLES_MAX`]); more give a smaller sigma but a longer memory of past
    /// motion (the default 8 span 117 ms at 60 Hz).
    pub velocity_samples: u32,
    /// Measurements older than this before the newest are left out of the velocity fit (ms,
    /// 1 ..= [`VELOCITY_WINDOW_MS_MAX`]).
    pub velocity_window_ms: u32,
    /// Speeds up to this never count as motion, whatever the sigma (m/s; 0 ..= the
    /// contract's `MAX_OBJECT_SPEED_M_S`).
    pub still_speed_m_s: f64,
}

/// Largest `velocity_samples` accepted.
pub const VELOCITY_SAMPLES_MAX: u32 = 32;

/// Largest `velocity_window_ms` accepted.
pub const VELOCITY_WINDOW_MS_MAX: u32 = 2_000;

/// Largest `settle_frames` accepted (2 s at 60 Hz).
pub const SETTLE_FRAMES_MAX: u32 = 120;

/// Largest `settle_quiet_ms` accepted.
pub const SETTLE_QUIET_MS_MAX: u32 = 2_000;

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            match_gate_m: 0.08,
            persist_frames: 3,
            noise_tolerance_m: 0.005,
            jump_m: 0.05,
            settle_frames: 3,
            settle_quiet_ms: 100,
            settle_motion_m: 0.005,
            position_noise_m: 0.001,
            velocity_samples: 8,
            velocity_window_ms: 500,
            still_speed_m_s: 0.02,
        }
    }
}

/// Why [`TrackerConfig::validate`] rejected the settings; each message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrackerConfigError {
    /// `match_gate_m` is not a positive number.
    #[error("match_gate_m = {0} must be > 0")]
    MatchGate(f64),
    /// `persist_frames` is 0.
    #[error("persist_frames must be ≥ 1")]
    PersistFrames,
    /// `noise_tolerance_m` is negative or not below `jump_m`.
    #[error("need 0 ≤ noise_tolerance_m ({noise_tolerance_m}) < jump_m ({jump_m})")]
    NoiseVsJump {
        /// The tolerance given (m).
        noise_tolerance_m: f64,
        /// The jump threshold given (m).
        jump_m: f64,
    },
    /// `settle_frames` is 0 or above [`SETTLE_FRAMES_MAX`].
    #[error("settle_frames = {0} must be in 1..={SETTLE_FRAMES_MAX}")]
    SettleFrames(u32),
    /// `settle_quiet_ms` is above [`SETTLE_QUIET_MS_MAX`].
    #[error("settle_quiet_ms = {0} must be in 0..={SETTLE_QUIET_MS_MAX}")]
    SettleQuiet(u32),
    /// `settle_motion_m` is below `noise_tolerance_m` (jitter the tracker ignores would keep
    /// every frame unsettled) or above `jump_m`.
    #[error(
        "settle_motion_m = {settle_motion_m} must be in noise_tolerance_m ..= jump_m ({noise_tolerance_m} ..= {jump_m})"
    )]
    SettleMotion {
        /// The threshold given (m).
        settle_motion_m: f64,
        /// The noise tolerance (m).
        noise_tolerance_m: f64,
        /// The jump threshold (m).
        jump_m: f64,
    },
    /// `position_noise_m` is not in (0, `jump_m`].
    #[error("position_noise_m = {position_noise_m} must be > 0 and ≤ jump_m ({jump_m})")]
    PositionNoise {
        /// The noise given (m).
        position_noise_m: f64,
        /// The jump threshold (m).
        jump_m: f64,
    },
    /// `velocity_samples` is outside [`velocity::MIN_SAMPLES`] ..= [`VELOCITY_SAMPLES_MAX`].
    #[error(
        "velocity_samples = {0} must be in {min}..={VELOCITY_SAMPLES_MAX}",
        min = velocity::MIN_SAMPLES
    )]
    VelocitySamples(u32),
    /// `velocity_window_ms` is 0 or above [`VELOCITY_WINDOW_MS_MAX`].
    #[error("velocity_window_ms = {0} must be in 1..={VELOCITY_WINDOW_MS_MAX}")]
    VelocityWindow(u32),
    /// `still_speed_m_s` is negative, not a number or above the contract's speed bound.
    #[error("still_speed_m_s = {0} must be in 0..={MAX_OBJECT_SPEED_M_S}")]
    StillSpeed(f64),
}

impl TrackerConfig {
    /// Checks the values.
    ///
    /// # Errors
    /// [`TrackerConfigError`] naming the first bad value.
    pub fn validate(&self) -> Result<(), TrackerConfigError> {
        if !(self.match_gate_m.is_finite() && self.match_gate_m > 0.0) {
            return Err(TrackerConfigError::MatchGate(self.match_gate_m));
        }
        if self.persist_frames == 0 {
            return Err(TrackerConfigError::PersistFrames);
        }
        if !(self.noise_tolerance_m >= 0.0 && self.jump_m > self.noise_tolerance_m) {
            return Err(TrackerConfigError::NoiseVsJump {
                noise_tolerance_m: self.noise_tolerance_m,
                jump_m: self.jump_m,
            });
        }
        if !(1..=SETTLE_FRAMES_MAX).contains(&self.settle_frames) {
            return Err(TrackerConfigError::SettleFrames(self.settle_frames));
        }
        if self.settle_quiet_ms > SETTLE_QUIET_MS_MAX {
            return Err(TrackerConfigError::SettleQuiet(self.settle_quiet_ms));
        }
        if !(self.noise_tolerance_m..=self.jump_m).contains(&self.settle_motion_m) {
            return Err(TrackerConfigError::SettleMotion {
                settle_motion_m: self.settle_motion_m,
                noise_tolerance_m: self.noise_tolerance_m,
                jump_m: self.jump_m,
            });
        }
        if !(self.position_noise_m > 0.0 && self.position_noise_m <= self.jump_m) {
            return Err(TrackerConfigError::PositionNoise {
                position_noise_m: self.position_noise_m,
                jump_m: self.jump_m,
            });
        }
        if !(velocity::MIN_SAMPLES..=VELOCITY_SAMPLES_MAX).contains(&self.velocity_samples) {
            return Err(TrackerConfigError::VelocitySamples(self.velocity_samples));
        }
        if !(1..=VELOCITY_WINDOW_MS_MAX).contains(&self.velocity_window_ms) {
            return Err(TrackerConfigError::VelocityWindow(self.velocity_window_ms));
        }
        if !(0.0..=f64::from(MAX_OBJECT_SPEED_M_S)).contains(&self.still_speed_m_s) {
            return Err(TrackerConfigError::StillSpeed(self.still_speed_m_s));
        }
        Ok(())
    }

    fn velocity_settings(&self) -> VelocitySettings {
        VelocitySettings {
            position_noise_m: self.position_noise_m,
            still_speed_m_s: self.still_speed_m_s,
        }
    }

    fn velocity_history(&self) -> VelocityHistory {
        VelocityHistory::new(self.velocity_samples as usize, self.velocity_window_ms)
    }
}

/// A reported (confirmed, debounced) object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackedObject {
    /// Stable id (never 0; never reused within a tracker's life).
    pub id: u32,
    /// Goal or obstacle.
    pub kind: ObjectKind,
    /// Latest detector confidence.
    pub confidence: f32,
    /// Reported centre (m).
    pub position_m: [f64; 3],
    /// Reported extents (m).
    pub size_m: [f64; 3],
    /// Estimated velocity of the centre (m/s; from the measured centres, see the module
    /// docs); zero while unknown.
    pub velocity_m_s: [f64; 3],
    /// 1-sigma uncertainty of `velocity_m_s`, along each axis (m/s):
    /// `UNKNOWN_VELOCITY_SIGMA_M_S` while unknown.
    pub velocity_sigma_m_s: f64,
}

#[derive(Debug, Clone)]
struct Track {
    id: u32,
    kind: ObjectKind,
    confidence: f32,
    latest: ([f64; 3], [f64; 3]),
    reported: Option<([f64; 3], [f64; 3])>,
    seen: u32,
    missed: u32,
    changing: u32,
    /// Frames seen since `reported` was last set (0 while unconfirmed).
    confirmed_frames: u32,
    /// Measured centres since the track was confirmed (empty while unconfirmed).
    history: VelocityHistory,
    /// The estimate from `history` after the latest measurement.
    velocity: Velocity,
}

/// The tracker.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    tracks: Vec<Track>,
    next_id: u32,
    pairs: Vec<(f64, usize, usize)>,
    /// Capture time of the last appearance, disappearance or motion (the first frame counts
    /// as one), ns.
    last_change_ns: Option<u64>,
    /// The latest frame was settled.
    settled: bool,
    /// A track was created or removed in the frame being processed.
    motion: bool,
}

/// Distance on the table (x, y): a box swapped for a taller one moves its centre up, not
/// across, and must stay the same object.
fn dist_xy(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Largest change of an extent.
fn size_dev(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max)
}

fn max_dev(a: &([f64; 3], [f64; 3]), b: &([f64; 3], [f64; 3])) -> f64 {
    (0..3)
        .map(|i| (a.0[i] - b.0[i]).abs().max((a.1[i] - b.1[i]).abs()))
        .fold(0.0, f64::max)
}

impl Tracker {
    /// A tracker with validated settings.
    ///
    /// # Errors
    /// [`TrackerConfigError`] naming the first bad value.
    pub fn new(config: TrackerConfig) -> Result<Self, TrackerConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            tracks: Vec::new(),
            next_id: 1,
            pairs: Vec::new(),
            last_change_ns: None,
            settled: false,
            motion: false,
        })
    }

    /// Whether the reported set of the latest frame is settled (see the module docs).
    pub fn settled(&self) -> bool {
        self.settled
    }

    /// Feeds one frame's detections, captured at `capture_time_ns` (`CLOCK_MONOTONIC`);
    /// returns whether the reported set changed (an object appeared, disappeared, moved or
    /// changed size). Updates [`Tracker::settled`].
    pub fn update(&mut self, detections: &[Detection], capture_time_ns: u64) -> bool {
        let changed = self.match_and_report(detections, capture_time_ns);
        self.update_settled(changed, capture_time_ns);
        changed
    }

    /// The camera could not be trusted at `now_ns` (`CLOCK_MONOTONIC`; e.g. a frame refused
    /// for a missing or stale depth image): the latest frame is no longer settled, and the
    /// quiet time starts over from `now_ns`, so the next settled frame needs
    /// `settle_quiet_ms` of good frames after it (what happened in between was not seen).
    pub fn interrupt(&mut self, now_ns: u64) {
        self.settled = false;
        self.last_change_ns = Some(self.last_change_ns.map_or(now_ns, |t| t.max(now_ns)));
    }

    /// The settle rule after a frame: `changed` (the reported set changed), any track
    /// created or removed (`motion` set by [`Tracker::match_and_report`]), or a measurement
    /// beyond `settle_motion_m` restarts the quiet time; a reported track whose speed estimate
    /// is beyond its noise ([`Velocity::moving`]) keeps this frame unsettled.
    fn update_settled(&mut self, changed: bool, now_ns: u64) {
        let cfg = self.config;
        let moving = self.tracks.iter().any(|t| {
            t.missed == 0
                && t.reported
                    .is_some_and(|r| max_dev(&r, &t.latest) > cfg.settle_motion_m)
        });
        if changed || moving || self.motion || self.last_change_ns.is_none() {
            self.last_change_ns = Some(now_ns);
        }
        self.motion = false;
        let quiet_ns = u64::from(cfg.settle_quiet_ms) * 1_000_000;
        // A capture time before the last change (a clock step back) is not quiet.
        let quiet = self
            .last_change_ns
            .and_then(|t| now_ns.checked_sub(t))
            .is_some_and(|d| d >= quiet_ns);
        let all_confirmed = self.tracks.iter().all(|t| {
            t.reported.is_some() && t.missed == 0 && t.confirmed_frames >= cfg.settle_frames
        });
        let fast = self
            .tracks
            .iter()
            .any(|t| t.reported.is_some() && t.velocity.moving);
        self.settled = quiet && all_confirmed && !moving && !fast;
    }

    fn match_and_report(&mut self, detections: &[Detection], capture_time_ns: u64) -> bool {
        let cfg = self.config;
        let velocity_settings = cfg.velocity_settings();
        self.pairs.clear();
        for (ti, t) in self.tracks.iter().enumerate() {
            for (di, d) in detections.iter().enumerate() {
                if d.kind == t.kind {
                    let e = dist_xy(&t.latest.0, &d.position_m);
                    if e <= cfg.match_gate_m {
                        self.pairs.push((e, ti, di));
                    }
                }
            }
        }
        self.pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut track_hit = vec![false; self.tracks.len()];
        let mut det_used = vec![false; detections.len()];
        let mut changed = false;
        for &(_, ti, di) in &self.pairs {
            if track_hit[ti] || det_used[di] {
                continue;
            }
            track_hit[ti] = true;
            det_used[di] = true;
            let d = &detections[di];
            changed |= update_matched(
                &mut self.tracks[ti],
                d,
                &cfg,
                &velocity_settings,
                capture_time_ns,
            );
        }
        let mut keep = Vec::with_capacity(self.tracks.len());
        for (ti, mut t) in std::mem::take(&mut self.tracks).into_iter().enumerate() {
            if !track_hit[ti] {
                t.seen = 0;
                t.missed += 1;
                if t.reported.is_none() {
                    self.motion = true;
                    continue;
                }
                if t.missed >= cfg.persist_frames {
                    changed = true;
                    continue;
                }
            }
            keep.push(t);
        }
        self.tracks = keep;
        for (di, d) in detections.iter().enumerate() {
            if det_used[di] {
                continue;
            }
            let id = self.next_id;
            self.next_id = self.next_id.wrapping_add(1).max(1);
            let latest = (d.position_m, d.size_m);
            let confirmed = cfg.persist_frames <= 1;
            changed |= confirmed;
            self.motion = true;
            let mut history = cfg.velocity_history();
            if confirmed {
                history.push(capture_time_ns, d.position_m);
            }
            self.tracks.push(Track {
                id,
                kind: d.kind,
                confidence: d.confidence,
                latest,
                reported: confirmed.then_some(latest),
                seen: 1,
                missed: 0,
                changing: 0,
                confirmed_frames: u32::from(confirmed),
                history,
                velocity: Velocity::UNKNOWN,
            });
        }
        changed
    }

    /// The reported objects, goal first, then by id.
    pub fn objects(&self) -> Vec<TrackedObject> {
        let mut v: Vec<TrackedObject> = self
            .tracks
            .iter()
            .filter_map(|t| {
                t.reported.map(|(p, s)| TrackedObject {
                    id: t.id,
                    kind: t.kind,
                    confidence: t.confidence,
                    position_m: p,
                    size_m: s,
                    velocity_m_s: t.velocity.velocity_m_s,
                    velocity_sigma_m_s: t.velocity.sigma_m_s,
                })
            })
            .collect();
        v.sort_by_key(|o| (o.kind != ObjectKind::Goal, o.id));
        v
    }
}

/// A track matched by detection `d` this frame: takes its position and size, and reports
/// it once it persisted (`persist_frames`), jumped (`jump_m`) or drifted past the noise
/// tolerance for `persist_frames` frames; a reported track's velocity is re-estimated.
/// Returns whether the reported objects changed.
fn update_matched(
    t: &mut Track,
    d: &Detection,
    cfg: &TrackerConfig,
    velocity_settings: &VelocitySettings,
    capture_time_ns: u64,
) -> bool {
    let mut changed = false;
    t.latest = (d.position_m, d.size_m);
    t.confidence = d.confidence;
    t.missed = 0;
    t.seen = t.seen.saturating_add(1);
    match t.reported {
        None => {
            if t.seen >= cfg.persist_frames {
                t.reported = Some(t.latest);
                t.confirmed_frames = 1;
                changed = true;
                t.history.clear();
            }
        }
        Some(rep) => {
            let dev = max_dev(&rep, &t.latest);
            t.confirmed_frames = t.confirmed_frames.saturating_add(1);
            if size_dev(&rep.1, &t.latest.1) > cfg.jump_m {
                // Another box at the same place: its velocity is not known.
                t.history.clear();
            }
            if dev > cfg.jump_m {
                t.reported = Some(t.latest);
                t.changing = 0;
                t.confirmed_frames = 1;
                changed = true;
            } else if dev > cfg.noise_tolerance_m {
                t.changing += 1;
                if t.changing >= cfg.persist_frames {
                    t.reported = Some(t.latest);
                    t.changing = 0;
                    t.confirmed_frames = 1;
                    changed = true;
                }
            } else {
                t.changing = 0;
            }
        }
    }
    if t.reported.is_some() {
        t.history.push(capture_time_ns, d.position_m);
        t.velocity = t.history.estimate(velocity_settings);
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(kind: ObjectKind, p: [f64; 3], s: [f64; 3]) -> Detection {
        Detection {
            kind,
            confidence: 0.9,
            bbox_px: [0, 0, 1, 1],
            position_m: p,
            size_m: s,
        }
    }

    #[test]
    fn objects_appear_after_persisting_and_keep_their_ids() {
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let g = det(ObjectKind::Goal, [0.4, 0.2, 0.025], [0.05; 3]);
        let o = det(ObjectKind::Obstacle, [0.35, 0.0, 0.05], [0.06, 0.06, 0.1]);
        assert!(!t.update(&[g.clone(), o.clone()], 0));
        assert!(!t.update(&[g.clone(), o.clone()], 0));
        assert!(t.objects().is_empty());
        assert!(t.update(&[o.clone(), g.clone()], 0));
        let objs = t.objects();
        assert_eq!(objs.len(), 2);
        assert_eq!(objs[0].kind, ObjectKind::Goal);
        let ids: Vec<u32> = objs.iter().map(|o| o.id).collect();
        // Jitter below the tolerance changes nothing, ids stay.
        let mut o2 = o.clone();
        o2.position_m[0] += 0.003;
        for _ in 0..5 {
            assert!(!t.update(&[g.clone(), o2.clone()], 0));
        }
        assert_eq!(t.objects().iter().map(|o| o.id).collect::<Vec<_>>(), ids);
        assert_eq!(t.objects()[1].position_m, o.position_m);
    }

    #[test]
    fn small_changes_count_after_persisting_and_jumps_at_once() {
        let cfg = TrackerConfig {
            persist_frames: 2,
            ..TrackerConfig::default()
        };
        let mut t = Tracker::new(cfg).unwrap();
        let o = det(ObjectKind::Obstacle, [0.35, 0.0, 0.05], [0.06, 0.06, 0.1]);
        t.update(std::slice::from_ref(&o), 0);
        t.update(std::slice::from_ref(&o), 0);
        let id = t.objects()[0].id;
        let mut moved = o.clone();
        moved.position_m[1] += 0.02;
        assert!(
            !t.update(std::slice::from_ref(&moved), 0),
            "one frame is not enough"
        );
        assert!(t.update(std::slice::from_ref(&moved), 0));
        assert!((t.objects()[0].position_m[1] - 0.02).abs() < 1e-12);
        // The small box is swapped for a tall one at the same place: counts at once.
        let mut tall = moved.clone();
        tall.size_m[2] = 0.3;
        tall.position_m[2] = 0.15;
        assert!(t.update(std::slice::from_ref(&tall), 0));
        assert_eq!(t.objects()[0].size_m[2], 0.3);
        assert_eq!(t.objects()[0].id, id);
        // A one-frame dropout keeps the object; persisting absence removes it.
        assert!(!t.update(&[], 0));
        assert_eq!(t.objects().len(), 1);
        assert!(t.update(&[], 0));
        assert!(t.objects().is_empty());
        // Something new gets a new id.
        t.update(std::slice::from_ref(&o), 0);
        t.update(std::slice::from_ref(&o), 0);
        assert!(t.objects()[0].id > id);
    }

    #[test]
    fn classes_do_not_match_each_other_and_bad_settings_are_rejected() {
        let mut t = Tracker::new(TrackerConfig {
            persist_frames: 1,
            ..TrackerConfig::default()
        })
        .unwrap();
        t.update(&[det(ObjectKind::Goal, [0.4, 0.0, 0.025], [0.05; 3])], 0);
        t.update(
            &[
                det(ObjectKind::Goal, [0.4, 0.0, 0.025], [0.05; 3]),
                det(ObjectKind::Obstacle, [0.4, 0.0, 0.025], [0.05; 3]),
            ],
            0,
        );
        let objs = t.objects();
        assert_eq!(objs.len(), 2, "{objs:?}");
        assert_ne!(objs[0].id, objs[1].id);
        assert_eq!(
            Tracker::new(TrackerConfig {
                persist_frames: 0,
                ..TrackerConfig::default()
            })
            .unwrap_err(),
            TrackerConfigError::PersistFrames
        );
        let e = Tracker::new(TrackerConfig {
            jump_m: 0.001,
            ..TrackerConfig::default()
        })
        .unwrap_err();
        assert!(matches!(e, TrackerConfigError::NoiseVsJump { .. }), "{e:?}");
        assert!(e.to_string().contains("jump_m"), "{e}");
    }

    /// Capture time of frame `k` of a 60 Hz camera, ns.
    fn at_60hz(k: u64) -> u64 {
        5_000_000_000 + k * 16_666_667
    }

    /// Feeds `frames` frames from frame `*k` on, each built by `dets(k)`; returns the
    /// settled flag of each.
    fn feed(
        t: &mut Tracker,
        k: &mut u64,
        frames: u64,
        dets: impl Fn(u64) -> Vec<Detection>,
    ) -> Vec<bool> {
        (0..frames)
            .map(|_| {
                t.update(&dets(*k), at_60hz(*k));
                *k += 1;
                t.settled()
            })
            .collect()
    }

    /// Issue 25 item 3: frames refused for stale depth interrupt a settled scene; it settles
    /// again only after the quiet time of good frames.
    #[test]
    fn an_interruption_unsettles_until_the_quiet_time_of_good_frames_passed() {
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let g1 = det(ObjectKind::Goal, [0.4, 0.2, 0.025], [0.05; 3]);
        let mut k = 0;
        let s = feed(&mut t, &mut k, 12, |_| vec![g1.clone()]);
        assert!(s[11], "{s:?}");
        // Frames k..k+30 refused (depth stalled for half a second), then good ones again.
        t.interrupt(at_60hz(k + 30));
        assert!(!t.settled());
        k += 31;
        let s = feed(&mut t, &mut k, 12, |_| vec![g1.clone()]);
        // 100 ms after the last refused frame (6 frames at 60 Hz), not before.
        assert_eq!(s.iter().position(|x| *x), Some(5), "{s:?}");
        assert!(s[5..].iter().all(|x| *x), "{s:?}");
        // An interruption stamped before the last change does not shorten the quiet time.
        t.interrupt(0);
        assert!(!t.settled());
    }

    /// The settle rule with the defaults at 60 Hz (issue 15): a frame is settled only once
    /// every object is confirmed (3 frames) and has kept its box for 3 frames, and nothing
    /// appeared, disappeared or moved beyond 5 mm for 100 ms. The intermediate views of a
    /// world change (the new goal with the old box, the new box not yet confirmed) are not.
    #[test]
    fn frames_are_settled_only_when_every_object_is_confirmed_and_nothing_changed_for_the_quiet_time()
     {
        let cfg = TrackerConfig::default();
        assert_eq!(
            (cfg.settle_frames, cfg.settle_quiet_ms, cfg.settle_motion_m),
            (3, 100, 0.005)
        );
        let mut t = Tracker::new(cfg).unwrap();
        let g1 = det(ObjectKind::Goal, [0.4, 0.2, 0.025], [0.05; 3]);
        let o1 = det(ObjectKind::Obstacle, [0.35, 0.0, 0.05], [0.06, 0.06, 0.1]);
        let mut k = 0;
        // Scene A: confirmed at frame 2 (the last change), settled 100 ms later: frame 8.
        let s = feed(&mut t, &mut k, 12, |_| vec![g1.clone(), o1.clone()]);
        assert_eq!(s.iter().position(|x| *x), Some(8), "{s:?}");
        assert!(s[8..].iter().all(|x| *x), "{s:?}");
        // Jitter below the threshold (3 mm) keeps it settled.
        let s = feed(&mut t, &mut k, 10, |k| {
            let mut o = o1.clone();
            o.position_m[0] += if k % 2 == 0 { 0.003 } else { -0.003 };
            vec![g1.clone(), o]
        });
        assert!(s.iter().all(|x| *x), "{s:?}");

        // Scene B from frame k0: the goal moves far away, the box goes, and a tall box
        // appears one frame later (it enters the image late).
        let k0 = k;
        let g2 = det(ObjectKind::Goal, [0.3, -0.25, 0.025], [0.05; 3]);
        let o2 = det(ObjectKind::Obstacle, [0.45, -0.1, 0.15], [0.06, 0.06, 0.3]);
        let mut published_without_o2 = false;
        let mut s = Vec::new();
        for _ in 0..16 {
            let mut d = vec![g2.clone()];
            if k > k0 {
                d.push(o2.clone());
            }
            t.update(&d, at_60hz(k));
            let objs = t.objects();
            if objs.iter().any(|o| o.position_m == g2.position_m)
                && !objs.iter().any(|o| o.position_m == o2.position_m)
            {
                // The intermediate scene of the issue: the new goal, the new box unseen.
                published_without_o2 = true;
                assert!(!t.settled(), "frame {}: intermediate scene settled", k - k0);
            }
            s.push(t.settled());
            k += 1;
        }
        assert!(published_without_o2, "the test shows an intermediate scene");
        // o2 confirmed at k0 + 3 (the last change): settled 100 ms later, at k0 + 9.
        assert_eq!(s.iter().position(|x| *x), Some(9), "{s:?}");
        assert!(s[9..].iter().all(|x| *x), "{s:?}");

        // A one-frame dropout of a confirmed box: that frame is not settled (it may be
        // disappearing); it is back at once when the box is.
        let s = feed(&mut t, &mut k, 3, |k| {
            if k % 3 == 0 {
                vec![g2.clone()]
            } else {
                vec![g2.clone(), o2.clone()]
            }
        });
        assert_eq!(s.iter().filter(|x| !**x).count(), 1, "{s:?}");

        // The box moves 8 mm (beyond the 5 mm threshold, below a jump): unsettled at once,
        // its new place reported two frames later (the last change), settled 100 ms after.
        let mut moved = o2.clone();
        moved.position_m[1] += 0.008;
        let s = feed(&mut t, &mut k, 10, |_| vec![g2.clone(), moved.clone()]);
        assert_eq!(s.iter().position(|x| *x), Some(8), "{s:?}");
    }

    #[test]
    fn an_empty_table_settles_after_the_quiet_time_and_a_clock_step_back_is_not_quiet() {
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let mut k = 0;
        let s = feed(&mut t, &mut k, 8, |_| Vec::new());
        assert_eq!(s.iter().position(|x| *x), Some(6), "{s:?}");
        t.update(&[], at_60hz(0) - 1);
        assert!(!t.settled(), "a capture time before the last change");
        // A flicker (one frame, never confirmed) restarts the quiet time.
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let mut k = 0;
        let blip = det(ObjectKind::Obstacle, [0.3, 0.1, 0.05], [0.05; 3]);
        let s = feed(&mut t, &mut k, 16, |k| {
            if k == 7 {
                vec![blip.clone()]
            } else {
                Vec::new()
            }
        });
        assert!(t.objects().is_empty());
        // Created at 7, gone at 8 (the last change): settled 100 ms after frame 8.
        assert_eq!(
            &s[6..],
            &[
                true, false, false, false, false, false, false, false, true, true
            ]
        );
    }

    /// A small deterministic wobble in [-amp, amp] (m), different per frame and axis.
    fn wobble(k: u64, axis: u64, amp_m: f64) -> f64 {
        let x = (k * 7919 + axis * 104_729).wrapping_mul(2_654_435_761) % 1_000;
        amp_m * (x as f64 / 500.0 - 1.0)
    }

    fn speed(v: &[f64; 3]) -> f64 {
        v.iter().map(|x| x * x).sum::<f64>().sqrt()
    }

    /// Issue 33 item 3: a box moving at 0.5 m/s (with ±0.3 mm of measurement wobble), 10
    /// frames at 60 Hz: its first two confirmed frames carry an unknown velocity (zero, the
    /// large sigma), then a velocity within 10 % with a sigma that shrinks as the track ages.
    #[test]
    fn a_box_moving_at_half_a_metre_per_second_gets_its_velocity_and_a_shrinking_sigma() {
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let v = [0.3, 0.4, 0.0];
        let unknown = f64::from(shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S);
        let mut sigmas = Vec::new();
        for k in 0..10u64 {
            let t_s = (at_60hz(k) - at_60hz(0)) as f64 * 1e-9;
            let p: [f64; 3] = std::array::from_fn(|a| {
                [0.3, -0.1, 0.05][a] + v[a] * t_s + wobble(k, a as u64, 0.0003)
            });
            t.update(&[det(ObjectKind::Obstacle, p, [0.05; 3])], at_60hz(k));
            assert!(!t.settled(), "frame {k}: a moving box settled");
            let objs = t.objects();
            match k {
                0 | 1 => assert!(objs.is_empty()),
                2 | 3 => {
                    // Confirmed at frame 2: one, then two measurements.
                    assert_eq!(objs[0].velocity_m_s, [0.0; 3], "frame {k}");
                    assert_eq!(objs[0].velocity_sigma_m_s, unknown, "frame {k}");
                }
                _ => {
                    let o = objs[0];
                    let err: Vec<f64> = (0..3).map(|a| o.velocity_m_s[a] - v[a]).collect();
                    assert!(
                        speed(&[err[0], err[1], err[2]]) <= 0.1 * 0.5,
                        "frame {k}: {:?}",
                        o.velocity_m_s
                    );
                    sigmas.push(o.velocity_sigma_m_s);
                }
            }
        }
        assert_eq!(sigmas.len(), 6);
        assert!(sigmas.windows(2).all(|w| w[1] < w[0]), "{sigmas:?}");
        assert!(sigmas[0] < unknown && sigmas[5] < 0.012, "{sigmas:?}");
        assert!(sigmas[5] < sigmas[0] / 3.0, "{sigmas:?}");
    }

    /// A still box, exact or with ±0.5 mm of measurement wobble: speed ≈ 0, a small sigma,
    /// and the scene settles when it did before velocities existed (frame 8) and stays so.
    #[test]
    fn a_still_box_has_no_speed_and_settles_as_before() {
        for amp_m in [0.0, 0.0005] {
            let mut t = Tracker::new(TrackerConfig::default()).unwrap();
            let mut k = 0;
            let s = feed(&mut t, &mut k, 120, |k| {
                let p = std::array::from_fn(|a| [0.35, 0.0, 0.05][a] + wobble(k, a as u64, amp_m));
                vec![det(ObjectKind::Obstacle, p, [0.06, 0.06, 0.1])]
            });
            assert_eq!(s.iter().position(|x| *x), Some(8), "{amp_m}: {s:?}");
            assert!(s[8..].iter().all(|x| *x), "{amp_m}: {s:?}");
            let o = t.objects()[0];
            let bound = if amp_m == 0.0 { 1e-9 } else { 0.02 };
            assert!(speed(&o.velocity_m_s) < bound, "{amp_m}: {o:?}");
            assert!(
                o.velocity_sigma_m_s > 0.0 && o.velocity_sigma_m_s < 0.015,
                "{amp_m}: {o:?}"
            );
        }
    }

    /// A box creeping at 4 cm/s never lets the scene settle. Without the velocity rule (a
    /// `still_speed_m_s` no speed reaches) the position rules alone let it settle between
    /// the updates of its reported box: the rule is what keeps it unsettled.
    #[test]
    fn a_moving_box_never_settles() {
        let creeping = |k: u64| {
            let t_s = (at_60hz(k) - at_60hz(0)) as f64 * 1e-9;
            vec![det(
                ObjectKind::Obstacle,
                [0.3 + 0.04 * t_s, 0.0, 0.05],
                [0.06, 0.06, 0.1],
            )]
        };
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let mut k = 0;
        let s = feed(&mut t, &mut k, 180, creeping);
        assert!(s.iter().all(|x| !*x), "{s:?}");
        let o = t.objects()[0];
        assert!((speed(&o.velocity_m_s) - 0.04).abs() < 1e-6, "{o:?}");
        let mut blind = Tracker::new(TrackerConfig {
            still_speed_m_s: 5.0,
            ..TrackerConfig::default()
        })
        .unwrap();
        let mut k = 0;
        let s = feed(&mut blind, &mut k, 180, creeping);
        assert!(
            s.iter().any(|x| *x),
            "the position rules alone never settled it"
        );
        // Fast: 0.5 m/s.
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let mut k = 0;
        let s = feed(&mut t, &mut k, 60, |k| {
            let t_s = (at_60hz(k) - at_60hz(0)) as f64 * 1e-9;
            vec![det(
                ObjectKind::Obstacle,
                [0.1 + 0.5 * t_s, 0.0, 0.05],
                [0.06, 0.06, 0.1],
            )]
        });
        assert!(s.iter().all(|x| !*x), "{s:?}");
        // It stops where it was last seen: the scene settles once the quiet time has passed
        // since its reported box last moved and its speed estimate has come down.
        let stop = [
            0.1 + 0.5 * (at_60hz(59) - at_60hz(0)) as f64 * 1e-9,
            0.0,
            0.05,
        ];
        let s = feed(&mut t, &mut k, 30, |_| {
            vec![det(ObjectKind::Obstacle, stop, [0.06, 0.06, 0.1])]
        });
        assert!(s[20..].iter().all(|x| *x), "{s:?}");
        assert_eq!(speed(&t.objects()[0].velocity_m_s), 0.0);
    }

    /// The velocity comes from capture times: frames at irregular intervals (10 and 30 ms in
    /// turn, and 16.7 ms ± 5 ms of jitter) give the true velocity, where a frame count at a
    /// nominal 60 Hz would be 17 % off (20 ms mean interval).
    #[test]
    fn velocity_comes_from_capture_times_not_frame_counts() {
        let alternating = |k: u64| 5_000_000_000 + (k / 2) * 40_000_000 + (k % 2) * 10_000_000;
        let jittered =
            |k: u64| (5_000_000_000.0 + k as f64 * 16_666_667.0 + wobble(k, 9, 5_000_000.0)) as u64;
        for stamp in [&alternating as &dyn Fn(u64) -> u64, &jittered] {
            let mut t = Tracker::new(TrackerConfig::default()).unwrap();
            for k in 0..12u64 {
                let t_s = (stamp(k) - stamp(0)) as f64 * 1e-9;
                t.update(
                    &[det(
                        ObjectKind::Goal,
                        [0.3 + 0.3 * t_s, 0.1, 0.025],
                        [0.05; 3],
                    )],
                    stamp(k),
                );
            }
            let o = t.objects()[0];
            assert!((o.velocity_m_s[0] - 0.3).abs() < 0.003, "{o:?}");
            assert!(o.velocity_m_s[1].abs() < 1e-9, "{o:?}");
        }
    }

    /// A box swapped for one of another size at the same place is another object: its
    /// velocity is unknown again (not the rise of its centre); a fast box keeps its history.
    #[test]
    fn a_box_swapped_for_another_size_has_an_unknown_velocity_again() {
        let unknown = f64::from(shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S);
        let mut t = Tracker::new(TrackerConfig::default()).unwrap();
        let small = det(ObjectKind::Obstacle, [0.35, 0.0, 0.05], [0.06, 0.06, 0.1]);
        let mut k = 0;
        feed(&mut t, &mut k, 10, |_| vec![small.clone()]);
        assert!(t.objects()[0].velocity_sigma_m_s < 0.015);
        let mut tall = small.clone();
        tall.size_m[2] = 0.3;
        tall.position_m[2] = 0.15;
        feed(&mut t, &mut k, 1, |_| vec![tall.clone()]);
        let o = t.objects()[0];
        assert_eq!((o.velocity_m_s, o.velocity_sigma_m_s), ([0.0; 3], unknown));
        assert_eq!(o.size_m[2], 0.3);
        // Two frames later the new box has a (zero) velocity of its own.
        feed(&mut t, &mut k, 2, |_| vec![tall.clone()]);
        let o = t.objects()[0];
        assert_eq!(o.velocity_m_s, [0.0; 3]);
        assert!(o.velocity_sigma_m_s < 0.05, "{o:?}");
    }

    #[test]
    fn velocity_settings_out_of_bounds_are_rejected_naming_the_field() {
        let bad = [
            (
                TrackerConfig {
                    position_noise_m: 0.0,
                    ..TrackerConfig::default()
                },
                "position_noise_m",
            ),
            (
                TrackerConfig {
                    position_noise_m: f64::NAN,
                    ..TrackerConfig::default()
                },
                "position_noise_m",
            ),
            (
                TrackerConfig {
                    position_noise_m: 0.06,
                    ..TrackerConfig::default()
                },
                "position_noise_m",
            ),
            (
                TrackerConfig {
                    velocity_samples: 2,
                    ..TrackerConfig::default()
                },
                "velocity_samples",
            ),
            (
                TrackerConfig {
                    velocity_samples: VELOCITY_SAMPLES_MAX + 1,
                    ..TrackerConfig::default()
                },
                "velocity_samples",
            ),
            (
                TrackerConfig {
                    velocity_window_ms: 0,
                    ..TrackerConfig::default()
                },
                "velocity_window_ms",
            ),
            (
                TrackerConfig {
                    velocity_window_ms: VELOCITY_WINDOW_MS_MAX + 1,
                    ..TrackerConfig::default()
                },
                "velocity_window_ms",
            ),
            (
                TrackerConfig {
                    still_speed_m_s: -0.01,
                    ..TrackerConfig::default()
                },
                "still_speed_m_s",
            ),
            (
                TrackerConfig {
                    still_speed_m_s: f64::NAN,
                    ..TrackerConfig::default()
                },
                "still_speed_m_s",
            ),
            (
                TrackerConfig {
                    still_speed_m_s: 6.0,
                    ..TrackerConfig::default()
                },
                "still_speed_m_s",
            ),
        ];
        for (cfg, field) in bad {
            let e = Tracker::new(cfg).unwrap_err();
            assert!(e.to_string().contains(field), "{field}: {e}");
        }
        Tracker::new(TrackerConfig {
            velocity_samples: 3,
            velocity_window_ms: 1,
            still_speed_m_s: 0.0,
            ..TrackerConfig::default()
        })
        .unwrap();
    }

    #[test]
    fn settle_settings_out_of_bounds_are_rejected_naming_the_field() {
        let bad = [
            TrackerConfig {
                settle_frames: 0,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                settle_frames: SETTLE_FRAMES_MAX + 1,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                settle_quiet_ms: SETTLE_QUIET_MS_MAX + 1,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                settle_motion_m: 0.001,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                settle_motion_m: 0.2,
                ..TrackerConfig::default()
            },
            TrackerConfig {
                settle_motion_m: f64::NAN,
                ..TrackerConfig::default()
            },
        ];
        let fields = [
            "settle_frames",
            "settle_frames",
            "settle_quiet_ms",
            "settle_motion_m",
            "settle_motion_m",
            "settle_motion_m",
        ];
        for (cfg, field) in bad.iter().zip(fields) {
            let e = Tracker::new(*cfg).unwrap_err();
            assert!(e.to_string().contains(field), "{field}: {e}");
        }
        Tracker::new(TrackerConfig {
            settle_frames: 1,
            settle_quiet_ms: 0,
            settle_motion_m: 0.05,
            ..TrackerConfig::default()
        })
        .unwrap();
    }
}
