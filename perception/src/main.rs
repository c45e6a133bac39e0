//! The `perception` binary: a thin command-line edge over the perception library.
//!
//! Subcommands live one per file under `cli/`: `render` (the synthetic camera), `calibrate`
//! (workspace corners → calibration file), `detect` (one image → JSON) and `run` (frames →
//! `DetectionFrame`s over iceoryx2). See perception/README.md for the workflow.

#![forbid(unsafe_code)]

mod cli;

fn main() -> anyhow::Result<()> {
    cli::main()
}
