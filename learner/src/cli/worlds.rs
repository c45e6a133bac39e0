//! `learner worlds`: the offline unseen-worlds benchmark, per world generator.
//!
//! `--generator task` (the default) draws `--worlds` worlds of the task's own `[world]`
//! sampler from `--seed` (the stream `foresight --runs N --seed S --worlds random` uses, so
//! both see the same worlds; infeasible draws stay in the table as refused). `uniform`,
//! `cluttered` and `adversarial` take the worlds of the independent generators of the
//! `worldgen` crate (no code shared with training): each draws until `--worlds` worlds are
//! proven feasible by the twin's planner and reports the infeasible draws it skipped.
//! `all` runs the four.
//!
//! For each world: the scripted straight line, the policy zero-shot (success, contact or
//! timeout), the planner — the feasibility proof's joint path re-tracked in the twin
//! (`worldgen::track_path`): 100 % of feasible worlds by construction, the ceiling of the
//! planner fallback, not a learned skill — and, with `--retrain`, for each feasible world
//! the policy fails, one retraining as `learner serve` runs it (the adaptation benchmark:
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

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use learner::checkpoint::{self, Checkpoint, write_atomic};
use learner::net::ActorCritic;
use learner::normalize::ObsNormalizer;
use learner::ppo::{EvalResult, evaluate, successes};
use learner::service;
use learner::twin_env::{CurriculumSampler, TwinTask, fixed_scenes};
use plotters::prelude::*;
use policy::{MlpPolicy, PolicyExpectation, PolicyLoader};
use rand::SeedableRng;
use serde::Serialize;
use twin::{Feasibility, Joints, Sampler, SamplingSettings, Scene, check_feasibility};
use worldgen::Generator;

use super::EVAL_SEED;
use super::serve::ServeArgs;

/// Which worlds `learner worlds` runs on (`--generator`).
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

/// Arguments of `learner worlds`.
#[derive(clap::Args)]
pub struct WorldsArgs {
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
    args: ServeArgs,
}

/// One world's row.
#[derive(Debug, Clone, Serialize)]
struct WorldRow {
    generator: &'static str,
    index: usize,
    /// The generator's case (`near_path`, …; the generator's name otherwise).
    kind: String,
    boxes: usize,
    tallest_box_m: f64,
    feasible: bool,
    infeasible_reason: Option<String>,
    feasibility_s: f64,
    straight_line: bool,
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
    wall_s: f64,
    steps: u64,
    stop: String,
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
    zero_shot: usize,
    zero_shot_contact: usize,
    zero_shot_timeout: usize,
    planner: usize,
    straight_line_rate: f64,
    zero_shot_rate: f64,
    zero_shot_contact_rate: f64,
    planner_rate: f64,
    /// Solved by the straight line and not by the policy.
    line_not_policy: usize,
    retrained: usize,
    retrain_success: usize,
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
    kind: String,
    scene: Scene,
    /// The planner's path, or why the world is infeasible.
    verdict: Result<Vec<Joints>, String>,
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

/// Runs `learner worlds`.
///
/// # Errors
/// Task, checkpoint, generation, training or output failures.
pub fn run(args: WorldsArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(1);
    let serve = &args.args;
    serve.check()?;
    anyhow::ensure!(
        (1..=10_000).contains(&args.worlds),
        "--worlds must be in 1..=10000 (got {})",
        args.worlds
    );
    let out = serve
        .out
        .clone()
        .context("learner worlds needs --out DIR")?;
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let env = TwinTask::load(&serve.task, None)?;
    let sources = args.generator.sources();
    if sources.contains(&Source::Task) && env.env.config().world.is_none() {
        anyhow::bail!(
            "{} has no [world] section: --generator task draws its worlds from it",
            serve.task.display()
        );
    }
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
    let mlp = if args.samples.is_empty() {
        None
    } else {
        sampling_settings(&args, 1)
            .validate()
            .map_err(|(field, why)| anyhow::anyhow!("--sample {field}: {why}"))?;
        let blob = learner::export::export_blob(&base, 1)?;
        let loader = PolicyLoader::new(PolicyExpectation::for_task_obs(
            env.task_hash(),
            env.env.config().obs_dim(),
        ));
        Some(
            loader
                .prepare(&blob)
                .map_err(|e| anyhow::anyhow!("the exported blob is refused: {e:?}"))?,
        )
    };
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
                            Feasibility::Infeasible(r) => {
                                Err(r.display_with(&scene.obstacles).to_string())
                            }
                        };
                        Candidate {
                            kind: "task".into(),
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
                        kind: w.kind.name().into(),
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
            "{:>3} {:<20} {:>5} {:>7} {:>9} {:>8} {:>9} {:>7} {:>10}  note",
            "#",
            "kind",
            "boxes",
            "tallest",
            "feasible",
            "straight",
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
        let mut tw = env.env.clone();
        let line = tw.straight_line_policy();
        let straight = twin::rollout(&mut tw, scene, |o| line.act(o), None);
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
            infeasible_reason: c.verdict.err(),
            feasibility_s: c.feasibility_s,
            straight_line: straight.success && straight.safe,
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
        let (sum, _) = service::retrain(
            self.base,
            self.env,
            scene,
            &serve.settings(),
            &dir,
            1,
            self.device,
            |_, _| true,
        )?;
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
            wall_s: sum.wall_s,
            steps: best.meta.steps.saturating_sub(self.base.meta.steps),
            stop: format!("{:?}", sum.stop),
            kept,
            library_kept: either as f64 / self.base_ok.len().max(1) as f64,
        })
    }
}

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn zero_shot_word(r: &WorldRow) -> &'static str {
    if r.zero_shot {
        "yes"
    } else if r.zero_shot_contact {
        "contact"
    } else {
        "timeout"
    }
}

