//! The sweep itself: the assets and settings of a run, one episode (world, policy, twists,
//! the worker and the cycle stepped together, every command checked by the [`oracle`]),
//! the tally and its summary, and [`run_sweep`] over worker threads. What an episode is and
//! what it counts: the crate's documentation.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use policy::{MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use shm_schemas::{
    ACT_DIM, DetectedObject, DetectionFrame, OBS_DIM, ObjectClass, PolicyBlob, PolicyBlobBuilder,
};
use twin::{DOF, Joints, ObstacleClass, RobotModel, Scene, TaskConfig, TwinEnv};

use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::{Brake, PathStop};
use rt_core::cycle::link::{InProcessArm, LinkError, LinkState, RobotLink};
use rt_core::cycle::plan::MotionState;
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::{self, Cycle, CycleConfig, CycleEvent, Mode, StopReason};
use rt_core::rt::clock::{Clock, ManualClock};
use rt_core::rt::rt_log::RtLogDrain;
use rt_core::twin_thread::TwinEvent;
use rt_core::twin_thread::intake::{AcceptedFrame, FrameRefusal, SceneIntake};
use rt_core::twin_thread::lookahead::{LookaheadActions, TwinLookahead};
use rt_core::twin_thread::node::ProductionWorker;
use rt_core::twin_thread::path_planner::TwinPathPlanner;
use rt_core::twin_thread::scene_path::ScenePath;
use rt_core::twin_thread::serve;
use rt_core::twin_thread::worker::PLANNER_POLICY_ID;

use crate::oracle::{
    CommandLimits, DistanceOracle, OracleBox, OracleBuildError, Point, TWIN_PADDING_M,
    segment_box_distance_m,
};

/// `CLOCK_MONOTONIC` at the cycle clock's origin in the sweep, ns (any value well above the
/// largest stamp offset works).
pub(crate) const ORIGIN_NS: u64 = 1_000_000_000_000;

/// How far ahead of the arm a box may be injected, cycles.
pub const MAX_INJECT_AHEAD_CYCLES: u64 = 200;

/// Why the sweep's assets could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum SweepAssetsError {
    /// `runtime.toml`.
    #[error("runtime.toml")]
    Config(#[from] rt_core::config::RuntimeConfigError),
    /// `xarm5.urdf`.
    #[error("xarm5.urdf")]
    Model(#[from] twin::UrdfLoadError),
    /// `task.toml`.
    #[error("task.toml")]
    Task(#[from] twin::TaskConfigError),
    /// The oracle's capsules.
    #[error("oracle")]
    Oracle(#[from] OracleBuildError),
}

/// Why the bundled policy is not used (the sweep substitutes the goal-seeker).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BundledPolicyProblem {
    /// `policy-distilled/policy.blob` could not be read as a blob.
    Unreadable,
    /// The loader refused it (e.g. trained for another task hash).
    Rejected(PolicyRejectReason),
}

/// What an episode is built from: the configuration, the model and the task of the
/// assets folder, and the bundled policy blob.
pub struct SweepAssets {
    /// `runtime.toml`.
    pub cfg: RuntimeConfig,
    /// `xarm5.urdf` (as `rt-core run` loads it).
    pub model: RobotModel,
    /// `task.toml`.
    pub task: TaskConfig,
    /// `policy-distilled/policy.blob`, when it loads and suits the task.
    pub bundled: Option<Box<PolicyBlob>>,
    /// Why not, otherwise.
    pub bundled_problem: Option<BundledPolicyProblem>,
    oracle: DistanceOracle,
}

impl SweepAssets {
    /// Loads `runtime.toml`, `xarm5.urdf`, `task.toml` and `policy-distilled/policy.blob` from an
    /// assets folder.
    ///
    /// # Errors
    /// [`SweepAssetsError`] (a missing or refused bundled policy is not an error: see
    /// [`SweepAssets::bundled_problem`]).
    pub fn load(assets: &Path) -> Result<Self, SweepAssetsError> {
        let cfg = RuntimeConfig::load(&assets.join("runtime.toml"))?;
        let model = RobotModel::load(&assets.join("xarm5.urdf"))?;
        cfg.check_against_model(&model)?;
        let task = TaskConfig::load(&assets.join("task.toml"))?;
        let loader = PolicyLoader::new(PolicyExpectation::for_task(task.hash()));
        let (bundled, bundled_problem) =
            match policy::read_policy_file(&assets.join("policy-distilled/policy.blob")) {
                Err(_) => (None, Some(BundledPolicyProblem::Unreadable)),
                Ok(blob) => match loader.check(&blob) {
                    Ok(()) => (Some(blob), None),
                    Err(r) => (None, Some(BundledPolicyProblem::Rejected(r))),
                },
            };
        // The oracle sees the arm as it is: with the task's tool, if any.
        let armed = model.clone().with_tool(task.tool.map(|t| t.capsule()));
        let oracle = DistanceOracle::new(&armed, TWIN_PADDING_M)?;
        Ok(Self {
            cfg,
            model,
            task,
            bundled,
            bundled_problem,
            oracle,
        })
    }

    /// The oracle over the arm's nominal capsules.
    pub fn oracle(&self) -> &DistanceOracle {
        &self.oracle
    }
}

/// The time the cycle needs to stop from the velocity limit, computed from its own stops.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BrakingHorizon {
    /// The per-joint [`Brake`] from every joint at its velocity limit to rest, s.
    pub brake_s: f64,
    /// The stop along the plan ([`PathStop`]) from the velocity limit, s (whole periods).
    pub path_stop_s: f64,
    /// The longer of the two plus one period (the cycle acts on its next period), s.
    pub horizon_s: f64,
    /// The same in cycles.
    pub horizon_cycles: u64,
    /// The cycle's own look-ahead for comparison (`brake_horizon_samples`: the stop's
    /// travel at full speed, in samples).
    pub cycle_lookahead_samples: usize,
}

impl BrakingHorizon {
    /// For `cfg`'s limits and rate.
    pub fn of(cfg: &RuntimeConfig) -> Self {
        let period_s = 1.0 / cfg.rate_hz;
        let l = &cfg.limits;
        let mut brake = Brake::new(l);
        brake.start(MotionState {
            q_rad: [0.0; DOF],
            dq_rad_s: l.max_velocity_rad_s,
            ddq_rad_s2: [0.0; DOF],
        });
        let mut steps = 0u64;
        while !brake.is_stopped() && steps < 1_000_000 {
            brake.step(period_s);
            steps += 1;
        }
        let brake_s = steps as f64 * period_s;
        let path =
            PathStop::duration_s(&l.max_velocity_rad_s, &l.max_acceleration_rad_s2, period_s);
        let path_stop_s = (path / period_s).ceil() * period_s;
        let horizon_s = brake_s.max(path_stop_s) + period_s;
        Self {
            brake_s,
            path_stop_s,
            horizon_s,
            horizon_cycles: (horizon_s / period_s).round() as u64,
            cycle_lookahead_samples: CycleConfig::from_runtime(cfg).brake_horizon_samples,
        }
    }
}

/// The policies an episode may run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum PolicyKind {
    /// `assets/policy-distilled/policy.blob`.
    Bundled,
    /// Random weights (as `bench-loop`).
    RandomWeights,
    /// Drives the TCP straight at the goal target, through whatever is in the way.
    GoalSeeking,
    /// Random weights × 1e6: saturated outputs.
    HugeWeights,
}

impl PolicyKind {
    const ALL: [PolicyKind; 4] = [
        PolicyKind::Bundled,
        PolicyKind::RandomWeights,
        PolicyKind::GoalSeeking,
        PolicyKind::HugeWeights,
    ];

    /// A short name (counters, reports).
    pub fn name(self) -> &'static str {
        match self {
            PolicyKind::Bundled => "bundled",
            PolicyKind::RandomWeights => "random_weights",
            PolicyKind::GoalSeeking => "goal_seeking",
            PolicyKind::HugeWeights => "huge_weights",
        }
    }
}

