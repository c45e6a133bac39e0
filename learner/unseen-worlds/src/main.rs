//! `unseen-worlds`: the offline unseen-worlds benchmark, per world generator.
//!
//! Its own binary, not a `learner` subcommand: it is the only code that uses the independent
//! world generators (`worldgen`) and the plots (`plotters`), so the learner, which trains, does
//! not depend on them, and Cargo's dependency graph keeps the benchmark's worlds out of
//! training (`tests/worldgen/tests/worldgen.rs` checks it).
//!
//! `--generator task` (the default) draws `--worlds` worlds of the task's own `[world]`
//! sampler from `--seed` (the stream `foresight --runs N --seed S --worlds random` uses, so
//! both see the same worlds; infeasible draws stay in the table as refused). `uniform`,
//! `cluttered` and `adversarial` take the worlds of the independent generators of the
//! `worldgen` crate (no code shared with training): each draws until `--worlds` worlds are
//! proven feasible by the twin's planner and reports the infeasible draws it skipped.
//! `all` runs the four.
//!
//! For each world: the scripted straight line (Cartesian), the joint straight line (the
//! joint-step space's baseline: `twin::JointLinePolicy` toward the goal posture the twin
//! chooses), the policy zero-shot in its checkpoint's action space (success, contact or
//! timeout), the planner — the feasibility proof's joint path re-tracked in the twin
//! (`worldgen::track_path`): 100 % of feasible worlds by construction, the ceiling of the
//! planner fallback, not a learned skill — and, with `--retrain`, for each feasible world
//! the policy fails, one retraining as `learner serve` runs it ([`learner::retrain::RetrainJob`]) (the adaptation benchmark:
//! world change → learned policy, steps, success on the world) and the retrained policy's
//! success on the pre-training evaluation scenes ("kept"), alone and as rt-core runs it — in
//! a policy library with the base policy (a scene counts when either policy solves it).
//!
//! With `--samples 1,8,32,64`, verified sampling as rt-core's twin worker runs it before its
//! planner fallback (`twin::Sampler`, the same code): for each K, the checkpoint's exported
//! blob (what rt-core runs) rolled out as K candidates — the deterministic rollout and K − 1
//! perturbed ones — each verified by the twin's episode (goal reached, no contact); pass@K
//! is the share of feasible worlds where at least one passes, with the wall time of the K
//! rollouts on `--sample-threads` threads.
//!
//! Prints the rows and a per-generator table, and writes (atomically) to `--out`:
//! `worlds.json`, `worlds.md`, `worlds.png` (per generator: policy vs straight line vs
//! planner) and, with `--retrain`, `adaptation.png` (retraining time per failed world).

#![forbid(unsafe_code)]

mod plot;
mod report;

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use learner::checkpoint::{self, Checkpoint, write_atomic};
use learner::net::ActorCritic;
use learner::normalize::ObsNormalizer;
use learner::ppo::{EvalResult, evaluate, successes};
use learner::retrain::{RetrainFlags, RetrainJob};
use learner::run::StopReason;
use learner::twin_env::{CurriculumSampler, EVAL_SEED, TwinTask, fixed_scenes};
use policy::{MlpPolicy, PolicyExpectation, PolicyLoader};
use rand::SeedableRng;
use serde::Serialize;
use shm_schemas::ActionSpace;
use twin::{
    Feasibility, InfeasibleReason, Joints, Sampler, SamplingSettings, Scene, check_feasibility,
};
use worldgen::Generator;

use plot::{plot_adaptation, plot_rates, png_atomic};
use report::{aggregate, markdown, print_row, sampling_table, summary_table};

/// Which worlds the benchmark runs on (`--generator`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GeneratorChoice {
    /// The task's own `[world]` sampler (what the generalist was trained on).
    Task,
    /// `worldgen`'s uniform generator.
    Uniform,
    /// `worldgen`'s cluttered generator.
    Cluttered,
    /// `worldgen`'s adversarial generator.
    Adversarial,
    /// The four, one table each.
    All,
}

