//! Backing out (issue 42 item 3). An arm at rest closer to a box than it can plan from
//! ([`TOO_CLOSE_EXTRA_M`] beyond the shield's clearance), and closer than in the scene its
//! last plan was approved in — stopped there by a controlled stop after a box appeared, or a
//! box came to it (a box walking at an arm at rest shows as its predicted occupancy closing
//! in) — retreats along the path it came (the
//! recorded path, reversed from where it rests), re-verified against the current scene. Where
//! it comes to rest (the retreat's end, or a stop on the way) is a pause of the episode, as
//! after any stop: a continuation from there when one passes, else (with `return_home`) home
//! along the executed path and the episode again; without `return_home`, the ordinary
//! planning from there. A fault (the controller's collision stop, an arm error, a lost link:
//! the cycle awaits an operator) is never backed out of.
//!
//! **The retreat rule**: on the way out, the arm's distance to every box never decreases —
//! from each sample of the retreat to the next, each box's distance (and the clearance to
//! the scene as a whole) is at least what it was ([`Shield::backs_out`]; checked on every
//! sample of the smoothed plan, [`retreat_gets_closer`]). The retreat ends at the first
//! waypoint [`CLEAR_EXTRA_M`] beyond the shield's clearance (or where the rule would break,
//! if the arm is out of the too-close band by then). Like every plan it is smoothed, passes
//! the one shield check (whose clearance lets an arm already too close move away, and only
//! away: [`Shield::check_pose_from`]), and is registered with the plan guard before the cycle
//! may adopt it: approved, guarded, revocable.
//!
//! [`Shield::backs_out`]: crate::cycle::shield::Shield::backs_out
//! [`Shield::check_pose_from`]: crate::cycle::shield::Shield::check_pose_from

use twin::Joints;

use super::{Lookahead, Phase, Rest, Transition, TwinEvent, TwinWorker};
use crate::cycle::shield::{Shield, ShieldModel};
use crate::cycle::{CycleReport, StopReason};

/// An arm at rest closer than this beyond the shield's clearance backs out, m (the lookahead's
/// own clearance is the shield's plus 5 mm: from there no plan would pass).
pub const TOO_CLOSE_EXTRA_M: f64 = 0.01;

/// A box counts as having come to the arm when the clearance is this much smaller than in the
/// scene its last plan was approved in, m.
pub const CAME_CLOSER_M: f64 = 0.001;

/// A retreat ends once the arm is this far beyond the shield's clearance, m.
pub const CLEAR_EXTRA_M: f64 = 0.04;

/// Where a retreat was refused last (the scene and the pose): not tried again until either
/// changes.
#[derive(Debug, Clone, Copy)]
pub struct RetreatWatch<S> {
    refused_at: Option<(S, Joints)>,
}

impl<S> Default for RetreatWatch<S> {
    fn default() -> Self {
        Self { refused_at: None }
    }
}

/// The retreat rule over `path` from `from`: the index of the first sample at which the arm
/// comes closer to the scene or to any box than at the sample before, if any.
pub fn retreat_gets_closer<M: ShieldModel>(
    shield: &mut Shield<M>,
    from: &Joints,
    path: &[Joints],
    scene: &M::Scene,
) -> Option<usize> {
    let mut prev = *from;
    for (i, q) in path.iter().enumerate() {
        let d = shield.model_mut().min_distance_m(q, scene);
        if !shield.backs_out(&prev, q, d, scene) {
            return Some(i);
        }
        prev = *q;
    }
    None
}

