//! The goal posture: which of the goal's IK branches the arm should end in
//! ([`choose_goal_posture`], whose docs give the candidates and the order).
//!
//! Planning code beside the feasibility check (it shares its contact rule and its
//! classification of what blocks a posture); it does not allocate.
//!
//! # Example
//! ```no_run
//! use std::path::Path;
//! use shm_schemas::scene_file::SceneFile;
//! use twin::{RobotModel, Scene, TaskConfig, TwinEnv, choose_goal_posture};
//!
//! let model = RobotModel::load(Path::new("assets/xarm5.urdf"))?;
//! let task = TaskConfig::load(Path::new("assets/task.toml"))?;
//! let scene = Scene::from_file(&SceneFile::load(Path::new("assets/scenes/tall_box.toml"))?)?;
//! let env = TwinEnv::new(model, task);
//! let choice = choose_goal_posture(&env, &scene, &env.config().start.joints_rad)?;
//! println!("goal posture {:?} ({:?})", choice.best().joints, choice.best().branch);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::f64::consts::{FRAC_PI_2, FRAC_PI_3, FRAC_PI_6, PI, TAU};

use nalgebra::{Vector2, Vector3};

use super::env::TwinEnv;
use super::feasibility::{Blocker, Classifier, DUPLICATE_GAP_RAD, InfeasibleReason, near_turn};
use super::ik::IkSolver;
use super::model::RobotModel;
use super::planner::contact;
use super::scene::Scene;
use super::{Joints, max_joint_gap_rad};

#[cfg(doc)]
use super::planner::is_safe_posture;

/// IK iterations per candidate (the closed-form candidates need none on the bundled model).
pub const POSTURE_IK_ITERATIONS: u32 = 200;

/// The wrist pitches of the closed-form candidates: the tool axis tilted this much (rad)
/// from straight down, away from the base (negative: toward it).
const WRIST_TILTS_RAD: [f64; 4] = [0.0, FRAC_PI_6, FRAC_PI_3, -FRAC_PI_6];

/// Candidates [`choose_goal_posture`] enumerates: the start seed, then 2 base sides × 2
/// elbows × the wrist pitches.
pub const MAX_BRANCH_POSTURES: usize = 1 + 2 * 2 * WRIST_TILTS_RAD.len();

/// Which side of the base joint 1 points to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BaseSide {
    /// Joint 1 aimed at the goal (within a quarter turn).
    Facing,
    /// Joint 1 turned away from the goal: the arm reaches back over its base.
    Flipped,
}

/// Which side of the shoulder–wrist line the elbow is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Elbow {
    /// Above the line (the bundled start posture's elbow).
    Up,
    /// Below it.
    Down,
}

/// The IK branch of a posture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Branch {
    /// The base side.
    pub base: BaseSide,
    /// The elbow side.
    pub elbow: Elbow,
}

/// A safe posture at the goal target on one branch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BranchPosture {
    /// Joints (rad), within the limits; joint 5 is the start's.
    pub joints: Joints,
    /// Its branch.
    pub branch: Branch,
    /// Joint-space distance from the start posture (Euclidean, rad): the order's key.
    pub distance_rad: f64,
    /// How far inside the contact rule it is (m), as `GoalPosture::margin_m`: the smallest
    /// of box and table distance minus the clearance and self distance minus the
    /// self-collision threshold.
    pub margin_m: f64,
    /// TCP distance to the goal target (m), within `success.tolerance_m`.
    pub tcp_error_m: f64,
}

/// The safe goal postures of a scene, ordered (see [`choose_goal_posture`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PostureChoice {
    /// The goal target point (m).
    pub target_m: [f64; 3],
    /// At least one posture, best first.
    pub postures: heapless::Vec<BranchPosture, MAX_BRANCH_POSTURES>,
    /// Candidates enumerated.
    pub candidates: usize,
    /// Candidates whose closed form left the joint limits.
    pub outside_limits: usize,
    /// Candidates that missed the goal target.
    pub unreachable: usize,
    /// Candidates that broke the contact rule.
    pub blocked: usize,
}

