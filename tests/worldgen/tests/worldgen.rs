//! The generators: deterministic, within their documented ranges, every world proven
//! feasible and its path re-tracked, and no code shared with (or used by) training.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use twin::{FeasibilityConfig, RobotModel, Scene, TaskConfig, TwinEnv};
use worldgen::{GOAL_GAP_M, Generator, WorldKind, draw_world, generate, track_path, world_rng};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn env() -> TwinEnv {
    let assets = root().join("assets");
    let model = RobotModel::load(&assets.join("xarm5.urdf")).expect("model");
    let task = TaskConfig::load(&assets.join("task.toml")).expect("task");
    TwinEnv::new(model, task)
}

fn draws(env: &TwinEnv, g: Generator, seed: u64, n: usize) -> Vec<(WorldKind, Scene)> {
    let mut rng = world_rng(g, seed);
    (0..n)
        .map(|_| draw_world(g, env, &mut rng).expect("a placement"))
        .collect()
}

#[test]
fn same_seed_same_worlds_and_each_generator_its_own_stream() {
    let env = env();
    for g in Generator::ALL {
        assert_eq!(draws(&env, g, 3, 12), draws(&env, g, 3, 12), "{g}");
        assert_ne!(draws(&env, g, 3, 12), draws(&env, g, 4, 12), "{g}");
    }
    assert_ne!(
        draws(&env, Generator::Uniform, 3, 5)
            .into_iter()
            .map(|d| d.1)
            .collect::<Vec<_>>(),
        draws(&env, Generator::Cluttered, 3, 5)
            .into_iter()
            .map(|d| d.1)
            .collect::<Vec<_>>()
    );
}

#[test]
fn draws_keep_to_their_ranges() {
    let env = env();
    let s = env.config().sampling;
    let start = env.start_tcp_m();
    for g in Generator::ALL {
        for (kind, scene) in draws(&env, g, 9, 60) {
            let [gx, gy, _] = scene.goal.center_m;
            assert!(
                (s.goal_x_m[0]..=s.goal_x_m[1]).contains(&gx)
                    && (s.goal_y_m[0]..=s.goal_y_m[1]).contains(&gy),
                "{g}: goal ({gx}, {gy}) outside the task's ranges"
            );
            assert!((gx - start.x).hypot(gy - start.y) >= s.min_goal_distance_m);
            for b in scene.obstacles.iter() {
                let gap_x = (b.center_m[0] - gx).abs() - (b.size_m[0] + s.goal_size_m) / 2.0;
                let gap_y = (b.center_m[1] - gy).abs() - (b.size_m[1] + s.goal_size_m) / 2.0;
                assert!(
                    gap_x.max(gap_y) >= GOAL_GAP_M - 1e-12,
                    "{g}: a box covers the goal"
                );
                assert!((b.center_m[2] - b.size_m[2] / 2.0 - s.table_height_m).abs() < 1e-12);
            }
            assert!(twin::is_safe_posture(
                &env,
                &scene,
                &env.config().start.joints_rad
            ));
            let n = scene.obstacles.len();
            let tallest = scene
                .obstacles
                .iter()
                .map(|b| b.size_m[2])
                .fold(0.0, f64::max);
            match kind {
                WorldKind::Uniform => assert!((1..=3).contains(&n)),
                WorldKind::Cluttered => {
                    assert_eq!(n, 3);
                    assert!(scene.obstacles.iter().all(|b| b.size_m[2] >= 0.20));
                }
                WorldKind::NearPath => assert_eq!(n, 1),
                WorldKind::PathAndGoal => assert_eq!(n, 2),
                WorldKind::SideGoalTallBase => {
                    assert_eq!(n, 1);
                    assert!(tallest >= 0.30 && (0.27..=0.33).contains(&gy.abs()));
                }
                WorldKind::FarSideTall => assert_eq!(n, 3),
            }
        }
    }
}

#[test]
fn every_generated_world_is_proven_feasible_and_its_path_retracks() {
    let env = env();
    let start = env.config().start.joints_rad;
    for g in Generator::ALL {
        let set = generate(&env, g, 1, 3, FeasibilityConfig::default()).expect("worlds");
        assert_eq!(set.worlds.len(), 3, "{g}");
        for w in &set.worlds {
            let verdict =
                twin::check_feasibility(&env, &w.scene, &start, FeasibilityConfig::default());
            assert!(verdict.is_feasible(), "{g} world {}", w.index);
            let check = track_path(&env, &w.scene, &start, &w.path);
            assert!(check.ok(), "{g} world {}: {check:?}", w.index);
        }
        for s in &set.skipped {
            let verdict =
                twin::check_feasibility(&env, &s.scene, &start, FeasibilityConfig::default());
            assert!(!verdict.is_feasible(), "{g} draw {} was skipped", s.draw);
        }
        let again = generate(&env, g, 1, 3, FeasibilityConfig::default()).expect("worlds");
        let scenes = |s: &worldgen::WorldSet| s.worlds.iter().map(|w| w.scene).collect::<Vec<_>>();
        assert_eq!(scenes(&set), scenes(&again), "{g}: same seed, same worlds");
    }
}

#[test]
fn unknown_generator_names_are_refused_by_name() {
    assert_eq!("cluttered".parse::<Generator>(), Ok(Generator::Cluttered));
    let e = "task"
        .parse::<Generator>()
        .expect_err("not a worldgen generator");
    assert!(e.to_string().contains("\"task\""), "{e}");
}

/// Source text of every `.rs` file under `dir`.
fn sources(dir: &Path) -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("a source folder").flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).expect("source");
                out.push((p, text));
            }
        }
    }
    out
}

#[test]
fn no_code_shared_with_training_and_training_does_not_use_it() {
    // The generators call none of the training samplers.
    for (p, text) in sources(&root().join("tests/worldgen/src")) {
        for banned in [
            "sample_world",
            "sample_scene",
            "twin_env",
            "CurriculumSampler",
        ] {
            assert!(!text.contains(banned), "{} uses {banned}", p.display());
        }
    }
    // Training (the twin and the learner's library) never names the crate; only the
    // benchmark subcommand of the learner binary does.
    for dir in ["rt-core/twin/src", "learner/src"] {
        for (p, text) in sources(&root().join(dir)) {
            let allowed = p.ends_with("cli/worlds.rs");
            assert!(
                allowed || !text.contains("worldgen"),
                "{} uses the benchmark's world generators",
                p.display()
            );
        }
    }
    let twin_toml = std::fs::read_to_string(root().join("rt-core/twin/Cargo.toml")).expect("toml");
    assert!(!twin_toml.contains("worldgen"));
}
