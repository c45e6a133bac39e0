//! A sampling-based joint-space path planner over the twin's geometry: RRT-Connect
//! (two trees, one from the start, one from every goal posture), edges checked at a fine
//! joint resolution with the task's contact rule, then shortcut-smoothed.
//!
//! Used by the feasibility check ([`super::check_feasibility`]) to decide, before any
//! training, whether the arm can get from its start to a safe goal posture at all. It
//! allocates (trees, paths) and reads the wall clock: planning code, not real-time code.
//!
//! # The rule a configuration must pass
//! The same as `TwinEnv::step`'s contact test ([`is_safe_posture`]): joints within their
//! limits, no self-collision, and every box (any link or the tool) and the table (links
//! 2–5 and the tool) at least `success.min_box_clearance_m` away.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::env::TwinEnv;
use super::geometry::{Distances, RobotGeometry};
use super::model::{JointLimits, RobotModel};
use super::scene::Scene;
use super::{DOF, Joints, max_joint_gap_rad};

/// Longest tree extension of RRT-Connect (rad, Euclidean in joint space).
const EXTEND_STEP_RAD: f64 = 0.3;

/// Shortcut attempts on a found path.
const SHORTCUT_ATTEMPTS: usize = 150;

/// For a joint whose range spans more than a full turn (joints 1 and 5 of the xArm5),
/// samples are drawn within this much of the start's and the goals' values (rad): every
/// direction is still reachable, without exploring a second copy of the same turn.
const WRAP_PAD_RAD: f64 = std::f64::consts::PI;

/// Smallest edge-check resolution accepted (rad); finer values are raised to it.
const MIN_EDGE_STEP_RAD: f64 = 1e-4;

/// Limits of one planner run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannerBudget {
    /// Most tree nodes, both trees together (start and goals included).
    pub max_nodes: usize,
    /// Most wall time (s), smoothing included.
    pub max_time_s: f64,
    /// Seed of the planner's random samples (same seed, same scene → same path, as long
    /// as `max_time_s` does not cut the run short).
    pub seed: u64,
    /// Largest joint change between two checked configurations along an edge (rad).
    pub edge_step_rad: f64,
}

impl Default for PlannerBudget {
    /// 20 000 nodes, 10 s, seed 0, 0.02 rad.
    fn default() -> Self {
        Self {
            max_nodes: 20_000,
            max_time_s: 10.0,
            seed: 0,
            edge_step_rad: 0.02,
        }
    }
}

/// Result of [`plan_path`].
#[derive(Debug, Clone, PartialEq)]
pub enum PlanOutcome {
    /// A collision-free path.
    Path {
        /// Waypoints from the start to a goal (both included, the goal exactly as given);
        /// consecutive waypoints are joined by straight joint-space segments, each checked
        /// at `edge_step_rad` ([`densify_path`] gives the checked configurations).
        path: Vec<Joints>,
        /// Index of the goal reached in the `goals` given.
        goal_index: usize,
        /// Tree nodes used.
        nodes: usize,
        /// Wall time (s).
        elapsed_s: f64,
    },
    /// No path within the budget (or the start is not a safe posture, or no goal is).
    NoPath {
        /// Tree nodes used (0 when the start or every goal is unsafe).
        nodes: usize,
        /// Wall time (s).
        elapsed_s: f64,
    },
}

impl PlanOutcome {
    /// The path, if one was found.
    pub fn path(&self) -> Option<&[Joints]> {
        match self {
            Self::Path { path, .. } => Some(path),
            Self::NoPath { .. } => None,
        }
    }
}

/// Exactly `TwinEnv::step`'s contact test on one set of distances: a self-collision, the
/// table or a box touching or closer than `clearance_m`.
pub(crate) fn contact(d: &Distances, clearance_m: f64) -> bool {
    d.own.colliding()
        || d.table.colliding
        || d.table.distance_m < clearance_m
        || d.boxes
            .is_some_and(|b| b.colliding || b.distance_m < clearance_m)
}

