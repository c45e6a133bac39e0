//! The generators' raw draws: one world (goal and boxes) from a random stream, before the
//! feasibility proof. Boxes are axis-aligned, stand on the table, keep clear of the goal
//! cube and of the arm's start posture (a world whose box is already in the arm is no
//! world); everything else is left to the planner's verdict.

use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

use rand::Rng;
use twin::{BoxObstacle, Goal, Scene, TwinEnv, is_safe_posture};

/// The table area in reach where boxes stand "anywhere" (box centres, m): in front of and
/// beside the base, up to the arm's reach.
pub const TABLE_X_M: [f64; 2] = [0.0, 0.65];
/// See [`TABLE_X_M`].
pub const TABLE_Y_M: [f64; 2] = [-0.55, 0.55];
/// Footprint sides of the uniform generator's boxes (m).
pub const UNIFORM_FOOTPRINT_M: [f64; 2] = [0.04, 0.12];
/// Heights of the uniform generator's boxes (m).
pub const UNIFORM_HEIGHT_M: [f64; 2] = [0.04, 0.40];
/// Heights of the cluttered generator's boxes (m).
pub const CLUTTER_HEIGHT_M: [f64; 2] = [0.20, 0.40];
/// Footprint sides of the cluttered and adversarial boxes (m).
pub const FOOTPRINT_M: [f64; 2] = [0.04, 0.10];
/// Smallest horizontal gap between a box and the goal cube (m): boxes never cover the goal.
pub const GOAL_GAP_M: f64 = 0.02;

/// Half the angle of the front workspace the cluttered boxes spread over (rad): −75° … 75°.
pub const FRONT_HALF_ANGLE_RAD: f64 = 75.0 * PI / 180.0;

/// Tries per box placement, and per world, before a draw gives up.
const PLACE_TRIES: usize = 60;
const WORLD_TRIES: usize = 100;

/// Which generator (`--generator`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Generator {
    /// A goal anywhere the task's goal ranges allow, 1–3 boxes anywhere on the table.
    Uniform,
    /// Three tall boxes spread around the workspace.
    Cluttered,
    /// Boxes near the path, near the goal, beside the base; two tall boxes behind the goal.
    Adversarial,
}

impl Generator {
    /// Every generator, in report order.
    pub const ALL: [Generator; 3] = [Self::Uniform, Self::Cluttered, Self::Adversarial];

    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Uniform => "uniform",
            Self::Cluttered => "cluttered",
            Self::Adversarial => "adversarial",
        }
    }

    /// The `ChaCha8` stream of this generator (one seed, three independent streams).
    pub fn stream(self) -> u64 {
        match self {
            Self::Uniform => 0x5746_0001,
            Self::Cluttered => 0x5746_0002,
            Self::Adversarial => 0x5746_0003,
        }
    }
}

impl fmt::Display for Generator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A generator name that is none of `uniform`, `cluttered`, `adversarial`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown world generator {0:?} (expected uniform, cluttered or adversarial)")]
pub struct UnknownGeneratorError(pub String);

impl FromStr for Generator {
    type Err = UnknownGeneratorError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|g| g.name() == s)
            .ok_or_else(|| UnknownGeneratorError(s.to_owned()))
    }
}

/// What kind of world one draw is: the generator's own name, or the adversarial case.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WorldKind {
    /// [`Generator::Uniform`].
    Uniform,
    /// [`Generator::Cluttered`].
    Cluttered,
    /// One box 0.06–0.22 m beside the start→goal segment (centre to segment).
    NearPath,
    /// A box on the start→goal segment and one 0.03–0.08 m beside the goal cube.
    PathAndGoal,
    /// A goal at |y| 0.27–0.33 m and a tall box (0.30–0.40 m) beside the base.
    SideGoalTallBase,
    /// Two tall boxes (0.25–0.40 m) beyond the goal, one low box anywhere.
    FarSideTall,
}

/// The adversarial generator's cases, drawn with equal odds.
pub const ADVERSARIAL_KINDS: [WorldKind; 4] = [
    WorldKind::NearPath,
    WorldKind::PathAndGoal,
    WorldKind::SideGoalTallBase,
    WorldKind::FarSideTall,
];

impl WorldKind {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Uniform => "uniform",
            Self::Cluttered => "cluttered",
            Self::NearPath => "near_path",
            Self::PathAndGoal => "path_and_goal",
            Self::SideGoalTallBase => "side_goal_tall_base",
            Self::FarSideTall => "far_side_tall",
        }
    }
}

/// The goal ranges of the task (`[sampling]`: `goal_x_m`, `goal_y_m`, `goal_size_m`,
/// `table_height_m`, `min_goal_distance_m`) and the start TCP they are measured from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalRanges {
    /// Goal centre x range (m).
    pub x_m: [f64; 2],
    /// Goal centre y range (m).
    pub y_m: [f64; 2],
    /// Goal cube edge (m).
    pub size_m: f64,
    /// Table top height (m).
    pub table_height_m: f64,
    /// Smallest horizontal distance from the start TCP to the goal centre (m).
    pub min_start_distance_m: f64,
    /// The start TCP's x, y (m).
    pub start_xy_m: [f64; 2],
}