/// Probabilities of each twist per episode, and the policy mix.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TwistRates {
    /// Weights of `PolicyKind::ALL` (bundled, random, goal-seeking, huge).
    pub policy_weights: [f64; 4],
    /// A box injected ahead of the arm.
    pub inject: f64,
    /// Of the injected boxes, 5 mm cubes.
    pub tiny_box: f64,
    /// The link cut during a stop.
    pub link_cut: f64,
    /// A burst of frames with a bad stamp (zero, future, stale, pre-start).
    pub bad_stamp: f64,
    /// A frame repeating the previous sequence.
    pub sequence_regress: f64,
    /// An object outside the calibrated workspace for a few frames.
    pub outside_workspace: f64,
    /// More obstacles than a frame holds, for a while.
    pub overfull: f64,
    /// No frames for longer than the detection age limit.
    pub dropout: f64,
    /// The goal below the confidence floor for a while.
    pub goal_hidden: f64,
    /// The goal near the base (some inside the intake's minimum radius).
    pub goal_near_base: f64,
    /// A second policy swapped in mid-episode.
    pub policy_swap: f64,
}

impl Default for TwistRates {
    fn default() -> Self {
        Self {
            policy_weights: [0.35, 0.15, 0.35, 0.15],
            inject: 0.5,
            tiny_box: 0.3,
            link_cut: 0.25,
            bad_stamp: 0.3,
            sequence_regress: 0.1,
            outside_workspace: 0.1,
            overfull: 0.1,
            dropout: 0.1,
            goal_hidden: 0.1,
            goal_near_base: 0.1,
            policy_swap: 0.15,
        }
    }
}

/// How the sweep runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SweepSettings {
    /// Seed of the whole sweep (episode `i` draws from a stream of its own).
    pub seed: u64,
    /// Number of episodes.
    pub episodes: u64,
    /// Index of the first episode (to replay one: `first_episode = i, episodes = 1`).
    pub first_episode: u64,
    /// Longest episode, s (cycle clock).
    pub max_episode_s: f64,
    /// Detection frames every this many cycles.
    pub frame_every_cycles: u64,
    /// Largest capture-to-delivery latency of a frame, s.
    pub max_latency_s: f64,
    /// Worker threads.
    pub jobs: usize,
    /// The twists.
    pub rates: TwistRates,
    /// The planner fallback installed in the worker, as `rt-core run --planner-fallback
    /// on` installs it (its search is bounded by wall time, so a sweep with it is not
    /// reproducible to the command under another load; its hard counts must still be 0).
    pub planner_fallback: bool,
}

impl Default for SweepSettings {
    fn default() -> Self {
        Self {
            seed: 1,
            episodes: 100,
            first_episode: 0,
            max_episode_s: 12.0,
            frame_every_cycles: 8,
            max_latency_s: 0.03,
            jobs: 1,
            rates: TwistRates::default(),
            planner_fallback: false,
        }
    }
}

/// A hard failure found by the oracle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HardFailure {
    /// The episode.
    pub episode: u64,
    /// Its cycle (time = cycle / rate).
    pub cycle: u64,
    /// What: `box_penetration`, `table_penetration`, `joint_step`, `tcp_speed`,
    /// `tcp_step`, `joint_limit`, `non_finite`.
    pub kind: &'static str,
    /// The measure: depth (m), step (rad; m for the TCP's), speed (m/s), or the joint.
    pub value: f64,
    /// The box (penetration), or the joint.
    pub index: Option<usize>,
    /// For a box: how long the runtime had known it, s.
    pub known_for_s: Option<f64>,
    /// The command, rad.
    pub q_rad: Joints,
}

/// The hard counts (all must be zero).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct HardCounts {
    /// Poses penetrating a box known for at least one braking horizon.
    pub box_penetrations: u64,
    /// Poses penetrating the table (links 2–5, tool).
    pub table_penetrations: u64,
    /// Joint steps over one period at the velocity limit (+ tolerance).
    pub joint_step_violations: u64,
    /// TCP speeds over the limit.
    pub tcp_speed_violations: u64,
    /// TCP steps over the controller's 5 mm per target
    /// ([`crate::oracle::CONTROLLER_TCP_STEP_M`]).
    pub tcp_step_violations: u64,
    /// Commands outside the joint limits.
    pub joint_limit_violations: u64,
    /// Non-finite commands.
    pub non_finite_commands: u64,
}

impl HardCounts {
    /// The sum.
    pub fn total(&self) -> u64 {
        self.box_penetrations
            + self.table_penetrations
            + self.joint_step_violations
            + self.tcp_speed_violations
            + self.tcp_step_violations
            + self.joint_limit_violations
            + self.non_finite_commands
    }

    pub(crate) fn add(&mut self, o: &Self) {
        self.box_penetrations += o.box_penetrations;
        self.table_penetrations += o.table_penetrations;
        self.joint_step_violations += o.joint_step_violations;
        self.tcp_speed_violations += o.tcp_speed_violations;
        self.tcp_step_violations += o.tcp_step_violations;
        self.joint_limit_violations += o.joint_limit_violations;
        self.non_finite_commands += o.non_finite_commands;
    }
}

/// What became of an injected box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InjectionRecord {
    /// The episode.
    pub episode: u64,
    /// Cycles ahead of the arm it was put on the plan.
    pub ahead_cycles: u64,
    /// Nominal clearance of the arm's pose at the injection to it, m (negative: it
    /// appeared on the arm).
    pub clearance_at_injection_m: f64,
    /// Cycles from the injection until the runtime knew it.
    pub known_after_cycles: Option<u64>,
    /// Cycles from the injection to the first commanded pose inside it.
    pub intruded_after_cycles: Option<u64>,
    /// Deepest penetration, m.
    pub depth_m: f64,
}

/// What one episode did.
#[derive(Debug, Clone, Default)]
pub struct EpisodeReport {
    /// Its index.
    pub episode: u64,
    /// Cycles run.
    pub cycles: u64,
    /// Commands sent (and checked).
    pub commands: u64,
    /// The hard counts.
    pub hard: HardCounts,
    /// The first hard failures (at most a few per episode).
    pub failures: Vec<HardFailure>,
    /// Poses inside a box not yet known for a braking horizon.
    pub unavoidable_poses: u64,
    /// Poses still inside a box known for a braking horizon, no deeper than the command
    /// before (the arm caught in an unavoidable intrusion, held or backing out).
    pub held_inside_poses: u64,
    /// Deepest penetration per intruded box, m.
    pub intrusion_depths_m: Vec<f64>,
    /// Smallest nominal clearance to a box known for a braking horizon, m.
    pub min_known_box_clearance_m: f64,
    /// Smallest nominal clearance to the table, m.
    pub min_table_clearance_m: f64,
    /// Named counters (outcomes, twists, events, frames).
    pub counts: BTreeMap<String, u64>,
    /// The injected boxes.
    pub injections: Vec<InjectionRecord>,
    /// Smallest nominal clearance to a box known for a braking horizon of a command that
    /// moves the arm (not a hold: an arm holding still where a box came to it), m.
    pub min_known_box_clearance_moving_m: f64,
}

impl EpisodeReport {
    fn bump(&mut self, key: &str) {
        self.bump_by(key, 1);
    }

    fn bump_by(&mut self, key: &str, n: u64) {
        if n > 0 {
            *self.counts.entry(key.to_owned()).or_insert(0) += n;
        }
    }
}

/// Unavoidable intrusions: how many and how deep.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IntrusionSummary {
    /// Poses inside a box the runtime had known for less than a braking horizon.
    pub poses: u64,
    /// Poses later still inside such a box, no deeper than the command before (holds).
    pub held_inside_poses: u64,
    /// Boxes so intruded (one event per box).
    pub events: u64,
    /// Depth percentiles over events, m.
    pub depth_p50_m: f64,
    /// 90th percentile, m.
    pub depth_p90_m: f64,
    /// 99th percentile, m.
    pub depth_p99_m: f64,
    /// Deepest, m.
    pub depth_max_m: f64,
    /// Events per depth bin (mm).
    pub depth_histogram_mm: BTreeMap<String, u64>,
}

