//! The synthetic camera: renders a scene file (table with the taped workspace rectangle, goal
//! cube, obstacle boxes) to a colour (BGR) and a depth (metres) image with known intrinsics
//! and pose, plus a per-pixel label image as exact ground truth. It follows a world script
//! (a timeline of scenes) for the demo.
//!
//! Boxes with paths move: [`SyntheticCamera::render_at`] draws every box where its path puts
//! it `t_s` seconds after the scene came into force. The live source
//! ([`crate::source::SyntheticSource`]) renders each frame at its capture time on
//! `CLOCK_MONOTONIC`, counted from the live scene file's `in_force_since_monotonic_ns` (the
//! origin the simulated arm uses too: [`shm_schemas::scene_file::live`]); a world script
//! counts from its step's `at_s`.
//!
//! The renderer casts one ray per pixel centre against the table plane and the axis-aligned
//! boxes, so depth is exact to floating-point precision; faces get flat Lambertian-like
//! shading so the image looks three-dimensional while each object keeps its hue.
//!
//! ```no_run
//! # use perception::synthetic::SyntheticCamera;
//! let cam = SyntheticCamera::load(std::path::Path::new("assets/perception/synthetic_camera.toml"))?;
//! let scene = shm_schemas::scene_file::SceneFile::load(std::path::Path::new("assets/scenes/small_box.toml"))?;
//! let frame = cam.render(&scene);
//! assert_eq!(frame.depth_m.len(), frame.width_px * frame.height_px);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use shm_schemas::scene_file::SceneFile;

use crate::geometry::{
    CameraModel, CameraPose, CameraPoseLookAtError, Intrinsics, IntrinsicsValidateError,
};
use crate::workspace::{WorkspaceRect, WorkspaceValidateError};

/// The camera frame id of the synthetic camera: what its calibrations name in `[camera]
/// frame_id` (the bundled `assets/perception/calibration.toml`, `perception render`'s, the
/// exact one `perception run --source synthetic:…` derives). A calibration naming it is
/// refused with a live camera ([`crate::camera_id`]), and the synthetic source takes no other.
pub const SYNTHETIC_CAMERA_FRAME_ID: &str = "foresight_synthetic_camera";

/// Label of a pixel that sees nothing (sky): depth is NaN there.
pub const LABEL_NONE: u8 = 0;
/// Label of the bare table top.
pub const LABEL_TABLE: u8 = 1;
/// Label of the workspace tape.
pub const LABEL_TAPE: u8 = 2;
/// Label of the goal cube.
pub const LABEL_GOAL: u8 = 3;
/// Label of obstacle `i` is `LABEL_OBSTACLE0 + i`.
pub const LABEL_OBSTACLE0: u8 = 4;

/// Why [`SyntheticCamera::new`] rejected a description; each message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SyntheticCameraConfigError {
    /// Bad `[intrinsics]`.
    #[error(transparent)]
    Intrinsics(#[from] IntrinsicsValidateError),
    /// Bad `[workspace]`.
    #[error(transparent)]
    Workspace(#[from] WorkspaceValidateError),
    /// `tape_width_m` is negative or not finite.
    #[error("tape_width_m = {0} must be ≥ 0")]
    TapeWidth(f64),
    /// `tape_width_m` is at least half the workspace's shorter side.
    #[error("tape_width_m = {0}: the tape is wider than half the workspace")]
    TapeTooWide(f64),
    /// `table_half_extent_m` is not a positive number.
    #[error("table_half_extent_m = {0} must be > 0")]
    TableHalfExtent(f64),
    /// `[pose]` gives no usable view.
    #[error(transparent)]
    Pose(#[from] CameraPoseLookAtError),
}

/// Why a synthetic camera description file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum SyntheticCameraLoadError {
    /// The file could not be read.
    #[error("cannot read synthetic camera file {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Malformed TOML.
    #[error("invalid synthetic camera file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// Out-of-range values.
    #[error("invalid synthetic camera file {path}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The first bad value.
        source: SyntheticCameraConfigError,
    },
}

