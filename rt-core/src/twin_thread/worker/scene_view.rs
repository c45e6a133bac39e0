//! [`SceneView`]: the scene the worker plans on, and the gates that keep it from planning —
//! a refused frame, a world still changing (not settled), no goal in sight.
//!
//! Plans are made only on a *settled* scene (perception's `FRAME_SETTLED`: every object
//! confirmed, nothing appearing, disappearing or moving): an intermediate view of a
//! changing world is re-verified against (and may revoke the running plan) but never gets a
//! plan approved — but two: a plan joining the running one before the stop the plan guard
//! scheduled on it (`TwinWorker`'s join before stopping), and, with `plan_in_moving_world`,
//! a plan from rest on the scene as it is now ([`SceneView::ready_unsettled`]; see the
//! worker's `moving` module). Scenes that do not come from a camera (a fixed scene, a bench)
//! are settled.

/// Why no plan can be made on the scene now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// No accepted frame yet.
    NoScene,
    /// The latest frame was refused: nothing is planned until a good frame arrives.
    Refused,
    /// The latest accepted frame is not settled: the world is changing.
    Unsettled,
    /// The latest accepted frame has no goal: there is nothing to plan toward.
    NoGoal,
}

/// What a new accepted frame changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameChange {
    /// A plan is due because of it (a refusal ended, the goal appeared or went, the scene
    /// changed).
    pub plan_due: bool,
    /// The scene itself changed: the running plan must be re-verified.
    pub scene_changed: bool,
}

/// The latest accepted scene and its gates.
#[derive(Debug, Clone)]
pub struct SceneView<S> {
    scene: Option<S>,
    /// Capture stamp of the latest accepted frame (cycle clock), ns.
    stamp_ns: u64,
    refused: bool,
    goal_seen: bool,
    settled: bool,
    /// [`Hold::NoGoal`] was reported for the current stretch without a goal.
    no_goal_reported: bool,
    /// [`Hold::Unsettled`] was reported for the current unsettled stretch.
    unsettled_reported: bool,
    /// The latest frame shows an obstacle moving (its `intruders`): a world still changing
    /// because something moves, not only because its object set is being confirmed.
    moving_seen: bool,
    /// Action goals withdrawn when the latest frame was accepted (see
    /// [`crate::twin_thread::intake::AcceptedFrame::goal_epoch`]): plans made on this scene
    /// are registered with it.
    goal_epoch: u64,
    /// The scene an episode plan that ended at its goal was approved in (camera goals: the
    /// arm then rests at home until the goal or the scene changes, the `acceptance`
    /// module). Compared with the scene in force, not cleared by it: while the arm hovers
    /// over the goal it may hide the cube from the camera, and the scene seen from home
    /// again is the one the plan was made in. Cleared by a withdrawn action goal.
    goal_reached_in: Option<S>,
}

impl<S: Copy + PartialEq> Default for SceneView<S> {
    fn default() -> Self {
        Self {
            scene: None,
            stamp_ns: 0,
            refused: false,
            goal_seen: false,
            settled: false,
            no_goal_reported: false,
            unsettled_reported: false,
            moving_seen: false,
            goal_epoch: 0,
            goal_reached_in: None,
        }
    }
}

impl<S: Copy + PartialEq> SceneView<S> {
    /// The scene plans are made on, or why none can be: refused first, then no scene, not
    /// settled, no goal.
    ///
    /// # Errors
    /// The [`Hold`].
    pub fn ready(&self) -> Result<S, Hold> {
        if self.refused {
            return Err(Hold::Refused);
        }
        let Some(scene) = self.scene else {
            return Err(Hold::NoScene);
        };
        if !self.settled {
            return Err(Hold::Unsettled);
        }
        if !self.goal_seen {
            return Err(Hold::NoGoal);
        }
        Ok(scene)
    }

