//! Obstacle paths: where a moving box's centre is at a time.
//!
//! A path is a list of keyframes `{ at_s, center_m }` with strictly ascending times. The
//! centre moves linearly between keyframes, sits at the first keyframe before it and is held
//! at the last keyframe after it. Time is counted from the moment the scene came into force
//! (see [`super::LiveScene`] for how processes agree on that moment).
//!
//! ```toml
//! [[obstacle]]
//! center_m = [0.05, 0.20, 0.10]
//! size_m = [0.06, 0.06, 0.20]
//! path = [ { at_s = 1.0, center_m = [0.05, 0.20, 0.10] },
//!          { at_s = 2.7, center_m = [0.55, 0.08, 0.10] } ]
//! ```
//!
//! The path has a fixed capacity ([`MAX_KEYFRAMES`]) so that [`super::BoxSpec`] stays `Copy`;
//! a longer list is refused when the file is parsed.

use serde::{Deserialize, Serialize};

/// Most keyframes one obstacle's path may hold.
pub const MAX_KEYFRAMES: usize = 32;

/// One keyframe of an obstacle's path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Time since the scene came into force (s).
    pub at_s: f64,
    /// Box centre at that time, in the base frame (m).
    pub center_m: [f64; 3],
}

/// A path given more than [`MAX_KEYFRAMES`] keyframes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("path holds {len} keyframes, at most {MAX_KEYFRAMES} are supported")]
pub struct BoxPathCapacityError {
    /// The number of keyframes given.
    pub len: usize,
}

/// An obstacle's path: up to [`MAX_KEYFRAMES`] keyframes (empty: the box stands still).
/// In TOML an array of `{ at_s, center_m }` tables.
#[derive(Clone, Copy, Serialize, Deserialize)]
#[serde(try_from = "Vec<Keyframe>", into = "Vec<Keyframe>")]
pub struct BoxPath {
    keyframes: [Keyframe; MAX_KEYFRAMES],
    len: usize,
}

const NO_KEYFRAME: Keyframe = Keyframe {
    at_s: 0.0,
    center_m: [0.0; 3],
};

impl BoxPath {
    /// No keyframes: a box that stands still.
    pub const EMPTY: BoxPath = BoxPath {
        keyframes: [NO_KEYFRAME; MAX_KEYFRAMES],
        len: 0,
    };

    /// A path through `keyframes` (not validated: [`super::SceneFile::validate`] does that).
    ///
    /// # Errors
    /// [`BoxPathCapacityError`] for more than [`MAX_KEYFRAMES`] keyframes.
    pub fn new(keyframes: &[Keyframe]) -> Result<Self, BoxPathCapacityError> {
        if keyframes.len() > MAX_KEYFRAMES {
            return Err(BoxPathCapacityError {
                len: keyframes.len(),
            });
        }
        let mut path = Self::EMPTY;
        path.keyframes[..keyframes.len()].copy_from_slice(keyframes);
        path.len = keyframes.len();
        Ok(path)
    }

    /// The keyframes.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes[..self.len.min(MAX_KEYFRAMES)]
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.keyframes().len()
    }

    /// Whether the path has no keyframes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether the path takes the box through more than one place.
    pub fn is_moving(&self) -> bool {
        let k = self.keyframes();
        k.iter().any(|f| f.center_m != k[0].center_m)
    }

    /// The centre `t_s` seconds after the scene came into force: the first keyframe's
    /// before it, linear between keyframes, the last keyframe's after it; `None` for an
    /// empty path. Times that do not ascend (refused by validation) never divide by zero:
    /// such a segment jumps to its later keyframe.
    pub fn center_at(&self, t_s: f64) -> Option<[f64; 3]> {
        let k = self.keyframes();
        let first = k.first()?;
        if t_s.is_nan() || t_s <= first.at_s {
            return Some(first.center_m);
        }
        for w in k.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            if t_s < b.at_s {
                let span_s = b.at_s - a.at_s;
                if span_s <= 0.0 {
                    return Some(b.center_m);
                }
                let u = ((t_s - a.at_s) / span_s).clamp(0.0, 1.0);
                return Some(std::array::from_fn(|i| {
                    a.center_m[i] + u * (b.center_m[i] - a.center_m[i])
                }));
            }
        }
        k.last().map(|f| f.center_m)
    }

    /// The centre's velocity `t_s` seconds after the scene came into force (m/s): the slope
    /// of the segment that holds `t_s` (at a keyframe, the segment that starts there); zero
    /// before the first and from the last keyframe on.
    pub fn velocity_at(&self, t_s: f64) -> [f64; 3] {
        for w in self.keyframes().windows(2) {
            let (a, b) = (&w[0], &w[1]);
            let span_s = b.at_s - a.at_s;
            if t_s >= a.at_s && t_s < b.at_s && span_s > 0.0 {
                return std::array::from_fn(|i| (b.center_m[i] - a.center_m[i]) / span_s);
            }
        }
        [0.0; 3]
    }
}

