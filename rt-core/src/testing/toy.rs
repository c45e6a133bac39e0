//! Small stand-ins for the twin, used by the runtime's tests and the `bench-loop` harness
//! until (and besides) the real twin: [`ToyArm`] (an xArm5-like serial chain with sphere-
//! swept links, analytic FK, distances to axis-aligned boxes), [`ToyScene`] and
//! [`ToyLookahead`] with [`ToyPolicy`] (a policy that is a small random MLP evaluated on the
//! joint error, rolled out for a whole episode). The toy's goal is the policy's joint
//! target: its TCP there is the goal target point.

use crate::cycle::shield::{ShieldModel, WATCHED_POINTS};
use crate::twin_thread::worker::{GoalApproach, Lookahead, Verdict};
use twin::{Blocker, DOF, InfeasibleReason, Joints, LINK_TOOL};

/// Maximum obstacles in a [`ToyScene`].
pub const TOY_MAX_OBSTACLES: usize = 8;

/// Link lengths of the toy chain, m (base height, upper arm, forearm, wrist).
const LINKS_M: [f64; 4] = [0.267, 0.29, 0.35, 0.10];
/// Radius of the spheres swept along the links, m.
const LINK_RADIUS_M: f64 = 0.04;
/// Spheres per link.
const SPHERES_PER_LINK: usize = 4;

/// A scene: a goal position and up to [`TOY_MAX_OBSTACLES`] axis-aligned boxes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToyScene {
    /// Goal position, m.
    pub goal_m: [f64; 3],
    /// Box centres, m.
    pub centers_m: [[f64; 3]; TOY_MAX_OBSTACLES],
    /// Box half extents, m.
    pub half_m: [[f64; 3]; TOY_MAX_OBSTACLES],
    /// Boxes in use.
    pub count: usize,
}

impl ToyScene {
    /// No obstacles, goal at the origin.
    pub fn empty() -> Self {
        Self {
            goal_m: [0.0; 3],
            centers_m: [[0.0; 3]; TOY_MAX_OBSTACLES],
            half_m: [[0.0; 3]; TOY_MAX_OBSTACLES],
            count: 0,
        }
    }

    /// Adds a box of full extents `size_m` at `center_m` (ignored when full).
    pub fn push_obstacle(&mut self, center_m: [f64; 3], size_m: [f64; 3]) {
        if self.count < TOY_MAX_OBSTACLES {
            self.centers_m[self.count] = center_m;
            self.half_m[self.count] = [size_m[0] / 2.0, size_m[1] / 2.0, size_m[2] / 2.0];
            self.count += 1;
        }
    }
}

/// The toy arm: base yaw, three pitch joints, wrist roll.
#[derive(Debug, Clone, Copy, Default)]
pub struct ToyArm;

impl ToyArm {
    /// Joint origins and the TCP, m: base, shoulder, elbow, wrist, TCP.
    pub fn points_m(q: &Joints) -> [[f64; 3]; 5] {
        let (s0, c0) = q[0].sin_cos();
        let mut pts = [[0.0; 3]; 5];
        pts[1] = [0.0, 0.0, LINKS_M[0]];
        let mut r = 0.0;
        let mut z = LINKS_M[0];
        let mut pitch = 0.0;
        for k in 0..3 {
            pitch += q[k + 1];
            // pitch 0 = straight up; positive tilts forward.
            r += LINKS_M[k + 1] * pitch.sin();
            z += LINKS_M[k + 1] * pitch.cos();
            pts[k + 2] = [r * c0, r * s0, z];
        }
        pts
    }
}

fn box_distance(p: &[f64; 3], c: &[f64; 3], h: &[f64; 3]) -> f64 {
    let mut out = 0.0;
    let mut inside = f64::NEG_INFINITY;
    for k in 0..3 {
        let d = (p[k] - c[k]).abs() - h[k];
        if d > 0.0 {
            out += d * d;
        }
        inside = inside.max(d);
    }
    if out > 0.0 { out.sqrt() } else { inside }
}

impl ShieldModel for ToyArm {
    type Scene = ToyScene;

    fn watched_points_m(&mut self, q_rad: &Joints) -> [[f64; 3]; WATCHED_POINTS] {
        let p = Self::points_m(q_rad);
        [p[2], p[3], p[4]]
    }

    fn min_distance_m(&mut self, q_rad: &Joints, scene: &ToyScene) -> f64 {
        if scene.count == 0 {
            return f64::INFINITY;
        }
        let pts = Self::points_m(q_rad);
        let mut best = f64::INFINITY;
        // Links from the shoulder on (the base column is fixed and cleared by layout).
        for l in 1..4 {
            let (a, b) = (pts[l], pts[l + 1]);
            for s in 0..=SPHERES_PER_LINK {
                let t = s as f64 / SPHERES_PER_LINK as f64;
                let p = [
                    a[0] + (b[0] - a[0]) * t,
                    a[1] + (b[1] - a[1]) * t,
                    a[2] + (b[2] - a[2]) * t,
                ];
                for o in 0..scene.count {
                    best = best.min(
                        box_distance(&p, &scene.centers_m[o], &scene.half_m[o]) - LINK_RADIUS_M,
                    );
                }
            }
        }
        best
    }
}

