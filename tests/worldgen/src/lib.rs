//! Independent world generators for the unseen-worlds benchmark (issue 26): worlds drawn by
//! someone other than the training sampler, so that a policy's zero-shot success measures
//! the skill and not the sampler it was trained on.
//!
//! Three generators ([`Generator`]), each seeded and deterministic (a `ChaCha8` stream per
//! generator, so `--seed S` gives each generator its own, reproducible worlds):
//!
//! - [`Generator::Uniform`]: a goal anywhere the task's `[sampling]` goal ranges allow, 1–3
//!   boxes (footprint 0.04–0.12 m, height 0.04–0.40 m) anywhere on the table in reach;
//! - [`Generator::Cluttered`]: 3 tall boxes (0.20–0.40 m), one in each third of the arm's
//!   front workspace;
//! - [`Generator::Adversarial`]: the failure cases of issue 26 — one box standing beside the
//!   start→goal segment, a box on the path plus one beside the goal, a goal near |y| ≈ 0.3 m
//!   with a tall box beside the base, or two tall boxes on the far side of the goal.
//!
//! A world counts only when the twin's planner proves it feasible
//! (`twin::check_feasibility`); [`generate`] draws until it has the worlds asked for and
//! reports the infeasible draws it skipped ([`WorldSet::skipped`]). [`track_path`] re-checks
//! the planner's path at a finer resolution than the planner's (the planner-fallback
//! ceiling of the benchmark).
//!
//! **Independence.** This crate shares no code with the training samplers (the twin's
//! world and scene samplers, the learner's environments): it reads only
//! the task's goal ranges (`TaskConfig::sampling`), the start posture and the twin's
//! geometry queries. It is a benchmark crate: no training code depends on it (a test of the
//! learner checks that).
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use worldgen::{Generator, generate};
//! # let env: twin::TwinEnv = unimplemented!();
//! let set = generate(&env, Generator::Cluttered, 1, 40, twin::FeasibilityConfig::default())?;
//! println!("{} worlds, {} infeasible draws skipped", set.worlds.len(), set.skipped.len());
//! # Ok(()) }
//! ```

#![forbid(unsafe_code)]

mod draw;
mod generate;
mod track;

pub use draw::{
    ADVERSARIAL_KINDS, CLUTTER_HEIGHT_M, FOOTPRINT_M, FRONT_HALF_ANGLE_RAD, GOAL_GAP_M, Generator,
    GoalRanges, TABLE_X_M, TABLE_Y_M, UNIFORM_FOOTPRINT_M, UNIFORM_HEIGHT_M, UnknownGeneratorError,
    WorldKind, draw_world,
};
pub use generate::{
    DRAWS_PER_WORLD, GenerateError, GeneratedWorld, Skipped, WorldSet, generate, world_rng,
};
pub use track::{PathCheck, TRACK_STEP_RAD, track_path};
