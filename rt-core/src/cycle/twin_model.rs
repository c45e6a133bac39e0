//! The shield's model on the real twin ([`TwinModel`]): it lives in the twin crate
//! (`twin::approval::shield_model`), where the learner's verification uses it too.

pub use twin::approval::TwinModel;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::cycle::shield::{Shield, ShieldLimits, ShieldModel, ShieldViolation};
    use twin::{BoxObstacle, Goal, Joints, RobotModel, Scene, TaskConfig, ToolConfig};

    fn assets() -> std::path::PathBuf {
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    fn model() -> RobotModel {
        RobotModel::load(&assets().join("xarm5.urdf")).unwrap()
    }

    fn start() -> Joints {
        TaskConfig::load(&assets().join("task.toml"))
            .unwrap()
            .start
            .joints_rad
    }

    fn shield(model: RobotModel) -> Shield<TwinModel> {
        let cfg = RuntimeConfig::xarm5_default();
        Shield::new(
            TwinModel::new(model),
            ShieldLimits::from_config(&cfg.limits, &cfg.shield),
        )
    }

    fn empty() -> Scene {
        Scene::empty(
            0.0,
            Goal {
                center_m: [0.40, 0.25, 0.025],
                size_m: 0.05,
            },
        )
    }

    /// The wrist driven down into the base: joints and TCP within their limits, the table
    /// clear, the links in each other.
    const FOLDED: Joints = [0.0, 0.5, 0.0, 1.0, 0.0];

    /// The shield refuses a posture folding the wrist into the base, in blind mode too, and
    /// passes the start posture and normal reaches (near the base and far out).
    #[test]
    fn a_self_colliding_posture_is_refused() {
        let mut s = shield(model());
        assert!(s.check_pose(&start(), &empty()).is_ok());
        let m = model();
        let ik = twin::IkSolver::new(&m, twin::IkConfig::default());
        for goal in [[0.20, 0.0, 0.10], [0.45, 0.35, 0.10], [0.30, -0.30, 0.25]] {
            let r = ik.solve(&m, &nalgebra::Vector3::from(goal), &start());
            assert!(r.reached, "{goal:?}");
            let verdict = s.check_pose(&r.joints, &empty());
            assert!(verdict.is_ok(), "{goal:?}: {verdict:?}");
        }
        let refused = s.check_pose(&FOLDED, &empty());
        assert!(
            matches!(refused, Err(ShieldViolation::SelfCollision { links, distance_m })
                if links[0] < links[1] && distance_m < twin::SELF_COLLISION_MIN_DISTANCE_M),
            "{refused:?}"
        );
        assert_eq!(refused.unwrap_err().code(), 9);
        let mut blind = Shield::new(
            TwinModel::new(model()).with_boxes_ignored(true),
            *s.limits(),
        );
        assert!(matches!(
            blind.check_pose(&FOLDED, &empty()),
            Err(ShieldViolation::SelfCollision { .. })
        ));
    }

    /// The tool on the model counts in the shield's clearance: the start posture with a
    /// box 5 mm into the gripper's reach is refused with the tool and passes without it.
    #[test]
    fn the_tool_counts_in_the_clearance() {
        let tcp = model().tcp_m(&start());
        let mut scene = empty();
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y, 0.0625],
                size_m: [0.10, 0.10, 0.125],
            })
            .unwrap();
        let bare = shield(model()).check_pose(&start(), &scene);
        assert!(matches!(bare, Ok(d) if d > 0.03), "{bare:?}");
        let tool = ToolConfig {
            from_m: [0.0, 0.0, 0.0],
            to_m: [0.0, 0.0, 0.10],
            radius_m: 0.03,
        };
        let armed = shield(model().with_tool(Some(tool.capsule()))).check_pose(&start(), &scene);
        assert!(
            matches!(armed, Err(ShieldViolation::Clearance { distance_m }) if distance_m < 0.0),
            "{armed:?}"
        );
    }

    /// The separation monitor's distance is to the moving boxes alone: the table, near the
    /// arm at every goal, does not count (it would slow every reach), nor does a still box
    /// (the plans are verified against it); blind mode has none.
    #[test]
    fn the_intruder_distance_counts_only_the_moving_boxes() {
        let mut m = TwinModel::new(model());
        let q = start();
        assert!(m.min_distance_m(&q, &empty()).is_finite());
        assert_eq!(m.intruder_distance_m(&q, &empty(), u32::MAX), f64::INFINITY);
        let tcp = model().tcp_m(&q);
        let mut scene = empty();
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y + 0.3, tcp.z],
                size_m: [0.05; 3],
            })
            .unwrap();
        let d = m.intruder_distance_m(&q, &scene, 0b1);
        assert!(d > 0.1 && d < 0.3, "{d}");
        assert!(m.min_distance_m(&q, &scene) <= d);
        // A still box nearer than the moving one: the moving one's distance still.
        scene
            .obstacles
            .push(BoxObstacle {
                center_m: [tcp.x, tcp.y - 0.15, tcp.z],
                size_m: [0.05; 3],
            })
            .unwrap();
        assert!(m.min_distance_m(&q, &scene) < d - 0.05);
        assert_eq!(m.intruder_distance_m(&q, &scene, 0b1), d);
        assert!(m.intruder_distance_m(&q, &scene, 0b11) < d - 0.05);
        assert_eq!(m.intruder_distance_m(&q, &scene, 0), f64::INFINITY);
        let mut blind = TwinModel::new(model()).with_boxes_ignored(true);
        assert_eq!(blind.intruder_distance_m(&q, &scene, 0b1), f64::INFINITY);
    }
}
