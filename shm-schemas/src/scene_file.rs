//! The scene file format (TOML) and world scripts: the one description of a workspace that
//! the twin, the simulated arm (`xarm-sim`, as ground truth) and the synthetic camera read.
//!
//! A scene is a table plane, one goal cube and up to [`MAX_OBSTACLES`] axis-aligned obstacle
//! boxes, all in the robot base frame (metres; z up; the table top is at `table.height_m`).
//!
//! ```toml
//! name = "small_box"
//! [table]
//! height_m = 0.0
//! [goal]
//! center_m = [0.40, 0.20, 0.025]
//! size_m = 0.05                     # cube edge
//! [[obstacle]]
//! center_m = [0.35, 0.0, 0.05]
//! size_m = [0.06, 0.06, 0.10]       # full extents x, y, z
//! ```
//!
//! A world script is a timeline of scenes (`at_s` from the script's start, ascending; paths
//! relative to the script's folder):
//!
//! ```toml
//! [[step]]
//! at_s = 0.0
//! scene = "small_box.toml"
//! [[step]]
//! at_s = 10.0
//! scene = "tall_box.toml"
//! ```
//!
//! Obstacles are axis-aligned boxes: the research system's boxes stood square to the table
//! edges, and perception reports axis-aligned footprints. A rotated box is a future field.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Most obstacle boxes a scene may hold (fixed capacity everywhere downstream).
pub const MAX_OBSTACLES: usize = 16;

/// Largest coordinate magnitude accepted anywhere in a scene (m): the xArm5 reaches 0.7 m.
pub const MAX_SCENE_EXTENT_M: f64 = 3.0;

/// Why a scene file or world script was rejected.
#[derive(Debug, thiserror::Error)]
pub enum SceneFileError {
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The TOML was malformed or had unknown/missing fields.
    #[error("malformed scene file {path}: {message}")]
    Parse {
        /// The file (or `<inline>`).
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// A value was out of range.
    #[error("invalid scene {path}: {message}")]
    Invalid {
        /// The file (or `<inline>`).
        path: PathBuf,
        /// What was wrong.
        message: String,
    },
}

/// The table plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableSpec {
    /// Height of the table top in the base frame (m).
    pub height_m: f64,
}

impl Default for TableSpec {
    fn default() -> Self {
        Self { height_m: 0.0 }
    }
}

/// The goal cube.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalSpec {
    /// Cube centre in the base frame (m).
    pub center_m: [f64; 3],
    /// Cube edge length (m).
    pub size_m: f64,
}

/// One axis-aligned obstacle box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Box centre in the base frame (m).
    pub center_m: [f64; 3],
    /// Full extents along x, y, z (m).
    pub size_m: [f64; 3],
}

impl BoxSpec {
    /// Height of the box's top face above its bottom face (m): `size_m[2]`.
    pub fn height_m(&self) -> f64 {
        self.size_m[2]
    }
}

