//! The retraining recipe: one retraining of a base checkpoint on a reported scene
//! ([`RetrainJob`]), what `learner serve` runs per request, `learner retrain` offline and the
//! unseen-worlds benchmark (`unseen-worlds --retrain`) per failed world.
//!
//! PPO resumes from the base checkpoint on the reported scene with randomisation around it
//! ([`RetrainSampler`]) and a share of the old distribution, a height curriculum
//! ([`next_height_start`] switches it between requests), evaluated on the reported scene
//! and pre-training scenes the base policy solves ("kept": the retraining converges only
//! when it still solves them); with demonstrations on, the feasibility planner's path is
//! cloned into the actor first ([`warm_start`]). It stops when the evaluation succeeds
//! (≥ 95 %, no contact, return converged) or a step/time budget runs out.
//!
//! - [`settings`]: [`RetrainSettings`] and the command-line flags behind them
//!   ([`RetrainFlags`]);
//! - [`warm_start`]: demonstrations and behaviour cloning before PPO ([`WarmStart`]);
//! - [`progress`](mod@progress): the `RetrainProgress` answers the service publishes.
//!
//! ```no_run
//! # use learner::{checkpoint::Checkpoint, twin_env::TwinTask, retrain::{RetrainJob, RetrainSettings}};
//! # fn job(base: &Checkpoint, env: &TwinTask, scene: twin::Scene, settings: &RetrainSettings)
//! # -> Result<(), learner::retrain::RetrainError> {
//! let outcome = RetrainJob {
//!     base,
//!     env,
//!     scene,
//!     planner_path: None, // the feasibility check runs here when demonstrations are on
//!     settings,
//!     out_dir: std::path::Path::new("runs/retrain"),
//!     eval_seed: 1,
//!     device: tch::Device::Cpu,
//! }
//! .run(|_iteration, _evaluation| true)?; // `false` cancels
//! println!("{:?} after {} steps", outcome.summary.stop, outcome.summary.steps);
//! # Ok(()) }
//! ```
//!
//! Training code: it allocates and is not for the real-time cycle.

pub mod progress;
pub mod settings;
pub mod warm_start;

use std::path::Path;
use std::time::Duration;

use serde::Serialize;
use twin::{Feasibility, Joints, Scene, check_feasibility};

use crate::checkpoint::{Checkpoint, CheckpointError};
use crate::ppo::{EvalResult, IterStats, Trainer, TrainerBuildError};
use crate::run::{RunOptions, RunSummary, StopReason, SuccessRule, train};
use crate::twin_env::{CurriculumSampler, Jitter, RetrainSampler, TwinTask, fixed_scenes};

pub use progress::{infeasible_progress, progress};
pub use settings::{OnOff, RetrainFlags, RetrainSettings};
pub use warm_start::WarmStart;

/// Why a retraining failed.
#[derive(Debug, thiserror::Error)]
pub enum RetrainError {
    /// The base checkpoint could not be restored, or a run checkpoint could not be written.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The trainer could not be built (invalid PPO configuration).
    #[error(transparent)]
    Trainer(#[from] TrainerBuildError),
}

/// Everything one retraining reports.
#[derive(Debug, Clone, Serialize)]
pub struct RetrainOutcome {
    /// The run.
    pub summary: RunSummary,
    /// The base policy's evaluation (reported scene and kept scenes).
    pub before: EvalResult,
    /// The demonstrations and cloning, when on.
    pub warm_start: Option<WarmStart>,
}

/// One retraining: `base` retrained on `scene` (with randomisation and a share of the old
/// distribution) into `out_dir` (best/last checkpoints, metrics, plot; emptied first).
#[derive(Debug, Clone, Copy)]
pub struct RetrainJob<'a> {
    /// The checkpoint to resume from.
    pub base: &'a Checkpoint,
    /// The task.
    pub env: &'a TwinTask,
    /// The reported scene.
    pub scene: Scene,
    /// The feasibility check's collision-free path to a safe goal posture, for the
    /// demonstrations; `None`: with `settings.demonstrations`, the check runs here for it.
    pub planner_path: Option<&'a [Joints]>,
    /// How it runs.
    pub settings: &'a RetrainSettings,
    /// Where the run writes.
    pub out_dir: &'a Path,
    /// Seed of the jittered evaluation variants of the reported scene.
    pub eval_seed: u64,
    /// Where the networks live.
    pub device: tch::Device,
}

