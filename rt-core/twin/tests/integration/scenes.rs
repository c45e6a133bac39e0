//! The bundled scenes and world script, and the demo story they are built for.

use shm_schemas::scene_file::WorldScript;
use twin::{Joints, MAX_EPISODE_STEPS, OBS_DIM, Scene, rollout};

use super::common::{assets, env, scene};

#[test]
fn scenes_round_trip_through_the_file_format() {
    for name in ["small_box.toml", "tall_box.toml"] {
        let s = scene(name);
        assert_eq!(s.obstacles.len(), 1);
        assert_eq!(Scene::from_file(&s.to_file()).unwrap(), s);
    }
    let small = scene("small_box.toml");
    let tall = scene("tall_box.toml");
    assert!(tall.obstacles[0].height_m() >= 0.30 && tall.obstacles[0].height_m() <= 0.40);
    assert!(small.obstacles[0].height_m() <= 0.10);
}

#[test]
fn demo_world_swaps_in_the_wide_tall_box_and_moves_the_goal_at_10_s() {
    let w = WorldScript::load(&assets().join("scenes/demo_world.toml")).unwrap();
    // The third act (issue 33): a box that crosses the arm's way while it moves.
    assert_eq!(w.steps.len(), 3);
    let (i2, third) = w.scene_at(1e3);
    assert_eq!(i2, 2);
    assert!(third.is_moving(), "{third:?}");
    assert!(!w.scene_at(10.0).1.is_moving());
    let (i0, first) = w.scene_at(9.9);
    let (i1, second) = w.scene_at(10.0);
    assert_eq!((i0, i1), (0, 1));
    assert_eq!(first.name, "small_box");
    assert_eq!(second.name, "wide_tall_box");
    assert!(second.obstacles[0].height_m() >= 0.30);
    assert_ne!(first.goal.center_m, second.goal.center_m);
}

#[test]
fn straight_line_passes_the_small_box_and_hits_the_tall_box() {
    let mut e = env();
    let p = e.straight_line_policy();
    let small = rollout(&mut e, &scene("small_box.toml"), |o| p.act(o), None);
    assert!(small.success && small.safe, "{small:?}");
    assert!(small.steps < 60);
    let tall = scene("tall_box.toml");
    e.reset(&tall);
    let p = e.straight_line_policy();
    let hit = rollout(&mut e, &tall, |o| p.act(o), None);
    assert!(!hit.safe && !hit.success, "{hit:?}");
}

/// Follows waypoints at full speed.
fn waypoint_policy(wps: &[[f64; 3]], scale_m: f64) -> impl FnMut(&[f32; OBS_DIM]) -> [f32; 3] + '_ {
    let mut k = 0;
    move |o| {
        let t = wps[k];
        let d = [
            t[0] - f64::from(o[3]),
            t[1] - f64::from(o[4]),
            t[2] - f64::from(o[5]),
        ];
        if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() < 0.01 && k + 1 < wps.len() {
            k += 1;
        }
        let mut a = d.map(|v| v / scale_m);
        let m = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if m > 1.0 {
            a = a.map(|v| v / m);
        }
        a.map(|v| v as f32)
    }
}

#[test]
fn tall_box_scene_is_solvable_by_a_detour() {
    // Pull in, swing past the box, reach out: the task is possible, only the straight
    // line fails.
    let mut e = env();
    let tall = scene("tall_box.toml");
    e.reset(&tall);
    let target = e.target_m();
    let wps = [
        [0.18, 0.0, 0.25],
        [0.127, -0.127, 0.25],
        [target.x, target.y, target.z],
    ];
    let scale = e.config().action.scale_m;
    let mut waypoints: heapless::Vec<Joints, MAX_EPISODE_STEPS> = heapless::Vec::new();
    let s = rollout(
        &mut e,
        &tall,
        waypoint_policy(&wps, scale),
        Some(&mut waypoints),
    );
    assert!(s.success && s.safe, "{s:?}");
    assert!(s.min_distance_m > 0.0);
    assert_eq!(waypoints.len(), s.steps as usize);
    assert_eq!(*waypoints.last().unwrap(), e.joints());
}

#[test]
fn sampled_scenes_follow_the_curriculum() {
    use rand::SeedableRng;
    use twin::ObstacleClass;
    let mut e = env();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let cfg = *e.config();
    let (mut small_ok, mut large_hit) = (0, 0);
    for _ in 0..40 {
        for class in [ObstacleClass::Small, ObstacleClass::Large] {
            let s = e.sample_scene(&mut rng, class);
            assert_eq!(s.obstacles.len(), 1, "a box is placed");
            let b = s.obstacles[0];
            let range = match class {
                ObstacleClass::Small => cfg.obstacles.small,
                ObstacleClass::Large => cfg.obstacles.large,
            };
            assert!(b.height_m() >= range.height_m[0] && b.height_m() <= range.height_m[1]);
            let g = s.goal.center_m;
            assert!(g[0] >= cfg.sampling.goal_x_m[0] && g[0] <= cfg.sampling.goal_x_m[1]);
            assert!(g[1] >= cfg.sampling.goal_y_m[0] && g[1] <= cfg.sampling.goal_y_m[1]);
            // No contact at the start.
            assert!(
                !e.geometry()
                    .in_contact(&e.model().fk(&cfg.start.joints_rad), &s, 0.0)
            );
            let p = {
                e.reset(&s);
                e.straight_line_policy()
            };
            let r = rollout(&mut e, &s, |o| p.act(o), None);
            match class {
                ObstacleClass::Small => small_ok += u32::from(r.success && r.safe),
                ObstacleClass::Large => large_hit += u32::from(!r.safe),
            }
        }
    }
    // Small boxes are mostly passable on the straight line; tall ones mostly block it.
    assert!(small_ok >= 30, "{small_ok}/40");
    assert!(large_hit >= 30, "{large_hit}/40");
}

#[test]
fn a_scene_holds_max_obstacles_boxes_and_refuses_one_more() {
    use shm_schemas::scene_file::BoxSpec;
    use twin::{MAX_OBSTACLES, SceneError};

    assert_eq!(MAX_OBSTACLES, 16);
    let mut file = scene("small_box.toml").to_file();
    file.obstacles = (0..MAX_OBSTACLES)
        .map(|k| BoxSpec {
            center_m: [0.2 + 0.02 * k as f64, -0.3, 0.03],
            size_m: [0.01, 0.04, 0.06],
            path: Default::default(),
        })
        .collect();
    let full = Scene::from_file(&file).unwrap();
    assert_eq!(full.obstacles.len(), MAX_OBSTACLES);
    assert_eq!(Scene::from_file(&full.to_file()).unwrap(), full);
    // Every box counts in the distance: the last one, moved under the TCP, is the nearest.
    let e = env();
    let mut near = full;
    let tcp = e.tcp_m();
    near.obstacles[MAX_OBSTACLES - 1].center_m = [tcp.x, tcp.y, 0.03];
    let d = e.geometry().distance_to_boxes(e.poses(), &near).unwrap();
    assert_eq!(d.obstacle, Some(MAX_OBSTACLES - 1), "{d:?}");
    let first = file.obstacles[0];
    file.obstacles.push(first);
    assert_eq!(Scene::from_file(&file), Err(SceneError::TooManyObstacles));
}
