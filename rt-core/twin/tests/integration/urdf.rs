//! Loading the URDF: the bundled model's facts, and malformed files rejected with the
//! right error.

use twin::{ACCELERATION_LIMIT_RAD_S2, JERK_LIMIT_RAD_S3, RobotModel, UrdfLoadError};

use super::common::{assets, model};

fn bundled() -> String {
    std::fs::read_to_string(assets().join("xarm5.urdf")).unwrap()
}

/// The `<joint name="jointN" …> … </joint>` element of the bundled file.
fn joint_element(text: &str, n: usize) -> String {
    let start = text.find(&format!("<joint name=\"joint{n}\"")).unwrap();
    let end = start + text[start..].find("</joint>").unwrap() + "</joint>".len();
    text[start..end].to_string()
}

#[test]
fn bundled_model_has_the_published_limits() {
    let m = model();
    let l = m.limits();
    let two_pi = std::f64::consts::TAU;
    assert_eq!(
        l.lower_rad,
        [-two_pi, -2.059488, -3.92699, -1.692969, -two_pi]
    );
    assert_eq!(
        l.upper_rad,
        [two_pi, 2.094395, 0.191986, std::f64::consts::PI, two_pi]
    );
    // The datasheet's 3.14 rad/s, not π.
    #[allow(clippy::approx_constant)]
    let datasheet_velocity_rad_s = 3.14;
    assert_eq!(l.velocity_rad_s, [datasheet_velocity_rad_s; 5]);
    assert_eq!(l.acceleration_rad_s2, [ACCELERATION_LIMIT_RAD_S2; 5]);
    assert_eq!(l.jerk_rad_s3, [JERK_LIMIT_RAD_S3; 5]);
    assert_eq!(ACCELERATION_LIMIT_RAD_S2, 20.0);
    assert_eq!(JERK_LIMIT_RAD_S3, 500.0);
    assert!(l.contains(&m.home()));
    let names: Vec<&str> = (0..=6).map(|i| m.link_name(i)).collect();
    assert_eq!(
        names,
        [
            "link_base",
            "link1",
            "link2",
            "link3",
            "link4",
            "link5",
            "tcp"
        ]
    );
}

#[test]
fn home_posture_is_above_the_table_in_front() {
    let m = model();
    let tcp = m.tcp_m(&m.home());
    assert!(tcp.x > 0.2 && tcp.y.abs() < 1e-9 && tcp.z > 0.15, "{tcp:?}");
}

#[test]
fn collision_capsules_cover_each_link_between_its_joints() {
    // Each arm link's capsule axes run from its joint to the next joint (within 1 mm): one
    // straight capsule for the upper arm and the forearm, two for the wrist's L (out along
    // its x axis, then along y to the flange axis), sharing the corner.
    let m = model();
    let p = m.fk(&[0.4, 0.3, -0.8, 0.6, 0.2]);
    let point = |frame: usize, v: [f64; 3]| (p.links[frame] * nalgebra::Point3::from(v)).coords;
    for (frame, from, to) in [(2, 2, 3), (3, 3, 4)] {
        let c = m.capsules().iter().find(|c| c.frame == frame).unwrap();
        let j0 = p.links[from].translation.vector;
        let j1 = p.links[to].translation.vector;
        assert!(
            (point(frame, c.a_m) - j0).norm() < 1e-3,
            "link{frame} start"
        );
        assert!((point(frame, c.b_m) - j1).norm() < 1e-3, "link{frame} end");
        assert!(c.radius_m >= 0.045, "link{frame} radius {}", c.radius_m);
    }
    let wrist: Vec<_> = m.capsules().iter().filter(|c| c.frame == 4).collect();
    assert_eq!(wrist.len(), 2, "the wrist is an L of two capsules");
    let ends = |c: &twin::LinkCapsule| [point(4, c.a_m), point(4, c.b_m)];
    let (first, second) = (ends(wrist[0]), ends(wrist[1]));
    let j4 = p.links[4].translation.vector;
    let j5 = p.links[5].translation.vector;
    let corner = point(4, [0.076, 0.0, 0.0]);
    let has = |e: &[nalgebra::Vector3<f64>; 2], v: &nalgebra::Vector3<f64>| {
        e.iter().any(|x| (x - v).norm() < 1e-3)
    };
    assert!(
        has(&first, &j4) && has(&first, &corner),
        "wrist axis -> corner"
    );
    assert!(
        has(&second, &corner) && has(&second, &j5),
        "corner -> flange axis"
    );
    assert!(wrist.iter().all(|c| c.radius_m >= 0.045));
    assert_eq!(m.capsules().len(), 7);
}