/// The posture test shared by the goal-posture check and the planner.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PostureCheck<'a> {
    pub(crate) model: &'a RobotModel,
    pub(crate) geometry: &'a RobotGeometry,
    pub(crate) scene: &'a Scene,
    pub(crate) clearance_m: f64,
}

impl<'a> PostureCheck<'a> {
    pub(crate) fn new(env: &'a TwinEnv, scene: &'a Scene) -> Self {
        Self {
            model: env.model(),
            geometry: env.geometry(),
            scene,
            clearance_m: env.config().success.min_box_clearance_m,
        }
    }

    pub(crate) fn limits(&self) -> &JointLimits {
        self.model.limits()
    }

    pub(crate) fn distances(&self, q: &Joints) -> Distances {
        self.geometry.all_distances(&self.model.fk(q), self.scene)
    }

    pub(crate) fn is_safe(&self, q: &Joints) -> bool {
        q.iter().all(|v| v.is_finite())
            && self.limits().contains(q)
            && !contact(&self.distances(q), self.clearance_m)
    }

    /// Whether every configuration on the straight segment `a → b` (at most `step_rad`
    /// apart, `b` included, `a` not) is safe.
    fn edge_is_safe(&self, a: &Joints, b: &Joints, step_rad: f64) -> bool {
        let n = edge_steps(a, b, step_rad);
        (1..=n).all(|k| self.is_safe(&lerp(a, b, k as f64 / n as f64)))
    }
}

/// Whether `q` is a safe posture in `scene` by `TwinEnv::step`'s rule: joints within
/// their limits, no self-collision, every box and (links 2–5, the tool) the table at least
/// `success.min_box_clearance_m` away.
pub fn is_safe_posture(env: &TwinEnv, scene: &Scene, q: &Joints) -> bool {
    PostureCheck::new(env, scene).is_safe(q)
}

fn edge_steps(a: &Joints, b: &Joints, step_rad: f64) -> usize {
    let gap = max_joint_gap_rad(a, b);
    let n = (gap / step_rad.max(MIN_EDGE_STEP_RAD)).ceil();
    if n.is_finite() && n >= 1.0 {
        n as usize
    } else {
        1
    }
}

fn lerp(a: &Joints, b: &Joints, t: f64) -> Joints {
    std::array::from_fn(|i| a[i] + (b[i] - a[i]) * t)
}

fn dist2(a: &Joints, b: &Joints) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// `path` with every segment cut into pieces of at most `max_step_rad` per joint: the
/// configurations the planner checked (for `max_step_rad = edge_step_rad`).
pub fn densify_path(path: &[Joints], max_step_rad: f64) -> Vec<Joints> {
    let mut out = Vec::with_capacity(path.len());
    if let Some(first) = path.first() {
        out.push(*first);
    }
    for w in path.windows(2) {
        let n = edge_steps(&w[0], &w[1], max_step_rad);
        out.extend((1..=n).map(|k| lerp(&w[0], &w[1], k as f64 / n as f64)));
    }
    out
}

#[derive(Debug, Clone, Copy)]
struct Node {
    q: Joints,
    parent: Option<u32>,
}

#[derive(Debug, Default)]
struct Tree {
    nodes: Vec<Node>,
}

enum Extend {
    Trapped,
    Advanced(u32),
    Reached(u32),
}

impl Tree {
    fn nearest(&self, q: &Joints) -> u32 {
        let mut best = (f64::INFINITY, 0);
        for (i, n) in self.nodes.iter().enumerate() {
            let d = dist2(&n.q, q);
            if d < best.0 {
                best = (d, i);
            }
        }
        best.1 as u32
    }

    fn push(&mut self, q: Joints, parent: Option<u32>) -> u32 {
        self.nodes.push(Node { q, parent });
        (self.nodes.len() - 1) as u32
    }