/// The sweep's figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepSummary {
    /// The settings.
    pub settings: SweepSettings,
    /// Episodes run.
    pub episodes: u64,
    /// Cycles run, all episodes.
    pub cycles: u64,
    /// Commands checked by the oracle.
    pub commands_checked: u64,
    /// The braking horizon used.
    pub braking_horizon: BrakingHorizon,
    /// The hard counts.
    pub hard: HardCounts,
    /// Unavoidable intrusions.
    pub unavoidable: IntrusionSummary,
    /// Smallest nominal clearance to a box known for a braking horizon, m. Since the
    /// backing-out rule (issue 42 item 3) a hold below the shield's clearance is sent (the
    /// arm stays put where a box came to it) and counts here too.
    pub min_known_box_clearance_m: f64,
    /// The same over the commands that move the arm (the holds left out), m.
    pub min_known_box_clearance_moving_m: f64,
    /// Smallest nominal clearance to the table, m.
    pub min_table_clearance_m: f64,
    /// Injected boxes per offset bin (cycles ahead): `[injected, intruded]`.
    pub injections_by_offset: BTreeMap<String, [u64; 2]>,
    /// Named counters summed over the episodes.
    pub counts: BTreeMap<String, u64>,
    /// The injected boxes (the first few thousand), by episode.
    pub injections: Vec<InjectionRecord>,
    /// Why the bundled policy was replaced by the goal-seeker, if it was.
    pub bundled_problem: Option<String>,
    /// The first hard failures.
    pub failures: Vec<HardFailure>,
    /// Wall time, s.
    pub wall_s: f64,
    /// Episodes per second.
    pub episodes_per_s: f64,
}

/// A pose inside a known box deeper than the command before by more than this moves into
/// it (a hard count), m; within it, the arm is held where the box caught it.
const DEEPER_TOLERANCE_M: f64 = 1e-6;

/// Most injection records kept in a summary.
const MAX_INJECTION_RECORDS: usize = 5000;

/// Most failures kept in a summary.
const MAX_FAILURES: usize = 50;

/// Sums episode reports.
#[derive(Debug, Clone)]
pub struct SweepTally {
    settings: SweepSettings,
    horizon: BrakingHorizon,
    episodes: u64,
    cycles: u64,
    commands: u64,
    hard: HardCounts,
    failures: Vec<HardFailure>,
    unavoidable_poses: u64,
    held_inside_poses: u64,
    depths_m: Vec<f64>,
    min_box_m: f64,
    min_box_moving_m: f64,
    min_table_m: f64,
    injections: BTreeMap<String, [u64; 2]>,
    injection_records: Vec<InjectionRecord>,
    counts: BTreeMap<String, u64>,
}

fn offset_bin(k: u64) -> String {
    let lo = (k / 25) * 25;
    format!("{lo:03}-{:03}", lo + 24)
}

impl SweepTally {
    /// An empty tally.
    pub fn new(settings: SweepSettings, horizon: BrakingHorizon) -> Self {
        Self {
            settings,
            horizon,
            episodes: 0,
            cycles: 0,
            commands: 0,
            hard: HardCounts::default(),
            failures: Vec::new(),
            unavoidable_poses: 0,
            held_inside_poses: 0,
            depths_m: Vec::new(),
            min_box_m: f64::INFINITY,
            min_box_moving_m: f64::INFINITY,
            min_table_m: f64::INFINITY,
            injections: BTreeMap::new(),
            injection_records: Vec::new(),
            counts: BTreeMap::new(),
        }
    }

    /// Adds one episode.
    pub fn add(&mut self, r: &EpisodeReport) {
        self.episodes += 1;
        self.cycles += r.cycles;
        self.commands += r.commands;
        self.hard.add(&r.hard);
        for f in &r.failures {
            if self.failures.len() < MAX_FAILURES {
                self.failures.push(*f);
            }
        }
        self.unavoidable_poses += r.unavoidable_poses;
        self.held_inside_poses += r.held_inside_poses;
        self.depths_m.extend_from_slice(&r.intrusion_depths_m);
        self.min_box_m = self.min_box_m.min(r.min_known_box_clearance_m);
        self.min_box_moving_m = self
            .min_box_moving_m
            .min(r.min_known_box_clearance_moving_m);
        self.min_table_m = self.min_table_m.min(r.min_table_clearance_m);
        for i in &r.injections {
            let e = self
                .injections
                .entry(offset_bin(i.ahead_cycles))
                .or_insert([0, 0]);
            e[0] += 1;
            e[1] += u64::from(i.intruded_after_cycles.is_some());
            if self.injection_records.len() < MAX_INJECTION_RECORDS {
                self.injection_records.push(*i);
            }
        }
        for (k, v) in &r.counts {
            *self.counts.entry(k.clone()).or_insert(0) += v;
        }
    }

    /// The hard counts so far.
    pub fn hard(&self) -> &HardCounts {
        &self.hard
    }

    /// Episodes so far.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// A named counter so far.
    pub fn count(&self, key: &str) -> u64 {
        self.counts.get(key).copied().unwrap_or(0)
    }

    /// The summary.
    pub fn summary(&self, bundled: Option<BundledPolicyProblem>, wall_s: f64) -> SweepSummary {
        let mut d = self.depths_m.clone();
        d.sort_by(f64::total_cmp);
        let pct = |q: f64| {
            if d.is_empty() {
                0.0
            } else {
                d[((q * d.len() as f64).ceil() as usize).clamp(1, d.len()) - 1]
            }
        };
        let mut hist = BTreeMap::new();
        for label in ["0-1", "1-2", "2-5", "5-10", "10-20", "20-50", "50+"] {
            hist.insert(label.to_owned(), 0u64);
        }
        for x in &d {
            let mm = x * 1e3;
            let label = match mm {
                m if m < 1.0 => "0-1",
                m if m < 2.0 => "1-2",
                m if m < 5.0 => "2-5",
                m if m < 10.0 => "5-10",
                m if m < 20.0 => "10-20",
                m if m < 50.0 => "20-50",
                _ => "50+",
            };
            *hist.entry(label.to_owned()).or_insert(0) += 1;
        }
        let mut failures = self.failures.clone();
        failures.sort_by_key(|f| (f.episode, f.cycle));
        SweepSummary {
            settings: self.settings,
            episodes: self.episodes,
            cycles: self.cycles,
            commands_checked: self.commands,
            braking_horizon: self.horizon,
            hard: self.hard,
            unavoidable: IntrusionSummary {
                poses: self.unavoidable_poses,
                held_inside_poses: self.held_inside_poses,
                events: d.len() as u64,
                depth_p50_m: pct(0.5),
                depth_p90_m: pct(0.9),
                depth_p99_m: pct(0.99),
                depth_max_m: d.last().copied().unwrap_or(0.0),
                depth_histogram_mm: hist,
            },
            min_known_box_clearance_m: self.min_box_m,
            min_known_box_clearance_moving_m: self.min_box_moving_m,
            min_table_clearance_m: self.min_table_m,
            injections_by_offset: self.injections.clone(),
            counts: self.counts.clone(),
            injections: {
                let mut v = self.injection_records.clone();
                v.sort_by_key(|i| i.episode);
                v
            },
            bundled_problem: bundled.map(|b| format!("{b:?}")),
            failures,
            wall_s,
            episodes_per_s: if wall_s > 0.0 {
                self.episodes as f64 / wall_s
            } else {
                0.0
            },
        }
    }
}

/// Runs the sweep on `settings.jobs` threads; `progress` is called (on the calling thread)
/// after each episode with the tally so far. Episodes are independent: the figures do not
/// depend on the number of threads.
// Wall time of the sweep, for its summary only; never fed to the cycle or the worker.
#[allow(clippy::disallowed_methods)]
pub fn run_sweep(
    assets: &SweepAssets,
    settings: &SweepSettings,
    mut progress: impl FnMut(&EpisodeReport, &SweepTally),
) -> SweepSummary {
    let t0 = std::time::Instant::now();
    let horizon = BrakingHorizon::of(&assets.cfg);
    let mut tally = SweepTally::new(*settings, horizon);
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel::<EpisodeReport>();
    std::thread::scope(|s| {
        for _ in 0..settings.jobs.max(1) {
            let tx = tx.clone();
            let (next, stop) = (&next, &stop);
            s.spawn(move || {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed) as u64;
                    if i >= settings.episodes || stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let r = run_episode(assets, settings, settings.first_episode + i);
                    if tx.send(r).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for r in rx {
            tally.add(&r);
            progress(&r, &tally);
        }
        stop.store(true, Ordering::Relaxed);
    });
    tally.summary(assets.bundled_problem, t0.elapsed().as_secs_f64())
}

/// The random stream of episode `index` of the sweep seeded `seed`.
pub(crate) fn episode_rng(seed: u64, index: u64) -> ChaCha8Rng {
    let mut z = seed ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    let mut rng = ChaCha8Rng::seed_from_u64(z ^ (z >> 31));
    rng.set_stream(index);
    rng
}

/// A detection-stamp twist.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StampKind {
    Zero,
    Future,
    Stale,
    PreStart,
}

/// A link cut during a stop.
#[derive(Debug, Clone, Copy)]
struct LinkCutPlan {
    /// Cycles after the arm first follows a plan when a refused frame forces a stop.
    force_stop_after: u64,
    /// Cycles into a stop when the link is cut.
    cut_after: u64,
    /// Cycles the link stays down.
    down: u64,
    /// Cycles after the link returns when the operator acknowledges.
    ack_after: u64,
    /// The cycle resumes on its own instead.
    auto_resume: bool,
}

/// Where an injected box goes on the arm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum InjectAt {
    Tcp,
    Wrist,
    Elbow,
    LinkAxis,
}

