//! The runtime's configuration (`assets/runtime.toml`): cycle rate, the arm's motion limits,
//! the shield's limits and margins, stale-input ages and the iceoryx2 service prefix. Loaded
//! with serde and validated once at load; the cycle then uses plain `Copy` values.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use shm_schemas::runtime_view;
/// `[limits]` too: the learner's verification of a plan reads it with `[shield]` and
/// `rate_hz` (`twin::approval::ApprovalSettings`), so it is defined once, in the view.
pub use shm_schemas::runtime_view::MotionLimits;
/// `[shield]`, `[intake]` and `[goal]` are defined once, with their defaults, in the view of
/// this file that the bridge and the launcher read too ([`shm_schemas::runtime_view`]).
pub use shm_schemas::runtime_view::{GoalConfig, GoalSource, IntakeConfig, ShieldConfig};

/// The shipped `assets/runtime.toml`.
pub const SHIPPED_RUNTIME_TOML: &str = include_str!("../../assets/runtime.toml");

/// Why a runtime configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeConfigError {
    /// The file could not be read.
    #[error("cannot read {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML did not parse into the expected shape.
    #[error("invalid runtime config")]
    Parse(#[from] toml::de::Error),
    /// A value is out of its allowed range.
    #[error("invalid runtime config: {field}: {why}")]
    Invalid {
        /// The offending field.
        field: &'static str,
        /// What is wrong with it.
        why: &'static str,
    },
}

/// Share of the acceleration limit the stop along the plan's time scaling may use
/// (`cycle::brake::PathStop`): the plan's own acceleration (scaled by `s² ≤ 1`) takes the
/// rest.
pub const PATH_STOP_ACCEL_SHARE: f64 = 0.8;

/// The longest stop of the arm from its velocity limits, s: the longer of the per-joint
/// jerk-limited brake's bound (`v/a + a/j`) and the stop along the plan
/// (`1.5·v / (share·a)`, `cycle::brake::PathStop::duration_s`), over all joints.
/// (`MotionLimits` is defined once, in `shm_schemas::runtime_view`.)
pub fn longest_stop_s(limits: &MotionLimits) -> f64 {
    (0..twin::DOF)
        .map(|j| {
            let (v, a) = (
                limits.max_velocity_rad_s[j],
                limits.max_acceleration_rad_s2[j],
            );
            let brake_s = v / a + a / limits.max_jerk_rad_s3[j];
            let path_s = 1.5 * v / (PATH_STOP_ACCEL_SHARE * a);
            brake_s.max(path_s)
        })
        .fold(0.0, f64::max)
}

/// Ages beyond which an input counts as stale.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaleConfig {
    /// Maximum age of the latest detection frame, s.
    pub max_detection_age_s: f64,
    /// Maximum age of the latest robot state, s.
    pub max_robot_state_age_s: f64,
}

/// The cycle's check that the arm follows its commands (`[tracking]`): the measured joints
/// more than `max_error_rad` from the last command sent for `max_error_cycles` periods in a
/// row is a frozen or blocked arm — a controlled stop, latched until an operator
/// acknowledges (see [`crate::cycle::StopReason::TrackingLost`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackingConfig {
    /// Largest joint gap between the last command sent and the measured joints, rad.
    #[serde(default = "default_tracking_error_rad")]
    pub max_error_rad: f64,
    /// Periods in a row beyond `max_error_rad` before the stop.
    #[serde(default = "default_tracking_error_cycles")]
    pub max_error_cycles: u32,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        Self {
            max_error_rad: default_tracking_error_rad(),
            max_error_cycles: default_tracking_error_cycles(),
        }
    }
}

fn default_tracking_error_rad() -> f64 {
    0.1
}
fn default_tracking_error_cycles() -> u32 {
    25
}

/// The bounds every safety limit is validated against (documented in
/// `assets/runtime.toml`). A value outside them is refused at load with the field named.
pub mod bounds {
    /// The xArm SDK's joint speed limit (180 °/s), rad/s: no configured joint velocity may
    /// exceed it (nor the URDF's, checked against the model at start).
    pub const SDK_MAX_JOINT_VELOCITY_RAD_S: f64 = std::f64::consts::PI;
    /// The xArm SDK's joint acceleration limit (1145 °/s²), rad/s².
    pub const SDK_MAX_JOINT_ACCELERATION_RAD_S2: f64 = 20.0;
    /// Largest joint jerk accepted, rad/s³ (the SDK's 28 647 °/s³).
    pub const SDK_MAX_JOINT_JERK_RAD_S3: f64 = 500.0;
    /// Largest cycle rate on the xArm link, Hz (the controller's servo-mode maximum).
    pub const XARM_MAX_RATE_HZ: f64 = 250.0;
    /// Smallest cycle rate on the xArm link, Hz: the controller executes each servo target
    /// within its own period (4 ms), so a slower stream sends larger jumps per target, and
    /// the cycle's one-step bound (a period's motion at the speed limits) grows with it.
    pub const XARM_MIN_RATE_HZ: f64 = 100.0;
    /// The controller's own servo period, s: it executes each servo target within it.
    pub const XARM_SERVO_PERIOD_S: f64 = 0.004;
    /// Largest detection age, s: older, a dead perception would leave the arm moving on a
    /// scene that may have changed.
    pub const MAX_DETECTION_AGE_S: f64 = 1.0;
    /// Largest robot-state age, s.
    pub const MAX_ROBOT_STATE_AGE_S: f64 = 0.2;
    /// Smallest clearance the shield may be given, m (the detection grid is 5 mm).
    pub const MIN_CLEARANCE_FLOOR_M: f64 = 0.005;
    /// Largest clearance, m (more leaves no room to work).
    pub const MAX_CLEARANCE_M: f64 = 0.2;
    /// Largest joint margin, rad.
    pub const MAX_JOINT_MARGIN_RAD: f64 = 0.5;
    /// Allowed range of the twin-vs-controller TCP tolerance, m: below 1 mm the controller's
    /// own rounding trips it; above 20 mm a wrong model goes unnoticed.
    pub const TCP_GAP_RANGE_M: (f64, f64) = (0.001, 0.02);
    /// The xArm5's reach (0.7 m) plus room for a tool, m: the TCP workspace and the
    /// calibrated workspace lie within this of the base axis in x and y.
    pub const REACH_BOUND_M: f64 = 0.8;
    /// Lowest z of a workspace, m (below the base plate).
    pub const WORKSPACE_MIN_Z_M: f64 = -0.1;
    /// Highest z of a workspace, m (the xArm5 stretched up reaches about 0.95 m).
    pub const WORKSPACE_MAX_Z_M: f64 = 1.1;
    /// Most user ids `[operator] ack_uids` may list.
    pub const MAX_OPERATOR_UIDS: usize = 16;
    /// Smallest goal-confidence floor.
    pub const MIN_GOAL_CONFIDENCE_FLOOR: f32 = 0.05;
    /// Allowed range of the tracking tolerance, rad: below 0.01 rad the controller's own
    /// lag at full speed trips it; above 0.5 rad a frozen arm goes unnoticed too long.
    pub const TRACKING_ERROR_RANGE_RAD: (f64, f64) = (0.01, 0.5);
    /// Allowed range of the tracking check's periods in a row (1000: 4 s at 250 Hz).
    pub const TRACKING_CYCLES_RANGE: (u32, u32) = (1, 1000);
    /// Allowed range of the separation monitor's assumed intruder speed, m/s (ISO/TS 15066
    /// assumes 1.6 m/s for a body part approaching; ISO 13855's hand speed is 2.0 m/s).
    pub const SEPARATION_INTRUDER_SPEED_RANGE_M_S: (f64, f64) = (0.5, 5.0);
    /// Largest reaction time of the separation monitor, s (the lower bound is one period).
    pub const SEPARATION_MAX_REACTION_TIME_S: f64 = 1.0;
    /// Largest intrusion distance C, m (ISO 13855's largest, a reach over a sensing field).
    pub const SEPARATION_MAX_INTRUSION_M: f64 = 0.85;
    /// Largest position uncertainty Z_d + Z_r, m.
    pub const SEPARATION_MAX_UNCERTAINTY_M: f64 = 0.2;
}

