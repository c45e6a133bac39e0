//! The warm start of a retraining: the feasibility planner's path demonstrated (re-tracked
//! in the twin, [`crate::demonstrations`]) on the reported scene and jittered variants of it,
//! then cloned into the actor ([`crate::ppo::bc`]) before PPO fine-tunes it.

use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use twin::{Joints, Scene, check_goal_postures};

use super::RetrainSettings;
use crate::demonstrations::{demonstrate, retrack_noisy};
use crate::env::Env;
use crate::ppo::bc::{BcConfig, BcReport, BcSet, behaviour_clone, policy_pairs};
use crate::ppo::{EvalResult, Trainer};
use crate::twin_env::{CurriculumSampler, RetrainSampler, TwinTask, fixed_scenes, jittered};

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
    /// Scenes whose demonstration follows a via-point route (no planner path re-tracked).
    pub via_routes: usize,
    /// Steps of the reported scene's demonstration (0 without one).
    pub reported_steps: usize,
    /// The cloning (absent when nothing was demonstrated).
    pub bc: Option<BcReport>,
    /// The cloned policy's evaluation (reported scene and kept scenes) before PPO.
    pub after_bc: Option<EvalResult>,
    /// Wall time of planning, re-tracking and cloning (s).
    pub wall_s: f64,
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
pub(super) fn warm_start(
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
        let d = demonstrate(
            &env.env,
            env.approval(),
            sc,
            first,
            s.feasibility,
            DEMO_TRIES,
            obs_dim,
        );
        out.paths_tried += d.paths_tried;
        out.via_routes += usize::from(d.via_point);
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
