//! `learner worlds`: the offline unseen-worlds benchmark. Draws `--worlds` worlds of the
//! task's broad `[world]` distribution from `--seed` (the generator `foresight --runs N
//! --seed S --worlds random` uses, so both see the same worlds), and for each one reports:
//! the feasibility verdict (goal postures from many IK seeds and a joint-space planner,
//! `twin::feasibility`), the scripted straight line, the policy zero-shot, and — with
//! `--retrain` for the feasible worlds the policy fails — one retraining as `learner serve`
//! runs it (time, steps, success on the world) and the retrained policy's success on the
//! pre-training evaluation scenes (what it kept), alone and as rt-core runs it — in a policy
//! library with the base policy, the lookahead taking whichever of the two passes (a scene
//! counts when either policy solves it). Prints a table and writes `worlds.json`
//! and `worlds.md` (atomically) to `--out`.

use std::time::Instant;

use anyhow::{Context, Result};
use learner::checkpoint::{self, Checkpoint, write_atomic};
use learner::normalize::ObsNormalizer;
use learner::ppo::{EvalResult, evaluate, successes};
use learner::service;
use learner::twin_env::{CurriculumSampler, TwinTask, fixed_scenes};
use rand::SeedableRng;
use serde::Serialize;
use twin::Scene;
use twin::{Feasibility, check_feasibility};

use super::EVAL_SEED;
use super::serve::ServeArgs;

/// Arguments of `learner worlds`.
#[derive(clap::Args)]
pub struct WorldsArgs {
    /// Worlds to draw.
    #[arg(long, default_value_t = 40, value_parser = shm_schemas::cli_bounds::int_within(1usize, 100_000), allow_negative_numbers = true)]
    worlds: usize,
    /// Seed of the world generator (the seed of `foresight --runs N --seed S --worlds random`).
    #[arg(long, default_value_t = 7, allow_negative_numbers = true)]
    seed: u64,
    /// Retrain on every feasible world the policy fails (as `learner serve` would).
    #[arg(long)]
    retrain: bool,
    /// Pre-training evaluation scenes (the fixed set `learner eval` uses) on which each
    /// retrained policy's success is measured afterwards ("kept").
    #[arg(long, default_value_t = 200, value_parser = shm_schemas::cli_bounds::int_within(0usize, 1_000_000), allow_negative_numbers = true)]
    kept_eval_episodes: usize,
    /// The checkpoint, task, output folder (`--out`, required here) and the retraining
    /// settings, as `learner serve` takes them.
    #[command(flatten)]
    args: ServeArgs,
}

