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
    // Each arm link's capsule axis runs from its joint to the next joint (within 1 mm).
    let m = model();
    let p = m.fk(&[0.4, 0.3, -0.8, 0.6, 0.2]);
    for (frame, from, to) in [(2, 2, 3), (3, 3, 4), (4, 4, 5)] {
        let c = m.capsules().iter().find(|c| c.frame == frame).unwrap();
        let a = p.links[frame] * nalgebra::Point3::from(c.a_m);
        let b = p.links[frame] * nalgebra::Point3::from(c.b_m);
        let j0 = p.links[from].translation.vector;
        let j1 = p.links[to].translation.vector;
        assert!((a.coords - j0).norm() < 1e-3, "link{frame} start");
        assert!((b.coords - j1).norm() < 1e-3, "link{frame} end");
        assert!(c.radius_m >= 0.045, "link{frame} radius {}", c.radius_m);
    }
    assert_eq!(m.capsules().len(), 6);
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
