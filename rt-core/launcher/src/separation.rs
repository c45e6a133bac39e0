//! The separation of the arm from the world's boxes over a run (issue 33 item 2): for every
//! arm state the launcher observes, the shortest distance from the arm's surface to any
//! obstacle box of the scene in force, where each box *really* is at that moment (moving
//! boxes on their paths, from when their scene came into force).
//!
//! Measured apart from the twin, like `xarm-sim`'s referee: the arm is the datasheet's (the
//! referee's DH kinematics and unpadded link bodies, `xarm_referee`), the boxes are the
//! world's ground truth, not what perception saw. Zero or less is contact. The report plots
//! it over time ([`plot_separation`], `separation.png`) and `summary.json` gives its minimum
//! while the arm moved and while it was at rest (`min_separation_moving_m`,
//! `min_separation_at_rest_m`).

use std::path::Path;

use plotters::prelude::*;
use shm_schemas::scene_file::SceneFile;
use xarm_referee::distance::{Aabb, segment_box_m};
use xarm_referee::kinematics::forward;
use xarm_referee::{ArmCapsules, LINKS};

use crate::report::{ReportError, tick_text};

/// Samples kept at most (a 10-minute run at 100 Hz); later ones fold into the last one
/// (its minimum).
const MAX_SAMPLES: usize = 60_000;

/// Samples closer together than this are merged (the smaller separation kept), s.
const MIN_SPACING_S: f64 = 0.01;

/// One point of the separation curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeparationSample {
    /// Launcher time, s.
    pub t_s: f64,
    /// Shortest distance from the arm's surface to any box, m (∞ without boxes; ≤ 0 is
    /// contact).
    pub separation_m: f64,
    /// Whether the arm moved since the state before.
    pub moving: bool,
}

/// The separation of `q_rad` from the boxes of `scene` at `t_in_scene_s` after it came into
/// force, m (∞ without boxes).
pub fn separation_m(q_rad: &[f64; 5], scene: &SceneFile, t_in_scene_s: f64) -> f64 {
    let caps = ArmCapsules::from_frames(&forward(q_rad));
    let mut best = f64::INFINITY;
    for b in &scene.obstacles {
        let bx = Aabb::from_center_size(&b.center_at(t_in_scene_s), &b.size_m);
        for (seg, link) in caps.segments_m.iter().zip(LINKS) {
            best = best.min(segment_box_m(&seg[0], &seg[1], &bx) - link.radius_m);
        }
    }
    best
}

/// The curve over a run.
#[derive(Debug, Clone, Default)]
pub struct SeparationTrace {
    samples: Vec<SeparationSample>,
    min_moving_m: Option<f64>,
    min_at_rest_m: Option<f64>,
}

impl SeparationTrace {
    /// Adds a sample (merged with the last when closer than `MIN_SPACING_S`).
    pub fn push(&mut self, s: SeparationSample) {
        if !s.separation_m.is_finite() {
            return;
        }
        let slot = if s.moving {
            &mut self.min_moving_m
        } else {
            &mut self.min_at_rest_m
        };
        *slot = Some(slot.map_or(s.separation_m, |m| m.min(s.separation_m)));
        let full = self.samples.len() >= MAX_SAMPLES;
        match self.samples.last_mut() {
            Some(last) if full || s.t_s - last.t_s < MIN_SPACING_S => {
                last.separation_m = last.separation_m.min(s.separation_m);
                last.moving |= s.moving;
            }
            _ => self.samples.push(s),
        }
    }

    /// The samples, oldest first.
    pub fn samples(&self) -> &[SeparationSample] {
        &self.samples
    }

    /// The smallest separation while the arm moved, m.
    pub fn min_moving_m(&self) -> Option<f64> {
        self.min_moving_m
    }

    /// The smallest separation while the arm was at rest, m.
    pub fn min_at_rest_m(&self) -> Option<f64> {
        self.min_at_rest_m
    }
}