/// One world's row.
#[derive(Debug, Clone, Serialize)]
struct WorldRow {
    index: usize,
    boxes: usize,
    tallest_box_m: f64,
    feasible: bool,
    infeasible_reason: Option<String>,
    feasibility_s: f64,
    straight_line: bool,
    zero_shot: bool,
    zero_shot_contact: bool,
    retrained: Option<RetrainRow>,
    scene: shm_schemas::scene_file::SceneFile,
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

/// The aggregate figures.
#[derive(Debug, Clone, Serialize)]
struct Aggregate {
    worlds: usize,
    feasible: usize,
    infeasible: usize,
    straight_line_rate: f64,
    zero_shot_rate: f64,
    zero_shot_contact_rate: f64,
    retrained: usize,
    retrain_success: usize,
    retrain_median_s: Option<f64>,
    kept_min: Option<f64>,
    kept_median: Option<f64>,
    library_kept_min: Option<f64>,
    library_kept_median: Option<f64>,
    base_kept: EvalResult,
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Runs `learner worlds`.
///
/// # Errors
/// Task, checkpoint, training or output failures.
pub fn run(args: WorldsArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(1);
    let serve = &args.args;
    serve.check()?;
    let out = serve
        .out
        .clone()
        .context("learner worlds needs --out DIR")?;
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let env = TwinTask::load(&serve.task, None)?;
    if env.env.config().world.is_none() {
        anyhow::bail!(
            "{} has no [world] section: the benchmark draws its worlds from it",
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
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let scenes: Vec<Scene> = (0..args.worlds)
        .map(|_| env.env.sample_world(&mut rng))
        .collect();
    let mut rows = Vec::with_capacity(scenes.len());
    println!(
        "{:>3} {:>5} {:>7} {:>9} {:>8} {:>9} {:>10}  note",
        "#", "boxes", "tallest", "feasible", "straight", "zero-shot", "retrained"
    );
    for (index, scene) in scenes.iter().enumerate() {
        let t0 = Instant::now();
        let verdict = check_feasibility(
            &env.env,
            scene,
            &env.env.config().start.joints_rad,
            serve.feasibility(),
        );
        let feasibility_s = t0.elapsed().as_secs_f64();
        let (feasible, infeasible_reason) = match &verdict {
            Feasibility::Feasible { .. } => (true, None),
            Feasibility::Infeasible(r) => (false, Some(r.to_string())),
        };
        let mut tw = env.env.clone();
        let line = tw.straight_line_policy();
        let straight = twin::rollout(&mut tw, scene, |o| line.act(o), None);
        let zs = evaluate(&net, &norm, &env, std::slice::from_ref(scene), 1);
        let zero_shot = zs.success_rate > 0.5;
        let retrained = if args.retrain && feasible && !zero_shot {
            let dir = out.join(format!("retrain-{index}"));
            let (sum, _) = service::retrain(
                &base,
                &env,
                *scene,
                &serve.settings(),
                &dir,
                1,
                device,
                |_, _| true,
            )?;
            let best = Checkpoint::load(&dir.join(checkpoint::BEST))?;
            let bnet = best.network(device)?;
            let bnorm =
                ObsNormalizer::from_stats(&best.meta.obs_rms.to_rms(), best.meta.ppo.clip_obs);
            let exact = evaluate(&bnet, &bnorm, &env, std::slice::from_ref(scene), 1);
            let kept = evaluate(&bnet, &bnorm, &env, &kept_scenes, workers);
            let re_ok = successes(&bnet, &bnorm, &env, &kept_scenes, workers);
            anyhow::ensure!(
                re_ok.len() == base_ok.len(),
                "an evaluation worker failed ({} of {} pre-training scenes evaluated)",
                re_ok.len(),
                base_ok.len()
            );
            let either = base_ok
                .iter()
                .zip(&re_ok)
                .filter(|(b, r)| **b || **r)
                .count();
            let library_kept = either as f64 / base_ok.len().max(1) as f64;
            Some(RetrainRow {
                success: exact.success_rate > 0.5,
                wall_s: sum.wall_s,
                steps: best.meta.steps.saturating_sub(base.meta.steps),
                stop: format!("{:?}", sum.stop),
                kept,
                library_kept,
            })
        } else {
            None
        };
        let row = WorldRow {
            index,
            boxes: scene.obstacles.len(),
            tallest_box_m: scene
                .obstacles
                .iter()
                .map(|b| b.size_m[2])
                .fold(0.0, f64::max),
            feasible,
            infeasible_reason,
            feasibility_s,
            straight_line: straight.success && straight.safe,
            zero_shot,
            zero_shot_contact: zs.collision_rate > 0.0,
            retrained,
            scene: scene.to_file(),
        };
        println!(
            "{:>3} {:>5} {:>6.2}m {:>9} {:>8} {:>9} {:>10}  {}",
            row.index,
            row.boxes,
            row.tallest_box_m,
            yes(row.feasible),
            yes(row.straight_line),
            if row.zero_shot {
                "yes"
            } else if row.zero_shot_contact {
                "contact"
            } else {
                "no"
            },
            row.retrained.as_ref().map_or("-".to_string(), |r| format!(
                "{} {:.1}s",
                yes(r.success),
                r.wall_s
            )),
            row.infeasible_reason.as_deref().unwrap_or("")
        );
        rows.push(row);
    }
    let agg = aggregate(&rows, base_kept);
    let md = markdown(&rows, &agg, args.seed);
    println!("\n{}", summary_lines(&agg));
    write_atomic(
        &out.join("worlds.json"),
        &serde_json::to_vec_pretty(&serde_json::json!({
            "seed": args.seed, "aggregate": agg, "worlds": rows,
        }))?,
    )?;
    write_atomic(&out.join("worlds.md"), md.as_bytes())?;
    println!("wrote {}", out.join("worlds.md").display());
    Ok(())
}

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn aggregate(rows: &[WorldRow], base_kept: EvalResult) -> Aggregate {
    let feasible: Vec<&WorldRow> = rows.iter().filter(|r| r.feasible).collect();
    let nf = feasible.len().max(1) as f64;
    let rate = |f: &dyn Fn(&WorldRow) -> bool| feasible.iter().filter(|r| f(r)).count() as f64 / nf;
    let re: Vec<&RetrainRow> = rows.iter().filter_map(|r| r.retrained.as_ref()).collect();
    let mut times: Vec<f64> = re.iter().map(|r| r.wall_s).collect();
    let mut kept: Vec<f64> = re.iter().map(|r| r.kept.success_rate).collect();
    let mut library: Vec<f64> = re.iter().map(|r| r.library_kept).collect();
    Aggregate {
        worlds: rows.len(),
        feasible: feasible.len(),
        infeasible: rows.len() - feasible.len(),
        straight_line_rate: rate(&|r| r.straight_line),
        zero_shot_rate: rate(&|r| r.zero_shot),
        zero_shot_contact_rate: rate(&|r| r.zero_shot_contact),
        retrained: re.len(),
        retrain_success: re.iter().filter(|r| r.success).count(),
        retrain_median_s: median(&mut times),
        kept_min: kept.iter().copied().reduce(f64::min),
        kept_median: median(&mut kept),
        library_kept_min: library.iter().copied().reduce(f64::min),
        library_kept_median: median(&mut library),
        base_kept,
    }
}

fn pct(v: f64) -> String {
    format!("{:.0} %", 100.0 * v)
}

fn summary_lines(a: &Aggregate) -> String {
    let mut s = format!(
        "{} worlds: {} feasible, {} infeasible. On the feasible ones: zero-shot {} ({} end in \
         contact), straight line {}.",
        a.worlds,
        a.feasible,
        a.infeasible,
        pct(a.zero_shot_rate),
        pct(a.zero_shot_contact_rate),
        pct(a.straight_line_rate)
    );
    s += &format!(
        " Pre-training scenes: {} before retraining.",
        pct(a.base_kept.success_rate)
    );
    if a.retrained > 0 {
        s += &format!(
            " Retrained {}: {} reached (median {:.1} s); pre-training scenes kept after \
             retraining: retrained policy alone min {}, median {}; with the base in the \
             policy library (what rt-core runs) min {}, median {}.",
            a.retrained,
            a.retrain_success,
            a.retrain_median_s.unwrap_or(0.0),
            pct(a.kept_min.unwrap_or(0.0)),
            pct(a.kept_median.unwrap_or(0.0)),
            pct(a.library_kept_min.unwrap_or(0.0)),
            pct(a.library_kept_median.unwrap_or(0.0))
        );
    }
    s
}

fn markdown(rows: &[WorldRow], a: &Aggregate, seed: u64) -> String {
    let mut s = format!("# Unseen worlds (seed {seed})\n\n{}\n\n", summary_lines(a));
    s += "| # | boxes | tallest (m) | feasible | straight line | zero-shot | retrained (s) | kept alone | kept in library | note |\n";
    s += "|---|---|---|---|---|---|---|---|---|---|\n";
    for r in rows {
        let (re, kept, library) = match &r.retrained {
            Some(t) => (
                format!("{} ({:.1})", yes(t.success), t.wall_s),
                pct(t.kept.success_rate),
                pct(t.library_kept),
            ),
            None => ("–".into(), "–".into(), "–".into()),
        };
        s += &format!(
            "| {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.index,
            r.boxes,
            r.tallest_box_m,
            yes(r.feasible),
            yes(r.straight_line),
            if r.zero_shot {
                "yes"
            } else if r.zero_shot_contact {
                "contact"
            } else {
                "no"
            },
            re,
            kept,
            library,
            r.infeasible_reason.as_deref().unwrap_or("")
        );
    }
    s
}