impl RetrainJob<'_> {
    /// Runs the retraining. `on_iter` sees every iteration with the steps taken in this
    /// retraining (and the evaluation when one ran); returning `false` cancels it
    /// ([`StopReason::Cancelled`]).
    ///
    /// # Errors
    /// [`RetrainError`]: the base checkpoint does not restore into the trainer, or a run
    /// checkpoint cannot be written.
    pub fn run(
        self,
        mut on_iter: impl FnMut(&IterStats, Option<&EvalResult>) -> bool,
    ) -> Result<RetrainOutcome, RetrainError> {
        let Self {
            base,
            env,
            scene,
            planner_path,
            settings: s,
            out_dir,
            eval_seed,
            device,
        } = self;
        // Without a path handed over, the one the service's feasibility check would hand over.
        let verdict = (s.demonstrations && planner_path.is_none()).then(|| {
            check_feasibility(
                &env.env,
                &scene,
                &env.env.config().start.joints_rad,
                s.feasibility,
            )
        });
        let path = planner_path.or_else(|| verdict.as_ref().and_then(Feasibility::path));
        let mut trainer = retrain_trainer(base, env, s, device)?;
        let sampler = RetrainSampler::new(env, scene, Jitter::default(), s.old_share);
        let mut eval_scenes = sampler.eval_scenes(s.eval_episodes, eval_seed, s.eval_jitter);
        let kept = kept_scenes(&trainer, env, s.kept_episodes);
        tracing::info!(
            kept = kept.len(),
            "pre-training scenes the base policy solves, evaluated with the reported scene"
        );
        eval_scenes.extend(kept);
        let before = trainer.evaluate(&eval_scenes);
        let warm = s
            .demonstrations
            .then(|| warm_start::warm_start(&mut trainer, env, &sampler, path, &eval_scenes, s));
        // When the cloned policy already passes the evaluation, PPO has only to confirm it: the
        // stop rule's two consecutive passing evaluations come twice as often (tall box: 2.1 s
        // instead of 4.6 s). Otherwise the configured interval (more evaluations only cost time
        // while PPO still has to learn: world 34 of the benchmark took 31.8 s instead of 22.4 s
        // evaluated every 4 096 steps).
        let cloned_passes = warm.as_ref().and_then(|w| w.after_bc).is_some_and(|e| {
            e.success_rate >= SuccessRule::default().min_success && e.collision_rate == 0.0
        });
        let eval_every = if cloned_passes {
            (s.eval_every / 2).max(1)
        } else {
            s.eval_every
        };
        let _ = std::fs::remove_dir_all(out_dir);
        let opts = RunOptions {
            out_dir: out_dir.to_path_buf(),
            total_steps: trainer.steps + s.max_steps,
            eval_every_steps: eval_every,
            seed: base.meta.seed,
            task_hash: env.task_hash(),
            time_budget: Some(Duration::from_secs_f64(s.time_budget_s)),
            success_rule: Some(SuccessRule::default()),
            title: format!("retraining ({})", out_dir.display()),
            progress: false,
            lr_schedule: None,
        };
        let start_steps = trainer.steps;
        tracing::info!(
            success = before.success_rate,
            collision = before.collision_rate,
            "base policy on the reported scene"
        );
        sampler.set_height_lo(s.height_start);
        let ramp_steps = (s.max_steps / 2).max(1) as f32;
        let sum = train(&mut trainer, &sampler, &eval_scenes, &opts, |st, e| {
            let mut st = st.clone();
            st.steps -= start_steps;
            let f = (st.steps as f32 / ramp_steps).min(1.0);
            sampler.set_height_lo(s.height_start + (1.0 - s.height_start) * f);
            on_iter(&st, e)
        })?;
        Ok(RetrainOutcome {
            summary: sum,
            before,
            warm_start: warm,
        })
    }
}

