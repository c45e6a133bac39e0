//! The simulator's ground truth: the scene in force, judged by the independent
//! [`Referee`] (its own DH kinematics, capsules and distance code; not the twin's geometry).
//! Gives the TCP pose for reports and tells whether the arm touches anything, and keeps the
//! referee's figures for the run ([`RefereeSummary`]).
//!
//! **Moving boxes.** A scene's boxes may follow paths
//! ([`shm_schemas::scene_file::BoxPath`]); time on a path counts from the moment the scene
//! came into force. The world keeps that moment on `CLOCK_MONOTONIC`
//! ([`World::set_scene_since`]: a live scene file's `in_force_since_monotonic_ns`, which the
//! launcher writes and the synthetic camera reads too, so both place a box at the same
//! instant; [`shm_schemas::scene_file::live`]) and each check ([`World::check_at`], once per
//! physics tick) places every box where its path puts it at the tick's time before judging.
//!
//! **Contacts while moving, contacts at rest.** A contact counts as the controller's
//! failure ([`RefereeSummary::contacts_while_moving`]) when the arm was moving as it began:
//! some joint's measured speed (the change of the checked joints over the time between two
//! checks) above [`ARM_MOVING_RAD_S`] in that tick or the previous one. Otherwise a box
//! walked into an arm at rest ([`RefereeSummary::contacts_at_rest`]). Both raise the
//! controller's collision error (31), as on a real xArm, whose collision detection also trips
//! when a person pushes a stopped arm; the split only says whose doing the contact was.
//!
//! **The reported TCP pose comes from the referee's kinematics** (UFactory's DH table), not
//! from the twin's URDF model: the controller has kinematics of its own, so a comparison of
//! the twin's TCP with the TCP the (simulated) controller reports in rt-core compares two
//! independent models and can reveal a URDF error. The twin's model is still loaded, for the
//! home posture and the controller's servo-mode TCP speed check.

use std::path::{Path, PathBuf};

use shm_schemas::clock::monotonic_now_ns;
use shm_schemas::scene_file::SceneFile;
use shm_schemas::scene_file::live::seconds_since;

use twin::{RobotModel, Scene};

use crate::referee::{Clearance, Referee, RefereeCheckError, RefereeSceneError};

/// Why the world could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// The URDF could not be loaded.
    #[error("cannot load robot model {path}: {reason}")]
    Model {
        /// The URDF path.
        path: PathBuf,
        /// What failed.
        reason: String,
    },
    /// The scene is not valid for the twin or the referee.
    #[error("invalid scene {name:?}: {reason}")]
    Scene {
        /// Scene name.
        name: String,
        /// What failed.
        reason: String,
    },
}

/// A joint faster than this (rad/s) means the arm is moving, for telling
/// [`RefereeSummary::contacts_while_moving`] from [`RefereeSummary::contacts_at_rest`].
pub const ARM_MOVING_RAD_S: f64 = 1e-3;

/// The referee's figures for a run, reported in the simulator's summary (`referee`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RefereeSummary {
    /// Motion steps judged (one per physics tick).
    pub steps: u64,
    /// Configurations evaluated (two per step, more where a step was bisected).
    pub evaluations: u64,
    /// Contacts: times the arm went from clear to touching (each raised error 31);
    /// `contacts_while_moving + contacts_at_rest`.
    pub contacts: u64,
    /// Contacts that began while the arm was moving (a joint faster than
    /// [`ARM_MOVING_RAD_S`] in that tick or the previous one): the controller's failure.
    pub contacts_while_moving: u64,
    /// Contacts that began with the arm at rest: a moving box walked into it.
    pub contacts_at_rest: u64,
    /// The clearance at the latest judged tick (m); `None` before the first. Polled over a
    /// run, the clearance over time.
    pub clearance_m: Option<f64>,
    /// Configurations the referee could not judge (non-finite joints).
    pub unjudged: u64,
    /// The smallest clearance seen in the run (m); negative or 0 is contact. `None` before
    /// the first step.
    pub min_clearance_m: Option<f64>,
    /// The link of the smallest clearance ("base", "link1" … "link5").
    pub min_link: Option<String>,
    /// What it was closest to: "obstacle N" (index in the scene's list, from 0), "table",
    /// or a link name (self-collision).
    pub min_other: Option<String>,
    /// The scene in force then.
    pub min_scene: Option<String>,
    /// The configuration (rad).
    pub min_q_rad: Option<[f64; 5]>,
    /// The contact margin the referee used (m).
    pub contact_margin_m: f64,
}