/// The whole runtime configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuntimeConfig {
    /// Cycle rate, Hz (250 = the xArm servo-mode maximum).
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// Prefix of every iceoryx2 service name this runtime opens.
    #[serde(default = "default_prefix")]
    pub service_prefix: String,
    /// How far ahead of the running plan a replacement plan joins it, s.
    #[serde(default = "default_join_ahead_s")]
    pub join_ahead_s: f64,
    /// When a new scene makes the running plan unsafe far enough ahead, schedule its stop
    /// where the stop still ends before the danger instead of stopping now, so a
    /// re-verified replacement joining it can take over without stopping
    /// ([`crate::twin_thread::plan_guard`]); off: stop at once.
    #[serde(default = "default_join_before_stopping")]
    pub join_before_stopping: bool,
    /// After a pause (a stop for an obstacle), plan the episode on from where the arm
    /// stopped, by the policies or the planner fallback, before going home along the
    /// executed path; off: always home first, then the episode again from its start.
    #[serde(default = "default_continue_after_pause")]
    pub continue_after_pause: bool,
    /// Plan from rest on the scene as it is now, also while perception sees something move
    /// (a frame not settled): each moving box counts as the volume it may sweep over
    /// `intake.prediction_horizon_s` (the reaction plus the stop), and every later frame
    /// re-verifies the plan as ever (issue 42 item 1). Off: plans only on settled scenes.
    #[serde(default = "default_plan_in_moving_world")]
    pub plan_in_moving_world: bool,
    /// After an episode reaches its goal, the arm rests `dwell_at_goal_s` and then returns
    /// to where the episode began along its own executed path, re-checked by the shield in
    /// the scene then in force. Every episode thus starts from the task's start posture,
    /// as in training (the research system's reset between episodes).
    #[serde(default = "runtime_view::default_return_home")]
    pub return_home: bool,
    /// Rest at the goal before returning home, s.
    #[serde(default = "default_dwell_at_goal_s")]
    pub dwell_at_goal_s: f64,
    /// Retrained policies rt-core may refuse for one scene (each judged from the task's
    /// start posture, as the learner trains) before the scene is "not learned" and no more
    /// retraining is asked for it (issue 40 item 2). Allowed: 1..=20.
    #[serde(default = "default_max_refused_retrainings")]
    pub max_refused_retrainings: u32,
    /// Motion limits.
    pub limits: MotionLimits,
    /// Shield.
    pub shield: ShieldConfig,
    /// Stale-input ages.
    pub stale: StaleConfig,
    /// What is accepted from perception.
    #[serde(default)]
    pub intake: IntakeConfig,
    /// The check that the arm follows its commands.
    #[serde(default)]
    pub tracking: TrackingConfig,
    /// The planner fallback (off by default).
    #[serde(default)]
    pub planner_fallback: PlannerFallbackConfig,
    /// Verified sampling before the planner fallback.
    #[serde(default)]
    pub sampling: SamplingConfig,
    /// Who may acknowledge a protective stop.
    #[serde(default)]
    pub operator: OperatorConfig,
    /// Where the goal comes from (the camera's goal cube, or the ROS 2 `Reach` action).
    #[serde(default)]
    pub goal: GoalConfig,
    /// Speed and separation monitoring (ISO/TS 15066), off by default.
    #[serde(default)]
    pub separation: SeparationConfig,
    /// The prediction horizon configured below its floor, s, when it was raised at load
    /// ([`RuntimeConfig::raise_horizon_to_floor`]); not a key of the file.
    #[serde(skip)]
    pub horizon_raised_from_s: Option<f64>,
}

/// Speed and separation monitoring after ISO/TS 15066 (`[separation]`): while an obstacle is
/// nearer than the protective separation distance `S_p(s) = v_h·(T_r + T_s(s)) + v_r(s)·T_r +
/// B(s) + C + Z`, the cycle plays the plan back at the largest speed scale `s ∈ [0, 1]` with
/// `S_p(s)` within the separation, rate-limited; at `s = 0` the arm stands on the plan and
/// goes on by itself once the separation allows (see [`crate::cycle::separation`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SeparationConfig {
    /// Scale the playback by separation (off: full speed up to the shield's clearance and the
    /// twin's revocation, as before).
    #[serde(default)]
    pub enabled: bool,
    /// v_h: the assumed speed of an intruder towards the arm, m/s.
    #[serde(default = "default_intruder_speed_m_s")]
    pub intruder_speed_m_s: f64,
    /// T_r: from an intruder's move to the cycle's reaction (camera frame, perception, the
    /// hand-over to the cycle, one period), s.
    #[serde(default = "default_separation_reaction_time_s")]
    pub reaction_time_s: f64,
    /// C: how far an intruder may reach towards the arm before it is detected, m.
    #[serde(default = "default_separation_intrusion_m")]
    pub intrusion_distance_m: f64,
    /// Z_d + Z_r: the position uncertainty of the detection and of the arm, m.
    #[serde(default = "default_separation_uncertainty_m")]
    pub position_uncertainty_m: f64,
}

impl Default for SeparationConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            intruder_speed_m_s: default_intruder_speed_m_s(),
            reaction_time_s: default_separation_reaction_time_s(),
            intrusion_distance_m: default_separation_intrusion_m(),
            position_uncertainty_m: default_separation_uncertainty_m(),
        }
    }
}

/// ISO/TS 15066's hand-arm speed, as `[intake]`'s default for an intruder of unknown velocity.
fn default_intruder_speed_m_s() -> f64 {
    IntakeConfig::default().intruder_speed_m_s
}
fn default_separation_reaction_time_s() -> f64 {
    0.1
}
fn default_separation_intrusion_m() -> f64 {
    0.02
}
fn default_separation_uncertainty_m() -> f64 {
    0.02
}