/// Surface colours (B, G, R), fully lit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Palette {
    /// Table top.
    pub table_bgr: [u8; 3],
    /// Workspace tape.
    pub tape_bgr: [u8; 3],
    /// Goal cube.
    pub goal_bgr: [u8; 3],
    /// Obstacle boxes.
    pub obstacle_bgr: [u8; 3],
    /// What lies beyond the table (no depth).
    pub background_bgr: [u8; 3],
}

impl Default for Palette {
    fn default() -> Self {
        Self {
            table_bgr: [170, 175, 180],
            tape_bgr: [40, 200, 230],
            goal_bgr: [60, 190, 40],
            obstacle_bgr: [200, 90, 30],
            background_bgr: [30, 30, 30],
        }
    }
}

/// Where the synthetic camera stands.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LookAt {
    /// Camera centre (m, twin frame).
    pub eye_m: [f64; 3],
    /// Point on the optical axis (m, twin frame).
    pub target_m: [f64; 3],
}

/// The synthetic camera's description as written in TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticCameraConfig {
    /// Intrinsics of the rendered images.
    pub intrinsics: Intrinsics,
    /// Camera placement.
    pub pose: LookAt,
    /// The taped rectangle (its `table_height_m` is overridden by each scene's table).
    pub workspace: WorkspaceRect,
    /// Width of the tape (m), inside the rectangle.
    pub tape_width_m: f64,
    /// Half-size of the square table top around the workspace centre (m); beyond it, nothing.
    pub table_half_extent_m: f64,
    /// Colours.
    #[serde(default)]
    pub palette: Palette,
}

/// The synthetic camera, ready to render.
#[derive(Debug, Clone)]
pub struct SyntheticCamera {
    /// Its description.
    pub config: SyntheticCameraConfig,
    /// Its intrinsics and pose.
    pub model: CameraModel,
}

/// One rendered frame with exact ground truth.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    /// Image width (px).
    pub width_px: usize,
    /// Image height (px).
    pub height_px: usize,
    /// Colour, 3 bytes per pixel in B, G, R order, row-major.
    pub bgr: Vec<u8>,
    /// Depth along the optical axis (m); NaN where the ray hits nothing.
    pub depth_m: Vec<f32>,
    /// What each pixel sees ([`LABEL_NONE`], [`LABEL_TABLE`], …).
    pub label: Vec<u8>,
}

impl RenderedFrame {
    /// Number of pixels that see `label`.
    pub fn count(&self, label: u8) -> usize {
        self.label.iter().filter(|&&l| l == label).count()
    }
}

#[derive(Clone, Copy)]
struct Solid {
    min: [f64; 3],
    max: [f64; 3],
    label: u8,
    bgr: [u8; 3],
}

impl SyntheticCamera {
    /// Builds a camera from its description.
    ///
    /// # Errors
    /// [`SyntheticCameraConfigError`] naming the first bad value.
    pub fn new(config: SyntheticCameraConfig) -> Result<Self, SyntheticCameraConfigError> {
        config.intrinsics.validate()?;
        config.workspace.validate()?;
        let tape = config.tape_width_m;
        if !(tape.is_finite() && tape >= 0.0) {
            return Err(SyntheticCameraConfigError::TapeWidth(tape));
        }
        if tape * 2.0 >= config.workspace.size_m[0].min(config.workspace.size_m[1]) {
            return Err(SyntheticCameraConfigError::TapeTooWide(tape));
        }
        if !(config.table_half_extent_m.is_finite() && config.table_half_extent_m > 0.0) {
            return Err(SyntheticCameraConfigError::TableHalfExtent(
                config.table_half_extent_m,
            ));
        }
        let pose = CameraPose::look_at(config.pose.eye_m, config.pose.target_m)?;
        Ok(Self {
            model: CameraModel {
                intrinsics: config.intrinsics,
                pose,
            },
            config,
        })
    }