/// Hidden width of the toy policy's MLP.
pub const TOY_HIDDEN: usize = 16;

/// A policy with random weights: a 2-layer tanh MLP from the joint error (target − q) to a
/// joint velocity, plus a proportional pull so every policy reaches its target.
#[derive(Debug, Clone)]
pub struct ToyPolicy {
    /// Policy id.
    pub id: u64,
    /// Joint target the policy drives to, rad.
    pub target_rad: Joints,
    w1: [[f64; DOF]; TOY_HIDDEN],
    w2: [[f64; TOY_HIDDEN]; DOF],
}

impl ToyPolicy {
    /// A policy with weights from `seed`.
    pub fn random(id: u64, target_rad: Joints, seed: u64) -> Self {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut w1 = [[0.0; DOF]; TOY_HIDDEN];
        let mut w2 = [[0.0; TOY_HIDDEN]; DOF];
        for row in &mut w1 {
            for w in row.iter_mut() {
                *w = next() * 0.2;
            }
        }
        for row in &mut w2 {
            for w in row.iter_mut() {
                *w = next() * 0.2;
            }
        }
        Self {
            id,
            target_rad,
            w1,
            w2,
        }
    }

    /// Joint velocity command for the error `e`, rad/s.
    pub fn act(&self, e: &Joints) -> Joints {
        let mut h = [0.0; TOY_HIDDEN];
        for (i, row) in self.w1.iter().enumerate() {
            h[i] = row.iter().zip(e).map(|(w, x)| w * x).sum::<f64>().tanh();
        }
        let mut out = [0.0; DOF];
        for j in 0..DOF {
            let mlp: f64 = self.w2[j].iter().zip(&h).map(|(w, x)| w * x).sum();
            out[j] = (1.5 * e[j] + 0.1 * mlp).clamp(-0.8, 0.8);
        }
        out
    }
}

/// The toy lookahead: rolls a [`ToyPolicy`] out for up to `steps` steps of `step_s` from the
/// start pose, checking clearance at each step against the scene.
#[derive(Debug, Clone)]
pub struct ToyLookahead {
    /// Steps per episode.
    pub steps: usize,
    /// Step duration, s.
    pub step_s: f64,
    /// Clearance below which the episode is unsafe, m.
    pub min_distance_m: f64,
    /// Joint tolerance for success, rad.
    pub tolerance_rad: f64,
    /// TCP distance to the goal target point (the TCP at the policy's joint target) that
    /// counts as reached on a smoothed plan, m: loose enough for every episode that ends
    /// within twice `tolerance_rad` of the target (a TCP within ~0.04 m).
    pub goal_tolerance_m: f64,
    /// Answer [`Lookahead::goal_taken`] (off: the toy never finds its goal taken).
    pub goal_check: bool,
}

impl Default for ToyLookahead {
    fn default() -> Self {
        Self {
            steps: 200,
            step_s: 0.05,
            min_distance_m: 0.01,
            tolerance_rad: 0.01,
            goal_tolerance_m: 0.05,
            goal_check: false,
        }
    }
}

/// The toy's goal target point for `policy`: the TCP at its joint target, m.
pub fn toy_goal_target_m(policy: &ToyPolicy) -> [f64; 3] {
    ToyArm::points_m(&policy.target_rad)[4]
}