/// Where one table's worlds come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Source {
    Task,
    Independent(Generator),
}

impl Source {
    fn name(self) -> &'static str {
        match self {
            Self::Task => "task",
            Self::Independent(g) => g.name(),
        }
    }
}

impl GeneratorChoice {
    fn sources(self) -> Vec<Source> {
        match self {
            Self::Task => vec![Source::Task],
            Self::Uniform => vec![Source::Independent(Generator::Uniform)],
            Self::Cluttered => vec![Source::Independent(Generator::Cluttered)],
            Self::Adversarial => vec![Source::Independent(Generator::Adversarial)],
            Self::All => std::iter::once(Source::Task)
                .chain(Generator::ALL.map(Source::Independent))
                .collect(),
        }
    }
}

/// Arguments of `unseen-worlds`.
#[derive(Parser)]
#[command(
    name = "unseen-worlds",
    about = "The offline unseen-worlds benchmark: feasibility, straight line, planner, zero-shot, verified sampling and (with --retrain) retraining on worlds of the task's [world] sampler and of the independent generators; table and worlds.json / worlds.md / worlds.png in --out"
)]
struct WorldsArgs {
    /// Worlds per generator (for the independent generators: feasible worlds).
    #[arg(long, default_value_t = 40, value_parser = shm_schemas::cli_bounds::int_within(1usize, 100_000), allow_negative_numbers = true)]
    worlds: usize,
    /// Seed of the world generators (for `task`: the seed of `foresight --runs N --seed S
    /// --worlds random`).
    #[arg(long, default_value_t = 7, allow_negative_numbers = true)]
    seed: u64,
    /// Which worlds: the task's own sampler, an independent generator, or all four.
    #[arg(long, value_enum, default_value_t = GeneratorChoice::Task)]
    generator: GeneratorChoice,
    /// Retrain on every feasible world the policy fails (as `learner serve` would).
    #[arg(long)]
    retrain: bool,
    /// Pre-training evaluation scenes (the fixed set `learner eval` uses) on which each
    /// retrained policy's success is measured afterwards ("kept").
    #[arg(long, default_value_t = 200, value_parser = shm_schemas::cli_bounds::int_within(0usize, 1_000_000), allow_negative_numbers = true)]
    kept_eval_episodes: usize,
    /// Verified sampling: the K values to measure pass@K for (comma-separated, each
    /// 1..=256; candidate 0 is the deterministic rollout). Empty: none.
    #[arg(long, value_delimiter = ',', value_parser = shm_schemas::cli_bounds::int_within(1usize, twin::MAX_SAMPLES), allow_negative_numbers = true)]
    samples: Vec<usize>,
    /// Standard deviation of the sampled candidates' action noise, action units (rt-core's
    /// `sampling.noise_sigma`).
    #[arg(long, default_value_t = SamplingSettings::default().noise_sigma, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 2.0), allow_negative_numbers = true)]
    sample_sigma: f64,
    /// Step-to-step correlation of that noise (`sampling.noise_correlation`).
    #[arg(long, default_value_t = SamplingSettings::default().noise_correlation, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 0.99), allow_negative_numbers = true)]
    sample_correlation: f64,
    /// Seed of the candidates' noise (`sampling.seed`).
    #[arg(long, default_value_t = SamplingSettings::default().seed, allow_negative_numbers = true)]
    sample_seed: u64,
    /// Share of the perturbed candidates that start with a via point instead of action
    /// noise (`sampling.via_point_share`).
    #[arg(long, default_value_t = SamplingSettings::default().via_point_share, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    sample_via_share: f64,
    /// Threads the candidates run on (`sampling.threads`).
    #[arg(long, default_value_t = SamplingSettings::default().threads, value_parser = shm_schemas::cli_bounds::int_within(1usize, twin::MAX_SAMPLE_THREADS), allow_negative_numbers = true)]
    sample_threads: usize,
    /// The checkpoint, task, output folder (`--out`, required here) and the retraining
    /// settings, as `learner serve` takes them.
    #[command(flatten)]
    args: RetrainFlags,
}

