//! The lookahead on the real twin: [`TwinLookahead`] runs the whole next episode through
//! `twin::rollout` with an [`MlpPolicy`] (the worker's [`Lookahead`] trait).
//!
//! The twin's episodes start from the task's start posture (`[start] joints_rad`). When the
//! arm stands elsewhere, the lookahead prepends a joint-space approach to the start posture
//! (at most `approach_speed_rad_s`); that approach is not part of the episode, but like every
//! sample of a plan it is checked by the shield against the scene before approval and again
//! in the cycle.
//!
//! "Goal reached" has one meaning: the TCP within the task's `success.tolerance_m` of
//! `scene.goal_target_m(success.goal_hover_m)`, on this lookahead's model (the task's tool
//! installed) — what `twin::TwinEnv::step` calls `task_done`, and what
//! [`TwinLookahead::goal_approach`] measures on the smoothed plan before it is approved.
//!
//! A policy's episode runs in its action space (`MlpPolicy::action_space`): a
//! Cartesian-step policy through `twin::rollout_until` (the twin's per-step IK), a
//! joint-step policy through `twin::rollout_joint` (joint steps toward the goal posture the
//! twin chooses at the reset). Their waypoints are joints either way, and smoothed, checked
//! and streamed the same way; verified sampling perturbs Cartesian steps only.
//!
//! With [`TwinLookahead::set_sampling`] (`[sampling]`), the lookahead also samples: after a
//! policy's deterministic rollout failed, `twin::Sampler` rolls out its perturbed variants
//! on a few threads within the worker's budget, each verified as the deterministic rollout
//! (the same episode, the same contact rule); a passing candidate's plan is the approach, its
//! episode and the same settling on the goal ([`Lookahead::sampled_plan`]).

use std::time::Instant;

use policy::MlpPolicy;
use shm_schemas::ActionSpace;
use twin::{
    Blocker, DOF, FeasibilityConfig, InfeasibleReason, Joints, MAX_EPISODE_STEPS, RobotModel,
    Sampler, SamplingSettings, Scene, TaskConfig, TwinEnv, check_goal_postures, max_joint_gap_rad,
    rollout_joint, rollout_until,
};

/// "Goal reached" on a path, and the settling of an episode's end onto the goal: the twin's
/// verification's (`twin::approval`), which the learner runs too.
pub use twin::approval::{SETTLE_DONE_M, SETTLE_STEPS, tcp_goal_approach};

use crate::twin_thread::worker::goal_taken::goal_overlap_reason;
use crate::twin_thread::worker::{GoalApproach, Lookahead, Sampled, Verdict};

/// How the lookahead picks the executed actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LookaheadActions {
    /// The policy's actions (production).
    Policy,
    /// The task's scripted straight-line actions, while still evaluating the policy at
    /// every step (the bench: random-weight policies, plans that always pass).
    ScriptedWithPolicyCost,
}

/// The lookahead on the twin: `twin::rollout` with an [`MlpPolicy`].
#[derive(Debug, Clone)]
pub struct TwinLookahead {
    env: TwinEnv,
    start_q_rad: Joints,
    step_s: f64,
    wps: heapless::Vec<Joints, MAX_EPISODE_STEPS>,
    actions: LookaheadActions,
    /// Speed of the approach to the start posture, rad/s.
    pub approach_speed_rad_s: f64,
    /// Blind (`--no-lookahead`): the episode runs on through contact, as the policy would
    /// on an arm nobody checks.
    pub blind: bool,
    /// Verified sampling, when on (`[sampling]`).
    sampler: Option<Box<Sampler>>,
}

impl TwinLookahead {
    /// Over a robot model and the task.
    pub fn new(model: RobotModel, task: TaskConfig, actions: LookaheadActions) -> Self {
        let start_q_rad = task.start.joints_rad;
        let step_s = task.episode.step_period_s;
        Self {
            env: TwinEnv::new(model, task),
            start_q_rad,
            step_s,
            wps: heapless::Vec::new(),
            actions,
            approach_speed_rad_s: 0.5,
            blind: false,
            sampler: None,
        }
    }