/// The closest approach of the toy arm's TCP along `path_q_rad` to `target_m`, m (infinite
/// for an empty path). No allocation.
pub fn toy_closest_approach_m(target_m: &[f64; 3], path_q_rad: &[Joints]) -> f64 {
    path_q_rad
        .iter()
        .map(|q| {
            let p = ToyArm::points_m(q)[4];
            ((p[0] - target_m[0]).powi(2)
                + (p[1] - target_m[1]).powi(2)
                + (p[2] - target_m[2]).powi(2))
            .sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

impl Lookahead for ToyLookahead {
    type Scene = ToyScene;
    type Policy = ToyPolicy;

    fn step_s(&self) -> f64 {
        self.step_s
    }

    fn policy_id(policy: &ToyPolicy) -> u64 {
        policy.id
    }

    fn lookahead(
        &mut self,
        policy: &ToyPolicy,
        scene: &ToyScene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        waypoints.clear();
        let mut q = *start_q_rad;
        let mut min_d = f64::INFINITY;
        let mut arm = ToyArm;
        let mut safe = true;
        let mut steps = 0;
        for _ in 0..self.steps {
            let mut e = [0.0; DOF];
            for j in 0..DOF {
                e[j] = policy.target_rad[j] - q[j];
            }
            if e.iter().all(|x| x.abs() < self.tolerance_rad) {
                break;
            }
            let v = policy.act(&e);
            for j in 0..DOF {
                q[j] += v[j] * self.step_s;
            }
            steps += 1;
            waypoints.push(q);
            let d = arm.min_distance_m(&q, scene);
            min_d = min_d.min(d);
            if d < self.min_distance_m {
                safe = false;
                break;
            }
        }
        let task_ok = safe
            && (0..DOF).all(|j| (policy.target_rad[j] - q[j]).abs() < self.tolerance_rad * 2.0);
        Verdict {
            task_ok,
            safe,
            min_distance_m: min_d,
            steps: steps as u32,
            policy_id: policy.id,
        }
    }

    /// With [`ToyLookahead::goal_check`]: the goal is taken when a box holds the toy's goal
    /// target point (the TCP at `policy`'s joint target, its one goal posture).
    fn goal_taken(&mut self, policy: &ToyPolicy, scene: &ToyScene) -> Option<InfeasibleReason> {
        if !self.goal_check {
            return None;
        }
        let tcp = ToyArm::points_m(&policy.target_rad)[4];
        (0..scene.count)
            .map(|i| (i, box_distance(&tcp, &scene.centers_m[i], &scene.half_m[i])))
            .find(|(_, d)| *d < 0.0)
            .map(|(i, d)| InfeasibleReason::NoGoalPosture {
                blocker: Blocker::Box(i),
                link: LINK_TOOL,
                deficit_m: self.min_distance_m - d,
                postures_tried: 1,
            })
    }

    fn goal_approach(
        &mut self,
        policy: &ToyPolicy,
        _scene: &ToyScene,
        path_q_rad: &[Joints],
    ) -> GoalApproach {
        GoalApproach {
            closest_m: toy_closest_approach_m(&toy_goal_target_m(policy), path_q_rad),
            tolerance_m: self.goal_tolerance_m,
        }
    }
}

/// A cycle over the [`ToyArm`] and an in-process arm standing at `start` (velocity limit
/// 3 rad/s per joint), configured from `cfg`, with its hand-overs: the twin's end and the
/// cycle's log. The rig the runtime's tests step on a manual clock.
pub fn toy_cycle(
    cfg: &crate::config::RuntimeConfig,
    start: Joints,
) -> (
    crate::cycle::Cycle<ToyArm, crate::cycle::link::InProcessArm>,
    crate::cycle::TwinIo<ToyScene>,
    crate::rt::rt_log::RtLogDrain<crate::cycle::CycleEvent>,
) {
    use crate::cycle::shield::{Shield, ShieldLimits};
    let limits = ShieldLimits::from_config(&cfg.limits, &cfg.shield);
    let (twin_io, cycle_io, log) = crate::cycle::wire::<ToyScene>();
    let arm = crate::cycle::link::InProcessArm::new(
        start,
        cfg.limits.joint_min_rad,
        cfg.limits.joint_max_rad,
        [3.0; DOF],
    );
    let cycle = crate::cycle::Cycle::new(
        crate::cycle::CycleConfig::from_runtime(cfg),
        Shield::new(ToyArm, limits),
        crate::cycle::brake::Brake::new(&cfg.limits),
        arm,
        cycle_io,
    );
    (cycle, twin_io, log)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fk_of_the_upright_arm_is_a_vertical_column() {
        let tcp = ToyArm.tcp_position_m(&[0.3, 0.0, 0.0, 0.0, 0.0]);
        assert!(tcp[0].abs() < 1e-12 && tcp[1].abs() < 1e-12);
        assert!((tcp[2] - LINKS_M.iter().sum::<f64>()).abs() < 1e-12);
        let p = ToyArm.tcp_position_m(&[
            std::f64::consts::FRAC_PI_2,
            std::f64::consts::FRAC_PI_2,
            0.0,
            0.0,
            0.0,
        ]);
        assert!(
            (p[1] - 0.74).abs() < 1e-9 && (p[2] - 0.267).abs() < 1e-9,
            "{p:?}"
        );
    }

    #[test]
    fn a_random_policy_reaches_its_target_in_a_free_scene_and_is_unsafe_through_a_box() {
        let mut la = ToyLookahead::default();
        let target = [0.8, 0.6, -0.9, 0.3, 0.0];
        let p = ToyPolicy::random(1, target, 7);
        let mut wps = Vec::new();
        let v = la.lookahead(&p, &ToyScene::empty(), &[0.0; DOF], &mut wps);
        assert!(v.task_ok && v.safe, "{v:?}");
        let mid = wps[wps.len() / 3];
        let mut scene = ToyScene::empty();
        scene.push_obstacle(ToyArm.tcp_position_m(&mid), [0.1; 3]);
        let v = la.lookahead(&p, &scene, &[0.0; DOF], &mut wps);
        assert!(!v.safe && !v.task_ok, "{v:?}");
    }
}
