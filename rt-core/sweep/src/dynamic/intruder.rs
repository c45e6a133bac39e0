//! The intruder of a dynamic episode: what is drawn before the episode runs, where it goes
//! once the rehearsal without it has shown the arm's path ([`Intruder`]: a [`BoxSpec`] with a
//! keyframed path on the episode's clock), and its ground truth at any time.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use shm_schemas::scene_file::{BoxPath, BoxSpec, Keyframe};

use crate::oracle::{DistanceOracle, OracleBox, Point};
use twin::Joints;

pub(crate) mod grown;

/// How the intruder comes in (and goes). The first four are the dynamic sweep's original
/// kinds ([`IntruderKind::CLASSIC`], drawn as they always were); the other five are issue
/// 42's ([`IntruderKind::GROWN`], drawn from a seed stream of their own: [`grown`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub enum IntruderKind {
    /// Enters the workspace, moves onto the arm's path and stays there.
    EnterAndStop,
    /// Enters, crosses the arm's path without stopping and leaves the workspace.
    Cross,
    /// Enters, stops on the arm's path for a while, then leaves the workspace.
    StopThenLeave,
    /// Appears at once, still, on or near the arm's path; after a while it leaves the
    /// workspace at its speed.
    Teleport,
    /// Already moving before the arm starts (and while it starts): crosses the view on a
    /// line through, or 0.1–0.3 m beside, the start of the arm's way.
    MovingAtStart,
    /// Crosses the view close beside the arm's way (a few cm from the swept arm) but never
    /// on it.
    NearMiss,
    /// Enters well ahead of the arm, parks on the rest of its path and stays (not on the
    /// goal).
    ParksOnPath,
    /// Slides along the table onto the goal cube, covers the goal's target point and stays.
    TakesGoal,
    /// Appears (does not slide in), still, a few mm to cm beside the arm where it is; stays,
    /// or leaves after a while.
    AppearsNextToArm,
}

impl IntruderKind {
    /// The original four kinds (issue 33), in the order of the reports.
    pub const CLASSIC: [IntruderKind; 4] = [
        IntruderKind::EnterAndStop,
        IntruderKind::Cross,
        IntruderKind::StopThenLeave,
        IntruderKind::Teleport,
    ];

    /// Issue 42's kinds.
    pub const GROWN: [IntruderKind; 5] = [
        IntruderKind::MovingAtStart,
        IntruderKind::NearMiss,
        IntruderKind::ParksOnPath,
        IntruderKind::TakesGoal,
        IntruderKind::AppearsNextToArm,
    ];

    /// Every kind, in the order of the reports.
    pub const ALL: [IntruderKind; 9] = [
        IntruderKind::EnterAndStop,
        IntruderKind::Cross,
        IntruderKind::StopThenLeave,
        IntruderKind::Teleport,
        IntruderKind::MovingAtStart,
        IntruderKind::NearMiss,
        IntruderKind::ParksOnPath,
        IntruderKind::TakesGoal,
        IntruderKind::AppearsNextToArm,
    ];

    /// A short name (reports, summary keys, `--kinds`).
    pub fn name(self) -> &'static str {
        match self {
            IntruderKind::EnterAndStop => "enter_and_stop",
            IntruderKind::Cross => "cross",
            IntruderKind::StopThenLeave => "stop_then_leave",
            IntruderKind::Teleport => "teleport",
            IntruderKind::MovingAtStart => "moving_at_start",
            IntruderKind::NearMiss => "near_miss",
            IntruderKind::ParksOnPath => "parks_on_path",
            IntruderKind::TakesGoal => "takes_goal",
            IntruderKind::AppearsNextToArm => "appears_next_to_arm",
        }
    }

    /// Whether it is one of the original four.
    pub fn is_classic(self) -> bool {
        Self::CLASSIC.contains(&self)
    }
}

/// Where on the arm the intruder's target point is taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ArmPoint {
    Tcp,
    Wrist,
    Elbow,
    LinkAxis,
}

