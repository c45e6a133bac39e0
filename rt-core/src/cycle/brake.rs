//! The controlled stops of the cycle, both allocation-free with plain `f64` arithmetic on
//! fixed arrays (no FFI, bounded time):
//!
//! - [`PathStop`], the first choice: time scaling along the running plan. The plan's own
//!   path is followed at a speed scale `s` that falls from 1 to 0 as a smoothstep
//!   (`s = 1 − 3τ² + 2τ³`, so velocity and acceleration reach zero together; from the
//!   playback scale instead of 1 when speed and separation monitoring slowed the plan), so
//!   every pose until rest lies on the path the twin verified — the stop envelope is a
//!   stretch of the plan, which the cycle checks ahead of the arm.
//! - [`Brake`], the fallback when the plan itself is not valid at the next sample: every
//!   joint decelerates to zero on its own (acceleration ramps at most `max_jerk`, is bounded
//!   by `max_acceleration`, and is shaped by `a = −sign(v)·min(A, √(2J|v|))`); this leaves
//!   the coordinated path, so its poses pass the command check one by one.
//!
//! [`MotionState`] is the position, velocity and acceleration the cycle and the smoother share.

use twin::{DOF, Joints};

// The share of the acceleration limit the path stop's time scaling may use lives beside the
// limits: the configuration derives the prediction horizon's floor from it.
use crate::config::{MotionLimits, PATH_STOP_ACCEL_SHARE};
// The state a brake works on lives beside `Plan` (whose samples are states).
use crate::cycle::plan::MotionState;
use crate::cycle::plan::Plan;

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

/// A stop along the running plan by time scaling (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct PathStop {
    /// Position along the plan, in samples (fractional).
    at_sample: f64,
    elapsed_s: f64,
    duration_s: f64,
    period_s: f64,
    /// The playback scale the stop falls from (1 but during speed and separation
    /// monitoring's scaled playback).
    from_scale: f64,
    stopped: bool,
    state: MotionState,
    max_acceleration_rad_s2: Joints,
}

impl PathStop {
    /// Idle, with the acceleration limits of `brake`.
    pub fn from_brake(brake: &Brake) -> Self {
        Self {
            max_acceleration_rad_s2: brake.max_acceleration_rad_s2,
            ..Self::new_with(brake.max_acceleration_rad_s2)
        }
    }

    /// Idle, with the arm's limits.
    pub fn new(limits: &MotionLimits) -> Self {
        Self::new_with(limits.max_acceleration_rad_s2)
    }

    fn new_with(max_acceleration_rad_s2: Joints) -> Self {
        Self {
            at_sample: 0.0,
            elapsed_s: 0.0,
            duration_s: 0.0,
            period_s: 1.0,
            from_scale: 1.0,
            stopped: true,
            state: MotionState::default(),
            max_acceleration_rad_s2,
        }
    }

    /// The stop's duration from velocity `dq_rad_s`: the smoothstep's steepest slope
    /// (1.5/T) times the speed stays within a share of the acceleration limit.
    pub fn duration_s(dq_rad_s: &Joints, max_acceleration_rad_s2: &Joints, period_s: f64) -> f64 {
        let mut t = 2.0 * period_s;
        for j in 0..DOF {
            t = t.max(
                1.5 * dq_rad_s[j].abs() / (PATH_STOP_ACCEL_SHARE * max_acceleration_rad_s2[j]),
            );
        }
        t
    }

    /// Begins stopping from `state`, the command sent for sample `sample` of the plan.
    pub fn start(&mut self, state: MotionState, sample: usize, period_s: f64) {
        self.start_scaled(state, sample as f64, 1.0, period_s);
    }

