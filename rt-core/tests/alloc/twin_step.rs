//! No allocation in any per-step query: FK, IK, distance, contact, step, rollout.

use nalgebra::Vector3;
use twin::{IkConfig, IkSolver, Joints, MAX_EPISODE_STEPS, RobotGeometry, rollout};

use crate::count_allocations;
use crate::twin_fixtures::{env, model, scene};

#[test]
fn per_step_work_does_not_allocate() {
    let m = model();
    let g = RobotGeometry::new(&m);
    let ik = IkSolver::new(&m, IkConfig::default());
    let small = scene("small_box.toml");
    let tall = scene("tall_box.toml");
    let mut e = env();
    let mut waypoints: heapless::Vec<Joints, MAX_EPISODE_STEPS> = heapless::Vec::new();
    let policy = e.straight_line_policy();
    // Warm up (lazy statics, thread locals).
    e.reset(&small);
    e.step(&[0.1, 0.2, 0.3]);
    let (checksum, allocations) = count_allocations(|| {
        let mut acc = 0.0;
        for i in 0..1000 {
            let q = [0.001 * f64::from(i), 0.2, -0.6, 0.5, 0.0];
            let p = m.fk(&q);
            acc += p.tcp_m().x;
            let r = ik.solve(&m, &Vector3::new(0.3, 0.1, 0.2 + 1e-5 * f64::from(i)), &q);
            acc += r.error_m;
            acc += g.distance(&p, &small).distance_m;
            acc += f64::from(u8::from(g.in_contact(&p, &tall, 0.02)));
        }
        for (k, s) in [&small, &tall].into_iter().cycle().take(20).enumerate() {
            e.reset(s);
            for j in 0..30 {
                let a = [((k + j) % 3) as f32 - 1.0, 0.5, -0.5];
                let out = e.step(&a);
                acc += f64::from(out.reward);
                if out.terminated {
                    break;
                }
            }
            let sum = rollout(&mut e, s, |o| policy.act(o), Some(&mut waypoints));
            acc += sum.return_ + waypoints.len() as f64;
        }
        acc
    });
    assert!(checksum.is_finite());
    assert_eq!(
        allocations, 0,
        "per-step twin work allocated {allocations} times"
    );
}

#[test]
fn the_counter_does_count() {
    // Guard against a counter that cannot fail.
    let (v, n) = count_allocations(|| vec![1u8; 64]);
    assert_eq!(v.len(), 64);
    assert!(n >= 1);
}

/// A full scene (`MAX_OBSTACLES` = 16 boxes), a tool on the flange and the self-collision
/// check: the distance queries and the task step still allocate nothing.
#[test]
fn sixteen_boxes_a_tool_and_self_collision_do_not_allocate() {
    use twin::{BoxObstacle, MAX_OBSTACLES, ToolConfig, TwinEnv};

    let mut task = crate::twin_fixtures::task();
    task.tool = Some(ToolConfig {
        from_m: [0.0, 0.0, 0.0],
        to_m: [0.0, 0.0, 0.08],
        radius_m: 0.03,
    });
    task.validate().unwrap();
    let m = model().with_tool(task.tool.map(|t| t.capsule()));
    let g = RobotGeometry::new(&m);
    assert!(g.has_tool());
    let mut full = scene("small_box.toml");
    full.obstacles.clear();
    for k in 0..MAX_OBSTACLES {
        let angle = k as f64 * std::f64::consts::TAU / MAX_OBSTACLES as f64;
        full.obstacles
            .push(BoxObstacle {
                center_m: [0.45 * angle.cos(), 0.45 * angle.sin(), 0.03],
                size_m: [0.04, 0.04, 0.06],
            })
            .unwrap();
    }
    assert_eq!(full.obstacles.len(), MAX_OBSTACLES);
    let mut e = TwinEnv::new(model(), task);
    assert!(e.geometry().has_tool());
    let policy = e.straight_line_policy();
    e.reset(&full);
    e.step(&[0.1, 0.2, 0.3]);
    let (checksum, allocations) = count_allocations(|| {
        let mut acc = 0.0;
        for i in 0..500 {
            let q = [
                0.01 * f64::from(i),
                0.2,
                -0.6 - 0.004 * f64::from(i),
                0.5,
                0.0,
            ];
            let p = m.fk(&q);
            let all = g.all_distances(&p, &full);
            acc += all.table.distance_m + all.own.distance_m;
            acc += all.boxes.map_or(0.0, |b| b.distance_m);
            acc += g.distance(&p, &full).distance_m;
            acc += f64::from(u8::from(g.in_contact(&p, &full, 0.02)));
            acc += f64::from(u8::from(g.self_collision(&p).is_some()));
        }
        for _ in 0..5 {
            let sum = rollout(&mut e, &full, |o| policy.act(o), None);
            acc += sum.return_;
        }
        acc
    });
    assert!(checksum.is_finite());
    assert_eq!(
        allocations, 0,
        "16 boxes + tool + self-collision allocated {allocations} times"
    );
}