    /// Root-to-node configurations, root first; and the root's index.
    fn branch(&self, mut i: u32) -> (Vec<Joints>, u32) {
        let mut out = Vec::new();
        loop {
            let n = &self.nodes[i as usize];
            out.push(n.q);
            match n.parent {
                Some(p) => i = p,
                None => break,
            }
        }
        out.reverse();
        (out, i)
    }
}

struct Rrt<'a> {
    check: PostureCheck<'a>,
    lower: Joints,
    upper: Joints,
    edge_step_rad: f64,
    rng: ChaCha8Rng,
}

impl Rrt<'_> {
    fn sample(&mut self) -> Joints {
        std::array::from_fn(|i| {
            self.lower[i] + (self.upper[i] - self.lower[i]) * self.rng.random::<f64>()
        })
    }

    /// One step of `tree` from its node nearest to `target` toward it.
    fn extend(&self, tree: &mut Tree, target: &Joints) -> Extend {
        let near = tree.nearest(target);
        let q_near = tree.nodes[near as usize].q;
        let d = dist2(&q_near, target).sqrt();
        let (q_new, reached) = if d <= EXTEND_STEP_RAD {
            (*target, true)
        } else {
            (lerp(&q_near, target, EXTEND_STEP_RAD / d), false)
        };
        if !self.check.edge_is_safe(&q_near, &q_new, self.edge_step_rad) {
            return Extend::Trapped;
        }
        let i = tree.push(q_new, Some(near));
        if reached {
            Extend::Reached(i)
        } else {
            Extend::Advanced(i)
        }
    }
}

/// Joint bounds for sampling: the limits, and for a joint turning more than a full turn
/// the start's and goals' values ± [`WRAP_PAD_RAD`] within them.
fn sampling_bounds(limits: &JointLimits, start: &Joints, goals: &[Joints]) -> (Joints, Joints) {
    let mut lower = limits.lower_rad;
    let mut upper = limits.upper_rad;
    for i in 0..DOF {
        if upper[i] - lower[i] > std::f64::consts::TAU {
            let lo = goals.iter().map(|g| g[i]).fold(start[i], f64::min);
            let hi = goals.iter().map(|g| g[i]).fold(start[i], f64::max);
            lower[i] = (lo - WRAP_PAD_RAD).max(limits.lower_rad[i]);
            upper[i] = (hi + WRAP_PAD_RAD).min(limits.upper_rad[i]);
        }
    }
    (lower, upper)
}

