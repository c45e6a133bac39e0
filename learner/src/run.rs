//! A training run: iterate PPO, evaluate periodically on fixed scenes, keep `best.ckpt` and
//! `last.ckpt`, write `metrics.csv` and the reward curve `reward.svg` next to them, show
//! progress, and stop on a step budget, a time budget or a success rule.

use shm_schemas::error_chain::error_chain;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::checkpoint::{BEST, Checkpoint, CheckpointError, LAST};
use crate::env::{Env, SceneSampler};
use crate::metrics::{MetricsLog, MetricsRow};
use crate::ppo::{EvalResult, IterStats, Trainer};

/// When a run may stop early because the policy is good enough.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SuccessRule {
    /// Evaluation success rate required.
    pub min_success: f64,
    /// Largest relative change of the evaluation mean return between the last two
    /// evaluations for the reward to count as converged.
    pub max_return_change: f64,
}

impl Default for SuccessRule {
    fn default() -> Self {
        Self {
            min_success: 0.95,
            max_return_change: 0.05,
        }
    }
}

impl SuccessRule {
    /// Whether `now` (after `prev`) satisfies the rule: success ≥ threshold, no contact at all,
    /// and the mean return changed by at most the allowed fraction.
    pub fn met(&self, prev: Option<&EvalResult>, now: &EvalResult) -> bool {
        let converged = prev.is_some_and(|p| {
            (now.mean_return - p.mean_return).abs()
                <= self.max_return_change * p.mean_return.abs().max(1e-3)
        });
        now.success_rate >= self.min_success && now.collision_rate == 0.0 && converged
    }
}

/// Options of a run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Directory for checkpoints, metrics and plots (created).
    pub out_dir: PathBuf,
    /// Stop once the trainer has taken this many environment steps in total.
    pub total_steps: u64,
    /// Evaluate (and checkpoint) every this many environment steps.
    pub eval_every_steps: u64,
    /// Seed (recorded in checkpoints).
    pub seed: u64,
    /// Task-configuration hash (recorded in checkpoints).
    pub task_hash: u64,
    /// Wall-time budget.
    pub time_budget: Option<Duration>,
    /// Early stop rule.
    pub success_rule: Option<SuccessRule>,
    /// Title of the reward plot.
    pub title: String,
    /// Show an indicatif progress bar (only drawn when stderr is a terminal).
    pub progress: bool,
    /// Linear learning-rate schedule over the run's steps: `(first, last)` (`None` keeps the
    /// trainer's rate).
    pub lr_schedule: Option<(f64, f64)>,
}

/// The learning rate `steps` into a run of `total` steps under the linear schedule
/// `(first, last)`.
pub fn scheduled_lr(schedule: (f64, f64), steps: u64, total: u64) -> f64 {
    let f = if total == 0 {
        1.0
    } else {
        (steps as f64 / total as f64).clamp(0.0, 1.0)
    };
    schedule.0 + (schedule.1 - schedule.0) * f
}

/// Why a run stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum StopReason {
    /// The step budget was used.
    Steps,
    /// The time budget ran out.
    TimeBudget,
    /// The success rule was met.
    Converged,
    /// The caller asked to stop.
    Cancelled,
}

/// What a run achieved.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    /// Why it stopped.
    pub stop: StopReason,
    /// Steps taken in this run.
    pub steps: u64,
    /// Total steps of the trainer.
    pub total_steps: u64,
    /// Wall time (s).
    pub wall_s: f64,
    /// Last evaluation.
    pub last_eval: Option<EvalResult>,
    /// Best evaluation.
    pub best_eval: Option<EvalResult>,
    /// Environment steps per second over the run, updates included.
    pub steps_per_s: f64,
}

/// Orders evaluations: success rate, then fewer collisions, then return.
pub fn better(a: &EvalResult, b: &EvalResult) -> bool {
    (a.success_rate, -a.collision_rate, a.mean_return)
        > (b.success_rate, -b.collision_rate, b.mean_return)
}

/// File name of the metrics CSV in a run directory.
pub const METRICS_CSV: &str = "metrics.csv";
/// File name of the reward curve in a run directory.
pub const REWARD_SVG: &str = "reward.svg";

/// Runs training until a stop condition; `on_iter` sees every iteration (and can cancel by
/// returning `false`).
///
/// # Errors
/// [`CheckpointError`] when a checkpoint or the metrics cannot be written.
pub fn train<E: Env + Clone, S: SceneSampler<E::Scene>>(
    trainer: &mut Trainer<E>,
    sampler: &S,
    eval_scenes: &[E::Scene],
    opts: &RunOptions,
    mut on_iter: impl FnMut(&IterStats, Option<&EvalResult>) -> bool,
) -> Result<RunSummary, CheckpointError> {
    std::fs::create_dir_all(&opts.out_dir).map_err(|source| CheckpointError::Io {
        path: opts.out_dir.clone(),
        source,
    })?;
    let mut run = Run::resume(trainer, opts);
    let bar = progress_bar(opts, trainer.steps);
    let mut stop = StopReason::Steps;
    while trainer.steps < opts.total_steps {
        if let Some(sched) = opts.lr_schedule {
            let lr = scheduled_lr(sched, trainer.steps, opts.total_steps);
            trainer.adam.lr = lr;
            trainer.cfg.learning_rate = lr;
        }
        let t0 = Instant::now();
        let st = trainer.iterate(sampler);
        let it_s = t0.elapsed().as_secs_f64();
        let batch = (trainer.cfg.n_envs * trainer.cfg.n_steps) as f64;
        let done = trainer.steps >= opts.total_steps;
        let out_of_time = opts.time_budget.is_some_and(|b| run.start.elapsed() >= b);
        let mut eval = None;
        if trainer.steps >= run.next_eval || done || out_of_time {
            eval = Some(run.evaluate(trainer, eval_scenes, opts)?);
        }
        run.log.rows.push(MetricsRow {
            iter: st.clone(),
            wall_s: run.start.elapsed().as_secs_f64(),
            steps_per_s: batch / it_s,
            eval,
        });
        if let Some(b) = &bar {
            b.set_position(trainer.steps.min(opts.total_steps));
            if let Some(e) = eval {
                b.set_message(format!("eval success {:.0}%", e.success_rate * 100.0));
            }
        }
        if let Some(e) = &eval
            && run.record_eval(e, &st, trainer.steps, opts)?
        {
            stop = StopReason::Converged;
            break;
        }
        if !on_iter(&st, eval.as_ref()) {
            stop = StopReason::Cancelled;
            break;
        }
        if out_of_time {
            stop = StopReason::TimeBudget;
            break;
        }
    }
    run.write_metrics(opts)?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    Ok(run.summary(stop, trainer.steps))
}

