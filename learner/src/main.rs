//! The `learner` binary: pre-training, evaluation, benchmarking, export and the retraining
//! service. Thin: parses arguments and calls the library.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use learner::checkpoint::{self, Checkpoint};
use learner::ppo::{PpoConfig, Trainer, evaluate};
use learner::run::{RunOptions, train};
use learner::twin_env::{CurriculumSampler, Jitter, RetrainSampler, TwinTask, fixed_scenes};
use learner::{export, service};
use rt_core::twin::Scene;
use shm_schemas::scene_file::SceneFile;

/// Seed of the fixed evaluation scenes (distinct from every training stream).
const EVAL_SEED: u64 = 0x00E0_A15E;

#[derive(Parser)]
#[command(
    name = "learner",
    about = "PPO on the Foresight twin: pre-train, evaluate, export, serve retraining"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(clap::Args, Clone)]
struct PpoArgs {
    /// Parallel environments.
    #[arg(long)]
    envs: Option<usize>,
    /// Rollout worker threads (0 = one per core).
    #[arg(long)]
    workers: Option<usize>,
    /// Steps per environment per rollout.
    #[arg(long)]
    n_steps: Option<usize>,
    /// Minibatch size.
    #[arg(long)]
    batch: Option<usize>,
    /// Epochs per rollout.
    #[arg(long)]
    epochs: Option<usize>,
    /// Learning rate.
    #[arg(long)]
    lr: Option<f64>,
    /// Torch intra-op threads.
    #[arg(long, default_value_t = 1)]
    torch_threads: i32,
}

