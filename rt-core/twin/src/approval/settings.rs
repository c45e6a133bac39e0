//! The settings rt-core approves plans with, from its `assets/runtime.toml`: the cycle rate
//! (the smoothed plan's sample period), the arm's motion limits (`[limits]`: Ruckig's
//! velocity, acceleration and jerk, the joint ranges, the TCP speed) and the shield's
//! (`[shield]`: workspace box, clearance, joint margin).
//!
//! rt-core's `RuntimeConfig` holds these sections as these types and validates their ranges;
//! the learner reads the same file with [`ApprovalSettings::from_runtime_toml`] (the other
//! sections ignored), so both sides verify a plan with the same numbers (rt-core's tests
//! compare the two readings of the shipped file).

use std::path::Path;

use serde::Deserialize;

/// The shipped `assets/runtime.toml`, compiled in.
pub const SHIPPED_RUNTIME_TOML: &str = include_str!("../../../../assets/runtime.toml");

/// `[limits]` and `[shield]`: defined once, in the view of `runtime.toml` that processes
/// other than rt-core read (`shm_schemas::runtime_view`), where `[shield]` already lived for
/// the bridge and the launcher; rt-core's `RuntimeConfig` holds the same types and validates
/// their ranges.
pub use shm_schemas::runtime_view::{DEFAULT_MAX_TCP_GAP_M, MotionLimits, ShieldConfig};

/// Why approval settings could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ApprovalSettingsError {
    /// The file could not be read.
    #[error("cannot read {path}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML did not parse into the expected shape.
    #[error("invalid runtime config (TOML)")]
    Parse(#[from] toml::de::Error),
    /// The cycle rate is not a positive finite number.
    #[error("invalid runtime config: rate_hz must be positive and finite")]
    Rate,
}

/// What rt-core approves a plan with: its cycle rate, motion limits and shield settings.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct ApprovalSettings {
    /// Cycle rate, Hz: the smoothed plan has one sample per cycle.
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// `[limits]`.
    pub limits: MotionLimits,
    /// `[shield]`.
    pub shield: ShieldConfig,
}

fn default_rate_hz() -> f64 {
    250.0
}

impl ApprovalSettings {
    /// Reads `rate_hz`, `[limits]` and `[shield]` of a runtime configuration's TOML text
    /// (rt-core validates the whole file; its other sections are ignored here).
    ///
    /// # Errors
    /// [`ApprovalSettingsError`].
    pub fn from_runtime_toml(text: &str) -> Result<Self, ApprovalSettingsError> {
        let s: Self = toml::from_str(text)?;
        if !(s.rate_hz.is_finite() && s.rate_hz > 0.0) {
            return Err(ApprovalSettingsError::Rate);
        }
        Ok(s)
    }

    /// [`Self::from_runtime_toml`] of a file.
    ///
    /// # Errors
    /// [`ApprovalSettingsError`].
    pub fn load(path: &Path) -> Result<Self, ApprovalSettingsError> {
        let text = std::fs::read_to_string(path).map_err(|source| ApprovalSettingsError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_runtime_toml(&text)
    }

    /// The shipped `assets/runtime.toml`'s.
    ///
    /// # Errors
    /// Never for a released build: this crate's tests parse the shipped file.
    pub fn shipped() -> Result<Self, ApprovalSettingsError> {
        Self::from_runtime_toml(SHIPPED_RUNTIME_TOML)
    }

    /// The cycle period, s: the smoothed plan's sample spacing.
    pub fn period_s(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// The most samples a smoothed plan may have (60 s of cycles).
    pub fn max_plan_samples(&self) -> usize {
        (60.0 * self.rate_hz) as usize
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_runtime_configuration_reads() {
        let s = ApprovalSettings::shipped().unwrap();
        assert!(s.rate_hz > 0.0);
        assert!(s.shield.min_distance_m > 0.0);
        assert!((s.period_s() * s.rate_hz - 1.0).abs() < 1e-12);
    }
}
