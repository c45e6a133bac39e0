//! One dynamic episode: a still world rehearsed without the intruder (the arm must reach its
//! goal, else another world is drawn), the intruder placed on the rehearsal's path, then the
//! same episode with it — the production intake, worker and cycle stepped on the manual
//! clock, 60 Hz frames with the intruder as a tracker reports it, every pose of the arm
//! checked against the intruder's *true* box at that time.

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::detection::UNKNOWN_VELOCITY_SIGMA_M_S;
use shm_schemas::{DetectedObject, DetectionFrame, ObjectClass};
use twin::{Joints, ObstacleClass, Scene, TwinEnv};

use rt_core::cycle::brake::PathStop;
use rt_core::cycle::{CycleEvent, Mode};
use rt_core::rt::clock::Clock;
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::intake::FrameRefusal;

use super::DynamicSettings;
use super::intruder::{ArmMotion, Intruder, IntruderDraw};
use super::kinds::{GROWN_SEED_SALT, KindChoice, choose};
use super::report::{Contact, DynamicEpisodeReport, Onset, Reaction};
use crate::oracle::{CommandLimits, NominalCapsule, OracleBox, Point, segment_box_distance_m};
use crate::sweep::{
    HardCounts, HardFailure, ORIGIN_NS, PolicyKind, Rig, SweepAssets, episode_rng, f32x3,
    make_policy, max_gap, stop_reason_name,
};

/// Velocity sigma a tracker gives a still object (a least-squares fit through 1 mm position
/// noise over 8 frames at 60 Hz: about 0.01 m/s), m/s.
pub const STILL_SIGMA_M_S: f32 = 0.01;

/// Frames a newly seen object is reported with zero velocity and
/// [`UNKNOWN_VELOCITY_SIGMA_M_S`] (as perception's tracker does).
pub const UNKNOWN_VELOCITY_FRAMES: u32 = 2;

/// Object id of the intruder in the frames.
const INTRUDER_ID: u32 = 50;

/// Longest rehearsal, s: a world whose rehearsal does not reach the goal by then is drawn
/// again.
const MAX_REHEARSAL_S: f64 = 12.0;

/// The intruder is *near* the path when its true box comes
/// this close (nominal clearance) to a pose the arm would still take, m: the twin's padding
/// plus the shield's `min_distance_m` (the runtime must react to such a frame).
fn near_m(assets: &SweepAssets) -> f64 {
    crate::oracle::TWIN_PADDING_M + assets.cfg.shield.min_distance_m
}

/// A standing intruder this much farther from the remaining path than [`near_m`] is out of
/// the way, m.
const OUT_OF_THE_WAY_EXTRA_M: f64 = 0.03;

/// Extra time an unavoidable intrusion's window lasts beyond reaction plus stop, s (two
/// periods at 250 Hz: the stop begins on a period boundary and ends on one).
const WINDOW_SLACK_S: f64 = 0.008;

/// The still world of an episode.
#[derive(Debug, Clone)]
struct StillWorld {
    policy: PolicyKind,
    goal_center: [f32; 3],
    goal_size: f32,
    /// (centre, size) of each box.
    boxes: Vec<([f32; 3], [f32; 3])>,
}

impl StillWorld {
    fn draw(rng: &mut ChaCha8Rng, assets: &SweepAssets) -> Self {
        let policy = if assets.bundled.is_some() && rng.random_bool(0.5) {
            PolicyKind::Bundled
        } else {
            PolicyKind::GoalSeeking
        };
        let env = TwinEnv::new(assets.model.clone(), assets.task);
        let kind = rng.random_range(0..3u8);
        let sampled = env.sample_scene(
            rng,
            if kind == 1 {
                ObstacleClass::Large
            } else {
                ObstacleClass::Small
            },
        );
        let boxes = if kind == 2 {
            Vec::new()
        } else {
            sampled
                .obstacles
                .iter()
                .map(|b| (f32x3(b.center_m), f32x3(b.size_m)))
                .collect()
        };
        Self {
            policy,
            goal_center: f32x3(sampled.goal.center_m),
            goal_size: sampled.goal.size_m as f32,
            boxes,
        }
    }
}

/// The arm's capsules at one pose, in the base frame: `(capsule, a, b)`.
type Capsules = Vec<(NominalCapsule, Point, Point)>;

/// What the rehearsal (the episode without the intruder) recorded.
struct Rehearsal {
    /// The command sent in each cycle.
    sent: Vec<Option<Joints>>,
    /// The arm's pose after each cycle.
    pose: Vec<Joints>,
    start_cycle: Option<u64>,
    reach_cycle: Option<u64>,
    /// The arm's capsules every other cycle from the start of motion to the goal.
    path: Vec<(u64, Capsules)>,
    /// Stops the cycle began.
    stops: u64,
}