fn print_row(r: &WorldRow) {
    let sampled: String = r
        .samples
        .iter()
        .map(|s| {
            format!(
                " @{}:{}",
                s.k,
                s.best_index.map_or("-".to_owned(), |i| i.to_string())
            )
        })
        .collect();
    println!(
        "{:>3} {:<20} {:>5} {:>6.2}m {:>9} {:>8} {:>9} {:>7} {:>10}  {}{sampled}",
        r.index,
        r.kind,
        r.boxes,
        r.tallest_box_m,
        yes(r.feasible),
        yes(r.straight_line),
        zero_shot_word(r),
        r.planner.map_or("-", yes),
        r.retrained.as_ref().map_or("-".to_string(), |t| format!(
            "{} {:.1}s",
            yes(t.success),
            t.wall_s
        )),
        r.infeasible_reason.as_deref().unwrap_or("")
    );
}

fn aggregate(rows: &[WorldRow]) -> Aggregate {
    let feasible: Vec<&WorldRow> = rows.iter().filter(|r| r.feasible).collect();
    let nf = feasible.len().max(1) as f64;
    let count = |f: &dyn Fn(&WorldRow) -> bool| feasible.iter().filter(|r| f(r)).count();
    let re: Vec<&RetrainRow> = rows.iter().filter_map(|r| r.retrained.as_ref()).collect();
    let mut times: Vec<f64> = re.iter().map(|r| r.wall_s).collect();
    let mut steps: Vec<f64> = re.iter().map(|r| r.steps as f64).collect();
    let mut kept: Vec<f64> = re.iter().map(|r| r.kept.success_rate).collect();
    let mut library: Vec<f64> = re.iter().map(|r| r.library_kept).collect();
    let straight_line = count(&|r| r.straight_line);
    let zero_shot = count(&|r| r.zero_shot);
    let zero_shot_contact = count(&|r| r.zero_shot_contact);
    let planner = count(&|r| r.planner == Some(true));
    let ks: Vec<usize> = feasible
        .first()
        .map(|r| r.samples.iter().map(|s| s.k).collect())
        .unwrap_or_default();
    let pass_at = ks
        .iter()
        .enumerate()
        .map(|(j, &k)| {
            let rows: Vec<&SampleRow> = feasible.iter().filter_map(|r| r.samples.get(j)).collect();
            let mut times: Vec<f64> = rows.iter().map(|s| s.elapsed_s).collect();
            let passed = rows.iter().filter(|s| s.passed).count();
            PassAt {
                k,
                passed,
                rate: passed as f64 / nf,
                rescued: rows
                    .iter()
                    .filter(|s| s.best_index.is_some_and(|i| i > 0))
                    .count(),
                max_s: times.iter().copied().reduce(f64::max),
                median_s: median(&mut times),
            }
        })
        .collect();
    Aggregate {
        worlds: rows.len(),
        feasible: feasible.len(),
        infeasible: rows.len() - feasible.len(),
        straight_line,
        zero_shot,
        zero_shot_contact,
        zero_shot_timeout: count(&|r| r.zero_shot_timeout),
        planner,
        straight_line_rate: straight_line as f64 / nf,
        zero_shot_rate: zero_shot as f64 / nf,
        zero_shot_contact_rate: zero_shot_contact as f64 / nf,
        planner_rate: planner as f64 / nf,
        line_not_policy: count(&|r| r.straight_line && !r.zero_shot),
        retrained: re.len(),
        retrain_success: re.iter().filter(|r| r.success).count(),
        retrain_max_s: times.iter().copied().reduce(f64::max),
        retrain_median_s: median(&mut times),
        retrain_median_steps: median(&mut steps),
        kept_min: kept.iter().copied().reduce(f64::min),
        kept_median: median(&mut kept),
        library_kept_min: library.iter().copied().reduce(f64::min),
        library_kept_median: median(&mut library),
        pass_at,
    }
}

