//! Stable object ids across frames and debouncing of what is reported.
//!
//! Detections are matched to tracks of the same class by nearest position on the table
//! (greedy, within `match_gate_m`). A new object is reported once it has been seen in `persist_frames`
//! consecutive frames; a lost one is dropped after `persist_frames` misses. A reported
//! object's position or size changes only when the new measurement differs from the
//! reported one by more than `noise_tolerance_m` for `persist_frames` consecutive frames, or
//! at once when it differs by more than `jump_m` (a box swapped for a taller one).

use serde::{Deserialize, Serialize};

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
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            match_gate_m: 0.08,
            persist_frames: 3,
            noise_tolerance_m: 0.005,
            jump_m: 0.05,
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
        Ok(())
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
}

/// The tracker.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    tracks: Vec<Track>,
    next_id: u32,
    pairs: Vec<(f64, usize, usize)>,
}

/// Distance on the table (x, y): a box swapped for a taller one moves its centre up, not
/// across, and must stay the same object.
fn dist_xy(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
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
        })
    }

    /// Feeds one frame's detections; returns whether the reported set changed (an object
    /// appeared, disappeared, moved or changed size).
    pub fn update(&mut self, detections: &[Detection]) -> bool {
        let cfg = self.config;
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
            let t = &mut self.tracks[ti];
            t.latest = (d.position_m, d.size_m);
            t.confidence = d.confidence;
            t.missed = 0;
            t.seen = t.seen.saturating_add(1);
            match t.reported {
                None => {
                    if t.seen >= cfg.persist_frames {
                        t.reported = Some(t.latest);
                        changed = true;
                    }
                }
                Some(rep) => {
                    let dev = max_dev(&rep, &t.latest);
                    if dev > cfg.jump_m {
                        t.reported = Some(t.latest);
                        t.changing = 0;
                        changed = true;
                    } else if dev > cfg.noise_tolerance_m {
                        t.changing += 1;
                        if t.changing >= cfg.persist_frames {
                            t.reported = Some(t.latest);
                            t.changing = 0;
                            changed = true;
                        }
                    } else {
                        t.changing = 0;
                    }
                }
            }
        }
        let mut keep = Vec::with_capacity(self.tracks.len());
        for (ti, mut t) in std::mem::take(&mut self.tracks).into_iter().enumerate() {
            if !track_hit[ti] {
                t.seen = 0;
                t.missed += 1;
                if t.reported.is_none() {
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
            self.tracks.push(Track {
                id,
                kind: d.kind,
                confidence: d.confidence,
                latest,
                reported: confirmed.then_some(latest),
                seen: 1,
                missed: 0,
                changing: 0,
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
                })
            })
            .collect();
        v.sort_by_key(|o| (o.kind != ObjectKind::Goal, o.id));
        v
    }
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
        assert!(!t.update(&[g.clone(), o.clone()]));
        assert!(!t.update(&[g.clone(), o.clone()]));
        assert!(t.objects().is_empty());
        assert!(t.update(&[o.clone(), g.clone()]));
        let objs = t.objects();
        assert_eq!(objs.len(), 2);
        assert_eq!(objs[0].kind, ObjectKind::Goal);
        let ids: Vec<u32> = objs.iter().map(|o| o.id).collect();
        // Jitter below the tolerance changes nothing, ids stay.
        let mut o2 = o.clone();
        o2.position_m[0] += 0.003;
        for _ in 0..5 {
            assert!(!t.update(&[g.clone(), o2.clone()]));
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
        t.update(std::slice::from_ref(&o));
        t.update(std::slice::from_ref(&o));
        let id = t.objects()[0].id;
        let mut moved = o.clone();
        moved.position_m[1] += 0.02;
        assert!(
            !t.update(std::slice::from_ref(&moved)),
            "one frame is not enough"
        );
        assert!(t.update(std::slice::from_ref(&moved)));
        assert!((t.objects()[0].position_m[1] - 0.02).abs() < 1e-12);
        // The small box is swapped for a tall one at the same place: counts at once.
        let mut tall = moved.clone();
        tall.size_m[2] = 0.3;
        tall.position_m[2] = 0.15;
        assert!(t.update(std::slice::from_ref(&tall)));
        assert_eq!(t.objects()[0].size_m[2], 0.3);
        assert_eq!(t.objects()[0].id, id);
        // A one-frame dropout keeps the object; persisting absence removes it.
        assert!(!t.update(&[]));
        assert_eq!(t.objects().len(), 1);
        assert!(t.update(&[]));
        assert!(t.objects().is_empty());
        // Something new gets a new id.
        t.update(std::slice::from_ref(&o));
        t.update(std::slice::from_ref(&o));
        assert!(t.objects()[0].id > id);
    }

    #[test]
    fn classes_do_not_match_each_other_and_bad_settings_are_rejected() {
        let mut t = Tracker::new(TrackerConfig {
            persist_frames: 1,
            ..TrackerConfig::default()
        })
        .unwrap();
        t.update(&[det(ObjectKind::Goal, [0.4, 0.0, 0.025], [0.05; 3])]);
        t.update(&[
            det(ObjectKind::Goal, [0.4, 0.0, 0.025], [0.05; 3]),
            det(ObjectKind::Obstacle, [0.4, 0.0, 0.025], [0.05; 3]),
        ]);
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
}
