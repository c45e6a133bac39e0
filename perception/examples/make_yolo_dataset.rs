//! Renders random synthetic scenes and writes them as an Ultralytics (YOLO) detection dataset,
//! the training data of the bundled `assets/perception/models/foresight-tiny-*.onnx`
//! (`scripts/train-yolo.sh` runs this, then `perception/tests/python/train_yolo_synthetic.py`).
//!
//! ```text
//! scripts/cargo.sh run --release -p perception --example make_yolo_dataset -- \
//!     --out DIR --count 1000 --seed 1 --val-fraction 0.2
//! ```
//!
//! Writes `DIR/images/{train,val}/NNNNN.png` (1280×720 BGR renders of the bundled synthetic
//! camera), `DIR/labels/{train,val}/NNNNN.txt` (`class cx cy w h`, normalised; class 0 = goal,
//! 1 = obstacle) and `DIR/data.yaml`. Each box is the tight pixel box of the object's visible
//! pixels in the renderer's exact label image (objects with fewer than `--min-pixels` visible
//! pixels get no box). Scenes: table top at −3…+3 cm, a goal cube of 4–6 cm and 0–4 boxes
//! (footprint 3–10 cm, 4–40 cm tall), anywhere inside the taped workspace, footprints at least
//! 1 cm apart (objects may hide each other partly). The same seed gives the same files.
//! `--scenes accuracy-test --val-fraction 1` writes instead the scenes of perception's accuracy
//! test (no object more than 3 % hidden) as a val-only set, to check a trained model on them.
//! `DIR/complete.txt` is written last (the arguments), so a caller can tell a finished dataset.

// A developer tool over test fixtures: a failed unwrap or expect ends the run with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Parser;
use perception::annotate::write_image;
use perception::frame::Frame;
use perception::synthetic::{LABEL_GOAL, LABEL_OBSTACLE0, RenderedFrame, SyntheticCamera};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::scene_file::{BoxSpec, GoalSpec, SceneFile, TableSpec};

/// Writes a YOLO dataset of random synthetic renders.
#[derive(Parser, Debug)]
struct Args {
    /// Output folder (created; files of an earlier run with the same names are overwritten).
    #[arg(long)]
    out: PathBuf,
    /// Number of images (train + val).
    #[arg(long, default_value_t = 1000)]
    count: usize,
    /// Random seed of the scenes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Fraction of the images kept for validation (the last ones).
    #[arg(long, default_value_t = 0.2)]
    val_fraction: f64,
    /// Objects with fewer visible pixels than this get no box.
    #[arg(long, default_value_t = 20)]
    min_pixels: usize,
    /// Scene distribution: `train` (the default, above) or `accuracy-test` (the scenes of
    /// perception's accuracy test: table at 0, goal 4–6 cm, 1–3 boxes 4–10 cm wide and
    /// 5–30 cm tall, 5 cm from the workspace edge, footprints 3 cm apart, redrawn when an
    /// object is more than 3 % hidden), for checking a trained model on what that test sees.
    #[arg(long, default_value = "train", value_parser = ["train", "accuracy-test"])]
    scenes: String,
    /// Synthetic camera description.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/perception/synthetic_camera.toml"))]
    camera: PathBuf,
}

/// Minimum gap between two footprints (m).
const GAP_M: f64 = 0.01;

/// A random scene: table height, a goal cube and 0–4 boxes inside the workspace.
fn random_scene(cam: &SyntheticCamera, rng: &mut ChaCha8Rng) -> SceneFile {
    let ws = cam.config.workspace;
    let [x0, y0] = ws.min_xy_m;
    let [x1, y1] = [x0 + ws.size_m[0], y0 + ws.size_m[1]];
    let table = rng.random_range(-0.03..0.03);
    loop {
        // Footprints [xmin, ymin, xmax, ymax] placed so far; a new one must keep GAP_M away.
        let mut placed: Vec<[f64; 4]> = Vec::new();
        let mut place = |sx: f64, sy: f64, rng: &mut ChaCha8Rng| -> Option<[f64; 2]> {
            for _ in 0..50 {
                let c = [
                    rng.random_range(x0 + sx / 2.0..x1 - sx / 2.0),
                    rng.random_range(y0 + sy / 2.0..y1 - sy / 2.0),
                ];
                let f = [
                    c[0] - sx / 2.0,
                    c[1] - sy / 2.0,
                    c[0] + sx / 2.0,
                    c[1] + sy / 2.0,
                ];
                let apart = placed.iter().all(|p| {
                    f[2] + GAP_M < p[0]
                        || p[2] + GAP_M < f[0]
                        || f[3] + GAP_M < p[1]
                        || p[3] + GAP_M < f[1]
                });
                if apart {
                    placed.push(f);
                    return Some(c);
                }
            }
            None
        };
        let gs = rng.random_range(0.04..0.06);
        let Some(gp) = place(gs, gs, rng) else {
            continue;
        };
        let mut scene = SceneFile {
            name: "yolo-dataset".into(),
            table: TableSpec { height_m: table },
            goal: GoalSpec {
                center_m: [gp[0], gp[1], table + gs / 2.0],
                size_m: gs,
            },
            obstacles: Vec::new(),
        };
        let n = rng.random_range(0..=4);
        for _ in 0..n {
            let size = [
                rng.random_range(0.03..0.10),
                rng.random_range(0.03..0.10),
                rng.random_range(0.04..0.40),
            ];
            if let Some(p) = place(size[0], size[1], rng) {
                scene.obstacles.push(BoxSpec {
                    center_m: [p[0], p[1], table + size[2] / 2.0],
                    size_m: size,
                    path: Default::default(),
                });
            }
        }
        if scene.validate().is_ok() {
            return scene;
        }
    }
}