fn pct(v: f64) -> String {
    format!("{:.0} %", 100.0 * v)
}

fn of(n: usize, d: usize) -> String {
    format!("{n}/{d} ({})", pct(n as f64 / d.max(1) as f64))
}

fn opt_s(v: Option<f64>) -> String {
    v.map_or("–".to_owned(), |s| format!("{s:.1}"))
}

fn opt_pct(v: Option<f64>) -> String {
    v.map_or("–".to_owned(), pct)
}

/// The per-generator table (Markdown).
fn summary_table(tables: &[GeneratorTable]) -> String {
    let mut s = String::from(
        "| generator | feasible worlds | infeasible skipped | policy zero-shot | contact | timeout | straight line | line, not policy | planner (path re-tracked) | retrained: learned | retraining median / max (s) | kept in library (min) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for t in tables {
        let a = &t.aggregate;
        let skipped = if t.generator == "task" {
            format!("{} (kept as rows)", a.infeasible)
        } else {
            t.skipped_infeasible.to_string()
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} |",
            t.generator,
            a.feasible,
            skipped,
            of(a.zero_shot, a.feasible),
            a.zero_shot_contact,
            a.zero_shot_timeout,
            of(a.straight_line, a.feasible),
            a.line_not_policy,
            of(a.planner, a.feasible),
            if a.retrained > 0 {
                format!("{}/{}", a.retrain_success, a.retrained)
            } else {
                "–".into()
            },
            opt_s(a.retrain_median_s),
            opt_s(a.retrain_max_s),
            opt_pct(a.library_kept_min),
        );
    }
    s
}

/// Verified sampling per generator: pass@K and the wall time of the K rollouts.
fn sampling_table(tables: &[GeneratorTable], threads: usize) -> String {
    let Some(ks) = tables
        .first()
        .map(|t| t.aggregate.pass_at.iter().map(|p| p.k).collect::<Vec<_>>())
        .filter(|k| !k.is_empty())
    else {
        return String::new();
    };
    let mut s = String::from("| generator | feasible |");
    for k in &ks {
        let _ = write!(s, " pass@{k} | K = {k}: median / max (ms) |");
    }
    s += " planner path |\n|---|---|";
    for _ in &ks {
        s += "---|---|";
    }
    s += "---|\n";
    for t in tables {
        let a = &t.aggregate;
        let _ = write!(s, "| {} | {} |", t.generator, a.feasible);
        for p in &a.pass_at {
            let _ = write!(
                s,
                " {} | {} / {} |",
                of(p.passed, a.feasible),
                p.median_s.map_or("–".into(), |v| format!("{:.1}", 1e3 * v)),
                p.max_s.map_or("–".into(), |v| format!("{:.1}", 1e3 * v)),
            );
        }
        let _ = writeln!(s, " {} |", of(a.planner, a.feasible));
    }
    let _ = writeln!(
        s,
        "\nCandidate 0 is the deterministic rollout of the exported blob; the others add AR(1) action noise; {threads} threads."
    );
    s
}

