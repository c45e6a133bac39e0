//! The shield on the real twin model ([`TwinModel`]).

use crate::twin_common;

/// The runtime shield's distance (`TwinModel`) covers the table as well as the boxes, so
/// a plan dipping the wrist to the table is refused even without any box in the scene.
#[test]
fn the_shield_model_measures_the_table_too() {
    use rt_core::cycle::shield::ShieldModel;
    use rt_core::cycle::twin_model::TwinModel;
    use twin::{Goal, Scene};

    let model = twin_common::model();
    let task = twin_common::task();
    let mut shield = TwinModel::new(model.clone());
    let empty = Scene::empty(
        0.0,
        Goal {
            center_m: [0.3, 0.0, 0.025],
            size_m: 0.05,
        },
    );
    let start = task.start.joints_rad;
    let high = shield.min_distance_m(&start, &empty);
    assert!(high.is_finite() && high > 0.1, "start posture: {high} m");
    // Shoulder forward, elbow open: the wrist goes down to the table.
    let mut low = start;
    low[1] += 0.9;
    let d_low = shield.min_distance_m(&low, &empty);
    assert!(
        d_low < high - 0.05,
        "lowering the arm must bring it closer to the table: {d_low} vs {high}"
    );
    let tcp = model.tcp_m(&low);
    assert!(
        (d_low - tcp.z).abs() < 0.2,
        "the distance is the table's, near the TCP height {}: {d_low}",
        tcp.z
    );
}

/// Blind mode (`rt-core run --no-lookahead`) leaves the obstacle boxes out of the cycle's
/// shield, never the table or a limit: the shield `rt-core run` builds for the cycle in
/// blind mode ([`cycle_shield`]) passes a pose whose TCP is inside a box, and still refuses
/// the wrist in the table, a joint out of range and the TCP out of the workspace. (The
/// twin worker's plan check, [`plan_shield`], has no clearance in blind mode: the plan
/// starts, and the cycle stops it.)
///
/// [`cycle_shield`]: rt_core::twin_thread::serve::cycle_shield
/// [`plan_shield`]: rt_core::twin_thread::serve::plan_shield
#[test]
fn blind_mode_ignores_the_boxes_but_keeps_the_table_and_the_limits() {
    use rt_core::config::RuntimeConfig;
    use rt_core::cycle::shield::{ShieldModel, ShieldViolation};
    use rt_core::twin_thread::serve::{cycle_shield, plan_shield};
    use twin::{BoxObstacle, Goal, Scene};

    let model = twin_common::model();
    let cfg = RuntimeConfig::load(&twin_common::assets().join("runtime.toml")).unwrap();
    let start = twin_common::task().start.joints_rad;
    let mut blind = cycle_shield(&cfg, &model, true);
    let mut gated = cycle_shield(&cfg, &model, false);
    assert!(blind.model_mut().boxes_ignored() && !gated.model_mut().boxes_ignored());

    let goal = Goal {
        center_m: [0.3, 0.0, 0.025],
        size_m: 0.05,
    };
    let empty = Scene::empty(0.0, goal);

    // A box around the TCP of the start posture (well clear of the table): both shields'
    // other checks pass, the gated one refuses the box, the blind one does not.
    let tcp = model.tcp_m(&start);
    assert!(tcp.z > 0.1, "start TCP height {}", tcp.z);
    let mut boxed = empty;
    boxed
        .obstacles
        .push(BoxObstacle {
            center_m: [tcp.x, tcp.y, tcp.z],
            size_m: [0.1, 0.1, 0.1],
        })
        .unwrap();
    assert!(
        matches!(
            gated.check_pose(&start, &boxed),
            Err(ShieldViolation::Clearance { distance_m }) if distance_m < 0.0
        ),
        "the gated shield must refuse the TCP inside the box"
    );
    let d = blind
        .check_pose(&start, &boxed)
        .expect("blind mode ignores the box");
    assert_eq!(
        Ok(d),
        blind.check_pose(&start, &empty),
        "with the boxes ignored, the clearance is the table's"
    );

    // The wrist into the table with the TCP still inside the workspace box (z >= 0): the
    // shoulder forward from the start posture until the clearance to the table is gone.
    let mut low = start;
    while blind.model_mut().min_distance_m(&low, &empty) >= 0.0 {
        low[1] += 0.01;
        assert!(low[1] < start[1] + 2.0, "no pose into the table found");
    }
    let low_tcp = model.tcp_m(&low);
    assert!(
        low_tcp.z >= cfg.shield.workspace_min_m[2],
        "TCP {low_tcp:?} must stay in the workspace for the table check to decide"
    );
    for (name, scene) in [("empty", &empty), ("boxed", &boxed)] {
        assert!(
            matches!(
                blind.check_pose(&low, scene),
                Err(ShieldViolation::Clearance { distance_m }) if distance_m < 0.0
            ),
            "blind mode must still refuse the wrist in the table ({name} scene): {:?}",
            blind.check_pose(&low, scene)
        );
    }

    // The plan check lets the blind plan start; the cycle stops it at the table.
    assert!(
        plan_shield(&cfg, &model, true)
            .check_pose(&low, &boxed)
            .is_ok()
    );
    assert!(
        plan_shield(&cfg, &model, false)
            .check_pose(&low, &empty)
            .is_err()
    );

    // The limits hold too.
    let mut q = start;
    q[1] = cfg.limits.joint_max_rad[1] + 0.1;
    assert_eq!(
        blind.check_pose(&q, &boxed),
        Err(ShieldViolation::JointLimit { joint: 1 })
    );
    let mut below = low;
    while model.tcp_m(&below).z >= cfg.shield.workspace_min_m[2] {
        below[1] += 0.01;
    }
    assert!(
        below[1] < blind.limits().joint_max_rad[1],
        "no pose below the workspace within the joint range"
    );
    assert_eq!(
        blind.check_pose(&below, &boxed),
        Err(ShieldViolation::Workspace)
    );
}
