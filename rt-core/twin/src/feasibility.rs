//! Feasibility of a reaching task, decided before any training: is there a safe posture
//! of the arm at the goal target point, and a collision-free path to one from the start?
//!
//! [`check_goal_postures`] runs the IK toward the goal target from many deterministic
//! seeds and keeps the postures that pass the task's contact rule (the one of
//! `TwinEnv::step`, see [`is_safe_posture`]); [`plan_path`] searches joint space for a
//! path to them; [`check_feasibility`] combines both. When a world is infeasible,
//! [`InfeasibleReason`] says why in words for an operator, and packs into the bytes of
//! `shm_schemas::RetrainProgress` ([`InfeasibleReason::wire`] / [`InfeasibleReason::from_wire`]).
//!
//! Planning code: it allocates and is not for the real-time cycle.

use std::fmt;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::{BLOCKER_NONE, BLOCKER_SELF, BLOCKER_TABLE, InfeasibleKind};

use super::env::TwinEnv;
use super::geometry::{Distances, RobotGeometry, SELF_COLLISION_MIN_DISTANCE_M};
use super::ik::IkSolver;
use super::kinematics::LinkPoses;
use super::model::{RobotModel, TOOL_FRAME};
use super::planner::{PlanOutcome, PlannerBudget, PostureCheck, contact, plan_path};
use super::scene::{BoxObstacle, Scene};
use super::{DOF, Joints, MAX_OBSTACLES, max_joint_gap_rad};

#[cfg(doc)]
use super::planner::is_safe_posture;

/// IK iterations per seed of the goal-posture check.
pub const GOAL_IK_ITERATIONS: u32 = 200;

/// Most safe goal postures kept by [`check_goal_postures`].
pub const MAX_GOAL_POSTURES: usize = 8;

/// Safe postures closer than this to a kept one (largest joint gap, rad) are duplicates.
pub(crate) const DUPLICATE_GAP_RAD: f64 = 0.1;

/// Seed of the random part of the goal-posture seeds (fixed: the check is deterministic).
const GOAL_SEED_RNG: u64 = 0x00F0_2E51_6470_0001;

/// Link number of the tool in [`InfeasibleReason::NoGoalPosture`] and on the wire.
pub const LINK_TOOL: u8 = 6;

/// Arm shapes `(joint2, joint3, joint4)` (rad) tried with joint 1 aimed at the goal and
/// turned away from it: shoulder back/upright/forward × elbow folded/bent/stretched ×
/// wrist level/pitched down.
const SHAPES_RAD: [[f64; 3]; 18] = {
    let q2 = [-0.9, 0.0, 0.9];
    let q3 = [-2.2, -1.2, -0.3];
    let q4 = [0.3, 1.5];
    let mut out = [[0.0; 3]; 18];
    let mut k = 0;
    while k < 18 {
        out[k] = [q2[k / 6], q3[(k / 2) % 3], q4[k % 2]];
        k += 1;
    }
    out
};

/// A safe posture of the arm at the goal target point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalPosture {
    /// Joints (rad), within the limits.
    pub joints: Joints,
    /// TCP distance to the goal target point (m), within `success.tolerance_m`.
    pub tcp_error_m: f64,
    /// How far inside the safe set the posture is (m): the smallest of (box distance −
    /// `min_box_clearance_m`), (table distance − `min_box_clearance_m`) and (self distance
    /// − [`SELF_COLLISION_MIN_DISTANCE_M`]); infinite with nothing around.
    pub margin_m: f64,
}

/// What blocks the arm in [`InfeasibleReason::NoGoalPosture`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Blocker {
    /// The obstacle box of this index in `Scene::obstacles` (0-based).
    Box(usize),
    /// The table.
    Table,
    /// The arm itself (a self-collision).
    SelfCollision,
}

impl Blocker {
    /// The blocker byte of `RetrainProgress::infeasible_blocker`: the box index,
    /// [`BLOCKER_TABLE`] or [`BLOCKER_SELF`] ([`BLOCKER_NONE`] for an index that does not
    /// fit, which a valid scene never has).
    pub fn wire(self) -> u8 {
        match self {
            Self::Box(i) => u8::try_from(i)
                .ok()
                .filter(|b| usize::from(*b) < MAX_OBSTACLES)
                .unwrap_or(BLOCKER_NONE),
            Self::Table => BLOCKER_TABLE,
            Self::SelfCollision => BLOCKER_SELF,
        }
    }