impl PostureChoice {
    /// No posture kept yet, nothing counted.
    fn none_yet(target: &Vector3<f64>) -> Self {
        Self {
            target_m: (*target).into(),
            postures: heapless::Vec::new(),
            candidates: MAX_BRANCH_POSTURES,
            outside_limits: 0,
            unreachable: 0,
            blocked: 0,
        }
    }

    /// The chosen goal posture: the first of [`PostureChoice::postures`].
    pub fn best(&self) -> &BranchPosture {
        // Never empty: `choose_goal_posture` returns an error instead.
        &self.postures[0]
    }
}

/// Why no goal posture can be chosen.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PostureChoiceError {
    /// No candidate within the joint limits brings the TCP within `success.tolerance_m` of
    /// the goal target.
    #[error(
        "no goal posture: the goal target is {by_m:.3} m beyond the arm's reach on every one of \
         the {candidates} IK branches tried"
    )]
    Unreachable {
        /// The smallest remaining distance to the goal target (m).
        by_m: f64,
        /// Candidates tried.
        candidates: usize,
    },
    /// The arm reaches the goal target, but every branch that does breaks the contact rule.
    #[error(
        "{} (every one of the {reached} IK branches that reach the goal target is blocked)",
        InfeasibleReason::NoGoalPosture {
            blocker: *blocker,
            link: *link,
            deficit_m: *deficit_m,
            postures_tried: *candidates,
        }
    )]
    Blocked {
        /// What blocks the branch closest to safe (the box of this index, the table, the
        /// arm itself).
        blocker: Blocker,
        /// The robot part blocked (1–5, `LINK_TOOL` for the tool, 0 for the base).
        link: u8,
        /// By how much that branch misses the rule (m).
        deficit_m: f64,
        /// Candidates that reached the goal target (all blocked).
        reached: usize,
        /// Candidates tried.
        candidates: usize,
    },
}

impl PostureChoiceError {
    /// The same reason as the feasibility check words it and `RetrainProgress` carries it.
    pub fn reason(&self) -> InfeasibleReason {
        match *self {
            Self::Unreachable { by_m, .. } => InfeasibleReason::OutOfReach { by_m },
            Self::Blocked {
                blocker,
                link,
                deficit_m,
                candidates,
                ..
            } => InfeasibleReason::NoGoalPosture {
                blocker,
                link,
                deficit_m,
                postures_tried: candidates,
            },
        }
    }
}

/// The arm in the vertical plane of joint 1: `r` along joint 1's heading, `z` up. The link
/// vector of joint k+1 (k = 2, 3, 4: the next joint's origin, and the TCP for k = 4) in link
/// k's frame has length `len[k-2]` and angle `c[k-2]`; in the plane it points at
/// `-(c + q2 + … + qk)` (the pitch axes are the base's +y at zero joints).
#[derive(Debug, Clone, Copy)]
struct PlanarArm {
    shoulder: Vector2<f64>,
    len: [f64; 3],
    c: [f64; 3],
    /// Angle offset of the tool axis (flange z) in link 4's frame.
    c_tool: f64,
}

impl PlanarArm {
    fn of(model: &RobotModel) -> Self {
        let o = &model.joint_origin;
        let v = |k: usize| {
            let t = if k == 4 {
                o[4].translation.vector + o[4].rotation * model.tcp_offset.translation.vector
            } else {
                o[k].translation.vector
            };
            (t.x.hypot(t.y), t.y.atan2(t.x))
        };
        let (l2, c2) = v(2);
        let (l3, c3) = v(3);
        let (l4, c4) = v(4);
        let axis = o[4].rotation * Vector3::z();
        Self {
            shoulder: Vector2::new(o[1].translation.x, o[0].translation.z + o[1].translation.z),
            len: [l2, l3, l4],
            c: [c2, c3, c4],
            c_tool: axis.y.atan2(axis.x),
        }
    }

