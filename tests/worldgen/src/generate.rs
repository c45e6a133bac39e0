//! Feasible worlds: a generator's draws, each proven feasible by the twin's planner
//! (`twin::check_feasibility` from the task's start posture); infeasible draws are skipped
//! and reported with their reason.

use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use twin::{Feasibility, FeasibilityConfig, InfeasibleReason, Joints, Scene, TwinEnv};

use crate::draw::{Generator, WorldKind, draw_world};

/// Most draws per world asked for before [`generate`] gives up.
pub const DRAWS_PER_WORLD: usize = 20;

/// One feasible world.
#[derive(Debug, Clone, PartialEq)]
pub struct GeneratedWorld {
    /// Position among the feasible worlds (0-based).
    pub index: usize,
    /// Position among all draws (0-based; infeasible draws included).
    pub draw: usize,
    /// The kind of world.
    pub kind: WorldKind,
    /// The world.
    pub scene: Scene,
    /// The planner's collision-free joint path from the start posture to a safe goal
    /// posture (the proof of feasibility).
    pub path: Vec<Joints>,
    /// Wall time of the feasibility proof (s).
    pub feasibility_s: f64,
}

/// A draw refused as infeasible.
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    /// Position among all draws (0-based).
    pub draw: usize,
    /// The kind of world.
    pub kind: WorldKind,
    /// The world.
    pub scene: Scene,
    /// Why it is infeasible.
    pub reason: InfeasibleReason,
}

/// A generator's feasible worlds.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldSet {
    /// The generator.
    pub generator: Generator,
    /// Its seed.
    pub seed: u64,
    /// The feasible worlds, in draw order.
    pub worlds: Vec<GeneratedWorld>,
    /// The infeasible draws skipped, in draw order.
    pub skipped: Vec<Skipped>,
}

/// Why [`generate`] could not deliver.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GenerateError {
    /// The draw limit ([`DRAWS_PER_WORLD`] per world) was reached first.
    #[error(
        "generator {generator}: only {found} of {wanted} worlds proven feasible after {draws} draws"
    )]
    TooFewFeasible {
        /// The generator.
        generator: Generator,
        /// Worlds asked for.
        wanted: usize,
        /// Feasible worlds found.
        found: usize,
        /// Draws made.
        draws: usize,
    },
    /// The generator found no valid placement for its boxes (the task leaves no room).
    #[error("generator {generator}: no valid placement of its boxes at draw {draw}")]
    NoPlacement {
        /// The generator.
        generator: Generator,
        /// The draw.
        draw: usize,
    },
}

/// The random stream of `generator` for `seed`.
pub fn world_rng(generator: Generator, seed: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(generator.stream());
    rng
}

/// Draws worlds of `generator` from `seed` until `n` are proven feasible by
/// `twin::check_feasibility(env, world, start, cfg)` (start: the task's start posture).
/// Same `env`, generator, seed, `n` and `cfg` ⇒ the same worlds (as long as the planner's
/// `cfg.planner.max_time_s` does not cut a search short: its node budget is deterministic).
///
/// # Errors
/// [`GenerateError`] when `n` feasible worlds are not found within `n ×`
/// [`DRAWS_PER_WORLD`] draws, or the boxes cannot be placed at all.
///
/// # Performance
/// Tens of ms per feasible world with an easy path; an infeasible draw may take the
/// planner's whole budget.
pub fn generate(
    env: &TwinEnv,
    generator: Generator,
    seed: u64,
    n: usize,
    cfg: FeasibilityConfig,
) -> Result<WorldSet, GenerateError> {
    let mut rng = world_rng(generator, seed);
    let start = env.config().start.joints_rad;
    let mut set = WorldSet {
        generator,
        seed,
        worlds: Vec::with_capacity(n),
        skipped: Vec::new(),
    };
    let limit = n.saturating_mul(DRAWS_PER_WORLD).max(DRAWS_PER_WORLD);
    let mut draw = 0;
    while set.worlds.len() < n {
        if draw >= limit {
            return Err(GenerateError::TooFewFeasible {
                generator,
                wanted: n,
                found: set.worlds.len(),
                draws: draw,
            });
        }
        let (kind, scene) = draw_world(generator, env, &mut rng)
            .ok_or(GenerateError::NoPlacement { generator, draw })?;
        let t0 = Instant::now();
        match twin::check_feasibility(env, &scene, &start, cfg) {
            Feasibility::Feasible { path, .. } => set.worlds.push(GeneratedWorld {
                index: set.worlds.len(),
                draw,
                kind,
                scene,
                path,
                feasibility_s: t0.elapsed().as_secs_f64(),
            }),
            Feasibility::Infeasible(reason) => set.skipped.push(Skipped {
                draw,
                kind,
                scene,
                reason,
            }),
        }
        draw += 1;
    }
    Ok(set)
}