    /// The inverse of [`Blocker::wire`]; `None` for [`BLOCKER_NONE`] and bytes that name
    /// no box.
    pub fn from_wire(byte: u8) -> Option<Self> {
        match byte {
            BLOCKER_TABLE => Some(Self::Table),
            BLOCKER_SELF => Some(Self::SelfCollision),
            b if usize::from(b) < MAX_OBSTACLES => Some(Self::Box(usize::from(b))),
            _ => None,
        }
    }
}

/// Why a reaching task cannot be done safely.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InfeasibleReason {
    /// No IK seed brings the TCP within `success.tolerance_m` of the goal target point.
    OutOfReach {
        /// Distance from the goal target to the closest TCP position found (m).
        by_m: f64,
    },
    /// The arm reaches the goal target, but every posture found there is in contact.
    NoGoalPosture {
        /// What blocks the posture that came closest to safe.
        blocker: Blocker,
        /// The robot part blocked: 1–5 for link1–link5, [`LINK_TOOL`] (6) for the tool, 0
        /// for the base.
        link: u8,
        /// By how much that posture misses the rule (m): `min_box_clearance_m` minus the
        /// distance for a box or the table, [`SELF_COLLISION_MIN_DISTANCE_M`] minus the
        /// distance for a self-collision.
        deficit_m: f64,
        /// Goal postures tried (IK seeds; 0 when decoded from the wire).
        postures_tried: usize,
    },
    /// Safe goal postures exist, but the planner found no collision-free path to any of
    /// them within its budget (also: the start posture itself is not safe, then `nodes` is
    /// 0).
    NoPath {
        /// Planner tree nodes used (0 when decoded from the wire).
        nodes: usize,
        /// Planner wall time (s; 0 when decoded from the wire).
        elapsed_s: f64,
    },
}

fn wire_m(v: f64) -> f32 {
    if v.is_finite() {
        v.clamp(0.0, f64::from(f32::MAX)) as f32
    } else {
        0.0
    }
}

impl InfeasibleReason {
    /// The kind of reason.
    pub fn kind(&self) -> InfeasibleKind {
        match self {
            Self::OutOfReach { .. } => InfeasibleKind::OutOfReach,
            Self::NoGoalPosture { .. } => InfeasibleKind::NoGoalPosture,
            Self::NoPath { .. } => InfeasibleKind::NoPath,
        }
    }

    /// The reason as `RetrainProgress`'s bytes: `(infeasible_kind, infeasible_blocker,
    /// infeasible_link, infeasible_by_m)`. The blocker is [`BLOCKER_NONE`] and the link 0
    /// except for `NoGoalPosture`; `by_m` is `by_m`, `deficit_m` or 0, never negative.
    pub fn wire(&self) -> (u8, u8, u8, f32) {
        let kind = self.kind() as u8;
        match *self {
            Self::OutOfReach { by_m } => (kind, BLOCKER_NONE, 0, wire_m(by_m)),
            Self::NoGoalPosture {
                blocker,
                link,
                deficit_m,
                ..
            } => (kind, blocker.wire(), link, wire_m(deficit_m)),
            Self::NoPath { .. } => (kind, BLOCKER_NONE, 0, 0.0),
        }
    }

    /// The reason from `RetrainProgress`'s bytes (the inverse of
    /// [`InfeasibleReason::wire`]; `postures_tried`, `nodes` and `elapsed_s` come back 0).
    /// `None` for kind 0 ([`InfeasibleKind::None`]), an unknown kind, a `NoGoalPosture`
    /// without a valid blocker or with a link above 6, or a negative or non-finite `by_m`.
    pub fn from_wire(kind: u8, blocker: u8, link: u8, by_m: f32) -> Option<Self> {
        if !(by_m.is_finite() && by_m >= 0.0) {
            return None;
        }
        match InfeasibleKind::try_from(kind).ok()? {
            InfeasibleKind::None => None,
            InfeasibleKind::OutOfReach => Some(Self::OutOfReach {
                by_m: f64::from(by_m),
            }),
            InfeasibleKind::NoGoalPosture => Some(Self::NoGoalPosture {
                blocker: Blocker::from_wire(blocker)?,
                link: Some(link).filter(|l| *l <= LINK_TOOL)?,
                deficit_m: f64::from(by_m),
                postures_tried: 0,
            }),
            InfeasibleKind::NoPath => Some(Self::NoPath {
                nodes: 0,
                elapsed_s: 0.0,
            }),
        }
    }