    /// Begins stopping from `state`, the command sent at (fractional) sample `at_sample` of
    /// the plan played back at speed scale `scale` (speed and separation monitoring,
    /// [`crate::cycle::separation`]): the stop's scale falls from `scale`, not from 1, so
    /// the arm never speeds up.
    pub fn start_scaled(&mut self, state: MotionState, at_sample: f64, scale: f64, period_s: f64) {
        self.state = state;
        self.at_sample = at_sample;
        self.elapsed_s = 0.0;
        self.duration_s =
            Self::duration_s(&state.dq_rad_s, &self.max_acceleration_rad_s2, period_s);
        self.period_s = period_s;
        self.from_scale = if scale.is_finite() {
            scale.clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.stopped = false;
    }

    /// Whether the stop has reached rest.
    pub fn is_stopped(&self) -> bool {
        self.stopped
    }

    /// Samples of the plan the stop will still cover (an upper bound): the stop envelope.
    pub fn remaining_samples(&self) -> f64 {
        let tau = (self.elapsed_s / self.duration_s).min(1.0);
        // ∫ s dτ from τ to 1 of the smoothstep, times T, in periods of one sample each.
        let rest = 0.5 - (tau - tau.powi(3) + 0.5 * tau.powi(4));
        self.from_scale * rest * self.duration_s / self.period_s
    }

    /// Advances by `dt_s` along `plan` (one sample per `dt_s` at full speed); returns the
    /// new state.
    pub fn step(&mut self, plan: &Plan, dt_s: f64) -> &MotionState {
        if self.stopped || plan.is_empty() {
            self.stopped = true;
            self.state.dq_rad_s = [0.0; DOF];
            self.state.ddq_rad_s2 = [0.0; DOF];
            return &self.state;
        }
        let s0 = self.from_scale;
        let scale = |tau: f64| s0 * (1.0 - 3.0 * tau * tau + 2.0 * tau * tau * tau);
        let t = self.duration_s;
        let tau0 = (self.elapsed_s / t).min(1.0);
        self.elapsed_s += dt_s;
        let tau1 = (self.elapsed_s / t).min(1.0);
        let s = scale(tau1);
        let s_dot = s0 * 6.0 * (tau1 * tau1 - tau1) / t;
        let last = (plan.len() - 1) as f64;
        self.at_sample = (self.at_sample + 0.5 * (scale(tau0) + s)).min(last);
        let i = self.at_sample.floor() as usize;
        let k = (i + 1).min(plan.len() - 1);
        let f = self.at_sample - i as f64;
        for j in 0..DOF {
            let lerp = |a: &[Joints]| a[i][j] + (a[k][j] - a[i][j]) * f;
            let dq = lerp(&plan.dq_rad_s);
            self.state.q_rad[j] = lerp(&plan.q_rad);
            self.state.dq_rad_s[j] = dq * s;
            self.state.ddq_rad_s2[j] = lerp(&plan.ddq_rad_s2) * s * s + dq * s_dot;
        }
        if tau1 >= 1.0 || self.at_sample >= last {
            self.stopped = true;
            self.state.dq_rad_s = [0.0; DOF];
            self.state.ddq_rad_s2 = [0.0; DOF];
        }
        &self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;

    /// Issue 42 item 5: the configuration's longest stop (the prediction horizon's floor) is
    /// at least the path stop's duration and the brake's own time to rest from the velocity
    /// limits.
    #[test]
    fn the_configured_longest_stop_bounds_the_path_stop_and_the_brake() {
        let lim = RuntimeConfig::xarm5_default().limits;
        let dt = 0.004;
        let longest_s = crate::config::longest_stop_s(&lim);
        let path_s =
            PathStop::duration_s(&lim.max_velocity_rad_s, &lim.max_acceleration_rad_s2, dt);
        assert!(
            longest_s >= path_s - 1e-12,
            "{longest_s} < path stop {path_s}"
        );
        let mut brake = Brake::new(&lim);
        brake.start(MotionState {
            q_rad: [0.0; DOF],
            dq_rad_s: lim.max_velocity_rad_s,
            ddq_rad_s2: [0.0; DOF],
        });
        let mut steps = 0u32;
        while !brake.is_stopped() && steps < 100_000 {
            brake.step(dt);
            steps += 1;
        }
        let brake_s = f64::from(steps) * dt;
        assert!(longest_s + dt >= brake_s, "{longest_s} < brake {brake_s}");
    }

    #[test]
    fn the_path_stop_stays_on_the_plan_and_slows_to_rest_within_the_step_limit() {
        let lim = RuntimeConfig::xarm5_default().limits;
        let dt = 0.004;
        // A straight plan at 0.8 rad/s on joint 0, 2 s long.
        let mut plan = Plan::with_capacity(1, 1, dt, 500);
        for i in 0..500 {
            let q = 0.8 * dt * i as f64;
            plan.push(
                [q, 0.1, -0.2, 0.3, 0.0],
                [0.8, 0.0, 0.0, 0.0, 0.0],
                [0.0; DOF],
            );
        }
        let mut stop = PathStop::new(&lim);
        let at = 100;
        stop.start(
            MotionState {
                q_rad: plan.q_rad[at],
                dq_rad_s: plan.dq_rad_s[at],
                ddq_rad_s2: plan.ddq_rad_s2[at],
            },
            at,
            dt,
        );
        let envelope = stop.remaining_samples();
        let mut prev = plan.q_rad[at];
        let mut steps = 0;
        let mut last_v = 0.8;
        while !stop.is_stopped() {
            let s = *stop.step(&plan, dt);
            let step = (s.q_rad[0] - prev[0]).abs();
            assert!(step <= 0.8 * dt + 1e-12, "step {step}");
            assert!(s.dq_rad_s[0] <= last_v + 1e-12, "speed rises");
            assert_eq!(&s.q_rad[1..], &plan.q_rad[0][1..], "off the path");
            last_v = s.dq_rad_s[0];
            prev = s.q_rad;
            steps += 1;
            assert!(steps < 1000);
        }
        let covered = (prev[0] - plan.q_rad[at][0]) / (0.8 * dt);
        assert!(covered <= envelope + 1.0, "{covered} > {envelope}");
        assert!(covered > 0.3 * envelope, "{covered} vs {envelope}");
    }

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
