//! Command-line parsing and dispatch of the `rt-core` binary. Each subcommand is one module
//! that owns its arguments (`clap::Args`) and a `run` function returning an exit code.

// The command line: set-up and tools around the runtime (the bench's wall time, the
// driver tools' waits), never the cycle's own code.
#![allow(clippy::disallowed_methods)]

use std::process::ExitCode;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};
use rt_core::rt::rt_setup::RtRequest;
use shm_schemas::cli_bounds::int_within;

mod ack;
mod bench_loop;
mod run;
mod twin;
mod xarm;

/// Foresight's real-time core.
#[derive(Debug, Parser)]
#[command(name = "rt-core", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Query the digital twin (kinematics, distances, rollouts); prints one JSON object.
    #[command(subcommand)]
    Twin(twin::TwinCommand),
    /// Latency and jitter harness of the full cycle; prints one JSON object.
    BenchLoop(bench_loop::BenchLoopArgs),
    /// The runtime: twin thread + control cycle with iceoryx2 I/O.
    Run(run::RunArgs),
    /// The operator's acknowledgement of a protective stop, sent to the rt-core that owns
    /// the arm at `--robot` (and no other).
    Ack(ack::AckArgs),
    /// xArm driver tools (`probe`).
    #[command(subcommand)]
    Xarm(xarm::XarmCommand),
}

/// Parses the command line and runs the chosen subcommand.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Twin(cmd) => twin::run(cmd),
        Command::BenchLoop(args) => bench_loop::run(args),
        Command::Run(args) => run::run(args),
        Command::Xarm(cmd) => xarm::run(cmd),
        Command::Ack(args) => ack::run(args),
    }
}

/// The real-time flags shared by `run` and `bench-loop`.
#[derive(Debug, Clone, Copy, Args)]
pub struct RtArgs {
    /// Pin the cycle thread to this CPU.
    #[arg(long, value_parser = int_within(0usize, 4095), allow_negative_numbers = true)]
    cpu: Option<usize>,
    /// Ask for SCHED_FIFO at this priority for the cycle thread.
    #[arg(long, value_parser = int_within(1i32, 99), allow_negative_numbers = true)]
    rt_priority: Option<i32>,
    /// Do not lock memory.
    #[arg(long)]
    no_mlock: bool,
}

impl RtArgs {
    /// The request the cycle thread applies to itself.
    pub fn request(&self) -> RtRequest {
        RtRequest {
            cpu: self.cpu,
            rt_priority: self.rt_priority,
            lock_memory: !self.no_mlock,
        }
    }
}

/// A flag's value parser: one of `names`, taken as the value at the same place in `values`.
fn one_of<T: Copy + Send + Sync + 'static, const N: usize>(
    names: [&'static str; N],
    values: [T; N],
) -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(names)
        .map(move |s| values[names.iter().position(|n| *n == s).unwrap_or_default()])
}

/// Logs to stderr (`RUST_LOG`, default `info`), in colour on a terminal.
fn init_tracing() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        // A log line that cannot be written (stderr on a full disk, a closed pipe) is lost,
        // never reported with `eprintln!`, which panics there — and in the deploy build a
        // panic of the log thread aborted rt-core without braking (issue 30 item 4).
        .log_internal_errors(false)
        .try_init();
}
