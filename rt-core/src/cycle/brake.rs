//! The controlled stop of the cycle: [`Brake`], an allocation-free jerk-limited deceleration
//! of every joint to zero velocity (acceleration ramps at most `max_jerk`, is bounded by
//! `max_acceleration`, and is shaped by `a = −sign(v)·min(A, √(2J|v|))` so that velocity and
//! acceleration reach zero together), computed with plain `f64` arithmetic on fixed arrays:
//! no allocation, no FFI, bounded time (a few hundred nanoseconds). [`MotionState`] is the
//! position, velocity and acceleration the cycle and the smoother share.

use twin::{DOF, Joints};

use crate::config::MotionLimits;

/// Position, velocity and acceleration of the arm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MotionState {
    /// Positions, rad.
    pub q_rad: Joints,
    /// Velocities, rad/s.
    pub dq_rad_s: Joints,
    /// Accelerations, rad/s².
    pub ddq_rad_s2: Joints,
}

impl MotionState {
    /// At rest at `q_rad`.
    pub fn at_rest(q_rad: Joints) -> Self {
        Self {
            q_rad,
            ..Self::default()
        }
    }
}

/// An allocation-free jerk-limited brake to zero velocity (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct Brake {
    state: MotionState,
    max_acceleration_rad_s2: Joints,
    max_jerk_rad_s3: Joints,
}

impl Brake {
    /// A brake with the arm's limits, idle at the origin.
    pub fn new(limits: &MotionLimits) -> Self {
        Self {
            state: MotionState::default(),
            max_acceleration_rad_s2: limits.max_acceleration_rad_s2,
            max_jerk_rad_s3: limits.max_jerk_rad_s3,
        }
    }

    /// Begins braking from `state`.
    pub fn start(&mut self, state: MotionState) {
        self.state = state;
    }

    /// The current braking state.
    pub fn state(&self) -> &MotionState {
        &self.state
    }

    /// Whether every joint stands still.
    pub fn is_stopped(&self) -> bool {
        self.state.dq_rad_s.iter().all(|v| *v == 0.0)
            && self.state.ddq_rad_s2.iter().all(|a| *a == 0.0)
    }

    /// Advances by `dt_s`; returns the new state.
    pub fn step(&mut self, dt_s: f64) -> &MotionState {
        for j in 0..DOF {
            let jmax = self.max_jerk_rad_s3[j];
            let amax = self.max_acceleration_rad_s2[j];
            let v = self.state.dq_rad_s[j];
            let a = self.state.ddq_rad_s2[j];
            let dv_stop = jmax * dt_s * dt_s;
            if v.abs() <= dv_stop && a.abs() <= jmax * dt_s {
                self.state.q_rad[j] += v * dt_s * 0.5;
                self.state.dq_rad_s[j] = 0.0;
                self.state.ddq_rad_s2[j] = 0.0;
                continue;
            }
            let a_des = -v.signum() * amax.min((2.0 * jmax * v.abs()).sqrt());
            let a_new = a + (a_des - a).clamp(-jmax * dt_s, jmax * dt_s);
            let mut v_new = v + 0.5 * (a + a_new) * dt_s;
            let mut a_out = a_new;
            if v != 0.0 && v_new.signum() != v.signum() {
                v_new = 0.0;
                a_out = 0.0;
            }
            self.state.q_rad[j] += 0.5 * (v + v_new) * dt_s;
            self.state.dq_rad_s[j] = v_new;
            self.state.ddq_rad_s2[j] = a_out;
        }
        &self.state
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;

    #[test]
    fn the_brake_stops_within_jerk_and_acceleration_limits() {
        let lim = RuntimeConfig::xarm5_default().limits;
        let mut b = Brake::new(&lim);
        b.start(MotionState {
            q_rad: [0.0; DOF],
            dq_rad_s: [1.0, -0.5, 0.0, 0.2, -1.0],
            ddq_rad_s2: [2.0, 0.0, 0.0, -1.0, 0.0],
        });
        let dt = 0.004;
        let mut prev = *b.state();
        let mut steps = 0;
        while !b.is_stopped() {
            let s = *b.step(dt);
            for j in 0..DOF {
                assert!(s.ddq_rad_s2[j].abs() <= lim.max_acceleration_rad_s2[j] + 1e-9);
                let jerk = (s.ddq_rad_s2[j] - prev.ddq_rad_s2[j]).abs() / dt;
                // the final snap to rest is bounded by one jerk step plus sqrt(2 J dv)
                assert!(
                    jerk <= lim.max_jerk_rad_s3[j] * 1.5 + 1e-6 || s.dq_rad_s[j] == 0.0,
                    "jerk {jerk}"
                );
            }
            prev = s;
            steps += 1;
            assert!(steps < 1000, "brake did not stop");
        }
        // 1 rad/s at 4 rad/s² and 40 rad/s³ stops in well under a second.
        assert!(steps as f64 * dt < 0.6, "{steps}");
        assert!(b.state().q_rad[0] > 0.1 && b.state().q_rad[4] < -0.1);
    }
}