    /// The reason in words with the blocking box described (size and position) from
    /// `obstacles` (the scene's boxes; `&[]` for the plain [`fmt::Display`] words).
    pub fn display_with<'a>(&'a self, obstacles: &'a [BoxObstacle]) -> impl fmt::Display + 'a {
        ReasonDisplay {
            reason: self,
            obstacles,
        }
    }
}

struct ReasonDisplay<'a> {
    reason: &'a InfeasibleReason,
    obstacles: &'a [BoxObstacle],
}

fn link_words(link: u8) -> String {
    match link {
        0 => "the base".to_owned(),
        LINK_TOOL => "the tool".to_owned(),
        l => format!("link{l}"),
    }
}

fn length_words(m: f64) -> String {
    let mm = m * 1000.0;
    if mm < 10.0 {
        format!("{mm:.1} mm")
    } else {
        format!("{mm:.0} mm")
    }
}

impl fmt::Display for ReasonDisplay<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self.reason {
            InfeasibleReason::OutOfReach { by_m } => {
                write!(f, "the goal target is {by_m:.2} m beyond the arm's reach")
            }
            InfeasibleReason::NoGoalPosture {
                blocker,
                link,
                deficit_m,
                postures_tried,
            } => {
                let link = link_words(link);
                let by = length_words(deficit_m);
                match blocker {
                    Blocker::Box(i) => {
                        write!(f, "no safe goal posture: box {i}")?;
                        if let Some(b) = self.obstacles.get(i) {
                            let [sx, sy, sz] = b.size_m;
                            let [x, y, _] = b.center_m;
                            write!(f, " ({sx:.2} × {sy:.2} × {sz:.2} m at x {x:.2}, y {y:.2})")?;
                        }
                        write!(f, " blocks {link} by {by}")?;
                    }
                    Blocker::Table => {
                        write!(f, "no safe goal posture: the table blocks {link} by {by}")?;
                    }
                    Blocker::SelfCollision => write!(
                        f,
                        "no safe goal posture: {link} collides with the arm itself by {by}"
                    )?,
                }
                if postures_tried > 0 {
                    write!(f, " in the best of {postures_tried} postures tried")?;
                }
                Ok(())
            }
            InfeasibleReason::NoPath { nodes, elapsed_s } => {
                write!(f, "no collision-free path found to any safe goal posture")?;
                if nodes > 0 {
                    write!(f, " (planner: {nodes} nodes, {elapsed_s:.1} s)")?;
                }
                Ok(())
            }
        }
    }
}

impl fmt::Display for InfeasibleReason {
    /// Plain words for an operator, e.g. "no safe goal posture: box 1 blocks link3 by
    /// 12 mm in the best of 64 postures tried" ([`InfeasibleReason::display_with`] adds
    /// the box's size and position).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.display_with(&[]).fmt(f)
    }
}

/// Result of [`check_goal_postures`].
#[derive(Debug, Clone, PartialEq)]
pub struct GoalPostureCheck {
    /// The goal target point (m).
    pub target_m: [f64; 3],
    /// Safe goal postures, deduplicated, largest margin first, at most
    /// [`MAX_GOAL_POSTURES`]; empty when there is none.
    pub postures: Vec<GoalPosture>,
    /// IK seeds tried.
    pub postures_tried: usize,
    /// Seeds whose IK brought the TCP within `success.tolerance_m` of the target.
    pub postures_reached: usize,
    /// Why there is no safe posture ([`InfeasibleReason::OutOfReach`] or
    /// [`InfeasibleReason::NoGoalPosture`]); `None` when `postures` is not empty.
    pub reason: Option<InfeasibleReason>,
}

/// Settings of [`check_feasibility`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeasibilityConfig {
    /// IK seeds of the goal-posture check.
    pub goal_seeds: usize,
    /// The planner's budget.
    pub planner: PlannerBudget,
}

impl Default for FeasibilityConfig {
    /// 64 seeds, the default [`PlannerBudget`].
    fn default() -> Self {
        Self {
            goal_seeds: 64,
            planner: PlannerBudget::default(),
        }
    }
}

