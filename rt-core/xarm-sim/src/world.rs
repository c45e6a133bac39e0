//! The simulator's ground truth: the twin's robot model and geometry against the current
//! scene. Gives the TCP pose for reports and tells whether the arm touches anything.

use std::path::{Path, PathBuf};

use shm_schemas::scene_file::SceneFile;

use twin::{LinkPoses, RobotGeometry, RobotModel, Scene};

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
    /// The scene is not valid for the twin.
    #[error("invalid scene {name:?}: {reason}")]
    Scene {
        /// Scene name.
        name: String,
        /// What failed.
        reason: String,
    },
}

/// The ground-truth world of the simulator.
#[derive(Debug, Clone)]
pub struct World {
    model: RobotModel,
    geometry: RobotGeometry,
    scene: Option<Scene>,
    scene_name: String,
    margin_m: f64,
    poses: LinkPoses,
}

/// What the world says about one arm configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldCheck {
    /// TCP pose as the controller reports it: x, y, z (mm), roll, pitch, yaw (rad).
    pub tcp_pose: [f32; 6],
    /// Whether any link touches an obstacle or the table (per the twin's rules).
    pub contact: bool,
}

impl World {
    /// Loads the robot model; no scene yet (nothing to collide with).
    ///
    /// # Errors
    /// [`WorldError::Model`].
    pub fn load(urdf: &Path, contact_margin_m: f64) -> Result<Self, WorldError> {
        let model = RobotModel::load(urdf).map_err(|e| WorldError::Model {
            path: urdf.to_path_buf(),
            reason: format!("{e:?}"),
        })?;
        let geometry = RobotGeometry::new(&model);
        Ok(Self {
            model,
            geometry,
            scene: None,
            scene_name: String::new(),
            margin_m: contact_margin_m,
            poses: LinkPoses::default(),
        })
    }

    /// Replaces the scene.
    ///
    /// # Errors
    /// [`WorldError::Scene`] if the twin refuses it.
    pub fn set_scene(&mut self, file: &SceneFile) -> Result<(), WorldError> {
        let scene = Scene::from_file(file).map_err(|e| WorldError::Scene {
            name: file.name.clone(),
            reason: format!("{e:?}"),
        })?;
        self.scene = Some(scene);
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

    /// FK and the contact test for `q_rad`.
    pub fn check(&mut self, q_rad: &[f64; 5]) -> WorldCheck {
        self.model.fk_into(q_rad, &mut self.poses);
        let t = self.poses.tcp.translation.vector;
        let (roll, pitch, yaw) = self.poses.tcp.rotation.euler_angles();
        let tcp_pose = [
            (t.x * 1000.0) as f32,
            (t.y * 1000.0) as f32,
            (t.z * 1000.0) as f32,
            roll as f32,
            pitch as f32,
            yaw as f32,
        ];
        let contact = self
            .scene
            .as_ref()
            .is_some_and(|s| self.geometry.in_contact(&self.poses, s, self.margin_m));
        WorldCheck { tcp_pose, contact }
    }
}