/// A box to inject, before its time is known.
#[derive(Debug, Clone, Copy)]
struct InjectPlan {
    ahead: u64,
    at: InjectAt,
    size_m: Point,
    offset_m: Point,
    axis_t: f64,
    axis_capsule: usize,
    pick: f64,
}

/// One world box of the ground truth.
#[derive(Debug, Clone, Copy)]
struct WorldBox {
    center: [f32; 3],
    size: [f32; 3],
    gt: OracleBox,
    appeared_cycle: u64,
    removed_cycle: Option<u64>,
    known_cycle: Option<u64>,
    injected_ahead: Option<u64>,
    clearance_at_appearance_m: f64,
    /// Nominal distance at the last command sent while present, m.
    last_distance_m: f64,
    first_intrusion_cycle: Option<u64>,
    intruded: bool,
    max_depth_m: f64,
}

impl WorldBox {
    fn new(center: [f32; 3], size: [f32; 3], appeared_cycle: u64) -> Self {
        let c = center.map(f64::from);
        let s = size.map(f64::from);
        Self {
            center,
            size,
            gt: OracleBox::new(c, s),
            appeared_cycle,
            removed_cycle: None,
            known_cycle: None,
            injected_ahead: None,
            clearance_at_appearance_m: f64::INFINITY,
            last_distance_m: f64::INFINITY,
            first_intrusion_cycle: None,
            intruded: false,
            max_depth_m: 0.0,
        }
    }

    fn present_at(&self, cycle: u64) -> bool {
        self.appeared_cycle <= cycle && self.removed_cycle.is_none_or(|r| cycle < r)
    }
}

/// Everything drawn for an episode before it runs.
#[derive(Debug, Clone)]
struct EpisodeSpec {
    policy: PolicyKind,
    swap: Option<(u64, PolicyKind)>,
    goal_center: [f32; 3],
    goal_size: f32,
    boxes: Vec<WorldBox>,
    stamps: Option<(u64, u64, StampKind)>,
    regress_at: Option<u64>,
    outside: Option<(u64, u64)>,
    overfull: Option<(u64, u64)>,
    dropout: Option<(u64, u64)>,
    goal_hidden: Option<(u64, u64)>,
    link_cut: Option<LinkCutPlan>,
    inject: Option<InjectPlan>,
    latency_seed: u64,
}

pub(crate) fn f32x3(p: [f64; 3]) -> [f32; 3] {
    p.map(|v| v as f32)
}

impl EpisodeSpec {
    fn draw(rng: &mut ChaCha8Rng, assets: &SweepAssets, settings: &SweepSettings) -> Self {
        let r = &settings.rates;
        let rate_hz = assets.cfg.rate_hz;
        let cyc = |s: f64| (s * rate_hz).round() as u64;
        let pick_policy = |rng: &mut ChaCha8Rng| {
            let total: f64 = r.policy_weights.iter().sum();
            let mut x = rng.random::<f64>() * total;
            for (k, w) in PolicyKind::ALL.iter().zip(r.policy_weights) {
                if x < w {
                    return *k;
                }
                x -= w;
            }
            PolicyKind::GoalSeeking
        };
        let policy = pick_policy(rng);
        let env = TwinEnv::new(assets.model.clone(), assets.task);
        let table = assets.task.sampling.table_height_m;
        let kind = rng.random_range(0..4u8);
        let sampled = env.sample_scene(
            rng,
            if kind == 1 {
                ObstacleClass::Large
            } else {
                ObstacleClass::Small
            },
        );
        let mut goal_center = f32x3(sampled.goal.center_m);
        let goal_size = sampled.goal.size_m as f32;
        let mut boxes = Vec::new();
        match kind {
            // The task's own scenes: a goal and a box on the way.
            0 | 1 => {
                for b in sampled.obstacles.iter() {
                    boxes.push(WorldBox::new(f32x3(b.center_m), f32x3(b.size_m), 0));
                }
            }
            // The goal alone.
            2 => {}
            // Clutter anywhere in reach (mostly clear of the start pose).
            _ => {
                let start = assets.task.start.joints_rad;
                for _ in 0..rng.random_range(1..=6) {
                    let s = [
                        rng.random_range(0.02..0.08),
                        rng.random_range(0.02..0.08),
                        rng.random_range(0.03..0.30),
                    ];
                    let c = [
                        rng.random_range(-0.6..0.6),
                        rng.random_range(-0.6..0.6),
                        table + s[2] / 2.0,
                    ];
                    let b = WorldBox::new(f32x3(c), f32x3(s), 0);
                    let clear = assets.oracle.clearance(&start, [&b.gt], table).box_m;
                    if clear > 0.05 || rng.random_bool(0.1) {
                        boxes.push(b);
                    }
                }
            }
        }
        if rng.random_bool(r.goal_near_base) {
            let radius = rng.random_range(0.10..0.20);
            let angle = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            goal_center = f32x3([
                radius * angle.cos(),
                radius * angle.sin(),
                table + sampled.goal.size_m / 2.0,
            ]);
        }
        let horizon_cycles = cyc(settings.max_episode_s);
        let window = |rng: &mut ChaCha8Rng, min_s: f64, max_s: f64| {
            (
                rng.random_range(0..horizon_cycles.max(2) / 2),
                rng.random_range(cyc(min_s)..=cyc(max_s)),
            )
        };
        let stamps = rng.random_bool(r.bad_stamp).then(|| {
            let kind = match rng.random_range(0..4u8) {
                0 => StampKind::Zero,
                1 => StampKind::Future,
                2 => StampKind::Stale,
                _ => StampKind::PreStart,
            };
            let (start, _) = window(rng, 0.0, 0.0);
            let frames = rng.random_range(1..=5);
            let start = if kind == StampKind::PreStart {
                0
            } else {
                start
            };
            (start, frames, kind)
        });
        let regress_at = rng
            .random_bool(r.sequence_regress)
            .then(|| window(rng, 0.0, 0.0).0);
        let outside = rng
            .random_bool(r.outside_workspace)
            .then(|| window(rng, 0.05, 0.3));
        let overfull = rng.random_bool(r.overfull).then(|| window(rng, 0.1, 1.0));
        let dropout = rng.random_bool(r.dropout).then(|| window(rng, 0.6, 1.2));
        let goal_hidden = rng
            .random_bool(r.goal_hidden)
            .then(|| window(rng, 0.1, 1.0));
        let swap = rng
            .random_bool(r.policy_swap)
            .then(|| (window(rng, 0.0, 0.0).0, pick_policy(rng)));
        let link_cut = rng.random_bool(r.link_cut).then(|| LinkCutPlan {
            force_stop_after: rng.random_range(10..150),
            cut_after: rng.random_range(0..10),
            down: rng.random_range(10..250),
            ack_after: rng.random_range(0..100),
            auto_resume: rng.random_bool(0.5),
        });
        let inject = rng.random_bool(r.inject).then(|| {
            let tiny = rng.random_bool(r.tiny_box);
            let size_m = if tiny {
                [0.005; 3]
            } else {
                [
                    rng.random_range(0.01..0.08),
                    rng.random_range(0.01..0.08),
                    rng.random_range(0.01..0.08),
                ]
            };
            let at = match rng.random_range(0..10u8) {
                0..4 => InjectAt::Tcp,
                4..6 => InjectAt::Wrist,
                6..8 => InjectAt::Elbow,
                _ => InjectAt::LinkAxis,
            };
            InjectPlan {
                ahead: rng.random_range(0..=MAX_INJECT_AHEAD_CYCLES),
                at,
                size_m,
                offset_m: [
                    rng.random_range(-0.01..0.01),
                    rng.random_range(-0.01..0.01),
                    rng.random_range(-0.01..0.01),
                ],
                axis_t: rng.random(),
                axis_capsule: rng.random_range(0..64),
                pick: rng.random(),
            }
        });
        Self {
            policy,
            swap,
            goal_center,
            goal_size,
            boxes,
            stamps,
            regress_at,
            outside,
            overfull,
            dropout,
            goal_hidden,
            link_cut,
            inject,
            latency_seed: rng.random(),
        }
    }
}

