//! A taken goal, said at once (issue 42 item 4). When every candidate failed on a settled
//! scene, the lookahead is asked whether a box has taken the goal ([`Lookahead::goal_taken`]:
//! it overlaps the goal cube, or blocks every goal posture). If so the worker says it —
//! [`TwinEvent::GoalTaken`], published as an `infeasible: <reason>` verdict — on that
//! frame's planning, instead of asking the learner to retrain for a goal no policy can
//! reach; nothing is sent, so the arm holds (at rest, or stopped by the plan guard, which
//! re-verified the running plan against the same scene). Said once per scene; a later scene
//! is planned on as ever, so when the box leaves the goal is live again.
//!
//! While the arm backs out ([`retreat`](super::retreat)) nothing is planned until the retreat
//! ends, about a second; so each new settled scene is asked then too, and a taken goal is
//! said on the first one that shows it. The retreat goes on; the planning after it finds the
//! goal already said for that scene and holds.
//!
//! [`goal_overlap`] is the first half of the real twin's check ([`TwinLookahead`]'s).
//!
//! [`TwinLookahead`]: crate::twin_thread::lookahead::TwinLookahead

use twin::{Blocker, InfeasibleReason, LINK_TOOL, Scene};

use super::{Lookahead, Phase, TwinEvent, TwinWorker};
use crate::cycle::shield::ShieldModel;

/// The scene the goal was last said taken in (a newer scene is checked again), and the last
/// scene asked about while the arm backs out.
#[derive(Debug, Clone, Copy)]
pub struct GoalWatch<S> {
    taken_in: Option<S>,
    asked_backing_out: Option<S>,
}

impl<S> Default for GoalWatch<S> {
    fn default() -> Self {
        Self {
            taken_in: None,
            asked_backing_out: None,
        }
    }
}

impl<S: Copy + PartialEq> GoalWatch<S> {
    /// The goal was said taken in `scene`.
    pub fn taken_in(&self, scene: &S) -> bool {
        self.taken_in.as_ref() == Some(scene)
    }
}

/// The first box (its index) overlapping the goal cube of `scene` by more than `slack_m` on
/// every axis, and by how much on the axis it overlaps least, m.
pub fn goal_overlap(scene: &Scene, slack_m: f64) -> Option<(usize, f64)> {
    let g = &scene.goal;
    let half_goal = g.size_m / 2.0;
    scene.obstacles.iter().enumerate().find_map(|(i, b)| {
        let depth_m = (0..3)
            .map(|k| half_goal + b.size_m[k] / 2.0 - (b.center_m[k] - g.center_m[k]).abs())
            .fold(f64::INFINITY, f64::min);
        (depth_m > slack_m).then_some((i, depth_m))
    })
}

/// The goal cube of `scene` overlapped by a box, as the reason the feasibility check gives
/// for a box blocking every goal posture: the box, the tool, by the overlap.
pub fn goal_overlap_reason(scene: &Scene, slack_m: f64) -> Option<InfeasibleReason> {
    goal_overlap(scene, slack_m).map(|(i, depth_m)| InfeasibleReason::NoGoalPosture {
        blocker: Blocker::Box(i),
        link: LINK_TOOL,
        deficit_m: depth_m,
        postures_tried: 0,
    })
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// After every candidate failed in `scene`: whether the goal is taken there (a settled
    /// scene only: a box passing by is not a taken goal). The first time in a scene the
    /// [`TwinEvent::GoalTaken`] is pushed. True: nothing more is tried (no sampling, no
    /// planner, no retraining), the arm holds.
    pub(super) fn goal_taken_in(
        &mut self,
        scene: L::Scene,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        if !self.settings.gate || !self.scene.settled() {
            return false;
        }
        if self.goal.taken_in(&scene) {
            return true;
        }
        let Some(policy) = self.library.current() else {
            return false;
        };
        let policy_id = L::policy_id(policy);
        let Some(reason) = self.approver.lookahead_mut().goal_taken(policy, &scene) else {
            self.goal.taken_in = None;
            return false;
        };
        self.goal.taken_in = Some(scene);
        events.push(TwinEvent::GoalTaken {
            reason,
            policy_id,
            scene,
        });
        true
    }

    /// While a retreat runs: each new settled scene is asked whether a box has taken the
    /// goal ([`Self::goal_taken_in`]), once per scene, so that it is said within the
    /// issue's second rather than after the retreat. Nothing is sent or revoked here.
    pub(super) fn say_taken_goal_while_backing_out(
        &mut self,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) {
        if !matches!(
            self.excursion.phase(),
            Phase::BackingOut { done: false, .. }
        ) {
            return;
        }
        let Ok(scene) = self.scene.ready() else {
            return;
        };
        if self.goal.asked_backing_out == Some(scene) {
            return;
        }
        self.goal.asked_backing_out = Some(scene);
        self.goal_taken_in(scene, events);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use twin::{BoxObstacle, Goal};

    fn scene_with(center_m: [f64; 3], size_m: [f64; 3]) -> Scene {
        let mut s = Scene::empty(
            0.0,
            Goal {
                center_m: [0.3, 0.25, 0.025],
                size_m: 0.05,
            },
        );
        s.obstacles
            .push(BoxObstacle { center_m, size_m })
            .unwrap_or_else(|_| panic!("room for one box"));
        s
    }

    #[test]
    fn a_box_on_the_goal_cube_takes_it_and_one_beside_it_does_not() {
        let on = scene_with([0.31, 0.25, 0.06], [0.06, 0.06, 0.12]);
        let (i, depth_m) = goal_overlap(&on, 0.0).unwrap_or_else(|| panic!("overlap"));
        assert_eq!(i, 0);
        assert!((depth_m - 0.045).abs() < 1e-9, "{depth_m}");
        assert!(matches!(
            goal_overlap_reason(&on, 0.0),
            Some(InfeasibleReason::NoGoalPosture {
                blocker: Blocker::Box(0),
                link: LINK_TOOL,
                ..
            })
        ));
        let beside = scene_with([0.40, 0.25, 0.06], [0.06, 0.06, 0.12]);
        assert_eq!(goal_overlap(&beside, 0.0), None);
    }
}