/// One world's row.
#[derive(Debug, Clone, Serialize)]
struct WorldRow {
    generator: &'static str,
    index: usize,
    /// The generator's case (`near_path`, …; the generator's name otherwise).
    kind: &'static str,
    boxes: usize,
    tallest_box_m: f64,
    feasible: bool,
    /// Why the world is infeasible, in words (naming the blocking boxes).
    infeasible_reason: Option<String>,
    feasibility_s: f64,
    straight_line: bool,
    /// The joint straight line to the goal posture the twin chooses reached the goal with no
    /// contact (the joint-step space's counterpart of `straight_line`).
    joint_line: bool,
    zero_shot: bool,
    zero_shot_contact: bool,
    zero_shot_timeout: bool,
    /// The planner's path re-tracked: safe all along and ending within tolerance (`None`
    /// for an infeasible world).
    planner: Option<bool>,
    /// Verified sampling, one entry per `--samples` K.
    samples: Vec<SampleRow>,
    retrained: Option<RetrainRow>,
    scene: shm_schemas::scene_file::SceneFile,
}

/// Verified sampling with K candidates on one world.
#[derive(Debug, Clone, Serialize)]
struct SampleRow {
    k: usize,
    /// At least one candidate passed.
    passed: bool,
    /// Candidates that passed.
    passing: usize,
    /// The best that passed (fewest steps, then clearance): its index and steps.
    best_index: Option<usize>,
    best_steps: Option<u32>,
    /// Wall time of the K rollouts, s.
    elapsed_s: f64,
}

/// pass@K over a generator's feasible worlds.
#[derive(Debug, Clone, Serialize)]
struct PassAt {
    k: usize,
    passed: usize,
    rate: f64,
    /// Passed by a perturbed candidate only (the deterministic one failed).
    rescued: usize,
    median_s: Option<f64>,
    max_s: Option<f64>,
}

/// What one retraining did.
#[derive(Debug, Clone, Serialize)]
struct RetrainRow {
    success: bool,
    /// The warm start found a demonstration of the reported world in the task's own action
    /// space (a planner path or a via-point route that Cartesian steps follow to the goal
    /// with no contact). Without one, the world may have no solution a policy can express:
    /// its safe goal postures exist (the feasibility proof) but the per-step IK does not
    /// lead there.
    demonstrated: bool,
    wall_s: f64,
    steps: u64,
    stop: StopReason,
    /// The retrained policy alone on the pre-training scenes.
    kept: EvalResult,
    /// The library (retrained policy, then the base) on the pre-training scenes: the share
    /// of scenes either solves.
    library_kept: f64,
}

/// The aggregate figures of one generator (rates over its feasible worlds).
#[derive(Debug, Clone, Serialize)]
struct Aggregate {
    worlds: usize,
    feasible: usize,
    infeasible: usize,
    straight_line: usize,
    joint_line: usize,
    zero_shot: usize,
    zero_shot_contact: usize,
    zero_shot_timeout: usize,
    planner: usize,
    straight_line_rate: f64,
    joint_line_rate: f64,
    zero_shot_rate: f64,
    zero_shot_contact_rate: f64,
    planner_rate: f64,
    /// Solved by the straight line and not by the policy.
    line_not_policy: usize,
    retrained: usize,
    retrain_success: usize,
    /// Retrained worlds not learned that had no demonstration in the action space
    /// ([`RetrainRow::demonstrated`]).
    retrain_failed_undemonstrated: usize,
    retrain_median_s: Option<f64>,
    retrain_max_s: Option<f64>,
    retrain_median_steps: Option<f64>,
    kept_min: Option<f64>,
    kept_median: Option<f64>,
    library_kept_min: Option<f64>,
    library_kept_median: Option<f64>,
    /// Verified sampling per K.
    pass_at: Vec<PassAt>,
}