impl PpoArgs {
    fn config(&self) -> PpoConfig {
        let mut c = PpoConfig::default();
        if let Some(v) = self.envs {
            c.n_envs = v;
        }
        if let Some(v) = self.workers {
            c.workers = v;
        }
        if let Some(v) = self.n_steps {
            c.n_steps = v;
        }
        if let Some(v) = self.batch {
            c.batch_size = v;
        }
        if let Some(v) = self.epochs {
            c.n_epochs = v;
        }
        if let Some(v) = self.lr {
            c.learning_rate = v;
        }
        c
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// Pre-train on random small-obstacle scenes; keeps best.ckpt and last.ckpt in --out.
    Pretrain {
        /// Task configuration (the robot model is read from xarm5.urdf beside it).
        #[arg(long, default_value = "assets/task.toml")]
        task: PathBuf,
        /// Environment steps.
        #[arg(long, default_value_t = 1_000_000)]
        steps: u64,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Continue from --out/last.ckpt.
        #[arg(long)]
        resume: bool,
        /// Evaluate and checkpoint every this many steps.
        #[arg(long, default_value_t = 100_000)]
        eval_every: u64,
        /// Evaluation scenes (fixed set).
        #[arg(long, default_value_t = 200)]
        eval_episodes: usize,
        /// Wall-time budget (s).
        #[arg(long)]
        time_budget_s: Option<f64>,
        #[command(flatten)]
        ppo: PpoArgs,
    },
    /// Evaluate a checkpoint: on a scene file (the scene and lightly jittered variants), or
    /// on random small-obstacle scenes without --scene. Prints JSON.
    Eval {
        /// Checkpoint file or run directory (best.ckpt).
        #[arg(long)]
        checkpoint: PathBuf,
        /// Scene file.
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Episodes.
        #[arg(long, default_value_t = 200)]
        episodes: usize,
        /// Task configuration.
        #[arg(long, default_value = "assets/task.toml")]
        task: PathBuf,
        /// Evaluate the exported blob's normalisation (what rt-core runs) instead of the
        /// checkpoint's.
        #[arg(long)]
        blob: bool,
    },
    /// PPO training throughput on the pre-training task; prints one JSON line.
    Bench {
        /// Environment steps.
        #[arg(long, default_value_t = 200_000)]
        steps: u64,
        /// Task configuration.
        #[arg(long, default_value = "assets/task.toml")]
        task: PathBuf,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[command(flatten)]
        ppo: PpoArgs,
    },
    /// Export a checkpoint's policy as PolicyBlob bytes.
    Export {
        /// Checkpoint file or run directory (best.ckpt).
        #[arg(long)]
        checkpoint: PathBuf,
        /// Output file.
        #[arg(long)]
        out: PathBuf,
        /// Policy id (default: derived from the checkpoint's step count and task hash).
        #[arg(long)]
        policy_id: Option<u64>,
    },
    /// Retraining service: answers RetrainRequests with PolicyBlobs over iceoryx2.
    Serve(service::ServeArgs),
    /// One retraining on a scene file, offline (what `serve` does for one request); prints
    /// a JSON summary. Output goes to --out (default: `retrain/` beside the checkpoint).
    Retrain {
        /// The failed scene.
        #[arg(long)]
        scene: PathBuf,
        #[command(flatten)]
        args: service::ServeArgs,
    },
}

fn load_scene(path: &Path) -> Result<Scene> {
    let file = SceneFile::load(path).with_context(|| format!("scene {}", path.display()))?;
    Scene::from_file(&file).map_err(|e| anyhow::anyhow!("scene {}: {e:?}", path.display()))
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let device = tch::Device::cuda_if_available();
    match cli.cmd {
        Cmd::Pretrain {
            task,
            steps,
            seed,
            out,
            resume,
            eval_every,
            eval_episodes,
            time_budget_s,
            ppo,
        } => {
            tch::set_num_threads(ppo.torch_threads);
            let env = TwinTask::load(&task, None)?;
            let hash = env.task_hash();
            let sampler = CurriculumSampler::small(&env);
            let eval_scenes = fixed_scenes(&sampler, eval_episodes, EVAL_SEED);
            let mut trainer =
                Trainer::new(ppo.config(), env, seed, device).map_err(anyhow::Error::msg)?;
            if resume {
                let ck = Checkpoint::load(&out.join(checkpoint::LAST))
                    .context("resume: reading last.ckpt")?;
                if ck.meta.task_hash != hash {
                    bail!(
                        "resume: last.ckpt was trained on task hash {:#x}, {} has {hash:#x}",
                        ck.meta.task_hash,
                        task.display()
                    );
                }
                trainer = Trainer::new(
                    ck.meta.ppo.clone(),
                    trainer_env(&task)?,
                    ck.meta.seed,
                    device,
                )
                .map_err(anyhow::Error::msg)?;
                ck.restore(&mut trainer)?;
                tracing::info!(steps = trainer.steps, "resumed");
            }
            let opts = RunOptions {
                out_dir: out.clone(),
                total_steps: steps,
                eval_every_steps: eval_every,
                seed,
                task_hash: hash,
                time_budget: time_budget_s.map(Duration::from_secs_f64),
                success_rule: None,
                title: format!("pre-training (seed {seed})"),
                progress: true,
            };
            tracing::info!(device = ?device, workers = trainer.cfg.effective_workers(), envs = trainer.cfg.n_envs, "pre-training");
            let sum = train(&mut trainer, &sampler, &eval_scenes, &opts, |_, _| true)?;
            println!("{}", serde_json::to_string(&sum)?);
        }
        Cmd::Eval {
            checkpoint,
            scene,
            episodes,
            task,
            blob,
        } => {
            let env = TwinTask::load(&task, None)?;
            let ck = Checkpoint::load(&checkpoint)?;
            if ck.meta.task_hash != env.task_hash() {
                tracing::warn!(
                    "checkpoint task hash {:#x} differs from {}'s {:#x}",
                    ck.meta.task_hash,
                    task.display(),
                    env.task_hash()
                );
            }
            let scenes = match scene {
                Some(p) => RetrainSampler::new(&env, load_scene(&p)?, Jitter::default(), 0.0)
                    .eval_scenes(episodes, EVAL_SEED, 0.5),
                None => fixed_scenes(&CurriculumSampler::small(&env), episodes, EVAL_SEED),
            };
            let net = ck.network(device)?;
            let norm = if blob {
                export::blob_normalizer(&*export::export_blob(&ck, 1)?)
            } else {
                learner::normalize::ObsNormalizer::from_stats(
                    &ck.meta.obs_rms.to_rms(),
                    ck.meta.ppo.clip_obs,
                )
            };
            let r = evaluate(&net, &norm, &env, &scenes, ck.meta.ppo.effective_workers());
            println!("{}", serde_json::to_string(&r)?);
        }
        Cmd::Bench {
            steps,
            task,
            seed,
            ppo,
        } => {
            tch::set_num_threads(ppo.torch_threads);
            let env = TwinTask::load(&task, None)?;
            let sampler = CurriculumSampler::small(&env);
            let mut trainer =
                Trainer::new(ppo.config(), env, seed, device).map_err(anyhow::Error::msg)?;
            let t0 = Instant::now();
            let (mut rollout_s, mut update_s) = (0.0, 0.0);
            while trainer.steps < steps {
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
        }
        Cmd::Export {
            checkpoint,
            out,
            policy_id,
        } => {
            let ck = Checkpoint::load(&checkpoint)?;
            let id = policy_id.unwrap_or_else(|| service::policy_id_for(&ck));
            let blob = export::export_blob(&ck, id)?;
            export::write_blob(&out, &blob)?;
            println!(
                "{}",
                serde_json::json!({"out": out, "policy_id": id, "task_config_hash": format!("{:#x}", ck.meta.task_hash), "steps": ck.meta.steps, "bytes": size_of_val(&*blob)})
            );
        }
        Cmd::Retrain { scene, args } => {
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
                scene.clone(),
                &args,
                &out,
                1,
                device,
                |_, _| true,
            )?;
            let best = Checkpoint::load(&out.join(checkpoint::BEST))?;
            let norm = learner::normalize::ObsNormalizer::from_stats(
                &best.meta.obs_rms.to_rms(),
                best.meta.ppo.clip_obs,
            );
            let exact = evaluate(&best.network(device)?, &norm, &env, &[scene], 1);
            let old = evaluate(
                &best.network(device)?,
                &norm,
                &env,
                &fixed_scenes(&CurriculumSampler::small(&env), 200, EVAL_SEED),
                best.meta.ppo.effective_workers(),
            );
            println!(
                "{}",
                serde_json::json!({"summary": sum, "before": before, "best": best.meta.eval, "exact_scene": exact, "small_obstacle_scenes": old, "best_steps": best.meta.steps - base.meta.steps, "out": out})
            );
        }
        Cmd::Serve(args) => {
            tch::set_num_threads(1);
            service::serve(&args, device)?;
        }
    }
    Ok(())
}

fn trainer_env(task: &Path) -> Result<TwinTask> {
    Ok(TwinTask::load(task, None)?)
}
