//! `learner export`: a checkpoint's policy as a validated `PolicyBlob` file (written
//! atomically); prints a JSON line with the file, policy id, task hash, steps and size.

use std::path::PathBuf;

use anyhow::Result;
use learner::checkpoint::Checkpoint;
use learner::export;

/// Arguments of `learner export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    /// Checkpoint file or run directory (best.ckpt).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Output file.
    #[arg(long)]
    out: PathBuf,
    /// Policy id (default: derived from the checkpoint's step count and task hash).
    #[arg(long, allow_negative_numbers = true)]
    policy_id: Option<u64>,
}

/// Runs `learner export`.
///
/// # Errors
/// Checkpoint, blob or write failures.
pub fn run(args: ExportArgs) -> Result<()> {
    let ck = Checkpoint::load(&args.checkpoint)?;
    let id = args.policy_id.unwrap_or_else(|| export::policy_id_for(&ck));
    let blob = export::export_blob(&ck, id)?;
    export::write_blob(&args.out, &blob)?;
    println!(
        "{}",
        serde_json::json!({"out": args.out, "policy_id": id, "task_config_hash": format!("{:#x}", ck.meta.task_hash), "steps": ck.meta.steps, "bytes": size_of_val(&*blob)})
    );
    Ok(())
}
