//! `foresight`: starts and supervises the whole system — `xarm-sim` (or a real arm with
//! `--robot HOST`), `perception`, `learner serve`, `rt-core run` and optionally the ROS 2
//! bridge — under one unique service prefix, plays a world script against it, prints a
//! running timeline, and leaves a report in `runs/<time>/` (`runs/latest` points at it).
//! `foresight reach --goal X,Y` sends such a run a goal through the ROS 2 `Reach` action
//! ([`launcher::reach`]).
//!
//! The logic lives in the `launcher` library ([`launcher::launch`]); this file parses the
//! command line and maps the outcome to an exit code.

#![forbid(unsafe_code)]

use std::process::ExitCode;

use clap::Parser;
use launcher::args::LaunchArgs;
use launcher::launch::run_all;

fn main() -> ExitCode {
    // `foresight reach --goal X,Y`: the Reach action's client (the rest is the launcher). DDS
    // chatter stays quiet unless RUST_LOG asks for it.
    if std::env::args_os().nth(1).is_some_and(|a| a == "reach") {
        tracing_subscriber::fmt()
            .with_env_filter(
                tracing_subscriber::EnvFilter::try_from_default_env()
                    .unwrap_or_else(|_| "error,rustdds=off".into()),
            )
            .with_writer(std::io::stderr)
            .init();
        let args = launcher::reach::ReachArgs::parse_from(std::env::args_os().skip(1));
        return match launcher::reach::run_reach(&args) {
            Ok(code) => ExitCode::from(code),
            Err(e) => {
                eprintln!("foresight reach: {e:#}");
                ExitCode::from(2)
            }
        };
    }
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