/// Result of [`check_feasibility`].
#[derive(Debug, Clone, PartialEq)]
pub enum Feasibility {
    /// The task can be done safely.
    Feasible {
        /// The safe goal postures found ([`GoalPostureCheck::postures`]).
        goal_postures: Vec<GoalPosture>,
        /// A collision-free joint-space path from the start to one of them
        /// ([`PlanOutcome::Path`]'s waypoints).
        path: Vec<Joints>,
    },
    /// It cannot, and why.
    Infeasible(InfeasibleReason),
}

impl Feasibility {
    /// Whether the task is feasible.
    pub fn is_feasible(&self) -> bool {
        matches!(self, Self::Feasible { .. })
    }

    /// The planner's collision-free joint path from the start to a safe goal posture, when
    /// feasible: the demonstration the learner's retraining starts from
    /// (`learner::demonstrations`).
    pub fn path(&self) -> Option<&[Joints]> {
        match self {
            Self::Feasible { path, .. } => Some(path),
            Self::Infeasible(_) => None,
        }
    }

    /// The reason, when infeasible.
    pub fn reason(&self) -> Option<&InfeasibleReason> {
        match self {
            Self::Feasible { .. } => None,
            Self::Infeasible(r) => Some(r),
        }
    }
}

/// `angle` moved by whole turns next to `reference`, then clamped into `[lo, hi]`.
pub(crate) fn near_turn(angle: f64, reference: f64, lo: f64, hi: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let a = angle - ((angle - reference) / tau).round() * tau;
    a.clamp(lo, hi)
}

/// The IK seeds: the start posture, the start posture aimed at the goal, the
/// [`SHAPES_RAD`] aimed at the goal and turned away from it, then random postures; the
/// first `n`, each within the limits.
fn goal_seeds(model: &RobotModel, target_m: &Vector3<f64>, n: usize) -> Vec<Joints> {
    let limits = model.limits();
    let (lo, hi) = (limits.lower_rad, limits.upper_rad);
    let home = model.home();
    let aim = near_turn(target_m.y.atan2(target_m.x), home[0], lo[0], hi[0]);
    let away = near_turn(aim + std::f64::consts::PI, home[0], lo[0], hi[0]);
    let mut seeds = Vec::with_capacity(n);
    seeds.push(home);
    let mut aimed = home;
    aimed[0] = aim;
    seeds.push(aimed);
    for q1 in [aim, away] {
        for s in SHAPES_RAD {
            seeds.push([q1, s[0], s[1], s[2], home[4]]);
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(GOAL_SEED_RNG);
    while seeds.len() < n {
        let mut q: Joints = std::array::from_fn(|i| lo[i] + (hi[i] - lo[i]) * rng.random::<f64>());
        q[0] = near_turn(
            aim + std::f64::consts::PI * (2.0 * rng.random::<f64>() - 1.0),
            home[0],
            lo[0],
            hi[0],
        );
        q[DOF - 1] = home[DOF - 1];
        seeds.push(q);
    }
    seeds.truncate(n);
    for q in &mut seeds {
        limits.clamp(q);
    }
    seeds
}

/// The worst violation of the contact rule at one posture.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Violation {
    pub(crate) blocker: Blocker,
    pub(crate) link: u8,
    pub(crate) deficit_m: f64,
}

/// The frame of a geometry report as a link number: 1–5, [`LINK_TOOL`] for the tool
/// frame, 0 for the base.
fn link_number(frame: usize) -> u8 {
    if frame == TOOL_FRAME {
        LINK_TOOL
    } else {
        u8::try_from(frame.min(DOF)).unwrap_or(0)
    }
}

pub(crate) struct Classifier<'a> {
    pub(crate) check: PostureCheck<'a>,
    /// The geometry without the tool (when there is one): tells the tool from link5, which
    /// the geometry's box and table reports both give as frame 5.
    tool_free: Option<RobotGeometry>,
}

impl<'a> Classifier<'a> {
    /// The classifier of `scene` under `env`'s task (the contact rule of
    /// [`is_safe_posture`]).
    pub(crate) fn new(env: &'a TwinEnv, scene: &'a Scene) -> Self {
        let model = env.model();
        Self {
            check: PostureCheck::new(env, scene),
            tool_free: model
                .tool()
                .map(|_| RobotGeometry::new(&model.clone().with_tool(None))),
        }
    }

    /// The margin (see [`GoalPosture::margin_m`]) and the worst violation.
    fn classify(&self, q: &Joints) -> (f64, Violation) {
        let c = &self.check;
        let poses = c.model.fk(q);
        let d = c.geometry.all_distances(&poses, c.scene);
        self.classify_at(&poses, &d)
    }

