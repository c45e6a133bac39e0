//! Helpers shared by several subcommands: where the bundled assets are, which detector to
//! build from the `--detector` / `--model` / `--labels` flags, and the exact calibration of
//! the synthetic camera for a scene's table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use perception::calibration::{Calibration, CalibrationFile};
use perception::color_detector::{ColourDetector, ColourDetectorConfig};
use perception::pipeline::Detector;
use perception::synthetic::SyntheticCamera;
use perception::yolo::{YoloConfig, YoloDetector};
use shm_schemas::scene_file::SceneFile;

/// A bundled perception asset: `$FORESIGHT_ASSETS/perception`, else `./assets/perception`
/// (the repository root is the working directory of `make demo`), else the source tree's
/// copy (a binary run from elsewhere on the build machine).
pub fn asset(name: &str) -> PathBuf {
    if let Some(dir) = std::env::var_os("FORESIGHT_ASSETS") {
        return Path::new(&dir).join("perception").join(name);
    }
    let local = Path::new("assets/perception").join(name);
    if local.exists() {
        return local;
    }
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/perception")).join(name)
}

/// The exact calibration of a synthetic camera for a scene's table.
pub fn synthetic_calibration(cam: &SyntheticCamera, scene: &SceneFile) -> Result<Calibration> {
    let corners = cam
        .workspace_corners_px(scene)
        .context("a workspace corner lies behind the synthetic camera")?;
    Ok(Calibration::new(CalibrationFile {
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(scene),
        corners_px: corners,
        rectified_px_per_m: 1000.0,
    })?)
}

/// The YOLOv8 detector when a model and its labels are given, else the colour detector
/// (configured by `detector`, else the bundled `colour_detector.toml`, else defaults).
pub fn load_detector(
    detector: Option<&Path>,
    model: Option<&Path>,
    labels: Option<&Path>,
) -> Result<Detector> {
    if let (Some(m), Some(l)) = (model, labels) {
        let y = YoloDetector::load(m, l, YoloConfig::default())?;
        if !y.rewritten_nodes.is_empty() {
            tracing::info!(
                "patched for OpenCV 4.6: {:?} (strides applied after inference)",
                y.rewritten_nodes
            );
        }
        return Ok(Detector::Yolo(Box::new(y)));
    }
    let cfg = match detector {
        Some(p) => ColourDetectorConfig::load(p)?,
        None => {
            let p = asset("colour_detector.toml");
            if p.is_file() {
                ColourDetectorConfig::load(&p)?
            } else {
                ColourDetectorConfig::default()
            }
        }
    };
    Ok(Detector::Colour(Box::new(ColourDetector::new(cfg)?)))
}
