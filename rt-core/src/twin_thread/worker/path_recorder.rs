//! [`PathRecorder`]: the excursion — the path the arm executed since it left home (at
//! rest), at the cycle's rate, joined plans included; and the way home, that path reversed.
//! Whether a controlled stop interrupted the excursion is the phase's
//! ([`super::phase::Excursion`]).

use twin::{Joints, max_joint_gap_rad};

use crate::cycle::plan::MotionState;
use crate::cycle::plan::{JoinPoint, Plan};

/// A rest pose this close (every joint) to a sample of the recorded path lies on it, rad.
const ON_PATH_TOLERANCE_RAD: f64 = 0.05;

/// The executed path from where the excursion began.
#[derive(Debug, Clone, Default)]
pub struct PathRecorder {
    /// Cycle-rate samples from where the excursion began (at rest) to the end of the last
    /// approved episode plan.
    path: Vec<Joints>,
    /// Where the sent plan's samples start in `path`.
    sent_offset: usize,
}

impl PathRecorder {
    /// Samples recorded.
    pub fn len(&self) -> usize {
        self.path.len()
    }

    /// Nothing recorded.
    pub fn is_empty(&self) -> bool {
        self.path.is_empty()
    }

    /// Home: the next excursion starts here.
    pub fn arrive_home(&mut self) {
        self.path.clear();
    }

    /// Extends the path with an approved episode plan starting at `start` (joining the
    /// sent plan at `join` unless that one is a way home).
    pub fn record_episode_plan(
        &mut self,
        start: &MotionState,
        join: Option<JoinPoint>,
        sent_is_return: bool,
        plan: &Plan,
    ) {
        match join {
            Some(j) if !sent_is_return => {
                self.path.truncate(self.sent_offset + j.index);
            }
            _ => {
                // From rest: on the recorded path the path is cut there; anywhere else a
                // new excursion begins here.
                if !self.cut_at(&start.q_rad) {
                    self.path.clear();
                    self.path.push(start.q_rad);
                }
            }
        }
        self.sent_offset = self.path.len();
        self.path.extend_from_slice(&plan.q_rad);
    }

    /// Where the arm rests at `q` on the recorded path (the end of the last plan, a brake's
    /// end near one of its samples, a return cut short), cuts the path there, ending exactly
    /// at `q`, and returns true; false (path untouched) when `q` is off the path.
    pub fn cut_at(&mut self, q: &Joints) -> bool {
        let Some((i, gap)) = self
            .path
            .iter()
            .enumerate()
            .map(|(i, p)| (i, max_joint_gap_rad(p, q)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|(_, g)| *g <= ON_PATH_TOLERANCE_RAD)
        else {
            return false;
        };
        self.path.truncate(i + 1);
        if gap > 1e-9 {
            self.path.push(*q);
        }
        true
    }

    /// The way home into `waypoints`: the executed path reversed, one waypoint every
    /// `stride` samples (a twin step), ending exactly where the excursion began.
    pub fn way_home(&self, stride: usize, waypoints: &mut Vec<Joints>) {
        waypoints.clear();
        let Some(first) = self.path.first() else {
            return;
        };
        let stride = stride.max(1);
        let mut i = self.path.len() - 1;
        while i > stride {
            i -= stride;
            waypoints.push(self.path[i]);
        }
        waypoints.push(*first);
    }
}
