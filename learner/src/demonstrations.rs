//! Demonstrations from the feasibility planner: the planner's collision-free joint path
//! (`twin::Feasibility::path`) turned into the task's own action space, so that a
//! retraining can start from a policy that already goes around (behaviour cloning,
//! [`crate::ppo::bc`]) instead of exploring from scratch.
//!
//! The task acts with Cartesian TCP steps (`[dx, dy, dz]` ∈ `[-1, 1]³` × `action.scale_m`,
//! turned into joints by the twin's IK each step), not with joints. So the path is
//! **re-tracked in the twin**: its configurations (densified as the planner checked them)
//! give TCP points, and at each step the action moves the TCP toward the path point a
//! little ahead of it (pure pursuit), scaled into the action bounds; the last point is
//! replaced by the goal target. The IK chooses its own arm posture for each TCP position,
//! so the re-tracked episode is checked like any other — it counts only when it reaches the
//! goal without contact ([`Demonstration::success`]) and, given rt-core's settings, when
//! rt-core would approve its plan (`twin::approval::EpisodeApproval`, the one verification
//! the learner's episodes pass too). When a path does not re-track
//! cleanly, [`demonstrate`] plans again with other planner seeds.
//!
//! Planning code: it allocates and is not for the real-time cycle.

use rand_chacha::ChaCha8Rng;
use twin::approval::{ApprovalSettings, EpisodeApproval};
use twin::{
    ACT_DIM, FeasibilityConfig, Joints, PlanOutcome, Scene, TwinEnv, check_goal_postures,
    densify_path, max_joint_gap_rad, plan_path,
};

use crate::random::randn;

/// Joint resolution at which the path is densified before taking its TCP points (rad):
/// the planner's default edge check step.
pub const PATH_STEP_RAD: f64 = 0.02;

/// How far ahead of the TCP the pursued path point lies, in action steps
/// (`action.scale_m`).
pub const LOOKAHEAD_STEPS: f64 = 1.5;

/// One re-tracked episode: what the policy saw and what it should have done.
#[derive(Debug, Clone, PartialEq)]
pub struct Demonstration {
    /// Raw observations before each step (`steps × obs_dim`, the policy's input before
    /// normalisation).
    pub obs: Vec<f32>,
    /// The action taken at each step (`steps × ACT_DIM`, within `[-1, 1]`).
    pub actions: Vec<f32>,
    /// The joints before each step (postures along the way).
    pub joints: Vec<Joints>,
    /// The planner's path it re-tracked.
    pub path: Vec<Joints>,
    /// Observation length.
    pub obs_dim: usize,
    /// The episode reached the goal.
    pub reached: bool,
    /// No step was in contact.
    pub safe: bool,
    /// The joints after the last step.
    pub end_joints: Joints,
}

impl Demonstration {
    /// Steps taken.
    pub fn steps(&self) -> usize {
        self.joints.len()
    }

    /// Reached the goal without any contact: fit to imitate.
    pub fn success(&self) -> bool {
        self.reached && self.safe
    }

    /// The episode's waypoints as rt-core would plan them: the joints after each step.
    pub fn waypoints(&self) -> Vec<Joints> {
        let mut w: Vec<Joints> = self.joints.iter().skip(1).copied().collect();
        w.push(self.end_joints);
        w
    }

    /// [`Self::success`], and rt-core would approve the plan in `scene` (with `approval`;
    /// `None`: no such check).
    pub fn approved(
        &self,
        env: &TwinEnv,
        scene: &Scene,
        approval: Option<&mut EpisodeApproval>,
    ) -> bool {
        self.success() && approval.is_none_or(|a| a.approve(env, scene, &self.waypoints()).is_ok())
    }
}

/// The TCP points of `path` (densified at [`PATH_STEP_RAD`]), m.
pub fn path_tcp_points_m(env: &TwinEnv, path: &[Joints]) -> Vec<[f64; 3]> {
    densify_path(path, PATH_STEP_RAD)
        .iter()
        .map(|q| {
            let p = env.model().tcp_m(q);
            [p.x, p.y, p.z]
        })
        .collect()
}

