//! Distilling the feasibility planner into the generalist (issue 26, deliverable 3): DAgger
//! over worlds of the task's **own** `[world]` sampler, so that the pre-trained policy starts
//! from a skill ("go around what is in the way") instead of from whatever PPO found.
//!
//! Each training world gets a *teacher* ([`Lesson`]): the scripted straight line when it
//! reaches the goal with no contact (the simplest expert, and one that labels every state
//! the same way), otherwise the pure-pursuit expert ([`crate::demonstrations::PathExpert`])
//! along the shortest clean TCP route through one via point, otherwise along a planner path
//! that re-tracks cleanly. Teachers plan with the boxes grown by a margin (2 cm) where the
//! world allows it, so that a student a little off their way is still clear. Worlds
//! without a teacher are skipped (infeasible, or nothing clean found) and counted.
//!
//! One DAgger iteration rolls the current policy out on every lesson, executing the
//! teacher's action with probability `beta` (1 in the first iteration: the teacher's own
//! episodes), with Gaussian action noise, and labels **every visited state** with the
//! teacher's action there; the pairs are added to the data set and the actor is cloned on
//! all of it ([`crate::ppo::bc::behaviour_clone`]). The policy thus learns the corrections
//! from the states its own mistakes lead to, not only the teacher's states. With a positive
//! [`DistilConfig::hinge_weight`] the cloning also penalises mean actions whose predicted
//! clearance to the nearest box (or the table) after the step falls below
//! [`DistilConfig::hinge_margin_m`] ([`ClearanceHinge`], issue 31).
//!
//! Measured on generators that share no code with this one (the benchmark's, under
//! `tests/`: `unseen-worlds --generator all`); figures in the README ("Independent world
//! generators").
//!
//! In the joint-step space (`--action-space joint_step`, issue 40 item 3) the teachers are
//! the joint straight line and pure pursuit along the planner's joint path to the goal
//! posture the twin chooses ([`joint`]); the rest is the same.
//!
//! [`DistilJob`] is one whole run (`learner distil`): teachers, DAgger, evaluation and the
//! checkpoints.
//!
//! Training code: it allocates and is not for the real-time cycle.

mod job;
pub mod joint;

pub use job::{DistilEvent, DistilJob, DistilJobError, DistilRecord, DistilSummary, SUMMARY};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use shm_schemas::ActionSpace;
use tch::Tensor;
use twin::{
    FeasibilityConfig, JOINT_ACT_DIM, JointLinePolicy, OBS_DIM, Scene, StraightLinePolicy, TwinEnv,
    check_feasibility, rollout,
};

use crate::demonstrations::{PathExpert, demonstrate, via_point_route};
use crate::env::SceneSampler;
use crate::net::ActorCritic;
use crate::normalize::ObsNormalizer;
use crate::ppo::bc::{BcConfig, BcReport, BcSet, ClearanceHinge, behaviour_clone};
use crate::random::randn;
use crate::twin_env::{CurriculumSampler, TwinTask, step_in_space};
use joint::JointPathExpert;
use twin::approval::ApprovalSettings;

/// Planner paths tried per world before it is skipped ([`demonstrate`]).
const PATH_TRIES: usize = 6;

/// Episodes stepped together (one batched forward pass of the actor per step).
const LOCKSTEP: usize = 256;

/// Who labels a world's states.
#[derive(Debug, Clone)]
pub enum Teacher {
    /// The scripted straight line (it reaches this world's goal with no contact).
    Line(StraightLinePolicy),
    /// Pure pursuit along a TCP route through one via point that reaches the goal with no
    /// contact (shortest such route of a fixed grid).
    Via(PathExpert),
    /// Pure pursuit along a planner path that re-tracks to the goal with no contact.
    Path(PathExpert),
    /// Joint-step space: the joint straight line to the goal posture (it reaches this
    /// world's goal with no contact).
    JointLine(JointLinePolicy),
    /// Joint-step space: pure pursuit along the planner's joint path to the goal posture.
    JointPath(JointPathExpert),
}