impl Rehearsal {
    /// The smallest nominal clearance of `bx` to the poses the rehearsal's arm took from
    /// `from_cycle` on to the goal (at least the pose at the goal), stopping early below
    /// `enough_m`.
    fn clearance_from(&self, from_cycle: u64, bx: &OracleBox, enough_m: f64) -> f64 {
        let mut best = f64::INFINITY;
        // From `from_cycle` to the goal; at least the pose at the goal (the arm rests there).
        let first = self
            .path
            .iter()
            .position(|(c, _)| *c >= from_cycle)
            .unwrap_or(self.path.len().saturating_sub(1));
        for (_, caps) in &self.path[first..] {
            for (cap, a, b) in caps {
                best = best.min(segment_box_distance_m(a, b, bx) - cap.radius_m);
            }
            if best < enough_m {
                break;
            }
        }
        best
    }
}

/// Per-contact-pose record, classified at the end of the run.
#[derive(Debug, Clone, Copy)]
struct ContactPose {
    t_s: f64,
    moving: bool,
    depth_m: f64,
    run: u32,
}

/// The checks of a run with the intruder.
struct Checks<'r> {
    intruder: Intruder,
    rehearsal: &'r Rehearsal,
    limits: CommandLimits,
    static_boxes: Vec<OracleBox>,
    prev_q: Joints,
    prev_tcp: Point,
    prev_caps: Capsules,
    hard: HardCounts,
    failures: Vec<HardFailure>,
    contact_poses: Vec<ContactPose>,
    run: u32,
    in_contact: bool,
    /// (t, separation, moving) of the poses within 0.2 m of the intruder.
    close: Vec<(f64, f64, bool)>,
    min_separation_m: f64,
    onsets_due: Vec<(f64, &'static str)>,
    onsets: Vec<Onset>,
    near: Option<(f64, u64)>,
    first_frame_cycle: Option<u64>,
    changed_cycle: Option<u64>,
    comparing: bool,
    commands: u64,
}

/// One run (rehearsal or with the intruder) on the production rig.
struct Run<'a> {
    assets: &'a SweepAssets,
    settings: &'a DynamicSettings,
    index: u64,
    world: &'a StillWorld,
    rig: Rig,
    period_ns: u64,
    period_s: f64,
    events: Vec<TwinEvent<Scene>>,
    counts: BTreeMap<String, u64>,
    frame_k: u64,
    last_delivery_ns: u64,
    pending: Option<(u64, u64)>,
    sequence: u64,
    latency_rng: ChaCha8Rng,
    noise_rng: ChaCha8Rng,
    intruder_frames: u32,
    /// The intruder's reported centre while it stands still (a tracker's debounce).
    held_center: Option<Point>,
    sent: Vec<Option<Joints>>,
    pose: Vec<Joints>,
    sent_seen: usize,
    start_cycle: Option<u64>,
    reach_cycle: Option<u64>,
    /// The cycle in which rt-core first said the goal taken.
    goal_taken_cycle: Option<u64>,
    goal_target: Point,
    /// Stops the cycle began.
    stops: u64,
}

/// The goal's target point: the TCP's, above the goal cube, m.
fn goal_target(assets: &SweepAssets, world: &StillWorld) -> Point {
    let gc = world.goal_center.map(f64::from);
    [
        gc[0],
        gc[1],
        gc[2] + f64::from(world.goal_size) / 2.0 + assets.task.success.goal_hover_m,
    ]
}

fn bump(counts: &mut BTreeMap<String, u64>, key: &str) {
    *counts.entry(key.to_owned()).or_insert(0) += 1;
}

/// A standard normal draw (Box–Muller).
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

impl<'a> Run<'a> {
    fn new(
        assets: &'a SweepAssets,
        settings: &'a DynamicSettings,
        index: u64,
        world: &'a StillWorld,
        seeds: (u64, u64),
    ) -> Self {
        let cfg = &assets.cfg;
        let mut rig = Rig::new(assets, false, settings.planner_fallback);
        let (policy, _) = make_policy(assets, world.policy, 1 + index * 8, index);
        if let Some(p) = policy {
            rig.worker.on_policy(p, &mut Vec::new());
        }
        Self {
            assets,
            settings,
            index,
            world,
            rig,
            period_ns: cfg.period_ns(),
            period_s: 1.0 / cfg.rate_hz,
            events: Vec::new(),
            counts: BTreeMap::new(),
            frame_k: 0,
            last_delivery_ns: 0,
            pending: None,
            sequence: 0,
            latency_rng: ChaCha8Rng::seed_from_u64(seeds.0),
            noise_rng: ChaCha8Rng::seed_from_u64(seeds.1),
            intruder_frames: 0,
            held_center: None,
            sent: Vec::new(),
            pose: Vec::new(),
            sent_seen: 0,
            start_cycle: None,
            reach_cycle: None,
            goal_taken_cycle: None,
            goal_target: goal_target(assets, world),
            stops: 0,
        }
    }