/// The bookkeeping of a run in progress.
struct Run {
    start: Instant,
    start_steps: u64,
    log: MetricsLog,
    best: Option<EvalResult>,
    last_eval: Option<EvalResult>,
    next_eval: u64,
}

impl Run {
    /// Starts at the trainer's state; a resumed run continues its log (rows past the
    /// checkpoint, written before a crash, are dropped: training repeats them) and its best
    /// evaluation.
    fn resume<E: Env + Clone>(trainer: &Trainer<E>, opts: &RunOptions) -> Self {
        let start = Instant::now();
        let mut log = std::fs::read_to_string(opts.out_dir.join(METRICS_CSV))
            .ok()
            .filter(|_| trainer.steps > 0)
            .map(|t| MetricsLog::from_csv(&t))
            .unwrap_or_default();
        log.rows.retain(|r| r.iter.steps <= trainer.steps);
        let best = Checkpoint::load(&opts.out_dir.join(BEST))
            .ok()
            .and_then(|c| c.meta.best_eval);
        Self {
            start,
            start_steps: trainer.steps,
            log,
            best,
            last_eval: None,
            next_eval: trainer.steps + opts.eval_every_steps,
        }
    }

    /// Evaluates, then saves `last.ckpt` (and `best.ckpt` when this is the best so far).
    fn evaluate<E: Env + Clone>(
        &mut self,
        trainer: &Trainer<E>,
        eval_scenes: &[E::Scene],
        opts: &RunOptions,
    ) -> Result<EvalResult, CheckpointError> {
        self.next_eval = trainer.steps + opts.eval_every_steps;
        let e = trainer.evaluate(eval_scenes);
        let is_best = self.best.is_none_or(|b| better(&e, &b));
        if is_best {
            self.best = Some(e);
        }
        let mut ck = Checkpoint::capture(trainer, opts.seed, opts.task_hash);
        ck.meta.eval = Some(e);
        ck.meta.best_eval = self.best;
        if is_best {
            ck.save(&opts.out_dir.join(BEST))?;
        }
        ck.save(&opts.out_dir.join(LAST))?;
        Ok(e)
    }

    /// After an evaluation: writes the metrics, logs, and tells whether the success rule is
    /// met.
    fn record_eval(
        &mut self,
        e: &EvalResult,
        st: &IterStats,
        steps: u64,
        opts: &RunOptions,
    ) -> Result<bool, CheckpointError> {
        self.write_metrics(opts)?;
        tracing::info!(
            steps,
            success = e.success_rate,
            collision = e.collision_rate,
            eval_return = e.mean_return,
            train_return = st.mean_return,
            "evaluation"
        );
        let met = opts
            .success_rule
            .is_some_and(|rule| rule.met(self.last_eval.as_ref(), e));
        self.last_eval = Some(*e);
        Ok(met)
    }

    /// Rewrites `metrics.csv` and `reward.svg` (a plot failure is only logged).
    fn write_metrics(&self, opts: &RunOptions) -> Result<(), CheckpointError> {
        self.log.write_csv(&opts.out_dir.join(METRICS_CSV))?;
        if let Err(e) = self.log.plot(&opts.out_dir.join(REWARD_SVG), &opts.title) {
            tracing::warn!("reward plot not drawn: {}", error_chain(&e));
        }
        Ok(())
    }

    fn summary(&self, stop: StopReason, total_steps: u64) -> RunSummary {
        let wall_s = self.start.elapsed().as_secs_f64();
        let steps = total_steps - self.start_steps;
        RunSummary {
            stop,
            steps,
            total_steps,
            wall_s,
            last_eval: self.last_eval,
            best_eval: self.best,
            steps_per_s: steps as f64 / wall_s.max(1e-9),
        }
    }
}

/// An indicatif bar over the step budget, when asked for and stderr is a terminal.
fn progress_bar(opts: &RunOptions, steps: u64) -> Option<ProgressBar> {
    (opts.progress && std::io::stderr().is_terminal()).then(|| {
        let b = ProgressBar::new(opts.total_steps);
        b.set_style(
            ProgressStyle::with_template("{bar:40} {pos}/{len} steps  {per_sec}  ETA {eta}  {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b.set_position(steps.min(opts.total_steps));
        b
    })
}