impl Teacher {
    /// The teacher's action in `env`'s current state, whose observation is `obs` (raw, full
    /// length), into `out` (the teacher's space's action length: 3 Cartesian, 5 joint).
    ///
    /// # Panics
    /// When `out` is shorter than that.
    pub fn action_into(&mut self, env: &TwinEnv, obs: &[f32; OBS_DIM], out: &mut [f32]) {
        match self {
            Self::Line(line) => out[..3].copy_from_slice(&line.act(obs)),
            Self::Via(expert) | Self::Path(expert) => {
                let t = env.tcp_m();
                out[..3].copy_from_slice(&expert.action(&[t.x, t.y, t.z]));
            }
            Self::JointLine(line) => out[..JOINT_ACT_DIM].copy_from_slice(&line.act(obs)),
            Self::JointPath(expert) => {
                out[..JOINT_ACT_DIM].copy_from_slice(&expert.action(&env.joints()));
            }
        }
    }

    fn restart(&mut self) {
        match self {
            Self::Via(expert) | Self::Path(expert) => expert.restart(),
            Self::JointPath(expert) => expert.restart(),
            Self::Line(_) | Self::JointLine(_) => {}
        }
    }
}

/// A training world and its teacher.
#[derive(Debug, Clone)]
pub struct Lesson {
    /// The world.
    pub scene: Scene,
    /// Its teacher.
    pub teacher: Teacher,
}

/// How the worlds drawn for [`lessons`] were taught.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct LessonCounts {
    /// Worlds drawn.
    pub worlds: usize,
    /// Taught by the straight line.
    pub line: usize,
    /// Taught by a route through a via point.
    pub via: usize,
    /// Taught by a planner path.
    pub planner: usize,
    /// Taught with the margin (the rest: planned in the world as it is).
    pub with_margin: usize,
    /// Skipped: no safe way found by the feasibility check.
    pub infeasible: usize,
    /// Skipped: no via-point route, and no planner path re-tracked cleanly in
    /// `PATH_TRIES` tries.
    pub no_clean_path: usize,
}

/// Samplers of the distillation worlds besides the task's own `[world]`: the same sampler
/// with its ranges pushed toward harder worlds, `[crowded, tall]` — crowded: 3 boxes of
/// 0.15 m up to the task's tallest; tall: 1–3 boxes of 0.20 m up to the tallest with
/// footprints up to 0.14 m. In both, boxes placed "anywhere" may also stand beside and
/// just in front of the base (x from 0, |y| up to 0.55 m), where a tall box meets the
/// arm's links rather than its TCP. Both keep the task's placements (on the path, beside
/// the goal, walls, anywhere); nothing here comes from the benchmark's generators under
/// `tests/`.
/// `None` when the task has no `[world]`.
pub fn harder_world_envs(env: &TwinEnv) -> Option<[TwinEnv; 2]> {
    let world = env.config().world?;
    let hi = world.height_m[1];
    let variant = |f: &dyn Fn(&mut twin::WorldConfig)| {
        let mut cfg = *env.config();
        let mut w = world;
        w.x_m = [w.x_m[0].min(0.0), w.x_m[1]];
        w.y_m = [w.y_m[0].min(-0.55), w.y_m[1].max(0.55)];
        f(&mut w);
        cfg.world = Some(w);
        TwinEnv::new(env.model().clone(), cfg)
    };
    let crowded = variant(&|w| {
        w.boxes = [3.max(w.boxes[0]), 3.max(w.boxes[1])];
        w.height_m = [0.15f64.min(hi), hi];
    });
    let tall = variant(&|w| {
        w.height_m = [0.20f64.min(hi), hi];
        w.footprint_m = [w.footprint_m[0], w.footprint_m[1].max(0.14)];
    });
    Some([crowded, tall])
}

