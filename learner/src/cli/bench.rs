//! `learner bench`: PPO training throughput on the pre-training task (no evaluation, no
//! checkpoints); prints one JSON line with steps per second overall and for rollouts alone.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use learner::ppo::Trainer;
use learner::twin_env::{CurriculumSampler, TwinTask};

use super::PpoArgs;

/// Arguments of `learner bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Environment steps.
    #[arg(long, default_value_t = 200_000, value_parser = shm_schemas::cli_bounds::int_within(1u64, 10_000_000_000), allow_negative_numbers = true)]
    steps: u64,
    /// Task configuration.
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Seed.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    #[command(flatten)]
    ppo: PpoArgs,
}

/// Runs `learner bench`.
///
/// # Errors
/// Task or configuration failures.
pub fn run(args: BenchArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(args.ppo.torch_threads);
    let env = TwinTask::load(&args.task, None)?;
    let sampler = CurriculumSampler::pretraining(&env);
    let mut trainer = Trainer::new(args.ppo.config(), env, args.seed, device)?;
    let t0 = Instant::now();
    let (mut rollout_s, mut update_s) = (0.0, 0.0);
    while trainer.steps < args.steps {
        let st = trainer.iterate(&sampler);
        rollout_s += st.rollout_s;
        update_s += st.update_s;
    }
    let wall_s = t0.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({
            "steps": trainer.steps,
            "wall_s": wall_s,
            "steps_per_s": trainer.steps as f64 / wall_s,
            "rollout_steps_per_s": trainer.steps as f64 / rollout_s,
            "update_s": update_s,
            "envs": trainer.cfg.n_envs,
            "workers": trainer.cfg.effective_workers(),
        })
    );
    Ok(())
}