/// Everything about the intruder drawn before the episode runs (its place needs the
/// rehearsal: [`Intruder::place`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct IntruderDraw {
    pub(crate) kind: IntruderKind,
    /// Its speed whenever it moves, m/s.
    pub(crate) speed_m_s: f64,
    /// Full extents, m.
    pub(crate) size_m: Point,
    /// When along the rehearsal's motion it is first seen (0..1).
    pick: f64,
    /// It reaches its target point this long before the rehearsal's arm does, s (negative:
    /// after it, behind the arm; a teleport: 0..1 s).
    lead_s: f64,
    /// Time it travels from where it is first seen to the target point, s (shortened by the
    /// edge of the workspace).
    travel_s: f64,
    /// Direction of travel toward the target point: azimuth and elevation, rad.
    azimuth_rad: f64,
    elevation_rad: f64,
    at: ArmPoint,
    offset_m: Point,
    axis_t: f64,
    axis_capsule: usize,
    /// How long it stays (stop-then-leave, teleport), s.
    dwell_s: f64,
    /// The way out: the way in, reversed and turned by this much about the vertical, rad.
    leave_turn_rad: f64,
    /// A teleport lands near the path (3–12 cm off the arm) rather than on it; a box moving
    /// at the start crosses beside the way; a box next to the arm stays.
    near: bool,
    near_offset_m: Point,
    /// The grown kinds' distance from the arm or its way (beside the way, the near miss's
    /// clearance, the gap next to the arm), m; 0 for the classic kinds.
    side_m: f64,
    /// The grown kinds' side of the line (the angle about its direction, 0 = horizontal,
    /// π/2 = above), rad; 0 for the classic kinds.
    side_angle_rad: f64,
}

fn unit(azimuth_rad: f64, elevation_rad: f64) -> Point {
    [
        elevation_rad.cos() * azimuth_rad.cos(),
        elevation_rad.cos() * azimuth_rad.sin(),
        elevation_rad.sin(),
    ]
}

impl IntruderDraw {
    /// Draws an intruder with speeds in `speed_m_s` (min, max).
    pub(crate) fn draw(rng: &mut ChaCha8Rng, speed_m_s: (f64, f64)) -> Self {
        let kind = IntruderKind::CLASSIC[rng.random_range(0..IntruderKind::CLASSIC.len())];
        let at = match rng.random_range(0..10u8) {
            0..4 => ArmPoint::Tcp,
            4..6 => ArmPoint::Wrist,
            6..8 => ArmPoint::Elbow,
            _ => ArmPoint::LinkAxis,
        };
        let near_dir = unit(
            rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
            rng.random_range(-0.6..0.6),
        );
        let near_m = rng.random_range(0.03..0.12);
        Self {
            kind,
            speed_m_s: rng.random_range(speed_m_s.0..=speed_m_s.1),
            size_m: [
                rng.random_range(0.02..0.15),
                rng.random_range(0.02..0.15),
                rng.random_range(0.02..0.15),
            ],
            pick: rng.random(),
            lead_s: rng.random_range(-0.2..0.8),
            travel_s: rng.random_range(0.2..1.2),
            azimuth_rad: rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
            elevation_rad: rng.random_range(-0.35..0.35),
            at,
            offset_m: [
                rng.random_range(-0.01..0.01),
                rng.random_range(-0.01..0.01),
                rng.random_range(-0.01..0.01),
            ],
            axis_t: rng.random(),
            axis_capsule: rng.random_range(0..64),
            dwell_s: rng.random_range(0.3..2.0),
            leave_turn_rad: rng.random_range(-1.0..1.0),
            near: rng.random_bool(0.3),
            near_offset_m: near_dir.map(|v| v * near_m),
            side_m: 0.0,
            side_angle_rad: 0.0,
        }
    }
}