/// The distillation's world distribution: the task's pre-training sampler, and with
/// probability `harder_share` one of the [`harder_world_envs`] (each half of that share).
/// Also what `learner pretrain --harder-share` fine-tunes on.
#[derive(Debug, Clone)]
pub struct DistilWorlds {
    base: CurriculumSampler,
    harder: Option<[TwinEnv; 2]>,
    harder_share: f64,
}

impl DistilWorlds {
    /// The mix for `task` (the task's sampler alone when it has no `[world]` or the share
    /// is 0).
    pub fn new(task: &TwinTask, harder_share: f64) -> Self {
        Self {
            base: CurriculumSampler::pretraining(task),
            harder: harder_world_envs(&task.env),
            harder_share: harder_share.clamp(0.0, 1.0),
        }
    }
}

impl SceneSampler<Scene> for DistilWorlds {
    fn sample(&self, rng: &mut ChaCha8Rng) -> Scene {
        match &self.harder {
            // No draw at all without a harder share, so that `learner pretrain` without
            // `--harder-share` sees the very scenes it saw before the mix existed.
            Some([crowded, tall])
                if self.harder_share > 0.0 && rng.random::<f64>() < self.harder_share =>
            {
                if rng.random::<bool>() {
                    crowded.sample_world(rng)
                } else {
                    tall.sample_world(rng)
                }
            }
            _ => self.base.sample(rng),
        }
    }
}

/// `scene` with every box grown by `margin_m` on each side and on top (its bottom stays on
/// the table).
pub fn inflated(scene: &Scene, margin_m: f64) -> Scene {
    let mut s = *scene;
    for b in s.obstacles.iter_mut() {
        b.size_m[0] += 2.0 * margin_m;
        b.size_m[1] += 2.0 * margin_m;
        b.size_m[2] += margin_m;
        b.center_m[2] += margin_m / 2.0;
    }
    s
}

/// Why a world gets no teacher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Untaught {
    /// The feasibility check found no safe way.
    Infeasible,
    /// No via-point route and no planner path that re-tracks cleanly.
    NoCleanPath,
}

/// The teacher of `scene` (in `env`'s action space), planned with the boxes grown by `margin_m` (so that a student a
/// little off the teacher's way is still clear), or without the margin when the grown world
/// has no teacher; whether the margin was kept.
fn lesson(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scene: &Scene,
    cfg: FeasibilityConfig,
    obs_dim: usize,
    margin_m: f64,
) -> Result<(Lesson, bool), Untaught> {
    let grown = inflated(scene, margin_m);
    let mut last = Err(Untaught::Infeasible);
    for (plan_in, with_margin) in [(&grown, true), (scene, false)] {
        if !with_margin && margin_m == 0.0 {
            break;
        }
        let found = match env.action_space() {
            ActionSpace::CartesianStep => teacher(env, approval, plan_in, cfg, obs_dim),
            ActionSpace::JointStep => joint::joint_teacher(env, approval, scene, plan_in, cfg),
        };
        match found {
            Ok(teacher) => {
                return Ok((
                    Lesson {
                        scene: *scene,
                        teacher,
                    },
                    with_margin,
                ));
            }
            Err(why) => last = Err(why),
        }
    }
    last
}

