//! Helpers shared by several subcommands: where the bundled assets are, which detector to
//! build from the `--detector` / YOLO flags ([`YoloArgs`]), and the exact calibration of
//! the synthetic camera for a scene's table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use perception::calibration::{Calibration, CalibrationFile};
use perception::camera_id::{CalibratedAt, CalibrationCamera};
use perception::color_detector::{ColourDetector, ColourDetectorConfig};
use perception::pipeline::Detector;
use perception::synthetic::SyntheticCamera;
use perception::yolo::{BackendChoice, YoloDetector, YoloFile};
use shm_schemas::cli_bounds::int_within;
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

/// The exact calibration of a synthetic camera for a scene's table, made now and naming the
/// synthetic camera (`[camera] frame_id`).
pub fn synthetic_calibration(cam: &SyntheticCamera, scene: &SceneFile) -> Result<Calibration> {
    let corners = cam
        .workspace_corners_px(scene)
        .context("a workspace corner lies behind the synthetic camera")?;
    Ok(Calibration::new(CalibrationFile {
        camera: CalibrationCamera::synthetic(CalibratedAt::now()),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(scene),
        corners_px: corners,
        rectified_px_per_m: 1000.0,
    })?)
}

/// Which YOLO model to run and how (shared by `detect` and `run`). A YOLO detector is used
/// when `--model` or `--yolo-config` is given; the flags override the file's settings.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct YoloArgs {
    /// YOLO ONNX model (stock YOLOv8/YOLO11 `[1,4+C,N]` or NMS-free `[1,N,6]` export); else
    /// the colour detector.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Labels file (needed only when the model's metadata does not name its classes
    /// `goal` / `obstacle`).
    #[arg(long)]
    pub labels: Option<PathBuf>,
    /// YOLO settings file (`model`, `labels`, `[detector]`); e.g. assets/perception/yolo.toml.
    #[arg(long)]
    pub yolo_config: Option<PathBuf>,
    /// Inference engine (default: the settings file's, else auto = ONNX Runtime when its
    /// library loads, else OpenCV DNN).
    #[arg(long, value_enum)]
    pub backend: Option<BackendChoice>,
    /// Inference threads (0: the cores this process may use).
    #[arg(long, value_parser = int_within(0usize, 1024), allow_negative_numbers = true)]
    pub threads: Option<usize>,
    /// ONNX Runtime shared library (default: ORT_DYLIB_PATH, else the one `make setup`
    /// installed).
    #[arg(long)]
    pub ort_library: Option<PathBuf>,
}

impl YoloArgs {
    /// Whether a YOLO detector was asked for.
    pub fn wanted(&self) -> bool {
        self.model.is_some() || self.yolo_config.is_some()
    }

    /// Loads the YOLO detector these flags describe.
    ///
    /// # Errors
    /// A bad settings file, model, labels or engine, with the file and the reason.
    pub fn load(&self) -> Result<YoloDetector> {
        let file = self
            .yolo_config
            .as_deref()
            .map(YoloFile::load)
            .transpose()?;
        // The file's `opencv_model` goes with its `model`, not with a `--model` given instead.
        let (model, opencv_model, labels) = match (&self.model, &file) {
            (Some(m), _) => (m.clone(), None, self.labels.clone()),
            (None, Some(f)) => (
                f.model.clone(),
                f.opencv_model.clone(),
                self.labels.clone().or(f.labels.clone()),
            ),
            (None, None) => anyhow::bail!("no YOLO model: give --model or --yolo-config"),
        };
        let mut config = file.map(|f| f.detector).unwrap_or_default();
        if let Some(b) = self.backend {
            config.backend = b;
        }
        if let Some(t) = self.threads {
            config.threads = t;
        }
        if let Some(l) = &self.ort_library {
            config.ort_library = Some(l.clone());
        }
        let y = YoloDetector::load_with_opencv_model(
            &model,
            opencv_model.as_deref(),
            labels.as_deref(),
            config,
        )
        .with_context(|| format!("loading YOLO model {}", model.display()))?;
        if let Some(why) = &y.fallback_reason {
            tracing::warn!("ONNX Runtime unavailable, running the model on OpenCV DNN: {why}");
        }
        if !y.rewritten_nodes.is_empty() {
            tracing::info!(
                "patched for OpenCV 4.6: {:?} (strides applied after inference)",
                y.rewritten_nodes
            );
        }
        tracing::info!(
            "YOLO model {} on {} at {} px ({:?})",
            y.model_path().display(),
            y.backend_name(),
            y.input_px(),
            y.layout()
        );
        Ok(y)
    }
}

/// The YOLO detector when `yolo` asks for one, else the colour detector (configured by
/// `detector`, else the bundled `colour_detector.toml`, else defaults).
pub fn load_detector(detector: Option<&Path>, yolo: &YoloArgs) -> Result<Detector> {
    if yolo.wanted() {
        return Ok(Detector::Yolo(Box::new(yolo.load()?)));
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