    fn dir(angle: f64) -> Vector2<f64> {
        Vector2::new(angle.cos(), angle.sin())
    }

    /// Joints 2–4 that put the TCP at `tcp` (plane coordinates) with the tool axis at
    /// `tool_angle` and the elbow on side `sign` (±1) of the shoulder–wrist line; `Err`
    /// with how far out of reach the wrist is.
    fn solve(&self, tcp: Vector2<f64>, tool_angle: f64, sign: f64) -> Result<[f64; 3], f64> {
        let [l2, l3, l4] = self.len;
        let [c2, c3, c4] = self.c;
        let a5 = tool_angle + self.c_tool - c4;
        let wrist = tcp - Self::dir(a5) * l4;
        let d = wrist - self.shoulder;
        let dist = d.norm();
        let short = dist - (l2 + l3);
        let long = (l2 - l3).abs() - dist;
        if short > 0.0 || long > 0.0 || dist < 1e-9 {
            return Err(short.max(long).max(0.0));
        }
        let cos_beta = ((l2 * l2 + dist * dist - l3 * l3) / (2.0 * l2 * dist)).clamp(-1.0, 1.0);
        let a_u = d.y.atan2(d.x) + sign * cos_beta.acos();
        let elbow = self.shoulder + Self::dir(a_u) * l2;
        let f = wrist - elbow;
        let a_f = f.y.atan2(f.x);
        let q2 = -a_u - c2;
        let q3 = -a_f - c3 - q2;
        let q4 = -a5 - c4 - q2 - q3;
        Ok([q2, q3, q4])
    }

    /// The branch of joints `q` reaching `target`: joint 1 within a quarter turn of the
    /// target's heading (facing) or not, and the elbow side.
    fn branch(&self, q: &Joints, target: &Vector3<f64>) -> Branch {
        let facing = (q[0] - target.y.atan2(target.x)).cos() >= 0.0;
        Branch {
            base: if facing {
                BaseSide::Facing
            } else {
                BaseSide::Flipped
            },
            elbow: self.elbow(q),
        }
    }

    /// The elbow side of joints `q` (geometric: the elbow above or below the line from the
    /// shoulder to the wrist, seen in the plane).
    fn elbow(&self, q: &Joints) -> Elbow {
        let [l2, l3, _] = self.len;
        let [c2, c3, _] = self.c;
        let e = Self::dir(-(c2 + q[1])) * l2;
        let w = e + Self::dir(-(c3 + q[1] + q[2])) * l3;
        let cross = w.x * e.y - w.y * e.x;
        // Counter-clockwise of the shoulder→wrist line is above it when the wrist is ahead.
        if (cross > 0.0) == (w.x >= 0.0) {
            Elbow::Up
        } else {
            Elbow::Down
        }
    }
}

/// `angle` moved by whole turns into `[lo, hi]`, if some turn of it lies there (the lowest).
fn wrap_into(angle: f64, lo: f64, hi: f64) -> Option<f64> {
    let a = lo + (angle - lo).rem_euclid(TAU);
    (a <= hi).then_some(a)
}

fn joint_distance_rad(a: &Joints, b: &Joints) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// The least blocked candidate so far.
#[derive(Debug, Clone, Copy)]
struct Least {
    blocker: Blocker,
    link: u8,
    deficit_m: f64,
}