/// Whether a stop for `reason` leaves the arm to an operator (never backed out of).
fn is_fault(reason: StopReason) -> bool {
    matches!(
        reason,
        StopReason::ArmError(_)
            | StopReason::ControllerStopped { .. }
            | StopReason::LinkLost
            | StopReason::ModelMismatch
            | StopReason::TrackingLost
            | StopReason::Shutdown
            | StopReason::Frozen
    )
}

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// One look at the arm at rest after its last plan: when it ended a retreat, planning is
    /// due (once); when it is too close to the current scene's boxes, a retreat is made and
    /// sent. True when a retreat is in hand (the step is over).
    pub(super) fn back_out_if_too_close(&mut self, events: &mut Vec<TwinEvent<L::Scene>>) -> bool {
        let Some((r, rest, sent_id, policy_id)) = self.rest_after_last_plan() else {
            return false;
        };
        if let (
            Rest::AtEnd,
            Phase::BackingOut {
                plan_id,
                done: false,
            },
        ) = (rest, self.excursion.phase())
            && plan_id == sent_id
        {
            self.excursion.next(Transition::BackedOut);
            self.planning.request();
        }
        let Some(scene) = self.scene.scene() else {
            return false;
        };
        if r.awaiting_ack
            || (r.stop_reason != StopReason::None && is_fault(r.stop_reason))
            || self.planning.backing_off(r.t_ns)
            || self.io.control.shutdown_requested()
            || self
                .retreat
                .refused_at
                .is_some_and(|(s, q)| s == scene && q == r.cmd.q_rad)
        {
            return false;
        }
        let min_m = self.approver.shield_mut().limits().min_distance_m;
        let here_m = self
            .approver
            .shield_mut()
            .model_mut()
            .min_distance_m(&r.cmd.q_rad, &scene);
        // Too close, and closer than in the scene its plan was approved in: a box came to it
        // (an approved plan may end 15 mm from a box it knew; that is no reason to back out).
        let planned = self.live_plan(sent_id).map(|(_, planned)| *planned);
        let planned_m = planned.map_or(f64::INFINITY, |planned| {
            self.approver
                .shield_mut()
                .model_mut()
                .min_distance_m(&r.cmd.q_rad, &planned)
        });
        // In contact (the padded distance at or below zero) nothing moves the arm.
        if here_m <= 0.0
            || here_m >= min_m + TOO_CLOSE_EXTRA_M
            || here_m >= planned_m - CAME_CLOSER_M
        {
            return false;
        }
        if self.send_retreat(r, policy_id, scene, min_m, events) {
            return true;
        }
        self.retreat.refused_at = Some((scene, r.cmd.q_rad));
        false
    }

    /// The retreat from where the arm rests (report `r`) along the recorded path — its
    /// cycle-rate samples reversed, cut where the arm is clear and where the rule would break,
    /// re-timed from rest ([`retime`]) — checked (the shield, the retreat rule on every sample)
    /// and sent. The recorded path is left as it is: the retreat runs back along it, so
    /// wherever the arm comes to rest — the retreat's end, or a stop on the way — lies on it
    /// and the pause that follows cuts it there. True when sent.
    fn send_retreat(
        &mut self,
        r: CycleReport,
        policy_id: u64,
        scene: L::Scene,
        min_m: f64,
        events: &mut Vec<TwinEvent<L::Scene>>,
    ) -> bool {
        let from = r.cmd.q_rad;
        if !self.path.cut_at(&from) || self.path.len() < 2 {
            return false;
        }
        let mut way = std::mem::take(&mut self.approver.waypoints);
        self.path.way_home(1, &mut way);
        let shield = self.approver.shield_mut();
        // Out to the first sample clear of the scene, and only as far as the rule holds.
        if let Some(k) = way
            .iter()
            .position(|q| shield.model_mut().min_distance_m(q, &scene) >= min_m + CLEAR_EXTRA_M)
        {
            way.truncate(k + 1);
        }
        if let Some(k) = retreat_gets_closer(shield, &from, &way, &scene) {
            way.truncate(k);
        }
        let out_m = way.last().map_or(f64::NEG_INFINITY, |q| {
            shield.model_mut().min_distance_m(q, &scene)
        });
        let limits = *shield.limits();
        let period_s = self.approver.period_s();
        let samples = retime(&from, &way, &limits.max_velocity_rad_s, period_s);
        self.approver.waypoints = way;
        if out_m < min_m + TOO_CLOSE_EXTRA_M {
            return false;
        }
        let Ok(plan) = self
            .approver
            .checked_samples(&from, &samples, policy_id, &scene)
        else {
            return false;
        };
        if retreat_gets_closer(self.approver.shield_mut(), &from, &plan.q_rad, &scene).is_some() {
            return false;
        }
        let (plan_id, n) = (plan.id, plan.len());
        if !self.send_plan(plan, scene) {
            return false;
        }
        self.excursion.next(Transition::BackOutSent { plan_id });
        self.planning.taken();
        self.retreat.refused_at = None;
        events.push(TwinEvent::BackingOut {
            plan_id,
            samples: n,
            clearance_m: out_m,
        });
        true
    }
}

/// A retreat's speed: this fraction of each joint's velocity limit at most.
pub const RETREAT_SPEED_FRACTION: f64 = 0.25;

/// A retreat reaches its speed (and stops from it) over this long, s.
pub const RETREAT_RAMP_S: f64 = 0.2;

