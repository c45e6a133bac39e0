//! The safety shield, the one check every command passes before it leaves the process: it
//! lives in the twin crate (`twin::approval::shield`) because the learner's verification
//! runs exactly it on every sample of a plan (issue 40); the cycle uses it from there.

pub use twin::approval::shield::{
    MAX_TCP_STEP_M, STEP_TOLERANCE, Shield, ShieldLimits, ShieldModel, ShieldViolation,
    WATCHED_POINTS,
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::testing::toy::{ToyArm, ToyScene};
    use twin::{DOF, Joints};

    fn shield() -> Shield<ToyArm> {
        let cfg = RuntimeConfig::xarm5_default();
        Shield::new(ToyArm, ShieldLimits::from_config(&cfg.limits, &cfg.shield))
    }

    const HOME: Joints = [0.0, -0.5, -1.0, 0.5, 0.0];

    #[test]
    fn a_free_pose_passes_and_reports_its_clearance() {
        let mut s = shield();
        let d = s.check_pose(&HOME, &ToyScene::empty()).unwrap();
        assert!(d.is_infinite());
        let tcp = ToyArm.tcp_position_m(&HOME);
        let mut scene = ToyScene::empty();
        scene.push_obstacle([tcp[0], tcp[1] + 0.3, tcp[2]], [0.05; 3]);
        let d = s.check_pose(&HOME, &scene).unwrap();
        assert!(d > 0.1 && d < 0.3, "{d}");
    }

    #[test]
    fn a_step_of_one_period_at_the_velocity_limit_passes_and_a_larger_one_does_not() {
        let mut s = shield();
        let empty = ToyScene::empty();
        let dt = 0.004;
        let v = s.limits().max_velocity_rad_s;
        let mut ok = HOME;
        ok[1] += v[1] * dt;
        assert!(s.check_step(&HOME, &ok, dt, &empty).is_ok());
        let mut jump = HOME;
        jump[1] += v[1] * dt * (1.0 + STEP_TOLERANCE) * 1.01;
        assert_eq!(
            s.check_step(&HOME, &jump, dt, &empty),
            Err(ShieldViolation::JointStep { joint: 1 })
        );
        // A hold passes; a non-finite previous command does not.
        assert!(s.check_step(&HOME, &HOME, dt, &empty).is_ok());
        let mut bad = HOME;
        bad[0] = f64::NAN;
        assert_eq!(
            s.check_step(&bad, &HOME, dt, &empty),
            Err(ShieldViolation::NonFinite)
        );
    }

    #[test]
    fn each_kind_of_violation_is_detected() {
        let mut s = shield();
        let empty = ToyScene::empty();
        let mut q = HOME;
        q[1] = 3.0;
        assert_eq!(
            s.check_pose(&q, &empty),
            Err(ShieldViolation::JointLimit { joint: 1 })
        );
        q = HOME;
        q[2] = f64::NAN;
        assert_eq!(s.check_pose(&q, &empty), Err(ShieldViolation::NonFinite));
        let tcp = ToyArm.tcp_position_m(&HOME);
        let mut blocked = ToyScene::empty();
        blocked.push_obstacle(tcp, [0.05; 3]);
        assert!(matches!(
            s.check_pose(&HOME, &blocked),
            Err(ShieldViolation::Clearance { .. })
        ));
        let mut fast = HOME;
        fast[0] += 0.2;
        assert!(matches!(
            s.check_step(&HOME, &fast, 0.004, &empty),
            Err(ShieldViolation::JointStep { joint: 0 })
        ));
        // Within the step limit per joint but too fast at the TCP: a far-reaching pose
        // whose joints all move at once.
        let mut slow_joints = HOME;
        let mut limits = *s.limits();
        limits.max_tcp_speed_m_s = 0.1;
        let mut tight = Shield::new(ToyArm, limits);
        for q in &mut slow_joints {
            *q += 0.9 * limits.max_velocity_rad_s[0].min(1.0) * 0.004;
        }
        assert!(matches!(
            tight.check_step(&HOME, &slow_joints, 0.004, &empty),
            Err(ShieldViolation::TcpSpeed { .. } | ShieldViolation::LinkSpeed { .. })
        ));
        let below_table = [0.0, 2.0, 0.15, 0.5, 0.0];
        // Issue 41 item 5: within the TCP speed limit at a slow rate (100 Hz), but farther
        // in one target than the controller's 5 mm (before: passed, the speed alone was
        // checked, which allows 8 mm at 0.8 m/s and 100 Hz).
        let mut limits = *s.limits();
        limits.max_tcp_speed_m_s = 0.8;
        limits.max_velocity_rad_s = [3.0; DOF];
        let mut slow_rate = Shield::new(ToyArm, limits);
        let dt = 0.01;
        let step_toward = |target_m: f64| {
            // Joint 0 (the base) alone: the TCP moves on a circle of the reach's radius.
            let tcp = ToyArm.tcp_position_m(&HOME);
            let reach_m = tcp[0].hypot(tcp[1]);
            let mut q = HOME;
            q[0] += target_m / reach_m;
            q
        };
        let eight_mm = step_toward(0.008);
        let moved = ToyArm.tcp_position_m(&eight_mm);
        let from = ToyArm.tcp_position_m(&HOME);
        let step_m = (0..3)
            .map(|k| (moved[k] - from[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(step_m > MAX_TCP_STEP_M && step_m / dt <= 0.8, "{step_m}");
        assert!(matches!(
            slow_rate.check_step(&HOME, &eight_mm, dt, &empty),
            Err(ShieldViolation::TcpStep { .. })
        ));
        assert!(
            slow_rate
                .check_step(&HOME, &step_toward(0.004), dt, &empty)
                .is_ok()
        );
        assert!((limits.tcp_speed_limit_m_s(dt) - 0.5).abs() < 1e-12);
        assert!((limits.tcp_speed_limit_m_s(0.004) - 0.8).abs() < 1e-12);
        assert_eq!(
            s.check_pose(&below_table, &empty),
            Err(ShieldViolation::Workspace)
        );
    }
}