/// One generator's table.
#[derive(Debug, Clone, Serialize)]
struct GeneratorTable {
    generator: &'static str,
    /// Infeasible draws the generator skipped (independent generators; the task's sampler
    /// keeps them as rows).
    skipped_infeasible: usize,
    skipped_reasons: Vec<String>,
    /// Generation and feasibility proofs (s).
    generation_s: f64,
    aggregate: Aggregate,
    worlds: Vec<WorldRow>,
}

/// A world to run: the scene and the feasibility verdict.
struct Candidate {
    kind: &'static str,
    scene: Scene,
    /// The planner's path, or why the world is infeasible.
    verdict: Result<Vec<Joints>, InfeasibleReason>,
    feasibility_s: f64,
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// The policy under test and what the retraining needs.
struct Bench<'a> {
    args: &'a WorldsArgs,
    env: &'a TwinTask,
    base: &'a Checkpoint,
    net: &'a ActorCritic,
    norm: &'a ObsNormalizer,
    workers: usize,
    kept_scenes: &'a [Scene],
    base_ok: &'a [bool],
    out: &'a Path,
    device: tch::Device,
    /// The checkpoint's exported blob, as rt-core runs it (with `--samples`).
    mlp: Option<MlpPolicy>,
}

fn main() -> Result<()> {
    learner::init_tracing();
    run(WorldsArgs::parse(), tch::Device::cuda_if_available())
}

/// Runs the benchmark.
///
/// # Errors
/// Task, checkpoint, generation, training or output failures.
fn run(args: WorldsArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(1);
    let serve = &args.args;
    anyhow::ensure!(
        (1..=10_000).contains(&args.worlds),
        "--worlds must be in 1..=10000 (got {})",
        args.worlds
    );
    let out = serve.out.clone().context("unseen-worlds needs --out DIR")?;
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let mut env = TwinTask::load(&serve.task, None)?;
    let sources = args.generator.sources();
    if sources.contains(&Source::Task) && env.env.config().world.is_none() {
        anyhow::bail!(
            "{} has no [world] section: --generator task draws its worlds from it",
            serve.task.display()
        );
    }
    let base = load_checkpoint(serve, &env)?;
    let space = policy_space(&args, &base, &mut env)?;
    let net = base.network(device)?;
    let norm = ObsNormalizer::from_stats(&base.meta.obs_rms.to_rms(), base.meta.ppo.clip_obs);
    let workers = base.meta.ppo.effective_workers();
    let kept_scenes = fixed_scenes(
        &CurriculumSampler::pretraining(&env),
        args.kept_eval_episodes,
        EVAL_SEED,
    );
    let base_kept = evaluate(&net, &norm, &env, &kept_scenes, workers);
    let base_ok = successes(&net, &norm, &env, &kept_scenes, workers);
    let mlp = exported_policy(&args, &base, &env)?;
    let bench = Bench {
        args: &args,
        env: &env,
        base: &base,
        net: &net,
        norm: &norm,
        workers,
        kept_scenes: &kept_scenes,
        base_ok: &base_ok,
        out: &out,
        device,
        mlp,
    };
    let mut tables = Vec::new();
    for source in sources {
        tables.push(bench.table(source)?);
    }
    let mut md = markdown(&tables, &base_kept, args.seed);
    println!("\n{}", summary_table(&tables));
    let sampled = sampling_table(&tables, args.sample_threads);
    if !sampled.is_empty() {
        println!(
            "verified sampling (sigma {}, correlation {}, via-point share {}, seed {}):\n{sampled}",
            args.sample_sigma, args.sample_correlation, args.sample_via_share, args.sample_seed
        );
        md += &format!(
            "\n## Verified sampling (sigma {}, correlation {}, via-point share {}, seed {})\n\n{sampled}",
            args.sample_sigma, args.sample_correlation, args.sample_via_share, args.sample_seed
        );
    }
    write_atomic(
        &out.join("worlds.json"),
        &serde_json::to_vec_pretty(&serde_json::json!({
            "seed": args.seed,
            "action_space": space.name(),
            "base_kept": base_kept,
            "generators": tables,
        }))?,
    )?;
    write_atomic(&out.join("worlds.md"), md.as_bytes())?;
    png_atomic(&out.join("worlds.png"), |p| {
        plot_rates(p, &tables, args.seed)
    })?;
    if tables.iter().any(|t| t.aggregate.retrained > 0) {
        png_atomic(&out.join("adaptation.png"), |p| plot_adaptation(p, &tables))?;
    }
    println!("wrote {}", out.join("worlds.md").display());
    Ok(())
}

