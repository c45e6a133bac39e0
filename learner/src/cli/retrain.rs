//! `learner retrain`: one retraining on a scene file (or one world of the unseen-worlds
//! benchmark's task generator), offline (what `serve` does for one request), then the best
//! checkpoint evaluated on the exact scene and on the fixed pre-training scenes (the task's
//! `[world]`: the retrained policy alone, the base, and both as the policy library rt-core
//! runs); prints a JSON summary.

use std::path::PathBuf;

use anyhow::{Context, Result};
use learner::checkpoint::{self, Checkpoint};
use learner::normalize::ObsNormalizer;
use learner::ppo::{evaluate, successes};
use learner::retrain::{RetrainFlags, RetrainJob};
use learner::twin_env::{CurriculumSampler, EVAL_SEED, TwinTask, fixed_scenes};
use rand::SeedableRng;
use twin::{Feasibility, Scene, check_feasibility};

use super::load_scene;

/// Arguments of `learner retrain`.
#[derive(clap::Args)]
pub struct RetrainArgs {
    /// The failed scene (or `--world-index`).
    #[arg(
        long,
        required_unless_present = "world_index",
        conflicts_with = "world_index"
    )]
    scene: Option<PathBuf>,
    /// Instead of `--scene`: world number N (0-based) of the worlds `unseen-worlds --seed S`
    /// draws (the task's `[world]` generator), e.g. `--world-index 34 --world-seed 7`.
    #[arg(long, allow_negative_numbers = true)]
    world_index: Option<usize>,
    /// The generator seed of `--world-index`.
    #[arg(long, default_value_t = 7, allow_negative_numbers = true)]
    world_seed: u64,
    /// The checkpoint, task, output folder and the retraining's settings (as `learner serve`
    /// takes them).
    #[command(flatten)]
    args: RetrainFlags,
}

/// World `index` of the `[world]` generator with `seed` (as `unseen-worlds` draws them).
fn benchmark_world(env: &TwinTask, seed: u64, index: usize) -> Scene {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut scene = env.env.sample_world(&mut rng);
    for _ in 0..index {
        scene = env.env.sample_world(&mut rng);
    }
    scene
}

/// Runs `learner retrain`.
///
/// # Errors
/// Task, scene, checkpoint or training failures, and an infeasible scene.
pub fn run(args: RetrainArgs, device: tch::Device) -> Result<()> {
    let RetrainArgs {
        scene,
        world_index,
        world_seed,
        args,
    } = args;
    tch::set_num_threads(1);
    let env = TwinTask::load(&args.task, None)?;
    let base = Checkpoint::load(&args.checkpoint)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| checkpoint::resolve(&args.checkpoint).with_file_name("retrain"));
    let scene = match (scene, world_index) {
        (Some(path), _) => load_scene(&path)?,
        (None, Some(i)) => {
            if env.env.config().world.is_none() {
                anyhow::bail!(
                    "--world-index: {} has no [world] section to draw worlds from",
                    args.task.display()
                );
            }
            benchmark_world(&env, world_seed, i)
        }
        (None, None) => anyhow::bail!("give --scene or --world-index"),
    };
    // As the service does: the feasibility check first; its path seeds the demonstrations.
    let t0 = std::time::Instant::now();
    let verdict = check_feasibility(
        &env.env,
        &scene,
        &env.env.config().start.joints_rad,
        args.feasibility(),
    );
    let feasibility_s = t0.elapsed().as_secs_f64();
    if let Feasibility::Infeasible(reason) = &verdict {
        anyhow::bail!(
            "infeasible scene: {} (checked in {feasibility_s:.2} s); not training",
            reason.display_with(&scene.obstacles)
        );
    }
    let outcome = RetrainJob {
        base: &base,
        env: &env,
        scene,
        planner_path: verdict.path(),
        settings: &args.settings(),
        out_dir: &out,
        eval_seed: 1,
        device,
    }
    .run(|_, _| true)?;
    let best = Checkpoint::load(&out.join(checkpoint::BEST))
        .with_context(|| format!("best checkpoint in {}", out.display()))?;
    let norm = ObsNormalizer::from_stats(&best.meta.obs_rms.to_rms(), best.meta.ppo.clip_obs);
    let exact = evaluate(&best.network(device)?, &norm, &env, &[scene], 1);
    let pre = fixed_scenes(&CurriculumSampler::pretraining(&env), 200, EVAL_SEED);
    let workers = best.meta.ppo.effective_workers();
    let old = evaluate(&best.network(device)?, &norm, &env, &pre, workers);
    // What rt-core runs: the policy library (retrained policy and base), the lookahead
    // taking whichever passes — a scene counts when either solves it.
    let base_norm = ObsNormalizer::from_stats(&base.meta.obs_rms.to_rms(), base.meta.ppo.clip_obs);
    let base_ok = successes(&base.network(device)?, &base_norm, &env, &pre, workers);
    let re_ok = successes(&best.network(device)?, &norm, &env, &pre, workers);
    let either = base_ok
        .iter()
        .zip(&re_ok)
        .filter(|(b, r)| **b || **r)
        .count();
    let library = either as f64 / pre.len().max(1) as f64;
    let base_rate = base_ok.iter().filter(|b| **b).count() as f64 / pre.len().max(1) as f64;
    println!(
        "{}",
        serde_json::json!({"summary": outcome.summary, "before": outcome.before, "warm_start": outcome.warm_start, "feasibility_s": feasibility_s, "best": best.meta.eval, "exact_scene": exact, "pretraining_scenes": old, "pretraining_scenes_base": base_rate, "pretraining_scenes_library": library, "best_steps": best.meta.steps - base.meta.steps, "out": out})
    );
    Ok(())
}
