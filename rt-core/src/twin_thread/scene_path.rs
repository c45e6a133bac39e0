//! The scene path: an accepted frame's scene goes to the cycle's shield at once and to the
//! [`PlanGuard`], which re-verifies every live plan against it — before, and independently
//! of, anything the twin worker does with the frame (plan, look ahead, search a path).
//!
//! In `rt-core run` the path runs on the intake thread (`twin_thread::intake_thread`), so
//! a planner search, a lookahead or a policy hand-over on the twin thread can delay neither
//! the cycle's scene nor the re-verification. The tests and the sweep, which step everything
//! in one thread, call it themselves in the same order: [`ScenePath::accepted`] (or
//! [`ScenePath::refused`]), then the worker's one door for a frame,
//! [`crate::twin_thread::TwinWorker::note_frame`] (or `note_refused`).
//! [`crate::twin_thread::TwinWorker::new`] makes the path beside the worker.

// The guard is shared by two non-real-time threads (the intake thread and the twin thread);
// the cycle never takes this lock (it sees scenes through a lock-free latest-value hand-over).
#![allow(clippy::disallowed_types)]

use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use crate::cycle::shield::ShieldModel;
use crate::cycle::{Intruders, SceneUpdate};
use crate::rt::handoff::LatestSender;
use crate::twin_thread::plan_guard::PlanGuard;

/// The plan guard, shared by the scene path and the worker.
pub type SharedGuard<M> = Arc<Mutex<PlanGuard<M>>>;

/// The guard, made shareable.
pub fn share_guard<M: ShieldModel>(guard: PlanGuard<M>) -> SharedGuard<M> {
    Arc::new(Mutex::new(guard))
}

/// Locks the guard (a panic on the other side does not poison it for this one: the guard's
/// state is a list of plans and a scene, consistent between calls).
pub fn lock_guard<M: ShieldModel>(guard: &SharedGuard<M>) -> MutexGuard<'_, PlanGuard<M>> {
    guard.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The cycle's scene hand-over and the plan guard; see the module docs.
pub struct ScenePath<M: ShieldModel> {
    scenes: LatestSender<SceneUpdate<M::Scene>>,
    guard: SharedGuard<M>,
    /// The last accepted scene, its capture stamp and moving obstacles (kept for the
    /// shield after a refusal).
    last: Option<(M::Scene, u64, Intruders)>,
}

impl<M: ShieldModel> ScenePath<M> {
    /// A path handing scenes to the cycle through `scenes` and re-verifying with `guard`.
    pub fn new(scenes: LatestSender<SceneUpdate<M::Scene>>, guard: SharedGuard<M>) -> Self {
        Self {
            scenes,
            guard,
            last: None,
        }
    }

    /// An accepted frame's scene, captured at `stamp_ns` on the cycle's clock, with its
    /// obstacles seen moving: to the cycle first (the shield checks the next command against
    /// it, speed and separation monitoring watches the moving ones), then re-verification.
    pub fn accepted(&mut self, scene: M::Scene, stamp_ns: u64, intruders: Intruders) {
        self.scenes.send(SceneUpdate {
            scene,
            stamp_ns,
            refused: false,
            intruders,
        });
        self.last = Some((scene, stamp_ns, intruders));
        lock_guard(&self.guard).scene_captured_moving(scene, stamp_ns, intruders.any());
    }

    /// Stamps the accepted scenes with the time they reach the plan guard, on the cycle's
    /// clock whose origin is `origin_ns` on the monotonic clock.
    pub fn set_clock_origin(&self, origin_ns: u64) {
        lock_guard(&self.guard).set_clock_origin(origin_ns);
    }

    /// The action goal was withdrawn (cancelled or pre-empted; `goal_epoch` withdrawals in
    /// all, [`crate::twin_thread::intake::SceneIntake::goal_epoch`]): the plan guard revokes
    /// every plan toward it, held by the cycle or on its way ([`PlanGuard::withdraw_goal`]).
    pub fn goal_withdrawn(&mut self, goal_epoch: u64) {
        lock_guard(&self.guard).withdraw_goal(goal_epoch);
    }

    /// A refused frame: the cycle is told at once (it stops the arm, keeping the last
    /// trusted scene for the shield's clearance while stopping).
    pub fn refused(&mut self) {
        if let Some((scene, stamp_ns, intruders)) = self.last {
            self.scenes.send(SceneUpdate {
                scene,
                stamp_ns,
                refused: true,
                intruders,
            });
        }
    }
}