    /// The next frame's capture and delivery times, ns on the cycle clock.
    fn next_frame(&mut self) -> (u64, u64) {
        if let Some(f) = self.pending {
            return f;
        }
        let s = self.settings;
        let capture = (self.frame_k as f64 * 1e9 / s.frame_rate_hz).round() as u64;
        let latency_s = s.latency_min_s + self.latency_rng.random::<f64>() * s.latency_span_s();
        let delivery = (capture + (latency_s * 1e9) as u64).max(self.last_delivery_ns);
        self.pending = Some((capture, delivery));
        (capture, delivery)
    }

    /// Builds the frame captured at `capture_ns` and hands it through the intake at
    /// `now_ns`; returns whether it carried the intruder.
    fn deliver(&mut self, capture_ns: u64, now_ns: u64, intruder: Option<&Intruder>) -> bool {
        let t_s = capture_ns as f64 * 1e-9;
        self.sequence += 1;
        let mut frame = DetectionFrame {
            sequence: self.sequence,
            capture_time_ns: ORIGIN_NS + capture_ns,
            camera_id: 1,
            ..DetectionFrame::default()
        };
        frame.push(
            DetectedObject::new(
                1,
                ObjectClass::Goal,
                0.9,
                self.world.goal_center,
                [self.world.goal_size; 3],
            )
            .with_velocity([0.0; 3], STILL_SIGMA_M_S),
        );
        for (i, (c, s)) in self.world.boxes.iter().enumerate() {
            frame.push(
                DetectedObject::new(10 + i as u32, ObjectClass::Obstacle, 0.9, *c, *s)
                    .with_velocity([0.0; 3], STILL_SIGMA_M_S),
            );
        }
        let mut settled = true;
        let mut carried = false;
        if let Some(i) = intruder.filter(|_| !self.settings.blind_to_intruder) {
            settled = i.settled_at(t_s, self.settings.settle_quiet_s);
            if i.present_at(t_s) {
                carried = true;
                let c = i.spec.center_at(t_s);
                let still = i.speed_at(t_s) == 0.0;
                let sp = self.settings.position_noise_m;
                let mut measure =
                    || -> Point { std::array::from_fn(|k| c[k] + sp * gauss(&mut self.noise_rng)) };
                // A tracker keeps a still object's reported box until a measurement leaves
                // its noise tolerance: the first measurement at rest is held.
                let center = if still {
                    *self.held_center.get_or_insert_with(&mut measure)
                } else {
                    self.held_center = None;
                    measure()
                };
                let (velocity, sigma) = if self.intruder_frames < UNKNOWN_VELOCITY_FRAMES {
                    ([0.0f32; 3], UNKNOWN_VELOCITY_SIGMA_M_S)
                } else {
                    let v = i.velocity_at(t_s);
                    let sv = if still {
                        f64::from(STILL_SIGMA_M_S)
                    } else {
                        self.settings.velocity_noise_m_s
                    };
                    let noisy: Point =
                        std::array::from_fn(|k| v[k] + sv * gauss(&mut self.noise_rng));
                    (f32x3(noisy), sv as f32)
                };
                frame.push(
                    DetectedObject::new(
                        INTRUDER_ID,
                        ObjectClass::Obstacle,
                        0.9,
                        f32x3(center),
                        f32x3(i.spec.size_m),
                    )
                    .with_velocity(velocity, sigma),
                );
                self.intruder_frames += 1;
            }
        }
        frame.set_settled(settled);
        bump(&mut self.counts, "frames_delivered");
        if !settled {
            bump(&mut self.counts, "frames_unsettled");
        }
        let rig = &mut self.rig;
        match rig.intake.deliver(
            &frame,
            ORIGIN_NS + now_ns,
            1,
            &mut rig.worker,
            &mut self.events,
        ) {
            Ok(_) => bump(&mut self.counts, "frames_accepted"),
            Err(r) => bump(
                &mut self.counts,
                &format!("frames_refused_{}", FrameRefusal::NAMES[r.index()]),
            ),
        }
        carried
    }