fn dist_m(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The action toward `target_m` from `tcp_m`: the displacement in action units, scaled down
/// (direction kept) so that no component exceeds 1.
pub fn action_toward(tcp_m: &[f64; 3], target_m: &[f64; 3], scale_m: f64) -> [f32; ACT_DIM] {
    let mut a: [f64; 3] = std::array::from_fn(|k| (target_m[k] - tcp_m[k]) / scale_m);
    let biggest = a.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    if biggest > 1.0 {
        a = a.map(|v| v / biggest);
    }
    a.map(|v| v as f32)
}

/// The pure-pursuit expert along a path's TCP points: from any TCP position, the action
/// toward the path point [`LOOKAHEAD_STEPS`] ahead of the nearest point (searched forward
/// from the last one, so the expert never turns back), the goal target after the last one.
/// It labels states off the path too (corrections back onto it).
#[derive(Debug, Clone)]
pub struct PathExpert {
    points_m: Vec<[f64; 3]>,
    goal_m: [f64; 3],
    scale_m: f64,
    lookahead_m: f64,
    i: usize,
}

/// Path points searched ahead of the last nearest one.
const SEARCH_WINDOW: usize = 40;

impl PathExpert {
    /// The expert for `path` in `env`'s task with the goal target `goal_m`.
    pub fn new(env: &TwinEnv, path: &[Joints], goal_m: [f64; 3]) -> Self {
        let scale_m = env.config().action.scale_m;
        Self {
            points_m: path_tcp_points_m(env, path),
            goal_m,
            scale_m,
            lookahead_m: LOOKAHEAD_STEPS * scale_m,
            i: 0,
        }
    }

    /// The expert along the polyline through `points_m` (TCP points, m), densified at
    /// `step_m`, with the goal target `goal_m` after its last point.
    pub fn through_points(
        points_m: &[[f64; 3]],
        goal_m: [f64; 3],
        scale_m: f64,
        step_m: f64,
    ) -> Self {
        let mut dense = Vec::new();
        for w in points_m.windows(2) {
            let n = (dist_m(&w[0], &w[1]) / step_m.max(1e-4)).ceil().max(1.0) as usize;
            dense.extend((0..n).map(|k| {
                let f = k as f64 / n as f64;
                std::array::from_fn(|c| w[0][c] + f * (w[1][c] - w[0][c]))
            }));
        }
        dense.extend(points_m.last().copied());
        Self {
            points_m: dense,
            goal_m,
            scale_m,
            lookahead_m: LOOKAHEAD_STEPS * scale_m,
            i: 0,
        }
    }

    /// Back to the path's start.
    pub fn restart(&mut self) {
        self.i = 0;
    }

    /// The action at TCP position `tcp_m`.
    pub fn action(&mut self, tcp_m: &[f64; 3]) -> [f32; ACT_DIM] {
        let n = self.points_m.len();
        let end = (self.i + SEARCH_WINDOW).min(n);
        if let Some(j) = (self.i..end).min_by(|&a, &b| {
            dist_m(tcp_m, &self.points_m[a]).total_cmp(&dist_m(tcp_m, &self.points_m[b]))
        }) {
            self.i = j;
        }
        let mut j = self.i;
        while j + 1 < n && dist_m(tcp_m, &self.points_m[j]) <= self.lookahead_m {
            j += 1;
        }
        let target = if j + 1 >= n {
            self.goal_m
        } else {
            self.points_m[j]
        };
        action_toward(tcp_m, &target, self.scale_m)
    }
}

/// Re-tracks `path` (joint waypoints from the start posture to a goal posture) in `scene`
/// with `env` (reset first; left at the episode's end), recording observations of length
/// `obs_dim`, actions and joints. See the module docs.
pub fn retrack(env: &mut TwinEnv, scene: &Scene, path: &[Joints], obs_dim: usize) -> Demonstration {
    retrack_noisy(env, scene, path, obs_dim, None)
}

/// [`retrack`], executing each action with Gaussian noise of std `noise.0` (per component,
/// then clipped) drawn from `noise.1` while recording the expert's clean action as the
/// label (noise injection: the states a slightly wrong imitator visits, with the
/// corrections back onto the path). Stops at contact.
pub fn retrack_noisy(
    env: &mut TwinEnv,
    scene: &Scene,
    path: &[Joints],
    obs_dim: usize,
    mut noise: Option<(f32, &mut ChaCha8Rng)>,
) -> Demonstration {
    let max_steps = env.config().episode.max_steps as usize;
    let mut obs = env.reset(scene);
    let goal_m = {
        let t = env.target_m();
        [t.x, t.y, t.z]
    };
    let mut expert = PathExpert::new(env, path, goal_m);
    let mut demo = Demonstration {
        obs: Vec::with_capacity(max_steps * obs_dim),
        actions: Vec::with_capacity(max_steps * ACT_DIM),
        joints: Vec::with_capacity(max_steps),
        path: path.to_vec(),
        obs_dim,
        reached: false,
        safe: true,
        end_joints: env.joints(),
    };
    for _ in 0..max_steps {
        let tcp = {
            let t = env.tcp_m();
            [t.x, t.y, t.z]
        };
        let action = expert.action(&tcp);
        demo.obs.extend_from_slice(&obs[..obs_dim]);
        demo.actions.extend_from_slice(&action);
        demo.joints.push(env.joints());
        let mut executed = action;
        if let Some((std, rng)) = noise.as_mut() {
            for v in &mut executed {
                *v = (*v + *std * randn(rng)).clamp(-1.0, 1.0);
            }
        }
        let out = env.step(&executed);
        obs = out.obs;
        demo.safe &= out.safe;
        demo.reached = out.task_done;
        demo.end_joints = env.joints();
        if out.terminated || out.truncated {
            break;
        }
    }
    demo
}

/// Via points of [`via_point_route`]: centres x, y and heights above the table (m).
const VIA_X_M: [f64; 5] = [0.15, 0.25, 0.35, 0.45, 0.55];
const VIA_Y_M: [f64; 7] = [-0.45, -0.30, -0.15, 0.0, 0.15, 0.30, 0.45];
const VIA_Z_M: [f64; 4] = [0.10, 0.25, 0.40, 0.50];

/// A clean route through one via point ([`via_point_route`]).
#[derive(Debug, Clone)]
pub struct ViaRoute {
    /// The pure-pursuit expert along start → via point → goal, at its start.
    pub expert: PathExpert,
    /// The joints the twin passed through following it, start to goal (a joint path whose
    /// TCP points are the route as driven, for [`retrack`] and [`retrack_noisy`]).
    pub joints: Vec<Joints>,
}

/// A TCP route start → via point → goal that the task's own steps (pure pursuit, the twin's
/// IK choosing the posture) follow to the goal with no contact, via points of a fixed grid
/// (140) tried shortest route first. It also serves worlds whose planner paths the TCP
/// cannot re-track (the planner chose an elbow posture the per-step IK does not): in
/// distillation 2 of 40 instead of 4–6 of 40 cluttered and adversarial benchmark worlds go
/// untaught.
pub fn via_point_route(env: &TwinEnv, scene: &Scene, goal_m: [f64; 3]) -> Option<ViaRoute> {
    let s = env.start_tcp_m();
    let start_m = [s.x, s.y, s.z];
    let table = scene.table_height_m;
    let mut vias: Vec<([f64; 3], f64)> = VIA_X_M
        .iter()
        .flat_map(|&x| {
            VIA_Y_M
                .iter()
                .flat_map(move |&y| VIA_Z_M.iter().map(move |&z| [x, y, table + z]))
        })
        .map(|v| (v, dist_m(&start_m, &v) + dist_m(&v, &goal_m)))
        .collect();
    vias.sort_by(|a, b| a.1.total_cmp(&b.1));
    let scale_m = env.config().action.scale_m;
    let max_steps = env.config().episode.max_steps;
    let mut tw = env.clone();
    let mut joints = Vec::with_capacity(max_steps as usize + 1);
    for (via, _) in vias {
        let mut expert =
            PathExpert::through_points(&[start_m, via, goal_m], goal_m, scale_m, 0.005);
        let proto = expert.clone();
        tw.reset(scene);
        joints.clear();
        let mut clean = false;
        for _ in 0..max_steps {
            joints.push(tw.joints());
            let t = tw.tcp_m();
            let a = expert.action(&[t.x, t.y, t.z]);
            let out = tw.step(&a);
            if out.terminated || out.truncated {
                clean = out.task_done && out.safe;
                break;
            }
        }
        if clean {
            joints.push(tw.joints());
            return Some(ViaRoute {
                expert: proto,
                joints,
            });
        }
    }
    None
}

/// What [`demonstrate`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoOutcome {
    /// The first demonstration that succeeded, if any.
    pub demonstration: Option<Demonstration>,
    /// Paths re-tracked (the given one included).
    pub paths_tried: usize,
    /// Of those, how many reached the goal without contact when re-tracked (the search
    /// stops at the first, so 0 or 1).
    pub paths_succeeded: usize,
    /// The demonstration follows a via-point route ([`via_point_route`]): no planner path
    /// re-tracked cleanly.
    pub via_point: bool,
}

