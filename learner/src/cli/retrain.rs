//! `learner retrain`: one retraining on a scene file, offline (what `serve` does for one
//! request), then the best checkpoint evaluated on the exact scene and on the fixed
//! pre-training scenes (the task's `[world]`); prints a JSON summary.

use std::path::PathBuf;

use anyhow::Result;
use learner::checkpoint::{self, Checkpoint};
use learner::normalize::ObsNormalizer;
use learner::ppo::evaluate;
use learner::service;
use learner::twin_env::{CurriculumSampler, TwinTask, fixed_scenes};

use super::serve::ServeArgs;
use super::{EVAL_SEED, load_scene};

/// Arguments of `learner retrain`.
#[derive(clap::Args)]
pub struct RetrainArgs {
    /// The failed scene.
    #[arg(long)]
    scene: PathBuf,
    #[command(flatten)]
    args: ServeArgs,
}

/// Runs `learner retrain`.
///
/// # Errors
/// Task, scene, checkpoint or training failures.
pub fn run(args: RetrainArgs, device: tch::Device) -> Result<()> {
    let RetrainArgs { scene, args } = args;
    tch::set_num_threads(1);
    let env = TwinTask::load(&args.task, None)?;
    let base = Checkpoint::load(&args.checkpoint)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| checkpoint::resolve(&args.checkpoint).with_file_name("retrain"));
    let scene = load_scene(&scene)?;
    let (sum, before) = service::retrain(
        &base,
        &env,
        scene,
        &args.settings(),
        &out,
        1,
        device,
        |_, _| true,
    )?;
    let best = Checkpoint::load(&out.join(checkpoint::BEST))?;
    let norm = ObsNormalizer::from_stats(&best.meta.obs_rms.to_rms(), best.meta.ppo.clip_obs);
    let exact = evaluate(&best.network(device)?, &norm, &env, &[scene], 1);
    let old = evaluate(
        &best.network(device)?,
        &norm,
        &env,
        &fixed_scenes(&CurriculumSampler::pretraining(&env), 200, EVAL_SEED),
        best.meta.ppo.effective_workers(),
    );
    println!(
        "{}",
        serde_json::json!({"summary": sum, "before": before, "best": best.meta.eval, "exact_scene": exact, "pretraining_scenes": old, "best_steps": best.meta.steps - base.meta.steps, "out": out})
    );
    Ok(())
}