/// The checkpoint of `serve`, refused when it was trained on another task than `env`.
fn load_checkpoint(serve: &RetrainFlags, env: &TwinTask) -> Result<Checkpoint> {
    let base = Checkpoint::load(&serve.checkpoint)
        .with_context(|| format!("loading {}", serve.checkpoint.display()))?;
    if base.meta.task_hash != env.task_hash() {
        anyhow::bail!(
            "{} was trained on task hash {:#x}, {} has {:#x}",
            serve.checkpoint.display(),
            base.meta.task_hash,
            serve.task.display(),
            env.task_hash()
        );
    }
    Ok(base)
}

/// The action space of `base`, which `env` is switched to; refused with `--samples` or
/// `--retrain` (Cartesian-step policies only) for a joint-step checkpoint.
fn policy_space(args: &WorldsArgs, base: &Checkpoint, env: &mut TwinTask) -> Result<ActionSpace> {
    let space = base.meta.action_space();
    anyhow::ensure!(
        space == ActionSpace::CartesianStep || (args.samples.is_empty() && !args.retrain),
        "--samples and --retrain run Cartesian-step policies only; {} acts in {}",
        args.args.checkpoint.display(),
        space.name()
    );
    env.set_action_space(space);
    println!("policy action space: {}", space.name());
    Ok(space)
}

/// With `--samples`: `base` exported and loaded as rt-core runs it (the sampling settings
/// checked first); without: `None`.
fn exported_policy(
    args: &WorldsArgs,
    base: &Checkpoint,
    env: &TwinTask,
) -> Result<Option<MlpPolicy>> {
    if args.samples.is_empty() {
        return Ok(None);
    }
    sampling_settings(args, 1)
        .validate()
        .map_err(|(field, why)| anyhow::anyhow!("--sample {field}: {why}"))?;
    let blob = learner::export::export_blob(base, 1)?;
    let loader = PolicyLoader::new(PolicyExpectation::for_task_obs(
        env.task_hash(),
        env.env.obs_dim(),
    ));
    Ok(Some(loader.prepare(&blob).map_err(|e| {
        anyhow::anyhow!("the exported blob is refused: {e:?}")
    })?))
}

/// The sampling settings of `args` with `k` candidates.
fn sampling_settings(args: &WorldsArgs, k: usize) -> SamplingSettings {
    SamplingSettings {
        candidates: k,
        noise_sigma: args.sample_sigma,
        noise_correlation: args.sample_correlation,
        seed: args.sample_seed,
        via_point_share: args.sample_via_share,
        threads: args.sample_threads,
    }
}