/// The adaptation table: every retrained world.
fn adaptation_table(tables: &[GeneratorTable]) -> String {
    let mut s = String::from(
        "| generator | world | kind | boxes | tallest (m) | zero-shot | world change → learned policy (s) | steps | learned | stop | kept alone | kept in library |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for t in tables {
        for r in &t.worlds {
            if let Some(re) = &r.retrained {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {:.2} | {} | {:.1} | {} | {} | {} | {} | {} |",
                    t.generator,
                    r.index,
                    r.kind,
                    r.boxes,
                    r.tallest_box_m,
                    zero_shot_word(r),
                    re.wall_s,
                    re.steps,
                    yes(re.success),
                    re.stop,
                    pct(re.kept.success_rate),
                    pct(re.library_kept),
                );
            }
        }
    }
    s
}

fn markdown(tables: &[GeneratorTable], base_kept: &EvalResult, seed: u64) -> String {
    let mut s = format!(
        "# Unseen worlds per generator (seed {seed})\n\n\
         `task` is the task's own `[world]` sampler (the generalist's training distribution); \
         `uniform`, `cluttered` and `adversarial` are the independent generators of the \
         `worldgen` crate, each world proven feasible by the twin's planner. Rates are over \
         the feasible worlds. The planner column re-tracks the feasibility proof's path in \
         the twin: 100 % by construction, the ceiling of the planner fallback. The base \
         policy solves {} of the pre-training scenes.\n\n",
        pct(base_kept.success_rate)
    );
    s += &summary_table(tables);
    s += "\n![policy vs straight line vs planner per generator](worlds.png)\n";
    if tables.iter().any(|t| t.aggregate.retrained > 0) {
        s += "\n## Adaptation: the worlds the policy does not solve zero-shot\n\n";
        s += &adaptation_table(tables);
        s += "\n![retraining time per world](adaptation.png)\n";
    }
    for t in tables {
        let _ = write!(
            s,
            "\n## {} ({} worlds, {} infeasible draws skipped, generated and proven in {:.1} s)\n\n",
            t.generator,
            t.worlds.len(),
            t.skipped_infeasible,
            t.generation_s
        );
        s += "| # | kind | boxes | tallest (m) | feasible | straight line | zero-shot | planner | retrained (s) | kept in library | note |\n";
        s += "|---|---|---|---|---|---|---|---|---|---|---|\n";
        for r in &t.worlds {
            let (re, library) = match &r.retrained {
                Some(x) => (
                    format!("{} ({:.1})", yes(x.success), x.wall_s),
                    pct(x.library_kept),
                ),
                None => ("–".into(), "–".into()),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} |",
                r.index,
                r.kind,
                r.boxes,
                r.tallest_box_m,
                yes(r.feasible),
                yes(r.straight_line),
                zero_shot_word(r),
                r.planner.map_or("–", yes),
                re,
                library,
                r.infeasible_reason
                    .as_deref()
                    .unwrap_or("")
                    .replace('|', "/")
            );
        }
        if !t.skipped_reasons.is_empty() {
            s += "\nSkipped as infeasible:\n\n";
            for why in &t.skipped_reasons {
                let _ = writeln!(s, "- {why}");
            }
        }
    }
    s
}

fn plot_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("plotting {}: {e}", path.display())
}

