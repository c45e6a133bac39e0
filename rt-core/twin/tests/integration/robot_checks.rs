//! The robot model is trusted only after checks: the tool capsule counts in every distance
//! query, and postures that fold the arm into itself are refused.

use nalgebra::Vector3;
use twin::{
    BoxObstacle, Goal, IkConfig, IkSolver, Joints, RobotGeometry, SELF_COLLISION_MIN_DISTANCE_M,
    Scene, TOOL_FRAME, TaskConfig, TwinEnv,
};

use super::common::{model, task};

/// A gripper: a 10 cm capsule of radius 3 cm straight out of the flange.
fn tool() -> twin::ToolConfig {
    twin::ToolConfig {
        from_m: [0.0, 0.0, 0.0],
        to_m: [0.0, 0.0, 0.10],
        radius_m: 0.03,
    }
}

fn task_with_tool() -> TaskConfig {
    let mut t = task();
    t.tool = Some(tool());
    t.validate().unwrap();
    t
}

/// A box under the flange at the start posture: its top 12.5 cm above the table, 4 cm
/// below link5's padded capsule, 5 mm above the tool's lowest point.
fn box_under_the_gripper() -> Scene {
    let start_tcp = model().tcp_m(&task().start.joints_rad);
    let mut s = Scene::empty(
        0.0,
        Goal {
            center_m: [0.40, 0.25, 0.025],
            size_m: 0.05,
        },
    );
    s.obstacles
        .push(BoxObstacle {
            center_m: [start_tcp.x, start_tcp.y, 0.0625],
            size_m: [0.10, 0.10, 0.125],
        })
        .unwrap();
    s
}

#[test]
fn the_tool_makes_a_pose_that_touches_a_box_with_the_gripper_unsafe() {
    let scene = box_under_the_gripper();
    let q = task().start.joints_rad;
    // Without the tool: clear by several centimetres.
    let bare = model();
    let g = RobotGeometry::new(&bare);
    let d = g.distance(&bare.fk(&q), &scene);
    assert!(d.distance_m > 0.03, "{d:?}");
    // With it: the gripper is in the box.
    let armed = model().with_tool(Some(tool().capsule()));
    let g = RobotGeometry::new(&armed);
    assert!(g.has_tool());
    let p = armed.fk(&q);
    let d = g.distance_to_boxes(&p, &scene).unwrap();
    assert!(d.colliding && d.distance_m < 0.0, "{d:?}");
    assert!(g.in_contact(&p, &scene, 0.0));
    // The task: holding still at the start posture is safe without the tool, contact with it.
    let mut env = TwinEnv::new(model(), task());
    env.reset(&scene);
    assert!(env.step(&[0.0; 3]).safe);
    let mut env = TwinEnv::new(model(), task_with_tool());
    assert!(env.geometry().has_tool());
    env.reset(&scene);
    let out = env.step(&[0.0; 3]);
    assert!(
        !out.safe && out.terminated && !out.self_collision,
        "{out:?}"
    );
    assert!(out.terms.terminal < 0.0);
    // A task without a tool removes a tool the model carried.
    let env = TwinEnv::new(armed, task());
    assert!(!env.geometry().has_tool());
}

#[test]
fn the_tool_counts_against_the_table() {
    // Lower the box scene's table to just under the gripper: the bare arm is clear of it,
    // the armed one is not.
    let q = task().start.joints_rad;
    let tcp = model().tcp_m(&q);
    let mut s = Scene::empty(
        tcp.z - 0.12,
        Goal {
            center_m: [0.40, 0.25, tcp.z - 0.095],
            size_m: 0.05,
        },
    );
    s.obstacles.clear();
    let bare = model();
    let t = RobotGeometry::new(&bare).distance_to_table(&bare.fk(&q), &s);
    assert!(t.distance_m > 0.03, "{t:?}");
    let armed = model().with_tool(Some(tool().capsule()));
    let t = RobotGeometry::new(&armed).distance_to_table(&armed.fk(&q), &s);
    assert!(t.colliding, "{t:?}");
}

/// The wrist driven down into the base (TCP 7 cm above the table on the base axis).
const WRIST_IN_BASE: Joints = [0.0, 0.5, 0.0, 1.0, 0.0];

/// The forearm folded onto the shoulder (joint 3 at its upper limit).
const FOREARM_ON_SHOULDER: Joints = [0.0, -0.5, 0.19, 0.0, 0.0];

