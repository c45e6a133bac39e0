//! One distillation run (`learner distil`): load the task and the checkpoint to start from,
//! draw the worlds ([`DistilWorlds`]), find their teachers ([`lessons`]), run DAgger
//! ([`distil`]) with an evaluation on the fixed pre-training scenes after each iteration, and
//! keep `best.ckpt` (best success, ties broken by fewer contacts: [`better`]), `last.ckpt` and
//! `distil.json` in the output folder, all written atomically.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use shm_schemas::ActionSpace;
use twin::{FeasibilityConfig, Scene};

use super::{
    DistilConfig, DistilIter, DistilWorlds, Lesson, LessonCounts, dagger_pairs, distil, lessons,
};
use crate::checkpoint::{self, Checkpoint, CheckpointError};
use crate::env::SceneSampler;
use crate::net::ActorCritic;
use crate::ppo::{EvalResult, Trainer, TrainerBuildError};
use crate::run::better;
use crate::twin_env::{CurriculumSampler, EVAL_SEED, TaskLoadError, TwinTask, fixed_scenes};

/// Seed family of the distillation worlds (distinct from the evaluation scenes' and from every
/// benchmark generator's).
const WORLD_SEED_BASE: u64 = 0xD157_0000;

/// Seed family of the joint-step network's observation statistics (the teachers' episodes
/// before the first iteration).
const STATS_SEED: u64 = 0x5747_0000;

/// The summary file written beside the checkpoints.
pub const SUMMARY: &str = "distil.json";

/// One distillation: where from, what, where to (each field is the `learner distil` flag of
/// the same name, see `--help`).
#[derive(Debug, Clone, PartialEq)]
pub struct DistilJob {
    /// The policy to start from (checkpoint file or run directory); its network shape and
    /// observation statistics are kept.
    pub checkpoint: PathBuf,
    /// Task configuration.
    pub task: PathBuf,
    /// Worlds drawn from the task's `[world]` sampler.
    pub worlds: usize,
    /// Share of the worlds drawn from the harder variants of `[world]`.
    pub harder_share: f64,
    /// Hidden layer widths of the distilled network (`None`: the checkpoint's); another shape
    /// starts from fresh weights with the checkpoint's observation statistics.
    pub hidden: Option<Vec<usize>>,
    /// DAgger iterations, noise and cloning.
    pub config: DistilConfig,
    /// Margin the teachers keep from every box (m).
    pub margin_m: f64,
    /// Evaluation scenes of the pre-training distribution (fixed set).
    pub eval_episodes: usize,
    /// Seed (worlds, noise, minibatches; the trainer's for a fresh network).
    pub seed: u64,
    /// Threads that find the teachers.
    pub threads: usize,
    /// Output directory.
    pub out: PathBuf,
    /// The action space the distilled policy acts in. The paper's Cartesian step keeps the
    /// checkpoint's network; the joint step (another network: 29 observations, 5 actions)
    /// starts from fresh weights of the checkpoint's (or `hidden`) shape, its observation
    /// statistics taken from the teachers' own episodes, and records the space in its
    /// checkpoints (and so in its blob).
    pub action_space: ActionSpace,
}

/// What a distillation reports while it runs (for a progress display).
#[derive(Debug, Clone, Copy)]
pub enum DistilEvent<'a> {
    /// The teachers of this many worlds are being searched (the longest quiet part).
    FindingTeachers {
        /// Worlds drawn.
        worlds: usize,
    },
    /// The teachers were found.
    TeachersFound {
        /// Worlds with and without a teacher, by kind.
        counts: &'a LessonCounts,
    },
    /// One DAgger iteration ended and was evaluated (its checkpoints are written).
    Iteration(&'a DistilRecord),
}

/// One DAgger iteration and its evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DistilRecord {
    /// The iteration.
    #[serde(flatten)]
    pub iter: DistilIter,
    /// The policy on the fixed pre-training scenes after it.
    pub eval: EvalResult,
    /// Wall time since the start of the run (s).
    pub elapsed_s: f64,
}

