//! `learner pretrain`: PPO on the task's pre-training distribution (its broad `[world]`, or
//! random small-obstacle scenes without one), evaluated on a fixed scene set of it; keeps `best.ckpt`, `last.ckpt`, `metrics.csv` and `reward.svg` in `--out`
//! (`--resume` continues from `last.ckpt`). Prints the run summary as JSON.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use learner::checkpoint::{self, Checkpoint};
use learner::distil::DistilWorlds;
use learner::ppo::Trainer;
use learner::run::{RunOptions, train};
use learner::twin_env::{CurriculumSampler, TwinTask, fixed_scenes};

use super::{EVAL_SEED, PpoArgs};

/// Arguments of `learner pretrain`.
#[derive(clap::Args)]
pub struct PretrainArgs {
    /// Task configuration (the robot model is read from xarm5.urdf beside it).
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Environment steps.
    #[arg(long, default_value_t = 1_000_000, value_parser = shm_schemas::cli_bounds::int_within(1u64, 100_000_000_000), allow_negative_numbers = true)]
    steps: u64,
    /// Seed.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Continue from --out/last.ckpt.
    #[arg(long)]
    resume: bool,
    /// Evaluate and checkpoint every this many steps.
    #[arg(long, default_value_t = 100_000, value_parser = shm_schemas::cli_bounds::int_within(1u64, 10_000_000_000), allow_negative_numbers = true)]
    eval_every: u64,
    /// Evaluation scenes (fixed set).
    #[arg(long, default_value_t = 200, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1_000_000), allow_negative_numbers = true)]
    eval_episodes: usize,
    /// Wall-time budget (s).
    #[arg(long, value_parser = shm_schemas::cli_bounds::f64_within(0.1, 1e7), allow_negative_numbers = true)]
    time_budget_s: Option<f64>,
    /// Anneal the learning rate linearly from `--lr` (or the default) to this by `--steps`.
    #[arg(long, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    lr_final: Option<f64>,
    /// Share of the episodes drawn from the harder variants of `[world]` (crowded, tall:
    /// `learner::distil::DistilWorlds`); 0 = the task's `[world]` alone. Used to fine-tune a
    /// `learner distil` result with PPO on the distribution it was distilled on.
    #[arg(long, default_value_t = 0.0, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    harder_share: f64,
    #[command(flatten)]
    ppo: PpoArgs,
}

/// Runs `learner pretrain`.
///
/// # Errors
/// Task, configuration, checkpoint or output failures.
pub fn run(args: PretrainArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(args.ppo.torch_threads);
    let env = TwinTask::load(&args.task, None)?;
    let hash = env.task_hash();
    if let Some(lr) = args.lr_final
        && !(lr.is_finite() && lr > 0.0 && lr <= 1.0)
    {
        bail!("--lr-final must be in (0, 1] (got {lr})");
    }
    // The evaluation (and so best.ckpt) stays on the task's own distribution.
    let eval_scenes = fixed_scenes(
        &CurriculumSampler::pretraining(&env),
        args.eval_episodes,
        EVAL_SEED,
    );
    let sampler = DistilWorlds::new(&env, args.harder_share);
    let mut trainer = Trainer::new(args.ppo.config(), env, args.seed, device)?;
    if args.resume {
        trainer = resumed(&args, hash, device)?;
    }
    let seed = args.seed;
    let opts = RunOptions {
        out_dir: args.out.clone(),
        total_steps: args.steps,
        eval_every_steps: args.eval_every,
        seed,
        task_hash: hash,
        time_budget: args.time_budget_s.map(Duration::from_secs_f64),
        success_rule: None,
        title: format!("pre-training (seed {seed})"),
        progress: true,
        lr_schedule: args.lr_final.map(|end| (trainer.cfg.learning_rate, end)),
    };
    tracing::info!(device = ?device, workers = trainer.cfg.effective_workers(), envs = trainer.cfg.n_envs, "pre-training");
    let sum = train(&mut trainer, &sampler, &eval_scenes, &opts, |_, _| true)?;
    println!("{}", serde_json::to_string(&sum)?);
    Ok(())
}

/// The trainer of `--out/last.ckpt` (its configuration and seed), checked against the task.
fn resumed(args: &PretrainArgs, hash: u64, device: tch::Device) -> Result<Trainer<TwinTask>> {
    let ck =
        Checkpoint::load(&args.out.join(checkpoint::LAST)).context("resume: reading last.ckpt")?;
    if ck.meta.task_hash != hash {
        bail!(
            "resume: last.ckpt was trained on task hash {:#x}, {} has {hash:#x}",
            ck.meta.task_hash,
            args.task.display()
        );
    }
    let mut env = TwinTask::load(&args.task, None)?;
    env.set_action_space(ck.meta.action_space());
    let mut trainer = Trainer::new(ck.meta.ppo.clone(), env, ck.meta.seed, device)?;
    ck.restore(&mut trainer)?;
    tracing::info!(steps = trainer.steps, "resumed");
    Ok(trainer)
}
