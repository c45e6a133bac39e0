//! What the launcher reads of rt-core's configuration (`assets/runtime.toml`): only the keys
//! that shape the scenario. rt-core itself validates the whole file, with bounds, when it
//! starts; the launcher reports rt-core's refusal if the file is bad.

use std::path::Path;

use serde::Deserialize;

use crate::args::GoalSourceChoice;

/// The launcher's view of the runtime configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub struct RuntimeView {
    /// Whether rt-core brings the arm home after each goal (rt-core's default: true).
    #[serde(default = "yes")]
    pub return_home: bool,
    /// `[goal]`: where the goal comes from (rt-core's default: the camera).
    #[serde(default)]
    pub goal: GoalView,
}

/// `[goal]` of the runtime configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub struct GoalView {
    /// `source`: `camera` or `action`.
    #[serde(default)]
    pub source: GoalSourceChoice,
}

fn yes() -> bool {
    true
}

/// Why the runtime configuration could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeViewError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not TOML of the expected shape.
    #[error("invalid runtime config: {0}")]
    Parse(#[from] toml::de::Error),
}

impl RuntimeView {
    /// Reads the keys the launcher needs.
    ///
    /// # Errors
    /// [`RuntimeViewError`] when unreadable or malformed.
    pub fn load(path: &Path) -> Result<Self, RuntimeViewError> {
        let text = std::fs::read_to_string(path).map_err(|source| RuntimeViewError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Ok(toml::from_str(&text)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_return_home_from_the_shipped_config() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/runtime.toml");
        assert!(RuntimeView::load(&p).unwrap().return_home);
        let off: RuntimeView = toml::from_str("return_home = false\nrate_hz = 250.0").unwrap();
        assert!(!off.return_home);
        assert_eq!(off.goal.source, GoalSourceChoice::Camera);
        let action: RuntimeView = toml::from_str("[goal]\nsource = \"action\"").unwrap();
        assert_eq!(action.goal.source, GoalSourceChoice::Action);
        let bad = toml::from_str::<RuntimeView>("[goal]\nsource = \"both\"").unwrap_err();
        assert!(bad.to_string().contains("source"), "{bad}");
    }
}