/// The ground-truth world of the simulator.
#[derive(Debug, Clone)]
pub struct World {
    model: RobotModel,
    referee: Referee,
    scene_name: String,
    /// The scene in force when a box of it moves (its boxes are placed every check).
    moving_scene: Option<SceneFile>,
    /// When the scene came into force (`CLOCK_MONOTONIC`, ns).
    in_force_since_ns: u64,
    last_q_rad: Option<[f64; 5]>,
    /// When `last_q_rad` was checked (`CLOCK_MONOTONIC`, ns).
    last_check_ns: Option<u64>,
    /// Whether the arm moved over the previous judged tick.
    moved_last_tick: bool,
    in_contact: bool,
    summary: RefereeSummary,
}

/// What the world says about one arm configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldCheck {
    /// TCP pose as the controller reports it: x, y, z (mm), roll, pitch, yaw (rad), from
    /// the referee's kinematics.
    pub tcp_pose: [f32; 6],
    /// Whether the arm touches an obstacle, the table or itself (per the referee), at this
    /// configuration or on the way from the previous one.
    pub contact: bool,
    /// Whether this is a new contact (the previous check was clear).
    pub new_contact: bool,
    /// Whether the arm was moving on this tick or the previous one ([`ARM_MOVING_RAD_S`]).
    pub arm_moving: bool,
    /// The referee's smallest clearance on the step (`None` when it could not judge).
    pub clearance: Option<Clearance>,
}

/// The controller's TCP pose report for `q_rad`: x, y, z (mm), roll, pitch, yaw (rad),
/// from the referee's kinematics.
pub fn tcp_pose_report(q_rad: &[f64; 5]) -> [f32; 6] {
    let p = Referee::tcp_pose(q_rad);
    [
        (p.position_m[0] * 1000.0) as f32,
        (p.position_m[1] * 1000.0) as f32,
        (p.position_m[2] * 1000.0) as f32,
        p.rpy_rad[0] as f32,
        p.rpy_rad[1] as f32,
        p.rpy_rad[2] as f32,
    ]
}

impl World {
    /// Loads the robot model; no scene yet (only self-collision is checked).
    ///
    /// # Errors
    /// [`WorldError::Model`].
    pub fn load(urdf: &Path, contact_margin_m: f64) -> Result<Self, WorldError> {
        let model = RobotModel::load(urdf).map_err(|e| WorldError::Model {
            path: urdf.to_path_buf(),
            reason: format!("{e:?}"),
        })?;
        let referee = Referee::new(contact_margin_m);
        let summary = RefereeSummary {
            contact_margin_m: referee.contact_margin_m(),
            ..RefereeSummary::default()
        };
        Ok(Self {
            model,
            referee,
            scene_name: String::new(),
            moving_scene: None,
            in_force_since_ns: 0,
            last_q_rad: None,
            last_check_ns: None,
            moved_last_tick: false,
            in_contact: false,
            summary,
        })
    }

    /// Replaces the scene, in force from now ([`World::set_scene_since`]).
    ///
    /// # Errors
    /// [`WorldError::Scene`] if the twin or the referee refuses it.
    pub fn set_scene(&mut self, file: &SceneFile) -> Result<(), WorldError> {
        self.set_scene_since(file, monotonic_now_ns())
    }

    /// Replaces the scene, in force since `in_force_since_ns` (`CLOCK_MONOTONIC`): the
    /// origin of its boxes' paths. The twin validates it too (the simulator takes the scenes
    /// the rest of the system takes), the referee judges with it (its boxes placed at the
    /// start of their paths until the next check places them in time).
    ///
    /// # Errors
    /// [`WorldError::Scene`] if the twin or the referee refuses it; the scene in force is
    /// kept then.
    pub fn set_scene_since(
        &mut self,
        file: &SceneFile,
        in_force_since_ns: u64,
    ) -> Result<(), WorldError> {
        let scene_err = |reason: String| WorldError::Scene {
            name: file.name.clone(),
            reason,
        };
        Scene::from_file(file).map_err(|e| scene_err(format!("{e:?}")))?;
        self.referee
            .set_scene(file)
            .map_err(|e: RefereeSceneError| scene_err(e.to_string()))?;
        self.scene_name.clone_from(&file.name);
        self.moving_scene = file.is_moving().then(|| file.clone());
        self.in_force_since_ns = in_force_since_ns;
        Ok(())
    }

    /// When the scene in force came into force (`CLOCK_MONOTONIC`, ns).
    pub fn in_force_since_ns(&self) -> u64 {
        self.in_force_since_ns
    }

    /// The robot model (for the controller's TCP speed check).
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The robot model's home posture (rad).
    pub fn home(&self) -> [f64; 5] {
        self.model.home()
    }

    /// Name of the scene in force ("" when none).
    pub fn scene_name(&self) -> &str {
        &self.scene_name
    }

    /// The referee.
    pub fn referee(&self) -> &Referee {
        &self.referee
    }

    /// The referee's figures so far.
    pub fn referee_summary(&self) -> &RefereeSummary {
        &self.summary
    }

