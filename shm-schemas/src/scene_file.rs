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
//!
//! **Moving boxes.** An obstacle may carry a `path` of keyframes ([`path`]): its centre moves
//! linearly between them, sits at the first before it and is held at the last after it, time
//! counted from the moment the scene came into force ([`live`] says how processes agree on
//! that moment). `center_m` stays required: it is where readers that do not play time (the
//! twin's snapshot of the file) see the box; write the first keyframe's centre there. A box
//! without `path` stands still, and its file serialises back without one.
//!
//! ```toml
//! [[obstacle]]
//! center_m = [0.05, 0.20, 0.10]
//! size_m = [0.06, 0.06, 0.20]
//! path = [ { at_s = 1.0, center_m = [0.05, 0.20, 0.10] },
//!          { at_s = 2.7, center_m = [0.55, 0.08, 0.10] } ]
//! ```
//!
//! [`SceneFile::at`] is the scene as it stands at a time (every box placed, paths dropped);
//! validation applies the rules of a static box's placement to every keyframe.

pub mod live;
pub mod path;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use live::LiveScene;
pub use path::{BoxPath, BoxPathCapacityError, Keyframe, MAX_KEYFRAMES};

/// Most obstacle boxes a scene may hold (fixed capacity everywhere downstream).
pub const MAX_OBSTACLES: usize = 16;

/// Largest coordinate magnitude accepted anywhere in a scene (m): the xArm5 reaches 0.7 m.
pub const MAX_SCENE_EXTENT_M: f64 = 3.0;

/// Why a scene file or world script was rejected.
#[derive(Debug, thiserror::Error)]
pub enum SceneFileError {
    /// The file could not be read.
    #[error("cannot read scene file {path}")]
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

/// One axis-aligned obstacle box, standing still or moving along a path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Box centre in the base frame (m). With a path, where readers that do not play time
    /// see the box (the first keyframe's centre by convention).
    pub center_m: [f64; 3],
    /// Full extents along x, y, z (m).
    pub size_m: [f64; 3],
    /// Keyframes of the box's motion (empty: it stands still at `center_m`).
    #[serde(default, skip_serializing_if = "BoxPath::is_empty")]
    pub path: BoxPath,
}

impl BoxSpec {
    /// A box that stands still.
    pub fn fixed(center_m: [f64; 3], size_m: [f64; 3]) -> Self {
        Self {
            center_m,
            size_m,
            path: BoxPath::EMPTY,
        }
    }

    /// Height of the box's top face above its bottom face (m): `size_m[2]`.
    pub fn height_m(&self) -> f64 {
        self.size_m[2]
    }

    /// The centre `t_s` seconds after the scene came into force: on its path
    /// ([`BoxPath::center_at`]), or `center_m` without one.
    pub fn center_at(&self, t_s: f64) -> [f64; 3] {
        self.path.center_at(t_s).unwrap_or(self.center_m)
    }

    /// The centre's velocity `t_s` seconds after the scene came into force (m/s).
    pub fn velocity_at(&self, t_s: f64) -> [f64; 3] {
        self.path.velocity_at(t_s)
    }

    /// Whether the box ever moves: its path goes through more than one place. (A path of
    /// one place still puts the box there, not at `center_m`.)
    pub fn is_moving(&self) -> bool {
        self.path.is_moving()
    }

    /// The box as it stands `t_s` seconds after the scene came into force, without a path.
    pub fn at(&self, t_s: f64) -> Self {
        Self::fixed(self.center_at(t_s), self.size_m)
    }
}

/// The TOML form of a scene file: [`SceneFile`]'s fields plus the live file's time origin
/// ([`live`]), which a plain scene reader ignores.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFileToml {
    #[serde(default)]
    in_force_since_monotonic_ns: Option<u64>,
    #[serde(default)]
    name: String,
    #[serde(default)]
    table: TableSpec,
    goal: GoalSpec,
    #[serde(default, rename = "obstacle")]
    obstacles: Vec<BoxSpec>,
}

impl From<SceneFileToml> for SceneFile {
    fn from(raw: SceneFileToml) -> Self {
        Self {
            name: raw.name,
            table: raw.table,
            goal: raw.goal,
            obstacles: raw.obstacles,
        }
    }
}

