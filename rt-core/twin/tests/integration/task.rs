//! The task: configuration loading and hashing, each reward term, termination flags,
//! observation layout.

use nalgebra::Vector3;
use twin::{ACT_DIM, BoxObstacle, Goal, OBS_DIM, Scene, TaskConfig, TaskConfigError, TwinEnv};

use super::common::{assets, env, model, task};

fn text() -> String {
    std::fs::read_to_string(assets().join("task.toml")).unwrap()
}

#[test]
fn bundled_task_loads_with_sensible_values() {
    let c = task();
    assert_eq!(c.episode.max_steps, 200);
    // TCP speed limit implied by the action scale stays well below 1 m/s.
    let max_speed_m_s = c.action.scale_m * 3f64.sqrt() / c.episode.step_period_s;
    assert!(max_speed_m_s < 0.6, "{max_speed_m_s}");
    assert_eq!(TaskConfig::from_toml_str(&c.to_toml_string()).unwrap(), c);
}

#[test]
fn hash_is_stable_and_sensitive() {
    let a = task();
    let b = TaskConfig::from_toml_str(&text()).unwrap();
    assert_eq!(a.hash(), b.hash());
    let mut c = a;
    c.reward.c3 += 1e-9;
    assert_ne!(a.hash(), c.hash());
    let mut d = a;
    d.episode.max_steps -= 1;
    assert_ne!(a.hash(), d.hash());
}

#[test]
fn malformed_or_invalid_task_files_are_rejected() {
    let ok = text();
    let parse = [
        ok.replace("[episode]", "[episod]"),
        ok.replace("max_steps = 200", "max_steps = \"many\""),
        ok.replace("c1 = 100.0", "c1 = 100.0\nc4 = 1.0"),
        ok.replace("scale_m = 0.015", ""),
        "this is = = not toml".to_string(),
    ];
    for t in parse {
        assert_eq!(TaskConfig::from_toml_str(&t), Err(TaskConfigError::Parse));
    }
    let invalid = [
        (ok.replace("max_steps = 200", "max_steps = 0"), "max_steps"),
        (
            ok.replace("max_steps = 200", "max_steps = 10000"),
            "max_steps",
        ),
        (
            ok.replace("step_period_s = 0.05", "step_period_s = -0.05"),
            "step_period_s",
        ),
        (ok.replace("scale_m = 0.015", "scale_m = nan"), "scale_m"),
        (ok.replace("c2 = 0.1", "c2 = -0.1"), "reward weights"),
        (
            ok.replace("tolerance_m = 0.02", "tolerance_m = 0.0"),
            "tolerance_m",
        ),
        (
            ok.replace("goal_x_m = [0.20, 0.45]", "goal_x_m = [0.45, 0.20]"),
            "goal_x_m",
        ),
        (
            ok.replace(
                "obstacle_fraction = [0.4, 0.6]",
                "obstacle_fraction = [0.4, 1.6]",
            ),
            "obstacle_fraction",
        ),
        (
            ok.replace("height_m = [0.30, 0.40]", "height_m = [0.0, 0.40]"),
            "obstacles",
        ),
        (
            ok.replace("max_iterations = 10", "max_iterations = 0"),
            "ik.max_iterations",
        ),
    ];
    for (t, field) in invalid {
        match TaskConfig::from_toml_str(&t) {
            Err(TaskConfigError::Invalid(msg)) => {
                assert!(msg.contains(field), "{msg} should name {field}")
            }
            other => panic!("expected Invalid naming {field}, got {other:?}"),
        }
    }
    assert_eq!(
        TaskConfig::load(std::path::Path::new("/nonexistent/task.toml")),
        Err(TaskConfigError::Io(std::io::ErrorKind::NotFound))
    );
}

/// A scene with the goal target 0.1 m in front of the start TCP and no box.
fn near_goal_scene(e: &TwinEnv) -> Scene {
    let start = e.start_tcp_m();
    let hover = e.config().success.goal_hover_m;
    let size = 0.05;
    Scene::empty(
        0.0,
        Goal {
            center_m: [start.x + 0.1, start.y, start.z - hover - size / 2.0],
            size_m: size,
        },
    )
}