/// The straight line if it is clean in `scene`, else the shortest clean route through one
/// via point, else a planner path that re-tracks cleanly. The via-point routes come before the
/// planner's paths because they label alike worlds alike (the randomised planner's paths
/// go around either side), which the student can imitate (adversarial worlds 85 % instead
/// of 75 % zero-shot, README).
fn teacher(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scene: &Scene,
    cfg: FeasibilityConfig,
    obs_dim: usize,
) -> Result<Teacher, Untaught> {
    let mut tw = env.clone();
    let line = tw.straight_line_policy();
    let straight = rollout(&mut tw, scene, |o| line.act(o), None);
    if straight.success && straight.safe {
        return Ok(Teacher::Line(line));
    }
    tw.reset(scene);
    let t = tw.target_m();
    let goal_m = [t.x, t.y, t.z];
    if let Some(via) = via_point_route(env, scene, goal_m) {
        return Ok(Teacher::Via(via.expert));
    }
    let start = env.config().start.joints_rad;
    let verdict = check_feasibility(env, scene, &start, cfg);
    if !verdict.is_feasible() {
        return Err(Untaught::Infeasible);
    }
    let out = demonstrate(
        env,
        approval,
        scene,
        verdict.path(),
        cfg,
        PATH_TRIES,
        obs_dim,
    );
    let demo = out.demonstration.ok_or(Untaught::NoCleanPath)?;
    Ok(Teacher::Path(PathExpert::new(env, &demo.path, goal_m)))
}