/// A whole scene as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "SceneFileToml")]
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
    /// everything within [`MAX_SCENE_EXTENT_M`] of the base, boxes not below the table; on a
    /// path, keyframe times finite, ≥ 0 and strictly ascending, and every keyframe's
    /// placement held to the rules of a box that stands still.
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
            let who = format!("obstacle[{i}]");
            check_center(&who, &b.center_m)?;
            if b.size_m
                .iter()
                .any(|s| !(s.is_finite() && *s > 0.0 && *s < 2.0))
            {
                return Err(format!(
                    "obstacle[{i}].size_m = {:?}: each extent must be in (0, 2) m",
                    b.size_m
                ));
            }
            check_above_table(&who, &b.center_m, &b.size_m, t)?;
            let mut previous_s = None;
            for (k, f) in b.path.keyframes().iter().enumerate() {
                let who = format!("obstacle[{i}].path[{k}]");
                if !(f.at_s.is_finite() && f.at_s >= 0.0) {
                    return Err(format!("{who}.at_s = {} must be finite and ≥ 0", f.at_s));
                }
                if let Some(p) = previous_s
                    && f.at_s <= p
                {
                    return Err(format!(
                        "{who}.at_s = {} must come after obstacle[{i}].path[{}].at_s = {p} \
                         (keyframe times ascend strictly)",
                        f.at_s,
                        k - 1
                    ));
                }
                previous_s = Some(f.at_s);
                // The same rules as a box that stands still, for every placement on the way
                // (the rules are convex, so the straight segments between keyframes keep them).
                check_center(&who, &f.center_m)?;
                check_above_table(&who, &f.center_m, &b.size_m, t)?;
            }
        }
        Ok(())
    }

    /// Whether any obstacle moves ([`BoxSpec::is_moving`]).
    pub fn is_moving(&self) -> bool {
        self.obstacles.iter().any(BoxSpec::is_moving)
    }

    /// The scene as it stands `t_s` seconds after it came into force: every box placed where
    /// its path puts it, paths dropped (a scene without paths comes back unchanged).
    pub fn at(&self, t_s: f64) -> SceneFile {
        SceneFile {
            name: self.name.clone(),
            table: self.table,
            goal: self.goal,
            obstacles: self.obstacles.iter().map(|b| b.at(t_s)).collect(),
        }
    }
}

/// A box placement's centre: finite and within [`MAX_SCENE_EXTENT_M`] (`who` names it).
fn check_center(who: &str, center_m: &[f64; 3]) -> Result<(), String> {
    if !finite3(center_m) || center_m.iter().any(|c| c.abs() > MAX_SCENE_EXTENT_M) {
        return Err(format!(
            "{who}.center_m = {center_m:?} is not finite or lies beyond ±{MAX_SCENE_EXTENT_M} m"
        ));
    }
    Ok(())
}