#[test]
fn malformed_files_are_rejected_with_the_right_error() {
    let ok = bundled();
    assert!(RobotModel::from_urdf_str(&ok).is_ok());
    let j3 = joint_element(&ok, 3);
    let j2 = joint_element(&ok, 2);
    let cases: Vec<(String, UrdfLoadError)> = vec![
        ("<robot name=\"x\"><link".to_string(), UrdfLoadError::Parse),
        ("not xml at all".to_string(), UrdfLoadError::Parse),
        (ok.replace(&j3, ""), UrdfLoadError::MissingJoint(3)),
        (
            ok.replace(&j2, &j2.replace("type=\"revolute\"", "type=\"prismatic\"")),
            UrdfLoadError::UnsupportedJointType(2),
        ),
        (
            ok.replace(&j2, &j2.replace("type=\"revolute\"", "type=\"continuous\"")),
            UrdfLoadError::UnsupportedJointType(2),
        ),
        (
            ok.replace(
                "<joint name=\"joint_tcp\" type=\"fixed\">",
                "<joint name=\"joint_tcp\" type=\"revolute\"><limit lower=\"-1\" upper=\"1\" velocity=\"1\" effort=\"1\"/>",
            ),
            UrdfLoadError::WrongJointCount(6),
        ),
        (
            ok.replace(&j3, &j3.replace("<parent link=\"link2\"/>", "<parent link=\"link1\"/>")),
            UrdfLoadError::BrokenChain(3),
        ),
        (
            ok.replace(&j3, &j3.replace("lower=\"-3.92699\"", "lower=\"1.0\"")),
            UrdfLoadError::BadLimits(3),
        ),
        (
            ok.replace(&j2, &j2.replace("<axis xyz=\"0 0 1\"/>", "<axis xyz=\"0 0 0\"/>")),
            UrdfLoadError::BadJoint(2),
        ),
        (
            ok.replace(
                "<geometry><cylinder radius=\"0.045\" length=\"0.04\"/></geometry>",
                "<geometry><mesh filename=\"link5.stl\"/></geometry>",
            ),
            UrdfLoadError::BadCollision(5),
        ),
    ];
    for (text, want) in cases {
        let got = RobotModel::from_urdf_str(&text).err();
        assert_eq!(got, Some(want), "expected {want}");
    }
    let missing = RobotModel::load(std::path::Path::new("/nonexistent/xarm5.urdf")).err();
    assert_eq!(
        missing,
        Some(UrdfLoadError::Io(std::io::ErrorKind::NotFound))
    );
}

#[test]
fn error_messages_name_the_joint() {
    assert!(
        UrdfLoadError::MissingJoint(3)
            .to_string()
            .contains("joint3")
    );
    assert!(
        UrdfLoadError::UnsupportedJointType(2)
            .to_string()
            .contains("joint2")
    );
    assert!(UrdfLoadError::WrongJointCount(6).to_string().contains('6'));
}

/// The bundled file with the `<collision>` elements of link `name` removed.
fn without_collision_of(text: &str, name: &str) -> String {
    let start = text.find(&format!("<link name=\"{name}\">")).unwrap();
    let end = start + text[start..].find("</link>").unwrap();
    let mut link = text[start..end].to_string();
    while let Some(s) = link.find("<collision>") {
        let e = s + link[s..].find("</collision>").unwrap() + "</collision>".len();
        link.replace_range(s..e, "");
    }
    format!("{}{}{}", &text[..start], link, &text[end..])
}

#[test]
fn a_moving_link_without_collision_geometry_is_refused_by_name() {
    let ok = bundled();
    for link in ["link1", "link2", "link3", "link4", "link5"] {
        let text = without_collision_of(&ok, link);
        let err = RobotModel::from_urdf_str(&text).err();
        match err {
            Some(UrdfLoadError::MissingCollision(name)) => assert_eq!(name.as_str(), link),
            other => panic!("{link} without collision: expected MissingCollision, got {other:?}"),
        }
        let message = err.unwrap().to_string();
        assert!(message.contains(link), "{message}");
    }
    // The base stands still: it may go without (the table is not tested against it).
    assert!(RobotModel::from_urdf_str(&without_collision_of(&ok, "link_base")).is_ok());
}

#[test]
fn a_urdf_without_any_collision_shape_is_refused() {
    let ok = bundled();
    let mut text = ok.clone();
    for link in ["link_base", "link1", "link2", "link3", "link4", "link5"] {
        text = without_collision_of(&text, link);
    }
    assert!(!text.contains("<collision>"));
    assert_eq!(
        RobotModel::from_urdf_str(&text).err(),
        Some(UrdfLoadError::NoCollisionShapes)
    );
}

#[test]
fn shapes_of_fixed_child_links_count_for_their_moving_parent() {
    // A gripper link hung on link5 by a fixed joint carries link5's only shape: link5 is
    // covered, and the shape sits where the fixed joint puts it.
    let ok = bundled();
    let text = without_collision_of(&ok, "link5").replace(
        "<link name=\"link_tcp\"/>",
        "<link name=\"link_tcp\"><collision><origin xyz=\"0 0 0.05\" rpy=\"0 0 0\"/>\
         <geometry><sphere radius=\"0.03\"/></geometry></collision></link>",
    );
    let text = text.replace(
        "<joint name=\"joint_tcp\" type=\"fixed\">\n    <parent link=\"link5\"/>\n    <child link=\"link_tcp\"/>\n    <origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>",
        "<joint name=\"joint_tcp\" type=\"fixed\">\n    <parent link=\"link5\"/>\n    <child link=\"link_tcp\"/>\n    <origin xyz=\"0 0 0.02\" rpy=\"0 0 0\"/>",
    );
    let m = RobotModel::from_urdf_str(&text).unwrap();
    let c = m.capsules().iter().find(|c| c.frame == 5).unwrap();
    assert_eq!(c.a_m, c.b_m);
    assert!((c.a_m[2] - 0.07).abs() < 1e-12, "{c:?}");
    assert_eq!(c.radius_m, 0.03);
}