    fn count_events(&mut self) {
        for e in self.events.drain(..) {
            let key = match e {
                TwinEvent::Verdict { verdict, .. } => {
                    if verdict.task_ok && verdict.safe {
                        "twin_verdicts_passed"
                    } else {
                        "twin_verdicts_failed"
                    }
                }
                TwinEvent::PlanApproved { .. } => "twin_plans_approved",
                TwinEvent::PlanRejected { .. } => "twin_plans_rejected",
                TwinEvent::Revoked { .. } => "twin_plans_revoked",
                TwinEvent::StopScheduled { .. } => "twin_stops_scheduled",
                TwinEvent::Retrain { .. } => "twin_retrain_requests",
                TwinEvent::ReturningHome { .. } => "twin_returns_home",
                TwinEvent::ReturnHomeRefused { .. } => "twin_returns_home_refused",
                TwinEvent::PolicySwapped { .. } => "twin_policy_swaps",
                TwinEvent::NoGoal { .. } => "twin_no_goal",
                TwinEvent::AwaitingSettledScene { .. } => "twin_awaiting_settled_scene",
                TwinEvent::RetrainingRefused { .. } => "twin_retrainings_refused",
                TwinEvent::NotLearned { .. } => "twin_not_learned",
                TwinEvent::GoalTaken { .. } => "twin_goal_taken",
                TwinEvent::BackingOut { .. } => "twin_backing_out",
            };
            bump(&mut self.counts, key);
        }
        let counts = &mut self.counts;
        let stops = &mut self.stops;
        self.rig.log.drain(|r| {
            let key = match r.event {
                CycleEvent::StopBegun { reason } => {
                    *stops += 1;
                    bump(counts, &format!("cycle_stops_{}", stop_reason_name(reason)));
                    return;
                }
                CycleEvent::PlanAdopted { .. } => "cycle_plans_adopted",
                CycleEvent::PlanRefused { .. } => "cycle_plans_refused",
                CycleEvent::PlanRevoked { .. } => "cycle_plans_revoked",
                CycleEvent::StopDue { .. } => "cycle_stops_due",
                CycleEvent::JoinedBeforeStop { .. } => "cycle_joins_before_stop",
                CycleEvent::CommandRefused { .. } => "cycle_commands_refused",
                _ => return,
            };
            bump(counts, key);
        });
    }

    /// Runs one cycle at `c`: frames due, the worker, the cycle; records the command and the
    /// pose; returns the mode and the frames delivered (capture time, ns; whether it
    /// carried the intruder).
    fn step(&mut self, c: u64, intruder: Option<&Intruder>) -> (Mode, Vec<(u64, bool)>) {
        let now = self.rig.clock.now_ns();
        let mut delivered = Vec::new();
        loop {
            let (capture, delivery) = self.next_frame();
            if delivery > now {
                break;
            }
            self.pending = None;
            self.frame_k += 1;
            self.last_delivery_ns = delivery;
            let carried = self.deliver(capture, now, intruder);
            delivered.push((capture, carried));
        }
        self.rig.worker.step(&mut self.events);
        let mode = self.rig.cycle.process(now);
        if self.goal_taken_cycle.is_none()
            && self
                .events
                .iter()
                .any(|e| matches!(e, TwinEvent::GoalTaken { .. }))
        {
            self.goal_taken_cycle = Some(c);
        }
        self.count_events();
        let sent = &self.rig.cycle.link().sent;
        let new = (sent.len() > self.sent_seen).then(|| sent[sent.len() - 1].1);
        self.sent_seen = sent.len();
        let prev = self
            .pose
            .last()
            .copied()
            .unwrap_or(self.assets.task.start.joints_rad);
        let pose = new.unwrap_or(prev);
        self.sent.push(new);
        self.pose.push(pose);
        if mode == Mode::Following && self.start_cycle.is_none() {
            self.start_cycle = Some(c);
        }
        if self.reach_cycle.is_none()
            && max_gap(&self.assets.oracle().tcp_m(&pose), &self.goal_target)
                <= self.assets.task.success.tolerance_m + 0.01
        {
            self.reach_cycle = Some(c);
        }
        (mode, delivered)
    }