/// Who may acknowledge a protective stop (`[operator]`). The acknowledgement reaches
/// `rt-core run` only through its operator channel ([`crate::operator_ack`]), a Unix socket
/// beside the arm's lock whose peer's user id the kernel gives: it is accepted from rt-core's
/// own user, root, and the user ids listed here. Run rt-core under a service account of its
/// own and list the operators' accounts, so no other process of the operator's (and no
/// process of rt-core's) can clear a stop on their behalf.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorConfig {
    /// User ids allowed to acknowledge besides rt-core's own and root (at most
    /// [`bounds::MAX_OPERATOR_UIDS`]).
    #[serde(default)]
    pub ack_uids: Vec<u32>,
}

/// Verified sampling (`[sampling]`): when no policy's deterministic rollout passes the
/// lookahead, the twin rolls out `candidates − 1` perturbed variants of each policy of the
/// library (action noise, `twin::Sampler`) on `threads` threads within `budget_s`, verifies
/// each exactly as the deterministic rollout (then smoothing, the shield and the goal check
/// on the smoothed plan), and sends the best that passes — fewest steps, then the largest
/// clearance; only then the planner fallback and retraining.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingConfig {
    /// Sample when the deterministic rollouts fail (off by default: see `assets/runtime.toml`).
    #[serde(default = "default_sampling_enabled")]
    pub enabled: bool,
    /// K: candidates per policy, the deterministic rollout included; 2..=256.
    #[serde(default = "default_sampling_candidates")]
    pub candidates: usize,
    /// Wall time for the sampling of one planning (all policies), s; 0.005..=2. Each thread
    /// stops before its next candidate once it has passed.
    #[serde(default = "default_sampling_budget_s")]
    pub budget_s: f64,
    /// Standard deviation of the action noise, action units (the action range is [-1, 1],
    /// times the task's `action.scale_m`); 0..=2.
    #[serde(default = "default_sampling_noise_sigma")]
    pub noise_sigma: f64,
    /// Step-to-step correlation of the noise, 0 (white) ..< 1.
    #[serde(default = "default_sampling_noise_correlation")]
    pub noise_correlation: f64,
    /// Seed of the candidates' noise (the same scene and policy give the same candidates).
    #[serde(default)]
    pub seed: u64,
    /// Share of the perturbed candidates that start the goal approach at a random via point
    /// instead of with action noise; 0..=1.
    #[serde(default = "default_sampling_via_point_share")]
    pub via_point_share: f64,
    /// Threads the candidates run on; 1..=16.
    #[serde(default = "default_sampling_threads")]
    pub threads: usize,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        Self {
            enabled: default_sampling_enabled(),
            candidates: default_sampling_candidates(),
            budget_s: default_sampling_budget_s(),
            noise_sigma: default_sampling_noise_sigma(),
            noise_correlation: default_sampling_noise_correlation(),
            seed: 0,
            via_point_share: default_sampling_via_point_share(),
            threads: default_sampling_threads(),
        }
    }
}

impl SamplingConfig {
    /// The sampler's settings.
    pub fn settings(&self) -> twin::SamplingSettings {
        twin::SamplingSettings {
            candidates: self.candidates,
            noise_sigma: self.noise_sigma,
            noise_correlation: self.noise_correlation,
            seed: self.seed,
            via_point_share: self.via_point_share,
            threads: self.threads,
        }
    }

    fn validate(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        if !(2..=twin::MAX_SAMPLES).contains(&self.candidates) {
            return bad("sampling.candidates", "must be within 2..=256");
        }
        if !(self.budget_s.is_finite() && (0.005..=2.0).contains(&self.budget_s)) {
            return bad("sampling.budget_s", "must be within 0.005..=2 s");
        }
        match self.settings().validate() {
            Ok(()) => Ok(()),
            Err(("noise_sigma", why)) => bad("sampling.noise_sigma", why),
            Err(("noise_correlation", why)) => bad("sampling.noise_correlation", why),
            Err(("threads", why)) => bad("sampling.threads", why),
            Err(("via_point_share", why)) => bad("sampling.via_point_share", why),
            Err((_, why)) => bad("sampling.candidates", why),
        }
    }
}

fn default_sampling_enabled() -> bool {
    false
}
fn default_sampling_candidates() -> usize {
    32
}
fn default_sampling_budget_s() -> f64 {
    0.05
}
fn default_sampling_noise_sigma() -> f64 {
    twin::SamplingSettings::default().noise_sigma
}
fn default_sampling_noise_correlation() -> f64 {
    twin::SamplingSettings::default().noise_correlation
}
fn default_sampling_via_point_share() -> f64 {
    twin::SamplingSettings::default().via_point_share
}
fn default_sampling_threads() -> usize {
    2
}

/// The planner fallback: when no policy passes the lookahead, the twin's feasibility
/// planner's collision-free path moves the arm — smoothed, checked by the shield and for
/// reaching the goal like a policy's plan, re-verified on every scene change — while the
/// learner retrains. Off, the arm holds until a policy passes (the paper's pure-RL
/// behaviour).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerFallbackConfig {
    /// Use the planner's path when no policy passes.
    #[serde(default)]
    pub enabled: bool,
    /// Longest search per planning, s. Detections reach the cycle and the plan guard on the
    /// intake thread meanwhile (`twin_thread::intake_thread`), and a path found in a scene
    /// that has changed since is verified against the newest one before the cycle may take
    /// it (`twin_thread::plan_guard`), so the budget is bounded only by how long a user
    /// would wait for a first motion.
    #[serde(default = "default_planner_budget_s")]
    pub budget_s: f64,
}

impl Default for PlannerFallbackConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            budget_s: default_planner_budget_s(),
        }
    }
}

fn default_planner_budget_s() -> f64 {
    0.25
}

fn default_rate_hz() -> f64 {
    250.0
}
fn default_prefix() -> String {
    "foresight".into()
}
fn default_join_ahead_s() -> f64 {
    0.1
}
fn default_join_before_stopping() -> bool {
    true
}
fn default_continue_after_pause() -> bool {
    true
}
fn default_plan_in_moving_world() -> bool {
    true
}

fn default_dwell_at_goal_s() -> f64 {
    1.0
}

fn default_max_refused_retrainings() -> u32 {
    2
}

