//! The generators: deterministic, within their documented ranges, every world proven
//! feasible and its path re-tracked, and no code shared with (or used by) training: the
//! generators name none of the training samplers, and Cargo's dependency graph keeps them
//! out of the learner (only the `unseen-worlds` benchmark depends on them).

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
fn the_generators_call_none_of_the_training_samplers() {
    // worldgen depends on the twin (for its planner and rollouts), so the dependency graph
    // cannot keep it from the twin's training samplers: their names must not appear.
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
}

/// The workspace's packages with their declared dependencies (`cargo metadata --no-deps`:
/// offline, nothing resolved or downloaded).
fn metadata() -> serde_json::Value {
    let out = std::process::Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .arg("--manifest-path")
        .arg(root().join("Cargo.toml"))
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("cargo metadata's JSON")
}

/// The workspace packages in the normal (not dev, not build) dependency closure of the
/// workspace package `name`, itself included. Only workspace packages can depend on
/// `worldgen` (a path crate no registry crate knows), so the walk stays among them; a
/// dependency is followed whatever its platform or optionality.
fn normal_closure(meta: &serde_json::Value, name: &str) -> std::collections::BTreeSet<String> {
    let packages = meta["packages"].as_array().expect("packages");
    let package = |n: &str| packages.iter().find(|p| p["name"] == n);
    assert!(package(name).is_some(), "{name} is not a workspace package");
    let mut names = std::collections::BTreeSet::new();
    let mut stack = vec![name.to_owned()];
    while let Some(n) = stack.pop() {
        let Some(p) = package(&n) else {
            continue; // a registry crate
        };
        if !names.insert(n) {
            continue;
        }
        for dep in p["dependencies"].as_array().expect("dependencies") {
            if dep["kind"].is_null() {
                stack.push(dep["name"].as_str().expect("a dependency name").to_owned());
            }
        }
    }
    names
}

#[test]
fn training_cannot_reach_the_benchmark_worlds_by_cargos_dependency_graph() {
    // The guarantee is Cargo's: a crate that does not depend on `worldgen`, directly or
    // through another, cannot name it. Training (the learner, the twin it trains on) and
    // the policy rt-core runs must not; the benchmark (`unseen-worlds`) must, which also
    // shows that the walk finds `worldgen` where it is.
    let meta = metadata();
    let bench = normal_closure(&meta, "unseen-worlds");
    assert!(
        bench.contains("worldgen") && bench.contains("learner"),
        "the benchmark's closure: {bench:?}"
    );
    for training in ["learner", "twin", "policy"] {
        let deps = normal_closure(&meta, training);
        assert!(
            deps.contains(training) && deps.len() > 1,
            "{training}: {deps:?}"
        );
        assert!(
            !deps.contains("worldgen"),
            "{training} depends on the benchmark's world generators (worldgen)"
        );
    }
    // Nor the other way round: the generators share no code with training.
    let generators = normal_closure(&meta, "worldgen");
    assert!(
        !generators.contains("learner"),
        "worldgen depends on the learner: {generators:?}"
    );
}
