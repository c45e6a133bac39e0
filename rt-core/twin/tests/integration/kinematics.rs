//! Forward kinematics at known poses.

use std::f64::consts::FRAC_PI_2;

use nalgebra::Vector3;

use super::common::model;

fn close(a: &Vector3<f64>, b: [f64; 3], tol: f64) {
    let d = (a - Vector3::from(b)).norm();
    assert!(d < tol, "{a:?} vs {b:?}: {d} m apart");
}

#[test]
fn flange_at_zero_joints_is_where_the_datasheet_says() {
    let m = model();
    let p = m.fk(&[0.0; 5]);
    close(&p.tcp_m(), [0.207, 0.0, 0.112], 1e-9);
    // The flange points down at zero joints.
    close(&(p.tcp.rotation * Vector3::z()), [0.0, 0.0, -1.0], 1e-9);
    // Joint origins along the chain.
    close(&p.links[1].translation.vector, [0.0, 0.0, 0.267], 1e-12);
    close(&p.links[3].translation.vector, [0.0535, 0.0, 0.5515], 1e-12);
    close(&p.links[4].translation.vector, [0.131, 0.0, 0.209], 1e-12);
}

#[test]
fn joint1_turns_the_arm_about_the_vertical() {
    let m = model();
    close(
        &m.tcp_m(&[FRAC_PI_2, 0.0, 0.0, 0.0, 0.0]),
        [0.0, 0.207, 0.112],
        1e-9,
    );
    close(
        &m.tcp_m(&[-FRAC_PI_2, 0.0, 0.0, 0.0, 0.0]),
        [0.0, -0.207, 0.112],
        1e-9,
    );
}

#[test]
fn joint5_spins_the_flange_in_place() {
    let m = model();
    let a = m.fk(&[0.3, 0.2, -0.5, 0.4, 0.0]);
    let b = m.fk(&[0.3, 0.2, -0.5, 0.4, 1.2]);
    close(&a.tcp_m(), b.tcp_m().into(), 1e-12);
    assert!((a.tcp.rotation.angle_to(&b.tcp.rotation) - 1.2).abs() < 1e-9);
}

#[test]
fn joint2_pitches_the_arm_forward_about_the_shoulder() {
    // With joint 2 at +90° the whole arm (planar in x-z) rotates about the shoulder at
    // z = 0.267 around +y: a point (x, z) relative to the shoulder maps to (z, −x).
    let m = model();
    let zero = m.tcp_m(&[0.0; 5]);
    let rel = (zero.x, zero.z - 0.267);
    let want = [rel.1, 0.0, 0.267 - rel.0];
    close(&m.tcp_m(&[0.0, FRAC_PI_2, 0.0, 0.0, 0.0]), want, 1e-9);
}

#[test]
fn elbow_geometry_matches_link_lengths() {
    // Whatever the joints, distances between consecutive joint origins are the link lengths.
    let m = model();
    let p = m.fk(&[0.7, -0.4, -1.3, 0.9, 0.5]);
    let d =
        |i: usize, j: usize| (p.links[i].translation.vector - p.links[j].translation.vector).norm();
    assert!((d(2, 3) - (0.0535f64.hypot(0.2845))).abs() < 1e-12);
    assert!((d(3, 4) - (0.0775f64.hypot(0.3425))).abs() < 1e-12);
    assert!((d(4, 5) - (0.076f64.hypot(0.097))).abs() < 1e-12);
}
