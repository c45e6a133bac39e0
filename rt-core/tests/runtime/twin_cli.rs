//! The `rt-core twin …` CLI: JSON shapes and bad arguments.

use std::process::Command;

use serde_json::Value;

fn run(args: &[&str]) -> (i32, Value, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_rt-core"))
        .arg("twin")
        .args(args)
        .env("FORESIGHT_ASSETS", crate::twin_common::assets())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let json = serde_json::from_str(&stdout).unwrap_or(Value::Null);
    (
        out.status.code().unwrap_or(-1),
        json,
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

fn vec3(v: &Value) -> [f64; 3] {
    let a = v.as_array().unwrap();
    assert_eq!(a.len(), 3);
    [
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    ]
}

#[test]
fn fk_prints_tcp_and_links() {
    let (code, j, _) = run(&["fk", "--joints", "0,0,0,0,0"]);
    assert_eq!(code, 0);
    let tcp = vec3(&j["tcp"]);
    assert!((tcp[0] - 0.207).abs() < 1e-6 && tcp[1].abs() < 1e-6 && (tcp[2] - 0.112).abs() < 1e-6);
    let links = j["links"].as_array().unwrap();
    assert_eq!(links.len(), 6);
    assert_eq!(links[5]["name"], "link5");
    vec3(&links[3]["pos"]);
    assert_eq!(links[2]["quat"].as_array().unwrap().len(), 4);
}

#[test]
fn ik_prints_joints_reached_and_error() {
    let (code, j, _) = run(&["ik", "--target", "0.35,-0.1,0.2"]);
    assert_eq!(code, 0);
    assert_eq!(j["joints"].as_array().unwrap().len(), 5);
    assert_eq!(j["reached"], true);
    assert!(j["error_m"].as_f64().unwrap() < 1e-3);
    let (code, j, _) = run(&["ik", "--target", "2,0,0", "--from", "0,0,0,0,0"]);
    assert_eq!(code, 0);
    assert_eq!(j["reached"], false);
}

#[test]
fn distance_prints_the_report() {
    let (code, j, _) = run(&[
        "distance",
        "--joints",
        "0,0,0,0,0",
        "--box",
        "0.35,0,0.1,0.1,0.1,0.2",
    ]);
    assert_eq!(code, 0);
    let d = j["distance_m"].as_f64().unwrap();
    assert!((d - 0.043).abs() < 1e-3, "{d}");
    assert_eq!(j["link"], "link4");
    assert_eq!(j["colliding"], false);
    vec3(&j["robot_point"]);
    vec3(&j["obstacle_point"]);
}

#[test]
fn rollout_prints_episodes_and_timing() {
    let scene = crate::twin_common::assets().join("scenes/small_box.toml");
    let (code, j, _) = run(&[
        "rollout",
        "--scene",
        scene.to_str().unwrap(),
        "--episodes",
        "2",
        "--seed",
        "4",
    ]);
    assert_eq!(code, 0);
    let eps = j["episodes"].as_array().unwrap();
    assert_eq!(eps.len(), 2);
    for e in eps {
        for k in ["success", "safe", "return", "steps", "min_distance_m"] {
            assert!(!e[k].is_null(), "missing {k}");
        }
        assert_eq!(e["success"], true);
    }
    assert!(j["timing"]["episode_ms_median"].as_f64().unwrap() > 0.0);
}

#[test]
fn bad_arguments_fail_with_a_message() {
    for args in [
        &["fk", "--joints", "0,0,0"][..],
        &["fk", "--joints", "a,b,c,d,e"],
        &["ik", "--target", "0.3,0.1"],
        &["distance", "--joints", "0,0,0,0,0"],
        &["distance", "--joints", "0,0,0,0,0", "--box", "0,0,0,1,1,-1"],
        &["rollout", "--scene", "/nonexistent.toml"],
        &["rollout", "--episodes", "0"],
        &["warp"],
    ] {
        let (code, _, err) = run(args);
        assert_ne!(code, 0, "{args:?}");
        assert!(!err.trim().is_empty(), "{args:?} should explain itself");
    }
}
