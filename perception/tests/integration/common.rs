//! Shared helpers: the synthetic camera of the assets, random scenes, exact calibrations.

use std::path::{Path, PathBuf};

use perception::calibration::{Calibration, CalibrationFile};
use perception::synthetic::{LABEL_GOAL, LABEL_OBSTACLE0, SyntheticCamera};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::scene_file::{BoxSpec, GoalSpec, SceneFile, TableSpec};

pub fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/perception")
}

pub fn camera() -> SyntheticCamera {
    SyntheticCamera::load(&assets().join("synthetic_camera.toml")).unwrap()
}

pub fn exact_calibration(cam: &SyntheticCamera, scene: &SceneFile) -> Calibration {
    Calibration::new(CalibrationFile {
        camera: perception::camera_id::CalibrationCamera::synthetic(
            perception::camera_id::CalibratedAt::now(),
        ),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(scene),
        corners_px: cam.workspace_corners_px(scene).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap()
}

/// Footprints (x0, y0, x1, y1) of the goal and obstacles.
fn footprints(s: &SceneFile) -> Vec<[f64; 4]> {
    let g = &s.goal;
    let mut v = vec![[
        g.center_m[0] - g.size_m / 2.0,
        g.center_m[1] - g.size_m / 2.0,
        g.center_m[0] + g.size_m / 2.0,
        g.center_m[1] + g.size_m / 2.0,
    ]];
    for b in &s.obstacles {
        v.push([
            b.center_m[0] - b.size_m[0] / 2.0,
            b.center_m[1] - b.size_m[1] / 2.0,
            b.center_m[0] + b.size_m[0] / 2.0,
            b.center_m[1] + b.size_m[1] / 2.0,
        ]);
    }
    v
}

/// A random scene inside the workspace: a goal cube (4–6 cm) and 1–3 obstacle boxes
/// (4–10 cm footprint, 5–30 cm tall), footprints at least 3 cm apart. Scenes where any
/// object is more than 3 % hidden behind another are redrawn: a camera cannot measure what
/// it cannot see (the test is about measurement, not about guessing hidden faces).
pub fn random_scene(cam: &SyntheticCamera, rng: &mut ChaCha8Rng) -> SceneFile {
    let ws = cam.config.workspace;
    let margin = 0.05;
    loop {
        let place = |sx: f64, sy: f64, rng: &mut ChaCha8Rng| {
            [
                rng.random_range(
                    ws.min_xy_m[0] + margin + sx / 2.0
                        ..ws.min_xy_m[0] + ws.size_m[0] - margin - sx / 2.0,
                ),
                rng.random_range(
                    ws.min_xy_m[1] + margin + sy / 2.0
                        ..ws.min_xy_m[1] + ws.size_m[1] - margin - sy / 2.0,
                ),
            ]
        };
        let gs = rng.random_range(0.04..0.06);
        let gp = place(gs, gs, rng);
        let mut scene = SceneFile {
            name: "random".into(),
            table: TableSpec { height_m: 0.0 },
            goal: GoalSpec {
                center_m: [gp[0], gp[1], gs / 2.0],
                size_m: gs,
            },
            obstacles: Vec::new(),
        };
        let n = rng.random_range(1..=3);
        for _ in 0..n {
            let size = [
                rng.random_range(0.04..0.10),
                rng.random_range(0.04..0.10),
                rng.random_range(0.05..0.30),
            ];
            let p = place(size[0], size[1], rng);
            scene.obstacles.push(BoxSpec {
                center_m: [p[0], p[1], size[2] / 2.0],
                size_m: size,
                path: Default::default(),
            });
        }
        let fp = footprints(&scene);
        let apart = (0..fp.len()).all(|i| {
            (i + 1..fp.len()).all(|j| {
                let (a, b) = (fp[i], fp[j]);
                a[2] + 0.03 < b[0] || b[2] + 0.03 < a[0] || a[3] + 0.03 < b[1] || b[3] + 0.03 < a[1]
            })
        });
        if !apart || scene.validate().is_err() {
            continue;
        }
        if visible_enough(cam, &scene) {
            return scene;
        }
    }
}

fn visible_enough(cam: &SyntheticCamera, scene: &SceneFile) -> bool {
    let full = cam.render(scene);
    let alone_goal = SceneFile {
        obstacles: Vec::new(),
        ..scene.clone()
    };
    if (full.count(LABEL_GOAL) as f64) < 0.97 * cam.render(&alone_goal).count(LABEL_GOAL) as f64 {
        return false;
    }
    for (i, b) in scene.obstacles.iter().enumerate() {
        let alone = SceneFile {
            goal: GoalSpec {
                center_m: [-2.5, 2.5, 0.01],
                size_m: 0.01,
            },
            obstacles: vec![*b],
            ..scene.clone()
        };
        let n_alone = cam.render(&alone).count(LABEL_OBSTACLE0) as f64;
        if (full.count(LABEL_OBSTACLE0 + i as u8) as f64) < 0.97 * n_alone {
            return false;
        }
    }
    true
}

/// A table with nothing on it (the goal cube lies far outside the camera's view).
pub fn empty_scene() -> SceneFile {
    SceneFile {
        name: "empty".into(),
        table: TableSpec { height_m: 0.0 },
        goal: GoalSpec {
            center_m: [-2.5, 2.5, 0.01],
            size_m: 0.02,
        },
        obstacles: Vec::new(),
    }
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}
