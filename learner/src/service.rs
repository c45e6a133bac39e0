//! The retraining service (`learner serve`): subscribes to [`RetrainRequest`]s over
//! iceoryx2; for each, first checks that the world is feasible (a safe goal posture from many
//! IK seeds, a collision-free joint-space path to it: `twin::feasibility`) and answers
//! [`RetrainPhase::Infeasible`] with the reason when not; otherwise resumes PPO from the base checkpoint on the reported scene (with
//! randomisation around it and a share of the old distribution), stops when the evaluation
//! on the reported scene succeeds (≥ 95 %, no contact, return converged) or a step/time
//! budget runs out, and publishes the best policy as a validated [`PolicyBlob`] plus
//! [`RetrainProgress`] along the way. Requests that arrive during training are coalesced:
//! the running training is abandoned and the latest request is trained instead.
//!
//! [`retrain`] is one retraining (also what `learner retrain` runs offline); [`serve`] is
//! the request loop around it. The command-line flags behind [`ServiceConfig`] and
//! [`RetrainSettings`] are documented in `learner serve --help` (`cli/serve.rs`).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::ipc;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use shm_schemas::checksum::Fnv1a64;
use shm_schemas::services;
use shm_schemas::{PolicyBlob, PolicyBuildError, RetrainPhase, RetrainProgress, RetrainRequest};
use twin::{Feasibility, FeasibilityConfig, InfeasibleReason, Joints, check_feasibility};
use twin::{Scene, check_goal_postures};

use crate::checkpoint::{self, Checkpoint, CheckpointError};
use crate::demonstrations::{demonstrate, retrack_noisy};
use crate::env::Env;
use crate::export;
use crate::ppo::bc::{BcConfig, BcReport, BcSet, behaviour_clone, policy_pairs};
use crate::ppo::{EvalResult, IterStats, Trainer, TrainerBuildError};
use crate::run::{RunOptions, RunSummary, StopReason, SuccessRule, train};
use crate::twin_env::{
    CurriculumSampler, Jitter, RetrainSampler, TaskLoadError, TwinTask, fixed_scenes, jittered,
};

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

/// The set-up of `learner serve`.
#[derive(Debug, Clone, PartialEq)]
pub struct ServiceConfig {
    /// Base checkpoint: a run directory (its best.ckpt) or a checkpoint file.
    pub checkpoint: PathBuf,
    /// Service-name prefix.
    pub prefix: String,
    /// Task configuration.
    pub task: PathBuf,
    /// Where retraining runs write (default: a `retrain` folder beside the base checkpoint).
    pub out: Option<PathBuf>,
    /// Exit after answering this many requests (0: serve forever).
    pub max_requests: u64,
    /// Each retraining.
    pub retrain: RetrainSettings,
    /// The feasibility check run before each retraining.
    pub feasibility: FeasibilityConfig,
}

