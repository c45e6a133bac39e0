//! `perception render`: one frame of the synthetic camera for a scene file, or for a world
//! script at a given time. Writes `colour.png`, `colour.depth.tiff` (m), `truth.toml` (the
//! scene rendered) and the exact `calibration.toml` into `--out`, then prints the folder.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use perception::annotate::write_image;
use perception::frame::{Frame, write_depth};
use perception::synthetic::SyntheticCamera;
use shm_schemas::cli_bounds::f64_within;
use shm_schemas::scene_file::{SceneFile, WorldScript};

use super::shared::{asset, synthetic_calibration};

/// `perception render`
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene file or world script.
    #[arg(long)]
    scene: PathBuf,
    /// Time into the world script (s).
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 1e7), allow_negative_numbers = true)]
    at_s: f64,
    /// Synthetic camera description.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

/// A world script, or a single scene file as a one-step script.
fn load_world(path: &Path) -> Result<WorldScript> {
    match WorldScript::load(path) {
        Ok(w) => Ok(w),
        Err(e) => SceneFile::load(path)
            .map(WorldScript::single)
            .map_err(|_| anyhow::anyhow!("{e}"))
            .with_context(|| {
                format!(
                    "{} is neither a world script nor a scene file",
                    path.display()
                )
            }),
    }
}

/// Renders the scene in force at `--at-s` and writes the four files.
pub fn run(args: RenderArgs) -> Result<()> {
    let RenderArgs {
        scene,
        at_s,
        camera,
        out,
    } = args;
    let cam = SyntheticCamera::load(&camera.unwrap_or_else(|| asset("synthetic_camera.toml")))?;
    let world = load_world(&scene)?;
    let (_, s) = world.scene_at(at_s);
    let f = Frame::from_rendered(&cam.render(s), 1, 0)?;
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    write_image(&out.join("colour.png"), &f.bgr)?;
    if let Some(d) = &f.depth_m {
        write_depth(&out.join("colour.depth.tiff"), d)?;
    }
    let truth = out.join("truth.toml");
    std::fs::write(&truth, s.to_toml_string())
        .with_context(|| format!("writing {}", truth.display()))?;
    synthetic_calibration(&cam, s)?.save(&out.join("calibration.toml"))?;
    println!("{}", out.display());
    Ok(())
}
