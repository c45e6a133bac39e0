//! Per-run metrics: one CSV row per PPO iteration (rewritten atomically, so a reader or a
//! crash never sees a torn file) and an SVG reward curve (`reward.svg`, drawn by
//! [`crate::chart`], also replaced atomically: temporary file, then rename).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::chart::{Chart, Panel, Series};
use crate::checkpoint::{CheckpointError, write_atomic};
use crate::ppo::{EvalResult, IterStats};

/// One CSV row.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsRow {
    /// Training statistics of the iteration.
    pub iter: IterStats,
    /// Seconds since the run started.
    pub wall_s: f64,
    /// Environment steps per second over the iteration (rollout + update).
    pub steps_per_s: f64,
    /// Evaluation, when one ran after this iteration.
    pub eval: Option<EvalResult>,
}

/// The rows of one run.
#[derive(Debug, Clone, Default)]
pub struct MetricsLog {
    /// Rows in order.
    pub rows: Vec<MetricsRow>,
}

/// CSV header.
pub const HEADER: &str = "steps,iteration,wall_s,episodes,mean_return,success_rate,collision_rate,policy_loss,value_loss,entropy,approx_kl,clip_fraction,steps_per_s,eval_success_rate,eval_collision_rate,eval_mean_return";

fn num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.6}")
    } else {
        String::new()
    }
}

impl MetricsLog {
    /// The CSV text.
    pub fn to_csv(&self) -> String {
        let mut s = String::from(HEADER);
        s.push('\n');
        for r in &self.rows {
            let i = &r.iter;
            let (es, ec, er) = r
                .eval
                .map_or((String::new(), String::new(), String::new()), |e| {
                    (
                        num(e.success_rate),
                        num(e.collision_rate),
                        num(e.mean_return),
                    )
                });
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{es},{ec},{er}",
                i.steps,
                i.iteration,
                num(r.wall_s),
                i.episodes,
                num(i.mean_return),
                num(i.success_rate),
                num(i.collision_rate),
                num(i.policy_loss),
                num(i.value_loss),
                num(i.entropy),
                num(i.approx_kl),
                num(i.clip_fraction),
                num(r.steps_per_s),
            );
        }
        s
    }

    /// Parses CSV written by [`MetricsLog::to_csv`] (to continue a resumed run's log);
    /// malformed lines are skipped.
    pub fn from_csv(text: &str) -> Self {
        let mut rows = Vec::new();
        for line in text.lines().skip(1) {
            let c: Vec<&str> = line.split(',').collect();
            if c.len() != HEADER.split(',').count() {
                continue;
            }
            let f = |i: usize| c[i].parse::<f64>().unwrap_or(f64::NAN);
            let (Ok(steps), Ok(iteration), Ok(episodes)) = (
                c[0].parse::<u64>(),
                c[1].parse::<u64>(),
                c[3].parse::<usize>(),
            ) else {
                continue;
            };
            let eval = (!c[13].is_empty()).then(|| EvalResult {
                episodes: 0,
                success_rate: f(13),
                collision_rate: f(14),
                mean_return: f(15),
            });
            rows.push(MetricsRow {
                iter: IterStats {
                    steps,
                    iteration,
                    episodes,
                    mean_return: f(4),
                    success_rate: f(5),
                    collision_rate: f(6),
                    policy_loss: f(7),
                    value_loss: f(8),
                    entropy: f(9),
                    approx_kl: f(10),
                    clip_fraction: f(11),
                    ..Default::default()
                },
                wall_s: f(2),
                steps_per_s: f(12),
                eval,
            });
        }
        Self { rows }
    }

    /// Writes the CSV atomically.
    ///
    /// # Errors
    /// [`CheckpointError::Io`].
    pub fn write_csv(&self, path: &Path) -> Result<(), CheckpointError> {
        write_atomic(path, self.to_csv().as_bytes())
    }

    /// The reward curve as an SVG document: training mean return and evaluation return
    /// over environment steps, evaluation success rate below; `None` while no training
    /// episode has finished.
    pub fn reward_svg(&self, title: &str) -> Option<String> {
        let train: Vec<(f64, f64)> = self
            .rows
            .iter()
            .filter(|r| r.iter.mean_return.is_finite())
            .map(|r| (r.iter.steps as f64, r.iter.mean_return))
            .collect();
        let eval: Vec<(f64, f64)> = self
            .rows
            .iter()
            .filter_map(|r| r.eval.map(|e| (r.iter.steps as f64, e.mean_return)))
            .collect();
        let succ: Vec<(f64, f64)> = self
            .rows
            .iter()
            .filter_map(|r| r.eval.map(|e| (r.iter.steps as f64, e.success_rate)))
            .collect();
        if train.is_empty() {
            return None;
        }
        let x_max = train.iter().map(|p| p.0).fold(1.0, f64::max);
        let ys = train.iter().chain(&eval).map(|p| p.1);
        let (mut y_min, mut y_max) =
            ys.fold((f64::MAX, f64::MIN), |(a, b), y| (a.min(y), b.max(y)));
        if y_max - y_min < 1e-6 {
            y_min -= 1.0;
            y_max += 1.0;
        }
        let pad = (y_max - y_min) * 0.05;
        let returns = [
            Series {
                name: "training (mean of finished episodes)",
                class: "train",
                color: "blue",
                width: 1.0,
                points: &train,
            },
            Series {
                name: "evaluation (deterministic)",
                class: "eval",
                color: "red",
                width: 2.0,
                points: &eval,
            },
        ];
        let success = [Series {
            name: "evaluation success rate",
            class: "success",
            color: "green",
            width: 2.0,
            points: &succ,
        }];
        let panels = [
            Panel {
                top: 40.0,
                height: 330.0,
                y_range: (y_min - pad, y_max + pad),
                y_label: "episode return",
                series: &returns,
                legend: true,
            },
            Panel {
                top: 410.0,
                height: 140.0,
                y_range: (0.0, 1.05),
                y_label: "eval success",
                series: &success,
                legend: false,
            },
        ];
        let chart = Chart {
            title,
            x_label: "environment steps",
            x_range: (0.0, x_max),
            panels: &panels,
        };
        Some(chart.to_svg())
    }

    /// Writes [`MetricsLog::reward_svg`] to `path` (temporary file beside it, then rename);
    /// writes nothing while no training episode has finished.
    ///
    /// # Errors
    /// [`MetricsPlotError::Io`] naming the file that could not be written or renamed.
    pub fn plot(&self, path: &Path, title: &str) -> Result<(), MetricsPlotError> {
        let Some(svg) = self.reward_svg(title) else {
            return Ok(());
        };
        let tmp = path.with_extension("tmp.svg");
        let io = |p: &Path| {
            let path = p.to_path_buf();
            move |source| MetricsPlotError::Io { path, source }
        };
        std::fs::write(&tmp, svg).map_err(io(&tmp))?;
        std::fs::rename(&tmp, path).map_err(io(path))
    }
}