impl Bench<'_> {
    /// Verified sampling on `scene` for each `--samples` K (none without a blob).
    fn samples(&self, scene: &Scene) -> Vec<SampleRow> {
        let Some(mlp) = &self.mlp else {
            return Vec::new();
        };
        let policy = |o: &[f32; twin::OBS_DIM]| mlp.act(o);
        self.args
            .samples
            .iter()
            .map(|&k| {
                let mut sampler = Sampler::new(&self.env.env, sampling_settings(self.args, k));
                let r = sampler.run(scene, &policy, 0, None);
                SampleRow {
                    k,
                    passed: r.best.is_some(),
                    passing: r.passed,
                    best_index: r.best.map(|b| b.index),
                    best_steps: r.best.map(|b| b.summary.steps),
                    elapsed_s: r.elapsed_s,
                }
            })
            .collect()
    }

    /// The worlds of `source`, with their verdicts; the infeasible draws skipped and why.
    fn candidates(&self, source: Source) -> Result<(Vec<Candidate>, Vec<String>)> {
        let env = &self.env.env;
        let fcfg = self.args.args.feasibility();
        match source {
            Source::Task => {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.args.seed);
                let scenes: Vec<Scene> = (0..self.args.worlds)
                    .map(|_| env.sample_world(&mut rng))
                    .collect();
                let start = env.config().start.joints_rad;
                let c = scenes
                    .into_iter()
                    .map(|scene| {
                        let t0 = Instant::now();
                        let verdict = match check_feasibility(env, &scene, &start, fcfg) {
                            Feasibility::Feasible { path, .. } => Ok(path),
                            Feasibility::Infeasible(r) => Err(r),
                        };
                        Candidate {
                            kind: "task",
                            scene,
                            verdict,
                            feasibility_s: t0.elapsed().as_secs_f64(),
                        }
                    })
                    .collect();
                Ok((c, Vec::new()))
            }
            Source::Independent(g) => {
                let set = worldgen::generate(env, g, self.args.seed, self.args.worlds, fcfg)?;
                let skipped = set
                    .skipped
                    .iter()
                    .map(|s| {
                        format!(
                            "draw {} ({}): {}",
                            s.draw,
                            s.kind.name(),
                            s.reason.display_with(&s.scene.obstacles)
                        )
                    })
                    .collect();
                let c = set
                    .worlds
                    .into_iter()
                    .map(|w| Candidate {
                        kind: w.kind.name(),
                        scene: w.scene,
                        verdict: Ok(w.path),
                        feasibility_s: w.feasibility_s,
                    })
                    .collect();
                Ok((c, skipped))
            }
        }
    }

    fn table(&self, source: Source) -> Result<GeneratorTable> {
        let t0 = Instant::now();
        let (candidates, skipped) = self.candidates(source)?;
        let generation_s = t0.elapsed().as_secs_f64();
        println!(
            "\n== generator {} (seed {}): {} worlds, {} infeasible draws skipped ({generation_s:.1} s) ==",
            source.name(),
            self.args.seed,
            candidates.len(),
            skipped.len()
        );
        println!(
            "{:>3} {:<20} {:>5} {:>7} {:>9} {:>8} {:>10} {:>9} {:>7} {:>10}  note",
            "#",
            "kind",
            "boxes",
            "tallest",
            "feasible",
            "straight",
            "joint line",
            "zero-shot",
            "planner",
            "retrained"
        );
        let mut rows = Vec::with_capacity(candidates.len());
        for (index, c) in candidates.into_iter().enumerate() {
            let row = self.row(source, index, c)?;
            print_row(&row);
            rows.push(row);
        }
        Ok(GeneratorTable {
            generator: source.name(),
            skipped_infeasible: skipped.len(),
            skipped_reasons: skipped,
            generation_s,
            aggregate: aggregate(&rows),
            worlds: rows,
        })
    }

    fn row(&self, source: Source, index: usize, c: Candidate) -> Result<WorldRow> {
        let env = self.env;
        let scene = &c.scene;
        let mut tw = env
            .env
            .clone()
            .with_action_space(ActionSpace::CartesianStep);
        let line = tw.straight_line_policy();
        let straight = twin::rollout(&mut tw, scene, |o| line.act(o), None);
        let joint_line = tw.joint_line_policy();
        let joint = twin::rollout_joint(&mut tw, scene, |o| joint_line.act(o), None, true);
        let zs = evaluate(self.net, self.norm, env, std::slice::from_ref(scene), 1);
        let zero_shot = zs.success_rate > 0.5;
        let zero_shot_contact = zs.collision_rate > 0.0;
        let start = env.env.config().start.joints_rad;
        let planner = c
            .verdict
            .as_ref()
            .ok()
            .map(|path| worldgen::track_path(&env.env, scene, &start, path).ok());
        let feasible = c.verdict.is_ok();
        let samples = if feasible {
            self.samples(scene)
        } else {
            Vec::new()
        };
        let retrained = if self.args.retrain && feasible && !zero_shot {
            Some(self.retrain(source, index, *scene)?)
        } else {
            None
        };
        Ok(WorldRow {
            generator: source.name(),
            index,
            kind: c.kind,
            boxes: scene.obstacles.len(),
            tallest_box_m: scene
                .obstacles
                .iter()
                .map(|b| b.size_m[2])
                .fold(0.0, f64::max),
            feasible,
            infeasible_reason: c
                .verdict
                .err()
                .map(|r| r.display_with(&scene.obstacles).to_string()),
            feasibility_s: c.feasibility_s,
            straight_line: straight.success && straight.safe,
            joint_line: joint.success && joint.safe,
            zero_shot,
            zero_shot_contact,
            zero_shot_timeout: !zero_shot && !zero_shot_contact,
            planner,
            samples,
            retrained,
            scene: scene.to_file(),
        })
    }

    /// One retraining on `scene`, as `learner serve` runs it, and what it kept.
    fn retrain(&self, source: Source, index: usize, scene: Scene) -> Result<RetrainRow> {
        let serve = &self.args.args;
        let dir = self.out.join(format!("retrain-{}-{index}", source.name()));
        // No path handed over: the feasibility check runs again inside, as the service's would.
        let outcome = RetrainJob {
            base: self.base,
            env: self.env,
            scene,
            planner_path: None,
            settings: &serve.settings(),
            out_dir: &dir,
            eval_seed: 1,
            device: self.device,
        }
        .run(|_, _| true)?;
        let sum = outcome.summary;
        let demonstrated = outcome.warm_start.is_some_and(|w| w.reported_scene);
        let best = Checkpoint::load(&dir.join(checkpoint::BEST))?;
        let bnet = best.network(self.device)?;
        let bnorm = ObsNormalizer::from_stats(&best.meta.obs_rms.to_rms(), best.meta.ppo.clip_obs);
        let exact = evaluate(&bnet, &bnorm, self.env, std::slice::from_ref(&scene), 1);
        let kept = evaluate(&bnet, &bnorm, self.env, self.kept_scenes, self.workers);
        let re_ok = successes(&bnet, &bnorm, self.env, self.kept_scenes, self.workers);
        anyhow::ensure!(
            re_ok.len() == self.base_ok.len(),
            "an evaluation worker failed ({} of {} pre-training scenes evaluated)",
            re_ok.len(),
            self.base_ok.len()
        );
        let either = self
            .base_ok
            .iter()
            .zip(&re_ok)
            .filter(|(b, r)| **b || **r)
            .count();
        Ok(RetrainRow {
            success: exact.success_rate > 0.5,
            demonstrated,
            wall_s: sum.wall_s,
            steps: best.meta.steps.saturating_sub(self.base.meta.steps),
            stop: sum.stop,
            kept,
            library_kept: either as f64 / self.base_ok.len().max(1) as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// clap's own consistency checks (a flag defined twice, e.g. by the flattened retraining
    /// flags and the benchmark's own, fails here instead of at a user's call).
    #[test]
    fn the_command_line_is_consistent() {
        super::WorldsArgs::command().debug_assert();
    }
}