    fn rehearse(mut self) -> Rehearsal {
        let max = (MAX_REHEARSAL_S / self.period_s).round() as u64;
        let mut c = 0;
        while c < max {
            self.step(c, None);
            c += 1;
            self.rig.clock.advance_ns(self.period_ns);
            if self.reach_cycle.is_some_and(|r| c > r + 50) {
                break;
            }
        }
        let oracle = self.assets.oracle();
        let mut path = Vec::new();
        if let (Some(s), Some(r)) = (self.start_cycle, self.reach_cycle) {
            let mut k = s.saturating_sub(1);
            while k < r {
                path.push((k, oracle.world_capsules(&self.pose[k as usize])));
                k += 2;
            }
            path.push((r, oracle.world_capsules(&self.pose[r as usize])));
        }
        Rehearsal {
            sent: self.sent,
            pose: self.pose,
            start_cycle: self.start_cycle,
            reach_cycle: self.reach_cycle,
            path,
            stops: self.stops,
        }
    }

    /// The run with the intruder, checked; fills `report`.
    fn with_intruder(
        mut self,
        intruder: &Intruder,
        rehearsal: &Rehearsal,
        report: &mut DynamicEpisodeReport,
    ) {
        let cfg = &self.assets.cfg;
        let table = self.assets.task.sampling.table_height_m;
        let start = self.assets.task.start.joints_rad;
        let oracle = self.assets.oracle();
        let mut ck = Checks {
            intruder: *intruder,
            rehearsal,
            limits: CommandLimits {
                joint_min_rad: cfg.limits.joint_min_rad,
                joint_max_rad: cfg.limits.joint_max_rad,
                max_velocity_rad_s: cfg.limits.max_velocity_rad_s,
                max_tcp_speed_m_s: cfg.limits.max_tcp_speed_m_s,
                period_s: self.period_s,
            },
            static_boxes: self
                .world
                .boxes
                .iter()
                .map(|(c, s)| OracleBox::new(c.map(f64::from), s.map(f64::from)))
                .collect(),
            prev_q: start,
            prev_tcp: oracle.tcp_m(&start),
            prev_caps: oracle.world_capsules(&start),
            hard: HardCounts::default(),
            failures: Vec::new(),
            contact_poses: Vec::new(),
            run: 0,
            in_contact: false,
            close: Vec::new(),
            min_separation_m: f64::INFINITY,
            onsets_due: intruder.onsets_s().collect(),
            onsets: Vec::new(),
            near: None,
            first_frame_cycle: None,
            changed_cycle: None,
            comparing: true,
            commands: 0,
        };
        let max = (self.settings.max_episode_s / self.period_s).round() as u64;
        let final_s = intruder.last_change_s();
        let mut c = 0;
        while c < max {
            let (_, delivered) = self.step(c, Some(intruder));
            for (capture, carried) in delivered {
                self.on_frame(&mut ck, capture, carried, c);
            }
            self.check_cycle(&mut ck, c, table);
            c += 1;
            self.rig.clock.advance_ns(self.period_ns);
            let t = c as f64 * self.period_s;
            let reached = self.reach_cycle.map(|r| r as f64 * self.period_s);
            if t >= final_s + self.settings.reach_limit_s
                || (t >= final_s + 1.0 && reached.is_some_and(|r| t >= r + 0.3))
            {
                break;
            }
        }
        let r = *self.rig.cycle.report();
        if r.envelope_breaches > 0 {
            *self
                .counts
                .entry("cycle_envelope_breaches".into())
                .or_insert(0) += r.envelope_breaches;
        }
        report.cycles = c;
        let p = self.period_s;
        report.start_s = self.start_cycle.map(|c| c as f64 * p);
        report.rehearsal_start_s = rehearsal.start_cycle.map(|c| c as f64 * p);
        report.stops = self.stops;
        report.rehearsal_stops = rehearsal.stops;
        self.finish(ck, rehearsal, report);
    }

    /// A frame captured at `capture_ns` was delivered in cycle `c`: the onsets it is the
    /// first to show (had perception seen the intruder), and whether it carried the intruder
    /// near the path first.
    fn on_frame(&mut self, ck: &mut Checks<'_>, capture_ns: u64, carried: bool, c: u64) {
        let t_cap = capture_ns as f64 * 1e-9;
        if !ck.intruder.present_at(t_cap) {
            return;
        }
        let bx = ck.intruder.box_at(t_cap);
        if carried {
            ck.first_frame_cycle.get_or_insert(c);
        }
        if carried && ck.near.is_none() {
            let clear = ck.rehearsal.clearance_from(c, &bx, near_m(self.assets));
            if clear < near_m(self.assets) {
                ck.near = Some((t_cap, c));
            }
        }
        while let Some(&(at_s, what)) = ck.onsets_due.first() {
            if at_s > t_cap {
                break;
            }
            ck.onsets_due.remove(0);
            let onset = self.judge_onset(ck, what, at_s, t_cap, c);
            ck.onsets.push(onset);
        }
    }