/// A trainer restored from `base` with the retraining's overrides (workers, entropy bonus,
/// frozen statistics, minibatch, learning rate) and the exploration floor applied.
fn retrain_trainer(
    base: &Checkpoint,
    env: &TwinTask,
    s: &RetrainSettings,
    device: tch::Device,
) -> Result<Trainer<TwinTask>, RetrainError> {
    let mut cfg = base.meta.ppo.clone();
    if s.workers > 0 {
        cfg.workers = s.workers;
    }
    let mut trainer = Trainer::new(cfg, env.clone(), base.meta.seed, device)?;
    base.restore(&mut trainer)?;
    trainer.cfg.ent_coef = s.ent_coef;
    trainer.cfg.update_stats = !s.freeze_stats;
    if s.batch > 0 {
        trainer.cfg.batch_size = s.batch;
    }
    if s.epochs > 0 {
        trainer.cfg.n_epochs = s.epochs;
    }
    if s.lr > 0.0 {
        trainer.cfg.learning_rate = s.lr;
        trainer.adam.lr = s.lr;
    }
    let std_before = trainer.net.log_std().detach().exp();
    if s.explore_std > 0.0 {
        let floor = s.explore_std.ln();
        tch::no_grad(|| {
            let mut ls = trainer.net.log_std();
            let _ = ls.clamp_min_(floor);
        });
    }
    tracing::info!(std_before = ?Vec::<f32>::try_from(&std_before).unwrap_or_default(), explore_std = s.explore_std, "exploration");
    Ok(trainer)
}

/// Seed of the kept scenes (distinct from the training and evaluation streams).
const KEPT_SEED: u64 = 0x4B45_5054;

/// Up to `n` scenes of the pre-training distribution that `trainer`'s policy solves (drawn
/// from a fixed seed; at most `2 n` tried).
fn kept_scenes(trainer: &Trainer<TwinTask>, env: &TwinTask, n: usize) -> Vec<Scene> {
    if n == 0 {
        return Vec::new();
    }
    let candidates = fixed_scenes(&CurriculumSampler::pretraining(env), 2 * n, KEPT_SEED);
    // One batched evaluation of all candidates (each scene's episode is its own, so the
    // choice is the same as evaluating them one at a time — which took 0.6 s of the 2.1 s
    // tall-box retraining).
    let solved = crate::ppo::successes(
        &trainer.net,
        &trainer.obs_normalizer(),
        env,
        &candidates,
        trainer.cfg.effective_workers(),
    );
    candidates
        .into_iter()
        .zip(solved)
        .filter_map(|(s, ok)| ok.then_some(s))
        .take(n)
        .collect()
}

