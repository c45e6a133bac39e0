//! `learner distil`: the feasibility planner (and the straight line where it suffices)
//! distilled into a checkpoint's policy by DAgger over worlds of the task's own `[world]`
//! sampler ([`learner::distil::DistilJob`]). Keeps `best.ckpt` (best success on the fixed
//! evaluation scenes of the pre-training distribution, ties broken by fewer contacts),
//! `last.ckpt` and `distil.json` in `--out`, all written atomically; prints the summary as
//! JSON. Follow with `learner pretrain --out DIR --resume` for PPO fine-tuning. With
//! `--action-space joint_step` the policy acts in the joint-step space (per-joint steps
//! toward the goal posture the twin chooses; `learner::distil::joint`).

use std::path::PathBuf;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use learner::distil::{DistilConfig, DistilEvent, DistilJob};
use learner::ppo::bc::BcConfig;
use shm_schemas::ActionSpace;

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
    /// Margin of the cloning's collision hinge (m): the clearance predicted after the
    /// policy's mean action (nearest box or table, from the observation) is kept above it.
    #[arg(long, default_value_t = learner::distil::DEFAULT_HINGE_MARGIN_M, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 0.2), allow_negative_numbers = true)]
    hinge_margin_m: f64,
    /// Weight of the cloning's collision hinge (the shortfall below the margin in steps,
    /// squared, beside the imitation loss); 0: off.
    #[arg(long, default_value_t = learner::distil::DEFAULT_HINGE_WEIGHT, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 100.0), allow_negative_numbers = true)]
    hinge_weight: f64,
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
    /// The action space of the distilled policy: `cartesian_step` (the paper's, the
    /// checkpoint's network) or `joint_step` (per-joint steps toward the goal posture the
    /// twin chooses; a fresh network of the checkpoint's or `--hidden` shape, the teachers
    /// the joint straight line and the planner's joint path to that posture).
    #[arg(long, value_enum, default_value_t = SpaceArg::CartesianStep)]
    action_space: SpaceArg,
}

/// `--action-space` (`shm_schemas::ActionSpace` by its schema name).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
#[clap(rename_all = "snake_case")]
pub enum SpaceArg {
    /// The paper's Cartesian TCP step.
    CartesianStep,
    /// Per-joint steps toward a goal posture.
    JointStep,
}

impl From<SpaceArg> for ActionSpace {
    fn from(a: SpaceArg) -> Self {
        match a {
            SpaceArg::CartesianStep => Self::CartesianStep,
            SpaceArg::JointStep => Self::JointStep,
        }
    }
}

/// Runs `learner distil`.
///
/// # Errors
/// Task, checkpoint or output failures, or no world with a teacher.
pub fn run(args: DistilArgs, device: tch::Device) -> Result<()> {
    let job = DistilJob {
        checkpoint: args.checkpoint,
        task: args.task,
        worlds: args.worlds,
        harder_share: args.harder_share,
        hidden: args.hidden,
        config: DistilConfig {
            iterations: args.iterations,
            noise_std: args.noise_std,
            bc: BcConfig {
                steps: args.bc_steps,
                lr: args.bc_lr,
                ..DistilConfig::default().bc
            },
            hinge_weight: args.hinge_weight,
            hinge_margin_m: args.hinge_margin_m,
            ..DistilConfig::default()
        },
        margin_m: args.margin_m,
        eval_episodes: args.eval_episodes,
        seed: args.seed,
        threads: args.threads,
        out: args.out,
        action_space: args.action_space.into(),
    };
    let iterations = job.config.iterations as u64;
    let spinner = ProgressBar::new_spinner();
    let mut bar: Option<ProgressBar> = None;
    let summary = job.run(device, |event| match event {
        DistilEvent::FindingTeachers { worlds } => {
            spinner.set_message(format!("finding a teacher for each of {worlds} worlds"));
            spinner.enable_steady_tick(std::time::Duration::from_millis(200));
        }
        DistilEvent::TeachersFound { .. } => {
            spinner.finish_and_clear();
            let b = ProgressBar::new(iterations);
            b.set_style(
                ProgressStyle::with_template("{bar:30} {pos}/{len} DAgger iterations {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            bar = Some(b);
        }
        DistilEvent::Iteration(r) => {
            if let Some(b) = &bar {
                b.inc(1);
                b.set_message(format!(
                    "success {:.1} %, contact {:.1} %",
                    100.0 * r.eval.success_rate,
                    100.0 * r.eval.collision_rate
                ));
            }
        }
    });
    spinner.finish_and_clear();
    if let Some(b) = bar {
        b.finish();
    }
    println!("{}", serde_json::to_string(&summary?)?);
    Ok(())
}