#[test]
fn folded_postures_self_collide_and_name_the_links() {
    let m = model();
    let g = RobotGeometry::new(&m);
    let s = g.self_collision(&m.fk(&WRIST_IN_BASE)).unwrap();
    assert_eq!(s.links, [0, 4], "{s:?}");
    assert!(s.distance_m < -0.1, "{s:?}");
    let s = g.self_collision(&m.fk(&FOREARM_ON_SHOULDER)).unwrap();
    assert_eq!(s.links, [1, 3], "{s:?}");
    assert!(s.distance_m < SELF_COLLISION_MIN_DISTANCE_M - 0.03, "{s:?}");
    // The tool is checked too: folded back onto the forearm at joint 4's limit.
    let armed = model().with_tool(Some(tool().capsule()));
    let g = RobotGeometry::new(&armed);
    let s = g.self_distance(&armed.fk(&[0.0, -0.383, -0.371, std::f64::consts::PI, 0.0]));
    assert!(s.colliding() && s.links[1] == TOOL_FRAME, "{s:?}");
    assert_eq!(armed.link_name(TOOL_FRAME), "tool");
}

#[test]
fn home_zero_and_reaches_across_the_goal_ranges_are_clear_of_themselves() {
    let m = model();
    let armed = model().with_tool(Some(tool().capsule()));
    let t = task();
    let ik = IkSolver::new(&m, IkConfig::default());
    let s = &t.sampling;
    let hover = t.success.goal_hover_m + s.goal_size_m;
    let mut postures = vec![t.start.joints_rad, m.home(), [0.0; 5]];
    for xi in 0..=5 {
        for yi in 0..=7 {
            for dz in [0.0, 0.1, 0.2] {
                let x = s.goal_x_m[0] + (s.goal_x_m[1] - s.goal_x_m[0]) * f64::from(xi) / 5.0;
                let y = s.goal_y_m[0] + (s.goal_y_m[1] - s.goal_y_m[0]) * f64::from(yi) / 7.0;
                let r = ik.solve(
                    &m,
                    &Vector3::new(x, y, s.table_height_m + hover + dz),
                    &m.home(),
                );
                assert!(r.reached, "({x}, {y})");
                postures.push(r.joints);
            }
        }
    }
    for (geometry, model) in [
        (RobotGeometry::new(&m), &m),
        (RobotGeometry::new(&armed), &armed),
    ] {
        for q in &postures {
            let d = geometry.self_distance(&model.fk(q));
            // Ordinary postures keep a real gap above the threshold, not a hair's breadth.
            assert!(
                d.distance_m > SELF_COLLISION_MIN_DISTANCE_M + 0.005,
                "{q:?}: {d:?}"
            );
        }
    }
}

#[test]
fn the_task_refuses_a_self_colliding_posture_and_passes_home_and_a_reach() {
    let scene = Scene::empty(
        0.0,
        Goal {
            center_m: [0.40, -0.20, 0.025],
            size_m: 0.05,
        },
    );
    // From the folded posture, holding still: contact (self-collision), the collision
    // penalty, the episode ends unsafe.
    let mut folded = task();
    folded.start.joints_rad = FOREARM_ON_SHOULDER;
    let mut env = TwinEnv::new(model(), folded);
    env.reset(&scene);
    let out = env.step(&[0.0; 3]);
    assert!(out.self_collision && !out.safe && out.terminated, "{out:?}");
    assert_eq!(out.terms.terminal, -folded.reward.collision_penalty as f32);
    // From home, the straight line to the goal: reached, no step self-colliding. (The TCP
    // stays the flange: with the 10 cm gripper the goal point hovers 15 cm up, or the
    // gripper would end in the table.)
    let mut armed = task_with_tool();
    armed.success.goal_hover_m = 0.15;
    for t in [task(), armed] {
        let mut env = TwinEnv::new(model(), t);
        env.reset(&scene);
        let policy = env.straight_line_policy();
        let mut obs = env.observation();
        let mut reached = false;
        for _ in 0..t.episode.max_steps {
            let out = env.step(&policy.act(&obs));
            assert!(out.safe && !out.self_collision, "{out:?}");
            obs = out.obs;
            if out.task_done {
                reached = true;
                break;
            }
        }
        assert!(reached);
    }
}