/// The in-process arm with a record of every command it received.
pub(crate) struct RecordingLink {
    arm: InProcessArm,
    pub(crate) sent: Vec<(u64, Joints)>,
}

impl RobotLink for RecordingLink {
    fn read_state(&mut self, now_ns: u64) -> Result<LinkState, LinkError> {
        self.arm.read_state(now_ns)
    }

    fn send_servo(&mut self, now_ns: u64, q_rad: &Joints) -> Result<(), LinkError> {
        self.arm.send_servo(now_ns, q_rad)?;
        self.sent.push((now_ns, *q_rad));
        Ok(())
    }

    fn acknowledge(&mut self, now_ns: u64) -> Result<(), LinkError> {
        self.arm.acknowledge(now_ns)
    }

    fn stop_controller(&mut self, now_ns: u64) {
        self.arm.stop_controller(now_ns);
    }
}

/// A prepared policy of `kind` for the task (the bundled one falls back to the goal-seeker
/// when unavailable; `fell_back` says so).
pub(crate) fn make_policy(
    assets: &SweepAssets,
    kind: PolicyKind,
    id: u64,
    seed: u64,
) -> (Option<Box<MlpPolicy>>, bool) {
    let hash = assets.task.hash();
    let loader = PolicyLoader::new(PolicyExpectation::for_task(hash));
    let random = || {
        PolicyBlobBuilder::random(id, hash, OBS_DIM, &[64, 64], ACT_DIM, seed)
            .build()
            .ok()
    };
    let goal_seeker = || goal_seeking_blob(&assets.task, id, hash);
    let (blob, fell_back) = match kind {
        PolicyKind::Bundled => match &assets.bundled {
            Some(b) => (Some(b.to_boxed()), false),
            None => (goal_seeker(), true),
        },
        PolicyKind::RandomWeights => (random(), false),
        PolicyKind::GoalSeeking => (goal_seeker(), false),
        PolicyKind::HugeWeights => (
            random().map(|mut b| {
                let n = b.n_weights as usize;
                for w in &mut b.weights[..n] {
                    *w *= 1e6;
                }
                b.seal();
                b
            }),
            false,
        ),
    };
    (
        blob.and_then(|b| loader.prepare(&b).ok()).map(Box::new),
        fell_back,
    )
}

/// A policy whose action points the TCP straight at the goal's target point, through
/// whatever stands in the way: one tanh layer computes `tanh(g·(target − tcp))` per axis
/// (goal x, y from the observation; the target's height from the task), the output layer
/// passes it on.
pub fn goal_seeking_blob(task: &TaskConfig, id: u64, task_hash: u64) -> Option<Box<PolicyBlob>> {
    const GAIN: f32 = 30.0;
    let s = &task.sampling;
    let target_z = (s.table_height_m + s.goal_size_m + task.success.goal_hover_m) as f32;
    let mut w1 = [0.0f32; 3 * OBS_DIM];
    // Observation: 1–2 goal x, y; 3–5 TCP.
    w1[1] = GAIN;
    w1[3] = -GAIN;
    w1[OBS_DIM + 2] = GAIN;
    w1[OBS_DIM + 4] = -GAIN;
    w1[2 * OBS_DIM + 5] = -GAIN;
    let b1 = [0.0, 0.0, GAIN * target_z];
    let w2 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    PolicyBlobBuilder::new(id, task_hash)
        .layer(OBS_DIM, 3, &w1, &b1)
        .layer(3, ACT_DIM, &w2, &[0.0; ACT_DIM])
        .build()
        .ok()
}

/// What a rehearsal recorded: the cycle's mode and the command sent at each cycle.
struct Rehearsal {
    modes: Vec<Mode>,
    sent: Vec<Option<Joints>>,
}

/// The name of a stop reason (for counters).
pub(crate) fn stop_reason_name(r: StopReason) -> &'static str {
    match r {
        StopReason::None => "none",
        StopReason::Shield(_) => "shield",
        StopReason::StaleDetection => "stale_detection",
        StopReason::StaleRobotState => "stale_robot_state",
        StopReason::LinkLost => "link_lost",
        StopReason::Revoked => "revoked",
        StopReason::ArmError(_) => "arm_error",
        StopReason::Shutdown => "shutdown",
        StopReason::DetectionRefused => "detection_refused",
        StopReason::ModelMismatch => "model_mismatch",
        StopReason::ControllerStopped { .. } => "controller_stopped",
        StopReason::TrackingLost => "tracking_lost",
        StopReason::Frozen => "frozen",
    }
}

/// The production worker and cycle of one episode, wired as `rt-core run` wires them, on a
/// manual clock at 0, the cycle started on the in-process arm at the task's start posture,
/// and the production intake in front of the worker.
pub(crate) struct Rig {
    pub(crate) clock: ManualClock,
    pub(crate) cycle: Cycle<TwinModel, RecordingLink>,
    pub(crate) worker: ProductionWorker,
    pub(crate) intake: SweepIntake,
    pub(crate) log: RtLogDrain<CycleEvent>,
    pub(crate) connection: Arc<AtomicBool>,
}

impl Rig {
    /// The rig for `assets`; `auto_resume` lets the cycle resume on its own after a link
    /// loss; `planner_fallback` installs the planner fallback in the worker.
    pub(crate) fn new(assets: &SweepAssets, auto_resume: bool, planner_fallback: bool) -> Self {
        let cfg = &assets.cfg;
        let start = assets.task.start.joints_rad;
        let (twin_io, cycle_io, log) = cycle::wire::<Scene>();
        let arm = InProcessArm::new(
            start,
            cfg.limits.joint_min_rad,
            cfg.limits.joint_max_rad,
            [std::f64::consts::PI; DOF],
        );
        let connection = arm.connection();
        let mut cycle_cfg = CycleConfig::from_runtime(cfg);
        cycle_cfg.auto_resume_after_link_loss = auto_resume;
        let mut cycle = Cycle::new(
            cycle_cfg,
            serve::cycle_shield(cfg, &assets.model, false),
            Brake::new(&cfg.limits),
            RecordingLink {
                arm,
                sent: Vec::with_capacity(4096),
            },
            cycle_io,
        );
        let clock = ManualClock::new(0);
        // The in-process arm is always readable at start.
        let _ = cycle.start(clock.now_ns());
        let lookahead =
            TwinLookahead::new(assets.model.clone(), assets.task, LookaheadActions::Policy);
        let (mut worker, path) = ProductionWorker::new(
            cfg,
            lookahead,
            serve::plan_shield(cfg, &assets.model, false),
            twin_io,
        );
        if planner_fallback {
            // As `rt-core run` installs it (serve.rs): over the model with the task's tool.
            let armed = assets
                .model
                .clone()
                .with_tool(assets.task.tool.map(|t| t.capsule()));
            worker.set_fallback_planner(Box::new(TwinPathPlanner::new(armed, assets.task, cfg)));
        }
        let checks = SceneIntake::new(
            cfg.intake,
            (cfg.stale.max_detection_age_s * 1e9) as u64,
            assets.task.sampling.table_height_m,
            ORIGIN_NS,
        )
        .with_covered_age_s(cfg.separation.reaction_time_s);
        let intake = SweepIntake { checks, path };
        Self {
            clock,
            cycle,
            worker,
            intake,
            log,
            connection,
        }
    }
}

/// The intake thread of `rt-core run`, stepped inline: each frame through the production
/// intake, then its scene (or its refusal) onto the worker's scene path — to the cycle and
/// the plan guard — and only then noted by the worker, the order and the doors the intake
/// thread and the twin node use (`twin_thread::intake_thread`, `twin_thread::node`).
pub(crate) struct SweepIntake {
    checks: SceneIntake,
    path: ScenePath<TwinModel>,
}

impl SweepIntake {
    /// Checks one frame received at `mono_now_ns` from `publishers` publishers and hands
    /// the outcome on as the intake thread does; the outcome as [`SceneIntake::accept`].
    pub(crate) fn deliver(
        &mut self,
        frame: &DetectionFrame,
        mono_now_ns: u64,
        publishers: usize,
        worker: &mut ProductionWorker,
        events: &mut Vec<TwinEvent<Scene>>,
    ) -> Result<AcceptedFrame, FrameRefusal> {
        let outcome = self.checks.accept(frame, mono_now_ns, publishers);
        match &outcome {
            Ok(a) => {
                self.path.accepted(a.scene, a.stamp_ns, a.intruders);
                worker.note_frame(a, events);
            }
            Err(_) => {
                self.path.refused();
                worker.note_refused();
            }
        }
        outcome
    }
}