    /// Reads a camera description from TOML.
    ///
    /// # Errors
    /// [`SyntheticCameraLoadError`] for an unreadable file, malformed TOML or bad values.
    pub fn load(path: &Path) -> Result<Self, SyntheticCameraLoadError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SyntheticCameraLoadError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let config: SyntheticCameraConfig =
            toml::from_str(&text).map_err(|e| SyntheticCameraLoadError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        Self::new(config).map_err(|source| SyntheticCameraLoadError::Invalid {
            path: path.to_path_buf(),
            source,
        })
    }

    /// The workspace rectangle on the table of `scene`.
    pub fn workspace_for(&self, scene: &SceneFile) -> WorkspaceRect {
        WorkspaceRect {
            table_height_m: scene.table.height_m,
            ..self.config.workspace
        }
    }

    /// Exact sub-pixel image positions of the workspace corners (calibration order).
    pub fn workspace_corners_px(&self, scene: &SceneFile) -> Option<[[f64; 2]; 4]> {
        let ws = self.workspace_for(scene);
        let mut out = [[0.0; 2]; 4];
        for (o, c) in out.iter_mut().zip(ws.corners_xy_m()) {
            *o = self.model.project([c[0], c[1], ws.table_height_m])?.0;
        }
        Some(out)
    }

    /// The goal cube and the obstacle boxes of `scene` as labelled, coloured solids, every
    /// box where its path puts it `t_s` seconds after the scene came into force.
    fn solids(&self, scene: &SceneFile, t_s: f64) -> Vec<Solid> {
        let pal = self.config.palette;
        let mut solids = Vec::with_capacity(1 + scene.obstacles.len());
        let g = &scene.goal;
        let half = g.size_m / 2.0;
        solids.push(Solid {
            min: g.center_m.map(|c| c - half),
            max: g.center_m.map(|c| c + half),
            label: LABEL_GOAL,
            bgr: pal.goal_bgr,
        });
        for (i, b) in scene.obstacles.iter().enumerate() {
            let center_m = b.center_at(t_s);
            let mut min = [0.0; 3];
            let mut max = [0.0; 3];
            for a in 0..3 {
                min[a] = center_m[a] - b.size_m[a] / 2.0;
                max[a] = center_m[a] + b.size_m[a] / 2.0;
            }
            solids.push(Solid {
                min,
                max,
                label: LABEL_OBSTACLE0
                    .saturating_add(u8::try_from(i).unwrap_or(u8::MAX - LABEL_OBSTACLE0)),
                bgr: pal.obstacle_bgr,
            });
        }
        solids
    }

    /// The table top of `scene` with the taped rectangle on it.
    fn table_top(&self, scene: &SceneFile) -> TableTop {
        let ws = self.workspace_for(scene);
        let [x0, y0] = ws.min_xy_m;
        let [x1, y1] = [x0 + ws.size_m[0], y0 + ws.size_m[1]];
        TableTop {
            z: ws.table_height_m,
            workspace: [x0, y0, x1, y1],
            tape: self.config.tape_width_m,
            centre: [(x0 + x1) / 2.0, (y0 + y1) / 2.0],
            half_extent: self.config.table_half_extent_m,
            table_bgr: self.config.palette.table_bgr,
            tape_bgr: self.config.palette.tape_bgr,
        }
    }

    /// Renders `scene` as it stands when it comes into force (a moving box at the start of
    /// its path: [`SyntheticCamera::render_at`] at 0 s).
    pub fn render(&self, scene: &SceneFile) -> RenderedFrame {
        self.render_at(scene, 0.0)
    }