/// Chooses the goal posture of `scene` for an arm starting at `start` (rad, clamped into
/// the limits).
///
/// The xArm5 reaches a TCP position with joints 1–4 (joint 5 turns the flange about its own
/// axis and does not move the TCP), so a goal target has a few discrete branches — joint 1
/// aimed at the goal or turned half a turn away from it (the arm reaching back over its
/// base), the elbow above or below the shoulder–wrist line — each a one-parameter family
/// over the wrist's pitch. This function enumerates a fixed set of candidates:
///
/// 1. what the twin's position IK ([`IkSolver`], the task's settings, pulled toward the
///    start) converges to from the start posture: the posture the Cartesian policy's
///    per-step IK drifts toward;
/// 2. for base facing / flipped × elbow up / down × four wrist pitches (the tool axis
///    straight down, tilted 30° and 60° away from the base, 30° toward it): the planar
///    closed form of the arm (joints 2–4 move in the vertical plane of joint 1, their link
///    vectors read from the model), polished by the same IK pulled toward it (0 iterations
///    on the bundled model: the closed form is exact).
///
/// On the bundled arm and goals on the table, the elbow-down and most flipped closed forms
/// leave the ranges of joints 2 and 3, so the postures kept are mostly the facing, elbow-up
/// branch at different wrist pitches (a flipped one appears for goals near the base).
///
/// Joint 5 keeps the start's value. A candidate is dropped when its closed form leaves the
/// joint limits, when its TCP misses the goal target by more than `success.tolerance_m`
/// (out of reach), when it breaks the task's contact rule (the one of `TwinEnv::step` and
/// the planner, [`is_safe_posture`]: a self-collision, or any box — or, links 2–5 and the
/// tool, the table — closer than `success.min_box_clearance_m`), or when it is within
/// 0.1 rad (largest joint gap) of a candidate kept before it.
///
/// # Order
/// The kept postures are ordered by their joint-space distance from the start posture
/// (Euclidean over the five joints, rad): the branch the arm gets to with the least joint
/// travel first. Equal distances go to the larger clearance margin
/// ([`BranchPosture::margin_m`]), then to the enumeration order above. The choice is a
/// pure function of the task, the scene and the start: deterministic.
///
/// # Errors
/// [`PostureChoiceError::Unreachable`] when no candidate reaches the goal target (by the
/// smallest remaining distance), [`PostureChoiceError::Blocked`] when every candidate that
/// does breaks the contact rule (naming what blocks the one closest to safe: box, table or
/// self-collision, and the link).
///
/// # Performance
/// [`MAX_BRANCH_POSTURES`] (17) candidates: one IK solve from the start (the only one that
/// iterates on the bundled model), sixteen closed forms (most of them outside the joint
/// limits for goals on the table, dropped before any FK), one FK and one distance query per
/// candidate within the limits; no allocation. 18–28 µs median on the tall box on the 2-core
/// dev machine, niced, idle to loaded (`cargo bench -p twin --bench twin -- goal_posture`).
pub fn choose_goal_posture(
    env: &TwinEnv,
    scene: &Scene,
    start: &Joints,
) -> Result<PostureChoice, PostureChoiceError> {
    let cfg = env.config();
    let model = env.model();
    let limits = model.limits();
    let mut start = *start;
    limits.clamp(&mut start);
    let target = scene.goal_target_m(cfg.success.goal_hover_m);
    let classifier = Classifier::new(env, scene);
    let planar = PlanarArm::of(model);
    let ik = IkSolver::new(model, cfg.ik);

    let mut choice = PostureChoice::none_yet(&target);
    let mut closest_m = f64::INFINITY;
    let seeds = seeds(model, &planar, &target, &start, &mut choice, &mut closest_m);

    let mut least: Option<Least> = None;
    let mut reached = 0;
    let mut kept: heapless::Vec<(BranchPosture, usize), MAX_BRANCH_POSTURES> = heapless::Vec::new();
    for (index, seed) in seeds.iter().enumerate() {
        let sol = ik
            .with_home(*seed)
            .solve_with(model, &target, seed, POSTURE_IK_ITERATIONS);
        let q = sol.joints;
        let poses = model.fk(&q);
        let tcp_error_m = (poses.tcp_m() - target).norm();
        closest_m = closest_m.min(tcp_error_m);
        if !(tcp_error_m <= cfg.success.tolerance_m && limits.contains(&q)) {
            choice.unreachable += 1;
            continue;
        }
        reached += 1;
        let d = classifier
            .check
            .geometry
            .all_distances(&poses, classifier.check.scene);
        let (margin_m, violation) = classifier.classify_at(&poses, &d);
        if contact(&d, classifier.check.clearance_m) {
            choice.blocked += 1;
            if least.is_none_or(|l| violation.deficit_m < l.deficit_m) {
                least = Some(Least {
                    blocker: violation.blocker,
                    link: violation.link,
                    deficit_m: violation.deficit_m,
                });
            }
            continue;
        }
        if kept
            .iter()
            .any(|(k, _)| max_joint_gap_rad(&k.joints, &q) < DUPLICATE_GAP_RAD)
        {
            continue;
        }
        let posture = BranchPosture {
            joints: q,
            branch: planar.branch(&q, &target),
            distance_rad: joint_distance_rad(&q, &start),
            margin_m,
            tcp_error_m,
        };
        let _ = kept.push((posture, index));
    }
    choice.postures = ordered(kept);
    if !choice.postures.is_empty() {
        return Ok(choice);
    }
    Err(no_posture(least, reached, closest_m))
}