/// Plans a collision-free joint-space path from `start` to any of `goals` in `scene`:
/// RRT-Connect, every edge checked at `budget.edge_step_rad` with the task's contact rule
/// ([`is_safe_posture`]), the result shortcut-smoothed. Goals that are not safe postures
/// are skipped; a start that is not one gives [`PlanOutcome::NoPath`] with 0 nodes.
///
/// Deterministic for a given `budget.seed` unless `budget.max_time_s` cuts the run short.
///
/// # Performance
/// A configuration check is one FK and one distance query (a few µs); nearest neighbours
/// are a linear scan. A direct start–goal segment is tried first.
pub fn plan_path(
    env: &TwinEnv,
    scene: &Scene,
    start: &Joints,
    goals: &[Joints],
    budget: PlannerBudget,
) -> PlanOutcome {
    let t0 = Instant::now();
    let elapsed_s = || t0.elapsed().as_secs_f64();
    let check = PostureCheck::new(env, scene);
    let goal_ids: Vec<usize> = (0..goals.len())
        .filter(|&i| check.is_safe(&goals[i]))
        .collect();
    if !check.is_safe(start) || goal_ids.is_empty() {
        return PlanOutcome::NoPath {
            nodes: 0,
            elapsed_s: elapsed_s(),
        };
    }
    let edge_step_rad = if budget.edge_step_rad.is_finite() && budget.edge_step_rad > 0.0 {
        budget.edge_step_rad.max(MIN_EDGE_STEP_RAD)
    } else {
        PlannerBudget::default().edge_step_rad
    };
    // A NaN limit counts as used up.
    let out_of_time = |t: f64| t >= budget.max_time_s || budget.max_time_s.is_nan();

    // The direct segment first (an empty scene needs no tree).
    for &g in &goal_ids {
        if check.edge_is_safe(start, &goals[g], edge_step_rad) {
            return PlanOutcome::Path {
                path: vec![*start, goals[g]],
                goal_index: g,
                nodes: 1 + goal_ids.len(),
                elapsed_s: elapsed_s(),
            };
        }
    }

    let safe_goals: Vec<Joints> = goal_ids.iter().map(|&g| goals[g]).collect();
    let (lower, upper) = sampling_bounds(check.limits(), start, &safe_goals);
    let mut rrt = Rrt {
        check,
        lower,
        upper,
        edge_step_rad,
        rng: ChaCha8Rng::seed_from_u64(budget.seed),
    };
    let mut from_start = Tree::default();
    from_start.push(*start, None);
    let mut from_goals = Tree::default();
    for g in &safe_goals {
        from_goals.push(*g, None);
    }
    // `a` grows toward the sample, `b` connects to it; they swap every iteration.
    let mut a_is_start = true;
    let found = loop {
        let nodes = from_start.nodes.len() + from_goals.nodes.len();
        if nodes >= budget.max_nodes || out_of_time(elapsed_s()) {
            return PlanOutcome::NoPath {
                nodes,
                elapsed_s: elapsed_s(),
            };
        }
        let (a, b) = if a_is_start {
            (&mut from_start, &mut from_goals)
        } else {
            (&mut from_goals, &mut from_start)
        };
        a_is_start = !a_is_start;
        let q_rand = rrt.sample();
        let new_a = match rrt.extend(a, &q_rand) {
            Extend::Trapped => continue,
            Extend::Advanced(i) | Extend::Reached(i) => i,
        };
        let q_new = a.nodes[new_a as usize].q;
        // Connect: b walks toward q_new until it gets there or is stopped.
        let mut reached_b = None;
        while a.nodes.len() + b.nodes.len() < budget.max_nodes {
            match rrt.extend(b, &q_new) {
                Extend::Trapped => break,
                Extend::Advanced(_) => {}
                Extend::Reached(i) => {
                    reached_b = Some(i);
                    break;
                }
            }
        }
        if let Some(new_b) = reached_b {
            // `a_is_start` was flipped above: `a` is the start tree when it is now false.
            break if a_is_start {
                (new_b, new_a)
            } else {
                (new_a, new_b)
            };
        }
    };
    let nodes = from_start.nodes.len() + from_goals.nodes.len();
    let (mut path, _) = from_start.branch(found.0);
    let (mut to_goal, root) = from_goals.branch(found.1);
    // The meeting configuration is in both branches.
    path.pop();
    to_goal.reverse();
    path.extend(to_goal);
    shortcut(&rrt.check, &mut path, edge_step_rad, &mut rrt.rng, || {
        out_of_time(elapsed_s())
    });
    PlanOutcome::Path {
        path,
        goal_index: goal_ids[root as usize],
        nodes,
        elapsed_s: elapsed_s(),
    }
}

/// Random shortcuts: joins two waypoints directly when the segment between them is safe,
/// dropping those in between; removes repeated waypoints first.
fn shortcut(
    check: &PostureCheck<'_>,
    path: &mut Vec<Joints>,
    edge_step_rad: f64,
    rng: &mut ChaCha8Rng,
    mut out_of_time: impl FnMut() -> bool,
) {
    path.dedup();
    for _ in 0..SHORTCUT_ATTEMPTS {
        if path.len() < 3 || out_of_time() {
            return;
        }
        let i = rng.random_range(0..path.len() - 2);
        let j = rng.random_range(i + 2..path.len());
        if check.edge_is_safe(&path[i], &path[j], edge_step_rad) {
            path.drain(i + 1..j);
        }
    }
}