/// A successful demonstration for `scene`: re-tracks `first_path` (the feasibility check's,
/// when given), then plans again to one safe goal posture at a time (IK from many seeds,
/// `cfg.goal_seeds`; postures nearest the start posture first, since the task's IK keeps
/// the arm near it; `plan_path` with `cfg.planner`) until one path re-tracks to the goal
/// without contact or `tries` paths in all have been tried; then, when none did, the
/// joints of a clean via-point route ([`via_point_route`]) re-tracked the same way. With
/// rt-core's `approval` settings a demonstration counts only when rt-core would approve its
/// plan ([`Demonstration::approved`]).
pub fn demonstrate(
    env: &TwinEnv,
    approval: Option<&ApprovalSettings>,
    scene: &Scene,
    first_path: Option<&[Joints]>,
    cfg: FeasibilityConfig,
    tries: usize,
    obs_dim: usize,
) -> DemoOutcome {
    let mut tw = env.clone();
    let mut verifier = approval.map(|a| EpisodeApproval::new(a, env));
    let start = env.config().start.joints_rad;
    let mut out = DemoOutcome {
        demonstration: None,
        paths_tried: 0,
        paths_succeeded: 0,
        via_point: false,
    };
    let mut goals: Option<Vec<Joints>> = None;
    let mut next_goal = 0usize;
    for k in 0..tries {
        let path: Vec<Joints> = match (k, first_path) {
            (0, Some(p)) => p.to_vec(),
            _ => {
                let g = goals.get_or_insert_with(|| {
                    let mut g: Vec<Joints> = check_goal_postures(env, scene, cfg.goal_seeds)
                        .postures
                        .iter()
                        .map(|p| p.joints)
                        .collect();
                    g.sort_by(|a, b| {
                        max_joint_gap_rad(a, &start).total_cmp(&max_joint_gap_rad(b, &start))
                    });
                    g
                });
                let Some(goal) = g.get(next_goal) else {
                    break;
                };
                next_goal += 1;
                match plan_path(env, scene, &start, std::slice::from_ref(goal), cfg.planner) {
                    PlanOutcome::Path { path, .. } => path,
                    PlanOutcome::NoPath { .. } => continue,
                }
            }
        };
        out.paths_tried += 1;
        let demo = retrack(&mut tw, scene, &path, obs_dim);
        if demo.approved(env, scene, verifier.as_mut()) {
            out.paths_succeeded += 1;
            out.demonstration = Some(demo);
            break;
        }
        tracing::debug!(
            try_ = k,
            reached = demo.reached,
            safe = demo.safe,
            steps = demo.steps(),
            "path did not re-track cleanly"
        );
    }
    if out.demonstration.is_none() {
        // No planner path re-tracked: drive a via-point route instead (the cluttered world 6
        // of the adaptation benchmark's seed 1: 16 planner paths over its 5 demonstration
        // scenes, none re-tracked, and PPO alone did not learn it in 30 s).
        tw.reset(scene);
        let t = tw.target_m();
        if let Some(route) = via_point_route(env, scene, [t.x, t.y, t.z]) {
            out.paths_tried += 1;
            let demo = retrack(&mut tw, scene, &route.joints, obs_dim);
            if demo.approved(env, scene, verifier.as_mut()) {
                out.paths_succeeded += 1;
                out.via_point = true;
                out.demonstration = Some(demo);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::twin_env::TwinTask;
    use twin::{Feasibility, check_feasibility};

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    #[test]
    fn the_action_toward_a_point_keeps_its_direction_within_the_bounds() {
        let a = action_toward(&[0.0, 0.0, 0.0], &[0.03, -0.015, 0.0], 0.015);
        assert_eq!(a, [1.0, -0.5, 0.0]);
        let b = action_toward(&[0.0, 0.0, 0.0], &[0.0075, 0.0, 0.0], 0.015);
        assert_eq!(b, [0.5, 0.0, 0.0]);
    }

    #[test]
    fn the_tall_box_path_re_tracks_to_the_goal_without_contact() {
        let task = TwinTask::load(&assets().join("task.toml"), None).expect("task");
        let file = shm_schemas::scene_file::SceneFile::load(&assets().join("scenes/tall_box.toml"))
            .expect("scene file");
        let scene = Scene::from_file(&file).expect("scene");
        // The straight line runs into the box: the demonstration has to go around.
        let mut tw = task.env.clone();
        let line = tw.straight_line_policy();
        let straight = twin::rollout(&mut tw, &scene, |o| line.act(o), None);
        assert!(!(straight.success && straight.safe));
        let start = task.env.config().start.joints_rad;
        let cfg = FeasibilityConfig::default();
        let verdict = check_feasibility(&task.env, &scene, &start, cfg);
        assert!(
            matches!(verdict, Feasibility::Feasible { .. }),
            "{verdict:?}"
        );
        let obs_dim = task.env.config().obs_dim();
        let out = demonstrate(
            &task.env,
            task.approval(),
            &scene,
            verdict.path(),
            cfg,
            8,
            obs_dim,
        );
        let demo = out.demonstration.expect("a demonstration");
        assert!(demo.success());
        assert_eq!(demo.obs.len(), demo.steps() * obs_dim);
        assert_eq!(demo.actions.len(), demo.steps() * ACT_DIM);
        assert!(demo.actions.iter().all(|a| (-1.0..=1.0).contains(a)));
        // Replaying the recorded actions gives the same clean episode.
        let mut k = 0;
        let replay = twin::rollout(
            &mut tw,
            &scene,
            |_| {
                let a = [
                    demo.actions[3 * k],
                    demo.actions[3 * k + 1],
                    demo.actions[3 * k + 2],
                ];
                k = (k + 1).min(demo.steps() - 1);
                a
            },
            None,
        );
        assert!(replay.success && replay.safe, "{replay:?}");
        assert!(!out.via_point, "the planner's path re-tracks here");
    }

    #[test]
    fn without_a_planner_path_that_re_tracks_a_via_point_route_is_demonstrated() {
        let task = TwinTask::load(&assets().join("task.toml"), None).expect("task");
        let file = shm_schemas::scene_file::SceneFile::load(&assets().join("scenes/tall_box.toml"))
            .expect("scene file");
        let scene = Scene::from_file(&file).expect("scene");
        let obs_dim = task.env.config().obs_dim();
        // No planner path tried (0 tries): only the via-point route can demonstrate it.
        let out = demonstrate(
            &task.env,
            task.approval(),
            &scene,
            None,
            FeasibilityConfig::default(),
            0,
            obs_dim,
        );
        assert!(out.via_point, "{:?}", out.paths_tried);
        assert_eq!((out.paths_tried, out.paths_succeeded), (1, 1));
        let demo = out.demonstration.expect("a demonstration");
        assert!(demo.success());
        // The route's joints start at the start posture and end where the goal was reached.
        let mut tw = task.env.clone();
        tw.reset(&scene);
        let t = tw.target_m();
        let route = via_point_route(&task.env, &scene, [t.x, t.y, t.z]).expect("a route");
        assert_eq!(route.joints[0], task.env.config().start.joints_rad);
        let end = task.env.model().tcp_m(route.joints.last().expect("joints"));
        assert!(
            (end - t).norm() <= task.env.config().success.tolerance_m,
            "{end:?} vs {t:?}"
        );
    }

    /// The figure of the README: of the feasible worlds of the benchmark's generator (`learner
    /// worlds --seed 7`), how many get a clean demonstration, from the first path and within
    /// 6 paths. `scripts/cargo.sh test --release -p learner -- --ignored
    /// demonstration_fraction --nocapture` (env `DEMO_WORLDS`, default 40).
    #[test]
    #[ignore = "a measurement (tens of seconds), not a check"]
    fn demonstration_fraction_on_benchmark_worlds() {
        use rand::SeedableRng;
        let task = TwinTask::load(&assets().join("task.toml"), None).expect("task");
        let n: usize = std::env::var("DEMO_WORLDS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(40);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let start = task.env.config().start.joints_rad;
        let cfg = FeasibilityConfig::default();
        let obs_dim = task.env.config().obs_dim();
        let (mut feasible, mut first, mut any) = (0, 0, 0);
        for i in 0..n {
            let scene = task.env.sample_world(&mut rng);
            let verdict = check_feasibility(&task.env, &scene, &start, cfg);
            if !verdict.is_feasible() {
                continue;
            }
            feasible += 1;
            let out = demonstrate(
                &task.env,
                task.approval(),
                &scene,
                verdict.path(),
                cfg,
                6,
                obs_dim,
            );
            if out.demonstration.is_some() {
                any += 1;
                if out.paths_tried == 1 {
                    first += 1;
                }
            } else {
                println!(
                    "world {i}: no clean demonstration in {} paths",
                    out.paths_tried
                );
            }
        }
        println!(
            "{n} worlds, {feasible} feasible: clean demonstration from the first path {first}, \
             within 6 paths {any}"
        );
    }
}