impl RuntimeConfig {
    /// Reads and validates a TOML file.
    ///
    /// # Errors
    /// [`RuntimeConfigError`] when unreadable, malformed or out of range.
    pub fn load(path: &Path) -> Result<Self, RuntimeConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| RuntimeConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml(&text)
    }

    /// Parses and validates TOML text.
    ///
    /// # Errors
    /// [`RuntimeConfigError`] when malformed or out of range.
    pub fn from_toml(text: &str) -> Result<Self, RuntimeConfigError> {
        let mut cfg: Self = toml::from_str(text)?;
        cfg.validate()?;
        cfg.raise_horizon_to_floor();
        Ok(cfg)
    }

    /// The shipped configuration, `assets/runtime.toml` (xArm5 limits, 250 Hz), compiled in:
    /// the defaults and the file cannot drift apart.
    ///
    /// # Panics
    /// Never for a released build: the shipped file is parsed and validated by this crate's
    /// tests (`the_shipped_config_is_the_default`).
    #[allow(clippy::expect_used)]
    pub fn xarm5_default() -> Self {
        Self::from_toml(SHIPPED_RUNTIME_TOML).expect("the shipped assets/runtime.toml is valid")
    }

    /// Where a requested goal (the `Reach` action) may lie: `[intake]`'s reach and
    /// calibrated area, `[shield]`'s workspace.
    pub fn goal_bounds(&self) -> shm_schemas::GoalBounds {
        runtime_view::goal_bounds(&self.intake, &self.shield)
    }

    /// The shortest prediction horizon a moving obstacle may be predicted over, s (issue 42
    /// item 5): from a frame's capture the arm must be able to react
    /// (`separation.reaction_time_s`: the frame, perception, the hand-over to the cycle) and
    /// then stop ([`longest_stop_s`]), and the cycle acts on its next period.
    /// A box predicted over less may reach the arm before the stop it caused has ended.
    pub fn prediction_floor_s(&self) -> f64 {
        self.separation.reaction_time_s + longest_stop_s(&self.limits) + 1.0 / self.rate_hz
    }

    /// Raises `intake.prediction_horizon_s` to [`RuntimeConfig::prediction_floor_s`] when
    /// configured below it (done at load: a moving box is never predicted over less than the
    /// reaction plus the stop), keeping what was asked for in
    /// [`RuntimeConfig::horizon_raised`].
    pub fn raise_horizon_to_floor(&mut self) {
        let floor_s = self.prediction_floor_s();
        let value_s = self.intake.prediction_horizon_s;
        if value_s < floor_s {
            self.horizon_raised_from_s = Some(value_s);
            self.intake.prediction_horizon_s = floor_s;
        }
    }

    /// When the prediction horizon was raised at load: what is said about it (the field,
    /// what was asked for and the floor it was raised to).
    pub fn horizon_raised(&self) -> Option<String> {
        self.horizon_raised_from_s.map(|asked_s| {
            format!(
                "intake.prediction_horizon_s = {asked_s} s is below its floor and was raised to \
                 {:.3} s: the reaction (separation.reaction_time_s) plus the longest stop from \
                 the velocity limits plus one period",
                self.intake.prediction_horizon_s
            )
        })
    }

    /// What plans are approved with (`twin::approval`): the cycle rate, `[limits]` and
    /// `[shield]` — what the learner reads from the same file.
    pub fn approval_settings(&self) -> twin::approval::ApprovalSettings {
        twin::approval::ApprovalSettings {
            rate_hz: self.rate_hz,
            limits: self.limits,
            shield: self.shield,
        }
    }

    /// The cycle period in nanoseconds.
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }

    /// Checks every range.
    ///
    /// # Errors
    /// [`RuntimeConfigError::Invalid`] naming the first bad field.
    pub fn validate(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        if !(self.rate_hz.is_finite() && (1.0..=1000.0).contains(&self.rate_hz)) {
            return bad("rate_hz", "must be within 1..=1000");
        }
        if self.service_prefix.is_empty()
            || !self
                .service_prefix
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
        {
            return bad("service_prefix", "must be non-empty ASCII [A-Za-z0-9_-./]");
        }
        if !(self.join_ahead_s.is_finite() && self.join_ahead_s >= 0.0 && self.join_ahead_s < 5.0) {
            return bad("join_ahead_s", "must be within 0..5 s");
        }
        if !(self.dwell_at_goal_s.is_finite() && (0.0..=60.0).contains(&self.dwell_at_goal_s)) {
            return bad("dwell_at_goal_s", "must be within 0..=60 s");
        }
        if !(1..=20).contains(&self.max_refused_retrainings) {
            return bad("max_refused_retrainings", "must be within 1..=20");
        }
        let budget_s = self.planner_fallback.budget_s;
        if !(budget_s.is_finite() && (0.05..=10.0).contains(&budget_s)) {
            return bad("planner_fallback.budget_s", "must be within 0.05..=10 s");
        }
        self.sampling.validate()?;
        self.validate_limits()?;
        self.validate_shield()?;
        let period_s = 1.0 / self.rate_hz;
        let st = &self.stale;
        if !(st.max_detection_age_s.is_finite()
            && st.max_detection_age_s > period_s
            && st.max_detection_age_s <= bounds::MAX_DETECTION_AGE_S)
        {
            return bad(
                "stale.max_detection_age_s",
                "must exceed one cycle period and be at most 1 s",
            );
        }
        if !(st.max_robot_state_age_s.is_finite()
            && st.max_robot_state_age_s > period_s
            && st.max_robot_state_age_s <= bounds::MAX_ROBOT_STATE_AGE_S)
        {
            return bad(
                "stale.max_robot_state_age_s",
                "must exceed one cycle period and be at most 0.2 s",
            );
        }
        self.validate_intake()?;
        self.validate_tracking()?;
        self.validate_operator()?;
        self.validate_separation()
    }

    fn validate_separation(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let s = &self.separation;
        let (lo, hi) = bounds::SEPARATION_INTRUDER_SPEED_RANGE_M_S;
        if !(s.intruder_speed_m_s.is_finite() && (lo..=hi).contains(&s.intruder_speed_m_s)) {
            return bad(
                "separation.intruder_speed_m_s",
                "must be within 0.5..=5 m/s",
            );
        }
        let period_s = 1.0 / self.rate_hz;
        if !(s.reaction_time_s.is_finite()
            && s.reaction_time_s >= period_s
            && s.reaction_time_s <= bounds::SEPARATION_MAX_REACTION_TIME_S)
        {
            return bad(
                "separation.reaction_time_s",
                "must be at least one cycle period and at most 1 s",
            );
        }
        if !(s.intrusion_distance_m.is_finite()
            && (0.0..=bounds::SEPARATION_MAX_INTRUSION_M).contains(&s.intrusion_distance_m))
        {
            return bad(
                "separation.intrusion_distance_m",
                "must be within 0..=0.85 m",
            );
        }
        if !(s.position_uncertainty_m.is_finite()
            && (0.0..=bounds::SEPARATION_MAX_UNCERTAINTY_M).contains(&s.position_uncertainty_m))
        {
            return bad(
                "separation.position_uncertainty_m",
                "must be within 0..=0.2 m",
            );
        }
        Ok(())
    }

    fn validate_operator(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let uids = &self.operator.ack_uids;
        if uids.len() > bounds::MAX_OPERATOR_UIDS {
            return bad("operator.ack_uids", "lists at most 16 user ids");
        }
        // uid_t's (u32) -1 is "no user" to the kernel (chown's "leave as is").
        if uids.contains(&u32::MAX) {
            return bad("operator.ack_uids", "4294967295 (-1) is no user");
        }
        Ok(())
    }

    fn validate_tracking(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let t = &self.tracking;
        let (lo, hi) = bounds::TRACKING_ERROR_RANGE_RAD;
        if !(t.max_error_rad.is_finite() && (lo..=hi).contains(&t.max_error_rad)) {
            return bad("tracking.max_error_rad", "must be within 0.01..=0.5 rad");
        }
        let (lo, hi) = bounds::TRACKING_CYCLES_RANGE;
        if !(lo..=hi).contains(&t.max_error_cycles) {
            return bad("tracking.max_error_cycles", "must be within 1..=1000");
        }
        Ok(())
    }

    fn validate_limits(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let within = |v: &[f64], max: f64| v.iter().all(|x| x.is_finite() && *x > 0.0 && *x <= max);
        let l = &self.limits;
        if !within(&l.max_velocity_rad_s, bounds::SDK_MAX_JOINT_VELOCITY_RAD_S) {
            return bad(
                "limits.max_velocity_rad_s",
                "must be > 0 and at most the SDK's pi rad/s",
            );
        }
        if !within(
            &l.max_acceleration_rad_s2,
            bounds::SDK_MAX_JOINT_ACCELERATION_RAD_S2,
        ) {
            return bad(
                "limits.max_acceleration_rad_s2",
                "must be > 0 and at most the SDK's 20 rad/s^2",
            );
        }
        if !within(&l.max_jerk_rad_s3, bounds::SDK_MAX_JOINT_JERK_RAD_S3) {
            return bad(
                "limits.max_jerk_rad_s3",
                "must be > 0 and at most 500 rad/s^3",
            );
        }
        if l.joint_min_rad
            .iter()
            .zip(&l.joint_max_rad)
            .any(|(a, b)| !(a.is_finite() && b.is_finite() && a < b))
        {
            return bad(
                "limits.joint_min_rad",
                "must be finite and below joint_max_rad",
            );
        }
        if !(l.max_tcp_speed_m_s.is_finite()
            && l.max_tcp_speed_m_s > 0.0
            && l.max_tcp_speed_m_s < 1.0)
        {
            return bad("limits.max_tcp_speed_m_s", "must be within (0, 1) m/s");
        }
        Ok(())
    }

    fn validate_shield(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let s = &self.shield;
        if !box_within_reach(&s.workspace_min_m, &s.workspace_max_m) {
            return bad(
                "shield.workspace_min_m",
                "must be finite, below workspace_max_m and within reach (|x|, |y| <= 0.8 m, z in -0.1..=1.1 m)",
            );
        }
        if !(s.min_distance_m.is_finite()
            && (bounds::MIN_CLEARANCE_FLOOR_M..=bounds::MAX_CLEARANCE_M)
                .contains(&s.min_distance_m))
        {
            return bad("shield.min_distance_m", "must be within 0.005..=0.2 m");
        }
        if !(s.joint_margin_rad.is_finite()
            && (0.0..=bounds::MAX_JOINT_MARGIN_RAD).contains(&s.joint_margin_rad))
        {
            return bad("shield.joint_margin_rad", "must be within 0..=0.5 rad");
        }
        let (lo, hi) = bounds::TCP_GAP_RANGE_M;
        if !(s.max_tcp_gap_m.is_finite() && (lo..=hi).contains(&s.max_tcp_gap_m)) {
            return bad("shield.max_tcp_gap_m", "must be within 0.001..=0.02 m");
        }
        Ok(())
    }

    fn validate_intake(&self) -> Result<(), RuntimeConfigError> {
        let bad = |field, why| Err(RuntimeConfigError::Invalid { field, why });
        let i = &self.intake;
        if !(i.min_goal_confidence.is_finite()
            && (bounds::MIN_GOAL_CONFIDENCE_FLOOR..=1.0).contains(&i.min_goal_confidence))
        {
            return bad("intake.min_goal_confidence", "must be within 0.05..=1");
        }
        if !box_within_reach(&i.calibrated_min_m, &i.calibrated_max_m) {
            return bad(
                "intake.calibrated_min_m",
                "must be finite, below calibrated_max_m and within reach (|x|, |y| <= 0.8 m, z in -0.1..=1.1 m)",
            );
        }
        if !(i.goal_min_radius_m.is_finite() && (0.0..=0.5).contains(&i.goal_min_radius_m)) {
            return bad("intake.goal_min_radius_m", "must be within 0..=0.5 m");
        }
        if !(i.goal_max_radius_m.is_finite()
            && i.goal_max_radius_m > i.goal_min_radius_m
            && i.goal_max_radius_m <= 0.7)
        {
            return bad(
                "intake.goal_max_radius_m",
                "must exceed goal_min_radius_m and be at most the xArm5's reach, 0.7 m",
            );
        }
        // Within 0..=1 s as configured; a horizon raised to its floor at load may lie above.
        let max_horizon_s = self.prediction_floor_s().max(1.0);
        if !(i.prediction_horizon_s.is_finite()
            && (0.0..=max_horizon_s).contains(&i.prediction_horizon_s))
        {
            return bad("intake.prediction_horizon_s", "must be within 0..=1 s");
        }
        if !(i.uncertainty_sigmas.is_finite() && (0.0..=5.0).contains(&i.uncertainty_sigmas)) {
            return bad("intake.uncertainty_sigmas", "must be within 0..=5");
        }
        if !(i.intruder_speed_m_s.is_finite() && (0.1..=5.0).contains(&i.intruder_speed_m_s)) {
            return bad("intake.intruder_speed_m_s", "must be within 0.1..=5 m/s");
        }
        Ok(())
    }

    /// Checks the parts that depend on the link: the xArm controller takes at most one
    /// servo target per 4 ms, and at least one per 10 ms
    /// ([`bounds::XARM_MIN_RATE_HZ`]..=[`bounds::XARM_MAX_RATE_HZ`]).
    ///
    /// # Errors
    /// [`RuntimeConfigError::Invalid`] naming `rate_hz`.
    pub fn check_for_xarm_link(&self) -> Result<(), RuntimeConfigError> {
        if self.rate_hz > bounds::XARM_MAX_RATE_HZ {
            return Err(RuntimeConfigError::Invalid {
                field: "rate_hz",
                why: "must be at most 250 Hz on the xArm link (the controller's servo-mode maximum)",
            });
        }
        if self.rate_hz < bounds::XARM_MIN_RATE_HZ {
            return Err(RuntimeConfigError::Invalid {
                field: "rate_hz",
                why: "must be at least 100 Hz on the xArm link (a slower servo stream sends \
                      larger jumps per target)",
            });
        }
        // Issue 30 item 5: one target's step at the configured speed must be one the
        // controller executes within its own servo period at its joint speed limit.
        let max_step_rad = bounds::SDK_MAX_JOINT_VELOCITY_RAD_S * bounds::XARM_SERVO_PERIOD_S;
        if self
            .limits
            .max_velocity_rad_s
            .iter()
            .any(|v| v / self.rate_hz > max_step_rad + 1e-12)
        {
            return Err(RuntimeConfigError::Invalid {
                field: "limits.max_velocity_rad_s",
                why: "with rate_hz, one servo target's step (max_velocity_rad_s / rate_hz) must be \
                      at most what the controller executes in its 4 ms servo period at its joint \
                      speed limit (pi rad/s x 4 ms = 12.6 mrad): lower limits.max_velocity_rad_s \
                      or raise rate_hz",
            });
        }
        Ok(())
    }

    /// Checks the joint limits against the robot model (URDF): every configured joint range
    /// lies within the URDF's (1 mrad of rounding allowed), and every joint velocity is at
    /// most the URDF's.
    ///
    /// # Errors
    /// [`RuntimeConfigError::Invalid`] naming the field.
    pub fn check_against_model(&self, model: &twin::RobotModel) -> Result<(), RuntimeConfigError> {
        let l = &self.limits;
        let urdf = model.limits();
        for j in 0..l.joint_min_rad.len() {
            if l.joint_min_rad[j] < urdf.lower_rad[j] - 1e-3 {
                return Err(RuntimeConfigError::Invalid {
                    field: "limits.joint_min_rad",
                    why: "must lie within the URDF's joint limits",
                });
            }
            if l.joint_max_rad[j] > urdf.upper_rad[j] + 1e-3 {
                return Err(RuntimeConfigError::Invalid {
                    field: "limits.joint_max_rad",
                    why: "must lie within the URDF's joint limits",
                });
            }
        }
        if l.max_velocity_rad_s
            .iter()
            .zip(&urdf.velocity_rad_s)
            .any(|(v, u)| *v > *u + 1e-9)
        {
            return Err(RuntimeConfigError::Invalid {
                field: "limits.max_velocity_rad_s",
                why: "must be at most the URDF's joint velocity limits",
            });
        }
        Ok(())
    }
}