/// Draws a PNG with `draw` into a scratch file beside `path`, then writes it to `path`
/// atomically ([`write_atomic`]): a reader never sees half a picture.
fn png_atomic(path: &Path, draw: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("plot.png");
    let scratch = path.with_file_name(format!(".{name}.{}.tmp.png", std::process::id()));
    let drawn = draw(&scratch).and_then(|()| {
        let bytes =
            std::fs::read(&scratch).with_context(|| format!("reading {}", scratch.display()))?;
        write_atomic(path, &bytes)?;
        Ok(())
    });
    let _ = std::fs::remove_file(&scratch);
    drawn
}

/// One series of bars: legend, colour and the rate it shows.
type Bars = (&'static str, RGBColor, fn(&Aggregate) -> f64);

/// Grouped bars: per generator, the policy zero-shot, the straight line and the planner
/// (success rate over the feasible worlds), each labelled with its value.
fn plot_rates(path: &Path, tables: &[GeneratorTable], seed: u64) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| plot_err(path, e);
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let n = tables.len().max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("Zero-shot success on feasible unseen worlds per generator (seed {seed})"),
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0f64..n as f64, 0.0f64..130.0)
        .map_err(|e| err(&e))?;
    let names: Vec<String> = tables
        .iter()
        .map(|t| format!("{} ({} worlds)", t.generator, t.aggregate.feasible))
        .collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - i as f64 - 0.5).abs() < 1e-6 {
                names.get(i).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc("success (% of feasible worlds)")
        .y_labels(14)
        .y_label_formatter(&|y| {
            if *y <= 100.0 {
                format!("{y:.0}")
            } else {
                String::new()
            }
        })
        .label_style(("sans-serif", 15))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(&e))?;
    let series: [Bars; 3] = [
        ("policy zero-shot", RGBColor(31, 119, 180), |a| {
            a.zero_shot_rate
        }),
        ("scripted straight line", RGBColor(255, 127, 14), |a| {
            a.straight_line_rate
        }),
        ("planner path (ceiling)", RGBColor(150, 150, 150), |a| {
            a.planner_rate
        }),
    ];
    for (k, (label, colour, value)) in series.into_iter().enumerate() {
        let bars: Vec<(f64, f64)> = tables
            .iter()
            .enumerate()
            .map(|(i, t)| {
                (
                    i as f64 + 0.15 + 0.24 * k as f64,
                    100.0 * value(&t.aggregate),
                )
            })
            .collect();
        chart
            .draw_series(
                bars.iter()
                    .map(|&(x, v)| Rectangle::new([(x, 0.0), (x + 0.22, v)], colour.filled())),
            )
            .map_err(|e| err(&e))?
            .label(label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], colour.filled()));
        chart
            .draw_series(bars.iter().map(|&(x, v)| {
                Text::new(
                    format!("{v:.0}"),
                    (x + 0.04, v + 5.0),
                    ("sans-serif", 14).into_font(),
                )
            }))
            .map_err(|e| err(&e))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// One bar per retrained world: world change → learned policy (s), green learned, red not.
fn plot_adaptation(path: &Path, tables: &[GeneratorTable]) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| plot_err(path, e);
    let rows: Vec<(String, &RetrainRow)> = tables
        .iter()
        .flat_map(|t| {
            t.worlds.iter().filter_map(move |r| {
                r.retrained
                    .as_ref()
                    .map(|re| (format!("{}{}", &t.generator[..1], r.index), re))
            })
        })
        .collect();
    let top = rows.iter().map(|(_, r)| r.wall_s).fold(1.0f64, f64::max) * 1.15;
    let n = rows.len().max(1);
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Retraining per failed world (t task, u uniform, c cluttered, a adversarial; green learned, red not)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(70)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0f64..n as f64, 0.0f64..top)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - i as f64 - 0.5).abs() < 1e-6 {
                rows.get(i).map(|r| r.0.clone()).unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc("retraining wall time (s)")
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| err(&e))?;
    chart
        .draw_series(rows.iter().enumerate().map(|(i, (_, r))| {
            let colour = if r.success {
                RGBColor(46, 160, 67)
            } else {
                RGBColor(214, 39, 40)
            };
            Rectangle::new(
                [(i as f64 + 0.15, 0.0), (i as f64 + 0.85, r.wall_s)],
                colour.filled(),
            )
        }))
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
