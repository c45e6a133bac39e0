//! Inverse kinematics: round trip on random reachable targets, limits, unreachable targets.

use nalgebra::Vector3;
use proptest::prelude::*;
use twin::{IkConfig, IkSolver};

use super::common::model;

proptest! {
    // PROPTEST_CASES raises the case count for a longer search.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(512),
        max_global_rejects: 1_000_000,
        ..ProptestConfig::default()
    })]

    /// Random reachable targets (FK of random joints in the working region in front of
    /// the robot) → FK(IK(x)) within 1 mm, joints within limits.
    #[test]
    fn fk_of_ik_returns_to_the_target(
        j1 in -1.6f64..1.6,
        j2 in -0.6f64..1.4,
        j3 in -2.4f64..-0.3,
        j4 in -0.5f64..1.8,
        j5 in -1.0f64..1.0,
    ) {
        let m = model();
        let target = m.tcp_m(&[j1, j2, j3, j4, j5]);
        // Reachable and not on the singular boundary of the workspace: above the table,
        // at least 0.1 m off the joint-1 axis and within 0.65 m of the shoulder (full
        // stretch is 0.76 m).
        let shoulder = nalgebra::Vector3::new(0.0, 0.0, 0.267);
        prop_assume!(target.z > 0.05);
        prop_assume!(target.xy().norm() > 0.1);
        prop_assume!((target - shoulder).norm() < 0.65);
        let solver = IkSolver::new(&m, IkConfig { max_iterations: 300, ..IkConfig::default() });
        let r = solver.solve(&m, &target, &m.home());
        prop_assert!(m.limits().contains(&r.joints));
        let back = m.tcp_m(&r.joints);
        prop_assert!((back - target).norm() < 1e-3, "target {:?} reached {:?} err {}", target, back, r.error_m);
        prop_assert!(r.reached);
        prop_assert!((r.error_m - (back - target).norm()).abs() < 1e-12);
    }
}

#[test]
fn unreachable_target_is_reported_with_its_residual() {
    let m = model();
    let solver = IkSolver::new(&m, IkConfig::default());
    let target = Vector3::new(1.5, 0.0, 0.3); // the xArm5 reaches about 0.7 m
    let r = solver.solve(&m, &target, &m.home());
    assert!(!r.reached);
    assert!(r.error_m > 0.7, "{}", r.error_m);
    assert!(m.limits().contains(&r.joints));
    assert_eq!(r.iterations, IkConfig::default().max_iterations);
}

#[test]
fn null_space_pull_keeps_the_redundant_joint_at_home() {
    // Joint 5 does not move the TCP: with the pull it stays at home's value, without it it
    // keeps the start value.
    let m = model();
    let target = Vector3::new(0.35, 0.1, 0.2);
    let start = [0.0, 0.0, -0.5, 0.5, 0.8];
    let pulled = IkSolver::new(&m, IkConfig::default()).solve(&m, &target, &start);
    let free = IkSolver::new(
        &m,
        IkConfig {
            nullspace_gain: 0.0,
            ..IkConfig::default()
        },
    )
    .solve(&m, &target, &start);
    assert!(pulled.reached && free.reached);
    assert!((free.joints[4] - 0.8).abs() < 1e-9);
    assert!((pulled.joints[4] - m.home()[4]).abs() < (free.joints[4] - m.home()[4]).abs());
}

#[test]
fn start_outside_limits_is_clamped() {
    let m = model();
    let solver = IkSolver::new(&m, IkConfig::default());
    let r = solver.solve(
        &m,
        &Vector3::new(0.3, 0.0, 0.25),
        &[0.0, 5.0, 3.0, -4.0, 0.0],
    );
    assert!(m.limits().contains(&r.joints));
}