/// The height curriculum of the retraining after one that stopped with `stop`: back to the
/// configured one after a success; after an exhausted budget the other one (the configured
/// curriculum ↔ off). Scenes that one setting does not solve within the budget the other
/// often does: offline, of the 3 of 20 random tall-box scenes that failed with the
/// curriculum (4e5 steps), the curriculum off solved 2 from the bundled policy, and 1 when
/// continuing from the failed run's last checkpoint (repeating the curriculum: 0 of 2).
pub fn next_height_start(current: f32, configured: f32, stop: StopReason) -> f32 {
    if stop == StopReason::Converged || configured >= 1.0 {
        configured
    } else if current < 1.0 {
        1.0
    } else {
        configured
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint;
    use crate::normalize::ObsNormalizer;
    use twin::FeasibilityConfig;

    fn assets() -> std::path::PathBuf {
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    /// The `learner serve` defaults ([`RetrainFlags`]), with a step budget for tests.
    fn settings(demonstrations: bool, max_steps: u64) -> RetrainSettings {
        RetrainSettings {
            max_steps,
            time_budget_s: 600.0,
            eval_every: 8_192,
            eval_episodes: 20,
            eval_jitter: 0.0,
            old_share: 0.5,
            explore_std: 0.5,
            freeze_stats: false,
            batch: 0,
            epochs: 0,
            lr: 0.0,
            ent_coef: 0.01,
            height_start: 0.3,
            workers: 0,
            kept_episodes: 40,
            demonstrations,
            demo_variants: 4,
            bc_steps: 300,
            feasibility: FeasibilityConfig::default(),
        }
    }

    /// Flipped to `false` by hand to see the test below fail without demonstrations.
    const DEMOS: bool = true;

    #[test]
    fn retraining_from_demonstrations_learns_the_tall_box_the_base_policy_fails() {
        tch::set_num_threads(1);
        let env = TwinTask::load(&assets().join("task.toml"), None).expect("task");
        let base = Checkpoint::load(&assets().join("policy/best.ckpt")).expect("base");
        let file = shm_schemas::scene_file::SceneFile::load(&assets().join("scenes/tall_box.toml"))
            .expect("scene file");
        let scene = Scene::from_file(&file).expect("scene");
        let one = std::slice::from_ref(&scene);
        let zero_shot = crate::ppo::evaluate(
            &base.network(tch::Device::Cpu).expect("net"),
            &ObsNormalizer::from_stats(&base.meta.obs_rms.to_rms(), base.meta.ppo.clip_obs),
            &env,
            one,
            1,
        );
        assert_eq!(
            zero_shot.success_rate, 0.0,
            "the base policy solves it already"
        );
        let dir = std::env::temp_dir().join(format!("learner-demo-retrain-{}", std::process::id()));
        let start = env.env.config().start.joints_rad;
        let verdict = check_feasibility(&env.env, &scene, &start, FeasibilityConfig::default());
        let o = RetrainJob {
            base: &base,
            env: &env,
            scene,
            planner_path: verdict.path(),
            // Within 49 152 steps: with demonstrations it converges at 12 288; from the base
            // policy alone PPO needs 114 688 (demonstrations off fails this test).
            settings: &settings(DEMOS, 49_152),
            out_dir: &dir,
            eval_seed: 1,
            device: tch::Device::Cpu,
        }
        .run(|_, _| true)
        .expect("retraining");
        assert_eq!(o.summary.stop, StopReason::Converged, "{:?}", o.summary);
        let warm = o.warm_start.expect("warm start");
        assert!(warm.reported_scene, "{warm:?}");
        let bc = warm.bc.expect("cloned");
        assert!(bc.demo_loss_after < bc.demo_loss_before, "{bc:?}");
        let best = Checkpoint::load(&dir.join(checkpoint::BEST)).expect("best");
        let norm = ObsNormalizer::from_stats(&best.meta.obs_rms.to_rms(), best.meta.ppo.clip_obs);
        let net = best.network(tch::Device::Cpu).expect("net");
        let exact = crate::ppo::evaluate(&net, &norm, &env, one, 1);
        assert_eq!((exact.success_rate, exact.collision_rate), (1.0, 0.0));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_exhausted_budget_switches_the_height_curriculum_and_a_success_restores_it() {
        let exhausted = StopReason::Steps;
        assert_eq!(next_height_start(0.3, 0.3, exhausted), 1.0);
        assert_eq!(next_height_start(1.0, 0.3, exhausted), 0.3);
        assert_eq!(next_height_start(1.0, 0.3, StopReason::TimeBudget), 0.3);
        assert_eq!(next_height_start(1.0, 0.3, StopReason::Converged), 0.3);
        assert_eq!(next_height_start(0.3, 0.3, StopReason::Converged), 0.3);
        // With the curriculum configured off there is nothing to switch to.
        assert_eq!(next_height_start(1.0, 1.0, exhausted), 1.0);
    }
}