/// Everything a distillation reports (`distil.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DistilSummary {
    /// The checkpoint started from.
    pub checkpoint: PathBuf,
    /// The distilled policy's action space (`cartesian_step`, `joint_step`).
    pub action_space: &'static str,
    /// Worlds with and without a teacher.
    pub worlds: LessonCounts,
    /// The DAgger configuration.
    pub config: DistilConfig,
    /// The starting policy on the fixed pre-training scenes.
    pub before: EvalResult,
    /// Every iteration.
    pub iterations: Vec<DistilRecord>,
    /// The iteration kept as `best.ckpt` (`None`: none ran).
    pub best_iteration: Option<usize>,
    /// Its evaluation.
    pub best: EvalResult,
    /// Wall time of the teacher search (s).
    pub teachers_s: f64,
    /// Wall time of the whole run (s).
    pub wall_s: f64,
}

/// Why a distillation failed.
#[derive(Debug, thiserror::Error)]
pub enum DistilJobError {
    /// The task or robot model could not be loaded.
    #[error(transparent)]
    Task(#[from] TaskLoadError),
    /// The checkpoint to start from could not be loaded.
    #[error("checkpoint {}", .path.display())]
    Load {
        /// The checkpoint file.
        path: PathBuf,
        /// Why.
        #[source]
        source: CheckpointError,
    },
    /// The checkpoint was trained on another task.
    #[error(
        "checkpoint {} was trained on task hash {checkpoint_hash:#x}, {} has {task_hash:#x}",
        .checkpoint.display(), .task.display()
    )]
    TaskMismatch {
        /// The checkpoint file.
        checkpoint: PathBuf,
        /// Its task hash.
        checkpoint_hash: u64,
        /// The task file.
        task: PathBuf,
        /// The task's hash.
        task_hash: u64,
    },
    /// The trainer could not be built (invalid PPO configuration or network shape).
    #[error(transparent)]
    Trainer(#[from] TrainerBuildError),
    /// No world drawn has a teacher: nothing to distil.
    #[error("no world of the {worlds} drawn has a teacher")]
    NoTeacher {
        /// Worlds drawn.
        worlds: usize,
    },
    /// The output folder could not be created.
    #[error("output folder {}", .path.display())]
    Output {
        /// The folder.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The checkpoint does not restore into the trainer, or a checkpoint or the summary could
    /// not be written.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The summary could not be encoded.
    #[error("{SUMMARY}")]
    Json(#[from] serde_json::Error),
}

impl DistilJob {
    /// Runs the distillation; `on_event` sees its progress.
    ///
    /// # Errors
    /// [`DistilJobError`]: task, checkpoint or output failures, or no world with a teacher.
    pub fn run(
        &self,
        device: tch::Device,
        mut on_event: impl FnMut(DistilEvent<'_>),
    ) -> Result<DistilSummary, DistilJobError> {
        let t0 = Instant::now();
        let mut env = TwinTask::load(&self.task, None)?;
        env.set_action_space(self.action_space);
        let hash = env.task_hash();
        let path = checkpoint::resolve(&self.checkpoint);
        let ck = Checkpoint::load(&path).map_err(|source| DistilJobError::Load {
            path: path.clone(),
            source,
        })?;
        if ck.meta.task_hash != hash {
            return Err(DistilJobError::TaskMismatch {
                checkpoint: path,
                checkpoint_hash: ck.meta.task_hash,
                task: self.task.clone(),
                task_hash: hash,
            });
        }
        let mut trainer = self.trainer(&ck, &env, device)?;
        let sampler = CurriculumSampler::pretraining(&env);
        let eval_scenes = fixed_scenes(&sampler, self.eval_episodes, EVAL_SEED);
        let before = trainer.evaluate(&eval_scenes);

        let mut rng = ChaCha8Rng::seed_from_u64(WORLD_SEED_BASE ^ self.seed);
        let mix = DistilWorlds::new(&env, self.harder_share);
        let worlds: Vec<Scene> = (0..self.worlds).map(|_| mix.sample(&mut rng)).collect();
        on_event(DistilEvent::FindingTeachers {
            worlds: worlds.len(),
        });
        let (lessons, counts) = lessons(
            &env.env,
            env.approval(),
            &worlds,
            FeasibilityConfig::default(),
            self.margin_m,
            self.threads,
        );
        let teachers_s = t0.elapsed().as_secs_f64();
        tracing::info!(?counts, teachers_s, "teachers found");
        on_event(DistilEvent::TeachersFound { counts: &counts });
        if lessons.is_empty() {
            return Err(DistilJobError::NoTeacher {
                worlds: self.worlds,
            });
        }

        if self.action_space != ck.meta.action_space() {
            self.teachers_statistics(&mut trainer, &env, &lessons);
        }
        let norm = trainer.obs_normalizer();

        std::fs::create_dir_all(&self.out).map_err(|source| DistilJobError::Output {
            path: self.out.clone(),
            source,
        })?;
        // The network is taken out of the trainer while it is cloned into, so that the
        // trainer's other state (statistics, configuration) can be read for the checkpoints
        // meanwhile.
        let spec = trainer.net.spec.clone();
        let mut net = std::mem::replace(&mut trainer.net, ActorCritic::new(spec, device, 0));
        let mut records: Vec<DistilRecord> = Vec::new();
        let mut best: Option<(usize, EvalResult)> = None;
        let mut save_err: Option<CheckpointError> = None;
        distil(
            &mut net,
            &norm,
            &env.env,
            &lessons,
            &self.config,
            self.seed,
            |net, it| {
                let eval = crate::ppo::evaluate(
                    net,
                    &norm,
                    &env,
                    &eval_scenes,
                    trainer.cfg.effective_workers(),
                );
                let record = DistilRecord {
                    iter: *it,
                    eval,
                    elapsed_s: t0.elapsed().as_secs_f64(),
                };
                records.push(record);
                let is_best = best.is_none_or(|(_, b)| better(&eval, &b));
                if let Err(e) = save(net, &trainer, &ck, hash, &self.out, is_best, eval) {
                    save_err = Some(e);
                    return false;
                }
                if is_best {
                    best = Some((it.iteration, eval));
                }
                on_event(DistilEvent::Iteration(&record));
                true
            },
        );
        trainer.net = net;
        if let Some(e) = save_err {
            return Err(e.into());
        }
        let summary = DistilSummary {
            checkpoint: path,
            action_space: self.action_space.name(),
            worlds: counts,
            config: self.config,
            before,
            iterations: records,
            best_iteration: best.map(|b| b.0),
            best: best.map(|b| b.1).unwrap_or_default(),
            teachers_s,
            wall_s: t0.elapsed().as_secs_f64(),
        };
        let json = serde_json::to_string_pretty(&summary)?;
        checkpoint::write_atomic(&self.out.join(SUMMARY), json.as_bytes())?;
        Ok(summary)
    }

    /// A fresh network of another observation layout than the checkpoint's gets its
    /// statistics from the teachers' own episodes (the states the first iteration clones on).
    fn teachers_statistics(
        &self,
        trainer: &mut Trainer<TwinTask>,
        env: &TwinTask,
        lessons: &[Lesson],
    ) {
        let (set, _) = dagger_pairs(
            &trainer.net,
            &trainer.obs_normalizer(),
            &env.env,
            lessons,
            1.0,
            self.config.noise_std,
            &mut ChaCha8Rng::seed_from_u64(STATS_SEED ^ self.seed),
        );
        trainer.obs_rms.update(&set.obs);
    }

    /// The trainer whose network is distilled into: the checkpoint's, or a fresh one of the
    /// asked shape with the checkpoint's statistics, or in the joint-step space a fresh one
    /// of the asked (or the checkpoint's) shape with fresh statistics.
    fn trainer(
        &self,
        ck: &Checkpoint,
        env: &TwinTask,
        device: tch::Device,
    ) -> Result<Trainer<TwinTask>, DistilJobError> {
        if self.action_space != ck.meta.action_space() {
            let mut cfg = ck.meta.ppo.clone();
            if let Some(h) = &self.hidden {
                cfg.hidden.clone_from(h);
            }
            return Ok(Trainer::new(cfg, env.clone(), self.seed, device)?);
        }
        Ok(match &self.hidden {
            Some(h) if *h != ck.meta.spec.hidden => {
                let mut cfg = ck.meta.ppo.clone();
                cfg.hidden.clone_from(h);
                let mut t = Trainer::new(cfg, env.clone(), self.seed, device)?;
                t.obs_rms = ck.meta.obs_rms.to_rms();
                t.ret_rms = ck.meta.ret_rms.to_rms();
                t
            }
            _ => {
                let mut t = Trainer::new(ck.meta.ppo.clone(), env.clone(), ck.meta.seed, device)?;
                ck.restore(&mut t)?;
                t
            }
        })
    }
}

/// Writes `last.ckpt` (and `best.ckpt` when `is_best`) for the network `net` with the base
/// checkpoint's trainer state (and the trainer's action space: [`Checkpoint::capture`]).
fn save(
    net: &ActorCritic,
    trainer: &Trainer<TwinTask>,
    base: &Checkpoint,
    hash: u64,
    out: &Path,
    is_best: bool,
    eval: EvalResult,
) -> Result<(), CheckpointError> {
    let mut ck = Checkpoint::capture(trainer, base.meta.seed, hash);
    ck.theta = net.flat();
    ck.meta.eval = Some(eval);
    ck.meta.best_eval = Some(eval);
    ck.save(&out.join(checkpoint::LAST))?;
    if is_best {
        ck.save(&out.join(checkpoint::BEST))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    fn job(worlds: usize, out: &Path) -> DistilJob {
        DistilJob {
            checkpoint: assets().join("policy"),
            task: assets().join("task.toml"),
            worlds,
            harder_share: 0.5,
            hidden: None,
            config: DistilConfig {
                iterations: 2,
                bc: crate::ppo::bc::BcConfig {
                    steps: 5,
                    ..DistilConfig::default().bc
                },
                ..DistilConfig::default()
            },
            margin_m: 0.02,
            eval_episodes: 4,
            seed: 3,
            threads: 2,
            out: out.to_path_buf(),
            action_space: ActionSpace::CartesianStep,
        }
    }

    #[test]
    fn a_run_keeps_best_last_and_its_summary_and_reports_each_step_in_order() {
        tch::set_num_threads(1);
        let out = std::env::temp_dir().join(format!("learner-distil-job-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let mut events = Vec::new();
        let summary = job(4, &out)
            .run(tch::Device::Cpu, |e| {
                events.push(match e {
                    DistilEvent::FindingTeachers { worlds } => format!("finding {worlds}"),
                    DistilEvent::TeachersFound { .. } => "found".to_owned(),
                    DistilEvent::Iteration(r) => format!("iteration {}", r.iter.iteration),
                });
            })
            .expect("distillation");
        assert_eq!(
            events,
            ["finding 4", "found", "iteration 0", "iteration 1"],
            "{summary:?}"
        );
        assert_eq!(summary.iterations.len(), 2);
        assert!(summary.best_iteration.is_some());
        for f in [checkpoint::BEST, checkpoint::LAST] {
            let ck = Checkpoint::load(&out.join(f)).expect("a checkpoint");
            assert!(ck.meta.eval.is_some(), "{f}");
        }
        let written: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join(SUMMARY)).expect(SUMMARY))
                .expect("JSON");
        assert_eq!(written["iterations"].as_array().map(Vec::len), Some(2));
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn no_world_means_no_teacher_and_nothing_written() {
        let out = std::env::temp_dir().join(format!("learner-distil-none-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let err = job(0, &out)
            .run(tch::Device::Cpu, |_| {})
            .expect_err("nothing to distil");
        assert!(
            matches!(err, DistilJobError::NoTeacher { worlds: 0 }),
            "{err}"
        );
        assert!(!out.exists());
    }

    #[test]
    fn a_checkpoint_of_another_task_is_refused_by_its_hash() {
        let dir = std::env::temp_dir().join(format!("learner-distil-task-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch");
        // The bundled task with one setting changed: another hash.
        let text = std::fs::read_to_string(assets().join("task.toml")).expect("task");
        let changed = text.replacen("max_steps", "max_steps = 199 #", 1);
        assert_ne!(changed, text, "the task file has no max_steps to change");
        std::fs::write(dir.join("task.toml"), changed).expect("task copy");
        std::fs::copy(assets().join("xarm5.urdf"), dir.join("xarm5.urdf")).expect("model");
        let mut j = job(1, &dir.join("out"));
        j.task = dir.join("task.toml");
        let err = j.run(tch::Device::Cpu, |_| {}).expect_err("another task");
        assert!(matches!(err, DistilJobError::TaskMismatch { .. }), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
