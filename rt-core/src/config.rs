//! The runtime's configuration (`assets/runtime.toml`): cycle rate, the arm's motion limits,
//! the shield's limits and margins, stale-input ages and the iceoryx2 service prefix. Loaded
//! with serde and validated once at load; the cycle then uses plain `Copy` values.

use std::path::Path;

use serde::Deserialize;

use twin::Joints;

/// The shipped `assets/runtime.toml`.
pub const SHIPPED_RUNTIME_TOML: &str = include_str!("../../assets/runtime.toml");

/// Why a runtime configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeConfigError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML did not parse into the expected shape.
    #[error("invalid runtime config: {0}")]
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

/// Motion limits of the arm, per joint.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionLimits {
    /// Maximum joint velocity, rad/s.
    pub max_velocity_rad_s: Joints,
    /// Maximum joint acceleration, rad/s².
    pub max_acceleration_rad_s2: Joints,
    /// Maximum joint jerk, rad/s³.
    pub max_jerk_rad_s3: Joints,
    /// Lower joint limits, rad.
    pub joint_min_rad: Joints,
    /// Upper joint limits, rad.
    pub joint_max_rad: Joints,
    /// Maximum TCP speed, m/s (the xArm controller faults at 1 m/s in servo mode).
    pub max_tcp_speed_m_s: f64,
}

/// Shield limits and margins.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShieldConfig {
    /// Workspace box of the TCP, lower corner in the base frame, m.
    pub workspace_min_m: [f64; 3],
    /// Workspace box of the TCP, upper corner, m.
    pub workspace_max_m: [f64; 3],
    /// Minimum allowed distance robot ↔ obstacles in the live scene, m.
    pub min_distance_m: f64,
    /// Margin kept from the joint limits, rad.
    pub joint_margin_rad: f64,
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
    /// After an episode reaches its goal, the arm rests `dwell_at_goal_s` and then returns
    /// to where the episode began along its own executed path, re-checked by the shield in
    /// the scene then in force. Every episode thus starts from the task's start posture,
    /// as in training (the research system's reset between episodes).
    #[serde(default = "default_return_home")]
    pub return_home: bool,
    /// Rest at the goal before returning home, s.
    #[serde(default = "default_dwell_at_goal_s")]
    pub dwell_at_goal_s: f64,
    /// Motion limits.
    pub limits: MotionLimits,
    /// Shield.
    pub shield: ShieldConfig,
    /// Stale-input ages.
    pub stale: StaleConfig,
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

fn default_return_home() -> bool {
    true
}
fn default_dwell_at_goal_s() -> f64 {
    1.0
}

fn finite_pos(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite() && *x > 0.0)
}

impl RuntimeConfig {
    /// Reads and validates a TOML file.
    ///
    /// # Errors
    /// [`RuntimeConfigError`] when unreadable, malformed or out of range.
    pub fn load(path: &Path) -> Result<Self, RuntimeConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| RuntimeConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml(&text)
    }

    /// Parses and validates TOML text.
    ///
    /// # Errors
    /// [`RuntimeConfigError`] when malformed or out of range.
    pub fn from_toml(text: &str) -> Result<Self, RuntimeConfigError> {
        let cfg: Self = toml::from_str(text)?;
        cfg.validate()?;
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
        let l = &self.limits;
        if !finite_pos(&l.max_velocity_rad_s) {
            return bad("limits.max_velocity_rad_s", "must be finite and > 0");
        }
        if !finite_pos(&l.max_acceleration_rad_s2) {
            return bad("limits.max_acceleration_rad_s2", "must be finite and > 0");
        }
        if !finite_pos(&l.max_jerk_rad_s3) {
            return bad("limits.max_jerk_rad_s3", "must be finite and > 0");
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
        let s = &self.shield;
        if s.workspace_min_m
            .iter()
            .zip(&s.workspace_max_m)
            .any(|(a, b)| !(a.is_finite() && b.is_finite() && a < b))
        {
            return bad(
                "shield.workspace_min_m",
                "must be finite and below workspace_max_m",
            );
        }
        if !(s.min_distance_m.is_finite() && s.min_distance_m >= 0.0) {
            return bad("shield.min_distance_m", "must be finite and >= 0");
        }
        if !(s.joint_margin_rad.is_finite() && s.joint_margin_rad >= 0.0) {
            return bad("shield.joint_margin_rad", "must be finite and >= 0");
        }
        let period_s = 1.0 / self.rate_hz;
        let st = &self.stale;
        if !(st.max_detection_age_s.is_finite() && st.max_detection_age_s > period_s) {
            return bad("stale.max_detection_age_s", "must exceed one cycle period");
        }
        if !(st.max_robot_state_age_s.is_finite() && st.max_robot_state_age_s > period_s) {
            return bad(
                "stale.max_robot_state_age_s",
                "must exceed one cycle period",
            );
        }
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

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

    #[test]
    fn the_shipped_config_is_the_default() {
        assert_eq!(
            RuntimeConfig::xarm5_default(),
            RuntimeConfig::from_toml(ASSET).unwrap()
        );
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
            (
                "max_jerk_rad_s3",
                "[40.0, 40.0, 0.0, 40.0, 40.0]",
                "limits.max_jerk_rad_s3",
            ),
        ];
        for (key, value, field) in cases {
            match RuntimeConfig::from_toml(&with_value(key, value)) {
                Err(RuntimeConfigError::Invalid { field: f, .. }) => assert_eq!(f, field),
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