/// One episode's rig and state.
struct Episode<'a> {
    assets: &'a SweepAssets,
    settings: &'a SweepSettings,
    spec: EpisodeSpec,
    index: u64,
    period_ns: u64,
    horizon_cycles: u64,
    clock: ManualClock,
    cycle: Cycle<TwinModel, RecordingLink>,
    worker: ProductionWorker,
    intake: SweepIntake,
    log: RtLogDrain<CycleEvent>,
    connection: Arc<AtomicBool>,
    events: Vec<TwinEvent<Scene>>,
    world: Vec<WorldBox>,
    limits: CommandLimits,
    prev_q: Joints,
    prev_tcp: Point,
    sent_seen: usize,
    sequence: u64,
    latency_rng: ChaCha8Rng,
    report: EpisodeReport,
    goal_target: Point,
}

impl<'a> Episode<'a> {
    fn new(
        assets: &'a SweepAssets,
        settings: &'a SweepSettings,
        spec: EpisodeSpec,
        index: u64,
    ) -> Self {
        let cfg = &assets.cfg;
        let start = assets.task.start.joints_rad;
        let Rig {
            clock,
            cycle,
            worker,
            intake,
            log,
            connection,
        } = Rig::new(
            assets,
            spec.link_cut.is_some_and(|l| l.auto_resume),
            settings.planner_fallback,
        );
        let oracle = &assets.oracle;
        let gc = spec.goal_center.map(f64::from);
        let goal_target = [
            gc[0],
            gc[1],
            gc[2] + f64::from(spec.goal_size) / 2.0 + assets.task.success.goal_hover_m,
        ];
        let world = spec.boxes.clone();
        let latency_rng = ChaCha8Rng::seed_from_u64(spec.latency_seed);
        Self {
            assets,
            settings,
            index,
            period_ns: cfg.period_ns(),
            horizon_cycles: BrakingHorizon::of(cfg).horizon_cycles,
            clock,
            cycle,
            worker,
            intake,
            log,
            connection,
            events: Vec::new(),
            world,
            limits: CommandLimits {
                joint_min_rad: cfg.limits.joint_min_rad,
                joint_max_rad: cfg.limits.joint_max_rad,
                max_velocity_rad_s: cfg.limits.max_velocity_rad_s,
                max_tcp_speed_m_s: cfg.limits.max_tcp_speed_m_s,
                period_s: 1.0 / cfg.rate_hz,
            },
            prev_q: start,
            prev_tcp: oracle.tcp_m(&start),
            sent_seen: 0,
            sequence: 0,
            latency_rng,
            report: EpisodeReport {
                episode: index,
                min_known_box_clearance_m: f64::INFINITY,
                min_known_box_clearance_moving_m: f64::INFINITY,
                min_table_clearance_m: f64::INFINITY,
                ..EpisodeReport::default()
            },
            goal_target,
            spec,
        }
    }

    fn in_window(w: Option<(u64, u64)>, cycle: u64) -> bool {
        w.is_some_and(|(s, n)| cycle >= s && cycle < s + n)
    }

