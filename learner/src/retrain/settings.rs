//! What one retraining runs with: [`RetrainSettings`], and the command-line flags behind
//! them ([`RetrainFlags`], flattened into `learner serve`, `learner retrain` and
//! `unseen-worlds`; `--help` documents the measurements behind the defaults). Every numeric
//! flag is bounded at parsing (`shm_schemas::cli_bounds`), naming the flag.

use std::path::PathBuf;

use twin::FeasibilityConfig;

/// How one retraining runs (each field is the `learner serve` / `learner retrain` flag of
/// the same name; see `--help` for the measurements behind the defaults).
#[derive(Debug, Clone, PartialEq)]
pub struct RetrainSettings {
    /// Step budget.
    pub max_steps: u64,
    /// Wall-time budget (s).
    pub time_budget_s: f64,
    /// Evaluate every this many steps.
    pub eval_every: u64,
    /// Evaluation episodes (the reported scene and lightly jittered variants).
    pub eval_episodes: usize,
    /// Jitter of the evaluation variants as a fraction of the training jitter.
    pub eval_jitter: f64,
    /// Share of training episodes from the old (pre-training) distribution.
    pub old_share: f64,
    /// Floor of the policy's standard deviation at the start (0 keeps it).
    pub explore_std: f64,
    /// Keep the observation/return statistics fixed.
    pub freeze_stats: bool,
    /// Minibatch size (0: the checkpoint's).
    pub batch: usize,
    /// Epochs per rollout (0: the checkpoint's).
    pub epochs: usize,
    /// Learning rate (0: the checkpoint's).
    pub lr: f64,
    /// Entropy bonus coefficient.
    pub ent_coef: f64,
    /// Start of the box-height curriculum (1 = off).
    pub height_start: f32,
    /// Rollout worker threads (0: the checkpoint's setting).
    pub workers: usize,
    /// Pre-training scenes the base policy solves that every evaluation also runs (0: none):
    /// the retraining converges only when the policy still solves them (no contact at all,
    /// ≥ 95 % success over the whole evaluation set), so it keeps what it knew.
    pub kept_episodes: usize,
    /// Start from the planner's demonstrations: the feasibility planner's path re-tracked
    /// in the twin ([`crate::demonstrations`]), cloned into the actor before PPO
    /// ([`crate::ppo::bc`]).
    pub demonstrations: bool,
    /// Jittered variants of the reported scene demonstrated besides the scene itself (each
    /// planned on its own).
    pub demo_variants: usize,
    /// Behaviour-cloning gradient steps.
    pub bc_steps: usize,
    /// The planner's settings for the demonstrations (goal-posture seeds, budget).
    pub feasibility: FeasibilityConfig,
}