/// The kept postures in the stated order: joint distance from the start, then the larger
/// margin, then the enumeration index.
fn ordered(
    mut kept: heapless::Vec<(BranchPosture, usize), MAX_BRANCH_POSTURES>,
) -> heapless::Vec<BranchPosture, MAX_BRANCH_POSTURES> {
    kept.sort_unstable_by(|(a, ia), (b, ib)| {
        a.distance_rad
            .total_cmp(&b.distance_rad)
            .then(b.margin_m.total_cmp(&a.margin_m))
            .then(ia.cmp(ib))
    });
    kept.into_iter().map(|(p, _)| p).collect()
}

/// The error when no candidate is kept: blocked (by the least blocked candidate's blocker)
/// when some reached the target, else out of reach by `closest_m`.
fn no_posture(least: Option<Least>, reached: usize, closest_m: f64) -> PostureChoiceError {
    match least {
        Some(l) => PostureChoiceError::Blocked {
            blocker: l.blocker,
            link: l.link,
            deficit_m: l.deficit_m,
            reached,
            candidates: MAX_BRANCH_POSTURES,
        },
        None => PostureChoiceError::Unreachable {
            by_m: if closest_m.is_finite() {
                closest_m
            } else {
                0.0
            },
            candidates: MAX_BRANCH_POSTURES,
        },
    }
}

/// The IK seeds in enumeration order: `start`, then the closed forms within the joint
/// limits (those outside them or out of reach counted in `choice`, the reach shortfall in
/// `closest_m`).
fn seeds(
    model: &RobotModel,
    planar: &PlanarArm,
    target: &Vector3<f64>,
    start: &Joints,
    choice: &mut PostureChoice,
    closest_m: &mut f64,
) -> heapless::Vec<Joints, MAX_BRANCH_POSTURES> {
    let limits = model.limits();
    let (lo, hi) = (limits.lower_rad, limits.upper_rad);
    let aim = near_turn(target.y.atan2(target.x), start[0], lo[0], hi[0]);
    let away = near_turn(aim + PI, start[0], lo[0], hi[0]);
    let reach_xy = target.x.hypot(target.y);
    let mut seeds: heapless::Vec<Joints, MAX_BRANCH_POSTURES> = heapless::Vec::new();
    let _ = seeds.push(*start);
    for (q1, side) in [(aim, 1.0), (away, -1.0)] {
        let tcp = Vector2::new(side * reach_xy, target.z);
        for sign in [1.0, -1.0] {
            for tilt in WRIST_TILTS_RAD {
                let tool = -FRAC_PI_2 + side * tilt;
                let q = planar.solve(tcp, tool, sign).map(|[q2, q3, q4]| {
                    [
                        Some(q1),
                        wrap_into(q2, lo[1], hi[1]),
                        wrap_into(q3, lo[2], hi[2]),
                        wrap_into(q4, lo[3], hi[3]),
                    ]
                });
                match q {
                    Err(by_m) => {
                        choice.unreachable += 1;
                        *closest_m = closest_m.min(by_m);
                    }
                    Ok([Some(q1), Some(q2), Some(q3), Some(q4)]) => {
                        let _ = seeds.push([q1, q2, q3, q4, start[4]]);
                    }
                    Ok(_) => choice.outside_limits += 1,
                }
            }
        }
    }
    seeds
}