/// The accuracy test's own scene sampler (`random_scene`, no object more than 3 % hidden),
/// shared rather than copied so that `--scenes accuracy-test` draws exactly what the test does.
#[path = "../tests/integration/common.rs"]
#[allow(dead_code)]
mod common;

/// Tight pixel boxes `[umin, vmin, umax, vmax]` (inclusive) and pixel counts per label.
fn label_boxes(f: &RenderedFrame, labels: usize) -> Vec<Option<([usize; 4], usize)>> {
    let mut out: Vec<Option<([usize; 4], usize)>> = vec![None; labels];
    for v in 0..f.height_px {
        for u in 0..f.width_px {
            let l = f.label[v * f.width_px + u] as usize;
            if l < labels {
                let e = out[l].get_or_insert(([u, v, u, v], 0));
                e.0[0] = e.0[0].min(u);
                e.0[1] = e.0[1].min(v);
                e.0[2] = e.0[2].max(u);
                e.0[3] = e.0[3].max(v);
                e.1 += 1;
            }
        }
    }
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    if !(0.0..=1.0).contains(&args.val_fraction) || args.count == 0 {
        return Err("--count must be ≥ 1 and --val-fraction in [0, 1]".into());
    }
    let cam = SyntheticCamera::load(&args.camera)?;
    let n_val = (args.count as f64 * args.val_fraction).round() as usize;
    let n_train = args.count - n_val;
    for split in ["train", "val"] {
        std::fs::create_dir_all(args.out.join("images").join(split))?;
        std::fs::create_dir_all(args.out.join("labels").join(split))?;
    }
    let _ = std::fs::remove_file(args.out.join("complete.txt"));
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let start = Instant::now();
    let mut counts = [[0usize; 2]; 2]; // [split][class]
    let mut skipped = 0usize;
    for i in 0..args.count {
        let scene = if args.scenes == "train" {
            random_scene(&cam, &mut rng)
        } else {
            common::random_scene(&cam, &mut rng)
        };
        let frame = cam.render(&scene);
        let (w, h) = (frame.width_px as f64, frame.height_px as f64);
        let n_labels = LABEL_OBSTACLE0 as usize + scene.obstacles.len();
        let boxes = label_boxes(&frame, n_labels);
        let mut text = String::new();
        let split = usize::from(i >= n_train);
        for (l, b) in boxes.iter().enumerate().skip(LABEL_GOAL as usize) {
            let class = usize::from(l != LABEL_GOAL as usize);
            match b {
                Some((bb, px)) if *px >= args.min_pixels => {
                    // Pixel u covers [u, u + 1): the box spans umin … umax + 1.
                    let (bx0, by0) = (bb[0] as f64, bb[1] as f64);
                    let (bx1, by1) = (bb[2] as f64 + 1.0, bb[3] as f64 + 1.0);
                    writeln!(
                        text,
                        "{class} {:.6} {:.6} {:.6} {:.6}",
                        (bx0 + bx1) / 2.0 / w,
                        (by0 + by1) / 2.0 / h,
                        (bx1 - bx0) / w,
                        (by1 - by0) / h
                    )?;
                    counts[split][class] += 1;
                }
                _ => skipped += 1,
            }
        }
        let (dir, name) = (["train", "val"][split], format!("{i:05}"));
        let img = Frame::from_rendered(&frame, i as u64, 0)?.bgr;
        write_image(
            &args
                .out
                .join("images")
                .join(dir)
                .join(format!("{name}.png")),
            &img,
        )?;
        std::fs::write(
            args.out
                .join("labels")
                .join(dir)
                .join(format!("{name}.txt")),
            text,
        )?;
        if (i + 1) % 50 == 0 || i + 1 == args.count {
            let el = start.elapsed().as_secs_f64();
            println!(
                "make_yolo_dataset: {}/{} images ({:.1} s, {:.0} ms/image)",
                i + 1,
                args.count,
                el,
                el * 1e3 / (i + 1) as f64
            );
        }
    }
    let abs = std::fs::canonicalize(&args.out)?;
    std::fs::write(
        args.out.join("data.yaml"),
        format!(
            "# Written by perception/examples/make_yolo_dataset.rs (--count {} --seed {} --val-fraction {} --scenes {})\n\
             path: {}\ntrain: images/train\nval: images/val\nnames:\n  0: goal\n  1: obstacle\n",
            args.count,
            args.seed,
            args.val_fraction,
            args.scenes,
            yaml_path(&abs)
        ),
    )?;
    println!(
        "make_yolo_dataset: {n_train} train images (goal {}, obstacle {} boxes), {n_val} val images \
         (goal {}, obstacle {} boxes), {skipped} objects under {} visible pixels left out, {:.1} s → {}",
        counts[0][0],
        counts[0][1],
        counts[1][0],
        counts[1][1],
        args.min_pixels,
        start.elapsed().as_secs_f64(),
        abs.display()
    );
    std::fs::write(
        args.out.join("complete.txt"),
        format!(
            "count={} seed={} val_fraction={} min_pixels={} scenes={}\n",
            args.count, args.seed, args.val_fraction, args.min_pixels, args.scenes
        ),
    )?;
    Ok(())
}

/// A path as a double-quoted YAML scalar.
fn yaml_path(p: &Path) -> String {
    format!(
        "\"{}\"",
        p.display()
            .to_string()
            .replace('\\', "\\\\")
            .replace('"', "\\\"")
    )
}
