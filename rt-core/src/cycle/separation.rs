//! Speed and separation monitoring after ISO/TS 15066: the middle step between full speed
//! and the pause. While the running plan stays collision-free but an obstacle is nearer
//! than the protective separation distance, the cycle plays the plan back slower instead of
//! stopping; at scale 0 the arm stands on the plan, and it goes on by itself (no latch) once
//! the separation allows.
//!
//! The protective separation distance at playback scale `s ∈ [0, 1]`:
//!
//! ```text
//! S_p(s) = v_h·(T_r + T_s(s)) + s·v_r·T_r + B(s) + C + Z
//! ```
//!
//! with `v_h` the intruder's speed (`[separation] intruder_speed_m_s`, or a tracked speed
//! when larger), `T_r` the reaction time, `v_r` the speed of the arm's watched points at full
//! playback (bounded by the shield's speed limit, `limits.max_tcp_speed_m_s`: the plans are
//! smoothed below it and every command is checked against it), `C` the intrusion distance and
//! `Z = Z_d + Z_r` the position uncertainty. `T_s(s)` and `B(s)` are the stopping time and
//! distance of the scale's own ramp to 0 from `s` (upper bounds, reversing a rise under way
//! included): the time grows with `s`, the distance with `s²`. Each period the monitor takes
//! the separation `d` (the shield model's distance from the last command sent to the live
//! scene's *moving* obstacles, those perception tracks with a velocity
//! ([`super::Intruders`], from the intake); a still box is no intruder, the plans are
//! verified against it: [`ShieldModel::intruder_distance_m`](super::shield::ShieldModel::intruder_distance_m)),
//! computes the largest `s` with `S_p(s) ≤ d` ([`SeparationParams::allowed_scale`]) and moves
//! its scale towards it, rate-limited so the joints stay within the plan's own limits:
//!
//! - the playback advances `0.5·(s_prev + s)` samples a period; the command's velocity is the
//!   plan's times `s` (never above the plan's), its acceleration the plan's times `s²` plus
//!   the plan's velocity times `ṡ`;
//! - `|ṡ|` is at most [`SCALE_ACCEL_SHARE`] of `min_j(a_max,j / v_max,j)` falling (so the
//!   added acceleration stays within that share of the limit, as the path stop's) and
//!   [`SCALE_RISE_SHARE`] of that rising; `|s̈|` at most [`SCALE_JERK_SHARE`] of
//!   `min_j(j_max,j / v_max,j)` (the added jerk `q̇·s̈`).
//!
//! Everything is `f64` arithmetic on `Copy` state: allocation-free, lock-free.

use twin::{DOF, Joints};

use crate::config::RuntimeConfig;
use crate::cycle::plan::MotionState;
use crate::cycle::plan::Plan;

/// Share of the acceleration limit the scale's fall may add (as the path stop's share).
pub const SCALE_ACCEL_SHARE: f64 = 0.8;
/// Share of the jerk limit the scale's change of rate may add.
pub const SCALE_JERK_SHARE: f64 = 0.5;
/// The scale rises at most this share of its fastest fall: a rise that must turn into a
/// fall overshoots little (the overshoot is part of `S_p`).
pub const SCALE_RISE_SHARE: f64 = 0.25;
/// A change of the scale since the last [`SeparationMonitor::update`] that reported one
/// (and logged `SpeedScaled`) that reports a new one; reaching 0 or 1 always does.
pub const LOG_STEP: f64 = 0.1;

/// The monitor's parameters, derived once from the runtime configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeparationParams {
    /// Scale the playback (off: always 1).
    pub enabled: bool,
    /// v_h, m/s.
    pub intruder_speed_m_s: f64,
    /// T_r, s.
    pub reaction_time_s: f64,
    /// C, m.
    pub intrusion_distance_m: f64,
    /// Z = Z_d + Z_r, m.
    pub position_uncertainty_m: f64,
    /// v_r at scale 1: the fastest the watched points move along a plan, m/s.
    pub robot_speed_m_s: f64,
    /// The scale's fastest fall, 1/s.
    pub max_fall_per_s: f64,
    /// The scale's fastest rise, 1/s.
    pub max_rise_per_s: f64,
    /// The largest change of the scale's rate, 1/s².
    pub max_rate_change_per_s2: f64,
}

