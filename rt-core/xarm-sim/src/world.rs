//! The simulator's ground truth: the scene in force, judged by the independent
//! [`Referee`] (its own DH kinematics, capsules and distance code; not the twin's geometry).
//! Gives the TCP pose for reports and tells whether the arm touches anything, and keeps the
//! referee's figures for the run ([`RefereeSummary`]).
//!
//! **The reported TCP pose comes from the referee's kinematics** (UFactory's DH table), not
//! from the twin's URDF model: the controller has kinematics of its own, so a comparison of
//! the twin's TCP with the TCP the (simulated) controller reports in rt-core compares two
//! independent models and can reveal a URDF error. The twin's model is still loaded, for the
//! home posture and the controller's servo-mode TCP speed check.

use std::path::{Path, PathBuf};

use shm_schemas::scene_file::SceneFile;

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

/// The referee's figures for a run, reported in the simulator's summary (`referee`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RefereeSummary {
    /// Motion steps judged (one per physics tick).
    pub steps: u64,
    /// Configurations evaluated (two per step, more where a step was bisected).
    pub evaluations: u64,
    /// Contacts: times the arm went from clear to touching (each raised error 31).
    pub contacts: u64,
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
    last_q_rad: Option<[f64; 5]>,
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
            last_q_rad: None,
            in_contact: false,
            summary,
        })
    }

    /// Replaces the scene. The twin validates it too (the simulator takes the scenes the
    /// rest of the system takes), the referee judges with it.
    ///
    /// # Errors
    /// [`WorldError::Scene`] if the twin or the referee refuses it.
    pub fn set_scene(&mut self, file: &SceneFile) -> Result<(), WorldError> {
        let scene_err = |reason: String| WorldError::Scene {
            name: file.name.clone(),
            reason,
        };
        Scene::from_file(file).map_err(|e| scene_err(format!("{e:?}")))?;
        self.referee
            .set_scene(file)
            .map_err(|e: RefereeSceneError| scene_err(e.to_string()))?;
        self.scene_name.clone_from(&file.name);
        Ok(())
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

    /// The TCP pose for `q_rad` and the referee's verdict on the step from the previously
    /// checked configuration to `q_rad` (the first check judges `q_rad` alone).
    pub fn check(&mut self, q_rad: &[f64; 5]) -> WorldCheck {
        let tcp_pose = tcp_pose_report(q_rad);
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
                    clearance: None,
                };
            }
        };
        self.last_q_rad = Some(*q_rad);
        self.summary.evaluations += u64::from(verdict.evaluations);
        let c = verdict.nearest;
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
        }
        self.in_contact = verdict.contact;
        WorldCheck {
            tcp_pose,
            contact: verdict.contact,
            new_contact,
            clearance: Some(c),
        }
    }
}
