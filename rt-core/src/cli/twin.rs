//! `rt-core twin …`: debugging queries of the digital twin, one JSON object on stdout.

use std::process::ExitCode;

use clap::Subcommand;

/// Twin queries.
#[derive(Debug, Subcommand)]
pub enum TwinCommand {
    /// Forward kinematics.
    Fk,
}

/// Runs a twin query.
pub fn run(cmd: TwinCommand) -> ExitCode {
    match cmd {
        TwinCommand::Fk => ExitCode::FAILURE,
    }
}
