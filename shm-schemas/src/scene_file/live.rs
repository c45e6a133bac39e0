//! The live scene file: the scene in force and the moment it came into force, shared by
//! every process that plays the world (the simulator's ground truth, the synthetic camera).
//!
//! **The time origin of moving boxes.** A box's path counts time from the moment its scene
//! came into force. Processes agree on that moment through the file itself: the launcher
//! writes the top-level key `in_force_since_monotonic_ns` (`CLOCK_MONOTONIC`,
//! [`crate::clock::monotonic_now_ns`], the clock every process on the machine shares) into
//! `world/live.toml` when it puts a scene in force (at start and at every switch), and the
//! simulator and the camera both place every box at
//! `t = (now − in_force_since_monotonic_ns) / 1e9` s — the same instant on both sides, so
//! they agree to the resolution of their own ticks and frames, well within a millisecond of
//! each other's origin. A file without the key (a hand-written scene, an older launcher):
//! time counts from when the reader loaded it.
//!
//! ```toml
//! in_force_since_monotonic_ns = 81234567890123
//! name = "crossing_box"
//! [goal]
//! center_m = [0.30, 0.25, 0.025]
//! size_m = 0.05
//! ```
//!
//! [`super::SceneFile::load`] accepts and ignores the key, so a live file is also a plain
//! scene file for every reader that does not play time.

use std::path::Path;

use super::{SceneFile, SceneFileError, SceneFileToml};

/// The TOML key of the time origin.
pub const IN_FORCE_SINCE_KEY: &str = "in_force_since_monotonic_ns";

/// A scene and, when known, when it came into force.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveScene {
    /// The scene.
    pub scene: SceneFile,
    /// When it came into force (`CLOCK_MONOTONIC`, ns); `None`: not stated, the reader
    /// counts from when it loaded the file ([`LiveScene::in_force_since_or`]).
    pub in_force_since_monotonic_ns: Option<u64>,
}

impl LiveScene {
    /// The scene in force since `in_force_since_monotonic_ns`.
    pub fn new(scene: SceneFile, in_force_since_monotonic_ns: u64) -> Self {
        Self {
            scene,
            in_force_since_monotonic_ns: Some(in_force_since_monotonic_ns),
        }
    }

    /// Reads and validates a live (or plain) scene file.
    ///
    /// # Errors
    /// [`SceneFileError`] as for [`SceneFile::load`].
    pub fn load(path: &Path) -> Result<Self, SceneFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and validates live scene TOML; `origin` names the source in error messages.
    ///
    /// # Errors
    /// [`SceneFileError::Parse`] or [`SceneFileError::Invalid`].
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self, SceneFileError> {
        let raw: SceneFileToml = toml::from_str(text).map_err(|e| SceneFileError::Parse {
            path: origin.to_path_buf(),
            message: e.to_string(),
        })?;
        let since = raw.in_force_since_monotonic_ns;
        let scene = SceneFile::from(raw);
        scene
            .validate()
            .map_err(|message| SceneFileError::Invalid {
                path: origin.to_path_buf(),
                message,
            })?;
        Ok(Self {
            scene,
            in_force_since_monotonic_ns: since,
        })
    }

    /// Serialises the scene with its time origin (the inverse of
    /// [`LiveScene::from_toml_str`]).
    pub fn to_toml_string(&self) -> String {
        let scene = self.scene.to_toml_string();
        match self.in_force_since_monotonic_ns {
            // A root key goes before the first table: at the very top is always valid.
            Some(ns) => format!("{IN_FORCE_SINCE_KEY} = {ns}\n{scene}"),
            None => scene,
        }
    }

    /// When the scene came into force, or `loaded_ns` (when the reader loaded the file)
    /// if the file does not say.
    pub fn in_force_since_or(&self, loaded_ns: u64) -> u64 {
        self.in_force_since_monotonic_ns.unwrap_or(loaded_ns)
    }
}

/// Seconds from `since_ns` to `now_ns` on `CLOCK_MONOTONIC` (0 when `now_ns` is earlier).
pub fn seconds_since(since_ns: u64, now_ns: u64) -> f64 {
    now_ns.saturating_sub(since_ns) as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = "name = \"s\"\n[goal]\ncenter_m = [0.3, 0.25, 0.025]\nsize_m = 0.05\n";

    #[test]
    fn the_time_origin_round_trips_and_plain_readers_ignore_it() {
        let plain = SceneFile::from_toml_str(SCENE, Path::new("<inline>")).unwrap();
        let live = LiveScene::new(plain.clone(), 81_234_567_890_123);
        let text = live.to_toml_string();
        assert!(text.starts_with("in_force_since_monotonic_ns = 81234567890123\n"));
        assert_eq!(
            LiveScene::from_toml_str(&text, Path::new("<rt>")).unwrap(),
            live
        );
        // A plain reader takes the same scene.
        assert_eq!(
            SceneFile::from_toml_str(&text, Path::new("<rt>")).unwrap(),
            plain
        );
        // Without the key the reader's own load time counts.
        let unstamped = LiveScene::from_toml_str(SCENE, Path::new("<inline>")).unwrap();
        assert_eq!(unstamped.in_force_since_monotonic_ns, None);
        assert_eq!(unstamped.in_force_since_or(42), 42);
        assert_eq!(live.in_force_since_or(42), 81_234_567_890_123);
        assert_eq!(unstamped.to_toml_string(), plain.to_toml_string());
    }

    #[test]
    fn a_bad_time_origin_is_refused_by_the_parser() {
        for bad in ["-5", "1.5", "\"soon\""] {
            let text = format!("{IN_FORCE_SINCE_KEY} = {bad}\n{SCENE}");
            let err = LiveScene::from_toml_str(&text, Path::new("<inline>")).unwrap_err();
            assert!(matches!(err, SceneFileError::Parse { .. }), "{bad}: {err}");
        }
    }

    #[test]
    fn seconds_since_counts_on_the_shared_clock_and_never_goes_negative() {
        assert_eq!(seconds_since(1_000_000_000, 3_500_000_000), 2.5);
        assert_eq!(seconds_since(3_500_000_000, 1_000_000_000), 0.0);
    }
}