    /// Turns verified sampling on with `settings` (its environments and buffers are made
    /// here), or off with `None`.
    pub fn set_sampling(&mut self, settings: Option<SamplingSettings>) {
        self.sampler = settings.map(|s| Box::new(Sampler::new(&self.env, s)));
    }

    /// The joint-space approach from `start_q_rad` to the task's start posture (none when
    /// the arm stands there), written to `waypoints` (cleared first).
    fn approach(&self, start_q_rad: &Joints, waypoints: &mut Vec<Joints>) {
        waypoints.clear();
        let gap = max_joint_gap_rad(&self.start_q_rad, start_q_rad);
        if gap > 1e-3 {
            let n = (gap / (self.approach_speed_rad_s * self.step_s))
                .ceil()
                .max(1.0) as usize;
            for k in 1..=n {
                let t = k as f64 / n as f64;
                let mut q = [0.0; DOF];
                for j in 0..DOF {
                    q[j] = start_q_rad[j] + (self.start_q_rad[j] - start_q_rad[j]) * t;
                }
                waypoints.push(q);
            }
        }
    }

    /// The task's start posture, rad.
    pub fn start_q_rad(&self) -> Joints {
        self.start_q_rad
    }

    /// Settles a successful episode's end on the goal target (`twin::approval::settle_on_goal`).
    fn settle_on_goal(&self, scene: &Scene, waypoints: &mut Vec<Joints>) {
        twin::approval::settle_on_goal(&self.env, self.step_s, scene, waypoints);
    }
}

impl Lookahead for TwinLookahead {
    type Scene = Scene;
    type Policy = MlpPolicy;

    fn step_s(&self) -> f64 {
        self.step_s
    }

    fn policy_id(policy: &MlpPolicy) -> u64 {
        policy.policy_id()
    }

    fn lookahead(
        &mut self,
        policy: &MlpPolicy,
        scene: &Scene,
        start_q_rad: &Joints,
        waypoints: &mut Vec<Joints>,
    ) -> Verdict {
        self.approach(start_q_rad, waypoints);
        // A policy's plan is the rollout in its own action space; the env's observation
        // layout follows it (the joint step's goal posture is chosen at the reset).
        let joint = policy.action_space() == ActionSpace::JointStep
            && self.actions == LookaheadActions::Policy;
        if !joint {
            self.env.set_action_space(ActionSpace::CartesianStep);
        }
        let summary = match self.actions {
            LookaheadActions::Policy if joint => rollout_joint(
                &mut self.env,
                scene,
                |obs| policy.act_joint(obs),
                Some(&mut self.wps),
                !self.blind,
            ),
            LookaheadActions::Policy => rollout_until(
                &mut self.env,
                scene,
                |obs| policy.act(obs),
                Some(&mut self.wps),
                !self.blind,
            ),
            LookaheadActions::ScriptedWithPolicyCost => {
                self.env.reset(scene);
                let scripted = self.env.straight_line_policy();
                rollout_until(
                    &mut self.env,
                    scene,
                    |obs| {
                        std::hint::black_box(policy.act(obs));
                        scripted.act(obs)
                    },
                    Some(&mut self.wps),
                    !self.blind,
                )
            }
        };
        waypoints.extend_from_slice(&self.wps);
        if summary.success && summary.safe && !self.blind {
            self.settle_on_goal(scene, waypoints);
        }
        Verdict {
            task_ok: summary.success,
            safe: summary.safe,
            min_distance_m: summary.min_distance_m,
            steps: summary.steps,
            policy_id: policy.policy_id(),
        }
    }