/// Why [`MetricsLog::plot`] could not write the reward curve.
#[derive(Debug, thiserror::Error)]
pub enum MetricsPlotError {
    /// Writing the temporary file or renaming it failed.
    #[error("reward plot {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_has_a_row_per_iteration_and_empty_cells_without_eval() {
        let mut log = MetricsLog::default();
        for k in 1..=3u64 {
            log.rows.push(MetricsRow {
                iter: IterStats {
                    steps: k * 100,
                    iteration: k,
                    mean_return: k as f64,
                    ..Default::default()
                },
                wall_s: k as f64,
                steps_per_s: 100.0,
                eval: (k == 2).then_some(EvalResult {
                    episodes: 4,
                    success_rate: 0.5,
                    collision_rate: 0.25,
                    mean_return: 3.0,
                }),
            });
        }
        let csv = log.to_csv();
        assert_eq!(MetricsLog::from_csv(&csv).to_csv(), csv);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4);
        let ncol = HEADER.split(',').count();
        assert!(lines.iter().all(|l| l.split(',').count() == ncol));
        assert!(
            lines[2].ends_with("0.500000,0.250000,3.000000"),
            "{}",
            lines[2]
        );
        assert!(lines[1].ends_with(",,,"));
        let dir = std::env::temp_dir().join(format!("learner-metrics-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        log.write_csv(&dir.join("m.csv")).unwrap();
        assert_eq!(std::fs::read_to_string(dir.join("m.csv")).unwrap(), csv);
        log.plot(&dir.join("r.svg"), "test <&>").unwrap();
        let svg = std::fs::read_to_string(dir.join("r.svg")).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("test &lt;&amp;&gt;"));
        let points = |class: &str| {
            let tag = format!(r#"<polyline class="{class}" points=""#);
            let start = svg.find(&tag).expect("polyline") + tag.len();
            let end = start + svg[start..].find('"').unwrap();
            svg[start..end].split(' ').count()
        };
        assert_eq!(points("train"), 3);
        assert_eq!(points("eval"), 1);
        assert_eq!(svg.matches("<polyline").count(), 3);
        assert!(!dir.join("r.tmp.svg").exists());
        std::fs::remove_dir_all(&dir).ok();
    }
}
