//! Issue 42's intruder kinds, the grown dynamic sweep ([`IntruderKind::GROWN`]): their draw
//! (from a seed stream of their own, so the four classic kinds draw exactly as before) and
//! their placement on the rehearsal's motion. Each placement checks that the box does what
//! its kind says (and gives up, for another candidate or world, where it cannot):
//! - [`IntruderKind::MovingAtStart`]: moving from the episode's first frame (pacing along its
//!   line inside the view) and still moving when the rehearsal's arm starts; its line goes
//!   through, or 0.1–0.3 m beside, the start of the arm's way and stays 2 cm clear of the
//!   arm at rest;
//! - [`IntruderKind::NearMiss`]: a line across the view whose every box along it keeps the
//!   drawn clearance (2–15 cm) from the swept arm (every pose of the rehearsal), never on it;
//! - [`IntruderKind::ParksOnPath`]: comes and parks while the arm moves, 0.3–2 s before it gets
//!   there, on a point of the path the arm still takes (its final box overlaps that path),
//!   off the goal;
//! - [`IntruderKind::TakesGoal`]: slides along the table onto the goal cube (covering its
//!   footprint) with its top above the goal's target point, seen first while the arm moves,
//!   before the arm gets there;
//! - [`IntruderKind::AppearsNextToArm`]: appears still, 5–40 mm from the arm where it is,
//!   and stays, or leaves after 0.5–3 s.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schemas::scene_file::{BoxPath, BoxSpec, Keyframe};
use twin::Joints;

use super::{
    ArmMotion, ArmPoint, Intruder, IntruderDraw, IntruderKind, View, add, arm_point, unit,
};
use crate::oracle::{DistanceOracle, OracleBox, Point};

/// Candidate directions tried per placement.
const LINE_CANDIDATES: usize = 8;

/// The golden angle: successive candidate directions spread evenly, rad.
const GOLDEN_ANGLE_RAD: f64 = 2.399_963_229_728_653;

/// Step of the near miss's line outward from the arm, m.
const NEAR_MISS_STEP_M: f64 = 0.01;

/// Farthest the near miss's line is moved off the arm, m.
const NEAR_MISS_MAX_OFFSET_M: f64 = 0.6;

/// Step of the box next to the arm outward from it, m.
const GAP_STEP_M: f64 = 0.002;

/// Shortest line (inside the view) a moving grown kind travels, m.
const MIN_LINE_M: f64 = 0.3;

/// A box moving at the start keeps this clear of the arm at rest, m.
const AT_REST_CLEAR_M: f64 = 0.02;

/// A parked box stays this far from the goal's target point, m.
const PARK_GOAL_CLEAR_M: f64 = 0.05;

/// A box parks at least this long after the arm started, s.
const PARK_AFTER_START_S: f64 = 0.1;

/// ... and at least this long before the arm gets there, s.
const PARK_MIN_LEAD_S: f64 = 0.3;

/// The box taking the goal: its footprint covers the goal cube's by this much, and its top
/// stands this far above the goal's target point, m.
const TAKE_MARGIN_M: f64 = 0.01;

/// Shortest way in of a box parking on the path or taking the goal, m.
const MIN_SLIDE_M: f64 = 0.05;

/// A box parking on the path or taking the goal is first seen at least this long after the
/// arm started (a box seen before the start is a world the arm plans in), s.
const SEEN_AFTER_START_S: f64 = 0.05;

