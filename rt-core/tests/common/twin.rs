//! Fixtures on the bundled assets: the model, the task, an environment and scenes (included
//! with `#[path]` by rt-core's test binaries).

#![allow(dead_code)]

use std::path::PathBuf;

use shm_schemas::scene_file::SceneFile;
use twin::{RobotModel, Scene, TaskConfig, TwinEnv};

pub fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
}

pub fn model() -> RobotModel {
    RobotModel::load(&assets().join("xarm5.urdf")).unwrap()
}

pub fn task() -> TaskConfig {
    TaskConfig::load(&assets().join("task.toml")).unwrap()
}

pub fn env() -> TwinEnv {
    TwinEnv::new(model(), task())
}

pub fn scene(name: &str) -> Scene {
    let file = SceneFile::load(&assets().join("scenes").join(name)).unwrap();
    Scene::from_file(&file).unwrap()
}