    /// Builds the frame of cycle `c` at `now_ns` and hands it through the intake.
    fn deliver_frame(&mut self, c: u64, now_ns: u64, stamp: Option<StampKind>) {
        let latency_ns = self
            .latency_rng
            .random_range(0..=(self.settings.max_latency_s * 1e9) as u64)
            .min(now_ns);
        let mono_now = ORIGIN_NS + now_ns;
        let capture_cycle_ns = now_ns - latency_ns;
        let capture = match stamp {
            None => ORIGIN_NS + capture_cycle_ns,
            Some(StampKind::Zero) => 0,
            Some(StampKind::Future) => mono_now + 50_000_000,
            Some(StampKind::Stale) => {
                mono_now - (self.assets.cfg.stale.max_detection_age_s * 1e9) as u64 - 100_000_000
            }
            Some(StampKind::PreStart) => ORIGIN_NS - 50_000_000,
        };
        if let Some(s) = stamp {
            self.report.bump(match s {
                StampKind::Zero => "twist_frames_zero_stamp",
                StampKind::Future => "twist_frames_future_stamp",
                StampKind::Stale => "twist_frames_stale_stamp",
                StampKind::PreStart => "twist_frames_prestart_stamp",
            });
        }
        let regress = self
            .spec
            .regress_at
            .is_some_and(|r| c >= r && c < r + self.settings.frame_every_cycles);
        if !regress || self.sequence == 0 {
            self.sequence += 1;
        } else {
            self.report.bump("twist_frames_sequence_regress");
        }
        // Settled: the sweep's world is its ground truth, not a tracker's view of it.
        let mut frame = DetectionFrame {
            sequence: self.sequence,
            capture_time_ns: capture,
            camera_id: 1,
            flags: DetectionFrame::FRAME_SETTLED,
            ..DetectionFrame::default()
        };
        let confidence = if Self::in_window(self.spec.goal_hidden, c) {
            self.report.bump("twist_frames_goal_hidden");
            0.2
        } else {
            0.9
        };
        frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            confidence,
            self.spec.goal_center,
            [self.spec.goal_size; 3],
        ));
        let period = self.period_ns;
        let mut carried = Vec::new();
        for (i, b) in self.world.iter().enumerate() {
            // In the frame when present at its capture time.
            let cap_cycle = capture_cycle_ns / period;
            if b.present_at(cap_cycle) || (stamp.is_some() && b.present_at(c)) {
                frame.push(DetectedObject::new(
                    10 + i as u32,
                    ObjectClass::Obstacle,
                    0.9,
                    b.center,
                    b.size,
                ));
                carried.push(i);
            }
        }
        if frame.dropped_count > 0 {
            self.report.bump("twist_frames_overfull");
        }
        if Self::in_window(self.spec.outside, c) {
            self.report.bump("twist_frames_outside_workspace");
            frame.push(DetectedObject::new(
                99,
                ObjectClass::Obstacle,
                0.9,
                [0.95, 0.0, 0.05],
                [0.05; 3],
            ));
        }
        self.report.bump("frames_delivered");
        for i in carried {
            if self.world[i].known_cycle.is_none() {
                self.world[i].known_cycle = Some(c);
            }
        }
        match self
            .intake
            .deliver(&frame, mono_now, 1, &mut self.worker, &mut self.events)
        {
            Ok(_) => self.report.bump("frames_accepted"),
            Err(refusal) => self.report.bump(&format!(
                "frames_refused_{}",
                FrameRefusal::NAMES[refusal.index()]
            )),
        }
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
                TwinEvent::PlanApproved {
                    joins, policy_id, ..
                } => {
                    if policy_id == PLANNER_POLICY_ID {
                        "twin_plans_approved_planner"
                    } else if joins {
                        "twin_plans_approved_joining"
                    } else {
                        "twin_plans_approved"
                    }
                }
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
            self.report.bump(key);
        }
        let report = &mut self.report;
        self.log.drain(|r| {
            let key = match r.event {
                CycleEvent::StopBegun { reason } => {
                    report.bump(&format!("cycle_stops_{}", stop_reason_name(reason)));
                    return;
                }
                CycleEvent::PlanAdopted { .. } => "cycle_plans_adopted",
                CycleEvent::PlanRefused { .. } => "cycle_plans_refused",
                CycleEvent::PlanRevoked { .. } => "cycle_plans_revoked",
                CycleEvent::StopDue { .. } => "cycle_stops_due",
                CycleEvent::JoinedBeforeStop { .. } => "cycle_joins_before_stop",
                CycleEvent::CommandRefused { .. } => "cycle_commands_refused",
                CycleEvent::SnappedToMeasured => "cycle_snapped_to_measured",
                CycleEvent::Acknowledged { .. } => "cycle_acknowledged",
                CycleEvent::LinkError { .. } => "cycle_link_errors",
                _ => return,
            };
            report.bump(key);
        });
    }

    /// Checks every command sent since the last call with the oracle.
    fn check_sent(&mut self) {
        let n = self.cycle.link().sent.len();
        let oracle = &self.assets.oracle;
        let table = self.assets.task.sampling.table_height_m;
        let period = self.period_ns;
        for k in self.sent_seen..n {
            let (t_ns, q) = self.cycle.link().sent[k];
            let at_cycle = t_ns / period;
            self.report.commands += 1;
            let tcp = oracle.tcp_m(&q);
            let m = self.limits.check(&self.prev_q, &q, &self.prev_tcp, &tcp);
            let fail = |kind: &'static str,
                        value: f64,
                        index: Option<usize>,
                        known: Option<f64>,
                        r: &mut EpisodeReport| {
                if r.failures.len() < 5 {
                    r.failures.push(HardFailure {
                        episode: r.episode,
                        cycle: at_cycle,
                        kind,
                        value,
                        index,
                        known_for_s: known,
                        q_rad: q,
                    });
                }
            };
            if m.non_finite {
                self.report.hard.non_finite_commands += 1;
                fail("non_finite", f64::NAN, None, None, &mut self.report);
                continue;
            }
            if let Some(j) = m.joint_limit {
                self.report.hard.joint_limit_violations += 1;
                fail("joint_limit", q[j], Some(j), None, &mut self.report);
            }
            if let Some((j, step)) = m.joint_step {
                self.report.hard.joint_step_violations += 1;
                fail("joint_step", step, Some(j), None, &mut self.report);
            }
            if let Some(v) = m.tcp_speed_m_s {
                self.report.hard.tcp_speed_violations += 1;
                fail("tcp_speed", v, None, None, &mut self.report);
            }
            if let Some(step) = m.tcp_step_m {
                self.report.hard.tcp_step_violations += 1;
                fail("tcp_step", step, None, None, &mut self.report);
            }
            let world = oracle.world_capsules(&q);
            let mut table_m = f64::INFINITY;
            for (cap, a, b) in &world {
                if cap.meets_table() {
                    table_m = table_m.min(a[2].min(b[2]) - table - cap.radius_m);
                }
            }
            self.report.min_table_clearance_m = self.report.min_table_clearance_m.min(table_m);
            if table_m < 0.0 {
                self.report.hard.table_penetrations += 1;
                fail("table_penetration", -table_m, None, None, &mut self.report);
            }
            let mut unavoidable_here = false;
            for (i, bx) in self.world.iter_mut().enumerate() {
                if !bx.present_at(at_cycle) {
                    continue;
                }
                let d = world
                    .iter()
                    .map(|(cap, a, b)| segment_box_distance_m(a, b, &bx.gt) - cap.radius_m)
                    .fold(f64::INFINITY, f64::min);
                let known_for = bx.known_cycle.map(|k| at_cycle.saturating_sub(k));
                let settled = known_for.is_some_and(|k| k >= self.horizon_cycles)
                    && bx.known_cycle.is_some_and(|k| k <= at_cycle);
                // Still inside a box it was caught in, no deeper: a hold (or a way out),
                // not a move into the box.
                let prev_d = std::mem::replace(&mut bx.last_distance_m, d);
                let held_inside = d < 0.0 && prev_d < 0.0 && d >= prev_d - DEEPER_TOLERANCE_M;
                if settled && !held_inside {
                    self.report.min_known_box_clearance_m =
                        self.report.min_known_box_clearance_m.min(d);
                    if q != self.prev_q {
                        self.report.min_known_box_clearance_moving_m =
                            self.report.min_known_box_clearance_moving_m.min(d);
                    }
                }
                if d >= 0.0 {
                    continue;
                }
                if settled && held_inside {
                    self.report.held_inside_poses += 1;
                } else if settled {
                    self.report.hard.box_penetrations += 1;
                    let known_s = known_for.map(|k| k as f64 * self.limits.period_s);
                    fail("box_penetration", -d, Some(i), known_s, &mut self.report);
                } else {
                    unavoidable_here = true;
                    bx.intruded = true;
                    bx.first_intrusion_cycle.get_or_insert(at_cycle);
                    bx.max_depth_m = bx.max_depth_m.max(-d);
                }
            }
            if unavoidable_here {
                self.report.unavoidable_poses += 1;
            }
            if max_gap(&tcp, &self.goal_target) <= self.assets.task.success.tolerance_m + 0.01 {
                self.report.bump("reached_goal_cycles");
            }
            self.prev_q = q;
            self.prev_tcp = tcp;
        }
        self.sent_seen = n;
    }

    /// Runs the episode; with `rehearse`, records modes and commands and stops early.
    fn run(
        mut self,
        inject: Option<(u64, WorldBox)>,
        rehearse: bool,
    ) -> (EpisodeReport, Option<Rehearsal>) {
        let rate_hz = self.assets.cfg.rate_hz;
        let max_cycles = (self.settings.max_episode_s * rate_hz).round() as u64;
        let mut rehearsal = rehearse.then(|| Rehearsal {
            modes: Vec::new(),
            sent: Vec::new(),
        });
        let (first_policy, fell_back) = make_policy(
            self.assets,
            self.spec.policy,
            1 + self.index * 8,
            self.index,
        );
        self.report
            .bump(&format!("policy_{}", self.spec.policy.name()));
        if fell_back {
            self.report.bump("policy_bundled_replaced_by_goal_seeking");
        }
        match first_policy {
            Some(p) => self.worker.on_policy(p, &mut self.events),
            None => self.report.bump("policy_refused_by_loader"),
        }
        let mut first_following: Option<u64> = None;
        let mut stamp_left = self.spec.stamps.map_or(0, |s| s.1);
        let mut stopping_for = 0u64;
        let mut cut_at: Option<u64> = None;
        let mut restored_at: Option<u64> = None;
        let mut acked = false;
        let mut forced_stop_done = false;
        let mut idle_for = 0u64;
        let mut last_twist = 0u64;
        for (s, n) in [
            self.spec.outside,
            self.spec.overfull,
            self.spec.dropout,
            self.spec.goal_hidden,
        ]
        .into_iter()
        .flatten()
        {
            last_twist = last_twist.max(s + n);
        }
        if let Some((s, _)) = self.spec.swap {
            last_twist = last_twist.max(s);
        }
        if let Some(s) = self.spec.stamps {
            last_twist = last_twist.max(s.0 + s.1 * self.settings.frame_every_cycles);
        }
        let mut overfull_ids: Vec<usize> = Vec::new();
        let mut c = 0u64;
        while c < max_cycles {
            let now = self.clock.now_ns();
            // The world changes.
            if let Some((at, b)) = inject
                && c == at
            {
                let clearance_at_appearance_m = self
                    .assets
                    .oracle
                    .clearance(&self.prev_q, [&b.gt], f64::NEG_INFINITY)
                    .box_m;
                self.world.push(WorldBox {
                    appeared_cycle: c,
                    clearance_at_appearance_m,
                    ..b
                });
                self.report.bump(if clearance_at_appearance_m < 0.0 {
                    "twist_boxes_injected_onto_the_arm"
                } else {
                    "twist_boxes_injected_ahead_of_the_arm"
                });
            }
            if let Some((s, n)) = self.spec.overfull {
                if c == s {
                    self.report.bump("twist_overfull_windows");
                    let mut rng = ChaCha8Rng::seed_from_u64(self.spec.latency_seed ^ 0x0f);
                    for _ in 0..shm_schemas::MAX_DETECTIONS {
                        let center = [
                            rng.random_range(-0.7f32..-0.45),
                            rng.random_range(-0.7f32..0.7),
                            0.015,
                        ];
                        overfull_ids.push(self.world.len());
                        self.world.push(WorldBox::new(center, [0.03; 3], c));
                    }
                }
                if c == s + n {
                    for &i in &overfull_ids {
                        self.world[i].removed_cycle = Some(c);
                    }
                }
            }
            // The link: cut mid-stop, restored, acknowledged.
            if let (Some(plan), Some(cut)) = (self.spec.link_cut, cut_at) {
                if restored_at.is_none() && c >= cut + plan.down {
                    self.connection.store(true, Ordering::Release);
                    restored_at = Some(c);
                    self.report.bump("twist_link_restored");
                }
                if let Some(r) = restored_at
                    && !plan.auto_resume
                    && !acked
                    && c >= r + plan.ack_after
                {
                    self.worker.control().acknowledge_latched();
                    acked = true;
                    self.report.bump("twist_operator_acknowledged");
                }
            }
            if let Some((s, kind)) = self.spec.swap
                && c == s
            {
                let (p, _) = make_policy(self.assets, kind, 5 + self.index * 8, self.index ^ 0x55);
                if let Some(p) = p {
                    self.worker.on_policy(p, &mut self.events);
                    self.report.bump("twist_policy_swapped_in");
                }
            }
            // Detection frames.
            let force_stop = !forced_stop_done
                && self
                    .spec
                    .link_cut
                    .is_some_and(|l| first_following.is_some_and(|f| c == f + l.force_stop_after));
            if force_stop {
                forced_stop_done = true;
                self.report.bump("twist_forced_stop_frames");
                self.deliver_frame(c, now, Some(StampKind::Zero));
            } else if c.is_multiple_of(self.settings.frame_every_cycles)
                && !Self::in_window(self.spec.dropout, c)
            {
                let stamp = match self.spec.stamps {
                    Some((s, _, kind)) if c >= s && stamp_left > 0 => {
                        stamp_left -= 1;
                        Some(kind)
                    }
                    _ => None,
                };
                self.deliver_frame(c, now, stamp);
            }
            if Self::in_window(self.spec.dropout, c) && c == self.spec.dropout.map_or(0, |d| d.0) {
                self.report.bump("twist_dropouts");
            }
            self.worker.step(&mut self.events);
            let mode = self.cycle.process(now);
            self.count_events();
            if !rehearse {
                self.check_sent();
            }
            if let Some(r) = rehearsal.as_mut() {
                let n = self.cycle.link().sent.len();
                let sent = (n > self.sent_seen).then(|| self.cycle.link().sent[n - 1].1);
                self.sent_seen = n;
                r.modes.push(mode);
                r.sent.push(sent);
            }
            if mode == Mode::Following && first_following.is_none() {
                first_following = Some(c);
            }
            // Cut the link in the middle of a stop.
            if mode == Mode::Stopping {
                stopping_for += 1;
                if let Some(plan) = self.spec.link_cut
                    && cut_at.is_none()
                    && stopping_for > plan.cut_after
                {
                    self.connection.store(false, Ordering::Release);
                    cut_at = Some(c);
                    self.report.bump("twist_link_cuts_mid_stop");
                }
            } else {
                stopping_for = 0;
            }
            // Early end: at rest long after every twist, nothing pending.
            if matches!(mode, Mode::Idle | Mode::Stopped) {
                idle_for += 1;
            } else {
                idle_for = 0;
            }
            let link_settled = cut_at.is_none_or(|_| restored_at.is_some());
            let injection_done = inject.is_none_or(|(at, _)| c > at);
            let rehearsal_done =
                rehearse && first_following.is_some_and(|f| c > f + 400 + MAX_INJECT_AHEAD_CYCLES);
            if rehearsal_done
                || (idle_for > 400
                    && c > last_twist
                    && link_settled
                    && injection_done
                    && (self.spec.link_cut.is_none()
                        || first_following.is_none()
                        || cut_at.is_some()))
            {
                c += 1;
                self.clock.advance_ns(self.period_ns);
                break;
            }
            c += 1;
            self.clock.advance_ns(self.period_ns);
        }
        self.report.cycles = c;
        let r = *self.cycle.report();
        self.report
            .bump_by("cycle_envelope_breaches", r.envelope_breaches);
        self.report
            .bump_by("cycle_commands_refused_total", r.commands_refused);
        // Outcome.
        let outcome = if self.report.counts.contains_key("reached_goal_cycles") {
            "outcome_reached_goal"
        } else if self.report.counts.contains_key("twin_retrain_requests") && r.plans_taken == 0 {
            "outcome_refused_by_lookahead"
        } else if r.plans_taken == 0 {
            "outcome_no_plan"
        } else if r.stops > 0 {
            "outcome_stopped_short"
        } else {
            "outcome_timed_out"
        };
        self.report.bump(outcome);
        self.report
            .bump(&format!("{outcome}_by_{}", self.spec.policy.name()));
        if r.stops > 0 {
            self.report.bump("episodes_with_a_stop");
        }
        if first_following.is_some() {
            self.report.bump("episodes_that_moved");
        }
        if self.spec.link_cut.is_some() && cut_at.is_none() {
            self.report.bump("twist_link_cut_not_reached");
        }
        for b in &self.world {
            if b.intruded {
                self.report.intrusion_depths_m.push(b.max_depth_m);
            }
            if let Some(k) = b.injected_ahead {
                self.report.injections.push(InjectionRecord {
                    episode: self.index,
                    ahead_cycles: k,
                    clearance_at_injection_m: b.clearance_at_appearance_m,
                    known_after_cycles: b.known_cycle.map(|c| c - b.appeared_cycle),
                    intruded_after_cycles: b.first_intrusion_cycle.map(|c| c - b.appeared_cycle),
                    depth_m: b.max_depth_m,
                });
            }
        }
        let _ = self.cycle.stop(self.clock.now_ns());
        (self.report, rehearsal)
    }
}

