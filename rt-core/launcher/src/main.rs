//! `foresight`: starts and supervises the whole system — `xarm-sim` (or a real arm with
//! `--robot HOST`), `perception`, `learner serve`, `rt-core run` and optionally the ROS 2
//! bridge — under one unique service prefix, plays a world script against it, prints a
//! running timeline, and leaves a report in `runs/<time>/` (`runs/latest` points at it).
//!
//! The logic lives in the `launcher` library ([`launcher::launch`]); this file parses the
//! command line and maps the outcome to an exit code.

#![forbid(unsafe_code)]

use std::process::ExitCode;

use clap::Parser;
use launcher::args::LaunchArgs;
use launcher::launch::run_all;

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args = LaunchArgs::parse();
    match run_all(&args) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("foresight: {e:#}");
            ExitCode::from(2)
        }
    }
}