    /// [`Classifier::classify`] on the posture's poses and distances, already computed.
    pub(crate) fn classify_at(&self, poses: &LinkPoses, d: &Distances) -> (f64, Violation) {
        let c = &self.check;
        let part =
            |frame: usize, d_with_tool: f64, without_tool: &dyn Fn(&RobotGeometry) -> f64| {
                match &self.tool_free {
                    Some(g) if frame == DOF && without_tool(g) > d_with_tool + 1e-9 => LINK_TOOL,
                    _ => link_number(frame),
                }
            };
        let mut worst = Violation {
            blocker: Blocker::Table,
            link: part(d.table.link, d.table.distance_m, &|g| {
                g.distance_to_table(poses, c.scene).distance_m
            }),
            deficit_m: c.clearance_m - d.table.distance_m,
        };
        if let Some(b) = d.boxes {
            let deficit_m = c.clearance_m - b.distance_m;
            if deficit_m > worst.deficit_m {
                worst = Violation {
                    blocker: Blocker::Box(b.obstacle.unwrap_or(0)),
                    link: part(b.link, b.distance_m, &|g| {
                        g.distance_to_boxes(poses, c.scene)
                            .map_or(f64::INFINITY, |r| r.distance_m)
                    }),
                    deficit_m,
                };
            }
        }
        let deficit_m = SELF_COLLISION_MIN_DISTANCE_M - d.own.distance_m;
        if deficit_m > worst.deficit_m {
            worst = Violation {
                blocker: Blocker::SelfCollision,
                link: link_number(d.own.links[1]),
                deficit_m,
            };
        }
        let margin_m = -worst.deficit_m;
        // The exact rule decides; the deficit is only the measure.
        if !contact(d, c.clearance_m) {
            worst.deficit_m = 0.0;
        }
        worst.deficit_m = worst.deficit_m.max(0.0);
        (margin_m, worst)
    }
}

/// Searches for safe postures of the arm at the goal target point of `scene`
/// (`scene.goal_target_m(success.goal_hover_m)`): IK ([`GOAL_IK_ITERATIONS`] iterations,
/// the task's IK settings, the null-space pull toward the seed) from `seeds` deterministic
/// seeds; a posture counts when its TCP is within `success.tolerance_m` of the target and
/// it passes `TwinEnv::step`'s contact rule ([`is_safe_posture`]).
///
/// Without a safe posture, [`GoalPostureCheck::reason`] says why: out of reach (no seed's
/// IK gets within tolerance; by the smallest remaining distance) or, from the reached
/// posture closest to safe, what blocks which link by how much.
///
/// # Performance
/// About 0.2 ms per seed (IK) plus one distance query per seed; 64 seeds take a few
/// tens of ms in release.
pub fn check_goal_postures(env: &TwinEnv, scene: &Scene, seeds: usize) -> GoalPostureCheck {
    let cfg = env.config();
    let model = env.model();
    let target = scene.goal_target_m(cfg.success.goal_hover_m);
    let classifier = Classifier::new(env, scene);
    // A copy of the model whose home is the seed: the IK's null-space pull keeps each
    // solution near its own seed, so the seeds give different postures.
    let mut pull_model = model.clone();
    let mut safe: Vec<GoalPosture> = Vec::new();
    let mut best_blocked: Option<Violation> = None;
    let mut closest_m = f64::INFINITY;
    let mut reached = 0;
    let seed_list = goal_seeds(model, &target, seeds.max(1));
    for seed in &seed_list {
        pull_model.set_home(*seed);
        let ik = IkSolver::new(&pull_model, cfg.ik);
        let sol = ik.solve_with(model, &target, seed, GOAL_IK_ITERATIONS);
        let q = sol.joints;
        let error_m = (model.tcp_m(&q) - target).norm();
        closest_m = closest_m.min(error_m);
        if !(error_m <= cfg.success.tolerance_m && model.limits().contains(&q)) {
            continue;
        }
        reached += 1;
        if classifier.check.is_safe(&q) {
            let (margin_m, _) = classifier.classify(&q);
            safe.push(GoalPosture {
                joints: q,
                tcp_error_m: error_m,
                margin_m,
            });
        } else {
            let (_, v) = classifier.classify(&q);
            if best_blocked.is_none_or(|b| v.deficit_m < b.deficit_m) {
                best_blocked = Some(v);
            }
        }
    }
    // Largest margin first (stable: seed order breaks ties), then drop near-duplicates.
    safe.sort_by(|a, b| b.margin_m.total_cmp(&a.margin_m));
    let mut postures: Vec<GoalPosture> = Vec::new();
    for p in safe {
        if postures.len() >= MAX_GOAL_POSTURES {
            break;
        }
        if postures
            .iter()
            .all(|k| max_joint_gap_rad(&k.joints, &p.joints) >= DUPLICATE_GAP_RAD)
        {
            postures.push(p);
        }
    }
    let reason = if !postures.is_empty() {
        None
    } else if let Some(v) = best_blocked {
        Some(InfeasibleReason::NoGoalPosture {
            blocker: v.blocker,
            link: v.link,
            deficit_m: v.deficit_m,
            postures_tried: seed_list.len(),
        })
    } else {
        Some(InfeasibleReason::OutOfReach {
            by_m: if closest_m.is_finite() {
                closest_m
            } else {
                0.0
            },
        })
    };
    GoalPostureCheck {
        target_m: target.into(),
        postures,
        postures_tried: seed_list.len(),
        postures_reached: reached,
        reason,
    }
}

