//! Trajectory smoothing of plans with Ruckig ([`PlanSmoother`]), what rt-core's twin thread
//! runs on every plan before the shield checks its samples, and what the learner's
//! verification runs on every successful episode (one function: [`super::smooth_and_check`]).
//!
//! # Decision: where Ruckig runs
//!
//! The official `ruckig` crate (0.19.4) bridges to the bundled C++ core through `cxx` and
//! copies every vector of its `InputParameter`/`OutputParameter` into fresh `Vec`s on every
//! `update()`/`calculate()` — it allocates on each call (measured by the counting allocator
//! in `tests/runtime_alloc.rs`). The cycle must not allocate, so:
//!
//! - **Plans** are smoothed by Ruckig on the twin thread ([`PlanSmoother`]): Ruckig's online
//!   interface is stepped at the cycle period through the lookahead's waypoints (each
//!   waypoint a target with a finite-difference target velocity), within the configured
//!   velocity, acceleration and jerk limits, and the velocity limits are scaled down until
//!   the TCP speed stays under its limit. The samples (position, velocity, acceleration per
//!   cycle) go into rt-core's `Plan`, which the cycle streams sample by sample. The shield then
//!   re-checks each sample in the cycle against the live scene.
//! - **Controlled stops** start from an arbitrary state inside the cycle, so they use
//!   rt-core's `Brake`: per joint, a jerk-limited deceleration to zero velocity (acceleration ramps at
//!   most `max_jerk`, is bounded by `max_acceleration`, and is shaped by
//!   `a = −sign(v)·min(A, √(2J|v|))` so that velocity and acceleration reach zero together),
//!   computed with plain `f64` arithmetic on fixed arrays. No allocation, no FFI, bounded
//!   time (a few hundred nanoseconds).

use ruckig::{InputParameter, OutputParameter, Result as RuckigResult, Ruckig};

use super::settings::MotionLimits;
use super::shield::ShieldModel;
use crate::{DOF, Joints};

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

/// Where [`PlanSmoother`] writes its samples: rt-core's `Plan` (what the cycle streams) or a
/// [`SmoothedPath`] (the learner's verification).
pub trait PlanSamples {
    /// Drops every sample; the samples that follow are `period_s` apart.
    fn restart(&mut self, period_s: f64);
    /// Appends one sample: positions, rad; velocities, rad/s; accelerations, rad/s².
    fn push_sample(&mut self, q_rad: Joints, dq_rad_s: Joints, ddq_rad_s2: Joints);
    /// The positions so far, rad, one per period.
    fn positions(&self) -> &[Joints];
}

/// Smoothed samples alone (no plan identity): what the learner's verification smooths into.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SmoothedPath {
    /// Sample period, s.
    pub period_s: f64,
    /// Joint positions, rad, one per period.
    pub q_rad: Vec<Joints>,
    /// Joint velocities, rad/s.
    pub dq_rad_s: Vec<Joints>,
    /// Joint accelerations, rad/s².
    pub ddq_rad_s2: Vec<Joints>,
}

impl PlanSamples for SmoothedPath {
    fn restart(&mut self, period_s: f64) {
        self.period_s = period_s;
        self.q_rad.clear();
        self.dq_rad_s.clear();
        self.ddq_rad_s2.clear();
    }

    fn push_sample(&mut self, q_rad: Joints, dq_rad_s: Joints, ddq_rad_s2: Joints) {
        self.q_rad.push(q_rad);
        self.dq_rad_s.push(dq_rad_s);
        self.ddq_rad_s2.push(ddq_rad_s2);
    }

    fn positions(&self) -> &[Joints] {
        &self.q_rad
    }
}

/// Share of a joint's velocity limit a plan segment is timed for (the rest is headroom for
/// Ruckig's pass-through profiles).
const SEGMENT_SPEED_SHARE: f64 = 0.7;

