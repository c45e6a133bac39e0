//! Criterion benchmarks of the digital twin's per-step work: FK, IK, robot-vs-box
//! distance (all links), the self-collision check, every distance with 16 boxes and a
//! tool, one task step and one 200-step episode; and the goal-posture choice.
//!
//! Run: `scripts/cargo.sh bench -p rt-core --bench twin`. Targets on the 2-core dev
//! machine: IK ≤ 10 µs, distance ≤ 5 µs, step ≤ 20 µs, episode ≤ 4 ms, goal-posture choice
//! ≤ 0.1 ms (issue 40).

// Benchmarks: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use shm_schemas::scene_file::SceneFile;
use twin::{
    IkSolver, RobotGeometry, RobotModel, Scene, TaskConfig, TwinEnv, choose_goal_posture, rollout,
};

fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
}

fn load() -> (RobotModel, TaskConfig, Scene, Scene) {
    let model = RobotModel::load(&assets().join("xarm5.urdf")).expect("bundled URDF");
    let task = TaskConfig::load(&assets().join("task.toml")).expect("bundled task");
    let scene = |n: &str| {
        let f = SceneFile::load(&assets().join("scenes").join(n)).expect("bundled scene");
        Scene::from_file(&f).expect("valid scene")
    };
    (model, task, scene("small_box.toml"), scene("tall_box.toml"))
}

fn benches(c: &mut Criterion) {
    let (model, task, small, tall) = load();
    let q = [0.3, 0.2, -0.8, 0.6, 0.1];

    c.bench_function("twin/fk", |b| b.iter(|| model.fk(black_box(&q))));

    // A per-step IK: 1.5 cm away from the current TCP, the task's settings (≤ 10 iterations).
    let step_ik = IkSolver::new(&model, task.ik);
    let tcp = model.tcp_m(&q);
    let near = tcp + Vector3::new(0.015, -0.01, 0.005);
    c.bench_function("twin/ik_step_1.5cm", |b| {
        b.iter(|| step_ik.solve(&model, black_box(&near), black_box(&q)))
    });
    // A full solve from home to a far target (tolerance 0.1 mm).
    let full_ik = IkSolver::new(&model, twin::IkConfig::default());
    let far = Vector3::new(0.40, -0.20, 0.12);
    let home = model.home();
    c.bench_function("twin/ik_full_from_home", |b| {
        b.iter(|| full_ik.solve(&model, black_box(&far), black_box(&home)))
    });

    // All links against one box (the box near the arm, so no broad-phase shortcut).
    let geometry = RobotGeometry::new(&model);
    let mut env = TwinEnv::new(model.clone(), task);
    env.reset(&small);
    let start_poses = *env.poses();
    c.bench_function("twin/distance_all_links_1_box", |b| {
        b.iter(|| geometry.distance_to_boxes(black_box(&start_poses), black_box(&small)))
    });
    c.bench_function("twin/distance_all_links_box_and_table", |b| {
        b.iter(|| geometry.distance(black_box(&start_poses), black_box(&tall)))
    });

    // The worst case the contract allows: 16 boxes (`MAX_OBSTACLES`) around the arm, a
    // tool on the flange, the table and the self-collision pairs, in one pass.
    let armed = model.clone().with_tool(Some(twin::LinkCapsule {
        frame: 5,
        a_m: [0.0, 0.0, 0.0],
        b_m: [0.0, 0.0, 0.08],
        radius_m: 0.03,
    }));
    let armed_geometry = RobotGeometry::new(&armed);
    let mut full = small;
    full.obstacles.clear();
    for k in 0..twin::MAX_OBSTACLES {
        let angle = k as f64 * std::f64::consts::TAU / twin::MAX_OBSTACLES as f64;
        let _ = full.obstacles.push(twin::BoxObstacle {
            center_m: [0.35 * angle.cos(), 0.35 * angle.sin(), 0.03],
            size_m: [0.04, 0.04, 0.06],
        });
    }
    c.bench_function("twin/self_distance_with_tool", |b| {
        b.iter(|| armed_geometry.self_distance(black_box(&start_poses)))
    });
    c.bench_function("twin/all_distances_16_boxes_tool_self", |b| {
        b.iter(|| armed_geometry.all_distances(black_box(&start_poses), black_box(&full)))
    });

    // The goal posture of the tall-box scene from the task's start: every IK branch of the
    // goal enumerated, checked against the box, the table and the arm itself, ordered.
    let start = env.config().start.joints_rad;
    assert!(choose_goal_posture(&env, &tall, &start).is_ok());
    c.bench_function("twin/goal_posture_tall_box", |b| {
        b.iter(|| choose_goal_posture(black_box(&env), black_box(&tall), black_box(&start)))
    });

    // One task step (IK + FK + distances + reward + observation), cycling through an
    // episode so the arm is in varied postures.
    let policy = env.straight_line_policy();
    c.bench_function("twin/step", |b| {
        env.reset(&small);
        let mut obs = env.observation();
        b.iter(|| {
            let out = env.step(black_box(&policy.act(&obs)));
            obs = out.obs;
            if out.terminated || out.truncated {
                obs = env.reset(&small);
            }
            out.reward
        })
    });

    // One whole 200-step episode: the TCP circles (radius ≈ 6 cm) in free space above the
    // small box, so the episode runs to truncation with a real IK solve every step.
    let circle = |o: &[f32; twin::OBS_DIM]| {
        let phase = std::f32::consts::TAU * 4.0 * o[0];
        [0.5 * phase.cos(), 0.5 * phase.sin(), 0.0]
    };
    let check = rollout(&mut env, &small, circle, None);
    assert_eq!(
        check.steps, 200,
        "the benchmark episode must run its full length"
    );
    c.bench_function("twin/episode_200_steps", |b| {
        b.iter(|| rollout(&mut env, black_box(&small), circle, None))
    });
}

criterion_group!(twin, benches);
criterion_main!(twin);
