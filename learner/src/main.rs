//! The `learner` binary: pre-training, evaluation, benchmarking, export, distillation and the
//! retraining service. Thin: parses arguments and dispatches to one module per subcommand
//! under `cli/`. (The unseen-worlds benchmark is its own binary, `unseen-worlds`, so that the
//! learner does not depend on the benchmark's world generators.)

#![forbid(unsafe_code)]

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "learner",
    about = "PPO on the Foresight twin: pre-train, evaluate, export, serve retraining"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Pre-train on the task's broad [world] distribution (random small-obstacle scenes
    /// without one); keeps best.ckpt and last.ckpt in --out.
    Pretrain(cli::pretrain::PretrainArgs),
    /// Evaluate a checkpoint: on a scene file (the scene and lightly jittered variants), or
    /// on the fixed pre-training scenes without --scene. Prints JSON.
    Eval(cli::eval::EvalArgs),
    /// PPO training throughput on the pre-training task; prints one JSON line.
    Bench(cli::bench::BenchArgs),
    /// Export a checkpoint's policy as PolicyBlob bytes, and with --onnx as policy.onnx
    /// + policy.schema.json (normaliser folded in).
    Export(cli::export::ExportArgs),
    /// Retraining service: answers RetrainRequests with PolicyBlobs over iceoryx2.
    Serve(cli::serve::ServeArgs),
    /// One retraining on a scene file, offline (what `serve` does for one request); prints
    /// a JSON summary. Output goes to --out (default: `retrain/` beside the checkpoint).
    Retrain(cli::retrain::RetrainArgs),
    /// Distil the feasibility planner (and the straight line where it suffices) into a
    /// checkpoint's policy: DAgger over worlds of the task's [world]; best.ckpt, last.ckpt
    /// and distil.json in --out (then `pretrain --resume` for PPO).
    Distil(cli::distil::DistilArgs),
}

fn main() -> Result<()> {
    learner::init_tracing();
    let args = Cli::parse();
    let device = tch::Device::cuda_if_available();
    match args.cmd {
        Cmd::Pretrain(a) => cli::pretrain::run(a, device),
        Cmd::Eval(a) => cli::eval::run(a, device),
        Cmd::Bench(a) => cli::bench::run(a, device),
        Cmd::Export(a) => cli::export::run(a),
        Cmd::Serve(a) => cli::serve::run(a, device),
        Cmd::Retrain(a) => cli::retrain::run(a, device),
        Cmd::Distil(a) => cli::distil::run(a, device),
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// clap's own consistency checks over every subcommand (a flag defined twice, e.g. by a
    /// flattened settings struct and the subcommand, fails here instead of at a user's call).
    #[test]
    fn the_command_line_is_consistent() {
        super::Cli::command().debug_assert();
    }
}