/// Candidate times tried per intruder for one at which it appears clear of the arm.
const PLACE_ATTEMPTS: usize = 16;

/// The box the intruder may occupy: inside the calibrated workspace (a frame with an object
/// centred outside it is refused: the camera's view), above the table.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View {
    pub(crate) lo_m: Point,
    pub(crate) hi_m: Point,
}

impl View {
    /// For a box of height `height_m` over a table at `table_z_m`, within `calibrated`
    /// (min, max) less a 2 cm margin for the position noise.
    pub(crate) fn new(calibrated: (Point, Point), table_z_m: f64, height_m: f64) -> Self {
        let (lo, hi) = calibrated;
        Self {
            lo_m: [
                lo[0] + 0.02,
                lo[1] + 0.02,
                (table_z_m + height_m / 2.0).max(lo[2] + 0.02),
            ],
            hi_m: [hi[0] - 0.02, hi[1] - 0.02, hi[2] - 0.05],
        }
    }

    fn clamp(&self, p: Point) -> Point {
        std::array::from_fn(|i| p[i].clamp(self.lo_m[i], self.hi_m[i]))
    }

    /// How far from `p` (inside) along `dir` the view ends, m, and on which axis.
    fn exit(&self, p: &Point, dir: &Point) -> (f64, usize) {
        let mut best = (f64::INFINITY, 0);
        for i in 0..3 {
            let t = if dir[i] > 1e-12 {
                (self.hi_m[i] - p[i]) / dir[i]
            } else if dir[i] < -1e-12 {
                (self.lo_m[i] - p[i]) / dir[i]
            } else {
                continue;
            };
            if t < best.0 {
                best = (t.max(0.0), i);
            }
        }
        best
    }
}

fn add(a: &Point, b: &Point, s: f64) -> Point {
    [a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s]
}

/// The rehearsal's arm as the placement needs it.
pub(crate) struct ArmMotion<'a> {
    /// The arm's pose after each cycle.
    pub(crate) pose: &'a [Joints],
    /// First cycle of motion.
    pub(crate) start_cycle: u64,
    /// Cycle the goal was reached.
    pub(crate) reach_cycle: u64,
    /// Cycle period, s.
    pub(crate) period_s: f64,
    /// The goal cube (the grown kinds keep off it, or take it).
    pub(crate) goal_cube: OracleBox,
    /// The goal's target point (the TCP's), m.
    pub(crate) goal_target_m: Point,
}

impl ArmMotion<'_> {
    /// The rehearsal's pose in the cycle of `t_s` (the last one after its end).
    pub(crate) fn pose_at(&self, t_s: f64) -> Joints {
        let k = ((t_s / self.period_s).floor().max(0.0) as usize).min(self.pose.len() - 1);
        self.pose[k]
    }

    /// Start of motion, s.
    pub(crate) fn start_s(&self) -> f64 {
        self.start_cycle as f64 * self.period_s
    }

    /// Goal reached, s.
    pub(crate) fn reach_s(&self) -> f64 {
        self.reach_cycle as f64 * self.period_s
    }
}

/// The point of the arm at `q` that `d` aims at.
fn arm_point(d: &IntruderDraw, oracle: &DistanceOracle, q: &Joints) -> Point {
    match d.at {
        ArmPoint::Tcp => oracle.tcp_m(q),
        ArmPoint::Wrist => oracle.frame_origins_m(q)[4],
        ArmPoint::Elbow => oracle.frame_origins_m(q)[3],
        ArmPoint::LinkAxis => {
            let caps = oracle.world_capsules(q);
            let (_, a, b) = caps[d.axis_capsule % caps.len()];
            add(&a, &[b[0] - a[0], b[1] - a[1], b[2] - a[2]], d.axis_t)
        }
    }
}