impl IntruderDraw {
    /// Draws an intruder of a grown `kind` with speeds in `speed_m_s` (min, max).
    pub(crate) fn draw_grown(
        rng: &mut ChaCha8Rng,
        kind: IntruderKind,
        speed_m_s: (f64, f64),
    ) -> Self {
        use std::f64::consts::PI;
        let at = match rng.random_range(0..10u8) {
            0..4 => ArmPoint::Tcp,
            4..6 => ArmPoint::Wrist,
            6..8 => ArmPoint::Elbow,
            _ => ArmPoint::LinkAxis,
        };
        let mut size_m: Point = std::array::from_fn(|_| rng.random_range(0.02..0.15));
        match kind {
            IntruderKind::TakesGoal => size_m[2] = rng.random_range(0.12..0.20),
            IntruderKind::AppearsNextToArm => size_m[2] = rng.random_range(0.05..0.35),
            _ => {}
        }
        let (lead_s, side_m) = match kind {
            IntruderKind::MovingAtStart => {
                (rng.random_range(-0.2..0.6), rng.random_range(0.1..0.3))
            }
            IntruderKind::NearMiss => (rng.random_range(-0.2..0.8), rng.random_range(0.02..0.15)),
            IntruderKind::ParksOnPath => (rng.random_range(0.6..2.0), 0.0),
            IntruderKind::AppearsNextToArm => (0.0, rng.random_range(0.005..0.04)),
            _ => (0.0, 0.0),
        };
        Self {
            kind,
            speed_m_s: rng.random_range(speed_m_s.0..=speed_m_s.1),
            size_m,
            pick: rng.random(),
            lead_s,
            travel_s: rng.random_range(0.2..1.2),
            azimuth_rad: rng.random_range(-PI..PI),
            elevation_rad: match kind {
                IntruderKind::ParksOnPath => rng.random_range(-0.35..0.35),
                IntruderKind::AppearsNextToArm => rng.random_range(-0.5..0.5),
                _ => 0.0,
            },
            at,
            offset_m: std::array::from_fn(|_| rng.random_range(-0.01..0.01)),
            axis_t: rng.random(),
            axis_capsule: rng.random_range(0..64),
            dwell_s: rng.random_range(0.5..3.0),
            leave_turn_rad: 0.0,
            near: rng.random_bool(0.5),
            near_offset_m: [0.0; 3],
            side_m,
            side_angle_rad: rng.random_range(0.0..PI),
        }
    }
}

/// Places a grown kind's intruder at `pick` (0..1) of the rehearsal's motion; `None` when
/// none of its candidates does what the kind says.
pub(crate) fn place(
    d: &IntruderDraw,
    pick: f64,
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    calibrated: (Point, Point),
    table_z_m: f64,
) -> Option<Intruder> {
    let view = View::new(calibrated, table_z_m, d.size_m[2]);
    match d.kind {
        IntruderKind::MovingAtStart => moving_at_start(d, pick, oracle, arm, &view),
        IntruderKind::NearMiss => near_miss(d, pick, oracle, arm, &view),
        IntruderKind::ParksOnPath => parks_on_path(d, pick, oracle, arm, &view),
        IntruderKind::TakesGoal => takes_goal(d, pick, arm, calibrated, table_z_m),
        IntruderKind::AppearsNextToArm => appears_next_to_arm(d, pick, oracle, arm, &view),
        _ => None,
    }
}

/// When a placed intruder appears, stops, moves off and vanishes, s.
struct Timing {
    appear_s: f64,
    stop_s: Option<f64>,
    depart_s: Option<f64>,
    vanish_s: Option<f64>,
}

fn build(
    d: &IntruderDraw,
    size_m: Point,
    mut keys: Vec<Keyframe>,
    t: Timing,
    target: (Point, f64),
) -> Option<Intruder> {
    keys.dedup_by(|b, a| b.at_s <= a.at_s + 1e-9);
    let path = BoxPath::new(&keys).ok()?;
    Some(Intruder {
        kind: d.kind,
        speed_m_s: d.speed_m_s,
        spec: BoxSpec {
            center_m: keys.first()?.center_m,
            size_m,
            path,
        },
        appear_s: t.appear_s,
        vanish_s: t.vanish_s,
        stop_s: t.stop_s,
        depart_s: t.depart_s,
        target_m: target.0,
        target_arm_s: target.1,
    })
}

fn key(at_s: f64, center_m: Point) -> Keyframe {
    Keyframe { at_s, center_m }
}

fn sub(a: &Point, b: &Point) -> Point {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: &Point, b: &Point) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn neg(a: &Point) -> Point {
    [-a[0], -a[1], -a[2]]
}

fn half_diagonal_m(size_m: &Point) -> f64 {
    dot(size_m, size_m).sqrt() / 2.0
}