/// Whether the reaching task in `scene` can be done safely from `start`: the
/// goal-posture check ([`check_goal_postures`] with `cfg.goal_seeds` seeds), then the
/// planner ([`plan_path`] with `cfg.planner`) from `start` to the safe goal postures.
///
/// # Performance
/// The goal-posture check takes tens of ms; the planner returns at once in a free scene
/// and within `cfg.planner.max_time_s` otherwise.
pub fn check_feasibility(
    env: &TwinEnv,
    scene: &Scene,
    start: &Joints,
    cfg: FeasibilityConfig,
) -> Feasibility {
    let goals = check_goal_postures(env, scene, cfg.goal_seeds);
    if let Some(reason) = goals.reason {
        return Feasibility::Infeasible(reason);
    }
    let joints: Vec<Joints> = goals.postures.iter().map(|p| p.joints).collect();
    match plan_path(env, scene, start, &joints, cfg.planner) {
        PlanOutcome::Path { path, .. } => Feasibility::Feasible {
            goal_postures: goals.postures,
            path,
        },
        PlanOutcome::NoPath { nodes, elapsed_s } => {
            Feasibility::Infeasible(InfeasibleReason::NoPath { nodes, elapsed_s })
        }
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::{Goal, TaskConfig, ToolConfig};

    fn env_with_tool(tool: Option<ToolConfig>) -> TwinEnv {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).expect("model");
        let mut task = TaskConfig::load(&assets.join("task.toml")).expect("task");
        task.tool = tool;
        TwinEnv::new(model, task)
    }

    #[test]
    fn the_tool_is_told_from_link5() {
        // At home the flange points down, the TCP 0.25 m up: a 10 cm tool (r 3 cm) ends
        // 0.12 m up. A table at 0.13 m is into the tool, not into link5.
        let tool = ToolConfig {
            from_m: [0.0, 0.0, 0.0],
            to_m: [0.0, 0.0, 0.10],
            radius_m: 0.03,
        };
        let goal = Goal {
            center_m: [0.3, 0.2, 0.155],
            size_m: 0.05,
        };
        let scene = Scene::empty(0.13, goal);
        for (tool, link) in [(Some(tool), LINK_TOOL), (None, 5)] {
            let e = env_with_tool(tool);
            let c = Classifier {
                check: PostureCheck::new(&e, &scene),
                tool_free: e
                    .model()
                    .tool()
                    .map(|_| RobotGeometry::new(&e.model().clone().with_tool(None))),
            };
            let home = e.model().home();
            let (margin_m, v) = c.classify(&home);
            if tool.is_some() {
                assert!(!c.check.is_safe(&home));
                assert_eq!((v.blocker, v.link), (Blocker::Table, link), "{v:?}");
                assert!(v.deficit_m > 0.0 && margin_m < 0.0, "{v:?}");
            } else {
                // Without the tool, the lowest part is link5 (or link4), and clear.
                assert!(c.check.is_safe(&home), "{v:?} {margin_m}");
                assert!(margin_m > 0.0);
                assert_eq!(v.deficit_m, 0.0);
                assert!(v.link == link || v.link == 4, "{v:?}");
            }
        }
    }
}
