//! `learner distil`: the feasibility planner (and the straight line where it suffices)
//! distilled into a checkpoint's policy by DAgger over worlds of the task's own `[world]`
//! sampler ([`learner::distil`]). Keeps `best.ckpt` (best success on the fixed evaluation
//! scenes of the pre-training distribution, ties broken by fewer contacts), `last.ckpt` and
//! `distil.json` in `--out`, all written atomically; prints the summary as JSON. Follow with
//! `learner pretrain --out DIR --resume` for PPO fine-tuning.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use learner::checkpoint::{self, Checkpoint};
use learner::distil::{DistilConfig, DistilIter, DistilWorlds, LessonCounts, distil, lessons};
use learner::ppo::{EvalResult, Trainer};
use learner::run::better;
use learner::twin_env::{CurriculumSampler, TwinTask, fixed_scenes};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use twin::{FeasibilityConfig, Scene};

use super::EVAL_SEED;
use learner::env::SceneSampler;

/// Seed family of the distillation worlds (distinct from the evaluation scenes' and from every
/// benchmark generator's).
const WORLD_SEED_BASE: u64 = 0xD157_0000;

/// Arguments of `learner distil`.
#[derive(clap::Args)]
pub struct DistilArgs {
    /// The policy to start from (checkpoint file or run directory); its network shape and
    /// observation statistics are kept.
    #[arg(long, default_value = "assets/policy")]
    checkpoint: PathBuf,
    /// Task configuration.
    #[arg(long, default_value = "assets/task.toml")]
    task: PathBuf,
    /// Worlds drawn from the task's `[world]` sampler.
    #[arg(long, default_value_t = 3000, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1_000_000), allow_negative_numbers = true)]
    worlds: usize,
    /// Share of the worlds drawn from the harder variants of `[world]` (crowded, tall:
    /// `learner::distil::harder_world_envs`).
    #[arg(long, default_value_t = 0.5, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    harder_share: f64,
    /// Hidden layer widths of the distilled network (e.g. `256,256`; each ≤ 256); default:
    /// the checkpoint's. Another shape starts from fresh weights with the checkpoint's
    /// observation statistics.
    #[arg(long, value_delimiter = ',', value_parser = shm_schemas::cli_bounds::int_within(1usize, 256), allow_negative_numbers = true)]
    hidden: Option<Vec<usize>>,
    /// DAgger iterations.
    #[arg(long, default_value_t = 6, value_parser = shm_schemas::cli_bounds::int_within(1usize, 100), allow_negative_numbers = true)]
    iterations: usize,
    /// Cloning steps after each iteration.
    #[arg(long, default_value_t = 3000, value_parser = shm_schemas::cli_bounds::int_within(1usize, 10_000_000), allow_negative_numbers = true)]
    bc_steps: usize,
    /// Cloning learning rate.
    #[arg(long, default_value_t = 1e-3, value_parser = shm_schemas::cli_bounds::f64_within(1e-7, 1.0), allow_negative_numbers = true)]
    bc_lr: f64,
    /// Action noise on every executed action (std, action units).
    #[arg(long, default_value_t = 0.2, value_parser = shm_schemas::cli_bounds::f32_within(0.0, 1.0), allow_negative_numbers = true)]
    noise_std: f32,
    /// Margin the teachers keep from every box (m): they plan with the boxes grown by it.
    #[arg(long, default_value_t = 0.02, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 0.1), allow_negative_numbers = true)]
    margin_m: f64,
    /// Evaluation scenes of the pre-training distribution (fixed set).
    #[arg(long, default_value_t = 200, value_parser = shm_schemas::cli_bounds::int_within(1usize, 1_000_000), allow_negative_numbers = true)]
    eval_episodes: usize,
    /// Seed (worlds, noise, minibatches).
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Threads that find the teachers.
    #[arg(long, default_value_t = 2, value_parser = shm_schemas::cli_bounds::int_within(1usize, 256), allow_negative_numbers = true)]
    threads: usize,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Serialize)]
struct Summary<'a> {
    checkpoint: String,
    worlds: LessonCounts,
    config: DistilConfig,
    before: EvalResult,
    iterations: &'a [Record],
    best_iteration: Option<usize>,
    best: EvalResult,
    teachers_s: f64,
    wall_s: f64,
}

#[derive(Serialize, Clone, Copy)]
struct Record {
    #[serde(flatten)]
    iter: DistilIter,
    eval: EvalResult,
    elapsed_s: f64,
}