impl SeparationParams {
    /// From the runtime configuration (`[separation]`, the motion limits and the shield's
    /// speed limit).
    pub fn from_runtime(cfg: &RuntimeConfig) -> Self {
        let l = &cfg.limits;
        let mut accel_per_velocity = f64::INFINITY;
        let mut jerk_per_velocity = f64::INFINITY;
        for j in 0..DOF {
            accel_per_velocity =
                accel_per_velocity.min(l.max_acceleration_rad_s2[j] / l.max_velocity_rad_s[j]);
            jerk_per_velocity =
                jerk_per_velocity.min(l.max_jerk_rad_s3[j] / l.max_velocity_rad_s[j]);
        }
        let fall = SCALE_ACCEL_SHARE * accel_per_velocity;
        let s = &cfg.separation;
        Self {
            enabled: s.enabled,
            intruder_speed_m_s: s.intruder_speed_m_s,
            reaction_time_s: s.reaction_time_s,
            intrusion_distance_m: s.intrusion_distance_m,
            position_uncertainty_m: s.position_uncertainty_m,
            robot_speed_m_s: l.max_tcp_speed_m_s,
            max_fall_per_s: fall,
            max_rise_per_s: SCALE_RISE_SHARE * fall,
            max_rate_change_per_s2: SCALE_JERK_SHARE * jerk_per_velocity,
        }
    }

    /// How far the scale may still rise while a rise at full rate turns into a fall.
    fn rise_overshoot(&self) -> f64 {
        self.max_rise_per_s.powi(2) / (2.0 * self.max_rate_change_per_s2)
    }

    /// Time to turn a rise at full rate around, plus the time to reach the full fall
    /// rate, s.
    fn ramp_time_s(&self) -> (f64, f64) {
        (
            self.max_rise_per_s / self.max_rate_change_per_s2,
            self.max_fall_per_s / self.max_rate_change_per_s2,
        )
    }

    /// T_s(s): an upper bound of the time from scale `s` to rest, s.
    pub fn stopping_time_s(&self, scale: f64) -> f64 {
        let (t_rev, t_jerk) = self.ramp_time_s();
        t_rev + t_jerk + (scale + self.rise_overshoot()) / self.max_fall_per_s
    }

    /// B(s): an upper bound of the watched points' travel from scale `s` to rest, m (the
    /// scale may rise by the overshoot first; the fall from there is point-symmetric, so it
    /// covers half its time at the starting speed).
    pub fn stopping_distance_m(&self, scale: f64) -> f64 {
        let (t_rev, t_jerk) = self.ramp_time_s();
        let top = scale + self.rise_overshoot();
        self.robot_speed_m_s * top * (t_rev + 0.5 * (t_jerk + top / self.max_fall_per_s))
    }

    /// S_p(s), m, for an intruder at `intruder_speed_m_s`.
    pub fn protective_distance_m(&self, scale: f64, intruder_speed_m_s: f64) -> f64 {
        intruder_speed_m_s * (self.reaction_time_s + self.stopping_time_s(scale))
            + scale * self.robot_speed_m_s * self.reaction_time_s
            + self.stopping_distance_m(scale)
            + self.intrusion_distance_m
            + self.position_uncertainty_m
    }