/// A teacher for each of `scenes` that has one (see the module docs; planned with the boxes
/// grown by `margin_m` where that is feasible), in order, worked out on `threads` threads,
/// and how the worlds were taught. A planner path's demonstration counts only when rt-core
/// would approve it (with `approval`, rt-core's settings: [`demonstrate`]).
pub fn lessons(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scenes: &[Scene],
    cfg: FeasibilityConfig,
    margin_m: f64,
    threads: usize,
) -> (Vec<Lesson>, LessonCounts) {
    let obs_dim = env.obs_dim();
    let threads = threads.max(1);
    let chunk = scenes.len().div_ceil(threads).max(1);
    let results: Vec<Vec<Result<(Lesson, bool), Untaught>>> = std::thread::scope(|s| {
        let handles: Vec<_> = scenes
            .chunks(chunk)
            .map(|part| {
                s.spawn(move || {
                    part.iter()
                        .map(|sc| lesson(env, approval, sc, cfg, obs_dim, margin_m))
                        .collect()
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    });
    let mut counts = LessonCounts {
        worlds: scenes.len(),
        ..Default::default()
    };
    let mut out = Vec::with_capacity(scenes.len());
    for r in results.into_iter().flatten() {
        match r {
            Ok((l, with_margin)) => {
                counts.with_margin += usize::from(with_margin);
                match l.teacher {
                    Teacher::Line(_) | Teacher::JointLine(_) => counts.line += 1,
                    Teacher::Via(_) => counts.via += 1,
                    Teacher::Path(_) | Teacher::JointPath(_) => counts.planner += 1,
                }
                out.push(l);
            }
            Err(Untaught::Infeasible) => counts.infeasible += 1,
            Err(Untaught::NoCleanPath) => counts.no_clean_path += 1,
        }
    }
    (out, counts)
}

/// Settings of [`distil`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DistilConfig {
    /// DAgger iterations (the first one is the teachers' own episodes).
    pub iterations: usize,
    /// Probability of executing the teacher's action in the second iteration; it halves in
    /// each one after.
    pub beta: f64,
    /// Action noise (std, action units) on every executed action.
    pub noise_std: f32,
    /// The cloning after each iteration (on all pairs so far).
    pub bc: BcConfig,
    /// Weight of the cloning's collision hinge ([`ClearanceHinge`]: the clearance predicted
    /// after the actor's mean action kept above [`Self::hinge_margin_m`]; 0: off).
    pub hinge_weight: f64,
    /// Margin of the collision hinge (m).
    pub hinge_margin_m: f64,
}

impl Default for DistilConfig {
    /// 6 iterations, beta 0.5, noise 0.2, 3 000 cloning steps of 512 rows at lr 1e-3.
    fn default() -> Self {
        Self {
            iterations: 6,
            beta: 0.5,
            noise_std: 0.2,
            bc: BcConfig {
                steps: 3000,
                batch: 512,
                lr: 1e-3,
                demo_share: 1.0,
                max_grad_norm: 1.0,
                hinge: None,
            },
            hinge_weight: DEFAULT_HINGE_WEIGHT,
            hinge_margin_m: DEFAULT_HINGE_MARGIN_M,
        }
    }
}

/// Default weight of the cloning's collision hinge ([`DistilConfig::hinge_weight`]).
pub const DEFAULT_HINGE_WEIGHT: f64 = 0.0;

/// Default margin of the cloning's collision hinge ([`DistilConfig::hinge_margin_m`]).
pub const DEFAULT_HINGE_MARGIN_M: f64 = 0.03;

/// Index of the closest robot point in the twin's observation (see the `twin` crate docs).
const OBS_ROBOT_POINT: usize = 11;

/// Index of the closest point of the nearest box (or the table) in the twin's observation.
const OBS_OBSTACLE_POINT: usize = 14;

impl DistilConfig {
    /// The cloning settings with the collision hinge for `env` (its action scale), when the
    /// hinge weight is positive and `env` is in the Cartesian space (the hinge predicts the
    /// clearance after a TCP step; the joint-step space has none).
    pub fn bc_for(&self, env: &TwinEnv) -> BcConfig {
        let cartesian = env.action_space() == ActionSpace::CartesianStep;
        BcConfig {
            hinge: (self.hinge_weight > 0.0 && cartesian).then(|| ClearanceHinge {
                weight: self.hinge_weight,
                margin_m: self.hinge_margin_m,
                action_scale_m: env.config().action.scale_m,
                robot_point_at: OBS_ROBOT_POINT,
                obstacle_point_at: OBS_OBSTACLE_POINT,
            }),
            ..self.bc
        }
    }
}

impl DistilConfig {
    /// The teacher's share of executed actions in iteration `it` (0-based).
    pub fn beta_at(&self, it: usize) -> f64 {
        if it == 0 {
            1.0
        } else {
            self.beta * 0.5f64.powi(it as i32 - 1)
        }
    }
}

/// What one batch of DAgger episodes did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EpisodeCounts {
    /// Episodes.
    pub episodes: usize,
    /// Reached the goal with no contact.
    pub reached: usize,
    /// Ended in contact.
    pub contact: usize,
    /// Labelled states.
    pub pairs: usize,
}

/// One DAgger pass: every lesson's episode with the policy `net` (mean action) or, with
/// probability `beta` per step, the teacher's action, plus `noise_std` Gaussian noise;
/// every visited state labelled with the teacher's action.
pub fn dagger_pairs(
    net: &ActorCritic,
    norm: &ObsNormalizer,
    env: &TwinEnv,
    lessons: &[Lesson],
    beta: f64,
    noise_std: f32,
    rng: &mut ChaCha8Rng,
) -> (BcSet, EpisodeCounts) {
    let d = env.obs_dim();
    let a_dim = env.action_space().act_dim();
    let mut set = BcSet::default();
    let mut counts = EpisodeCounts::default();
    let dev = net.device();
    for group in lessons.chunks(LOCKSTEP) {
        let mut envs: Vec<TwinEnv> = group.iter().map(|_| env.clone()).collect();
        let mut teachers: Vec<Teacher> = group.iter().map(|l| l.teacher.clone()).collect();
        let mut obs: Vec<[f32; OBS_DIM]> = Vec::with_capacity(group.len());
        for ((e, l), t) in envs.iter_mut().zip(group).zip(&mut teachers) {
            obs.push(e.reset(&l.scene));
            t.restart();
        }
        let mut alive: Vec<usize> = (0..group.len()).collect();
        let mut x = Vec::with_capacity(group.len() * d);
        let mut means = vec![0.0f32; group.len() * a_dim];
        let mut row = vec![0.0f32; d];
        let mut label = vec![0.0f32; a_dim];
        let mut act = vec![0.0f32; a_dim];
        while !alive.is_empty() {
            x.clear();
            for &i in &alive {
                norm.apply(&obs[i][..d], &mut row);
                x.extend_from_slice(&row);
            }
            let m = alive.len();
            let out = tch::no_grad(|| {
                net.actor_mean(
                    &Tensor::from_slice(&x)
                        .view([m as i64, d as i64])
                        .to_device(dev),
                )
                .to_device(tch::Device::Cpu)
            });
            out.view([-1]).copy_data(&mut means[..m * a_dim], m * a_dim);
            let mut next = Vec::with_capacity(m);
            for (k, &i) in alive.iter().enumerate() {
                teachers[i].action_into(&envs[i], &obs[i], &mut label);
                set.extend(&obs[i][..d], &label);
                if rng.random::<f64>() < beta {
                    act.copy_from_slice(&label);
                } else {
                    act.copy_from_slice(&means[k * a_dim..(k + 1) * a_dim]);
                }
                for v in &mut act {
                    *v = (*v + noise_std * randn(rng)).clamp(-1.0, 1.0);
                }
                let step = step_in_space(&mut envs[i], &act);
                obs[i] = step.obs;
                if step.terminated || step.truncated {
                    counts.episodes += 1;
                    counts.reached += usize::from(step.task_done && step.safe);
                    counts.contact += usize::from(!step.safe);
                } else {
                    next.push(i);
                }
            }
            alive = next;
        }
    }
    counts.pairs = set.len(d);
    (set, counts)
}

/// What one iteration of [`distil`] did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DistilIter {
    /// Iteration (0-based).
    pub iteration: usize,
    /// Teacher's share of executed actions.
    pub beta: f64,
    /// The DAgger episodes.
    pub episodes: EpisodeCounts,
    /// Pairs in the data set after it.
    pub total_pairs: usize,
    /// The cloning.
    pub bc: BcReport,
}

/// DAgger: `cfg.iterations` passes of [`dagger_pairs`] over `lessons`, each followed by
/// cloning `net`'s actor on all pairs so far. `after_iter` sees each iteration (to evaluate
/// and keep the best policy); returning `false` stops early.
pub fn distil(
    net: &mut ActorCritic,
    norm: &ObsNormalizer,
    env: &TwinEnv,
    lessons: &[Lesson],
    cfg: &DistilConfig,
    seed: u64,
    mut after_iter: impl FnMut(&ActorCritic, &DistilIter) -> bool,
) -> Vec<DistilIter> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut data = BcSet::default();
    let mut iters = Vec::with_capacity(cfg.iterations);
    let bc_cfg = cfg.bc_for(env);
    for it in 0..cfg.iterations {
        let beta = cfg.beta_at(it);
        let (pairs, episodes) =
            dagger_pairs(net, norm, env, lessons, beta, cfg.noise_std, &mut rng);
        data.extend(&pairs.obs, &pairs.actions);
        let bc = behaviour_clone(net, norm, &data, &BcSet::default(), &bc_cfg, &mut rng);
        let rec = DistilIter {
            iteration: it,
            beta,
            episodes,
            total_pairs: data.len(env.obs_dim()),
            bc,
        };
        tracing::info!(
            iteration = it,
            beta,
            reached = episodes.reached,
            contact = episodes.contact,
            pairs = rec.total_pairs,
            loss = bc.demo_loss_after,
            hinge = bc.hinge_loss_after,
            "distillation iteration"
        );
        iters.push(rec);
        if !after_iter(net, &rec) {
            break;
        }
    }
    iters
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::checkpoint::Checkpoint;
    use shm_schemas::scene_file::SceneFile;

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    fn task() -> TwinTask {
        TwinTask::load(&assets().join("task.toml"), None).expect("task")
    }

    fn scene(name: &str) -> Scene {
        let file = SceneFile::load(&assets().join("scenes").join(name)).expect("scene file");
        Scene::from_file(&file).expect("scene")
    }

    /// Runs `teacher` from the start of `scene`: (reached with no contact, steps).
    fn teach(env: &TwinEnv, scene: &Scene, teacher: &Teacher) -> (bool, usize) {
        let mut tw = env.clone();
        let mut t = teacher.clone();
        t.restart();
        let mut obs = tw.reset(scene);
        let mut action = vec![0.0f32; env.action_space().act_dim()];
        for k in 0..env.config().episode.max_steps as usize {
            t.action_into(&tw, &obs, &mut action);
            let out = step_in_space(&mut tw, &action);
            obs = out.obs;
            if out.terminated || out.truncated {
                return (out.task_done && out.safe, k + 1);
            }
        }
        (false, env.config().episode.max_steps as usize)
    }

    #[test]
    fn without_a_harder_share_the_mix_is_the_tasks_own_sampler_draw_for_draw() {
        let t = task();
        let own = CurriculumSampler::pretraining(&t);
        let mix = DistilWorlds::new(&t, 0.0);
        let (mut a, mut b) = (ChaCha8Rng::seed_from_u64(9), ChaCha8Rng::seed_from_u64(9));
        for _ in 0..20 {
            let (x, y) = (own.sample(&mut a), mix.sample(&mut b));
            assert_eq!(x.goal, y.goal);
            assert_eq!(x.obstacles.len(), y.obstacles.len());
            for (p, q) in x.obstacles.iter().zip(y.obstacles.iter()) {
                assert_eq!((p.center_m, p.size_m), (q.center_m, q.size_m));
            }
        }
        // With the share, some worlds come from the harder variants (3 boxes or taller).
        let harder = DistilWorlds::new(&t, 1.0);
        let mut c = ChaCha8Rng::seed_from_u64(9);
        let tall = (0..20)
            .map(|_| harder.sample(&mut c))
            .filter(|w| w.obstacles.iter().any(|o| o.height_m() >= 0.15))
            .count();
        assert!(
            tall >= 15,
            "{tall} of 20 harder worlds have a box of 0.15 m or more"
        );
    }

    #[test]
    fn grown_boxes_keep_their_bottom_on_the_table() {
        let s = scene("tall_box.toml");
        let g = inflated(&s, 0.02);
        assert_eq!(g.obstacles.len(), s.obstacles.len());
        for (a, b) in s.obstacles.iter().zip(g.obstacles.iter()) {
            assert!((b.size_m[0] - a.size_m[0] - 0.04).abs() < 1e-12);
            assert!((b.size_m[1] - a.size_m[1] - 0.04).abs() < 1e-12);
            assert!((b.size_m[2] - a.size_m[2] - 0.02).abs() < 1e-12);
            let bottom = |o: &twin::BoxObstacle| o.center_m[2] - o.size_m[2] / 2.0;
            assert!((bottom(a) - bottom(b)).abs() < 1e-12);
        }
        assert_eq!(inflated(&s, 0.0).obstacles[0].size_m, s.obstacles[0].size_m);
    }

    #[test]
    fn the_tall_box_is_taught_around_the_box_and_a_free_table_by_the_line() {
        let t = task();
        let mut free = scene("tall_box.toml");
        free.obstacles.clear();
        let worlds = [scene("tall_box.toml"), free];
        let (lessons, counts) = lessons(
            &t.env,
            t.approval(),
            &worlds,
            FeasibilityConfig::default(),
            0.02,
            2,
        );
        assert_eq!(lessons.len(), 2, "{counts:?}");
        assert_eq!(counts.worlds, 2);
        assert_eq!(counts.line, 1, "{counts:?}");
        assert_eq!(counts.via + counts.planner, 1, "{counts:?}");
        // In order: the tall box needs a way around (the straight line runs into it).
        assert!(!matches!(lessons[0].teacher, Teacher::Line(_)));
        assert!(matches!(lessons[1].teacher, Teacher::Line(_)));
        for l in &lessons {
            let (clean, steps) = teach(&t.env, &l.scene, &l.teacher);
            assert!(
                clean,
                "the teacher of {:?} did not reach the goal cleanly",
                l.scene.goal
            );
            assert!(steps > 1);
        }
        // The free table is taught with the margin (the tall box leaves too little room
        // for it and is taught as it is).
        assert!(counts.with_margin >= 1, "{counts:?}");
    }

    #[test]
    fn dagger_labels_every_visited_state_with_the_teachers_action() {
        let t = task();
        let ck = Checkpoint::load(&assets().join("policy/best.ckpt")).expect("bundled policy");
        let net = ck.network(tch::Device::Cpu).expect("network");
        let norm = ObsNormalizer::from_stats(&ck.meta.obs_rms.to_rms(), ck.meta.ppo.clip_obs);
        let (lessons, _) = lessons(
            &t.env,
            t.approval(),
            &[scene("tall_box.toml")],
            FeasibilityConfig::default(),
            0.02,
            1,
        );
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // beta 1, no noise: the teacher's own episode, every step labelled.
        let (set, counts) = dagger_pairs(&net, &norm, &t.env, &lessons, 1.0, 0.0, &mut rng);
        let (clean, steps) = teach(&t.env, &lessons[0].scene, &lessons[0].teacher);
        assert!(clean);
        assert_eq!(counts.episodes, 1);
        assert_eq!(counts.reached, 1);
        assert_eq!(counts.pairs, steps);
        let d = t.env.config().obs_dim();
        assert_eq!(set.len(d), steps);
        assert_eq!(set.actions.len(), steps * twin::ACT_DIM);
        // beta 0: the bundled policy drives (it runs into the tall box) and is still
        // labelled with the teacher's actions, which differ from its own.
        let (set0, counts0) = dagger_pairs(&net, &norm, &t.env, &lessons, 0.0, 0.0, &mut rng);
        assert_eq!(counts0.contact, 1, "{counts0:?}");
        let own = crate::ppo::bc::policy_pairs(&net, &norm, &t, &[lessons[0].scene]);
        assert_eq!(set0.obs, own.obs[..set0.obs.len()]);
        assert_ne!(set0.actions, own.actions[..set0.actions.len()]);
    }

    #[test]
    fn distillation_fits_the_teachers_and_reports_each_iteration() {
        let t = task();
        let ck = Checkpoint::load(&assets().join("policy/best.ckpt")).expect("bundled policy");
        let mut net = ck.network(tch::Device::Cpu).expect("network");
        let norm = ObsNormalizer::from_stats(&ck.meta.obs_rms.to_rms(), ck.meta.ppo.clip_obs);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let worlds: Vec<Scene> = (0..12).map(|_| t.env.sample_world(&mut rng)).collect();
        let (lessons, counts) = lessons(
            &t.env,
            t.approval(),
            &worlds,
            FeasibilityConfig::default(),
            0.02,
            2,
        );
        assert_eq!(
            counts.line + counts.via + counts.planner + counts.infeasible + counts.no_clean_path,
            12
        );
        let cfg = DistilConfig {
            iterations: 2,
            bc: BcConfig {
                steps: 150,
                ..DistilConfig::default().bc
            },
            ..DistilConfig::default()
        };
        let mut seen = Vec::new();
        let iters = distil(&mut net, &norm, &t.env, &lessons, &cfg, 3, |_, it| {
            seen.push(it.iteration);
            true
        });
        assert_eq!(seen, [0, 1]);
        assert_eq!(iters[0].beta, 1.0);
        assert_eq!(iters[1].beta, cfg.beta);
        assert!(iters[1].total_pairs > iters[0].total_pairs);
        let bc = iters[0].bc;
        assert!(
            bc.demo_loss_after < 0.5 * bc.demo_loss_before,
            "cloning did not fit the teachers: {bc:?}"
        );
        // Stopping early: the callback's false ends the loop.
        let stopped = distil(&mut net, &norm, &t.env, &lessons, &cfg, 3, |_, _| false);
        assert_eq!(stopped.len(), 1);
    }
}