    /// The policy's perturbed variants (`twin::Sampler`, candidates 1..K: the worker has
    /// seen the deterministic one fail), verified as [`TwinLookahead::lookahead`] verifies
    /// it; nothing without a sampler, in blind mode or with the scripted bench actions.
    ///
    /// # Performance
    /// K − 1 episodes on the sampler's threads, until `deadline`.
    fn sample(&mut self, policy: &MlpPolicy, scene: &Scene, deadline: Instant) -> Sampled {
        let Some(sampler) = self.sampler.as_mut() else {
            return Sampled::default();
        };
        // Sampling perturbs Cartesian steps: not (yet) for a joint-step policy.
        if self.blind
            || self.actions != LookaheadActions::Policy
            || policy.action_space() != ActionSpace::CartesianStep
        {
            return Sampled::default();
        }
        let report = sampler.run(scene, &|obs| policy.act(obs), 1, Some(deadline));
        Sampled {
            of: sampler.settings().candidates,
            tried: report.tried,
            ranked: sampler.ranked().iter().map(|s| s.index).collect(),
            elapsed_s: report.elapsed_s,
        }
    }

    fn sampled_plan(
        &mut self,
        policy: &MlpPolicy,
        scene: &Scene,
        start_q_rad: &Joints,
        index: usize,
        waypoints: &mut Vec<Joints>,
    ) -> Option<Verdict> {
        let summary = self.sampler.as_ref()?.summary(index)?;
        self.approach(start_q_rad, waypoints);
        waypoints.extend_from_slice(self.sampler.as_ref()?.waypoints(index));
        if summary.success && summary.safe {
            self.settle_on_goal(scene, waypoints);
        }
        Some(Verdict {
            task_ok: summary.success,
            safe: summary.safe,
            min_distance_m: summary.min_distance_m,
            steps: summary.steps,
            policy_id: policy.policy_id(),
        })
    }

    /// A box on the goal cube ([`goal_overlap_reason`]), else the learner's goal-posture
    /// check ([`check_goal_postures`], its default seeds) finding every posture at the goal
    /// target blocked by a box. Out of reach, or blocked by the table or the arm itself, is
    /// not a taken goal (the learner's feasibility check says those).
    ///
    /// # Performance
    /// Tens of ms (the check's IK seeds); asked once per settled scene whose candidates all
    /// failed.
    fn goal_taken(&mut self, _policy: &MlpPolicy, scene: &Scene) -> Option<InfeasibleReason> {
        goal_overlap_reason(scene, 0.0).or_else(|| {
            let seeds = FeasibilityConfig::default().goal_seeds;
            check_goal_postures(&self.env, scene, seeds)
                .reason
                .filter(|r| {
                    matches!(
                        r,
                        InfeasibleReason::NoGoalPosture {
                            blocker: Blocker::Box(_),
                            ..
                        }
                    )
                })
        })
    }