    /// Renders `scene` as it stands `t_s` seconds after it came into force: every box where
    /// its path puts it ([`shm_schemas::scene_file::BoxSpec::center_at`]).
    pub fn render_at(&self, scene: &SceneFile, t_s: f64) -> RenderedFrame {
        let k = self.config.intrinsics;
        let (w, h) = (k.width_px as usize, k.height_px as usize);
        let solids = self.solids(scene, t_s);
        let table = self.table_top(scene);
        let background = self.config.palette.background_bgr;

        let rot_inv = self.model.pose.rotation.inverse();
        let m = rot_inv.matrix();
        let col_x: Vector3<f64> = m.column(0).into();
        let col_y: Vector3<f64> = m.column(1).into();
        let col_z: Vector3<f64> = m.column(2).into();
        let eye = self.model.pose.eye_m();
        let o = [eye.x, eye.y, eye.z];

        let mut bgr = vec![0u8; w * h * 3];
        let mut depth = vec![f32::NAN; w * h];
        let mut label = vec![LABEL_NONE; w * h];
        for v in 0..h {
            let b = (v as f64 - k.cy_px) / k.fy_px;
            let row_dir = col_y * b + col_z;
            for u in 0..w {
                let a = (u as f64 - k.cx_px) / k.fx_px;
                // Camera-frame direction (a, b, 1): the ray parameter equals the depth.
                let dv = col_x * a + row_dir;
                let hit = trace(o, [dv.x, dv.y, dv.z], &table, &solids, background);
                let i = v * w + u;
                label[i] = hit.label;
                if hit.t.is_finite() {
                    depth[i] = hit.t as f32;
                }
                for c in 0..3 {
                    bgr[i * 3 + c] = (f64::from(hit.bgr[c]) * hit.shade).round() as u8;
                }
            }
        }
        RenderedFrame {
            width_px: w,
            height_px: h,
            bgr,
            depth_m: depth,
            label,
        }
    }
}

/// The table top: a square around the workspace centre at height `z`, with the tape along
/// the inside of the workspace rectangle.
struct TableTop {
    z: f64,
    /// `[xmin, ymin, xmax, ymax]` (m).
    workspace: [f64; 4],
    tape: f64,
    centre: [f64; 2],
    half_extent: f64,
    table_bgr: [u8; 3],
    tape_bgr: [u8; 3],
}

impl TableTop {
    /// Where a ray from `o` along `d` meets the table top: distance, label and colour.
    fn hit(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, u8, [u8; 3])> {
        let t = (self.z - o[2]) / d[2];
        let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
        let on_table = d[2] < -1e-12
            && t > 0.0
            && (x - self.centre[0]).abs() <= self.half_extent
            && (y - self.centre[1]).abs() <= self.half_extent;
        if !on_table {
            return None;
        }
        let [x0, y0, x1, y1] = self.workspace;
        let tape = self.tape;
        let inside = x >= x0 && x <= x1 && y >= y0 && y <= y1;
        let inner = x >= x0 + tape && x <= x1 - tape && y >= y0 + tape && y <= y1 - tape;
        Some(if inside && !inner {
            (t, LABEL_TAPE, self.tape_bgr)
        } else {
            (t, LABEL_TABLE, self.table_bgr)
        })
    }
}

/// What a pixel's ray hits first.
struct Hit {
    /// Ray parameter (= depth); infinite for nothing.
    t: f64,
    label: u8,
    bgr: [u8; 3],
    /// Brightness of the face (top 1.0, sides darker).
    shade: f64,
}

/// Casts the ray from `o` along `d` against the table and the solids.
fn trace(o: [f64; 3], d: [f64; 3], table: &TableTop, solids: &[Solid], background: [u8; 3]) -> Hit {
    let mut hit = Hit {
        t: f64::INFINITY,
        label: LABEL_NONE,
        bgr: background,
        shade: 1.0,
    };
    if let Some((t, label, bgr)) = table.hit(o, d) {
        (hit.t, hit.label, hit.bgr) = (t, label, bgr);
    }
    for s in solids {
        if let Some((t, axis)) = ray_box(o, d, s)
            && t < hit.t
        {
            hit = Hit {
                t,
                label: s.label,
                bgr: s.bgr,
                shade: match axis {
                    2 => 1.0,
                    0 => 0.78,
                    _ => 0.62,
                },
            };
        }
    }
    hit
}