#[test]
fn observation_layout_after_reset() {
    let mut e = env();
    let s = super::common::scene("small_box.toml");
    let obs = e.reset(&s);
    assert_eq!(obs.len(), OBS_DIM);
    let tcp = e.tcp_m();
    assert_eq!(obs[0], 0.0);
    assert_eq!([obs[1], obs[2]], [0.30, 0.25]);
    assert_eq!(
        [obs[3], obs[4], obs[5]],
        [tcp.x as f32, tcp.y as f32, tcp.z as f32]
    );
    assert_eq!([obs[6], obs[7], obs[8]], [0.0; 3]);
    assert_eq!([obs[9], obs[10]], [0.06, 0.06]);
    // Closest points: on the robot and on the box, as far apart as the reported distance.
    let r = Vector3::new(obs[11], obs[12], obs[13]).cast::<f64>();
    let o = Vector3::new(obs[14], obs[15], obs[16]).cast::<f64>();
    let b = &s.obstacles[0];
    for k in 0..3 {
        assert!((o[k] - b.center_m[k]).abs() <= b.size_m[k] / 2.0 + 1e-4);
    }
    assert!((r - o).norm() > 0.03);
    // After a step: t advances, velocity is displacement / period.
    let out = e.step(&[1.0, 0.0, 0.0]);
    assert!((out.obs[0] - 1.0 / 200.0).abs() < 1e-7);
    let v = (e.tcp_m() - tcp) / e.config().episode.step_period_s;
    assert!((f64::from(out.obs[6]) - v.x).abs() < 1e-5);
    assert!(v.x > 0.1, "TCP should move along +x: {v:?}");
}

#[test]
fn progress_term_is_the_decrease_of_goal_distance() {
    let mut e = env();
    let s = near_goal_scene(&e);
    e.reset(&s);
    let target = e.target_m();
    let d0 = (target - e.tcp_m()).norm();
    let out = e.step(&[1.0, 0.0, 0.0]);
    let d1 = (target - e.tcp_m()).norm();
    assert!((f64::from(out.terms.progress) - (d0 - d1)).abs() < 1e-6);
    assert!(
        out.terms.progress > 0.01,
        "moving toward the goal is progress"
    );
    let back = e.step(&[-1.0, 0.0, 0.0]);
    assert!(
        back.terms.progress < -0.01,
        "moving away is negative progress"
    );
    let c = e.config().reward;
    let want = c.c1 * f64::from(back.terms.progress) + c.c2 * f64::from(back.terms.action);
    assert!((f64::from(back.reward) - want).abs() < 1e-4);
}

#[test]
fn action_term_is_minus_the_norm_of_the_clipped_action() {
    let mut e = env();
    e.reset(&near_goal_scene(&e));
    assert_eq!(e.step(&[0.0; ACT_DIM]).terms.action, 0.0);
    let out = e.step(&[0.3, -0.4, 0.0]);
    assert!((out.terms.action + 0.5).abs() < 1e-6);
    let clipped = e.step(&[5.0, 0.0, f32::NAN]);
    assert!(
        (clipped.terms.action + 1.0).abs() < 1e-6,
        "clipped to 1, NaN treated as 0"
    );
}

#[test]
fn proximity_term_fires_below_d_thre_only() {
    let mut e = env();
    let d_thre = e.config().reward.d_thre_m;
    let base = near_goal_scene(&e);
    let tcp = e.start_tcp_m();
    // A box just below the flange: distance to link5/link4 under d_thre but no contact.
    let mut near = base;
    let top = tcp.z - 0.05 - d_thre / 2.0;
    near.obstacles
        .push(BoxObstacle {
            center_m: [tcp.x + 0.1, tcp.y + 0.3, top - 0.05],
            size_m: [0.05, 0.05, 0.1],
        })
        .unwrap();
    let mut far = base;
    far.obstacles
        .push(BoxObstacle {
            center_m: [-0.4, -0.4, 0.05],
            size_m: [0.05, 0.05, 0.1],
        })
        .unwrap();
    e.reset(&far);
    let out = e.step(&[0.0; 3]);
    assert_eq!(out.terms.proximity, 0.0);
    assert!(out.distance.obstacle == Some(0) && out.distance.distance_m > d_thre);
    // Move the box under the TCP: same scene but box centred below the flange.
    near.obstacles[0].center_m = [tcp.x, tcp.y, top - 0.05];
    e.reset(&near);
    let out = e.step(&[0.0; 3]);
    assert!(out.safe, "{:?}", out.distance);
    assert!(out.distance.distance_m < d_thre, "{:?}", out.distance);
    assert_eq!(out.terms.proximity, -1.0);
    let c = e.config().reward;
    let want = c.c1 * f64::from(out.terms.progress) - c.c3;
    assert!((f64::from(out.reward) - want).abs() < 1e-4);
}