    /// The TCP's closest approach to `scene.goal_target_m(success.goal_hover_m)` along the
    /// path, against `success.tolerance_m`: the target, tolerance and TCP (the model with the
    /// task's tool) of `twin::TwinEnv::step`'s `task_done`.
    ///
    /// # Performance
    /// One forward kinematics per sample; no allocation.
    fn goal_approach(
        &mut self,
        _policy: &MlpPolicy,
        scene: &Scene,
        path_q_rad: &[Joints],
    ) -> GoalApproach {
        tcp_goal_approach(&self.env, scene, path_q_rad)
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use rand::SeedableRng;
    use twin::{BoxObstacle, Goal, IkSolver, RobotModel, Scene, TaskConfig, is_safe_posture};

    use super::*;
    use crate::config::RuntimeConfig;
    use crate::cycle::plan::{MotionState, Plan};
    use crate::twin_thread::path_planner::TwinPathPlanner;
    use crate::twin_thread::serve::plan_shield;
    use crate::twin_thread::smoother::PlanSmoother;
    use crate::twin_thread::worker::FallbackPlanner;

    /// A joint-step network that is the joint line to the goal posture, clipped per joint:
    /// h = relu([e; −e]) of the joint error e (observation 1–5), a = clamp((h₊ − h₋) / s, ±1).
    fn joint_line_blob(task: &TaskConfig) -> Box<shm_schemas::PolicyBlob> {
        use shm_schemas::{JOINT_ACT_DIM, JOINT_OBS_DIM, PolicyBlobBuilder};
        let mut w1 = vec![0.0f32; 2 * DOF * JOINT_OBS_DIM];
        let mut w2 = vec![0.0f32; JOINT_ACT_DIM * 2 * DOF];
        let scale = task.action.joint_scale_rad();
        for i in 0..DOF {
            w1[i * JOINT_OBS_DIM + 1 + i] = 1.0;
            w1[(DOF + i) * JOINT_OBS_DIM + 1 + i] = -1.0;
            w2[i * 2 * DOF + i] = (1.0 / scale[i]) as f32;
            w2[i * 2 * DOF + DOF + i] = -(1.0 / scale[i]) as f32;
        }
        PolicyBlobBuilder::new(40, task.hash())
            .activation(shm_schemas::Activation::Relu)
            .action_space(ActionSpace::JointStep)
            .layer(JOINT_OBS_DIM, 2 * DOF, &w1, &[0.0; 2 * DOF])
            .layer(2 * DOF, JOINT_ACT_DIM, &w2, &[0.0; JOINT_ACT_DIM])
            .obs_normalization(&[0.0; JOINT_OBS_DIM], &[1.0; JOINT_OBS_DIM], 100.0)
            .action_scaling(&[1.0; JOINT_ACT_DIM], 1.0)
            .build()
            .unwrap()
    }

    /// Issue 40 item 3: rt-core's lookahead runs a joint-step policy in its own space — to
    /// the goal posture in a free scene, and caught at the wide tall box that stands on its
    /// joint-space path — and a Cartesian-step policy as before, on the same lookahead.
    #[test]
    fn the_lookahead_runs_a_joint_step_policy_in_its_space() {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let loader = policy::PolicyLoader::new(policy::PolicyExpectation::for_task_obs(
            task.hash(),
            task.obs_dim(),
        ));
        let joint = loader.prepare(&joint_line_blob(&task)).unwrap();
        assert_eq!(joint.action_space(), ActionSpace::JointStep);
        let file = |name: &str| {
            let f = shm_schemas::scene_file::SceneFile::load(&assets.join("scenes").join(name))
                .unwrap();
            Scene::from_file(&f).unwrap()
        };
        let boxed = file("wide_tall_box.toml");
        let mut free = boxed;
        free.obstacles.clear();
        let mut la = TwinLookahead::new(model, task, LookaheadActions::Policy);
        let start = task.start.joints_rad;
        let mut wps = Vec::new();
        let v = la.lookahead(&joint, &free, &start, &mut wps);
        assert!(v.task_ok && v.safe, "{v:?}");
        assert_eq!(v.policy_id, 40);
        let goal = la.env.goal_posture().unwrap();
        assert!(
            max_joint_gap_rad(wps.last().unwrap(), &goal) < 0.05,
            "{wps:?}"
        );
        let caught = la.lookahead(&joint, &boxed, &start, &mut wps);
        assert!(!caught.safe && !caught.task_ok, "{caught:?}");

        // The Cartesian policy on the same lookahead: the twin back in its space.
        let cartesian = loader
            .prepare(
                &policy::read_policy_file(&assets.join("policy-distilled/policy.blob")).unwrap(),
            )
            .unwrap();
        let small = file("small_box.toml");
        let v = la.lookahead(&cartesian, &small, &start, &mut wps);
        assert_eq!(la.env.action_space(), ActionSpace::CartesianStep);
        assert!(v.task_ok && v.safe, "{v:?}");
    }

    /// The settling of a plan's end onto the goal target adds no waypoint that breaks the
    /// episode's contact rule: with a box placed so that the posture at the target is too
    /// close to it while the episode's end, 17 mm away, is clear, no waypoint toward it is
    /// added.
    #[test]
    fn settling_onto_the_goal_never_adds_an_unsafe_waypoint() {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let la = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
        let goal = Goal {
            center_m: [0.35, 0.0, 0.025],
            size_m: 0.05,
        };
        let free = Scene::empty(0.0, goal);
        let target = free.goal_target_m(task.success.goal_hover_m);
        let ik = IkSolver::new(&model, task.ik);
        let start = task.start.joints_rad;
        let at_target = ik.solve(&model, &target, &start).joints;
        let end_point = target - nalgebra::Vector3::new(0.017, 0.0, 0.0);
        let episode_end = ik.solve(&model, &end_point, &at_target).joints;
        assert!((model.tcp_m(&episode_end) - target).norm() > 0.015);

        // In the free scene the plan is settled onto the target.
        let mut waypoints = vec![episode_end];
        la.settle_on_goal(&free, &mut waypoints);
        let end_m = (model.tcp_m(waypoints.last().unwrap()) - target).norm();
        assert!(end_m <= SETTLE_DONE_M, "{end_m}");

        // A box beyond the target (+x), moved toward it until the posture at the target
        // breaks the contact rule while the episode's end (17 mm nearer the base) keeps it.
        let env = la.env.clone();
        let mut blocked = None;
        for mm in 0..200 {
            let face_x = target.x + 0.20 - f64::from(mm) * 0.001;
            let mut scene = free;
            scene
                .obstacles
                .push(BoxObstacle {
                    center_m: [face_x + 0.05, 0.0, 0.20],
                    size_m: [0.10, 0.30, 0.40],
                })
                .unwrap();
            if !is_safe_posture(&env, &scene, &at_target) {
                assert!(is_safe_posture(&env, &scene, &episode_end), "no such box");
                blocked = Some(scene);
                break;
            }
        }
        let blocked = blocked.expect("a box that blocks the target posture");
        let mut waypoints = vec![episode_end];
        la.settle_on_goal(&blocked, &mut waypoints);
        for q in &waypoints {
            assert!(is_safe_posture(&env, &blocked, q), "unsafe waypoint {q:?}");
        }
    }

    /// Verified sampling against the planner fallback, twin side, on the worlds of the
    /// task's sampler (seed 26) where a bundled policy's deterministic rollout fails: for
    /// each, the sampling (`[sampling]` as shipped but on, K = 32 in 50 ms on 2 threads), the
    /// best passing candidate's plan smoothed and checked by the shield and the goal check —
    /// and the planner fallback (plan, smooth, shield) on the same world. What separates a
    /// settled scene from a plan handed to the cycle once the deterministic rollout failed.
    /// Prints counts and median / p95 / max; asserts no timing.
    /// `cargo test --release -p rt-core --lib -- --ignored sampling_vs_planner_latency --nocapture`
    #[test]
    #[ignore = "a measurement; prints figures"]
    #[allow(clippy::disallowed_methods)]
    fn sampling_vs_planner_latency() {
        let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let model = RobotModel::load(&assets.join("xarm5.urdf")).unwrap();
        let task = TaskConfig::load(&assets.join("task.toml")).unwrap();
        let model = model.with_tool(task.tool.map(|t| t.capsule()));
        let mut cfg = RuntimeConfig::xarm5_default();
        cfg.sampling.enabled = true;
        let env = TwinEnv::new(model.clone(), task);
        let mut shield = plan_shield(&cfg, &model, false);
        let period_s = 1.0 / cfg.rate_hz;
        let mut smoother = PlanSmoother::new(period_s, cfg.limits, (60.0 * cfg.rate_hz) as usize);
        let start = task.start.joints_rad;
        let state = MotionState::at_rest(start);
        for blob in ["policy/policy.blob", "policy-distilled/policy.blob"] {
            let loader = policy::PolicyLoader::new(policy::PolicyExpectation::for_task_obs(
                task.hash(),
                task.obs_dim(),
            ));
            let policy = loader
                .prepare(&policy::read_policy_file(&assets.join(blob)).unwrap())
                .unwrap();
            let mut la = TwinLookahead::new(model.clone(), task, LookaheadActions::Policy);
            la.set_sampling(Some(cfg.sampling.settings()));
            let mut planner = TwinPathPlanner::new(model.clone(), task, &cfg);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(26);
            let mut wps = Vec::new();
            let (mut failed, mut sampled_ok, mut planner_ok) = (0, 0, 0);
            let (mut t_sampling, mut t_planner) = (Vec::new(), Vec::new());
            let mut smooth_check = |wps: &Vec<Joints>, scene: &Scene| -> Option<Plan> {
                let mut plan = Plan::with_capacity(1, 1, period_s, 0);
                let step_s = task.episode.step_period_s;
                smoother
                    .smooth(&state, wps, step_s, shield.model_mut(), &mut plan)
                    .ok()?;
                shield
                    .check_path(&start, &plan.q_rad, period_s, scene)
                    .ok()?;
                Some(plan)
            };
            for _ in 0..400 {
                let scene = env.sample_world(&mut rng);
                let t0 = std::time::Instant::now();
                let v = la.lookahead(&policy, &scene, &start, &mut wps);
                if v.task_ok && v.safe {
                    continue;
                }
                failed += 1;
                let deadline = t0 + std::time::Duration::from_secs_f64(cfg.sampling.budget_s);
                let sampled = la.sample(&policy, &scene, deadline);
                let mut ok = false;
                for &index in sampled.ranked.iter().take(4) {
                    la.sampled_plan(&policy, &scene, &start, index, &mut wps);
                    let plan = smooth_check(&wps, &scene);
                    if plan.is_some_and(|p| la.goal_approach(&policy, &scene, &p.q_rad).reached()) {
                        ok = true;
                        break;
                    }
                }
                t_sampling.push(t0.elapsed().as_secs_f64());
                sampled_ok += usize::from(ok);
                let t1 = std::time::Instant::now();
                let pv = planner.plan(&scene, &start, &mut wps);
                let pok = pv.task_ok
                    && smooth_check(&wps, &scene)
                        .is_some_and(|p| planner.goal_approach(&scene, &p.q_rad).reached());
                t_planner.push(t1.elapsed().as_secs_f64());
                planner_ok += usize::from(pok);
            }
            print_latency(
                blob,
                &cfg,
                (failed, sampled_ok, planner_ok),
                &mut t_sampling,
                &mut t_planner,
            );
        }
    }

    /// The figures of [`sampling_vs_planner_latency`] for one policy blob: `counts` are the
    /// worlds its rollout failed, those sampling approved and those the planner approved.
    fn print_latency(
        blob: &str,
        cfg: &RuntimeConfig,
        (failed, sampled_ok, planner_ok): (usize, usize, usize),
        t_sampling: &mut [f64],
        t_planner: &mut [f64],
    ) {
        let q = |v: &mut [f64], f: f64| {
            v.sort_by(f64::total_cmp);
            v.get(((v.len().max(1) - 1) as f64 * f).round() as usize)
                .copied()
                .unwrap_or(f64::NAN)
        };
        println!(
            "{blob}: 400 worlds of the task's sampler (seed 26), {failed} failed the \
             deterministic rollout. Sampling (K = {}, {} s budget): {sampled_ok} approved, \
             lookahead + sampling + smooth + shield median {:.4} s, p95 {:.4} s, max {:.4} s. \
             Planner fallback on the same worlds: {planner_ok} approved, plan + smooth + \
             shield median {:.4} s, p95 {:.4} s, max {:.4} s",
            cfg.sampling.candidates,
            cfg.sampling.budget_s,
            q(t_sampling, 0.5),
            q(t_sampling, 0.95),
            q(t_sampling, 1.0),
            q(t_planner, 0.5),
            q(t_planner, 0.95),
            q(t_planner, 1.0),
        );
    }
}