/// Why retraining or the service failed.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The task or robot model could not be loaded.
    #[error(transparent)]
    Task(#[from] TaskLoadError),
    /// A checkpoint could not be read or written.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The trainer could not be built (invalid PPO configuration).
    #[error(transparent)]
    Trainer(#[from] TrainerBuildError),
    /// The policy could not be packed into a blob.
    #[error("policy blob: {0}")]
    Blob(#[from] PolicyBuildError),
    /// iceoryx2 (node, services, loan, send).
    #[error("iceoryx2: {0}")]
    Shm(String),
}

/// A policy id for a checkpoint: FNV-1a of its weights and step count, never 0.
pub fn policy_id_for(ck: &Checkpoint) -> u64 {
    let mut h = Fnv1a64::new();
    h.write_f32s(&ck.theta);
    h.write_u64(ck.meta.steps);
    h.write_u64(ck.meta.task_hash);
    h.finish().max(1)
}

fn progress(
    req: &RetrainRequest,
    phase: RetrainPhase,
    steps: u64,
    ret: f64,
    succ: f64,
    t0: Instant,
    policy_id: u64,
) -> RetrainProgress {
    RetrainProgress {
        request_id: req.request_id,
        steps_done: steps,
        published_policy_id: policy_id,
        mean_return: if ret.is_finite() { ret } else { 0.0 },
        success_rate: succ,
        wall_time_s: t0.elapsed().as_secs_f64(),
        phase: phase as u8,
        ..Default::default()
    }
}

/// The final answer to `req` when the feasibility check finds no safe way: phase
/// [`RetrainPhase::Infeasible`] with the reason's wire form.
pub fn infeasible_progress(
    req: &RetrainRequest,
    reason: &InfeasibleReason,
    t0: Instant,
) -> RetrainProgress {
    let (kind, blocker, link, by_m) = reason.wire();
    RetrainProgress {
        infeasible_kind: kind,
        infeasible_blocker: blocker,
        infeasible_link: link,
        infeasible_by_m: by_m,
        ..progress(req, RetrainPhase::Infeasible, 0, 0.0, 0.0, t0, 0)
    }
}

/// A trainer restored from `base` with the retraining's overrides (workers, entropy bonus,
/// frozen statistics, minibatch, learning rate) and the exploration floor applied.
fn retrain_trainer(
    base: &Checkpoint,
    env: &TwinTask,
    s: &RetrainSettings,
    device: tch::Device,
) -> Result<Trainer<TwinTask>, ServeError> {
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

/// Tries per scene to find a path that re-tracks cleanly ([`demonstrate`]).
const DEMO_TRIES: usize = 6;

/// Noisy re-tracks per demonstration ([`retrack_noisy`]).
const NOISY_REPEATS: usize = 4;

/// Their action noise (std, action units).
const NOISE_STD: f32 = 0.3;

/// Seed of the jittered demonstration variants and of the cloning minibatches.
const DEMO_SEED: u64 = 0x4445_4D4F;

/// What the demonstrations and the behaviour cloning before a retraining did.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct WarmStart {
    /// Scenes demonstrated (the reported one and its jittered variants).
    pub scenes: usize,
    /// Of those, scenes with a demonstration that reached the goal without contact in the
    /// twin.
    pub demonstrated: usize,
    /// Whether the reported scene itself has one.
    pub reported_scene: bool,
    /// Planner paths re-tracked in all (the first clean one per scene ends the search).
    pub paths_tried: usize,
    /// Steps of the reported scene's demonstration (0 without one).
    pub reported_steps: usize,
    /// The cloning (absent when nothing was demonstrated).
    pub bc: Option<BcReport>,
    /// The cloned policy's evaluation (reported scene and kept scenes) before PPO.
    pub after_bc: Option<EvalResult>,
    /// Wall time of planning, re-tracking and cloning (s).
    pub wall_s: f64,
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

/// Seed of the pre-training scenes whose episodes anchor the cloning (distinct from the
/// kept scenes' seed: the gate is not trained on).
const ANCHOR_SEED: u64 = 0x414E_4348;

/// Pre-training scenes whose base-policy episodes anchor the cloning.
const ANCHOR_SCENES: usize = 80;

/// Demonstrates `scene` (re-tracking `path` first when given) and `s.demo_variants`
/// jittered variants of it, each with [`NOISY_REPEATS`] noisy re-tracks, then clones the
/// demonstrations into `trainer`'s actor, anchored by the policy's own actions along its
/// episodes on [`ANCHOR_SCENES`] pre-training scenes and on the kept scenes (the part of
/// `eval_scenes` after the first `s.eval_episodes`: without them, 3 of the 40 kept scenes
/// ended in contact after cloning the tall box, with them none); evaluates the result on
/// `eval_scenes`.
fn warm_start(
    trainer: &mut Trainer<TwinTask>,
    env: &TwinTask,
    sampler: &RetrainSampler,
    path: Option<&[Joints]>,
    eval_scenes: &[Scene],
    s: &RetrainSettings,
) -> WarmStart {
    let t0 = Instant::now();
    let obs_dim = env.obs_dim();
    let mut rng = ChaCha8Rng::seed_from_u64(DEMO_SEED);
    let mut scenes = vec![sampler.scene];
    scenes.extend((0..s.demo_variants).map(|_| jittered(&sampler.scene, sampler.jitter, &mut rng)));
    let mut demos = BcSet::default();
    let mut out = WarmStart {
        scenes: scenes.len(),
        ..Default::default()
    };
    for (k, sc) in scenes.iter().enumerate() {
        let first = if k == 0 { path } else { None };
        if k > 0
            && check_goal_postures(&env.env, sc, s.feasibility.goal_seeds)
                .reason
                .is_some()
        {
            continue;
        }
        let d = demonstrate(&env.env, sc, first, s.feasibility, DEMO_TRIES, obs_dim);
        out.paths_tried += d.paths_tried;
        if let Some(demo) = d.demonstration {
            out.demonstrated += 1;
            if k == 0 {
                out.reported_scene = true;
                out.reported_steps = demo.steps();
            }
            demos.extend(&demo.obs, &demo.actions);
            // Noise injection: the states of a slightly wrong imitator, labelled by the
            // path expert.
            for _ in 0..NOISY_REPEATS {
                let mut tw = env.env.clone();
                let d = retrack_noisy(
                    &mut tw,
                    sc,
                    &demo.path,
                    obs_dim,
                    Some((NOISE_STD, &mut rng)),
                );
                demos.extend(&d.obs, &d.actions);
            }
        }
    }
    if !demos.is_empty() {
        let norm = trainer.obs_normalizer();
        let anchor_scenes = fixed_scenes(
            &CurriculumSampler::pretraining(env),
            ANCHOR_SCENES,
            ANCHOR_SEED,
        );
        let mut anchors = policy_pairs(&trainer.net, &norm, env, &anchor_scenes);
        let kept = &eval_scenes[s.eval_episodes.min(eval_scenes.len())..];
        let kept_pairs = policy_pairs(&trainer.net, &norm, env, kept);
        anchors.extend(&kept_pairs.obs, &kept_pairs.actions);
        let cfg = BcConfig {
            steps: s.bc_steps,
            ..Default::default()
        };
        out.bc = Some(behaviour_clone(
            &mut trainer.net,
            &norm,
            &demos,
            &anchors,
            &cfg,
            &mut rng,
        ));
        out.after_bc = Some(trainer.evaluate(eval_scenes));
    }
    out.wall_s = t0.elapsed().as_secs_f64();
    tracing::info!(warm_start = ?out, "demonstrations cloned");
    out
}

/// Retrains `base` on `scene` (with randomisation and a share of the old distribution) into
/// `out_dir` (best/last checkpoints, metrics, plot). `on_iter` sees every iteration with the
/// steps taken in this retraining; returning `false` cancels. Returns the run summary and
/// the base policy's evaluation on the reported scene. With `settings.demonstrations`, the
/// feasibility check runs here for its path ([`retrain_with`] takes one already found).
///
/// # Errors
/// Checkpoint or configuration failures.
#[allow(clippy::too_many_arguments)]
pub fn retrain(
    base: &Checkpoint,
    env: &TwinTask,
    scene: Scene,
    settings: &RetrainSettings,
    out_dir: &Path,
    eval_seed: u64,
    device: tch::Device,
    on_iter: impl FnMut(&IterStats, Option<&EvalResult>) -> bool,
) -> Result<(RunSummary, EvalResult), ServeError> {
    // The path the service's feasibility check would hand over.
    let verdict = settings.demonstrations.then(|| {
        check_feasibility(
            &env.env,
            &scene,
            &env.env.config().start.joints_rad,
            settings.feasibility,
        )
    });
    let path = verdict.as_ref().and_then(Feasibility::path);
    let o = retrain_with(
        base, env, scene, path, settings, out_dir, eval_seed, device, on_iter,
    )?;
    Ok((o.summary, o.before))
}

/// [`retrain`] with the feasibility check's path for the demonstrations (`None`: planned
/// here when `settings.demonstrations` is on), reporting the warm start too.
///
/// # Errors
/// Checkpoint or configuration failures.
#[allow(clippy::too_many_arguments)]
pub fn retrain_with(
    base: &Checkpoint,
    env: &TwinTask,
    scene: Scene,
    path: Option<&[Joints]>,
    settings: &RetrainSettings,
    out_dir: &Path,
    eval_seed: u64,
    device: tch::Device,
    mut on_iter: impl FnMut(&IterStats, Option<&EvalResult>) -> bool,
) -> Result<RetrainOutcome, ServeError> {
    let s = settings;
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
        .then(|| warm_start(&mut trainer, env, &sampler, path, &eval_scenes, s));
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

/// Seed of the kept scenes (distinct from the training and evaluation streams).
const KEPT_SEED: u64 = 0x4B45_5054;

/// Up to `n` scenes of the pre-training distribution that `trainer`'s policy solves (drawn
/// from a fixed seed; at most `2 n` tried).
fn kept_scenes(trainer: &Trainer<TwinTask>, env: &TwinTask, n: usize) -> Vec<Scene> {
    if n == 0 {
        return Vec::new();
    }
    let candidates = fixed_scenes(&CurriculumSampler::pretraining(env), 2 * n, KEPT_SEED);
    candidates
        .into_iter()
        .filter(|s| {
            let e = trainer.evaluate(std::slice::from_ref(s));
            e.success_rate > 0.5 && e.collision_rate == 0.0
        })
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

/// Runs the service until `max_requests` are answered (or forever, or until SIGINT/SIGTERM).
///
/// # Errors
/// Setup failures (task, checkpoint, iceoryx2); per-request failures are logged and the
/// service carries on.
pub fn serve(cfg: &ServiceConfig, device: tch::Device) -> Result<(), ServeError> {
    let mut server = Server::open(cfg, device)?;
    let mut answered = 0u64;
    let mut pending: Option<RetrainRequest> = None;
    loop {
        if pending.is_none() {
            server.drain(&mut pending);
        }
        let Some(req) = pending.take() else {
            if server.node.wait(Duration::from_millis(20)).is_err() {
                break;
            }
            continue;
        };
        match server.handle(&req)? {
            Handled::Skipped => {}
            Handled::Stop => break,
            Handled::Superseded(newer) => pending = newer,
            Handled::Answered(newer) => {
                answered += 1;
                if cfg.max_requests > 0 && answered >= cfg.max_requests {
                    break;
                }
                pending = newer;
            }
        }
    }
    Ok(())
}

/// What became of one request.
enum Handled {
    /// Unusable scene or failed retraining (logged).
    Skipped,
    /// SIGINT/SIGTERM during training.
    Stop,
    /// A newer request arrived during training and supersedes it.
    Superseded(Option<RetrainRequest>),
    /// A policy was published; a request that arrived meanwhile, if any.
    Answered(Option<RetrainRequest>),
}

/// The service's state between requests. Ports are declared before the node so that they
/// are dropped first.
struct Server<'a> {
    cfg: &'a ServiceConfig,
    device: tch::Device,
    env: TwinTask,
    hash: u64,
    out_root: PathBuf,
    /// The checkpoint the next retraining resumes from.
    base_path: PathBuf,
    /// The settings of the next retraining (its height curriculum changes between requests,
    /// see [`next_height_start`]).
    settings: RetrainSettings,
    requests: Subscriber<ipc::Service, RetrainRequest, ()>,
    blobs: Publisher<ipc::Service, PolicyBlob, ()>,
    progress: Publisher<ipc::Service, RetrainProgress, ()>,
    node: Node<ipc::Service>,
}

impl<'a> Server<'a> {
    /// Loads the task and the base checkpoint and opens the iceoryx2 ports.
    fn open(cfg: &'a ServiceConfig, device: tch::Device) -> Result<Self, ServeError> {
        let env = TwinTask::load(&cfg.task, None)?;
        let hash = env.task_hash();
        let base_path = checkpoint::resolve(&cfg.checkpoint);
        let base = Checkpoint::load(&base_path)?;
        if base.meta.task_hash != hash {
            tracing::warn!(
                "base checkpoint task hash {:#x} differs from {}'s {hash:#x}: blobs will carry {hash:#x}",
                base.meta.task_hash,
                cfg.task.display()
            );
        }
        let out_root = cfg.out.clone().unwrap_or_else(|| {
            base_path
                .parent()
                .map_or_else(|| PathBuf::from("retrain"), |p| p.join("retrain"))
        });
        let shm = |e: &dyn std::fmt::Display| ServeError::Shm(e.to_string());
        let (node, _) = services::create_node::<ipc::Service>("learner")
            .map_err(|e| ServeError::Shm(format!("node: {e}")))?;
        let requests = services::open_subscriber::<RetrainRequest, _>(&node, &cfg.prefix)
            .map_err(|e| shm(&e))?;
        let blobs =
            services::open_publisher::<PolicyBlob, _>(&node, &cfg.prefix).map_err(|e| shm(&e))?;
        let progress = services::open_publisher::<RetrainProgress, _>(&node, &cfg.prefix)
            .map_err(|e| shm(&e))?;
        tracing::info!(prefix = %cfg.prefix, base = %base_path.display(), "learner serve: waiting for retrain requests");
        Ok(Self {
            cfg,
            device,
            env,
            hash,
            out_root,
            base_path,
            settings: cfg.retrain.clone(),
            requests,
            blobs,
            progress,
            node,
        })
    }

    /// Receives every waiting request; the latest valid one ends up in `latest`.
    fn drain(&self, latest: &mut Option<RetrainRequest>) {
        loop {
            let s = match self.requests.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!("receiving retrain requests: {e:?}");
                    break;
                }
            };
            let r: RetrainRequest = *s.payload();
            tracing::debug!(request = r.request_id, "retrain request received");
            match r.validate() {
                Ok(()) => *latest = Some(r),
                Err(e) => tracing::warn!("rejected retrain request: {e}"),
            }
        }
    }

    /// Retrains for `req` and publishes the result.
    fn handle(&mut self, req: &RetrainRequest) -> Result<Handled, ServeError> {
        let hash = self.hash;
        if req.task_config_hash != 0 && req.task_config_hash != hash {
            tracing::warn!(
                request = req.request_id,
                "request for task hash {:#x}, serving {hash:#x}: training anyway",
                req.task_config_hash
            );
        }
        let scene = match Scene::from_file(&req.scene()) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(request = req.request_id, "unusable scene: {e:?}");
                return Ok(Handled::Skipped);
            }
        };
        let t0 = Instant::now();
        // Feasibility first: a world with no safe goal posture, or no collision-free path to
        // one, is answered at once with the reason, and nothing is trained.
        let verdict = check_feasibility(
            &self.env.env,
            &scene,
            &self.env.env.config().start.joints_rad,
            self.cfg.feasibility,
        );
        if let Feasibility::Infeasible(reason) = &verdict {
            let words = reason.display_with(&scene.obstacles).to_string();
            tracing::warn!(
                request = req.request_id,
                check_s = t0.elapsed().as_secs_f64(),
                "no safe way found: {words}; not training"
            );
            let _ = self
                .progress
                .send_copy(infeasible_progress(req, reason, t0));
            println!(
                "{}",
                serde_json::json!({"request_id": req.request_id, "infeasible": words, "check_s": t0.elapsed().as_secs_f64()})
            );
            return Ok(Handled::Answered(None));
        }
        tracing::info!(
            request = req.request_id,
            obstacles = scene.obstacles.len(),
            feasibility_s = t0.elapsed().as_secs_f64(),
            "feasible; retraining"
        );
        let base = Checkpoint::load(&self.base_path)?;
        let out_dir = self.out_root.join(format!("request-{}", req.request_id));
        let mut newer: Option<RetrainRequest> = None;
        let mut stop_requested = false;
        let res = retrain_with(
            &base,
            &self.env,
            scene,
            verdict.path(),
            &self.settings,
            &out_dir,
            req.request_id,
            self.device,
            |st, eval| self.on_iter(req, st, eval, t0, &mut newer, &mut stop_requested),
        );
        let (sum, before) = match res {
            Ok(o) => (o.summary, o.before),
            Err(e) => {
                tracing::error!(request = req.request_id, "retraining failed: {e}");
                return Ok(Handled::Skipped);
            }
        };
        if stop_requested {
            tracing::info!(
                request = req.request_id,
                "termination requested; abandoning the retraining"
            );
            return Ok(Handled::Stop);
        }
        if sum.stop == StopReason::Cancelled {
            tracing::info!(request = req.request_id, "superseded by a newer request");
            return Ok(Handled::Superseded(newer));
        }
        self.publish(req, &sum, &before, &out_dir, t0)?;
        // The next request resumes from here: the best checkpoint once converged; after an
        // exhausted budget the last one, which holds all the training so far (the best by
        // evaluation may be an early one when nothing has succeeded yet), so that repeated
        // requests for a hard scene accumulate training instead of starting over.
        self.base_path = if sum.stop == StopReason::Converged {
            out_dir.join(checkpoint::BEST)
        } else {
            out_dir.join(checkpoint::LAST)
        };
        self.settings.height_start = next_height_start(
            self.settings.height_start,
            self.cfg.retrain.height_start,
            sum.stop,
        );
        Ok(Handled::Answered(newer))
    }

    /// Per training iteration: publishes progress, notices termination signals and newer
    /// requests; `false` cancels the retraining.
    fn on_iter(
        &self,
        req: &RetrainRequest,
        st: &IterStats,
        eval: Option<&EvalResult>,
        t0: Instant,
        newer: &mut Option<RetrainRequest>,
        stop_requested: &mut bool,
    ) -> bool {
        let (ret, succ) = eval.map_or((st.mean_return, st.success_rate), |e| {
            (e.mean_return, e.success_rate)
        });
        let phase = if eval.is_some() {
            RetrainPhase::Evaluating
        } else {
            RetrainPhase::Training
        };
        let _ = self
            .progress
            .send_copy(progress(req, phase, st.steps, ret, succ, t0, 0));
        if self.node.wait(Duration::ZERO).is_err() {
            // SIGINT/SIGTERM: stop training; the request loop exits.
            *stop_requested = true;
            return false;
        }
        self.drain(newer);
        // A repeat of the request in training is not a new one.
        if newer.is_some_and(|n| n.request_id == req.request_id) {
            *newer = None;
        }
        newer.is_none()
    }

    /// Publishes the retraining's best policy (with the served task hash) and the final
    /// progress message, and prints a JSON line.
    fn publish(
        &self,
        req: &RetrainRequest,
        sum: &RunSummary,
        before: &EvalResult,
        out_dir: &Path,
        t0: Instant,
    ) -> Result<(), ServeError> {
        let best = Checkpoint::load(&out_dir.join(checkpoint::BEST))?;
        let id = policy_id_for(&best);
        let mut ck = best.clone();
        ck.meta.task_hash = self.hash;
        let builder = export::builder(&ck, id);
        // Written in place in shared memory: no stack copy of the ~320 KB blob.
        let mut sample = services::loan_zeroed(&self.blobs)
            .map_err(|e| ServeError::Shm(format!("loan: {e:?}")))?;
        builder.write_into(sample.payload_mut())?;
        sample
            .send()
            .map_err(|e| ServeError::Shm(format!("send: {e:?}")))?;
        let e = best.meta.eval.unwrap_or_default();
        let phase = if sum.stop == StopReason::Converged {
            RetrainPhase::Published
        } else {
            RetrainPhase::BudgetExhausted
        };
        let msg = progress(req, phase, sum.steps, e.mean_return, e.success_rate, t0, id);
        let _ = self.progress.send_copy(msg);
        if sum.stop == StopReason::Converged {
            tracing::info!(
                request = req.request_id,
                policy_id = id,
                steps = sum.steps,
                wall_s = sum.wall_s,
                success = e.success_rate,
                "converged; policy published"
            );
        } else {
            tracing::warn!(request = req.request_id, policy_id = id, steps = sum.steps, wall_s = sum.wall_s, success = e.success_rate, stop = ?sum.stop, "budget exhausted before the success rule was met; best policy published anyway");
        }
        println!(
            "{}",
            serde_json::json!({"request_id": req.request_id, "policy_id": id, "stop": format!("{:?}", sum.stop), "steps": sum.steps, "wall_s": sum.wall_s, "before": before, "best": best.meta.eval})
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::{CheckpointMeta, FORMAT, StatsState};
    use crate::net::NetSpec;
    use crate::normalize::ObsNormalizer;
    use crate::ppo::PpoConfig;
    use crate::random::RngState;

    fn assets() -> std::path::PathBuf {
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    /// The `learner serve` defaults (`cli/serve.rs`), with a step budget for tests.
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
        let o = retrain_with(
            &base,
            &env,
            scene,
            verdict.path(),
            // Within 49 152 steps: with demonstrations it converges at 12 288; from the base
            // policy alone PPO needs 114 688 (demonstrations off fails this test).
            &settings(DEMOS, 49_152),
            &dir,
            1,
            tch::Device::Cpu,
            |_, _| true,
        )
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

    /// The policy id as it was computed before the shared hasher (FNV-1a written out here).
    fn old_policy_id(ck: &Checkpoint) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |b: &[u8]| {
            for x in b {
                h ^= u64::from(*x);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        for w in &ck.theta {
            eat(&w.to_le_bytes());
        }
        eat(&ck.meta.steps.to_le_bytes());
        eat(&ck.meta.task_hash.to_le_bytes());
        h.max(1)
    }

    #[test]
    fn policy_id_is_unchanged_by_the_shared_fnv_hasher() {
        let stats = StatsState {
            mean: vec![0.0],
            var: vec![1.0],
            count: 1.0,
        };
        let rng = RngState {
            seed: [0; 32],
            stream: 0,
            word_pos: [0, 0],
        };
        let mut ck = Checkpoint {
            meta: CheckpointMeta {
                format: FORMAT.into(),
                spec: NetSpec {
                    obs_dim: 1,
                    act_dim: 1,
                    hidden: vec![1],
                },
                ppo: PpoConfig::default(),
                seed: 1,
                task_hash: 0xfeed_beef_0123_4567,
                steps: 123_456,
                iteration: 0,
                adam_t: 0,
                obs_rms: stats.clone(),
                ret_rms: stats,
                trainer_rng: rng,
                env_rngs: vec![],
                eval: None,
                best_eval: None,
            },
            theta: vec![0.5, -1.25, 3.0e-7, f32::MIN_POSITIVE, -0.0, 1.0e9],
            adam_m: vec![],
            adam_v: vec![],
        };
        assert_eq!(policy_id_for(&ck), old_policy_id(&ck));
        ck.theta.clear();
        ck.meta.steps = 0;
        assert_eq!(policy_id_for(&ck), old_policy_id(&ck));
    }
}