impl GoalRanges {
    /// The ranges of `env`'s task.
    pub fn of(env: &TwinEnv) -> Self {
        let s = &env.config().sampling;
        let start = env.start_tcp_m();
        Self {
            x_m: s.goal_x_m,
            y_m: s.goal_y_m,
            size_m: s.goal_size_m,
            table_height_m: s.table_height_m,
            min_start_distance_m: s.min_goal_distance_m,
            start_xy_m: [start.x, start.y],
        }
    }

    fn goal_at(&self, x: f64, y: f64) -> Goal {
        Goal {
            center_m: [x, y, self.table_height_m + self.size_m / 2.0],
            size_m: self.size_m,
        }
    }

    fn far_enough(&self, x: f64, y: f64) -> bool {
        (x - self.start_xy_m[0]).hypot(y - self.start_xy_m[1]) >= self.min_start_distance_m
    }
}

fn between<R: Rng + ?Sized>(rng: &mut R, [lo, hi]: [f64; 2]) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

fn sign<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    if rng.random::<bool>() { 1.0 } else { -1.0 }
}

/// A goal drawn in `x_m` × `y_m` at the task's distance from the start (`None` after
/// [`PLACE_TRIES`] misses).
fn goal_in<R: Rng + ?Sized>(
    g: &GoalRanges,
    rng: &mut R,
    x_m: [f64; 2],
    y_m: [f64; 2],
) -> Option<Goal> {
    (0..PLACE_TRIES).find_map(|_| {
        let (x, y) = (between(rng, x_m), between(rng, y_m));
        g.far_enough(x, y).then(|| g.goal_at(x, y))
    })
}

/// A box standing on the table.
fn standing(g: &GoalRanges, center_xy: [f64; 2], size_m: [f64; 3]) -> BoxObstacle {
    BoxObstacle {
        center_m: [
            center_xy[0],
            center_xy[1],
            g.table_height_m + size_m[2] / 2.0,
        ],
        size_m,
    }
}

/// Adds `b` to `scene` when it keeps [`GOAL_GAP_M`] from the goal cube and off the arm's
/// start posture; true when added.
fn place(env: &TwinEnv, scene: &mut Scene, b: BoxObstacle) -> bool {
    let goal = &scene.goal;
    let gap_x = (b.center_m[0] - goal.center_m[0]).abs() - (b.size_m[0] + goal.size_m) / 2.0;
    let gap_y = (b.center_m[1] - goal.center_m[1]).abs() - (b.size_m[1] + goal.size_m) / 2.0;
    if gap_x.max(gap_y) < GOAL_GAP_M {
        return false;
    }
    let mut trial = *scene;
    if trial.obstacles.push(b).is_err() {
        return false;
    }
    if !is_safe_posture(env, &trial, &env.config().start.joints_rad) {
        return false;
    }
    *scene = trial;
    true
}

/// Tries `make` up to [`PLACE_TRIES`] times until its box is placed.
fn place_one<R: Rng + ?Sized>(
    env: &TwinEnv,
    scene: &mut Scene,
    rng: &mut R,
    mut make: impl FnMut(&mut R) -> BoxObstacle,
) -> bool {
    (0..PLACE_TRIES).any(|_| {
        let b = make(rng);
        place(env, scene, b)
    })
}

/// A footprint `[sx, sy]` with sides in `range`.
fn footprint<R: Rng + ?Sized>(rng: &mut R, range: [f64; 2]) -> [f64; 2] {
    [between(rng, range), between(rng, range)]
}

/// One world of `generator` from `rng`, with its kind; `None` when no valid placement was
/// found in `WORLD_TRIES` attempts (a generator or task that leaves no room).
pub fn draw_world<R: Rng + ?Sized>(
    generator: Generator,
    env: &TwinEnv,
    rng: &mut R,
) -> Option<(WorldKind, Scene)> {
    let g = GoalRanges::of(env);
    (0..WORLD_TRIES).find_map(|_| {
        let kind = match generator {
            Generator::Uniform => WorldKind::Uniform,
            Generator::Cluttered => WorldKind::Cluttered,
            Generator::Adversarial => {
                ADVERSARIAL_KINDS[rng.random_range(0..ADVERSARIAL_KINDS.len())]
            }
        };
        draw_kind(kind, &g, env, rng).map(|s| (kind, s))
    })
}