    /// [`World::check_at`] now.
    pub fn check(&mut self, q_rad: &[f64; 5]) -> WorldCheck {
        self.check_at(q_rad, monotonic_now_ns())
    }

    /// The TCP pose for `q_rad` and the referee's verdict on the step from the previously
    /// checked configuration to `q_rad` (the first check judges `q_rad` alone), with every
    /// moving box where its path puts it at `now_ns` (`CLOCK_MONOTONIC`).
    pub fn check_at(&mut self, q_rad: &[f64; 5], now_ns: u64) -> WorldCheck {
        let tcp_pose = tcp_pose_report(q_rad);
        if let Some(file) = &self.moving_scene {
            let t_s = seconds_since(self.in_force_since_ns, now_ns);
            // The scene was validated when it was set: placing its boxes cannot fail; if it
            // did, the last placement stands.
            let _ = self.referee.set_scene_at(file, t_s);
        }
        let from = self.last_q_rad.unwrap_or(*q_rad);
        self.summary.steps += 1;
        let verdict = match self.referee.check_motion(&from, q_rad) {
            Ok(v) => v,
            Err(RefereeCheckError::NonFiniteJoint { .. }) => {
                self.summary.unjudged += 1;
                return WorldCheck {
                    tcp_pose,
                    contact: self.in_contact,
                    new_contact: false,
                    arm_moving: self.moved_last_tick,
                    clearance: None,
                };
            }
        };
        let moved_now = match (self.last_q_rad, self.last_check_ns) {
            (Some(prev), Some(prev_ns)) => {
                let dt_s = seconds_since(prev_ns, now_ns);
                prev.iter()
                    .zip(q_rad)
                    .any(|(a, b)| (b - a).abs() > ARM_MOVING_RAD_S * dt_s)
            }
            _ => false,
        };
        let arm_moving = moved_now || self.moved_last_tick;
        self.moved_last_tick = moved_now;
        self.last_q_rad = Some(*q_rad);
        self.last_check_ns = Some(now_ns);
        self.summary.evaluations += u64::from(verdict.evaluations);
        let c = verdict.nearest;
        self.summary.clearance_m = Some(c.clearance_m);
        if self
            .summary
            .min_clearance_m
            .is_none_or(|m| c.clearance_m < m)
        {
            self.summary.min_clearance_m = Some(c.clearance_m);
            self.summary.min_link = Some(c.link_name().to_owned());
            self.summary.min_other = Some(c.other.to_string());
            self.summary.min_scene = Some(self.scene_name.clone());
            self.summary.min_q_rad = Some(verdict.nearest_q_rad);
        }
        let new_contact = verdict.contact && !self.in_contact;
        if new_contact {
            self.summary.contacts += 1;
            if arm_moving {
                self.summary.contacts_while_moving += 1;
            } else {
                self.summary.contacts_at_rest += 1;
            }
        }
        self.in_contact = verdict.contact;
        WorldCheck {
            tcp_pose,
            contact: verdict.contact,
            new_contact,
            arm_moving,
            clearance: Some(c),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::scene_file::{BoxPath, BoxSpec, GoalSpec, Keyframe, TableSpec};

    const S: u64 = 1_000_000_000;
    /// The task's start posture (assets/task.toml): TCP at about (0.30, 0, 0.25) m.
    const START_Q: [f64; 5] = [0.0, -0.383, -0.371, 0.855, 0.0];

    fn world() -> World {
        let urdf = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/xarm5.urdf");
        World::load(&urdf, 0.0).unwrap()
    }

    fn scene(boxes: Vec<BoxSpec>) -> SceneFile {
        SceneFile {
            name: "test".into(),
            table: TableSpec { height_m: 0.0 },
            goal: GoalSpec {
                center_m: [0.3, 0.25, 0.025],
                size_m: 0.05,
            },
            obstacles: boxes,
        }
    }

    /// A 6 cm box on the table beside the flange at the start posture, sliding along y
    /// from `y0` (until 1 s) to `y1` (at 2 s).
    fn sliding_box(y0: f64, y1: f64) -> BoxSpec {
        let at = |at_s, y| Keyframe {
            at_s,
            center_m: [0.30, y, 0.20],
        };
        BoxSpec {
            path: BoxPath::new(&[at(1.0, y0), at(2.0, y1)]).unwrap(),
            ..BoxSpec::fixed([0.30, y0, 0.20], [0.06, 0.06, 0.40])
        }
    }

    #[test]
    fn a_box_walking_into_the_arm_at_rest_counts_as_a_contact_at_rest() {
        let mut w = world();
        let t0 = 50 * S;
        w.set_scene_since(&scene(vec![sliding_box(0.40, 0.0)]), t0)
            .unwrap();
        // Still at its start for the first second: clear.
        let before = w.check_at(&START_Q, t0 + S / 2);
        assert!(!before.contact && !before.arm_moving, "{before:?}");
        let far_m = before.clearance.unwrap().clearance_m;
        assert!(far_m > 0.1, "{far_m}");
        // It slides in at 0.4 m/s, ticks of 4 ms; the arm does not move.
        let mut hit_at_ns = None;
        for k in 0..500u64 {
            let c = w.check_at(&START_Q, t0 + S + k * 4_000_000);
            if c.new_contact {
                assert!(!c.arm_moving);
                hit_at_ns.get_or_insert(k * 4_000_000);
            }
        }
        let hit_s = hit_at_ns.expect("the box reaches the arm") as f64 * 1e-9;
        assert!(
            hit_s > 0.3 && hit_s < 1.0,
            "contact {hit_s} s into the slide"
        );
        let r = w.referee_summary();
        assert_eq!(
            (r.contacts, r.contacts_at_rest, r.contacts_while_moving),
            (1, 1, 0)
        );
        assert!(r.clearance_m.unwrap() <= 0.0, "{r:?}");
    }

    #[test]
    fn the_arm_moving_into_a_box_counts_as_a_contact_while_moving() {
        let mut w = world();
        // A still box (the same one, parked) where the arm's J1 swing takes the flange.
        w.set_scene_since(
            &scene(vec![BoxSpec::fixed([0.30, 0.10, 0.20], [0.06, 0.06, 0.40])]),
            0,
        )
        .unwrap();
        let mut q = START_Q;
        let mut first = None;
        for k in 0..200u64 {
            q[0] = 0.002 * k as f64; // 0.5 rad/s at 250 Hz
            let c = w.check_at(&q, k * 4_000_000);
            if c.new_contact {
                first.get_or_insert(c);
            }
        }
        assert!(first.unwrap().arm_moving);
        let r = w.referee_summary();
        assert_eq!(
            (r.contacts, r.contacts_while_moving, r.contacts_at_rest),
            (1, 1, 0)
        );
    }

    #[test]
    fn a_contact_just_after_the_arm_stopped_still_counts_as_moving() {
        // The arm moved on the previous tick and is still on this one, as the box arrives.
        let mut w = world();
        let t0 = 10 * S;
        w.set_scene_since(&scene(vec![sliding_box(0.40, 0.0)]), t0)
            .unwrap();
        let mut q = START_Q;
        // Find the tick of contact with the arm at rest throughout.
        let mut probe = w.clone();
        let hit = (0..500u64)
            .map(|k| t0 + S + k * 4_000_000)
            .find(|&t| probe.check_at(&START_Q, t).new_contact)
            .unwrap();
        // Hold still up to two ticks before, move a little, then stop on the contact tick.
        let mut t = t0;
        while t < hit - 8_000_000 {
            w.check_at(&q, t);
            t += 4_000_000;
        }
        q[4] += 0.01; // J5 turns the flange about its own axis: no change in clearance to speak of
        assert!(!w.check_at(&q, hit - 4_000_000).new_contact);
        let c = w.check_at(&q, hit);
        assert!(c.new_contact && c.arm_moving, "{c:?}");
        assert_eq!(w.referee_summary().contacts_while_moving, 1);
    }

    #[test]
    fn the_boxes_are_placed_by_the_time_since_the_scene_came_into_force() {
        let mut w = world();
        let file = scene(vec![sliding_box(0.40, 0.0)]);
        // The same wall-clock tick, two different origins: 0.2 s vs 3 s into the scene.
        w.set_scene_since(&file, 99 * S).unwrap();
        let early = w.check_at(&START_Q, 99 * S + S / 5);
        let mut late_world = world();
        late_world.set_scene_since(&file, 96 * S + S / 5).unwrap();
        let late = late_world.check_at(&START_Q, 99 * S + S / 5);
        assert!(!early.contact && late.contact, "{early:?} {late:?}");
        assert_eq!(w.in_force_since_ns(), 99 * S);
        // A static scene needs no placing and judges as before.
        let mut still = world();
        still.set_scene(&scene(vec![])).unwrap();
        assert!(!still.check(&START_Q).contact);
    }

    #[test]
    fn the_crossing_box_world_never_touches_the_arm_at_its_start_posture() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../assets/scenes/crossing_box.toml");
        let file = SceneFile::load(&path).unwrap();
        let mut w = world();
        w.set_scene_since(&file, 0).unwrap();
        let mut min_m = f64::INFINITY;
        for k in 0..1000u64 {
            let c = w.check_at(&START_Q, k * 4_000_000);
            min_m = min_m.min(c.clearance.unwrap().clearance_m);
        }
        assert_eq!(w.referee_summary().contacts, 0);
        assert!(min_m > 0.02, "closest approach {min_m} m");
    }
}
