//! Command-line parsing and dispatch of the `perception` binary. Each subcommand is one
//! module that owns its arguments (`clap::Args`) and a `run` function; errors reach `main`
//! as `anyhow` errors with context, printed on stderr with exit status 1.
//!
//! [`shared`] holds what several subcommands need: the bundled assets, the detector choice
//! and the exact calibration of the synthetic camera.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod calibrate;
mod detect;
mod render;
mod run;
mod shared;

#[derive(Parser)]
#[command(
    name = "perception",
    about = "Foresight perception: camera frames to goal/obstacle boxes in the twin's frame"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene (or a world script at a time) with the synthetic camera: colour PNG,
    /// depth TIFF (m), exact calibration and ground truth.
    Render(render::RenderArgs),
    /// Calibrate from the four workspace corners (given, or found from the tape): writes the
    /// calibration TOML and the rectified top view PNG.
    Calibrate(calibrate::CalibrateArgs),
    /// Detect objects in one image; prints JSON and writes an annotated PNG.
    Detect(detect::DetectArgs),
    /// Run: frames from a source → detections → DetectionFrames over iceoryx2.
    Run(run::RunArgs),
}

/// Logs to stderr; `RUST_LOG` overrides the default filter (DDS chatter kept quiet).
fn init_tracing() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,rustdds=warn,ros2_client=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
}

/// Parses the command line and runs the chosen subcommand.
pub fn main() -> Result<()> {
    init_tracing();
    match Cli::parse().command {
        Command::Render(args) => render::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Detect(args) => detect::run(args),
        Command::Run(args) => run::run(args),
    }
}