#[test]
fn reaching_the_goal_terminates_with_task_done() {
    let mut e = env();
    let s = near_goal_scene(&e);
    e.reset(&s);
    let p = e.straight_line_policy();
    let mut obs = e.observation();
    let mut last = None;
    for _ in 0..50 {
        let out = e.step(&p.act(&obs));
        obs = out.obs;
        last = Some(out);
        if out.terminated || out.truncated {
            break;
        }
    }
    let out = last.unwrap();
    assert!(out.task_done && out.safe && out.terminated && !out.truncated);
    assert!((e.tcp_m() - e.target_m()).norm() <= e.config().success.tolerance_m);
    assert_eq!(out.terms.terminal as f64, e.config().reward.success_bonus);
}

#[test]
fn contact_terminates_unsafe() {
    let mut e = env();
    let s = super::common::scene("tall_box.toml");
    e.reset(&s);
    let p = e.straight_line_policy();
    let mut obs = e.observation();
    for _ in 0..200 {
        let out = e.step(&p.act(&obs));
        obs = out.obs;
        if out.terminated {
            assert!(!out.safe && !out.task_done && !out.truncated);
            // Contact is any distance below the task's clearance, touching or not.
            assert!(out.distance.distance_m < e.config().success.min_box_clearance_m);
            assert!(e.config().success.min_box_clearance_m > 0.0);
            assert_eq!(
                out.terms.terminal as f64,
                -e.config().reward.collision_penalty
            );
            return;
        }
    }
    panic!("the straight line should run into the tall box");
}

#[test]
fn step_budget_truncates() {
    let mut cfg = task();
    cfg.episode.max_steps = 7;
    let mut e = TwinEnv::new(model(), cfg);
    e.reset(&near_goal_scene(&e));
    for i in 1..=7 {
        let out = e.step(&[0.0; 3]);
        assert_eq!(out.truncated, i == 7, "step {i}");
        assert!(!out.terminated && out.safe);
    }
}

#[test]
fn joint_change_per_step_respects_the_velocity_limit() {
    let mut cfg = task();
    cfg.action.scale_m = 0.1; // ask for far more than the joints may do in one step
    let mut e = TwinEnv::new(model(), cfg);
    e.reset(&near_goal_scene(&e));
    let lim = *e.model().limits();
    let mut q = e.joints();
    for a in [[1.0, 1.0, -1.0], [-1.0, -1.0, 1.0], [0.0, 1.0, 1.0]] {
        let out = e.step(&a);
        for (i, (after, before)) in out.joints.iter().zip(&q).enumerate() {
            let max_rad = lim.velocity_rad_s[i] * cfg.episode.step_period_s;
            assert!((after - before).abs() <= max_rad + 1e-12, "joint {i}");
        }
        q = out.joints;
    }
}

/// Closer to the table than the task's clearance (links 2–5) ends the episode unsafe, as a
/// box does: the lookahead never passes what the shield would refuse near the table.
#[test]
fn table_clearance_is_contact() {
    let mut e = env();
    let s = super::common::scene("small_box.toml");
    e.reset(&s);
    // Straight down from the start posture.
    for _ in 0..200 {
        let out = e.step(&[0.0, 0.0, -1.0]);
        if out.terminated {
            assert!(!out.safe, "{out:?}");
            let table = e.geometry().distance_to_table(e.poses(), &s);
            assert!(
                table.distance_m < e.config().success.min_box_clearance_m,
                "{table:?}"
            );
            assert!(
                table.distance_m > -0.02,
                "stopped at the clearance, not deep in: {table:?}"
            );
            return;
        }
    }
    panic!("driving down must end at the table");
}

