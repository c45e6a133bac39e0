//! The `rt-core` binary: a thin command-line edge over the rt-core library.
//!
//! Subcommands live one per file under `cli/`: `twin` (debugging the digital twin, JSON on
//! stdout), and, as they land, `run` (the real-time runtime), `bench-loop` (latency and
//! jitter harness) and `xarm` (driver tools such as `probe`).

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