/// Why a plan could not be smoothed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SmoothError {
    /// There were no waypoints.
    #[error("no waypoints")]
    Empty,
    /// Ruckig refused the input (its result code).
    #[error("ruckig error {0}")]
    Ruckig(i32),
    /// The smoothed plan needs more samples than allowed.
    #[error("plan longer than {0} samples")]
    TooLong(usize),
    /// The TCP speed limit could not be met.
    #[error("TCP speed limit not met")]
    TcpSpeed,
}

fn ruckig_code(r: &RuckigResult) -> i32 {
    match r {
        RuckigResult::Working => 0,
        RuckigResult::Finished => 1,
        RuckigResult::Error => -1,
        RuckigResult::ErrorInvalidInput => -100,
        RuckigResult::ErrorTrajectoryDuration => -101,
        RuckigResult::ErrorPositionalLimits => -102,
        RuckigResult::ErrorZeroLimits => -104,
        RuckigResult::ErrorExecutionTimeCalculation => -110,
        RuckigResult::ErrorSynchronizationCalculation => -111,
    }
}

/// Ruckig-based plan smoothing (off the cycle; allocates).
#[derive(Debug, Clone)]
pub struct PlanSmoother {
    period_s: f64,
    limits: MotionLimits,
    max_samples: usize,
}

impl PlanSmoother {
    /// A smoother for plans sampled every `period_s`, at most `max_samples` long.
    pub fn new(period_s: f64, limits: MotionLimits, max_samples: usize) -> Self {
        Self {
            period_s,
            limits,
            max_samples,
        }
    }

    /// The sample period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Smooths `waypoints` (one every `step_s`, starting after `start`) into `plan`, scaling
    /// the velocity limits down until the TCP speed stays under the limit.
    ///
    /// # Errors
    /// [`SmoothError`].
    pub fn smooth<M: ShieldModel, P: PlanSamples>(
        &mut self,
        start: &MotionState,
        waypoints: &[Joints],
        step_s: f64,
        model: &mut M,
        plan: &mut P,
    ) -> Result<(), SmoothError> {
        // The shield's bound: the speed limit, and no TCP step per sample beyond the
        // controller's (issue 41 item 5).
        let limit_m_s = self
            .limits
            .max_tcp_speed_m_s
            .min(super::shield::MAX_TCP_STEP_M / self.period_s);
        let mut scale = 1.0;
        for _ in 0..5 {
            self.smooth_scaled(start, waypoints, step_s, scale, plan)?;
            let speed = max_tcp_speed_m_s(model, &start.q_rad, plan.positions(), self.period_s);
            if speed <= limit_m_s {
                return Ok(());
            }
            scale *= 0.95 * limit_m_s / speed;
        }
        Err(SmoothError::TcpSpeed)
    }

