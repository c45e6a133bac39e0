//! Distance queries against analytic cases (sphere/box, capsule/box, capsule/table).

use nalgebra::Vector3;
use twin::{BoxObstacle, Goal, RobotGeometry, RobotModel, Scene};

use super::common::{assets, model};

/// The bundled URDF with every collision shape removed, `shape` put on link5, and a 1 mm
/// sphere at the origin of each of link1–link4 (a moving link must have a shape; these are
/// far from every box below).
fn model_with_link5_shape(shape: &str) -> RobotModel {
    let text = std::fs::read_to_string(assets().join("xarm5.urdf")).unwrap();
    let mut out = String::new();
    let mut rest = text.as_str();
    while let Some(start) = rest.find("<collision>") {
        out.push_str(&rest[..start]);
        let end = start + rest[start..].find("</collision>").unwrap() + "</collision>".len();
        rest = &rest[end..];
    }
    out.push_str(rest);
    let out = out.replace(
        "<link name=\"link5\">",
        &format!("<link name=\"link5\"><collision><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/><geometry>{shape}</geometry></collision>"),
    );
    let mut out = out;
    for link in ["link1", "link2", "link3", "link4"] {
        out = out.replace(
            &format!("<link name=\"{link}\">"),
            &format!("<link name=\"{link}\"><collision><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/><geometry><sphere radius=\"0.001\"/></geometry></collision>"),
        );
    }
    let m = RobotModel::from_urdf_str(&out).unwrap();
    assert_eq!(m.capsules().len(), 5);
    m
}

fn scene_with(boxes: &[([f64; 3], [f64; 3])]) -> Scene {
    let mut s = Scene::empty(
        -1.0,
        Goal {
            center_m: [0.5, 0.5, 0.0],
            size_m: 0.05,
        },
    );
    for (c, size) in boxes {
        s.obstacles
            .push(BoxObstacle {
                center_m: *c,
                size_m: *size,
            })
            .unwrap();
    }
    s
}

fn close(a: [f64; 3], b: [f64; 3], tol: f64) {
    let d = (Vector3::from(a) - Vector3::from(b)).norm();
    assert!(d < tol, "{a:?} vs {b:?}");
}

const TOL_M: f64 = 1e-4; // parry works in f32

#[test]
fn sphere_to_box_face_and_corner() {
    // At zero joints link5's origin is at (0.207, 0, 0.112).
    let m = model_with_link5_shape("<sphere radius=\"0.05\"/>");
    let g = RobotGeometry::new(&m);
    let p = m.fk(&[0.0; 5]);
    let c = [0.207, 0.0, 0.112];
    // Face: box spanning x ≥ 0.35.
    let s = scene_with(&[([0.40, 0.0, 0.112], [0.1, 0.1, 0.1])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    assert!(
        (d.distance_m - (0.35 - 0.207 - 0.05)).abs() < TOL_M,
        "{d:?}"
    );
    close(d.robot_point_m, [0.257, 0.0, 0.112], TOL_M);
    close(d.obstacle_point_m, [0.35, 0.0, 0.112], TOL_M);
    assert_eq!(d.link, 5);
    assert_eq!(d.obstacle, Some(0));
    assert!(!d.colliding);
    // Corner: the nearest corner of a box beyond x, y and z.
    let corner = [0.30, 0.10, 0.20];
    let s = scene_with(&[([0.35, 0.15, 0.25], [0.1, 0.1, 0.1])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    let want: f64 = (Vector3::from(corner) - Vector3::from(c)).norm() - 0.05;
    assert!(
        (d.distance_m - want).abs() < TOL_M,
        "{} vs {want}",
        d.distance_m
    );
    close(d.obstacle_point_m, corner, TOL_M);
    // Penetration: negative distance, colliding.
    let s = scene_with(&[([0.27, 0.0, 0.112], [0.1, 0.1, 0.1])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    assert!(d.colliding && d.distance_m < 0.0, "{d:?}");
    assert!(g.in_contact(&p, &s, 0.0));
}

#[test]
fn capsule_to_box_side_and_end() {
    // A cylinder of length 0.1 along link5's z: at zero joints link5's z points down, so
    // the capsule axis runs from (0.207, 0, 0.162) to (0.207, 0, 0.062), radius 0.03.
    let m = model_with_link5_shape("<cylinder radius=\"0.03\" length=\"0.1\"/>");
    let g = RobotGeometry::new(&m);
    let p = m.fk(&[0.0; 5]);
    // Side: a box beside the capsule, overlapping its height → perpendicular distance.
    let s = scene_with(&[([0.0, 0.25, 0.10], [0.6, 0.1, 0.02])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    assert!((d.distance_m - (0.20 - 0.03)).abs() < TOL_M, "{d:?}");
    assert!((d.obstacle_point_m[1] - 0.20).abs() < TOL_M);
    // End: a box below the capsule's lower end → the cap's distance.
    let s = scene_with(&[([0.207, 0.0, 0.0], [0.1, 0.1, 0.02])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    assert!(
        (d.distance_m - (0.062 - 0.03 - 0.01)).abs() < TOL_M,
        "{d:?}"
    );
    close(d.robot_point_m, [0.207, 0.0, 0.032], TOL_M);
    // Two boxes: the nearer one is reported.
    let s = scene_with(&[
        ([0.0, 0.25, 0.10], [0.6, 0.1, 0.02]),
        ([0.207, 0.0, 0.0], [0.1, 0.1, 0.02]),
    ]);
    assert_eq!(g.distance_to_boxes(&p, &s).unwrap().obstacle, Some(1));
    // Margins: within 0.03 but not within 0.01.
    assert!(g.in_contact(&p, &s, 0.03));
    assert!(!g.in_contact(&p, &s, 0.01));
}

#[test]
fn table_counts_for_the_upper_links_only() {
    let m = model();
    let g = RobotGeometry::new(&m);
    // At zero joints the base capsule reaches into the table plane at z = 0, yet the
    // table report is about links 2–5: link4's capsule, whose lowest end is the flange
    // axis point at z = 0.112 with radius 0.05.
    let p = m.fk(&[0.0; 5]);
    let mut s = Scene::empty(
        0.0,
        Goal {
            center_m: [0.4, 0.0, 0.025],
            size_m: 0.05,
        },
    );
    let t = g.distance_to_table(&p, &s);
    assert!(t.obstacle.is_none());
    assert!(t.link >= 2, "{t:?}");
    assert!((t.distance_m - (0.112 - 0.05)).abs() < 1e-3, "{t:?}");
    assert!(!g.in_contact(&p, &s, 0.0));
    assert!(g.distance(&p, &s).distance_m > 0.0);
    // Raising the table to the flange height makes contact.
    s.table_height_m = 0.10;
    assert!(g.in_contact(&p, &s, 0.0));
    let d = g.distance(&p, &s);
    assert!(d.colliding && d.obstacle.is_none());
}

#[test]
fn real_model_reports_the_nearest_link() {
    let m = model();
    let g = RobotGeometry::new(&m);
    let p = m.fk(&[0.0; 5]);
    // A box right in front of the flange: link4 or link5 is nearest, never the base.
    let s = scene_with(&[([0.35, 0.0, 0.1], [0.1, 0.1, 0.2])]);
    let d = g.distance_to_boxes(&p, &s).unwrap();
    assert!(d.link >= 4, "{d:?}");
    assert!(d.distance_m > 0.0 && d.distance_m < 0.1);
    let dist = (Vector3::from(d.robot_point_m) - Vector3::from(d.obstacle_point_m)).norm();
    assert!((dist - d.distance_m).abs() < TOL_M);
}