/// A box given by two corners is finite, ordered and within [`bounds::REACH_BOUND_M`].
fn box_within_reach(min_m: &[f64; 3], max_m: &[f64; 3]) -> bool {
    let finite_ordered = min_m
        .iter()
        .zip(max_m)
        .all(|(a, b)| a.is_finite() && b.is_finite() && a < b);
    finite_ordered
        && min_m[..2]
            .iter()
            .chain(&max_m[..2])
            .all(|v| v.abs() <= bounds::REACH_BOUND_M)
        && min_m[2] >= bounds::WORKSPACE_MIN_Z_M
        && max_m[2] <= bounds::WORKSPACE_MAX_Z_M
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `[shield] max_tcp_gap_m`'s default (defined with the shared view, which cannot name
    /// rt-core) is the xArm adapter's gap.
    #[test]
    fn the_default_tcp_gap_is_the_xarm_links() {
        assert_eq!(
            shm_schemas::runtime_view::DEFAULT_MAX_TCP_GAP_M,
            crate::cycle::xarm_link::MAX_TCP_GAP_M
        );
    }

    const ASSET: &str = include_str!("../../assets/runtime.toml");

    /// Replaces the value of `key = …` on its line in the shipped TOML.
    fn with_value(key: &str, value: &str) -> String {
        let mut found = false;
        let text: Vec<String> = ASSET
            .lines()
            .map(|l| {
                if l.trim_start().starts_with(&format!("{key} =")) {
                    found = true;
                    format!("{key} = {value}")
                } else {
                    l.to_owned()
                }
            })
            .collect();
        assert!(found, "{key} not in runtime.toml");
        text.join("\n")
    }

    /// `[sampling]`'s `budget_s` set to `value` (the planner fallback's left as shipped).
    fn with_sampling_budget(value: &str) -> String {
        let (head, tail) = ASSET.split_once("[sampling]").unwrap();
        let tail = tail.replacen("budget_s = 0.05", &format!("budget_s = {value}"), 1);
        format!("{head}[sampling]{tail}")
    }

    #[test]
    fn the_sampling_budget_is_bounded_by_name() {
        for value in ["0.0", "nan", "3.0"] {
            match RuntimeConfig::from_toml(&with_sampling_budget(value)) {
                Err(RuntimeConfigError::Invalid { field, .. }) => {
                    assert_eq!(field, "sampling.budget_s");
                }
                other => panic!("budget_s = {value}: got {other:?}"),
            }
        }
        let cfg = RuntimeConfig::from_toml(&with_sampling_budget("0.2")).unwrap();
        assert_eq!(cfg.sampling.budget_s, 0.2);
        assert_eq!(cfg.planner_fallback.budget_s, 0.25);
        // The shipped section is the defaults (a file without it samples the same way).
        assert_eq!(
            RuntimeConfig::xarm5_default().sampling,
            SamplingConfig::default()
        );
    }

    #[test]
    fn the_shipped_config_is_the_default() {
        assert_eq!(
            RuntimeConfig::xarm5_default(),
            RuntimeConfig::from_toml(ASSET).unwrap()
        );
    }

    /// The learner reads the approval settings from the same file with the twin's reader:
    /// both readings of a configuration agree (the shipped one, and one with other values).
    #[test]
    fn the_learner_reads_the_approval_settings_rt_core_uses() {
        let cfg = RuntimeConfig::from_toml(ASSET).unwrap();
        let twin_side = twin::approval::ApprovalSettings::from_runtime_toml(ASSET).unwrap();
        assert_eq!(cfg.approval_settings(), twin_side);
        let other = ASSET
            .replace("rate_hz = 250.0", "rate_hz = 200.0")
            .replace("min_distance_m = 0.01", "min_distance_m = 0.02");
        let cfg = RuntimeConfig::from_toml(&other).unwrap();
        assert_eq!(cfg.rate_hz, 200.0);
        assert_eq!(cfg.shield.min_distance_m, 0.02);
        let twin_side = twin::approval::ApprovalSettings::from_runtime_toml(&other).unwrap();
        assert_eq!(cfg.approval_settings(), twin_side);
    }

    #[test]
    fn the_shipped_config_and_the_defaults_load() {
        let cfg = RuntimeConfig::from_toml(ASSET).unwrap();
        assert_eq!(cfg.rate_hz, 250.0);
        assert_eq!(cfg.period_ns(), 4_000_000);
        assert!(cfg.limits.max_tcp_speed_m_s < 1.0);
        RuntimeConfig::xarm5_default().validate().unwrap();
    }

    #[test]
    fn out_of_range_values_are_refused_by_name() {
        let cases = [
            ("rate_hz", "5000.0", "rate_hz"),
            ("max_tcp_speed_m_s", "1.2", "limits.max_tcp_speed_m_s"),
            (
                "max_robot_state_age_s",
                "0.001",
                "stale.max_robot_state_age_s",
            ),
            ("min_distance_m", "-1.0", "shield.min_distance_m"),
            ("dwell_at_goal_s", "-0.5", "dwell_at_goal_s"),
            ("budget_s", "0.0", "planner_fallback.budget_s"),
            ("budget_s", "nan", "planner_fallback.budget_s"),
            ("budget_s", "11.0", "planner_fallback.budget_s"),
            ("candidates", "1", "sampling.candidates"),
            ("candidates", "257", "sampling.candidates"),
            ("noise_sigma", "-0.1", "sampling.noise_sigma"),
            ("noise_correlation", "1.0", "sampling.noise_correlation"),
            ("threads", "0", "sampling.threads"),
            ("via_point_share", "2.0", "sampling.via_point_share"),
            (
                "max_jerk_rad_s3",
                "[40.0, 40.0, 0.0, 40.0, 40.0]",
                "limits.max_jerk_rad_s3",
            ),
            // Issue 14's limits without bounds: each of these loaded and ran.
            ("max_detection_age_s", "1e9", "stale.max_detection_age_s"),
            (
                "max_velocity_rad_s",
                "[100.0, 1.0, 1.0, 1.0, 1.0]",
                "limits.max_velocity_rad_s",
            ),
            ("min_distance_m", "0.0", "shield.min_distance_m"),
            (
                "workspace_min_m",
                "[-1000.0, -1000.0, 0.0]",
                "shield.workspace_min_m",
            ),
            (
                "workspace_max_m",
                "[1000.0, 1000.0, 1000.0]",
                "shield.workspace_min_m",
            ),
            (
                "max_robot_state_age_s",
                "5.0",
                "stale.max_robot_state_age_s",
            ),
            (
                "max_acceleration_rad_s2",
                "[400.0, 4.0, 4.0, 4.0, 4.0]",
                "limits.max_acceleration_rad_s2",
            ),
            ("joint_margin_rad", "3.0", "shield.joint_margin_rad"),
            ("min_goal_confidence", "0.0", "intake.min_goal_confidence"),
            (
                "calibrated_max_m",
                "[5.0, 0.8, 1.0]",
                "intake.calibrated_min_m",
            ),
            ("goal_max_radius_m", "3.0", "intake.goal_max_radius_m"),
            (
                "prediction_horizon_s",
                "-0.1",
                "intake.prediction_horizon_s",
            ),
            ("prediction_horizon_s", "nan", "intake.prediction_horizon_s"),
            ("prediction_horizon_s", "2.0", "intake.prediction_horizon_s"),
            ("uncertainty_sigmas", "9.0", "intake.uncertainty_sigmas"),
            ("intruder_speed_m_s", "0.0", "intake.intruder_speed_m_s"),
            ("max_tcp_gap_m", "0.5", "shield.max_tcp_gap_m"),
        ];
        for (key, value, field) in cases {
            match RuntimeConfig::from_toml(&with_value(key, value)) {
                Err(RuntimeConfigError::Invalid { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{key} = {value}: expected Invalid({field}), got {other:?}"),
            }
        }
    }

    /// Issue 42 item 5: the prediction horizon is never below the reaction time plus the
    /// longest stop (plus a period): the old default 0.25 s, and 0 s, are raised to that
    /// floor at load, and it is said (naming the field and the floor); the shipped horizon
    /// covers it as it is.
    #[test]
    fn a_prediction_horizon_below_reaction_plus_stop_is_raised_to_its_floor_and_said() {
        let shipped = RuntimeConfig::xarm5_default();
        let floor_s = shipped.prediction_floor_s();
        // 0.1 s reaction, the path stop 1.5·1/(0.8·4) = 0.469 s, one 4 ms period.
        assert!((floor_s - 0.57275).abs() < 1e-9, "{floor_s}");
        assert!(shipped.intake.prediction_horizon_s >= floor_s);
        assert_eq!(shipped.horizon_raised(), None);
        for value in ["0.0", "0.25", "0.5"] {
            let cfg = RuntimeConfig::from_toml(&with_value("prediction_horizon_s", value)).unwrap();
            assert_eq!(cfg.intake.prediction_horizon_s, floor_s, "{value}");
            let said = cfg.horizon_raised().unwrap();
            assert!(said.contains("intake.prediction_horizon_s"), "{said}");
            assert!(said.contains("0.573"), "{said}");
        }
        // A slower reaction raises the floor with it.
        let text = ASSET.replace("reaction_time_s = 0.1", "reaction_time_s = 0.2");
        let cfg = RuntimeConfig::from_toml(&text).unwrap();
        assert!((cfg.intake.prediction_horizon_s - (floor_s + 0.1)).abs() < 1e-9);
        // Faster joints: a floor above the 1 s bound of the configured value, still loaded.
        let fast = with_value("max_velocity_rad_s", "[3.1415, 1.0, 1.0, 1.0, 1.0]");
        let cfg = RuntimeConfig::from_toml(&fast).unwrap();
        assert!(cfg.intake.prediction_horizon_s > 1.0);
        cfg.validate().unwrap();
    }

    #[test]
    fn the_xarm_link_takes_at_most_250_hz() {
        let cfg = RuntimeConfig::from_toml(&with_value("rate_hz", "500.0")).unwrap();
        match cfg.check_for_xarm_link() {
            Err(RuntimeConfigError::Invalid { field, .. }) => assert_eq!(field, "rate_hz"),
            other => panic!("expected Invalid(rate_hz), got {other:?}"),
        }
        // Issue 25 item 13: and at least 100 Hz (25 Hz passed the general 1..=1000 bound).
        for slow in ["25.0", "50.0", "99.9"] {
            let cfg = RuntimeConfig::from_toml(&with_value("rate_hz", slow)).unwrap();
            match cfg.check_for_xarm_link() {
                Err(e @ RuntimeConfigError::Invalid { field, .. }) => {
                    assert_eq!(field, "rate_hz");
                    assert!(e.to_string().contains("at least 100 Hz"), "{e}");
                }
                other => panic!("rate_hz = {slow}: expected Invalid(rate_hz), got {other:?}"),
            }
        }
        RuntimeConfig::from_toml(&with_value("rate_hz", "100.0"))
            .unwrap()
            .check_for_xarm_link()
            .unwrap();
        // Issue 30 item 5: 100 Hz with 1.5 rad/s asks for 15 mrad per target, more than the
        // controller executes in its 4 ms servo period (12.6 mrad at its speed limit).
        let fast = with_value("rate_hz", "100.0").replace(
            "max_velocity_rad_s = [1.0, 1.0, 1.0, 1.0, 1.0]",
            "max_velocity_rad_s = [1.0, 1.5, 1.0, 1.0, 1.0]",
        );
        match RuntimeConfig::from_toml(&fast)
            .unwrap()
            .check_for_xarm_link()
        {
            Err(e @ RuntimeConfigError::Invalid { field, .. }) => {
                assert_eq!(field, "limits.max_velocity_rad_s");
                assert!(e.to_string().contains("rate_hz"), "{e}");
            }
            other => panic!("expected Invalid(limits.max_velocity_rad_s), got {other:?}"),
        }
        let fast_at_250 = fast.replace("rate_hz = 100.0", "rate_hz = 250.0");
        RuntimeConfig::from_toml(&fast_at_250)
            .unwrap()
            .check_for_xarm_link()
            .unwrap();
        RuntimeConfig::xarm5_default()
            .check_for_xarm_link()
            .unwrap();
    }

    #[test]
    fn joint_limits_are_checked_against_the_urdf() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/xarm5.urdf");
        let model = twin::RobotModel::load(std::path::Path::new(urdf)).unwrap();
        RuntimeConfig::xarm5_default()
            .check_against_model(&model)
            .unwrap();
        let cases = [
            (
                "joint_max_rad",
                "[6.283, 2.094, 1.5, 3.141, 6.283]",
                "limits.joint_max_rad",
            ),
            (
                "joint_min_rad",
                "[-6.283, -2.5, -3.927, -1.693, -6.283]",
                "limits.joint_min_rad",
            ),
        ];
        for (key, value, field) in cases {
            let cfg = RuntimeConfig::from_toml(&with_value(key, value)).unwrap();
            match cfg.check_against_model(&model) {
                Err(RuntimeConfigError::Invalid { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{key} = {value}: expected Invalid({field}), got {other:?}"),
            }
        }
        // Velocity above the URDF's 3.14 rad/s but within the SDK's pi: refused by the model.
        let cfg = RuntimeConfig::from_toml(&with_value(
            "max_velocity_rad_s",
            "[3.1415, 1.0, 1.0, 1.0, 1.0]",
        ))
        .unwrap();
        assert!(matches!(
            cfg.check_against_model(&model),
            Err(RuntimeConfigError::Invalid {
                field: "limits.max_velocity_rad_s",
                ..
            })
        ));
    }

    #[test]
    fn tracking_bounds_name_the_field() {
        let d = RuntimeConfig::xarm5_default();
        assert_eq!(d.tracking, TrackingConfig::default());
        for (key, value, field) in [
            ("max_error_rad", "0.001", "tracking.max_error_rad"),
            ("max_error_rad", "nan", "tracking.max_error_rad"),
            ("max_error_rad", "inf", "tracking.max_error_rad"),
            ("max_error_rad", "-0.1", "tracking.max_error_rad"),
            ("max_error_cycles", "0", "tracking.max_error_cycles"),
            ("max_error_cycles", "5000", "tracking.max_error_cycles"),
        ] {
            match RuntimeConfig::from_toml(&with_value(key, value)) {
                Err(RuntimeConfigError::Invalid { field: f, .. }) => {
                    assert_eq!(f, field, "{key} = {value}");
                }
                other => panic!("{key} = {value}: expected Invalid({field}), got {other:?}"),
            }
        }
        // A file without the section takes the defaults.
        let without = ASSET.split("[tracking]").next().unwrap();
        assert_eq!(
            RuntimeConfig::from_toml(without).unwrap().tracking,
            TrackingConfig::default()
        );
    }

    #[test]
    fn operator_uids_are_bounded_and_named() {
        assert!(RuntimeConfig::xarm5_default().operator.ack_uids.is_empty());
        let with = |list: &str| format!("{ASSET}\n[operator]\nack_uids = {list}\n");
        let ok = RuntimeConfig::from_toml(&with("[1000, 1001]")).unwrap();
        assert_eq!(ok.operator.ack_uids, vec![1000, 1001]);
        let many = format!(
            "[{}]",
            (1000..1017)
                .map(|u| u.to_string())
                .collect::<Vec<_>>()
                .join(",")
        );
        for list in [many.as_str(), "[4294967295]"] {
            match RuntimeConfig::from_toml(&with(list)) {
                Err(RuntimeConfigError::Invalid { field, .. }) => {
                    assert_eq!(field, "operator.ack_uids", "{list}");
                }
                other => panic!("{list}: expected Invalid(operator.ack_uids), got {other:?}"),
            }
        }
    }

    /// Issue 32 item 1: the goal's source is explicit, `camera` by default, and anything
    /// but `camera` or `action` is refused naming the field.
    #[test]
    fn the_goal_source_is_camera_or_action_and_nothing_else() {
        assert_eq!(
            RuntimeConfig::xarm5_default().goal.source,
            GoalSource::Camera
        );
        let with = |v: &str| ASSET.replace("source = \"camera\"", &format!("source = {v}"));
        let cfg = RuntimeConfig::from_toml(&with("\"action\"")).unwrap();
        assert_eq!(cfg.goal.source, GoalSource::Action);
        assert_eq!(cfg.goal.source.name(), "action");
        match RuntimeConfig::from_toml(&with("\"both\"")) {
            Err(RuntimeConfigError::Parse(e)) => {
                let text = e.to_string();
                assert!(text.contains("source") && text.contains("camera"), "{text}");
            }
            other => panic!("expected a parse error naming goal.source, got {other:?}"),
        }
    }

    /// `[separation]`: off and at ISO/TS 15066's defaults when absent; each bound refuses a
    /// bad value naming the field.
    #[test]
    fn separation_bounds_name_the_field() {
        let shipped = RuntimeConfig::xarm5_default().separation;
        assert!(!shipped.enabled);
        assert_eq!(shipped.intruder_speed_m_s, 1.6);
        let without = ASSET.split("[separation]").next().unwrap();
        assert_eq!(
            RuntimeConfig::from_toml(without).unwrap().separation,
            SeparationConfig::default()
        );
        // The keys of `[separation]` only (`intruder_speed_m_s` is also an `[intake]` key).
        let with = |key: &str, value: &str| {
            let (head, tail) = ASSET.split_once("[separation]").unwrap();
            let line = tail
                .lines()
                .find(|l| l.starts_with(&format!("{key} =")))
                .unwrap();
            format!(
                "{head}[separation]{}",
                tail.replacen(line, &format!("{key} = {value}"), 1)
            )
        };
        let on = RuntimeConfig::from_toml(&with("enabled", "true")).unwrap();
        assert!(on.separation.enabled);
        for (key, value, field) in [
            ("intruder_speed_m_s", "0.1", "separation.intruder_speed_m_s"),
            ("intruder_speed_m_s", "nan", "separation.intruder_speed_m_s"),
            ("reaction_time_s", "0.001", "separation.reaction_time_s"),
            ("reaction_time_s", "2.0", "separation.reaction_time_s"),
            (
                "intrusion_distance_m",
                "-0.01",
                "separation.intrusion_distance_m",
            ),
            (
                "intrusion_distance_m",
                "inf",
                "separation.intrusion_distance_m",
            ),
            (
                "position_uncertainty_m",
                "0.5",
                "separation.position_uncertainty_m",
            ),
        ] {
            match RuntimeConfig::from_toml(&with(key, value)) {
                Err(RuntimeConfigError::Invalid { field: f, .. }) => {
                    assert_eq!(f, field, "{key} = {value}");
                }
                other => panic!("{key} = {value}: expected Invalid({field}), got {other:?}"),
            }
        }
    }

    #[test]
    fn unknown_keys_are_refused() {
        let text = format!("{ASSET}\nbogus = 1\n");
        assert!(matches!(
            RuntimeConfig::from_toml(&text),
            Err(RuntimeConfigError::Parse(_))
        ));
    }
}