impl Default for BoxPath {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl PartialEq for BoxPath {
    fn eq(&self, other: &Self) -> bool {
        self.keyframes() == other.keyframes()
    }
}

impl std::fmt::Debug for BoxPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.keyframes()).finish()
    }
}

impl TryFrom<Vec<Keyframe>> for BoxPath {
    type Error = BoxPathCapacityError;

    fn try_from(v: Vec<Keyframe>) -> Result<Self, Self::Error> {
        Self::new(&v)
    }
}

impl From<BoxPath> for Vec<Keyframe> {
    fn from(p: BoxPath) -> Self {
        p.keyframes().to_vec()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kf(at_s: f64, x: f64) -> Keyframe {
        Keyframe {
            at_s,
            center_m: [x, 0.1, 0.05],
        }
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn the_centre_sits_before_moves_between_and_holds_after_the_keyframes() {
        let p = BoxPath::new(&[kf(1.0, 0.2), kf(2.0, 0.4), kf(4.0, 0.0)]).unwrap();
        // Before the first keyframe (and at it): the first centre.
        assert_eq!(p.center_at(0.0), Some([0.2, 0.1, 0.05]));
        assert_eq!(p.center_at(-3.0), Some([0.2, 0.1, 0.05]));
        assert_eq!(p.center_at(1.0), Some([0.2, 0.1, 0.05]));
        // Between: linear.
        assert!(close(p.center_at(1.25).unwrap(), [0.25, 0.1, 0.05]));
        assert!(close(p.center_at(2.0).unwrap(), [0.4, 0.1, 0.05]));
        assert!(close(p.center_at(3.0).unwrap(), [0.2, 0.1, 0.05]));
        // After the last: held.
        assert_eq!(p.center_at(4.0), Some([0.0, 0.1, 0.05]));
        assert_eq!(p.center_at(1e9), Some([0.0, 0.1, 0.05]));
        assert_eq!(BoxPath::EMPTY.center_at(1.0), None);
    }

    #[test]
    fn the_velocity_is_the_slope_of_the_segment_in_force() {
        let p = BoxPath::new(&[kf(1.0, 0.2), kf(2.0, 0.5), kf(4.0, 0.1)]).unwrap();
        assert_eq!(p.velocity_at(0.5), [0.0; 3]);
        assert!(close(p.velocity_at(1.0), [0.3, 0.0, 0.0]));
        assert!(close(p.velocity_at(1.5), [0.3, 0.0, 0.0]));
        assert!(close(p.velocity_at(3.0), [-0.2, 0.0, 0.0]));
        assert_eq!(p.velocity_at(4.0), [0.0; 3]);
        assert!(p.is_moving());
        let still = BoxPath::new(&[kf(0.0, 0.2), kf(5.0, 0.2)]).unwrap();
        assert!(!still.is_moving());
        assert_eq!(still.velocity_at(1.0), [0.0; 3]);
        assert!(!BoxPath::EMPTY.is_moving());
    }

    #[test]
    fn bad_times_never_divide_by_zero_and_the_capacity_is_enforced() {
        let p = BoxPath::new(&[kf(1.0, 0.2), kf(1.0, 0.4)]).unwrap();
        assert_eq!(p.center_at(1.0), Some([0.2, 0.1, 0.05]));
        assert_eq!(p.center_at(f64::NAN), Some([0.2, 0.1, 0.05]));
        assert_eq!(p.velocity_at(1.0), [0.0; 3]);
        let many = vec![kf(0.0, 0.1); MAX_KEYFRAMES + 1];
        assert_eq!(
            BoxPath::try_from(many),
            Err(BoxPathCapacityError {
                len: MAX_KEYFRAMES + 1
            })
        );
    }
}