/// The worker's goal check of a smoothed plan (`Lookahead::goal_approach` on the real twin)
/// allocates nothing, and judges a lookahead's own waypoints as the rollout judged them: the
/// same target point and tolerance as `task_done`.
#[test]
fn the_goal_check_of_a_plan_matches_task_done_and_does_not_allocate() {
    use policy::{PolicyExpectation, PolicyLoader};
    use rt_core::twin_thread::Lookahead;
    use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
    use shm_schemas::PolicyBlobBuilder;
    use twin::ACT_DIM;

    let task = crate::twin_fixtures::task();
    let hash = task.hash();
    let blob = PolicyBlobBuilder::random(1, hash, task.obs_dim(), &[64, 64], ACT_DIM, 1)
        .build()
        .unwrap();
    let policy = PolicyLoader::new(PolicyExpectation::for_task_obs(hash, task.obs_dim()))
        .prepare(&blob)
        .unwrap();
    let model = model().with_tool(task.tool.map(|t| t.capsule()));
    let mut la = TwinLookahead::new(
        model.clone(),
        task,
        LookaheadActions::ScriptedWithPolicyCost,
    );
    // The small-box scene's goal, the box taken away: the straight line reaches it.
    let mut small = scene("small_box.toml");
    small.obstacles.clear();
    let mut waypoints = Vec::with_capacity(MAX_EPISODE_STEPS + 64);
    let start = la.start_q_rad();
    let verdict = la.lookahead(&policy, &small, &start, &mut waypoints);
    assert!(verdict.task_ok, "{verdict:?}");
    la.goal_approach(&policy, &small, &waypoints);
    let (approach, allocations) = count_allocations(|| {
        let mut a = la.goal_approach(&policy, &small, &waypoints);
        for k in 1..100 {
            let b = la.goal_approach(&policy, &small, &waypoints[..waypoints.len() - k % 7]);
            a.closest_m = a.closest_m.min(b.closest_m);
        }
        a
    });
    assert_eq!(
        allocations, 0,
        "the goal check allocated {allocations} times"
    );
    assert_eq!(approach.tolerance_m, task.success.tolerance_m);
    assert!(approach.reached(), "{approach:?}");
    // The episode's last step reached the goal, the ones before did not; the waypoints
    // after it settle the TCP on the target (`TwinLookahead`'s settling) and end closest.
    let steps = verdict.steps as usize;
    let before = la.goal_approach(&policy, &small, &waypoints[..steps - 1]);
    assert!(!before.reached(), "{before:?}");
    assert!(
        la.goal_approach(&policy, &small, &waypoints[..steps])
            .reached()
    );
    let target = small.goal_target_m(task.success.goal_hover_m);
    let last = model.tcp_m(&waypoints[waypoints.len() - 1]);
    assert!(((last - target).norm() - approach.closest_m).abs() < 1e-12);
}