/// Re-times the path `from` → `way` (dense: the recorded cycle-rate samples) from rest to rest
/// at the cycle's period: along the path (linear between its samples, so the arm takes the
/// very poses it came by) at most [`RETREAT_SPEED_FRACTION`] of each joint's limit, ramping up
/// and down over [`RETREAT_RAMP_S`]. Samples `(q, dq, ddq)`; the last is the path's end, at
/// rest.
pub fn retime(
    from: &Joints,
    way: &[Joints],
    max_velocity_rad_s: &Joints,
    period_s: f64,
) -> Vec<(Joints, Joints, Joints)> {
    let mut pts = Vec::with_capacity(way.len() + 1);
    pts.push(*from);
    pts.extend_from_slice(way);
    let n = pts.len() - 1;
    let mut out = Vec::new();
    if n == 0 || period_s <= 0.0 {
        return out;
    }
    // Index units per second at which no joint exceeds its share of the limit.
    let worst = pts
        .windows(2)
        .map(|w| {
            (0..twin::DOF)
                .map(|j| (w[1][j] - w[0][j]).abs() / max_velocity_rad_s[j].max(1e-9))
                .fold(0.0, f64::max)
        })
        .fold(1e-12, f64::max);
    let top = RETREAT_SPEED_FRACTION / worst;
    let accel = top / RETREAT_RAMP_S;
    let at = |u: f64| {
        let i = (u.floor() as usize).min(n - 1);
        let t = u - i as f64;
        let mut q = pts[i];
        for j in 0..twin::DOF {
            q[j] += (pts[i + 1][j] - pts[i][j]) * t;
        }
        q
    };
    let (mut u, mut rate) = (0.0_f64, 0.0_f64);
    let (mut prev_q, mut prev_dq) = (*from, [0.0; twin::DOF]);
    let last = n as f64;
    while u < last {
        let braking = (2.0 * accel * (last - u)).sqrt();
        rate = (rate + accel * period_s)
            .min(top)
            .min(braking)
            .max(accel * period_s);
        u = (u + rate * period_s).min(last);
        let q = if u >= last { pts[n] } else { at(u) };
        let dq: Joints = std::array::from_fn(|j| (q[j] - prev_q[j]) / period_s);
        let ddq: Joints = std::array::from_fn(|j| (dq[j] - prev_dq[j]) / period_s);
        out.push((q, dq, ddq));
        (prev_q, prev_dq) = (q, dq);
    }
    // Come to rest at the end.
    let ddq: Joints = std::array::from_fn(|j| -prev_dq[j] / period_s);
    out.push((pts[n], [0.0; twin::DOF], ddq));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RuntimeConfig;
    use crate::cycle::shield::ShieldLimits;
    use crate::cycle::shield::tests::{HOME, box_beyond_tcp};
    use crate::testing::toy::ToyArm;

    /// The retreat rule: a path along which the arm only moves away from the box passes; one
    /// that turns back toward it is caught at the first sample that comes closer.
    #[test]
    fn the_retreat_rule_refuses_the_first_sample_that_comes_closer_to_a_box() {
        let cfg = RuntimeConfig::xarm5_default();
        let mut shield = Shield::new(ToyArm, ShieldLimits::from_config(&cfg.limits, &cfg.shield));
        let scene = box_beyond_tcp(0.005);
        // The base turning takes the TCP sideways, away from the box beyond it.
        let out: Vec<Joints> = (1..=20)
            .map(|k| {
                let mut q = HOME;
                q[0] += 0.01 * f64::from(k);
                q
            })
            .collect();
        assert_eq!(retreat_gets_closer(&mut shield, &HOME, &out, &scene), None);
        let mut back_in = out.clone();
        back_in.extend(out.iter().rev().skip(1).take(3).copied());
        assert_eq!(
            retreat_gets_closer(&mut shield, &HOME, &back_in, &scene),
            Some(out.len()),
            "the first sample back toward the box"
        );
        // Re-timed from rest to rest, through the same poses, within a quarter of the limits.
        let limits = *shield.limits();
        let samples = retime(&HOME, &out, &limits.max_velocity_rad_s, 0.004);
        assert_eq!(samples.last().map(|s| s.0), out.last().copied());
        assert!(samples.iter().all(|(_, dq, _)| {
            (0..5).all(|j| {
                dq[j].abs() <= limits.max_velocity_rad_s[j] * RETREAT_SPEED_FRACTION * 1.01
            })
        }));
        let qs: Vec<Joints> = samples.iter().map(|s| s.0).collect();
        assert_eq!(retreat_gets_closer(&mut shield, &HOME, &qs, &scene), None);
        // Staying put is not coming closer.
        assert_eq!(
            retreat_gets_closer(&mut shield, &HOME, &[HOME, HOME], &scene),
            None
        );
    }
}
