//! Trajectory smoothing of approved plans: Ruckig on the twin thread. It lives in the twin
//! crate (`twin::approval::smoother`, where the decision on where Ruckig runs is written),
//! because the learner's verification smooths exactly as rt-core does (issue 40); the
//! allocation-free brake of controlled stops is `crate::cycle::brake`.

pub use twin::approval::smoother::{PlanSmoother, SmoothError, max_tcp_speed_m_s};

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::cycle::plan::{MotionState, Plan};
    use crate::testing::toy::ToyArm;
    use twin::{DOF, Joints};

    #[test]
    fn ruckig_plans_follow_the_waypoints_within_the_limits() {
        let cfg = RuntimeConfig::xarm5_default();
        let period = 0.004;
        let mut sm = PlanSmoother::new(period, cfg.limits, 100_000);
        let wps: Vec<Joints> = (1..=40)
            .map(|i| {
                let t = i as f64 / 40.0;
                [0.5 * t, -0.3 * t, -0.6 * t, 0.2 * t, 0.0]
            })
            .collect();
        let mut plan = Plan::with_capacity(1, 1, period, 0);
        sm.smooth(
            &MotionState::at_rest([0.0; DOF]),
            &wps,
            0.05,
            &mut ToyArm,
            &mut plan,
        )
        .unwrap();
        assert!(plan.len() as f64 * period >= 2.0 - 1e-9);
        let last = plan.q_rad[plan.len() - 1];
        for j in 0..DOF {
            assert!((last[j] - wps[39][j]).abs() < 1e-6, "{last:?}");
            assert!(plan.dq_rad_s[plan.len() - 1][j].abs() < 1e-6);
        }
        for k in 0..plan.len() {
            for j in 0..DOF {
                assert!(plan.dq_rad_s[k][j].abs() <= cfg.limits.max_velocity_rad_s[j] + 1e-6);
                assert!(
                    plan.ddq_rad_s2[k][j].abs() <= cfg.limits.max_acceleration_rad_s2[j] + 1e-6
                );
            }
        }
        let speed = max_tcp_speed_m_s(&mut ToyArm, &[0.0; DOF], &plan.q_rad, period);
        assert!(speed <= cfg.limits.max_tcp_speed_m_s, "{speed}");
    }
}