const TOOL: &str = "\n[tool]\nfrom_m = [0.0, 0.0, 0.0]\nto_m = [0.0, 0.0, 0.10]\nradius_m = 0.03\n";

#[test]
fn an_absent_tool_keeps_the_hash_of_the_bundled_policies() {
    // The hash the bundled policy was trained under (assets/policy/README.md) and the one
    // written into its blob: a task file without `[tool]` must still produce it.
    let t = task();
    assert!(t.tool.is_none());
    assert_eq!(t.hash(), 0x4eaf_4daa_786b_1e0c);
    let bytes = std::fs::read(assets().join("policy/policy.blob")).unwrap();
    let blob = shm_schemas::PolicyBlob::from_bytes(&bytes).unwrap();
    assert_eq!(blob.task_config_hash, t.hash());
    assert!(!t.to_toml_string().contains("tool"));
}

#[test]
fn a_tool_section_loads_round_trips_and_changes_the_hash() {
    let with = TaskConfig::from_toml_str(&(text() + TOOL)).unwrap();
    let tool = with.tool.unwrap();
    assert_eq!(tool.to_m, [0.0, 0.0, 0.10]);
    assert_eq!(tool.radius_m, 0.03);
    assert_ne!(with.hash(), task().hash());
    assert_eq!(
        TaskConfig::from_toml_str(&with.to_toml_string()).unwrap(),
        with
    );
    let mut wider = with;
    wider.tool = Some(twin::ToolConfig {
        radius_m: 0.031,
        ..tool
    });
    assert_ne!(wider.hash(), with.hash());
}

#[test]
fn a_malformed_tool_section_is_refused_naming_the_field() {
    let base = text();
    let invalid = [
        (
            TOOL.replace("radius_m = 0.03", "radius_m = 0.0"),
            "tool.radius_m",
        ),
        (
            TOOL.replace("radius_m = 0.03", "radius_m = -0.03"),
            "tool.radius_m",
        ),
        (
            TOOL.replace("radius_m = 0.03", "radius_m = nan"),
            "tool.radius_m",
        ),
        (
            TOOL.replace("radius_m = 0.03", "radius_m = 0.5"),
            "tool.radius_m",
        ),
        (
            TOOL.replace("to_m = [0.0, 0.0, 0.10]", "to_m = [0.0, 0.0, 0.9]"),
            "tool.to_m",
        ),
        (
            TOOL.replace("to_m = [0.0, 0.0, 0.10]", "to_m = [0.0, inf, 0.1]"),
            "tool.to_m",
        ),
        (
            TOOL.replace("from_m = [0.0, 0.0, 0.0]", "from_m = [nan, 0.0, 0.0]"),
            "tool.from_m",
        ),
    ];
    for (tool, field) in invalid {
        match TaskConfig::from_toml_str(&(base.clone() + &tool)) {
            Err(TaskConfigError::Invalid(msg)) => {
                assert!(msg.contains(field), "{msg} should name {field}")
            }
            other => panic!("expected Invalid naming {field}, got {other:?}"),
        }
    }
    // Missing, unknown or mistyped fields: a parse error (the parser's message, which
    // names the field, is logged).
    let parse = [
        TOOL.replace("radius_m = 0.03\n", ""),
        TOOL.replace("radius_m", "radius"),
        TOOL.replace("to_m = [0.0, 0.0, 0.10]", "to_m = [0.0, 0.10]"),
        TOOL.replace("radius_m = 0.03", "radius_m = 0.03\nshape = \"box\""),
    ];
    for tool in parse {
        assert_eq!(
            TaskConfig::from_toml_str(&(base.clone() + &tool)),
            Err(TaskConfigError::Parse),
            "{tool}"
        );
    }
}