    /// Is the intruder, as it stands at `t_cap`, closer to the arm than the arm can stop?
    fn judge_onset(
        &self,
        ck: &Checks<'_>,
        what: &'static str,
        at_s: f64,
        t_cap: f64,
        delivered_cycle: u64,
    ) -> Onset {
        let oracle = self.assets.oracle();
        let p = self.period_s;
        let k = ((t_cap / p).floor() as usize).min(self.pose.len().saturating_sub(1));
        let q = self.pose.get(k).copied().unwrap_or(ck.prev_q);
        let q_prev = if k > 0 { self.pose[k - 1] } else { q };
        let caps = oracle.world_capsules(&q);
        let caps_prev = oracle.world_capsules(&q_prev);
        let mut arm_speed = 0.0f64;
        for ((_, a, b), (_, a0, b0)) in caps.iter().zip(&caps_prev) {
            arm_speed = arm_speed.max(max_gap(a, a0) / p).max(max_gap(b, b0) / p);
        }
        let dq: Joints = std::array::from_fn(|j| (q[j] - q_prev[j]) / p);
        let arm_stop_s =
            PathStop::duration_s(&dq, &self.assets.cfg.limits.max_acceleration_rad_s2, p);
        let reaction_s = delivered_cycle as f64 * p - t_cap + p;
        let bx = ck.intruder.box_at(t_cap);
        let distance_m = caps
            .iter()
            .map(|(cap, a, b)| segment_box_distance_m(a, b, &bx) - cap.radius_m)
            .fold(f64::INFINITY, f64::min);
        let v_h = ck.intruder.speed_at(t_cap);
        let arm_m = arm_speed * (reaction_s + arm_stop_s / 2.0);
        let stopping_distance_m = arm_m + v_h * (reaction_s + arm_stop_s);
        Onset {
            what,
            at_s,
            capture_s: t_cap,
            distance_m,
            arm_speed_m_s: arm_speed,
            intruder_speed_m_s: v_h,
            reaction_s,
            arm_stop_s,
            stopping_distance_m,
            stopping_distance_reaction_only_m: arm_m + v_h * reaction_s,
            unavoidable: distance_m < stopping_distance_m,
            window_end_s: t_cap + reaction_s + arm_stop_s + WINDOW_SLACK_S,
        }
    }