    fn smooth_scaled<P: PlanSamples>(
        &mut self,
        start: &MotionState,
        waypoints: &[Joints],
        step_s: f64,
        vel_scale: f64,
        plan: &mut P,
    ) -> Result<(), SmoothError> {
        if waypoints.is_empty() {
            return Err(SmoothError::Empty);
        }
        plan.restart(self.period_s);
        let vmax: Vec<f64> = self
            .limits
            .max_velocity_rad_s
            .iter()
            .map(|v| v * vel_scale)
            .collect();
        let mut ruckig = Ruckig::new_direct(DOF, self.period_s);
        let mut input = InputParameter::new(DOF);
        let mut output = OutputParameter::new_direct(DOF);
        input.current_position = start.q_rad.to_vec();
        input.current_velocity = start.dq_rad_s.to_vec();
        input.current_acceleration = start.ddq_rad_s2.to_vec();
        input.max_velocity = vmax.clone();
        input.max_acceleration = self.limits.max_acceleration_rad_s2.to_vec();
        input.max_jerk = self.limits.max_jerk_rad_s3.to_vec();
        let n = waypoints.len();
        // Each segment gets at least `step_s`, and longer where a joint would otherwise
        // exceed `SEGMENT_SPEED_SHARE` of its velocity limit: the arm follows the waypoints'
        // path more slowly instead of cutting its corners (the path is what the lookahead
        // and the shield checked).
        let segment_s = |from: &Joints, to: &Joints| {
            (0..DOF).fold(step_s, |d, j| {
                d.max((to[j] - from[j]).abs() / (SEGMENT_SPEED_SHARE * vmax[j]))
            })
        };
        let mut t_s = 0.0;
        let mut t_end = 0.0;
        for i in 0..n {
            let prev = if i == 0 {
                start.q_rad
            } else {
                waypoints[i - 1]
            };
            let target = waypoints[i];
            let here_s = segment_s(&prev, &target);
            let mut tv = [0.0; DOF];
            if i + 1 < n {
                let next = waypoints[i + 1];
                let span_s = here_s + segment_s(&target, &next);
                for j in 0..DOF {
                    tv[j] = ((next[j] - prev[j]) / span_s).clamp(-0.9 * vmax[j], 0.9 * vmax[j]);
                }
            }
            input.target_position = target.to_vec();
            input.target_velocity = tv.to_vec();
            input.target_acceleration = vec![0.0; DOF];
            t_end += here_s;
            let last = i + 1 == n;
            self.run_segment(
                &mut ruckig,
                &mut input,
                &mut output,
                plan,
                (&mut t_s, t_end, last),
            )?;
        }
        Ok(())
    }

    /// Ruckig's samples toward `input`'s target appended to `plan`, until the segment's
    /// time: `(t_s, t_end, last)` — the plan's time so far, the segment's end, and whether
    /// it is the last segment (then until the target is reached). A target reached early
    /// is held until its time comes.
    fn run_segment<P: PlanSamples>(
        &self,
        ruckig: &mut Ruckig,
        input: &mut InputParameter,
        output: &mut OutputParameter,
        plan: &mut P,
        (t_s, t_end, last): (&mut f64, f64, bool),
    ) -> Result<(), SmoothError> {
        loop {
            if !last && *t_s >= t_end - 1e-9 {
                break;
            }
            let mut r = ruckig.update(input, output);
            if !matches!(r, RuckigResult::Working | RuckigResult::Finished) {
                // Some pass-through velocities have no time-optimal profile from the
                // current state (Ruckig -110): pass this waypoint at rest instead.
                input.target_velocity = vec![0.0; DOF];
                r = ruckig.update(input, output);
            }
            let done = match r {
                RuckigResult::Working => false,
                RuckigResult::Finished => true,
                ref e => return Err(SmoothError::Ruckig(ruckig_code(e))),
            };
            if plan.positions().len() >= self.max_samples {
                return Err(SmoothError::TooLong(self.max_samples));
            }
            let mut q = [0.0; DOF];
            let mut dq = [0.0; DOF];
            let mut ddq = [0.0; DOF];
            q.copy_from_slice(&output.new_position);
            dq.copy_from_slice(&output.new_velocity);
            ddq.copy_from_slice(&output.new_acceleration);
            plan.push_sample(q, dq, ddq);
            output.pass_to_input(input);
            *t_s += self.period_s;
            // Reached early, a waypoint is held until its time comes.
            if done && (last || *t_s >= t_end - 1e-9) {
                break;
            }
        }
        Ok(())
    }
}

/// The largest TCP speed along `qs` (sampled every `dt_s`, after `start`), m/s.
pub fn max_tcp_speed_m_s<M: ShieldModel>(
    model: &mut M,
    start: &Joints,
    qs: &[Joints],
    dt_s: f64,
) -> f64 {
    let mut prev = model.tcp_position_m(start);
    let mut max = 0.0f64;
    for q in qs {
        let p = model.tcp_position_m(q);
        let d =
            ((p[0] - prev[0]).powi(2) + (p[1] - prev[1]).powi(2) + (p[2] - prev[2]).powi(2)).sqrt();
        max = max.max(d / dt_s);
        prev = p;
    }
    max
}