/// A placed intruder: its box and path on the episode's clock, and when it appears,
/// starts moving, stops and leaves.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Intruder {
    /// How it comes and goes.
    pub kind: IntruderKind,
    /// Speed whenever it moves, m/s.
    pub speed_m_s: f64,
    /// The box and its path (`at_s` on the episode's clock, s).
    pub spec: BoxSpec,
    /// It appears, s.
    pub appear_s: f64,
    /// It leaves the view (is gone), s; never for `EnterAndStop`.
    pub vanish_s: Option<f64>,
    /// It comes to rest on the target point (`EnterAndStop`, `StopThenLeave`), s.
    pub stop_s: Option<f64>,
    /// It starts moving again after standing (`StopThenLeave`, `Teleport`), s.
    pub depart_s: Option<f64>,
    /// The target point on (or near) the rehearsal's path, m.
    pub target_m: Point,
    /// The rehearsal's arm is at the target point then, s.
    pub target_arm_s: f64,
}

impl Intruder {
    /// Places `d` on the rehearsal's motion; `None` when the rehearsal did not move. Of a
    /// few candidate times (from the drawn one on), the first at which the intruder appears
    /// clear of the arm is taken (else the last: it appears on the arm); the second value
    /// says whether it appears clear.
    pub(crate) fn place(
        d: &IntruderDraw,
        oracle: &DistanceOracle,
        arm: &ArmMotion<'_>,
        calibrated: (Point, Point),
        table_z_m: f64,
    ) -> Option<(Self, bool)> {
        if arm.reach_cycle <= arm.start_cycle || arm.pose.is_empty() {
            return None;
        }
        let mut placed = None;
        for attempt in 0..PLACE_ATTEMPTS {
            let pick = (d.pick + attempt as f64 * 0.618_033_988_749_895).fract();
            let placed_at = if d.kind.is_classic() {
                Self::place_at(d, pick, oracle, arm, calibrated, table_z_m)
            } else {
                grown::place(d, pick, oracle, arm, calibrated, table_z_m)
            };
            let Some(i) = placed_at else {
                continue;
            };
            let k = ((i.appear_s / arm.period_s).floor() as usize).min(arm.pose.len() - 1);
            let box_now = i.box_at(i.appear_s);
            let clear = oracle
                .clearance(&arm.pose[k], [&box_now], f64::NEG_INFINITY)
                .box_m
                > 0.0;
            placed = Some((i, clear));
            if clear {
                break;
            }
        }
        placed
    }