    /// The checks of cycle `c`: the command sent (limits, table, still boxes), the arm's
    /// pose against the intruder's true box, and the command against the rehearsal's.
    fn check_cycle(&mut self, ck: &mut Checks<'_>, c: u64, table: f64) {
        let oracle = self.assets.oracle();
        let t = c as f64 * self.period_s;
        let pose = self.pose[c as usize];
        let caps = oracle.world_capsules(&pose);
        if let Some(q) = self.sent[c as usize] {
            ck.commands += 1;
            let tcp = oracle.tcp_m(&q);
            let m = ck.limits.check(&ck.prev_q, &q, &ck.prev_tcp, &tcp);
            let episode = self.index;
            let mut fail = |kind: &'static str, value: f64, index: Option<usize>| {
                if ck.failures.len() < 5 {
                    ck.failures.push(HardFailure {
                        episode,
                        cycle: c,
                        kind,
                        value,
                        index,
                        known_for_s: None,
                        q_rad: q,
                    });
                }
            };
            if m.non_finite {
                ck.hard.non_finite_commands += 1;
                fail("non_finite", f64::NAN, None);
            } else {
                if let Some(j) = m.joint_limit {
                    ck.hard.joint_limit_violations += 1;
                    fail("joint_limit", q[j], Some(j));
                }
                if let Some((j, step)) = m.joint_step {
                    ck.hard.joint_step_violations += 1;
                    fail("joint_step", step, Some(j));
                }
                if let Some(v) = m.tcp_speed_m_s {
                    ck.hard.tcp_speed_violations += 1;
                    fail("tcp_speed", v, None);
                }
                if let Some(step) = m.tcp_step_m {
                    ck.hard.tcp_step_violations += 1;
                    fail("tcp_step", step, None);
                }
                let mut table_m = f64::INFINITY;
                for (cap, a, b) in &caps {
                    if cap.meets_table() {
                        table_m = table_m.min(a[2].min(b[2]) - table - cap.radius_m);
                    }
                }
                if table_m < 0.0 {
                    ck.hard.table_penetrations += 1;
                    fail("table_penetration", -table_m, None);
                }
                for (i, bx) in ck.static_boxes.iter().enumerate() {
                    let d = caps
                        .iter()
                        .map(|(cap, a, b)| segment_box_distance_m(a, b, bx) - cap.radius_m)
                        .fold(f64::INFINITY, f64::min);
                    if d < 0.0 {
                        ck.hard.box_penetrations += 1;
                        fail("box_penetration", -d, Some(i));
                    }
                }
            }
            ck.prev_q = q;
            ck.prev_tcp = tcp;
        }
        // The arm against the intruder's true box now.
        if ck.intruder.present_at(t) {
            let bx = ck.intruder.box_at(t);
            let mut sep = f64::INFINITY;
            let mut moving = false;
            for ((cap, a, b), (_, a0, b0)) in caps.iter().zip(&ck.prev_caps) {
                let d = segment_box_distance_m(a, b, &bx) - cap.radius_m;
                sep = sep.min(d);
                if d < 0.0 && (max_gap(a, a0) > 1e-9 || max_gap(b, b0) > 1e-9) {
                    moving = true;
                }
            }
            let cap_moving = caps
                .iter()
                .zip(&ck.prev_caps)
                .any(|((_, a, b), (_, a0, b0))| max_gap(a, a0) > 1e-9 || max_gap(b, b0) > 1e-9);
            ck.min_separation_m = ck.min_separation_m.min(sep);
            if sep < 0.2 {
                ck.close.push((t, sep, cap_moving));
            }
            if sep < 0.0 {
                if !ck.in_contact {
                    ck.run += 1;
                }
                ck.in_contact = true;
                ck.contact_poses.push(ContactPose {
                    t_s: t,
                    moving,
                    depth_m: -sep,
                    run: ck.run,
                });
            } else {
                ck.in_contact = false;
            }
        } else {
            ck.in_contact = false;
        }
        ck.prev_caps = caps;
        // The command against the running plan's (the rehearsal's) in the same cycle.
        if ck.comparing && ck.changed_cycle.is_none() {
            match ck.rehearsal.sent.get(c as usize) {
                None => ck.comparing = false,
                Some(r) if *r != self.sent[c as usize] => ck.changed_cycle = Some(c),
                Some(_) => {}
            }
        }
    }

    fn finish(self, ck: Checks<'_>, rehearsal: &Rehearsal, report: &mut DynamicEpisodeReport) {
        let p = self.period_s;
        let in_window = |t: f64| {
            ck.onsets
                .iter()
                .any(|o| o.unavoidable && t >= o.at_s && t <= o.window_end_s)
        };
        let in_narrow_window = |t: f64| {
            ck.onsets.iter().any(|o| {
                o.distance_m < o.stopping_distance_reaction_only_m
                    && t >= o.at_s
                    && t <= o.window_end_s
            })
        };
        let mut run_narrow: BTreeMap<u32, bool> = BTreeMap::new();
        // A contact begun within an unavoidable window stays unavoidable while it lasts.
        let mut run_unavoidable: BTreeMap<u32, bool> = BTreeMap::new();
        let mut deepest: Option<Contact> = None;
        let mut last_run = None;
        for cp in &ck.contact_poses {
            let begun = *run_unavoidable
                .entry(cp.run)
                .or_insert_with(|| in_window(cp.t_s));
            let unavoidable = begun || in_window(cp.t_s);
            let contact = Contact {
                at_s: cp.t_s,
                depth_m: cp.depth_m,
                moving: cp.moving,
                unavoidable,
            };
            let narrow = *run_narrow
                .entry(cp.run)
                .or_insert_with(|| in_narrow_window(cp.t_s))
                || in_narrow_window(cp.t_s);
            if cp.moving && !narrow {
                report.moving_contact_poses_avoidable_reaction_only_rule += 1;
            }
            if cp.moving {
                if unavoidable {
                    report.moving_contact_poses_unavoidable += 1;
                } else {
                    report.moving_contact_poses_avoidable += 1;
                }
                report.max_moving_depth_m = report.max_moving_depth_m.max(cp.depth_m);
            } else {
                report.rest_contact_poses += 1;
            }
            if last_run != Some(cp.run) && report.contacts.len() < 6 {
                report.contacts.push(contact);
            }
            last_run = Some(cp.run);
            if deepest.is_none_or(|d| cp.depth_m > d.depth_m) {
                deepest = Some(contact);
            }
        }
        if let Some(d) = deepest
            && !report.contacts.contains(&d)
        {
            report.contacts.push(d);
        }
        report.min_separation_m = ck.min_separation_m;
        report.min_separation_avoidable_m = ck
            .close
            .iter()
            .filter(|(t, _, moving)| *moving && !in_window(*t))
            .map(|(_, s, _)| *s)
            .fold(f64::INFINITY, f64::min);
        report.reaction = ck.near.map(|(near_capture_s, near_delivery_cycle)| {
            let changed = ck.changed_cycle;
            Reaction {
                near_capture_s,
                near_delivery_cycle,
                changed_cycle: changed,
                from_capture_s: changed.map(|c| c as f64 * p - near_capture_s),
                from_delivery_cycles: changed.map(|c| c as i64 - near_delivery_cycle as i64),
            }
        });
        report.first_intruder_frame_cycle = ck.first_frame_cycle;
        report.changed_cycle = ck.changed_cycle;
        report.reach_s = self.reach_cycle.map(|r| r as f64 * p);
        report.rehearsal_reach_s = rehearsal.reach_cycle.map(|r| r as f64 * p);
        let i = &ck.intruder;
        report.cleared_s = match (i.vanish_s, i.stop_s) {
            (Some(v), _) => Some(v),
            (None, Some(stop)) => {
                let from = (i.appear_s / p) as u64;
                let bx = i.box_at(stop);
                let enough = near_m(self.assets) + OUT_OF_THE_WAY_EXTRA_M;
                (rehearsal.clearance_from(from, &bx, enough) >= enough).then_some(stop)
            }
            (None, None) => None,
        };
        report.commands = ck.commands;
        report.hard = ck.hard;
        report.failures = ck.failures;
        report.onsets = ck.onsets;
        report.infeasible_reported = self.counts.contains_key("twin_goal_taken");
        report.infeasible_report_delay_s = self
            .goal_taken_cycle
            .zip(i.stop_s)
            .map(|(c, stop)| c as f64 * p - stop);
        report.counts = self.counts;
    }
}