/// A box placement's bottom is not below the table at `table_m` (1 mm slack).
fn check_above_table(
    who: &str,
    center_m: &[f64; 3],
    size_m: &[f64; 3],
    table_m: f64,
) -> Result<(), String> {
    let bottom = center_m[2] - size_m[2] / 2.0;
    if bottom < table_m - 1e-3 {
        return Err(format!(
            "{who} reaches below the table (bottom z = {bottom:.4} m, table at {table_m} m)"
        ));
    }
    Ok(())
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

    /// `SMALL` with obstacle 1 moving along `path` (TOML inline array).
    fn moving(path: &str) -> String {
        format!(
            "{SMALL}[[obstacle]]\ncenter_m = [0.5, -0.2, 0.05]\nsize_m = [0.06, 0.06, 0.10]\n\
             path = {path}\n"
        )
    }

    const PATH: &str = "[ { at_s = 1.0, center_m = [0.5, -0.2, 0.05] }, \
                        { at_s = 2.0, center_m = [0.5, 0.2, 0.05] }, \
                        { at_s = 4.0, center_m = [0.3, 0.2, 0.15] } ]";

    #[test]
    fn a_moving_box_parses_round_trips_and_is_placed_in_time() {
        let s = SceneFile::from_toml_str(&moving(PATH), Path::new("<inline>")).unwrap();
        assert!(s.is_moving());
        let b = &s.obstacles[1];
        assert_eq!(b.path.len(), 3);
        // Before the first keyframe, between, after the last.
        assert_eq!(b.center_at(0.0), [0.5, -0.2, 0.05]);
        let mid = b.center_at(1.5);
        assert!((mid[1] - 0.0).abs() < 1e-12 && mid[0] == 0.5, "{mid:?}");
        let late = b.center_at(3.0);
        assert!((late[0] - 0.4).abs() < 1e-12 && (late[2] - 0.10).abs() < 1e-12);
        assert_eq!(b.center_at(10.0), [0.3, 0.2, 0.15]);
        assert!((b.velocity_at(1.5)[1] - 0.4).abs() < 1e-12);
        assert_eq!(b.velocity_at(5.0), [0.0; 3]);
        // The static box does not move and keeps its centre at any time.
        assert!(!s.obstacles[0].is_moving());
        assert_eq!(s.obstacles[0].center_at(3.0), [0.35, 0.0, 0.05]);
        // The scene at a time: boxes placed, paths dropped, the rest unchanged.
        let at = s.at(1.5);
        assert!(!at.is_moving() && at.obstacles.iter().all(|b| b.path.is_empty()));
        assert_eq!(at.obstacles[1].center_m, mid);
        assert_eq!(at.obstacles[0], s.obstacles[0]);
        assert_eq!((&at.goal, &at.name), (&s.goal, &s.name));
        at.validate().unwrap();
        // Round trip keeps the path; a file without paths writes none.
        let back = SceneFile::from_toml_str(&s.to_toml_string(), Path::new("<rt>")).unwrap();
        assert_eq!(back, s);
        let plain = SceneFile::from_toml_str(SMALL, Path::new("<inline>")).unwrap();
        assert!(!plain.to_toml_string().contains("path"));
        assert!(!plain.is_moving());
        assert_eq!(plain.at(7.0), plain);
        assert_eq!(
            plain.obstacles[0],
            BoxSpec::fixed([0.35, 0.0, 0.05], [0.06, 0.06, 0.10])
        );
    }

    #[test]
    fn bad_paths_are_refused_naming_the_keyframe() {
        let kf = |t: &str, c: &str| format!("{{ at_s = {t}, center_m = {c} }}");
        let ok = "[0.5, -0.2, 0.05]";
        let cases = [
            // Times not strictly ascending.
            (
                format!("[{}, {}]", kf("1.0", ok), kf("1.0", ok)),
                "obstacle[1].path[1].at_s = 1 must come after obstacle[1].path[0].at_s",
            ),
            (
                format!("[{}, {}, {}]", kf("1.0", ok), kf("2.0", ok), kf("1.5", ok)),
                "obstacle[1].path[2].at_s",
            ),
            // Negative or non-finite times.
            (
                format!("[{}]", kf("-0.5", ok)),
                "obstacle[1].path[0].at_s = -0.5",
            ),
            (
                format!("[{}, {}]", kf("0.0", ok), kf("inf", ok)),
                "obstacle[1].path[1].at_s = inf",
            ),
            (
                format!("[{}]", kf("nan", ok)),
                "obstacle[1].path[0].at_s = NaN",
            ),
            // Non-finite or far centres.
            (
                format!("[{}, {}]", kf("0.0", ok), kf("1.0", "[0.5, nan, 0.05]")),
                "obstacle[1].path[1].center_m",
            ),
            (
                format!("[{}, {}]", kf("0.0", ok), kf("1.0", "[4.0, 0.0, 0.05]")),
                "obstacle[1].path[1].center_m",
            ),
            // A keyframe that puts the box below the table.
            (
                format!(
                    "[{}, {}, {}]",
                    kf("0.0", ok),
                    kf("1.0", ok),
                    kf("2.0", "[0.5, 0.2, 0.0]")
                ),
                "obstacle[1].path[2] reaches below the table",
            ),
        ];
        for (path, want) in cases {
            let err = SceneFile::from_toml_str(&moving(&path), Path::new("<inline>")).unwrap_err();
            assert!(
                matches!(err, SceneFileError::Invalid { .. }) && err.to_string().contains(want),
                "{err} should mention {want}"
            );
        }
        // A keyframe with an unknown field, or too many keyframes: refused by the parser.
        let typo = moving("[ { at_s = 0.0, centre_m = [0.5, -0.2, 0.05] } ]");
        let err = SceneFile::from_toml_str(&typo, Path::new("<inline>")).unwrap_err();
        assert!(err.to_string().contains("centre_m"), "{err}");
        let many = (0..=MAX_KEYFRAMES)
            .map(|k| kf(&format!("{k}.0"), ok))
            .collect::<Vec<_>>()
            .join(", ");
        let err = SceneFile::from_toml_str(&moving(&format!("[{many}]")), Path::new("<inline>"))
            .unwrap_err();
        assert!(err.to_string().contains("at most 32"), "{err}");
        // The same keyframes in order are fine.
        SceneFile::from_toml_str(&moving(PATH), Path::new("<inline>")).unwrap();
    }

    #[test]
    fn the_crossing_box_world_validates_and_its_box_crosses_the_straight_path() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/crossing_box.toml");
        let s = SceneFile::load(&path).unwrap();
        assert!(s.is_moving());
        let demo = SceneFile::load(&path.with_file_name("small_box.toml")).unwrap();
        assert_eq!(s.goal, demo.goal, "the demo's goal");
        let b = &s.obstacles[0];
        assert_eq!(
            b.center_m,
            b.center_at(0.0),
            "center_m is the first keyframe"
        );
        // Still for about a second, then ≈ 0.3 m/s.
        assert_eq!(b.center_at(0.9), b.center_at(0.0));
        let v = b.velocity_at(1.5);
        let speed = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((speed - 0.3).abs() < 0.02, "{speed} m/s");
        // The straight start → goal segment in plan view runs along x = 0.30 from y = 0 to
        // the goal's y: the box is on one side of it at first, on the other at the end, and
        // covers it on the way.
        let x = |t: f64| b.center_at(t)[0];
        let half_x = b.size_m[0] / 2.0;
        assert!(x(0.0) + half_x < 0.30 && x(60.0) - half_x > 0.30);
        let crossing = (0..400)
            .map(|k| k as f64 * 0.01)
            .find(|t| (x(*t) - 0.30).abs() < half_x);
        let t = crossing.expect("the box crosses x = 0.30");
        let y = b.center_at(t)[1];
        assert!(y > 0.0 && y < s.goal.center_m[1], "crosses at y = {y}");
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
