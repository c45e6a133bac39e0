//! `learner eval`: a checkpoint's deterministic policy on a scene file (the scene and lightly
//! jittered variants) or on the fixed scenes of the task's pre-training distribution; prints the
//! [`learner::ppo::EvalResult`] as JSON.

use std::path::PathBuf;

use anyhow::Result;
use learner::checkpoint::Checkpoint;
use learner::export;
use learner::normalize::ObsNormalizer;
use learner::ppo::evaluate;
use learner::twin_env::{CurriculumSampler, Jitter, RetrainSampler, TwinTask, fixed_scenes};

use super::{EVAL_SEED, load_scene};

/// Arguments of `learner eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Checkpoint file or run directory (best.ckpt).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Scene file.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Episodes.
    #[arg(long, default_value_t = 200, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1_000_000), allow_negative_numbers = true)]
    episodes: usize,
    /// Task configuration.
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Evaluate the exported blob's normalisation (what rt-core runs) instead of the
    /// checkpoint's.
    #[arg(long)]
    blob: bool,
}

/// Runs `learner eval`.
///
/// # Errors
/// Task, checkpoint, scene or export failures.
pub fn run(args: EvalArgs, device: tch::Device) -> Result<()> {
    let mut env = TwinTask::load(&args.task, None)?;
    let ck = Checkpoint::load(&args.checkpoint)?;
    env.set_action_space(ck.meta.action_space());
    if ck.meta.task_hash != env.task_hash() {
        tracing::warn!(
            "checkpoint task hash {:#x} differs from {}'s {:#x}",
            ck.meta.task_hash,
            args.task.display(),
            env.task_hash()
        );
    }
    let scenes =
        match &args.scene {
            Some(p) => RetrainSampler::new(&env, load_scene(p)?, Jitter::default(), 0.0)
                .eval_scenes(args.episodes, EVAL_SEED, 0.5),
            None => fixed_scenes(
                &CurriculumSampler::pretraining(&env),
                args.episodes,
                EVAL_SEED,
            ),
        };
    let net = ck.network(device)?;
    let norm = if args.blob {
        export::blob_normalizer(&*export::export_blob(&ck, 1)?)
    } else {
        ObsNormalizer::from_stats(&ck.meta.obs_rms.to_rms(), ck.meta.ppo.clip_obs)
    };
    let r = evaluate(&net, &norm, &env, &scenes, ck.meta.ppo.effective_workers());
    println!("{}", serde_json::to_string(&r)?);
    Ok(())
}