/// The flags of one retraining, shared by `learner serve`, `learner retrain` and
/// `unseen-worlds` (the checkpoint, the task, the output folder and [`RetrainSettings`]).
#[derive(Debug, Clone, clap::Args)]
pub struct RetrainFlags {
    /// Base checkpoint: a run directory (its best.ckpt) or a checkpoint file.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Task configuration.
    #[arg(long, default_value = "assets/task.toml")]
    pub task: PathBuf,
    /// Where retraining runs write checkpoints, metrics and plots (default: a `retrain`
    /// folder beside the base checkpoint).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Step budget per request (the tall-box scene needs about 2e5–6e5 from the bundled
    /// policy, see the learner README).
    #[arg(long, default_value_t = 600_000, value_parser = shm_schemas::cli_bounds::int_within(1u64, 10_000_000_000), allow_negative_numbers = true)]
    pub max_steps: u64,
    /// Wall-time budget per request (s).
    #[arg(long, default_value_t = 90.0, value_parser = shm_schemas::cli_bounds::f64_within(0.1, 86_400.0), allow_negative_numbers = true)]
    pub time_budget_s: f64,
    /// Evaluate every this many steps.
    #[arg(long, default_value_t = 8_192, value_parser = shm_schemas::cli_bounds::int_within(1u64, 1_000_000_000), allow_negative_numbers = true)]
    pub eval_every: u64,
    /// Evaluation episodes (the reported scene and lightly jittered variants).
    #[arg(long, default_value_t = 20, value_parser = shm_schemas::cli_bounds::int_within(1usize, 100_000), allow_negative_numbers = true)]
    pub eval_episodes: usize,
    /// Jitter of the evaluation variants as a fraction of the training jitter (2 cm, 10 %):
    /// 0 (default) evaluates the reported scene exactly as reported (the lookahead re-checks
    /// the live scene anyway); 0.5 asks for robustness to ±1 cm / ±5 % and takes ~5× longer.
    #[arg(long, default_value_t = 0.0, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    pub eval_jitter: f64,
    /// Share of training episodes from the old (pre-training) distribution. 0.5 by default
    /// with the generalist policy: on the tall-box scene from a generalist checkpoint, 0.5
    /// (with `--explore-std 0.5`) converged in 1.5e5 steps and kept 91.5 % of the
    /// pre-training scenes (base 94.5 %), where 0 (with `--explore-std 2`) had not converged
    /// after 3e5 steps and kept 79.5 %. (With the earlier small-obstacle policy 0 was best.)
    #[arg(long, default_value_t = 0.5, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    pub old_share: f64,
    /// Raise the policy's standard deviation to at least this at the start of a retraining
    /// (a converged policy barely explores; 0 keeps it). 0.5 by default for the generalist
    /// (see `--old-share`; 2.0, best for the earlier small-obstacle policy, wipes out much
    /// of what the generalist knew).
    #[arg(long, default_value_t = 0.5, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 10.0), allow_negative_numbers = true)]
    pub explore_std: f64,
    /// Keep the pre-training observation/return statistics fixed while retraining (off by
    /// default: measured worse — the unseen tall-box features saturate at the clip).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set)]
    pub freeze_stats: bool,
    /// Minibatch size during retraining (0: the checkpoint's).
    #[arg(long, default_value_t = 0, value_parser = shm_schemas::cli_bounds::int_within(0usize, 1_000_000), allow_negative_numbers = true)]
    pub batch: usize,
    /// Epochs per rollout during retraining (0: the checkpoint's).
    #[arg(long, default_value_t = 0, value_parser = shm_schemas::cli_bounds::int_within(0usize, 100), allow_negative_numbers = true)]
    pub epochs: usize,
    /// Learning rate during retraining (0: the checkpoint's).
    #[arg(long, default_value_t = 0.0, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    pub lr: f64,
    /// Entropy bonus coefficient during retraining (keeps the raised exploration alive;
    /// 0.01 measured best of 0, 0.005, 0.01 on the tall-box scene).
    #[arg(long, default_value_t = 0.01, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 1.0), allow_negative_numbers = true)]
    pub ent_coef: f64,
    /// Height curriculum: box heights start scaled by a factor in `[h, 1]` and `h` rises
    /// to 1 over the first half of the step budget (1 = off). 0.3 by default: on the 20
    /// tall-box scenes of `foresight --runs 20 --seed 7`, offline from the bundled policy
    /// with a 4e5-step budget, 17 converged (median 9.8e4 steps, 5.3 s) against 14 with the
    /// curriculum off (median 1.1e5 steps, 6.2 s). Evaluation is always on the full heights.
    #[arg(long, default_value_t = 0.3, value_parser = shm_schemas::cli_bounds::f32_within(0.0, 1.0), allow_negative_numbers = true)]
    pub height_start: f32,
    /// Rollout worker threads (0 = the checkpoint's setting).
    #[arg(long, default_value_t = 0, value_parser = shm_schemas::cli_bounds::int_within(0usize, 256), allow_negative_numbers = true)]
    pub workers: usize,
    /// Pre-training scenes the base policy solves, evaluated with the reported scene: a
    /// retraining converges only when it still solves them with no contact (0 = off).
    #[arg(long, default_value_t = 40, value_parser = shm_schemas::cli_bounds::int_within(0usize, 100_000), allow_negative_numbers = true)]
    pub kept_episodes: usize,
    /// Wall-time budget of the feasibility check's joint-space planner per request (s): a
    /// world whose safe goal postures it cannot connect to the start within it is answered
    /// as infeasible ("no collision-free path found").
    #[arg(long, default_value_t = 20.0, value_parser = shm_schemas::cli_bounds::f64_within(0.001, 600.0), allow_negative_numbers = true)]
    pub planner_budget_s: f64,
    /// Start each retraining from the planner's demonstrations: the feasibility check's
    /// collision-free path re-tracked in the twin with the task's Cartesian actions, cloned
    /// into the actor (anchored by the policy's own actions on pre-training scenes it
    /// solves) before PPO fine-tunes it (`off`: PPO from the base policy alone, as before).
    #[arg(long, value_enum, default_value_t = OnOff::On)]
    pub demonstrations: OnOff,
    /// Jittered variants of the reported scene (±2 cm, ±10 %) demonstrated besides the
    /// scene itself, each planned on its own.
    #[arg(long, default_value_t = 4, value_parser = shm_schemas::cli_bounds::int_within(0usize, 64), allow_negative_numbers = true)]
    pub demo_variants: usize,
    /// Behaviour-cloning gradient steps (minibatches of 256, half demonstrations, half the
    /// policy's own actions on pre-training scenes).
    #[arg(long, default_value_t = 300, value_parser = shm_schemas::cli_bounds::int_within(0usize, 100_000), allow_negative_numbers = true)]
    pub bc_steps: usize,
}

/// A switch flag's value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    /// On.
    On,
    /// Off.
    Off,
}

impl RetrainFlags {
    /// The settings of each retraining.
    pub fn settings(&self) -> RetrainSettings {
        RetrainSettings {
            max_steps: self.max_steps,
            time_budget_s: self.time_budget_s,
            eval_every: self.eval_every,
            eval_episodes: self.eval_episodes,
            eval_jitter: self.eval_jitter,
            old_share: self.old_share,
            explore_std: self.explore_std,
            freeze_stats: self.freeze_stats,
            batch: self.batch,
            epochs: self.epochs,
            lr: self.lr,
            ent_coef: self.ent_coef,
            height_start: self.height_start,
            workers: self.workers,
            kept_episodes: self.kept_episodes,
            demonstrations: self.demonstrations == OnOff::On,
            demo_variants: self.demo_variants,
            bc_steps: self.bc_steps,
            feasibility: self.feasibility(),
        }
    }

    /// The feasibility check's settings (the planner's budget from `--planner-budget-s`).
    pub fn feasibility(&self) -> FeasibilityConfig {
        let mut f = FeasibilityConfig::default();
        f.planner.max_time_s = self.planner_budget_s;
        f
    }
}