/// Draws the separation over time (moving: blue, at rest: grey), with the world changes at
/// `changes_s` as vertical lines and contact (0) as a red line.
///
/// # Errors
/// [`ReportError::Plot`].
pub fn plot_separation(
    out: &Path,
    samples: &[SeparationSample],
    changes_s: &[f64],
) -> Result<(), ReportError> {
    let err = |message: String| ReportError::Plot(out.to_path_buf(), message);
    let t_hi = samples.last().map_or(1.0, |s| s.t_s).max(1.0);
    let y_hi = samples
        .iter()
        .map(|s| s.separation_m)
        .fold(0.05f64, f64::max)
        .min(1.0);
    let y_lo = samples
        .iter()
        .map(|s| s.separation_m)
        .fold(0.0f64, f64::min)
        .max(-0.2);
    let root = BitMapBackend::new(out, (900, 400)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Separation of the arm from the boxes (datasheet arm, true boxes)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..t_hi, (y_lo - 0.005)..(y_hi * 1.05))
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("time since start (s)")
        .y_desc("separation (m)")
        .x_labels(10)
        .y_labels(6)
        .x_label_formatter(&|v| tick_text(*v))
        .y_label_formatter(&|v| tick_text(*v))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for &t in changes_s {
        chart
            .draw_series(LineSeries::new(
                [(t, y_lo - 0.005), (t, y_hi * 1.05)],
                BLACK.mix(0.3).stroke_width(1),
            ))
            .map_err(|e| err(e.to_string()))?;
    }
    chart
        .draw_series(LineSeries::new(
            [(0.0, 0.0), (t_hi, 0.0)],
            RED.stroke_width(1),
        ))
        .map_err(|e| err(e.to_string()))?
        .label("contact")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 12, y)], RED.stroke_width(1)));
    let moving = BLUE.stroke_width(2);
    let resting = BLACK.mix(0.4).stroke_width(2);
    chart
        .draw_series(samples.windows(2).map(|w| {
            let style = if w[1].moving { moving } else { resting };
            PathElement::new(
                [
                    (w[0].t_s, w[0].separation_m.min(y_hi * 1.05)),
                    (w[1].t_s, w[1].separation_m.min(y_hi * 1.05)),
                ],
                style,
            )
        }))
        .map_err(|e| err(e.to_string()))?
        .label("arm moving (blue) / at rest (grey)")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], moving));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::scene_file::{BoxPath, BoxSpec, GoalSpec, Keyframe, TableSpec};

    fn scene_with(boxes: Vec<BoxSpec>) -> SceneFile {
        SceneFile {
            name: "s".into(),
            table: TableSpec::default(),
            goal: GoalSpec {
                center_m: [0.3, 0.25, 0.025],
                size_m: 0.05,
            },
            obstacles: boxes,
        }
    }

    /// The flange sits at (0.207, 0, 0.112) m at zero joints; link5's body is a capsule of
    /// radius 0.035 m from the wrist down to the flange. A box whose top face is 0.05 m
    /// below the flange is 0.05 − 0.035 m from link5's surface, by hand; the same box moved
    /// along its path to 1 m away is far.
    #[test]
    fn separation_is_measured_from_the_arm_surface_to_where_the_box_is_now() {
        let top_z = 0.112 - 0.05;
        let path = BoxPath::new(&[
            Keyframe {
                at_s: 0.0,
                center_m: [0.207, 0.0, top_z - 0.01],
            },
            Keyframe {
                at_s: 1.0,
                center_m: [1.2, 0.0, top_z - 0.01],
            },
        ])
        .unwrap();
        let scene = scene_with(vec![BoxSpec {
            center_m: [0.207, 0.0, top_z - 0.01],
            size_m: [0.02, 0.02, 0.02],
            path,
        }]);
        let d = separation_m(&[0.0; 5], &scene, 0.0);
        assert!((d - (0.05 - 0.035)).abs() < 1e-4, "{d}");
        assert!(separation_m(&[0.0; 5], &scene, 1.0) > 0.5);
        assert!(separation_m(&[0.0; 5], &scene_with(Vec::new()), 0.0).is_infinite());
    }

    #[test]
    fn the_trace_keeps_the_minimum_while_moving_and_at_rest_apart() {
        let mut t = SeparationTrace::default();
        for (t_s, sep, moving) in [
            (0.0, 0.30, false),
            (0.005, 0.20, true),
            (0.1, 0.05, true),
            (0.2, 0.01, false),
        ] {
            t.push(SeparationSample {
                t_s,
                separation_m: sep,
                moving,
            });
        }
        assert_eq!(t.min_moving_m(), Some(0.05));
        assert_eq!(t.min_at_rest_m(), Some(0.01));
        // The first two merged (5 ms apart), keeping the smaller.
        assert_eq!(t.samples().len(), 3);
        assert_eq!(t.samples()[0].separation_m, 0.20);
        let dir = std::env::temp_dir().join(format!("foresight-sep-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        plot_separation(&dir.join("s.png"), t.samples(), &[0.1]).unwrap();
        let bytes = std::fs::read(dir.join("s.png")).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