#[cfg(test)]
mod tests {
    use std::f64::consts::FRAC_PI_4;
    use std::path::PathBuf;

    use shm_schemas::scene_file::SceneFile;

    use super::*;
    use crate::{TaskConfig, is_safe_posture};

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
    }

    fn env() -> TwinEnv {
        let model = RobotModel::load(&assets().join("xarm5.urdf")).expect("model");
        let task = TaskConfig::load(&assets().join("task.toml")).expect("task");
        TwinEnv::new(model, task)
    }

    fn scene(name: &str) -> Scene {
        let f = SceneFile::load(&assets().join("scenes").join(name)).expect("scene file");
        Scene::from_file(&f).expect("scene")
    }

    fn start(env: &TwinEnv) -> Joints {
        env.config().start.joints_rad
    }

    #[test]
    fn the_closed_form_is_exact_on_the_bundled_arm() {
        let e = env();
        let planar = PlanarArm::of(e.model());
        let mut solved = 0;
        for (x, y, z) in [
            (0.3, 0.0, 0.25),
            (0.28, -0.28, 0.1),
            (0.0, 0.42, 0.1),
            (0.45, 0.2, 0.3),
        ] {
            let q1 = f64::atan2(y, x);
            for side in [1.0, -1.0] {
                for sign in [1.0, -1.0] {
                    for tool in [-FRAC_PI_2, -FRAC_PI_4, -3.0 * FRAC_PI_4] {
                        let tcp = Vector2::new(side * f64::hypot(x, y), z);
                        let Ok([q2, q3, q4]) = planar.solve(tcp, tool, sign) else {
                            continue;
                        };
                        let base = if side > 0.0 { q1 } else { q1 + PI };
                        let q = [base, q2, q3, q4, 0.3];
                        let err = (e.model().tcp_m(&q) - Vector3::new(x, y, z)).norm();
                        assert!(err < 1e-9, "{x} {y} {z} side {side} sign {sign}: {err}");
                        assert_eq!(
                            planar.elbow(&q),
                            if sign * side > 0.0 {
                                Elbow::Up
                            } else {
                                Elbow::Down
                            },
                            "{q:?}"
                        );
                        solved += 1;
                    }
                }
            }
        }
        assert!(solved >= 20, "{solved}");
    }

    #[test]
    fn kept_postures_reach_the_goal_safely_in_the_stated_order() {
        let e = env();
        for name in ["tall_box.toml", "wide_tall_box.toml", "small_box.toml"] {
            let s = scene(name);
            let choice = choose_goal_posture(&e, &s, &start(&e)).expect(name);
            let target = Vector3::from(choice.target_m);
            for p in &choice.postures {
                assert!(is_safe_posture(&e, &s, &p.joints), "{name}: {p:?}");
                let err = (e.model().tcp_m(&p.joints) - target).norm();
                assert!(err <= e.config().success.tolerance_m, "{name}: {err}");
                assert_eq!(p.joints[4], start(&e)[4]);
                assert!(p.margin_m >= 0.0);
            }
            for w in choice.postures.windows(2) {
                assert!(
                    w[0].distance_rad < w[1].distance_rad
                        || (w[0].distance_rad == w[1].distance_rad
                            && w[0].margin_m >= w[1].margin_m),
                    "{name}: {w:?}"
                );
            }
            for (i, a) in choice.postures.iter().enumerate() {
                for b in &choice.postures[i + 1..] {
                    assert!(max_joint_gap_rad(&a.joints, &b.joints) >= DUPLICATE_GAP_RAD);
                }
            }
            // The nearest branch is the start's own: joint 1 aimed at the goal, elbow up.
            assert_eq!(
                choice.best().branch,
                Branch {
                    base: BaseSide::Facing,
                    elbow: Elbow::Up
                },
                "{name}"
            );
        }
    }

    /// The tall box of `tall_box.toml`, moved onto the line from the base through the goal,
    /// 12 cm beyond the goal: it stands where the wrist of the postures that reach over the
    /// goal with the tool tilted back toward the base would be.
    fn tall_box_behind_the_goal() -> Scene {
        let mut s = scene("tall_box.toml");
        let g = s.goal.center_m;
        let r = g[0].hypot(g[1]);
        s.obstacles[0].center_m[0] = g[0] + g[0] / r * 0.12;
        s.obstacles[0].center_m[1] = g[1] + g[1] / r * 0.12;
        s
    }

    #[test]
    fn a_branch_blocked_by_a_box_is_dropped() {
        let e = env();
        let s = tall_box_behind_the_goal();
        let mut empty = s;
        empty.obstacles.clear();
        let free = choose_goal_posture(&e, &empty, &start(&e)).expect("free");
        let boxed = choose_goal_posture(&e, &s, &start(&e)).expect("boxed");
        assert_eq!(free.blocked, 0);
        assert!(boxed.blocked >= 1, "{boxed:?}");
        let dropped: Vec<_> = free
            .postures
            .iter()
            .filter(|p| !boxed.postures.iter().any(|b| b.joints == p.joints))
            .collect();
        assert!(!dropped.is_empty(), "{free:?} {boxed:?}");
        for p in &dropped {
            assert!(is_safe_posture(&e, &empty, &p.joints));
            assert!(!is_safe_posture(&e, &s, &p.joints), "{p:?}");
        }
        // Every posture kept with the box was a candidate without it; the nearest free one
        // is among the dropped, so the choice moves on to a farther branch.
        for b in &boxed.postures {
            assert!(free.postures.iter().any(|p| p.joints == b.joints), "{b:?}");
        }
        assert!(dropped.iter().any(|p| p.joints == free.best().joints));
        assert!(boxed.best().distance_rad > free.best().distance_rad);
        // The demo's tall box itself stands in the way, not at the goal: nothing dropped.
        let tall = choose_goal_posture(&e, &scene("tall_box.toml"), &start(&e)).expect("tall");
        assert_eq!(tall.blocked, 0);
        assert_eq!(tall.best().joints, free.best().joints);
    }

    #[test]
    fn no_posture_says_why() {
        let e = env();
        // blocked_goal.toml: a wall in front of the goal blocks every branch's forearm.
        let err = choose_goal_posture(&e, &scene("blocked_goal.toml"), &start(&e))
            .expect_err("the wall blocks every branch");
        let PostureChoiceError::Blocked {
            blocker, reached, ..
        } = err
        else {
            panic!("{err:?}");
        };
        assert_eq!(blocker, Blocker::Box(0));
        assert!(reached >= 1);
        let words = err.to_string();
        assert!(words.contains("box 0 blocks link"), "{words}");
        assert_eq!(
            err.reason().kind(),
            shm_schemas::InfeasibleKind::NoGoalPosture
        );
        // A goal 1.2 m out: beyond the arm's reach on every branch.
        let mut far = scene("tall_box.toml");
        far.obstacles.clear();
        far.goal.center_m = [1.2, 0.0, 0.025];
        let err = choose_goal_posture(&e, &far, &start(&e)).expect_err("out of reach");
        let PostureChoiceError::Unreachable { by_m, .. } = err else {
            panic!("{err:?}");
        };
        assert!(by_m > 0.2 && by_m < 1.2, "{by_m}");
        assert!(err.to_string().contains("beyond the arm's reach"), "{err}");
    }

    #[test]
    fn the_choice_is_deterministic() {
        let e = env();
        for s in [scene("tall_box.toml"), tall_box_behind_the_goal()] {
            let a = choose_goal_posture(&e, &s, &start(&e));
            let b = choose_goal_posture(&e.clone(), &s, &start(&e));
            assert_eq!(a, b);
        }
    }
}