    fn place_at(
        d: &IntruderDraw,
        pick: f64,
        oracle: &DistanceOracle,
        arm: &ArmMotion<'_>,
        calibrated: (Point, Point),
        table_z_m: f64,
    ) -> Option<Self> {
        let view = View::new(calibrated, table_z_m, d.size_m[2]);
        let p = arm.period_s;
        let start_s = arm.start_cycle as f64 * p;
        let reach_s = arm.reach_cycle as f64 * p;
        // It is first seen at a random time of the motion; it reaches its target point
        // `travel_s` later (a teleport: at once), where the rehearsal's arm is `lead_s` after
        // that (or at the goal, when that is later than the motion).
        let seen_s = start_s + pick * (reach_s - start_s);
        let arrive_s = match d.kind {
            IntruderKind::Teleport => seen_s,
            _ => seen_s + d.travel_s,
        };
        let lead_s = match d.kind {
            IntruderKind::Teleport => d.lead_s + 0.2,
            _ => d.lead_s,
        };
        let target_arm_s = (arrive_s + lead_s).clamp(start_s, reach_s);
        let target_cycle = (target_arm_s / p).round() as u64;
        let q = arm.pose[(target_cycle as usize).min(arm.pose.len() - 1)];
        let point = arm_point(d, oracle, &q);
        let offset = if d.kind == IntruderKind::Teleport && d.near {
            add(&d.offset_m, &d.near_offset_m, 1.0)
        } else {
            d.offset_m
        };
        let target = view.clamp(add(&point, &offset, 1.0));
        let v = d.speed_m_s;
        let dir = unit(d.azimuth_rad, d.elevation_rad);
        // The way out: the way in reversed, turned about the vertical, level.
        let back = d.azimuth_rad + std::f64::consts::PI + d.leave_turn_rad;
        let out_dir = unit(back, 0.0);
        let mut keys: Vec<Keyframe> = Vec::new();
        let key = |at_s: f64, center_m: Point| Keyframe { at_s, center_m };
        let (appear_s, vanish_s, stop_s, depart_s);
        match d.kind {
            IntruderKind::Teleport => {
                appear_s = seen_s;
                let depart = appear_s + d.dwell_s;
                let (len, _) = view.exit(&target, &out_dir);
                let gone = depart + len / v;
                keys.push(key(appear_s, target));
                keys.push(key(depart, target));
                keys.push(key(gone, add(&target, &out_dir, len)));
                (vanish_s, stop_s, depart_s) = (Some(gone), None, Some(depart));
            }
            _ => {
                let (room, _) = view.exit(&target, &[-dir[0], -dir[1], -dir[2]]);
                // Seen when drawn; it arrives sooner when the edge of the view shortens its
                // way in.
                let approach = (v * d.travel_s).min(room);
                let entry = add(&target, &dir, -approach);
                appear_s = seen_s;
                let arrive = seen_s + approach / v;
                keys.push(key(appear_s, entry));
                keys.push(key(arrive, target));
                match d.kind {
                    IntruderKind::EnterAndStop => {
                        (vanish_s, stop_s, depart_s) = (None, Some(arrive), None);
                    }
                    IntruderKind::StopThenLeave => {
                        let depart = arrive + d.dwell_s;
                        let (len, _) = view.exit(&target, &out_dir);
                        let gone = depart + len / v;
                        keys.push(key(depart, target));
                        keys.push(key(gone, add(&target, &out_dir, len)));
                        (vanish_s, stop_s, depart_s) = (Some(gone), Some(arrive), Some(depart));
                    }
                    _ => {
                        // Across: on along the same line; a line that meets the table goes
                        // on level from there.
                        let (len, axis) = view.exit(&target, &dir);
                        let mut at = add(&target, &dir, len);
                        let mut t = arrive + len / v;
                        keys.push(key(t, at));
                        if axis == 2 && dir[2] < 0.0 {
                            let level = unit(d.azimuth_rad, 0.0);
                            let (more, _) = view.exit(&at, &level);
                            at = add(&at, &level, more);
                            t += more / v;
                            keys.push(key(t, at));
                        }
                        (vanish_s, stop_s, depart_s) = (Some(t), None, None);
                    }
                }
            }
        }
        // Keyframe times strictly ascend (a zero-length leg is dropped).
        keys.dedup_by(|b, a| b.at_s <= a.at_s + 1e-9);
        let path = BoxPath::new(&keys).ok()?;
        Some(Self {
            kind: d.kind,
            speed_m_s: v,
            spec: BoxSpec {
                center_m: keys[0].center_m,
                size_m: d.size_m,
                path,
            },
            appear_s,
            vanish_s,
            stop_s,
            depart_s,
            target_m: target,
            target_arm_s,
        })
    }

    /// Whether it is in the world at `t_s`.
    pub fn present_at(&self, t_s: f64) -> bool {
        t_s >= self.appear_s && self.vanish_s.is_none_or(|v| t_s < v)
    }

    /// Its true box at `t_s` (whether present or not).
    pub fn box_at(&self, t_s: f64) -> OracleBox {
        OracleBox::new(self.spec.center_at(t_s), self.spec.size_m)
    }

    /// Its true velocity at `t_s`, m/s.
    pub fn velocity_at(&self, t_s: f64) -> Point {
        if self.present_at(t_s) {
            self.spec.velocity_at(t_s)
        } else {
            [0.0; 3]
        }
    }