/// A unit vector perpendicular to the level direction `u`: level at 0 (to its left), up at
/// π/2, level to its right at π.
fn perpendicular(u: &Point, angle_rad: f64) -> Point {
    let left = [-u[1], u[0], 0.0];
    let n = dot(&left, &left).sqrt().max(1e-12);
    let left = left.map(|x| x / n);
    let up = [0.0, 0.0, 1.0];
    std::array::from_fn(|i| left[i] * angle_rad.cos() + up[i] * angle_rad.sin())
}

fn inside(view: &View, p: &Point) -> bool {
    (0..3).all(|i| p[i] >= view.lo_m[i] - 1e-9 && p[i] <= view.hi_m[i] + 1e-9)
}

fn boxes_overlap(a: &OracleBox, b: &OracleBox) -> bool {
    (0..3).all(|i| (a.center_m[i] - b.center_m[i]).abs() < a.half_m[i] + b.half_m[i])
}

/// The distance between segments `p1`–`q1` and `p2`–`q2`, m (closest points, as in
/// Ericson's *Real-Time Collision Detection* 5.1.9).
pub(crate) fn segment_segment_distance_m(p1: &Point, q1: &Point, p2: &Point, q2: &Point) -> f64 {
    const EPS: f64 = 1e-12;
    let (d1, d2, r) = (sub(q1, p1), sub(q2, p2), sub(p1, p2));
    let (a, e, f) = (dot(&d1, &d1), dot(&d2, &d2), dot(&d2, &r));
    let (s, t) = if a <= EPS && e <= EPS {
        (0.0, 0.0)
    } else if a <= EPS {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = dot(&d1, &r);
        if e <= EPS {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = dot(&d1, &d2);
            let denom = a * e - b * b;
            let s = if denom > EPS {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t = (b * s + f) / e;
            if t < 0.0 {
                ((-c / a).clamp(0.0, 1.0), 0.0)
            } else if t > 1.0 {
                (((b - c) / a).clamp(0.0, 1.0), 1.0)
            } else {
                (s, t)
            }
        }
    };
    let c1 = add(p1, &d1, s);
    let c2 = add(p2, &d2, t);
    let g = sub(&c1, &c2);
    dot(&g, &g).sqrt()
}

/// An arm's capsules as (a, b, radius).
type Swept = Vec<(Point, Point, f64)>;

fn capsules_of(oracle: &DistanceOracle, q: &Joints, out: &mut Swept) {
    out.extend(
        oracle
            .world_capsules(q)
            .into_iter()
            .map(|(c, a, b)| (a, b, c.radius_m)),
    );
}

/// The swept arm: the rehearsal's poses from the one before the motion to its last (every
/// other cycle, and the last).
pub(crate) fn swept_arm(oracle: &DistanceOracle, arm: &ArmMotion<'_>) -> Swept {
    let mut out = Vec::new();
    let last = arm.pose.len() - 1;
    let mut k = (arm.start_cycle as usize).saturating_sub(1).min(last);
    while k < last {
        capsules_of(oracle, &arm.pose[k], &mut out);
        k += 2;
    }
    capsules_of(oracle, &arm.pose[last], &mut out);
    out
}

/// A lower bound of the clearance between any box of half diagonal `rb_m` centred on the
/// segment `a`–`b` and the capsules `swept`, m.
fn line_clearance_m(a: &Point, b: &Point, rb_m: f64, swept: &Swept) -> f64 {
    swept
        .iter()
        .map(|(p, q, r)| segment_segment_distance_m(a, b, p, q) - r - rb_m)
        .fold(f64::INFINITY, f64::min)
}

/// The smallest clearance of `bx` to the rehearsal's poses from `from_s` on (every other
/// cycle), stopping below 0, m.
pub(crate) fn path_clearance_m(
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    from_s: f64,
    bx: &OracleBox,
) -> f64 {
    let first = ((from_s / arm.period_s).floor().max(0.0) as usize).min(arm.pose.len() - 1);
    let mut best = f64::INFINITY;
    for q in arm.pose[first..].iter().step_by(2) {
        best = best.min(oracle.clearance(q, [bx], f64::NEG_INFINITY).box_m);
        if best < 0.0 {
            break;
        }
    }
    best
}

/// The keyframes of a box pacing between `c - u·back` and `c + u·fwd` at `v` from time 0,
/// through `c` (forward) at `arrive_s`, and on to the far end.
fn pacing_keys(
    c: &Point,
    u: &Point,
    back_m: f64,
    fwd_m: f64,
    v: f64,
    arrive_s: f64,
) -> Vec<Keyframe> {
    let at = |s_m: f64| add(c, u, s_m);
    let mut rev = vec![key(arrive_s, at(0.0))];
    // Back in time from (arrive, 0): to the near end, then alternately to the far end.
    let (mut t, mut s) = (arrive_s, 0.0);
    let mut next = -back_m;
    loop {
        let dt = (s - next).abs() / v;
        if t - dt <= 0.0 {
            rev.push(key(0.0, at(s + (next - s) * t / dt)));
            break;
        }
        t -= dt;
        s = next;
        rev.push(key(t, at(s)));
        next = if next < 0.0 { fwd_m } else { -back_m };
    }
    rev.reverse();
    rev.push(key(arrive_s + fwd_m / v, at(fwd_m)));
    rev
}

/// Moving from the first frame, through (or beside) the start of the arm's way.
fn moving_at_start(
    d: &IntruderDraw,
    pick: f64,
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    view: &View,
) -> Option<Intruder> {
    let (start, reach) = (arm.start_s(), arm.reach_s());
    let target_arm_s = start + (0.3 + 0.7 * pick) * (reach - start).min(1.5);
    let point = add(
        &arm_point(d, oracle, &arm.pose_at(target_arm_s)),
        &d.offset_m,
        1.0,
    );
    let mut at_rest = Vec::new();
    capsules_of(oracle, &arm.pose_at(start - arm.period_s), &mut at_rest);
    let rb = half_diagonal_m(&d.size_m);
    let v = d.speed_m_s;
    let arrive = target_arm_s - d.lead_s;
    for k in 0..LINE_CANDIDATES {
        let u = unit(d.azimuth_rad + k as f64 * GOLDEN_ANGLE_RAD, 0.0);
        let c = if d.near {
            add(&point, &perpendicular(&u, d.side_angle_rad), d.side_m)
        } else {
            point
        };
        let c = view.clamp(c);
        let (back, _) = view.exit(&c, &neg(&u));
        let (fwd, _) = view.exit(&c, &u);
        let ends = (add(&c, &u, -back), add(&c, &u, fwd));
        if back + fwd < MIN_LINE_M
            || arrive <= 0.0
            || arrive + fwd / v < start + 0.1
            || line_clearance_m(&ends.0, &ends.1, rb, &at_rest) < AT_REST_CLEAR_M
        {
            continue;
        }
        let keys = pacing_keys(&c, &u, back, fwd, v, arrive);
        let timing = Timing {
            appear_s: 0.0,
            stop_s: None,
            depart_s: None,
            vanish_s: Some(arrive + fwd / v),
        };
        return build(d, d.size_m, keys, timing, (c, target_arm_s));
    }
    None
}

/// Across the view, beside the swept arm by the drawn clearance, never on it.
fn near_miss(
    d: &IntruderDraw,
    pick: f64,
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    view: &View,
) -> Option<Intruder> {
    let (start, reach) = (arm.start_s(), arm.reach_s());
    let seen = start + pick * (reach - start);
    let arrive = seen + d.travel_s;
    let target_arm_s = (arrive + d.lead_s).clamp(start, reach);
    let point = arm_point(d, oracle, &arm.pose_at(target_arm_s));
    let swept = swept_arm(oracle, arm);
    let rb = half_diagonal_m(&d.size_m);
    let v = d.speed_m_s;
    for k in 0..LINE_CANDIDATES {
        let u = unit(d.azimuth_rad + k as f64 * GOLDEN_ANGLE_RAD, 0.0);
        let angle = (d.side_angle_rad + k as f64 * 1.1) % std::f64::consts::PI;
        let n = perpendicular(&u, angle);
        let mut r = 0.0;
        let mut found = None;
        while r <= NEAR_MISS_MAX_OFFSET_M {
            let c = add(&point, &n, r);
            if !inside(view, &c) {
                break;
            }
            let (back, _) = view.exit(&c, &neg(&u));
            let (fwd, _) = view.exit(&c, &u);
            if line_clearance_m(&add(&c, &u, -back), &add(&c, &u, fwd), rb, &swept) >= d.side_m {
                found = Some((c, back, fwd));
                break;
            }
            r += NEAR_MISS_STEP_M;
        }
        let Some((c, back, fwd)) = found else {
            continue;
        };
        if back + fwd < MIN_LINE_M {
            continue;
        }
        let approach = (v * d.travel_s).min(back);
        let appear = arrive - approach / v;
        let keys = vec![
            key(appear, add(&c, &u, -approach)),
            key(arrive, c),
            key(arrive + fwd / v, add(&c, &u, fwd)),
        ];
        let timing = Timing {
            appear_s: appear,
            stop_s: None,
            depart_s: None,
            vanish_s: Some(arrive + fwd / v),
        };
        return build(d, d.size_m, keys, timing, (c, target_arm_s));
    }
    None
}

/// Parks well ahead of the arm on the path it still takes, off the goal, and stays.
fn parks_on_path(
    d: &IntruderDraw,
    pick: f64,
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    view: &View,
) -> Option<Intruder> {
    let (start, reach) = (arm.start_s(), arm.reach_s());
    let target_arm_s = start + (0.1 + 0.65 * pick) * (reach - start);
    let point = arm_point(d, oracle, &arm.pose_at(target_arm_s));
    let target = view.clamp(add(&point, &d.offset_m, 1.0));
    let parked = OracleBox::new(target, d.size_m);
    // It parks while the arm moves (after its start), ahead of it.
    let lead_s = d.lead_s.min(target_arm_s - start - PARK_AFTER_START_S);
    let arrive = target_arm_s - lead_s;
    if lead_s < PARK_MIN_LEAD_S
        || parked.signed_distance_m(&arm.goal_target_m) < PARK_GOAL_CLEAR_M
        || boxes_overlap(&parked, &arm.goal_cube)
        || path_clearance_m(oracle, arm, arrive, &parked) >= 0.0
    {
        return None;
    }
    let v = d.speed_m_s;
    let dir = unit(d.azimuth_rad, d.elevation_rad);
    let (room, _) = view.exit(&target, &neg(&dir));
    let approach = (v * d.travel_s)
        .min(room)
        .min(v * (arrive - start - SEEN_AFTER_START_S));
    if approach < MIN_SLIDE_M {
        return None;
    }
    let appear = arrive - approach / v;
    let keys = vec![
        key(appear, add(&target, &dir, -approach)),
        key(arrive, target),
    ];
    let timing = Timing {
        appear_s: appear,
        stop_s: Some(arrive),
        depart_s: None,
        vanish_s: None,
    };
    build(d, d.size_m, keys, timing, (target, target_arm_s))
}

/// Slides level along the table onto the goal cube before the arm gets there, and stays.
fn takes_goal(
    d: &IntruderDraw,
    pick: f64,
    arm: &ArmMotion<'_>,
    calibrated: (Point, Point),
    table_z_m: f64,
) -> Option<Intruder> {
    let g = arm.goal_cube;
    let goal = arm.goal_target_m;
    let mut size = d.size_m;
    for (s, h) in size.iter_mut().zip(&g.half_m).take(2) {
        *s = s.max(2.0 * (h + TAKE_MARGIN_M) + 0.01);
    }
    size[2] = size[2].max(goal[2] - table_z_m + 2.0 * TAKE_MARGIN_M);
    let view = View::new(calibrated, table_z_m, size[2]);
    // The goal cube's footprint stays inside the box's by the margin wherever the offset
    // puts it.
    let slack: [f64; 2] = std::array::from_fn(|i| size[i] / 2.0 - g.half_m[i] - TAKE_MARGIN_M);
    let center = [
        g.center_m[0] + d.offset_m[0] / 0.01 * slack[0],
        g.center_m[1] + d.offset_m[1] / 0.01 * slack[1],
        table_z_m + size[2] / 2.0,
    ];
    if !inside(&view, &center) {
        return None;
    }
    let (start, reach) = (arm.start_s(), arm.reach_s());
    let arrive = start + (0.3 + 0.6 * pick) * (reach - start);
    let v = d.speed_m_s;
    for k in 0..LINE_CANDIDATES {
        let u = unit(d.azimuth_rad + k as f64 * GOLDEN_ANGLE_RAD, 0.0);
        let (room, _) = view.exit(&center, &neg(&u));
        let approach = (v * d.travel_s)
            .min(room)
            .min(v * (arrive - start - SEEN_AFTER_START_S));
        if approach < MIN_SLIDE_M {
            continue;
        }
        let appear = arrive - approach / v;
        let keys = vec![
            key(appear, add(&center, &u, -approach)),
            key(arrive, center),
        ];
        let timing = Timing {
            appear_s: appear,
            stop_s: Some(arrive),
            depart_s: None,
            vanish_s: None,
        };
        return build(d, size, keys, timing, (center, reach));
    }
    None
}

/// Appears still a few mm to cm beside the arm where it is; stays, or leaves after a while.
fn appears_next_to_arm(
    d: &IntruderDraw,
    pick: f64,
    oracle: &DistanceOracle,
    arm: &ArmMotion<'_>,
    view: &View,
) -> Option<Intruder> {
    let (start, reach) = (arm.start_s(), arm.reach_s());
    let appear = start + (0.1 + 0.8 * pick) * (reach - start);
    let q = arm.pose_at(appear);
    let point = arm_point(d, oracle, &q);
    for k in 0..LINE_CANDIDATES {
        let az = d.azimuth_rad + k as f64 * GOLDEN_ANGLE_RAD;
        let n = unit(az, d.elevation_rad);
        let mut r = 0.0;
        let mut found = None;
        while r <= 0.5 {
            let c = add(&point, &n, r);
            let bx = OracleBox::new(c, d.size_m);
            if oracle.clearance(&q, [&bx], f64::NEG_INFINITY).box_m >= d.side_m {
                found = Some(c);
                break;
            }
            r += GAP_STEP_M;
        }
        let Some(c) = found.filter(|c| inside(view, c)) else {
            continue;
        };
        let mut keys = vec![key(appear, c)];
        let timing = if d.near {
            Timing {
                appear_s: appear,
                stop_s: Some(appear),
                depart_s: None,
                vanish_s: None,
            }
        } else {
            let depart = appear + d.dwell_s;
            let out = unit(az, 0.0);
            let (len, _) = view.exit(&c, &out);
            let gone = depart + len / d.speed_m_s;
            keys.push(key(depart, c));
            keys.push(key(gone, add(&c, &out, len)));
            Timing {
                appear_s: appear,
                stop_s: None,
                depart_s: Some(depart),
                vanish_s: Some(gone),
            }
        };
        return build(d, d.size_m, keys, timing, (c, appear));
    }
    None
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;
    use crate::sweep::SweepAssets;

    const PERIOD_S: f64 = 0.004;
    const REST_CYCLES: usize = 200;
    const MOTION_CYCLES: usize = 600;

    /// A rehearsal-like motion: at rest 0.8 s, a smooth 2.4 s joint move, at rest again.
    struct Rig {
        assets: SweepAssets,
        pose: Vec<Joints>,
        goal_cube: OracleBox,
        goal_target_m: Point,
    }

    impl Rig {
        fn new() -> Self {
            let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
            let assets = SweepAssets::load(&dir).expect("assets");
            let q0 = assets.task.start.joints_rad;
            let q1: Joints = [0.7, -0.1, -0.6, 0.7, 0.7];
            let mut pose = vec![q0; REST_CYCLES];
            for k in 1..=MOTION_CYCLES {
                let s = 0.5 - 0.5 * (std::f64::consts::PI * k as f64 / MOTION_CYCLES as f64).cos();
                pose.push(std::array::from_fn(|j| q0[j] + (q1[j] - q0[j]) * s));
            }
            pose.extend(std::iter::repeat_n(q1, 50));
            let tcp = assets.oracle().tcp_m(&q1);
            assert!(
                tcp[2] > 0.05,
                "the made-up motion ends above the table: {tcp:?}"
            );
            Self {
                goal_cube: OracleBox::new([tcp[0], tcp[1], 0.025], [0.05; 3]),
                goal_target_m: [tcp[0], tcp[1], 0.10],
                assets,
                pose,
            }
        }

        fn arm(&self) -> ArmMotion<'_> {
            ArmMotion {
                pose: &self.pose,
                start_cycle: REST_CYCLES as u64,
                reach_cycle: (REST_CYCLES + MOTION_CYCLES) as u64,
                period_s: PERIOD_S,
                goal_cube: self.goal_cube,
                goal_target_m: self.goal_target_m,
            }
        }

        fn calibrated(&self) -> (Point, Point) {
            let i = &self.assets.cfg.intake;
            (i.calibrated_min_m, i.calibrated_max_m)
        }

        /// Up to `n` placed intruders of `kind` (seeds 0..n); at least half must place.
        fn placed(&self, kind: IntruderKind, n: u64) -> Vec<Intruder> {
            let out: Vec<Intruder> = (0..n)
                .filter_map(|seed| {
                    let mut rng = ChaCha8Rng::seed_from_u64(seed);
                    let d = IntruderDraw::draw_grown(&mut rng, kind, (0.1, 1.6));
                    Intruder::place(
                        &d,
                        self.assets.oracle(),
                        &self.arm(),
                        self.calibrated(),
                        0.0,
                    )
                    .map(|(i, _)| i)
                })
                .collect();
            assert!(
                out.len() as u64 * 2 >= n,
                "{kind:?}: {} of {n} placed",
                out.len()
            );
            assert!(out.iter().all(|i| i.kind == kind));
            out
        }

        fn clearance_m(&self, q: &Joints, bx: &OracleBox) -> f64 {
            self.assets
                .oracle()
                .clearance(q, [bx], f64::NEG_INFINITY)
                .box_m
        }
    }

    fn times(from_s: f64, to_s: f64, step_s: f64) -> impl Iterator<Item = f64> {
        let n = ((to_s - from_s) / step_s).ceil().max(0.0) as usize;
        (0..=n).map(move |k| (from_s + k as f64 * step_s).min(to_s))
    }

    #[test]
    fn a_box_moving_at_the_start_moves_from_the_first_frame_through_the_arms_start() {
        let rig = Rig::new();
        let arm = rig.arm();
        let view = View::new(rig.calibrated(), 0.0, 0.15);
        for i in rig.placed(IntruderKind::MovingAtStart, 16) {
            assert_eq!(i.appear_s, 0.0);
            assert!(i.present_at(0.0) && i.speed_at(0.0) > 0.0, "{i:?}");
            let start = arm.start_s();
            assert!(
                i.present_at(start) && i.speed_at(start) > 0.0,
                "still at the start: {i:?}"
            );
            let v = i.vanish_s.expect("it leaves");
            for t in times(0.0, v - 1e-6, 0.02) {
                assert!(
                    (i.speed_at(t) - i.speed_m_s).abs() < 1e-9,
                    "moving at {t}: {i:?}"
                );
                let c = i.spec.center_at(t);
                assert!((0..2).all(|k| c[k] >= view.lo_m[k] - 1e-6 && c[k] <= view.hi_m[k] + 1e-6));
            }
            for t in times(0.0, start, 0.01) {
                let clear = rig.clearance_m(&arm.pose_at(t), &i.box_at(t));
                assert!(
                    clear >= AT_REST_CLEAR_M - 1e-9,
                    "on the arm at rest at {t}: {clear}"
                );
            }
        }
    }

    #[test]
    fn a_near_miss_never_overlaps_the_swept_arm_and_passes_close() {
        let rig = Rig::new();
        let arm = rig.arm();
        let poses: Vec<Joints> = rig.pose.iter().step_by(4).copied().collect();
        for i in rig.placed(IntruderKind::NearMiss, 8) {
            let v = i.vanish_s.expect("it crosses and leaves");
            let mut closest = f64::INFINITY;
            for t in times(i.appear_s, v, 0.02 / i.speed_m_s) {
                let bx = i.box_at(t);
                for q in &poses {
                    closest = closest.min(rig.clearance_m(q, &bx));
                }
            }
            assert!(
                closest > 0.0,
                "the near miss overlaps the swept arm: {closest} {i:?}"
            );
            assert!(closest < 0.3, "not near: {closest} m");
            assert!(i.speed_at((i.appear_s + v) / 2.0) > 0.0 && arm.reach_s() > i.appear_s);
        }
    }

    #[test]
    fn a_parked_box_stays_on_the_path_the_arm_still_takes_and_off_the_goal() {
        let rig = Rig::new();
        let arm = rig.arm();
        for i in rig.placed(IntruderKind::ParksOnPath, 16) {
            let stop = i.stop_s.expect("it parks");
            assert_eq!(i.vanish_s, None, "it stays");
            assert!(i.speed_at(stop + 0.01) == 0.0 && i.box_at(stop) == i.box_at(stop + 30.0));
            let parked = i.box_at(stop);
            let on_path = rig.pose[(stop / PERIOD_S) as usize..]
                .iter()
                .map(|q| rig.clearance_m(q, &parked))
                .fold(f64::INFINITY, f64::min);
            assert!(on_path < 0.0, "the parked box is off the path: {on_path}");
            assert!(parked.signed_distance_m(&rig.goal_target_m) >= PARK_GOAL_CLEAR_M);
            assert!(!boxes_overlap(&parked, &rig.goal_cube));
            assert!(stop < arm.reach_s(), "parks before the arm is at the goal");
            assert!(i.appear_s > arm.start_s(), "comes while the arm moves");
            assert!(
                stop + PARK_MIN_LEAD_S <= i.target_arm_s + 1e-9,
                "ahead of the arm"
            );
        }
    }

    #[test]
    fn a_box_taking_the_goal_slides_level_onto_it_and_stays() {
        let rig = Rig::new();
        let arm = rig.arm();
        for i in rig.placed(IntruderKind::TakesGoal, 16) {
            let stop = i.stop_s.expect("it stops on the goal");
            assert_eq!(i.vanish_s, None, "it stays");
            assert!(stop < arm.reach_s(), "before the arm gets there");
            assert!(i.appear_s > arm.start_s(), "comes while the arm moves");
            let taken = i.box_at(stop + 30.0);
            assert!(
                taken.signed_distance_m(&rig.goal_target_m) < 0.0,
                "covers the target"
            );
            assert!(boxes_overlap(&taken, &rig.goal_cube));
            for k in 0..2 {
                let (g, b) = (&rig.goal_cube, &taken);
                assert!(b.center_m[k] - b.half_m[k] <= g.center_m[k] - g.half_m[k]);
                assert!(b.center_m[k] + b.half_m[k] >= g.center_m[k] + g.half_m[k]);
            }
            let first = i.spec.center_at(i.appear_s);
            assert!(i.speed_at(i.appear_s + 1e-3) > 0.0, "it slides in");
            assert!(max_gap(&first, &taken.center_m) >= MIN_SLIDE_M - 1e-9);
            assert!(
                (first[2] - taken.center_m[2]).abs() < 1e-12,
                "level, along the table"
            );
            assert!(
                (taken.center_m[2] - taken.half_m[2]).abs() < 1e-12,
                "on the table"
            );
        }
    }

    fn max_gap(a: &Point, b: &Point) -> f64 {
        let d = sub(a, b);
        dot(&d, &d).sqrt()
    }

    #[test]
    fn a_box_appearing_next_to_the_arm_appears_still_beside_it() {
        let rig = Rig::new();
        let arm = rig.arm();
        let mut stays = 0;
        for i in rig.placed(IntruderKind::AppearsNextToArm, 16) {
            let t = i.appear_s;
            assert!(!i.present_at(t - 1e-3) && i.present_at(t));
            let until = i.depart_s.unwrap_or(t + 30.0);
            assert!(
                i.speed_at(t) == 0.0 && i.speed_at(until - 1e-3) == 0.0,
                "{i:?}"
            );
            assert!(
                i.box_at(t) == i.box_at(until - 1e-3),
                "appears, does not slide in"
            );
            let gap = rig.clearance_m(&arm.pose_at(t), &i.box_at(t));
            assert!(gap > 0.0 && gap <= 0.045, "next to the arm: {gap} m");
            stays += usize::from(i.vanish_s.is_none());
        }
        assert!(stays > 0, "some stay");
    }
}
