//! The retraining service (`learner serve`): the iceoryx2 node around the retraining recipe
//! ([`crate::retrain`]). It subscribes to [`RetrainRequest`]s; for each, first checks that
//! the world is feasible (a safe goal posture from many IK seeds, a collision-free
//! joint-space path to it: `twin::feasibility`) and answers [`RetrainPhase::Infeasible`]
//! with the reason when not; otherwise runs one [`RetrainJob`] from the current base
//! checkpoint with the check's path, publishes [`RetrainProgress`] along the way and the
//! best policy as a validated [`PolicyBlob`] at the end. Requests that arrive during
//! training are coalesced: the running training is abandoned and the latest request is
//! trained instead. The next request resumes from this one's result.
//!
//! The command-line flags behind [`ServiceConfig`] and [`RetrainSettings`] are documented
//! in `learner serve --help`.

use shm_schemas::error_chain::error_chain;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{LoanError, SendError};
use iceoryx2::prelude::ipc;
use shm_schemas::services::{self, NodeCreateError, ShmOpenError};
use shm_schemas::{PolicyBlob, PolicyBuildError, RetrainPhase, RetrainProgress, RetrainRequest};
use twin::{Feasibility, FeasibilityConfig, Scene, check_feasibility};

use crate::checkpoint::{self, Checkpoint, CheckpointError};
use crate::export::{self, policy_id_for};
use crate::ppo::{EvalResult, IterStats};
use crate::retrain::{
    RetrainJob, RetrainSettings, infeasible_progress, next_height_start, progress,
};
use crate::run::{RunSummary, StopReason};
use crate::twin_env::{TaskLoadError, TwinTask};

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
    /// Hold each retrained policy this long before publishing it (a test aid: a slow
    /// learner, as on a slower machine), s; 0 = none.
    pub publish_delay_s: f64,
}

/// Why the service could not be set up or publish (per-request retraining failures are
/// logged and the service carries on).
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The task or robot model could not be loaded.
    #[error(transparent)]
    Task(#[from] TaskLoadError),
    /// A checkpoint could not be read.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The policy could not be packed into a blob.
    #[error("policy blob")]
    Blob(#[from] PolicyBuildError),
    /// The iceoryx2 node could not be created.
    #[error("iceoryx2 node")]
    Node(#[from] NodeCreateError),
    /// A port (requests, policies, progress) could not be opened.
    #[error("iceoryx2")]
    Open(#[from] ShmOpenError),
    /// No shared-memory sample could be loaned for a policy.
    #[error("iceoryx2 loan")]
    Loan(#[from] LoanError),
    /// A policy could not be sent.
    #[error("iceoryx2 send")]
    Send(#[from] SendError),
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
        let (node, _) = services::create_node::<ipc::Service>("learner")?;
        let requests = services::open_subscriber::<RetrainRequest, _>(&node, &cfg.prefix)?;
        let blobs = services::open_publisher::<PolicyBlob, _>(&node, &cfg.prefix)?;
        let progress = services::open_publisher::<RetrainProgress, _>(&node, &cfg.prefix)?;
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
        let res = RetrainJob {
            base: &base,
            env: &self.env,
            scene,
            planner_path: verdict.path(),
            settings: &self.settings,
            out_dir: &out_dir,
            eval_seed: req.request_id,
            device: self.device,
        }
        .run(|st, eval| self.on_iter(req, st, eval, t0, &mut newer, &mut stop_requested));
        let (sum, before) = match res {
            Ok(o) => (o.summary, o.before),
            Err(e) => {
                tracing::error!(
                    request = req.request_id,
                    "retraining failed: {}",
                    error_chain(&e)
                );
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
        if self.cfg.publish_delay_s > 0.0 {
            tracing::info!(
                request = req.request_id,
                delay_s = self.cfg.publish_delay_s,
                "holding the retrained policy before publishing it (--publish-delay-s)"
            );
            // The node's wait returns early with an error on SIGINT/SIGTERM.
            if self
                .node
                .wait(Duration::from_secs_f64(self.cfg.publish_delay_s))
                .is_err()
            {
                return Ok(Handled::Stop);
            }
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
        let mut sample = services::loan_zeroed(&self.blobs)?;
        builder.write_into(sample.payload_mut())?;
        sample.send()?;
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