pub(crate) fn max_gap(a: &Point, b: &Point) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Where to put an injected box, from the rehearsal: a cycle at which the arm follows a
/// plan, and the point of the arm `ahead` cycles later.
fn place_injection(
    assets: &SweepAssets,
    plan: &InjectPlan,
    rehearsal: &Rehearsal,
) -> Option<(u64, WorldBox)> {
    let following: Vec<usize> = rehearsal
        .modes
        .iter()
        .enumerate()
        .filter(|(_, m)| **m == Mode::Following)
        .map(|(i, _)| i)
        .collect();
    if following.is_empty() {
        return None;
    }
    let sent_by = |cycle: usize| {
        rehearsal.sent[..=cycle.min(rehearsal.sent.len() - 1)]
            .iter()
            .rev()
            .flatten()
            .next()
            .copied()
    };
    let oracle = &assets.oracle;
    let mut placed = None;
    // A box on the path ahead, not one dropped on the arm: the first of a few candidate
    // times at which the box clears the arm's pose (else the last candidate).
    for attempt in 0..INJECT_ATTEMPTS {
        let pick = (plan.pick + attempt as f64 * 0.618_033_988_749_895).fract();
        let at = following[((pick * following.len() as f64) as usize).min(following.len() - 1)];
        let (Some(q_now), Some(q)) = (sent_by(at), sent_by(at + plan.ahead as usize)) else {
            continue;
        };
        let point = match plan.at {
            InjectAt::Tcp => oracle.tcp_m(&q),
            InjectAt::Wrist => oracle.frame_origins_m(&q)[4],
            InjectAt::Elbow => oracle.frame_origins_m(&q)[3],
            InjectAt::LinkAxis => {
                let caps = oracle.world_capsules(&q);
                let (_, a, b) = caps[plan.axis_capsule % caps.len()];
                [
                    a[0] + (b[0] - a[0]) * plan.axis_t,
                    a[1] + (b[1] - a[1]) * plan.axis_t,
                    a[2] + (b[2] - a[2]) * plan.axis_t,
                ]
            }
        };
        let center = [
            point[0] + plan.offset_m[0],
            point[1] + plan.offset_m[1],
            point[2] + plan.offset_m[2],
        ];
        let mut b = WorldBox::new(f32x3(center), f32x3(plan.size_m), at as u64);
        b.injected_ahead = Some(plan.ahead);
        let clear = oracle.clearance(&q_now, [&b.gt], f64::NEG_INFINITY).box_m > 0.0;
        placed = Some((at as u64, b));
        if clear {
            break;
        }
    }
    placed
}

/// Candidate injection times tried per box.
const INJECT_ATTEMPTS: usize = 24;

/// Runs episode `index` of the sweep (deterministic in `settings.seed` and `index`).
pub fn run_episode(assets: &SweepAssets, settings: &SweepSettings, index: u64) -> EpisodeReport {
    let mut rng = episode_rng(settings.seed, index);
    let spec = EpisodeSpec::draw(&mut rng, assets, settings);
    let injection = match spec.inject {
        Some(plan) => {
            let (_, rehearsal) =
                Episode::new(assets, settings, spec.clone(), index).run(None, true);
            let placed = rehearsal.and_then(|r| place_injection(assets, &plan, &r));
            if placed.is_none() {
                let mut r = Episode::new(assets, settings, spec, index)
                    .run(None, false)
                    .0;
                r.bump("twist_injection_skipped_no_motion");
                return r;
            }
            placed
        }
        None => None,
    };
    Episode::new(assets, settings, spec, index)
        .run(injection, false)
        .0
}