/// Episode `index`'s intruder, and the generator its world is drawn from next: a classic
/// kind from the classic stream (as before issue 42), a grown one from its own.
fn draw_intruder(settings: &DynamicSettings, index: u64) -> (ChaCha8Rng, IntruderDraw) {
    let speeds = (settings.min_speed_m_s, settings.max_speed_m_s);
    match choose(settings.kinds, settings.seed, index) {
        KindChoice::Classic(kind) => {
            let mut rng = episode_rng(settings.seed ^ super::DYNAMIC_SEED_SALT, index);
            let mut draw = IntruderDraw::draw(&mut rng, speeds);
            if let Some(k) = kind {
                draw.kind = k;
            }
            (rng, draw)
        }
        KindChoice::Grown(kind) => {
            let mut rng = episode_rng(settings.seed ^ GROWN_SEED_SALT, index);
            let draw = IntruderDraw::draw_grown(&mut rng, kind, speeds);
            (rng, draw)
        }
    }
}

/// Runs dynamic episode `index` (deterministic in `settings.seed` and `index`).
pub fn run_dynamic_episode(
    assets: &SweepAssets,
    settings: &DynamicSettings,
    index: u64,
) -> DynamicEpisodeReport {
    let (mut rng, draw) = draw_intruder(settings, index);
    let seeds = (rng.random::<u64>(), rng.random::<u64>());
    let mut report = DynamicEpisodeReport::new(index, draw.kind, draw.speed_m_s, draw.size_m);
    let cal = &assets.cfg.intake;
    let calibrated = (cal.calibrated_min_m, cal.calibrated_max_m);
    let table = assets.task.sampling.table_height_m;
    for attempt in 1..=settings.world_attempts {
        let world = StillWorld::draw(&mut rng, assets);
        let rehearsal = Run::new(assets, settings, index, &world, seeds).rehearse();
        let (Some(start_cycle), Some(reach_cycle)) = (rehearsal.start_cycle, rehearsal.reach_cycle)
        else {
            continue;
        };
        let goal_size = f64::from(world.goal_size);
        let goal_center = world.goal_center.map(f64::from);
        let motion = ArmMotion {
            pose: &rehearsal.pose,
            start_cycle,
            reach_cycle,
            period_s: 1.0 / assets.cfg.rate_hz,
            goal_cube: OracleBox::new(goal_center, [goal_size; 3]),
            goal_target_m: goal_target(assets, &world),
        };
        let Some((intruder, clear)) =
            Intruder::place(&draw, assets.oracle(), &motion, calibrated, table)
        else {
            continue;
        };
        report.world_attempts = attempt;
        report.policy = world.policy;
        report.intruder = Some(intruder);
        report.size_m = intruder.spec.size_m;
        Run::new(assets, settings, index, &world, seeds).with_intruder(
            &intruder,
            &rehearsal,
            &mut report,
        );
        if !clear {
            bump(&mut report.counts, "intruders_appearing_on_the_arm");
        }
        return report;
    }
    report
}