/// Runs `learner distil`.
///
/// # Errors
/// Task, checkpoint or output failures.
pub fn run(args: DistilArgs, device: tch::Device) -> Result<()> {
    let t0 = Instant::now();
    let env = TwinTask::load(&args.task, None)?;
    let hash = env.task_hash();
    let path = checkpoint::resolve(&args.checkpoint);
    let ck = Checkpoint::load(&path).with_context(|| format!("--checkpoint {}", path.display()))?;
    if ck.meta.task_hash != hash {
        bail!(
            "--checkpoint {} was trained on task hash {:#x}, {} has {hash:#x}",
            path.display(),
            ck.meta.task_hash,
            args.task.display()
        );
    }
    let mut trainer = match &args.hidden {
        Some(h) if *h != ck.meta.spec.hidden => {
            let mut cfg = ck.meta.ppo.clone();
            cfg.hidden.clone_from(h);
            let mut t = Trainer::new(cfg, env.clone(), args.seed, device)?;
            t.obs_rms = ck.meta.obs_rms.to_rms();
            t.ret_rms = ck.meta.ret_rms.to_rms();
            t
        }
        _ => {
            let mut t = Trainer::new(ck.meta.ppo.clone(), env.clone(), ck.meta.seed, device)?;
            ck.restore(&mut t)?;
            t
        }
    };
    let norm = trainer.obs_normalizer();
    let sampler = CurriculumSampler::pretraining(&env);
    let eval_scenes = fixed_scenes(&sampler, args.eval_episodes, EVAL_SEED);
    let before = trainer.evaluate(&eval_scenes);

    let mut rng = ChaCha8Rng::seed_from_u64(WORLD_SEED_BASE ^ args.seed);
    let mix = DistilWorlds::new(&env, args.harder_share);
    let worlds: Vec<Scene> = (0..args.worlds).map(|_| mix.sample(&mut rng)).collect();
    let spinner = ProgressBar::new_spinner().with_message(format!(
        "finding a teacher for each of {} worlds",
        worlds.len()
    ));
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let (lessons, counts) = lessons(
        &env.env,
        &worlds,
        FeasibilityConfig::default(),
        args.margin_m,
        args.threads,
    );
    spinner.finish_and_clear();
    let teachers_s = t0.elapsed().as_secs_f64();
    tracing::info!(?counts, teachers_s, "teachers found");
    if lessons.is_empty() {
        bail!("no world of the {} drawn has a teacher", args.worlds);
    }

    let cfg = DistilConfig {
        iterations: args.iterations,
        noise_std: args.noise_std,
        bc: learner::ppo::bc::BcConfig {
            steps: args.bc_steps,
            lr: args.bc_lr,
            ..DistilConfig::default().bc
        },
        ..DistilConfig::default()
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("--out {}", args.out.display()))?;
    let bar = ProgressBar::new(cfg.iterations as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} DAgger iterations {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // The network is taken out of the trainer while it is cloned into, so that the trainer's
    // other state (statistics, configuration) can be read for the checkpoints meanwhile.
    let spec = trainer.net.spec.clone();
    let mut net = std::mem::replace(
        &mut trainer.net,
        learner::net::ActorCritic::new(spec, device, 0),
    );
    let mut records: Vec<Record> = Vec::new();
    let mut best: Option<(usize, EvalResult)> = None;
    let mut save_err: Option<anyhow::Error> = None;
    distil(
        &mut net,
        &norm,
        &env.env,
        &lessons,
        &cfg,
        args.seed,
        |net, it| {
            let eval = learner::ppo::evaluate(
                net,
                &norm,
                &env,
                &eval_scenes,
                trainer.cfg.effective_workers(),
            );
            records.push(Record {
                iter: *it,
                eval,
                elapsed_s: t0.elapsed().as_secs_f64(),
            });
            bar.inc(1);
            bar.set_message(format!(
                "success {:.1} %, contact {:.1} %",
                100.0 * eval.success_rate,
                100.0 * eval.collision_rate
            ));
            let is_best = best.is_none_or(|(_, b)| better(&eval, &b));
            let r = save(net, &trainer, &ck, hash, &args.out, is_best, eval);
            if let Err(e) = r {
                save_err = Some(e);
                return false;
            }
            if is_best {
                best = Some((it.iteration, eval));
            }
            true
        },
    );
    bar.finish();
    trainer.net = net;
    if let Some(e) = save_err {
        return Err(e);
    }
    let summary = Summary {
        checkpoint: path.display().to_string(),
        worlds: counts,
        config: cfg,
        before,
        iterations: &records,
        best_iteration: best.map(|b| b.0),
        best: best.map(|b| b.1).unwrap_or_default(),
        teachers_s,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    let json = serde_json::to_string_pretty(&summary)?;
    checkpoint::write_atomic(&args.out.join("distil.json"), json.as_bytes())?;
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}

/// Writes `last.ckpt` (and `best.ckpt` when `is_best`) for the network `net` with the base
/// checkpoint's trainer state.
fn save(
    net: &learner::net::ActorCritic,
    trainer: &Trainer<TwinTask>,
    base: &Checkpoint,
    hash: u64,
    out: &std::path::Path,
    is_best: bool,
    eval: EvalResult,
) -> Result<()> {
    let mut ck = Checkpoint::capture(trainer, base.meta.seed, hash);
    ck.theta = net.flat();
    ck.meta.eval = Some(eval);
    ck.meta.best_eval = Some(eval);
    ck.save(&out.join(checkpoint::LAST))?;
    if is_best {
        ck.save(&out.join(checkpoint::BEST))?;
    }
    Ok(())
}