/// A whole scene as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// A short name for logs and reports.
    #[serde(default)]
    pub name: String,
    /// The table plane.
    #[serde(default)]
    pub table: TableSpec,
    /// The goal cube.
    pub goal: GoalSpec,
    /// Obstacle boxes (at most [`MAX_OBSTACLES`]).
    #[serde(default, rename = "obstacle")]
    pub obstacles: Vec<BoxSpec>,
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SceneFile {
    /// Reads and validates a scene file.
    ///
    /// # Errors
    /// [`SceneFileError`] for an unreadable file, malformed TOML or values out of range.
    pub fn load(path: &Path) -> Result<Self, SceneFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and validates scene TOML; `origin` names the source in error messages.
    ///
    /// # Errors
    /// [`SceneFileError::Parse`] or [`SceneFileError::Invalid`].
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self, SceneFileError> {
        let scene: SceneFile = toml::from_str(text).map_err(|e| SceneFileError::Parse {
            path: origin.to_path_buf(),
            message: e.to_string(),
        })?;
        scene
            .validate()
            .map_err(|message| SceneFileError::Invalid {
                path: origin.to_path_buf(),
                message,
            })?;
        Ok(scene)
    }

    /// Serialises the scene to TOML (the inverse of [`SceneFile::from_toml_str`]).
    pub fn to_toml_string(&self) -> String {
        // Serialising plain numbers and strings cannot fail.
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// Checks ranges: finite numbers, positive sizes, at most [`MAX_OBSTACLES`] boxes,
    /// everything within [`MAX_SCENE_EXTENT_M`] of the base, boxes not below the table.
    ///
    /// # Errors
    /// A message naming the first bad value.
    pub fn validate(&self) -> Result<(), String> {
        let t = self.table.height_m;
        if !t.is_finite() || t.abs() > MAX_SCENE_EXTENT_M {
            return Err(format!(
                "table.height_m = {t} is not a finite height within ±{MAX_SCENE_EXTENT_M} m"
            ));
        }
        let g = &self.goal;
        if !finite3(&g.center_m) || g.center_m.iter().any(|c| c.abs() > MAX_SCENE_EXTENT_M) {
            return Err(format!(
                "goal.center_m = {:?} is not finite or lies beyond ±{MAX_SCENE_EXTENT_M} m",
                g.center_m
            ));
        }
        if !(g.size_m.is_finite() && g.size_m > 0.0 && g.size_m < 1.0) {
            return Err(format!("goal.size_m = {} must be in (0, 1) m", g.size_m));
        }
        if self.obstacles.len() > MAX_OBSTACLES {
            return Err(format!(
                "{} obstacles given, at most {MAX_OBSTACLES} are supported",
                self.obstacles.len()
            ));
        }
        for (i, b) in self.obstacles.iter().enumerate() {
            if !finite3(&b.center_m) || b.center_m.iter().any(|c| c.abs() > MAX_SCENE_EXTENT_M) {
                return Err(format!(
                    "obstacle[{i}].center_m = {:?} is not finite or lies beyond ±{MAX_SCENE_EXTENT_M} m",
                    b.center_m
                ));
            }
            if b.size_m
                .iter()
                .any(|s| !(s.is_finite() && *s > 0.0 && *s < 2.0))
            {
                return Err(format!(
                    "obstacle[{i}].size_m = {:?}: each extent must be in (0, 2) m",
                    b.size_m
                ));
            }
            let bottom = b.center_m[2] - b.size_m[2] / 2.0;
            if bottom < t - 1e-3 {
                return Err(format!(
                    "obstacle[{i}] reaches below the table (bottom z = {bottom:.4} m, table at {t} m)"
                ));
            }
        }
        Ok(())
    }
}

/// One entry of a world script: from `at_s` on, the world looks like `scene`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldStep {
    /// Time from the script's start (s).
    pub at_s: f64,
    /// Scene file, relative to the script's folder.
    pub scene: PathBuf,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WorldScriptToml {
    #[serde(rename = "step")]
    steps: Vec<WorldStep>,
}

/// A loaded world script: a timeline of validated scenes.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldScript {
    /// `(at_s, scene)` pairs in ascending time; the first starts at 0.
    pub steps: Vec<(f64, SceneFile)>,
}