    /// The largest scale `s ∈ [0, 1]` with `S_p(s) ≤ separation_m` (0 when even
    /// `S_p(0)` is not, or the separation is NaN).
    pub fn allowed_scale(&self, separation_m: f64, intruder_speed_m_s: f64) -> f64 {
        let v_h = intruder_speed_m_s;
        let c = self.protective_distance_m(0.0, v_h);
        // NaN counts as no separation.
        if separation_m.is_nan() || separation_m <= c {
            return 0.0;
        }
        let full = self.protective_distance_m(1.0, v_h);
        if separation_m >= full {
            return 1.0;
        }
        // S_p is quadratic in s: a·s² + b·s + c, from its values at -1, 0 and 1.
        let minus = self.protective_distance_m(-1.0, v_h);
        let a = 0.5 * (full + minus) - c;
        let b = 0.5 * (full - minus);
        let e = separation_m - c;
        // The positive root of a·s² + b·s − e, in the form without cancellation.
        let s = 2.0 * e / (b + (b * b + 4.0 * a * e).sqrt());
        if s.is_finite() {
            s.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// The monitor's state: the playback scale and its rate (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeparationMonitor {
    params: SeparationParams,
    /// The scale now.
    scale: f64,
    /// The scale one period before.
    prev_scale: f64,
    /// ṡ, 1/s.
    rate_per_s: f64,
    /// The scale the separation allows now.
    allowed: f64,
    /// The last separation, m.
    separation_m: f64,
    /// The scale last reported.
    reported: f64,
}

impl SeparationMonitor {
    /// At full speed.
    pub fn new(params: SeparationParams) -> Self {
        Self {
            params,
            scale: 1.0,
            prev_scale: 1.0,
            rate_per_s: 0.0,
            allowed: 1.0,
            separation_m: f64::INFINITY,
            reported: 1.0,
        }
    }

    /// Whether it scales at all.
    pub fn enabled(&self) -> bool {
        self.params.enabled
    }

    /// The parameters.
    pub fn params(&self) -> &SeparationParams {
        &self.params
    }

    /// The playback scale now, 0..=1.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// ṡ, 1/s.
    pub fn rate_per_s(&self) -> f64 {
        self.rate_per_s
    }

    /// The scale the last separation allows.
    pub fn allowed_scale(&self) -> f64 {
        self.allowed
    }

    /// The last separation, m (infinite before the first, or when off).
    pub fn separation_m(&self) -> f64 {
        self.separation_m
    }

    /// One period of `dt_s` at separation `separation_m` (NaN: unknown, counted as none)
    /// with an obstacle tracked at `tracked_speed_m_s` (0 when unknown: the configured
    /// intruder speed counts whenever it is larger). Returns the new scale when it is one to
    /// report: [`LOG_STEP`] away from the last one reported, or 0 or 1 reached.
    pub fn update(&mut self, separation_m: f64, tracked_speed_m_s: f64, dt_s: f64) -> Option<f64> {
        self.prev_scale = self.scale;
        if !self.params.enabled {
            return None;
        }
        let p = &self.params;
        let v_h = p.intruder_speed_m_s.max(tracked_speed_m_s);
        let target = p.allowed_scale(separation_m, v_h);
        self.separation_m = separation_m;
        self.allowed = target;
        // The scale as a position with a bounded rate and a bounded change of rate: towards
        // the target at the rate from which it can still stop there (as the brake's).
        let (s, r) = (self.scale, self.rate_per_s);
        let rr = p.max_rate_change_per_s2;
        let e = target - s;
        // The error left after this period at the present rate: from there the rate must
        // still be able to reach 0 on the target (without it the rate lags the curve by a
        // few periods and is cut short at the target).
        let ahead = e - r * dt_s;
        let left = if ahead * e > 0.0 { ahead.abs() } else { 0.0 };
        let r_des = if e >= 0.0 {
            p.max_rise_per_s.min((2.0 * rr * left).sqrt())
        } else {
            -p.max_fall_per_s.min((2.0 * rr * left).sqrt())
        };
        let r_new = r + (r_des - r).clamp(-rr * dt_s, rr * dt_s);
        let mut s_new = s + 0.5 * (r + r_new) * dt_s;
        let mut r_out = r_new;
        // Crossed the target slowly: settle on it.
        if e * (target - s_new) <= 0.0 && r_new.abs() <= 2.0 * rr * dt_s {
            s_new = target;
            r_out = 0.0;
        }
        if s_new <= 0.0 {
            s_new = 0.0;
            r_out = r_out.max(0.0);
        } else if s_new >= 1.0 {
            s_new = 1.0;
            r_out = r_out.min(0.0);
        }
        self.scale = s_new;
        self.rate_per_s = r_out;
        let reached_end = (s_new == 0.0 || s_new == 1.0) && s_new != self.reported;
        if reached_end || (s_new - self.reported).abs() >= LOG_STEP {
            self.reported = s_new;
            return Some(s_new);
        }
        None
    }

    /// The command of this period along `plan` and where it lies: the last command lay
    /// `frac` of a sample beyond sample `next − 1` (before sample 0 when `next` is 0); the
    /// playback advances `0.5·(s_prev + s)` samples. Returns the sample at or before the new
    /// point, the fraction beyond it, and the command: the position interpolated, the
    /// velocity the plan's times `s`, the acceleration the plan's times `s²` plus the plan's
    /// velocity times `ṡ`. At full speed on a sample it is sample `next` exactly, as
    /// planned. `next` must be below `plan.len()`.
    pub fn playback(&self, plan: &Plan, next: usize, frac: f64) -> (usize, f64, MotionState) {
        let step = 0.5 * (self.prev_scale + self.scale);
        if step == 1.0 && frac == 0.0 {
            return (next, 0.0, plan.sample(next));
        }
        let last = plan.len().saturating_sub(1);
        let at = (next as f64 - 1.0 + frac + step).clamp(0.0, last as f64);
        let i = (at.floor() as usize).min(last);
        let f = at - i as f64;
        let k = (i + 1).min(last);
        let (s, rate) = (self.scale, self.rate_per_s);
        let mut st = MotionState::default();
        for j in 0..DOF {
            let lerp = |a: &[Joints]| a[i][j] + (a[k][j] - a[i][j]) * f;
            let dq = lerp(&plan.dq_rad_s);
            st.q_rad[j] = lerp(&plan.q_rad);
            st.dq_rad_s[j] = dq * s;
            st.ddq_rad_s2[j] = lerp(&plan.ddq_rad_s2) * s * s + dq * rate;
        }
        (i, f, st)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use crate::cycle::link::InProcessArm;
    use crate::cycle::shield::ShieldModel;
    use crate::cycle::{Cycle, CycleEvent, Intruders, Mode, SceneUpdate, StopReason, TwinIo};
    use crate::rt::rt_log::RtLogDrain;
    use crate::testing::toy::{ToyArm, ToyScene};

    const DT: f64 = 0.004;
    const START: Joints = [0.0, -0.3, -0.6, 0.4, 0.0];

    fn config(enabled: bool) -> RuntimeConfig {
        let mut cfg = RuntimeConfig::xarm5_default();
        cfg.separation.enabled = enabled;
        cfg
    }

    fn params() -> SeparationParams {
        SeparationParams::from_runtime(&config(true))
    }

    /// The formula: S_p grows with s, the allowed scale inverts it, and its ends.
    #[test]
    fn the_allowed_scale_inverts_the_protective_distance() {
        let p = params();
        let v_h = p.intruder_speed_m_s;
        let (near, far) = (
            p.protective_distance_m(0.0, v_h),
            p.protective_distance_m(1.0, v_h),
        );
        // ISO/TS 15066 with the shipped values: the minimum covers the intruder over the
        // reaction and the scale's ramps, plus C and Z.
        assert!(
            near > v_h * p.reaction_time_s + 0.04 && near < far,
            "{near} {far}"
        );
        // The figures assets/runtime.toml and the README give for the shipped values.
        assert!(
            (near - 0.53).abs() < 0.005 && (far - 1.33).abs() < 0.005,
            "{near} {far}"
        );
        for k in 1..10 {
            let s = f64::from(k) / 10.0;
            let d = p.protective_distance_m(s, v_h);
            assert!(d > p.protective_distance_m(s - 0.1, v_h));
            assert!((p.allowed_scale(d, v_h) - s).abs() < 1e-9, "{s}");
        }
        assert_eq!(p.allowed_scale(near, v_h), 0.0);
        assert_eq!(p.allowed_scale(0.5 * near, v_h), 0.0);
        assert_eq!(p.allowed_scale(-0.01, v_h), 0.0);
        assert_eq!(p.allowed_scale(f64::NAN, v_h), 0.0);
        assert_eq!(p.allowed_scale(far, v_h), 1.0);
        assert_eq!(p.allowed_scale(f64::INFINITY, v_h), 1.0);
        // A faster intruder needs more room for the same scale.
        let mid = 0.5 * (near + far);
        assert!(p.allowed_scale(mid, 2.0 * v_h) < p.allowed_scale(mid, v_h));
        // B grows with s² (its second difference is v_r / (2 ṡ_max) · 2 · 0.5²), T_s with s.
        let b = |s| p.stopping_distance_m(s);
        let second = b(1.0) - 2.0 * b(0.5) + b(0.0);
        assert!((second - 0.25 * p.robot_speed_m_s / p.max_fall_per_s).abs() < 1e-12);
        assert!(b(0.0) < 0.05 * b(1.0), "{} {}", b(0.0), b(1.0));
        assert!(p.stopping_time_s(1.0) > p.stopping_time_s(0.5));
    }

    /// (1) A far obstacle (or none) leaves the playback at full speed, and nothing is logged.
    #[test]
    fn a_far_obstacle_keeps_full_speed() {
        let p = params();
        let far = p.protective_distance_m(1.0, p.intruder_speed_m_s) + 0.01;
        let mut m = SeparationMonitor::new(p);
        for k in 0..500 {
            let d = if k % 2 == 0 { far } else { f64::INFINITY };
            assert_eq!(m.update(d, 0.0, DT), None);
            assert_eq!(m.scale(), 1.0);
        }
        // Off, nothing scales whatever the separation.
        let mut off = SeparationMonitor::new(SeparationParams::from_runtime(&config(false)));
        assert_eq!(off.update(0.0, 0.0, DT), None);
        assert_eq!(off.scale(), 1.0);
    }

    /// The scale follows the allowed one within its rate limits both ways, settles on it,
    /// reaches exactly 0 and exactly 1, and reports only steps of LOG_STEP and the ends.
    #[test]
    fn the_scale_is_rate_limited_and_reported_sparingly() {
        let p = params();
        let v_h = p.intruder_speed_m_s;
        let mut m = SeparationMonitor::new(p);
        let mut reports = 0;
        let mut rate = 0.0;
        let check = |m: &SeparationMonitor, rate: &mut f64| {
            assert!(m.rate_per_s() >= -p.max_fall_per_s - 1e-12);
            assert!(m.rate_per_s() <= p.max_rise_per_s + 1e-12);
            let dr = m.rate_per_s() - *rate;
            // The change of rate is bounded, except when settling from a slow rate.
            assert!(
                dr.abs() <= 2.0 * p.max_rate_change_per_s2 * DT + 1e-12,
                "{dr} at {}",
                m.scale()
            );
            *rate = m.rate_per_s();
        };
        // Too close: down to exactly 0 within the stopping time bound.
        let mut periods = 0;
        while m.scale() > 0.0 {
            reports += usize::from(m.update(0.0, 0.0, DT).is_some());
            check(&m, &mut rate);
            periods += 1;
            assert!(
                f64::from(periods) * DT <= p.stopping_time_s(1.0),
                "{periods}"
            );
        }
        // Mid-way: settles on the allowed scale from below.
        let d = p.protective_distance_m(0.5, v_h);
        for _ in 0..2000 {
            reports += usize::from(m.update(d, 0.0, DT).is_some());
            check(&m, &mut rate);
            assert!(m.scale() <= 0.5 + p.rise_overshoot() + 1e-9);
        }
        assert!((m.scale() - 0.5).abs() < 1e-9, "{}", m.scale());
        // Clear: back to exactly 1, no faster than the rise rate.
        let mut prev = m.scale();
        for _ in 0..2000 {
            reports += usize::from(m.update(f64::INFINITY, 0.0, DT).is_some());
            check(&m, &mut rate);
            assert!(m.scale() - prev <= p.max_rise_per_s * DT + 1e-12);
            prev = m.scale();
        }
        assert_eq!(m.scale(), 1.0);
        // 1 → 0 → 0.5 → 1: at most one report per step and per end.
        assert!(reports <= 10 + 5 + 5 + 3, "{reports}");
        assert!(reports >= 3, "{reports}");
    }

    /// A quintic move of the base joint by 1 rad in 3 s, from rest to rest.
    fn plan(id: u64) -> Plan {
        let (dist, dur) = (1.0, 3.0);
        let n = (dur / DT) as usize + 1;
        let mut p = Plan::with_capacity(id, 1, DT, n);
        for i in 0..n {
            let t = (i as f64 * DT / dur).min(1.0);
            let mut q = START;
            let mut dq = [0.0; DOF];
            let mut ddq = [0.0; DOF];
            q[0] += dist * (10.0 * t.powi(3) - 15.0 * t.powi(4) + 6.0 * t.powi(5));
            dq[0] = dist / dur * (30.0 * t * t - 60.0 * t.powi(3) + 30.0 * t.powi(4));
            ddq[0] = dist / dur.powi(2) * (60.0 * t - 180.0 * t * t + 120.0 * t.powi(3));
            p.push(q, dq, ddq);
        }
        p
    }

    /// A thin box on the base axis, above the arm, at `distance_m` from the arm at START
    /// (the base joint's rotation leaves the distance all but unchanged).
    fn box_at(distance_m: f64) -> ToyScene {
        let at = |z: f64| {
            let mut s = ToyScene::empty();
            s.push_obstacle([0.0, 0.0, z], [0.01, 0.01, 0.01]);
            s
        };
        let (mut lo, mut hi) = (1.0, 3.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if ToyArm.min_distance_m(&START, &at(mid)) < distance_m {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        at(lo)
    }

    struct Bench {
        cycle: Cycle<ToyArm, InProcessArm>,
        twin: TwinIo<ToyScene>,
        log: RtLogDrain<CycleEvent>,
        now_ns: u64,
        scene: ToyScene,
        cmds: Vec<MotionState>,
    }

    impl Bench {
        fn new(enabled: bool, scene: ToyScene) -> Self {
            let cfg = config(enabled);
            let (mut cycle, twin, log) = crate::testing::toy::toy_cycle(&cfg, START);
            let now_ns = 1_000_000_000;
            cycle.start(now_ns).unwrap();
            let mut b = Self {
                cycle,
                twin,
                log,
                now_ns,
                scene,
                cmds: Vec::new(),
            };
            b.run(2);
            assert!(b.twin.plans.send(Box::new(plan(1))).is_ok());
            b
        }

        fn run(&mut self, periods: usize) {
            for _ in 0..periods {
                self.twin.scenes.send(SceneUpdate {
                    scene: self.scene,
                    stamp_ns: self.now_ns,
                    refused: false,
                    intruders: Intruders::ALL_UNKNOWN,
                });
                self.cycle.process(self.now_ns);
                self.cmds.push(self.cycle.report().cmd);
                self.now_ns += 4_000_000;
                self.twin.plans.collect_returned();
            }
        }

        fn tcp(&self) -> [f64; 3] {
            ToyArm.tcp_position_m(&self.cycle.report().cmd.q_rad)
        }

        fn events(&mut self) -> Vec<CycleEvent> {
            let mut out = Vec::new();
            self.log.drain(|r| out.push(r.event));
            out
        }

        /// Every command within the plan's velocity and the acceleration limit (the second
        /// difference of the commands sent).
        fn assert_within_limits(&self) {
            let cfg = config(true);
            let plan_v = 1.875 / 3.0; // the quintic's peak, rad/s
            for w in self.cmds.windows(3) {
                for j in 0..DOF {
                    let v = (w[2].q_rad[j] - w[1].q_rad[j]) / DT;
                    let a = (w[2].q_rad[j] - 2.0 * w[1].q_rad[j] + w[0].q_rad[j]) / (DT * DT);
                    assert!(v.abs() <= plan_v + 1e-3, "joint {j}: {v} rad/s");
                    assert!(
                        a.abs() <= cfg.limits.max_acceleration_rad_s2[j] + 0.05,
                        "joint {j}: {a} rad/s^2"
                    );
                }
            }
        }
    }

    fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    }

    /// (2) An obstacle inside S_p but clear of the path: the scale settles strictly between
    /// 0 and 1 and the arm keeps moving along the plan, slower than unscaled, with no stop.
    #[test]
    fn an_obstacle_inside_the_protective_distance_slows_the_arm_without_stopping_it() {
        let p = params();
        let v_h = p.intruder_speed_m_s;
        let mid = 0.5 * (p.protective_distance_m(0.0, v_h) + p.protective_distance_m(1.0, v_h));
        let scene = box_at(mid);
        let mut slow = Bench::new(true, scene);
        let mut full = Bench::new(false, scene);
        let tcp0 = slow.tcp();
        slow.run(300);
        full.run(300);
        let r = *slow.cycle.report();
        assert!(
            r.speed_scale > 0.05 && r.speed_scale < 0.95,
            "{}",
            r.speed_scale
        );
        assert!(
            (r.separation_m - mid).abs() < 0.02,
            "{} vs {mid}",
            r.separation_m
        );
        assert_eq!(r.mode, Mode::Following);
        assert_eq!((r.stops, r.awaiting_ack), (0, false));
        assert!(r.cmd.dq_rad_s[0] > 0.0, "the arm stands");
        let (moved, unscaled) = (dist(tcp0, slow.tcp()), dist(tcp0, full.tcp()));
        assert!(
            moved > 0.01 && moved < 0.8 * unscaled,
            "{moved} vs {unscaled}"
        );
        assert_eq!(full.cycle.report().speed_scale, 1.0);
        slow.assert_within_limits();
        // Logged on change only: a handful of SpeedScaled events in 300 periods.
        let scaled = slow
            .events()
            .iter()
            .filter(|e| matches!(e, CycleEvent::SpeedScaled { .. }))
            .count();
        assert!((1..=12).contains(&scaled), "{scaled}");
        assert!(
            full.events()
                .iter()
                .all(|e| !matches!(e, CycleEvent::SpeedScaled { .. }))
        );
    }

    /// (3) An obstacle nearer than S_p(0), still clear of the shield's clearance: the scale
    /// reaches 0 and the arm comes to rest on the plan — no stop, no latch. (4) Once it
    /// leaves, the scale recovers to 1 by itself and the plan runs to its end.
    #[test]
    fn a_near_obstacle_brings_the_arm_to_rest_and_it_goes_on_once_clear() {
        let p = params();
        let near = 0.5 * p.protective_distance_m(0.0, p.intruder_speed_m_s);
        let mut b = Bench::new(true, ToyScene::empty());
        b.run(150); // under way at full speed
        assert_eq!(b.cycle.report().speed_scale, 1.0);
        b.scene = box_at(near);
        b.run(200);
        let r = *b.cycle.report();
        assert_eq!(r.speed_scale, 0.0);
        assert_eq!(r.mode, Mode::Following);
        assert_eq!((r.stops, r.awaiting_ack), (0, false));
        assert_eq!(r.cmd.dq_rad_s, [0.0; DOF]);
        let rest = b.tcp();
        let at = r.next_index;
        b.run(100);
        assert_eq!(b.tcp(), rest, "the arm moved at scale 0");
        assert_eq!(b.cycle.report().next_index, at);
        assert!(b.cycle.link().q_rad()[0] > START[0] + 0.01);
        // (4) Clear again: full speed by itself, and the plan runs to its end.
        b.scene = ToyScene::empty();
        b.run(400); // the scale rises at most max_rise_per_s (0.8 /s)
        assert_eq!(b.cycle.report().speed_scale, 1.0);
        assert!(dist(rest, b.tcp()) > 0.01);
        b.run(800);
        let r = *b.cycle.report();
        assert_eq!(r.mode, Mode::Idle);
        assert_eq!((r.stops, r.awaiting_ack), (0, false));
        assert!((b.cycle.link().q_rad()[0] - (START[0] + 1.0)).abs() < 1e-6);
        b.assert_within_limits();
        let ev = b.events();
        assert!(ev.contains(&CycleEvent::SpeedScaled { scale: 0.0 }));
        assert!(ev.contains(&CycleEvent::SpeedScaled { scale: 1.0 }));
        assert!(
            ev.iter()
                .any(|e| matches!(e, CycleEvent::PlanFinished { .. }))
        );
    }

    /// A plan joining the running one during scaled playback takes over where the arm is,
    /// between two samples: the arm goes on forwards (it used to go back to the join sample).
    #[test]
    fn a_joining_plan_takes_over_between_samples_without_going_back() {
        let p = params();
        let d = p.protective_distance_m(0.4, p.intruder_speed_m_s);
        let mut b = Bench::new(true, box_at(d));
        b.run(300);
        let r = *b.cycle.report();
        assert!(
            r.speed_scale > 0.05 && r.speed_scale < 0.9,
            "{}",
            r.speed_scale
        );
        // The same path from 10 samples ahead, as the twin's replacement plans are.
        let index = r.next_index + 10;
        let whole = plan(1);
        let mut join = Plan::with_capacity(2, 1, DT, whole.len() - index);
        join.join = Some(crate::cycle::plan::JoinPoint { plan_id: 1, index });
        for k in index..whole.len() {
            join.push(whole.q_rad[k], whole.dq_rad_s[k], whole.ddq_rad_s2[k]);
        }
        assert!(b.twin.plans.send(Box::new(join)).is_ok());
        let before = b.cmds.len();
        b.run(200);
        assert_eq!(b.cycle.report().plan_id, 2, "not joined");
        assert_eq!(b.cycle.report().stops, 0);
        for w in b.cmds[before - 1..].windows(2) {
            assert!(
                w[1].q_rad[0] > w[0].q_rad[0],
                "{} -> {}",
                w[0].q_rad[0],
                w[1].q_rad[0]
            );
        }
        b.assert_within_limits();
    }

    /// A stop along the plan begun during scaled playback starts from the scaled speed: the
    /// arm never speeds up (the time-scaled stop used to start from the plan's full speed).
    #[test]
    fn a_stop_during_scaled_playback_never_speeds_the_arm_up() {
        let p = params();
        let v_h = p.intruder_speed_m_s;
        let d = p.protective_distance_m(0.3, v_h);
        let mut b = Bench::new(true, box_at(d));
        b.run(300);
        let s = b.cycle.report().speed_scale;
        assert!(s > 0.05 && s < 0.6, "{s}");
        let before = b.cmds.len();
        b.twin.control.revoke_up_to(1);
        b.run(300);
        let r = *b.cycle.report();
        assert_eq!(r.stop_reason, StopReason::Revoked);
        assert_eq!(r.mode, Mode::Stopped);
        let speed = |w: &[MotionState]| (w[1].q_rad[0] - w[0].q_rad[0]).abs() / DT;
        let v0 = speed(&b.cmds[before - 2..before]);
        for w in b.cmds[before - 1..].windows(2) {
            assert!(speed(w) <= v0 * 1.01 + 1e-9, "{} > {v0}", speed(w));
        }
        b.assert_within_limits();
    }
}
