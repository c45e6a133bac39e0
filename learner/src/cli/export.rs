//! `learner export`: a checkpoint's policy as a validated `PolicyBlob` file (written
//! atomically), and with `--onnx DIR` as `policy.onnx` + `policy.schema.json` (the
//! normaliser folded in; `learner::onnx`); `--blob` exports an existing blob file instead
//! of a checkpoint. Prints a JSON line with what was written.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use learner::checkpoint::Checkpoint;
use learner::{export, onnx};
use twin::TaskConfig;

/// Arguments of `learner export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    /// Checkpoint file or run directory (best.ckpt).
    #[arg(long, conflicts_with = "blob", required_unless_present = "blob")]
    checkpoint: Option<PathBuf>,
    /// A policy blob file to export (with --onnx) instead of a checkpoint.
    #[arg(long, requires = "onnx")]
    blob: Option<PathBuf>,
    /// Output blob file (with --checkpoint).
    #[arg(long, required_unless_present_any = ["blob", "onnx"])]
    out: Option<PathBuf>,
    /// Also write `policy.onnx` and `policy.schema.json` into this folder (made if missing).
    #[arg(long)]
    onnx: Option<PathBuf>,
    /// The task file whose `action.scale_m` the schema states (only when its hash is the
    /// policy's task hash; otherwise the schema leaves it null and says so on stderr).
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Policy id (default: derived from the checkpoint's step count and task hash).
    #[arg(long, allow_negative_numbers = true)]
    policy_id: Option<u64>,
}

/// Runs `learner export`.
///
/// # Errors
/// Checkpoint, blob, task or write failures.
pub fn run(args: ExportArgs) -> Result<()> {
    let (blob, steps) = match (&args.checkpoint, &args.blob) {
        (Some(path), None) => {
            let ck = Checkpoint::load(path)?;
            let id = args.policy_id.unwrap_or_else(|| export::policy_id_for(&ck));
            (export::export_blob(&ck, id)?, Some(ck.meta.steps))
        }
        (None, Some(path)) => (
            export::read_blob(path).with_context(|| format!("reading {}", path.display()))?,
            None,
        ),
        _ => bail!("give exactly one of --checkpoint and --blob"),
    };
    let mut report = serde_json::json!({
        "policy_id": blob.policy_id,
        "task_config_hash": format!("{:#x}", blob.task_config_hash),
        "steps": steps,
    });
    if let Some(out) = &args.out {
        export::write_blob(out, &blob)?;
        report["out"] = serde_json::json!(out);
        report["bytes"] = serde_json::json!(size_of_val(&*blob));
    }
    if let Some(dir) = &args.onnx {
        let scale_m = match TaskConfig::load(&args.task) {
            Ok(task) if task.hash() == blob.task_config_hash => Some(onnx::ActionScales {
                scale_m: task.action.scale_m,
                joint_scale_rad: task.action.joint_scale_rad(),
            }),
            Ok(_) => {
                eprintln!(
                    "learner export: {} is not the policy's task (hash differs): the schema's action scale is null",
                    args.task.display()
                );
                None
            }
            Err(e) => {
                eprintln!(
                    "learner export: {}: {e}; the schema's action scale is null",
                    args.task.display()
                );
                None
            }
        };
        let (onnx_path, schema_path) = onnx::write_export(dir, &blob, scale_m)
            .with_context(|| format!("exporting to {}", dir.display()))?;
        report["onnx"] = serde_json::json!(onnx_path);
        report["schema"] = serde_json::json!(schema_path);
    }
    println!("{report}");
    Ok(())
}