/// Slab test: entry distance and the axis of the entry face, for a ray starting outside.
fn ray_box(o: [f64; 3], d: [f64; 3], s: &Solid) -> Option<(f64, usize)> {
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis = 0;
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            if o[a] < s.min[a] || o[a] > s.max[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let (mut t0, mut t1) = ((s.min[a] - o[a]) * inv, (s.max[a] - o[a]) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > t_near {
            t_near = t0;
            axis = a;
        }
        t_far = t_far.min(t1);
        if t_near > t_far {
            return None;
        }
    }
    (t_near > 0.0).then_some((t_near, axis))
}

/// A world script played by the synthetic camera: which scene is in force at a given time.
#[derive(Debug, Clone)]
pub struct ScriptedCamera {
    /// The camera.
    pub camera: SyntheticCamera,
    /// The timeline.
    pub script: shm_schemas::scene_file::WorldScript,
}

impl ScriptedCamera {
    /// Renders the scene in force `t_s` seconds after the script's start, its boxes where
    /// their paths put them (time counted from the step's `at_s`); returns the step index
    /// too, so callers can report scene changes.
    pub fn render_at(&self, t_s: f64) -> (usize, &SceneFile, RenderedFrame) {
        let (idx, scene) = self.script.scene_at(t_s);
        let since_s = self.script.steps.get(idx).map_or(0.0, |(at_s, _)| *at_s);
        (idx, scene, self.camera.render_at(scene, t_s - since_s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    pub(crate) fn camera() -> SyntheticCamera {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../assets/perception/synthetic_camera.toml");
        SyntheticCamera::load(&path).unwrap()
    }

    fn scene() -> SceneFile {
        SceneFile::from_toml_str(
            "[goal]\ncenter_m = [0.40, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.35, -0.1, 0.05]\nsize_m = [0.06, 0.08, 0.10]\n",
            Path::new("<inline>"),
        )
        .unwrap()
    }

    #[test]
    fn depth_is_exact_on_the_table_and_on_a_box_top() {
        let cam = camera();
        let s = scene();
        let f = cam.render(&s);
        // Project a point on the box's top face to the nearest pixel centre, back-project it
        // with the rendered depth: it must land on the top face (z = 0.10) exactly.
        let (px, _) = cam.model.project([0.35, -0.1, 0.10]).unwrap();
        let (u, v) = (px[0].round() as usize, px[1].round() as usize);
        let i = v * f.width_px + u;
        assert_eq!(f.label[i], LABEL_OBSTACLE0);
        let p = cam
            .model
            .unproject(u as f64, v as f64, f64::from(f.depth_m[i]));
        assert!((p[2] - 0.10).abs() < 1e-5, "{p:?}");
        // A table pixel well away from everything.
        let (px, _) = cam.model.project([0.5, 0.0, 0.0]).unwrap();
        let (u, v) = (px[0].round() as usize, px[1].round() as usize);
        let i = v * f.width_px + u;
        assert_eq!(f.label[i], LABEL_TABLE);
        let p = cam
            .model
            .unproject(u as f64, v as f64, f64::from(f.depth_m[i]));
        assert!(p[2].abs() < 1e-5, "{p:?}");
    }

    #[test]
    fn the_whole_workspace_and_its_objects_are_in_view() {
        let cam = camera();
        let s = scene();
        let corners = cam.workspace_corners_px(&s).unwrap();
        let k = cam.config.intrinsics;
        for c in corners {
            assert!(
                c[0] > 10.0 && c[0] < f64::from(k.width_px) - 10.0,
                "{corners:?}"
            );
            assert!(
                c[1] > 10.0 && c[1] < f64::from(k.height_px) - 10.0,
                "{corners:?}"
            );
        }
        // Image order: top-left, top-right, bottom-right, bottom-left.
        assert!(corners[0][0] < corners[1][0] && corners[3][0] < corners[2][0]);
        assert!(corners[0][1] < corners[3][1] && corners[1][1] < corners[2][1]);
        let f = cam.render(&s);
        assert!(f.count(LABEL_GOAL) > 500 && f.count(LABEL_OBSTACLE0) > 500);
        assert!(f.count(LABEL_TAPE) > 1000);
        // A taller box covers more pixels.
        let mut tall = s.clone();
        tall.obstacles[0].size_m[2] = 0.3;
        tall.obstacles[0].center_m[2] = 0.15;
        assert!(cam.render(&tall).count(LABEL_OBSTACLE0) > f.count(LABEL_OBSTACLE0) * 2);
    }

    /// The label of the pixel that sees the top face's centre of a box centred at `c`
    /// (0.10 m tall, on the table).
    fn label_at_top(cam: &SyntheticCamera, f: &RenderedFrame, c: [f64; 3]) -> u8 {
        let (px, _) = cam.model.project([c[0], c[1], c[2] + 0.05]).unwrap();
        let (u, v) = (px[0].round() as usize, px[1].round() as usize);
        f.label[v * f.width_px + u]
    }

    #[test]
    fn a_moving_box_is_drawn_where_its_path_puts_it() {
        let cam = camera();
        let s = SceneFile::from_toml_str(
            "[goal]\ncenter_m = [0.40, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\n\
             center_m = [0.35, -0.2, 0.05]\nsize_m = [0.06, 0.06, 0.10]\n\
             path = [ { at_s = 1.0, center_m = [0.35, -0.2, 0.05] }, \
                      { at_s = 2.0, center_m = [0.35, 0.0, 0.05] } ]\n",
            Path::new("<inline>"),
        )
        .unwrap();
        let (start, end) = ([0.35, -0.2, 0.05], [0.35, 0.0, 0.05]);
        // Before its path starts (and in a plain render) it stands at the first keyframe.
        for f in [cam.render(&s), cam.render_at(&s, 0.5)] {
            assert_eq!(label_at_top(&cam, &f, start), LABEL_OBSTACLE0);
            assert_eq!(label_at_top(&cam, &f, end), LABEL_TABLE);
        }
        // Half way, and after the last keyframe.
        let mid = cam.render_at(&s, 1.5);
        assert_eq!(
            label_at_top(&cam, &mid, [0.35, -0.1, 0.05]),
            LABEL_OBSTACLE0
        );
        assert_eq!(label_at_top(&cam, &mid, start), LABEL_TABLE);
        let late = cam.render_at(&s, 9.0);
        assert_eq!(label_at_top(&cam, &late, end), LABEL_OBSTACLE0);
        assert_eq!(label_at_top(&cam, &late, start), LABEL_TABLE);
        // A world script counts from the step's at_s.
        let scripted = ScriptedCamera {
            camera: cam.clone(),
            script: shm_schemas::scene_file::WorldScript {
                steps: vec![(0.0, scene()), (10.0, s)],
            },
        };
        let (step, _, f) = scripted.render_at(11.5);
        assert_eq!(step, 1);
        assert_eq!(label_at_top(&cam, &f, [0.35, -0.1, 0.05]), LABEL_OBSTACLE0);
    }

    #[test]
    fn bad_camera_files_are_rejected_with_the_reason() {
        let mut c = camera().config;
        c.tape_width_m = 1.0;
        assert!(
            SyntheticCamera::new(c.clone())
                .unwrap_err()
                .to_string()
                .contains("tape")
        );
        c.tape_width_m = 0.02;
        c.pose.target_m = c.pose.eye_m;
        let e = SyntheticCamera::new(c).unwrap_err();
        assert!(matches!(e, SyntheticCameraConfigError::Pose(_)), "{e:?}");
        assert!(e.to_string().contains("degenerate"), "{e}");
        let err = SyntheticCamera::load(Path::new("/nonexistent/cam.toml")).unwrap_err();
        assert!(err.to_string().contains("cannot read"));
    }
}