fn draw_kind<R: Rng + ?Sized>(
    kind: WorldKind,
    g: &GoalRanges,
    env: &TwinEnv,
    rng: &mut R,
) -> Option<Scene> {
    let goal = match kind {
        WorldKind::SideGoalTallBase => {
            let y = sign(rng) * between(rng, [0.27, 0.33]);
            let y = y.clamp(g.y_m[0], g.y_m[1]);
            goal_in(g, rng, g.x_m, [y, y])?
        }
        _ => goal_in(g, rng, g.x_m, g.y_m)?,
    };
    let mut scene = Scene::empty(g.table_height_m, goal);
    let [gx, gy, _] = goal.center_m;
    let [s0x, s0y] = g.start_xy_m;
    // The start→goal segment: direction and its left normal.
    let len = (gx - s0x).hypot(gy - s0y).max(1e-9);
    let (ux, uy) = ((gx - s0x) / len, (gy - s0y) / len);
    let on_segment = |f: f64, lateral: f64| {
        [
            s0x + f * (gx - s0x) - uy * lateral,
            s0y + f * (gy - s0y) + ux * lateral,
        ]
    };
    let placed = match kind {
        WorldKind::Uniform => {
            let n = rng.random_range(1..=3);
            (0..n).all(|_| {
                place_one(env, &mut scene, rng, |r| {
                    let [sx, sy] = footprint(r, UNIFORM_FOOTPRINT_M);
                    let h = between(r, UNIFORM_HEIGHT_M);
                    let c = [between(r, TABLE_X_M), between(r, TABLE_Y_M)];
                    standing(g, c, [sx, sy, h])
                })
            })
        }
        WorldKind::Cluttered => {
            // One box in each third of the front workspace.
            let third = 2.0 * FRONT_HALF_ANGLE_RAD / 3.0;
            (0..3).all(|k| {
                place_one(env, &mut scene, rng, |r| {
                    let angle = -FRONT_HALF_ANGLE_RAD + third * (k as f64 + r.random::<f64>());
                    let radius = between(r, [0.20, 0.55]);
                    let [sx, sy] = footprint(r, FOOTPRINT_M);
                    let h = between(r, CLUTTER_HEIGHT_M);
                    standing(g, [radius * angle.cos(), radius * angle.sin()], [sx, sy, h])
                })
            })
        }
        WorldKind::NearPath => place_one(env, &mut scene, rng, |r| {
            let lateral = sign(r) * between(r, [0.06, 0.22]);
            let c = on_segment(between(r, [0.3, 0.7]), lateral);
            let [sx, sy] = footprint(r, FOOTPRINT_M);
            standing(g, c, [sx, sy, between(r, [0.10, 0.40])])
        }),
        WorldKind::PathAndGoal => {
            place_one(env, &mut scene, rng, |r| {
                let c = on_segment(between(r, [0.35, 0.65]), between(r, [-0.04, 0.04]));
                let [sx, sy] = footprint(r, [0.04, 0.08]);
                standing(g, c, [sx, sy, between(r, [0.05, 0.25])])
            }) && place_one(env, &mut scene, rng, |r| beside_goal(g, r, [gx, gy]))
        }
        WorldKind::SideGoalTallBase => place_one(env, &mut scene, rng, |r| {
            let side = if r.random::<bool>() {
                gy.signum()
            } else {
                -gy.signum()
            };
            let c = [between(r, [-0.05, 0.12]), side * between(r, [0.12, 0.22])];
            let [sx, sy] = footprint(r, [0.04, 0.08]);
            standing(g, c, [sx, sy, between(r, [0.30, 0.40])])
        }),
        WorldKind::FarSideTall => place_far_side_tall(g, env, &mut scene, rng, [gx, gy]),
    };
    placed.then_some(scene)
}

/// [`WorldKind::PathAndGoal`]'s second box: beside one face of the goal cube (centred at
/// `[gx, gy]`), 0.03–0.08 m from it.
fn beside_goal<R: Rng + ?Sized>(g: &GoalRanges, r: &mut R, [gx, gy]: [f64; 2]) -> BoxObstacle {
    let [sx, sy] = footprint(r, [0.04, 0.08]);
    let gap = between(r, [0.03, 0.08]);
    let along = between(r, [-0.03, 0.03]);
    let side = sign(r);
    let c = if r.random::<bool>() {
        [gx + side * ((g.size_m + sx) / 2.0 + gap), gy + along]
    } else {
        [gx + along, gy + side * ((g.size_m + sy) / 2.0 + gap)]
    };
    standing(g, c, [sx, sy, between(r, [0.10, 0.35])])
}

/// [`WorldKind::FarSideTall`]'s boxes: two tall ones beyond the goal (at `[gx, gy]`), one on
/// each side of its bearing, and a low one anywhere on the table; `false` when one could not
/// be placed.
fn place_far_side_tall<R: Rng + ?Sized>(
    g: &GoalRanges,
    env: &TwinEnv,
    scene: &mut Scene,
    rng: &mut R,
    [gx, gy]: [f64; 2],
) -> bool {
    let rho = gx.hypot(gy);
    let phi = gy.atan2(gx);
    [1.0, -1.0].into_iter().all(|side| {
        place_one(env, scene, rng, |r| {
            let radius = rho + between(r, [0.08, 0.20]);
            let angle = phi + side * between(r, [0.1, 0.5]);
            let [sx, sy] = footprint(r, FOOTPRINT_M);
            standing(
                g,
                [radius * angle.cos(), radius * angle.sin()],
                [sx, sy, between(r, [0.25, 0.40])],
            )
        })
    }) && place_one(env, scene, rng, |r| {
        let [sx, sy] = footprint(r, FOOTPRINT_M);
        let c = [between(r, TABLE_X_M), between(r, TABLE_Y_M)];
        standing(g, c, [sx, sy, between(r, [0.04, 0.12])])
    })
}