    /// Its true speed at `t_s`, m/s.
    pub fn speed_at(&self, t_s: f64) -> f64 {
        let v = self.velocity_at(t_s);
        (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
    }

    /// The times the world changes (it appears, stops, starts, vanishes), s.
    pub fn changes_s(&self) -> impl Iterator<Item = f64> + '_ {
        [
            Some(self.appear_s),
            self.stop_s,
            self.depart_s,
            self.vanish_s,
        ]
        .into_iter()
        .flatten()
    }

    /// The moments it starts to threaten: it appears, or starts moving after standing, s.
    pub fn onsets_s(&self) -> impl Iterator<Item = (f64, &'static str)> + '_ {
        [
            Some((self.appear_s, "appears")),
            self.depart_s.map(|t| (t, "moves_off")),
        ]
        .into_iter()
        .flatten()
    }

    /// The last change of the world (after it nothing moves), s.
    pub fn last_change_s(&self) -> f64 {
        self.changes_s().fold(self.appear_s, f64::max)
    }

    /// Whether a frame captured at `t_s` is settled as perception's tracker would mark it:
    /// nothing moves, and nothing appeared, stopped, started or vanished within
    /// `quiet_s` before it.
    pub fn settled_at(&self, t_s: f64, quiet_s: f64) -> bool {
        if self.present_at(t_s) && self.speed_at(t_s) > 0.0 {
            return false;
        }
        !self.changes_s().any(|c| c <= t_s && t_s - c < quiet_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> View {
        View::new(([-0.8, -0.8, -0.05], [0.8, 0.8, 1.0]), 0.0, 0.1)
    }

    #[test]
    fn the_view_ends_where_the_ray_leaves_it() {
        let v = view();
        let (t, axis) = v.exit(&[0.0, 0.0, 0.3], &[1.0, 0.0, 0.0]);
        assert!((t - 0.78).abs() < 1e-12 && axis == 0);
        let (t, axis) = v.exit(&[0.0, 0.0, 0.3], &[0.0, 0.0, -1.0]);
        assert!((t - 0.25).abs() < 1e-12 && axis == 2, "{t}");
    }

    #[test]
    fn a_stop_then_leave_intruder_is_settled_only_while_standing_after_the_quiet_time() {
        let mut keys = vec![
            Keyframe {
                at_s: 1.0,
                center_m: [0.5, 0.0, 0.1],
            },
            Keyframe {
                at_s: 1.5,
                center_m: [0.3, 0.0, 0.1],
            },
            Keyframe {
                at_s: 2.5,
                center_m: [0.3, 0.0, 0.1],
            },
        ];
        keys.push(Keyframe {
            at_s: 3.0,
            center_m: [0.3, 0.4, 0.1],
        });
        let i = Intruder {
            kind: IntruderKind::StopThenLeave,
            speed_m_s: 0.4,
            spec: BoxSpec {
                center_m: keys[0].center_m,
                size_m: [0.05; 3],
                path: BoxPath::new(&keys).unwrap(),
            },
            appear_s: 1.0,
            vanish_s: Some(3.0),
            stop_s: Some(1.5),
            depart_s: Some(2.5),
            target_m: [0.3, 0.0, 0.1],
            target_arm_s: 1.7,
        };
        assert!(i.settled_at(0.5, 0.3), "before it: a still world");
        assert!(!i.present_at(0.99) && i.present_at(1.0));
        assert!(!i.settled_at(1.2, 0.3), "moving");
        assert!((i.speed_at(1.2) - 0.4).abs() < 1e-12);
        assert!(!i.settled_at(1.7, 0.3), "stopped 0.2 s ago");
        assert!(i.settled_at(1.9, 0.3));
        assert!(!i.settled_at(2.7, 0.3), "leaving");
        assert!(!i.present_at(3.0) && !i.settled_at(3.1, 0.3), "just gone");
        assert!(i.settled_at(3.4, 0.3));
        assert_eq!(i.last_change_s(), 3.0);
        assert_eq!(i.onsets_s().count(), 2);
    }
}