impl WorldScript {
    /// Reads a world script and every scene it names.
    ///
    /// # Errors
    /// [`SceneFileError`] for the script or any scene in it; times must start at 0 and ascend.
    pub fn load(path: &Path) -> Result<Self, SceneFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let raw: WorldScriptToml = toml::from_str(&text).map_err(|e| SceneFileError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let invalid = |message: String| SceneFileError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        if raw.steps.is_empty() {
            return Err(invalid("a world script needs at least one [[step]]".into()));
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut steps = Vec::with_capacity(raw.steps.len());
        let mut last = -1.0;
        for (i, s) in raw.steps.iter().enumerate() {
            if !s.at_s.is_finite() || s.at_s < 0.0 || s.at_s <= last {
                return Err(invalid(format!(
                    "step[{i}].at_s = {} must be finite, ≥ 0 and after the previous step",
                    s.at_s
                )));
            }
            if i == 0 && s.at_s != 0.0 {
                return Err(invalid("the first step must be at_s = 0".into()));
            }
            last = s.at_s;
            steps.push((s.at_s, SceneFile::load(&dir.join(&s.scene))?));
        }
        Ok(Self { steps })
    }

    /// A script holding one scene forever.
    pub fn single(scene: SceneFile) -> Self {
        Self {
            steps: vec![(0.0, scene)],
        }
    }

    /// The scene in force `t_s` seconds after the script's start, and its index.
    pub fn scene_at(&self, t_s: f64) -> (usize, &SceneFile) {
        let mut idx = 0;
        for (i, (at, _)) in self.steps.iter().enumerate() {
            if *at <= t_s {
                idx = i;
            }
        }
        (idx, &self.steps[idx].1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = r#"
name = "small"
[goal]
center_m = [0.4, 0.2, 0.025]
size_m = 0.05
[[obstacle]]
center_m = [0.35, 0.0, 0.05]
size_m = [0.06, 0.06, 0.10]
"#;

    #[test]
    fn parses_and_round_trips() {
        let s = SceneFile::from_toml_str(SMALL, Path::new("<inline>")).unwrap();
        assert_eq!(s.obstacles.len(), 1);
        assert_eq!(s.obstacles[0].height_m(), 0.10);
        let back = SceneFile::from_toml_str(&s.to_toml_string(), Path::new("<rt>")).unwrap();
        assert_eq!(s, back);
    }

    #[test]
    fn rejects_bad_scenes_with_a_reason() {
        let cases = [
            (
                SMALL.replace("size_m = 0.05", "size_m = -0.05"),
                "goal.size_m",
            ),
            (
                SMALL.replace("[0.06, 0.06, 0.10]", "[0.06, nan, 0.10]"),
                "obstacle[0].size_m",
            ),
            (
                SMALL.replace("[0.35, 0.0, 0.05]", "[0.35, 0.0, -0.5]"),
                "below the table",
            ),
            (
                SMALL.replace("name =", "colour = 1\nname ="),
                "unknown field",
            ),
            (SMALL.replace("[goal]", "[gaol]"), "malformed"),
        ];
        for (text, want) in cases {
            let err = SceneFile::from_toml_str(&text, Path::new("<inline>")).unwrap_err();
            assert!(
                err.to_string().contains(want),
                "{err} should mention {want}"
            );
        }
        let many = (0..=MAX_OBSTACLES).fold(SMALL.to_string(), |s, _| {
            s + "[[obstacle]]\ncenter_m = [0.3, 0.3, 0.05]\nsize_m = [0.05, 0.05, 0.1]\n"
        });
        let err = SceneFile::from_toml_str(&many, Path::new("<inline>")).unwrap_err();
        assert!(err.to_string().contains("at most"), "{err}");
    }

    #[test]
    fn world_script_picks_the_scene_in_force() {
        let dir = std::env::temp_dir().join(format!("foresight-ws-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("a.toml"), SMALL).unwrap();
        std::fs::write(
            dir.join("b.toml"),
            SMALL
                .replace("0.10]", "0.30]")
                .replace("0.05]\n", "0.15]\n"),
        )
        .unwrap();
        std::fs::write(
            dir.join("w.toml"),
            "[[step]]\nat_s = 0.0\nscene = \"a.toml\"\n[[step]]\nat_s = 10.0\nscene = \"b.toml\"\n",
        )
        .unwrap();
        let w = WorldScript::load(&dir.join("w.toml")).unwrap();
        assert_eq!(w.scene_at(3.0).0, 0);
        assert_eq!(w.scene_at(10.0).0, 1);
        assert!((w.scene_at(11.0).1.obstacles[0].size_m[2] - 0.30).abs() < 1e-12);
        std::fs::write(
            dir.join("bad.toml"),
            "[[step]]\nat_s = 0.0\nscene = \"a.toml\"\n[[step]]\nat_s = 0.0\nscene = \"b.toml\"\n",
        )
        .unwrap();
        assert!(WorldScript::load(&dir.join("bad.toml")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
