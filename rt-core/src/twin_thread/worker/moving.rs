//! Planning in a moving world (issue 42 item 1, `plan_in_moving_world`): from rest, the worker
//! plans on the scene as it is now, not only on a settled one. A frame perception has not
//! marked settled already counts each obstacle as the volume it may sweep from its capture
//! over `intake.prediction_horizon_s` — along its velocity, grown by its uncertainty
//! ([`crate::twin_thread::intake::predicted_occupancy`]) — and that horizon is never shorter
//! than the reaction plus the arm's longest stop
//! ([`crate::config::RuntimeConfig::prediction_floor_s`]). A plan approved in such a scene is
//! clear of every moving box for as long as the arm needs to see it coming and stop; the plan
//! guard re-verifies it against every later frame, so a box that turns towards the way stops
//! the arm (or revokes the plan before the cycle adopts it) as for any plan. A box moving
//! beside or away from the way thus no longer delays the start.
//!
//! Only a world that changes because something is *seen moving* (the frame names moving
//! obstacles: the intake's `Intruders`) is planned on this way. A frame unsettled only
//! because perception is still confirming its object set (a world change: the new goal
//! with the old box, a box not confirmed yet and so not in the frame) still waits for the
//! settled one (issue 15). An object just seen, of unknown velocity, counts as moving, but
//! its volume is grown by the assumed intruder speed over the horizon and blocks every plan
//! until its velocity is known.
//!
//! What stays as before: while the arm follows a plan, an unsettled frame gets no new plan
//! of its own but the join before a scheduled stop (the running plan is re-verified); and
//! a planning that fails on a scene still changing asks for no retraining (a moment of a
//! moving world is no task to learn).

use super::{Hold, Lookahead, TwinWorker};
use crate::cycle::Mode;
use crate::cycle::shield::ShieldModel;

/// Whether a failed planning on a scene asks for retraining: not on a scene still changing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum RetrainOnFailure {
    Yes,
    No,
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// Whether a plan from rest may be made on the current scene although it is not
    /// settled: planning in a moving world is on, the latest frame shows an obstacle moving
    /// (a frame unsettled only because perception is still confirming its objects — a world
    /// change, a box not yet in the frame — still waits for the settled one), and the cycle
    /// (as of its last report) stands still — idle or stopped, not following nor stopping.
    pub(super) fn plans_in_moving_world(&self) -> bool {
        self.settings.plan_in_moving_world
            && self.scene.moving_seen()
            && self.cycle.report.is_some_and(|r| {
                // Not while a plan sent since is on its way (the cycle may have adopted it
                // already): a plan from rest would be refused once it follows.
                matches!(r.mode, Mode::Idle | Mode::Stopped)
                    && !self.sent.live.iter().any(|(p, _)| p.id > r.plan_id)
            })
    }

    /// After a pause in a world still moving, when no continuation passed: the way home
    /// waits (true) and the continuation is tried again on the next frame — the box that
    /// stopped the arm may be passing, and going home at once costs the episode (with the
    /// setting off, nothing was planned before the world settled).
    pub(super) fn home_waits_for_the_world(&mut self) -> bool {
        let waits = self.plans_in_moving_world() && self.scene.ready() == Err(Hold::Unsettled);
        if waits {
            self.planning.taken();
        }
        waits
    }

    /// The scene a plan from rest is made on, with whether a failure there asks for
    /// retraining: a settled scene with a goal, or — planning in a moving world, the arm at
    /// rest — the scene as it is now (its moving boxes as their predicted volumes).
    ///
    /// # Errors
    /// The [`Hold`] that keeps the worker from planning.
    pub(super) fn scene_at_rest(&self) -> Result<(L::Scene, RetrainOnFailure), Hold> {
        match self.scene.ready() {
            Ok(scene) => Ok((scene, RetrainOnFailure::Yes)),
            Err(Hold::Unsettled) if self.plans_in_moving_world() => self
                .scene
                .ready_unsettled()
                .map(|scene| (scene, RetrainOnFailure::No)),
            Err(hold) => Err(hold),
        }
    }
}