    /// As [`SceneView::ready`] but for the world still changing: the scene with its
    /// moving boxes as their predicted volumes, or why none can be planned on (refused, no
    /// scene, no goal).
    ///
    /// # Errors
    /// The [`Hold`] other than [`Hold::Unsettled`].
    pub fn ready_unsettled(&self) -> Result<S, Hold> {
        match self.ready() {
            Err(Hold::Unsettled) if self.goal_seen => self.scene.ok_or(Hold::NoScene),
            Err(Hold::Unsettled) => Err(Hold::NoGoal),
            other => other,
        }
    }

    /// The latest accepted frame is settled (nothing appearing, disappearing or moving).
    pub fn settled(&self) -> bool {
        self.settled
    }

    /// The latest accepted scene, whatever its gates.
    pub fn scene(&self) -> Option<S> {
        self.scene
    }

    /// Capture stamp of the latest accepted frame, ns.
    pub fn stamp_ns(&self) -> u64 {
        self.stamp_ns
    }

    /// An accepted frame arrived.
    pub fn accept(
        &mut self,
        scene: S,
        stamp_ns: u64,
        goal_seen: bool,
        settled: bool,
    ) -> FrameChange {
        let mut change = FrameChange::default();
        self.stamp_ns = stamp_ns;
        if self.refused {
            self.refused = false;
            change.plan_due = true;
        }
        if goal_seen != self.goal_seen {
            self.goal_seen = goal_seen;
            self.no_goal_reported = false;
            change.plan_due = true;
        }
        if settled != self.settled {
            // A plan due while unsettled stays due: it is made on the first settled frame.
            // Settling alone (the same scene) asks for no new plan.
            self.settled = settled;
            self.unsettled_reported = false;
        }
        if self.scene != Some(scene) {
            self.scene = Some(scene);
            change.plan_due = true;
            change.scene_changed = true;
        }
        change
    }

    /// Whether the latest frame shows an obstacle moving.
    pub fn moving_seen(&self) -> bool {
        self.moving_seen
    }

    /// The latest frame shows an obstacle moving (`moving`) or none.
    pub fn set_moving_seen(&mut self, moving: bool) {
        self.moving_seen = moving;
    }

    /// The withdrawn-goal count the latest frame was accepted under.
    pub fn goal_epoch(&self) -> u64 {
        self.goal_epoch
    }

    /// The latest frame was accepted under `goal_epoch` withdrawn goals.
    pub fn set_goal_epoch(&mut self, goal_epoch: u64) {
        if goal_epoch != self.goal_epoch {
            self.goal_reached_in = None;
        }
        self.goal_epoch = goal_epoch;
    }

    /// An episode plan approved in `scene` ended at its goal.
    pub fn mark_goal_reached(&mut self, scene: S) {
        self.goal_reached_in = Some(scene);
    }

    /// A settled `scene` seen with the arm at rest away from the goal: a goal reached in
    /// another scene is forgotten (the world changed; back to the same scene later, its
    /// goal is driven again).
    pub fn forget_goal_reached_unless(&mut self, scene: S) {
        if self.goal_reached_in != Some(scene) {
            self.goal_reached_in = None;
        }
    }

    /// Whether the scene in force is one whose goal an episode plan reached last.
    pub fn goal_reached(&self) -> bool {
        self.goal_reached_in.is_some() && self.goal_reached_in == self.scene
    }

    /// A frame was refused.
    pub fn refuse(&mut self) {
        self.refused = true;
    }

    /// Whether `hold` should be reported now: once per stretch of [`Hold::Unsettled`] or
    /// [`Hold::NoGoal`].
    pub fn report_once(&mut self, hold: Hold) -> bool {
        let reported = match hold {
            Hold::Unsettled => &mut self.unsettled_reported,
            Hold::NoGoal => &mut self.no_goal_reported,
            Hold::NoScene | Hold::Refused => return false,
        };
        !std::mem::replace(reported, true)
    }
}
