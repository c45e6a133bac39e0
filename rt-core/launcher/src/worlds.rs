//! The unseen-worlds benchmark (`foresight --runs N --seed S --worlds random`): one row per
//! world from its run's summary — boxes, outcome (`reached`, `infeasible`, `not_learned`),
//! zero-shot or retrained, world change → motion, retraining time, collisions — printed as a
//! table, and written as `worlds.md`, `worlds.json` and the plot `worlds.png` (each world's
//! world change → motion time, coloured by outcome) into `<out>/worlds-seed<S>/`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;
use serde::Serialize;
use shm_schemas::scene_file::SceneFile;

use crate::report::{Outcome, ReportError, Summary};
use crate::run_dir::write_atomic;

/// One world's end-to-end result.
#[derive(Debug, Clone, Serialize)]
pub struct WorldRun {
    /// Run number.
    pub index: usize,
    /// Boxes in the world.
    pub boxes: usize,
    /// The tallest box (m).
    pub tallest_box_m: f64,
    /// How it ended.
    pub outcome: Outcome,
    /// Why (plain words; empty when reached).
    pub reason: String,
    /// The policy in force passed the lookahead at once.
    pub zero_shot: Option<bool>,
    /// World change → the arm moving toward the new goal (s).
    pub change_to_motion_s: Option<f64>,
    /// The first settled frame of the new scene → the arm moving (s): the twin's part of
    /// the reaction (perception's quiet time before it excluded).
    pub settled_to_motion_s: Option<f64>,
    /// The first settled frame of the new scene → the twin's first approved plan on it (s).
    pub settled_to_approval_s: Option<f64>,
    /// Retrain request → new policy (s).
    pub retrain_s: Option<f64>,
    /// Collisions the arm reported.
    pub collisions: u64,
    /// What moved the arm (`policy`, `planner`, `planner, then policy`; empty: nothing).
    pub executor: String,
    /// The run's folder.
    pub run_dir: PathBuf,
    /// The world.
    pub scene: SceneFile,
}

impl WorldRun {
    /// The row of run `index` over world `scene`.
    pub fn new(index: usize, scene: &SceneFile, s: &Summary, run_dir: PathBuf) -> Self {
        Self {
            index,
            boxes: scene.obstacles.len(),
            tallest_box_m: scene
                .obstacles
                .iter()
                .map(|b| b.size_m[2])
                .fold(0.0, f64::max),
            outcome: s.outcome,
            reason: s.outcome_reason.clone(),
            zero_shot: s.zero_shot,
            change_to_motion_s: s.world_change_to_motion_s,
            settled_to_motion_s: s
                .world_change_to_motion_s
                .zip(s.world_change_to_settled_s)
                .map(|(m, st)| m - st),
            settled_to_approval_s: s
                .world_change_to_approval_s
                .zip(s.world_change_to_settled_s)
                .map(|(a, st)| a - st),
            retrain_s: s.retrain_s,
            collisions: s.collisions,
            executor: s.executor.clone(),
            run_dir,
            scene: scene.clone(),
        }
    }
}

/// The benchmark's aggregate figures.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct WorldsAggregate {
    /// Worlds run.
    pub worlds: usize,
    /// Reached.
    pub reached: usize,
    /// Refused as infeasible.
    pub infeasible: usize,
    /// Not learned in time.
    pub not_learned: usize,
    /// Reached with the policy in force (no retraining).
    pub zero_shot: usize,
    /// Collisions over all runs.
    pub collisions: u64,
    /// Median world change → motion over the reached worlds (s).
    pub change_to_motion_median_s: Option<f64>,
    /// 95th percentile of the same (s; nearest rank).
    pub change_to_motion_p95_s: Option<f64>,
    /// Median settled scene → motion over the worlds reached zero-shot or by the planner
    /// fallback, without a retraining in between (s).
    pub settled_to_motion_median_s: Option<f64>,
    /// Median settled scene → approved plan over the same worlds (s).
    pub settled_to_approval_median_s: Option<f64>,
    /// Median retraining time over the retrained worlds (s).
    pub retrain_median_s: Option<f64>,
}

fn percentile(v: &[f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = ((p * s.len() as f64).ceil() as usize).clamp(1, s.len());
    Some(s[rank - 1])
}

/// The aggregate of `rows`.
pub fn aggregate(rows: &[WorldRun]) -> WorldsAggregate {
    let count = |o: Outcome| rows.iter().filter(|r| r.outcome == o).count();
    let motion: Vec<f64> = rows
        .iter()
        .filter(|r| r.outcome == Outcome::Reached)
        .filter_map(|r| r.change_to_motion_s)
        .collect();
    let settled_motion: Vec<f64> = rows
        .iter()
        .filter(|r| r.outcome == Outcome::Reached && r.retrain_s.is_none())
        .filter_map(|r| r.settled_to_motion_s)
        .collect();
    let settled_approval: Vec<f64> = rows
        .iter()
        .filter(|r| r.outcome == Outcome::Reached && r.retrain_s.is_none())
        .filter_map(|r| r.settled_to_approval_s)
        .collect();
    let retrain: Vec<f64> = rows.iter().filter_map(|r| r.retrain_s).collect();
    WorldsAggregate {
        worlds: rows.len(),
        reached: count(Outcome::Reached),
        infeasible: count(Outcome::Infeasible),
        not_learned: count(Outcome::NotLearned),
        zero_shot: rows
            .iter()
            .filter(|r| r.outcome == Outcome::Reached && r.zero_shot == Some(true))
            .count(),
        collisions: rows.iter().map(|r| r.collisions).sum(),
        change_to_motion_median_s: percentile(&motion, 0.5),
        change_to_motion_p95_s: percentile(&motion, 0.95),
        settled_to_motion_median_s: percentile(&settled_motion, 0.5),
        settled_to_approval_median_s: percentile(&settled_approval, 0.5),
        retrain_median_s: percentile(&retrain, 0.5),
    }
}

fn secs(v: Option<f64>) -> String {
    v.map_or("–".to_owned(), |s| format!("{s:.2}"))
}

/// The Markdown table (with the aggregate line above it).
pub fn table(seed: u64, rows: &[WorldRun]) -> String {
    let a = aggregate(rows);
    let mut md = format!(
        "# Unseen worlds, end to end (seed {seed})\n\n{} worlds: {} reached ({} zero-shot), {} \
         refused as infeasible, {} not learned; {} collision(s). World change → motion over \
         the reached worlds: median {} s, p95 {} s; settled scene → approved plan without retraining: \
         median {} ms, → the arm moved 2 mrad: median {} ms. Retraining: median {} s.\n\n",
        a.worlds,
        a.reached,
        a.zero_shot,
        a.infeasible,
        a.not_learned,
        a.collisions,
        secs(a.change_to_motion_median_s),
        secs(a.change_to_motion_p95_s),
        a.settled_to_approval_median_s
            .map_or("–".to_owned(), |v| format!("{:.0}", 1e3 * v)),
        a.settled_to_motion_median_s
            .map_or("–".to_owned(), |v| format!("{:.0}", 1e3 * v)),
        secs(a.retrain_median_s),
    );
    md += "| # | boxes | tallest (m) | outcome | zero-shot | moved by | change → motion (s) | settled → motion (ms) | retraining (s) | collisions | reason |\n";
    md += "|---|---|---|---|---|---|---|---|---|---|---|\n";
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.index,
            r.boxes,
            r.tallest_box_m,
            r.outcome.name(),
            r.zero_shot.map_or("–", |z| if z { "yes" } else { "no" }),
            if r.executor.is_empty() {
                "–"
            } else {
                &r.executor
            },
            secs(r.change_to_motion_s),
            r.settled_to_motion_s
                .map_or("–".to_owned(), |v| format!("{:.0}", 1e3 * v)),
            secs(r.retrain_s),
            r.collisions,
            r.reason.replace('|', "/"),
        );
    }
    md
}

/// Writes `worlds.md`, `worlds.json` and `worlds.png` into `dir`; returns the table.
///
/// # Errors
/// [`ReportError`] when a file cannot be written.
pub fn write_benchmark(dir: &Path, seed: u64, rows: &[WorldRun]) -> Result<String, ReportError> {
    std::fs::create_dir_all(dir).map_err(|e| ReportError::Io(dir.to_path_buf(), e))?;
    let md = table(seed, rows);
    let png = dir.join("worlds.png");
    plot(&png, rows)?;
    let md_full = format!("{md}\n![world change → motion per world](worlds.png)\n");
    write_atomic(&dir.join("worlds.md"), md_full.as_bytes())
        .map_err(|e| ReportError::Io(dir.join("worlds.md"), e))?;
    let json = serde_json::json!({ "seed": seed, "aggregate": aggregate(rows), "worlds": rows });
    let text = serde_json::to_string_pretty(&json).unwrap_or_default();
    write_atomic(&dir.join("worlds.json"), text.as_bytes())
        .map_err(|e| ReportError::Io(dir.join("worlds.json"), e))?;
    Ok(md)
}

/// One bar per world: world change → motion (s), green reached zero-shot, blue reached after
/// retraining, grey refused as infeasible (bar at 0), red not learned (bar at the top).
fn plot(out: &Path, rows: &[WorldRun]) -> Result<(), ReportError> {
    let err = |e: String| ReportError::Plot(out.to_path_buf(), e);
    let root = BitMapBackend::new(out, (1000, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let top = rows
        .iter()
        .filter_map(|r| r.change_to_motion_s)
        .fold(1.0f64, f64::max)
        * 1.15;
    let n = rows.len().max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Unseen worlds: world change → motion (green zero-shot, blue retrained, grey infeasible, red not learned)",
            ("sans-serif", 18),
        )
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), 0.0f64..top)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("world")
        .y_desc("world change → motion (s)")
        // One label per world (at most 20), as whole numbers; the seconds as 0.5, 1, 1.5.
        .x_labels(n.min(20) * 2 + 1)
        .x_label_formatter(&|x| {
            let k = x.round();
            if (x - k).abs() < 1e-6 && k >= 0.0 {
                format!("{k:.0}")
            } else {
                String::new()
            }
        })
        .y_label_formatter(&|y| crate::report::tick_text(*y))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (i, r) in rows.iter().enumerate() {
        let x = i as f64;
        let (colour, h) = match r.outcome {
            Outcome::Reached if r.zero_shot == Some(true) => {
                (RGBColor(46, 160, 67), r.change_to_motion_s.unwrap_or(0.0))
            }
            Outcome::Reached => (RGBColor(31, 119, 180), r.change_to_motion_s.unwrap_or(0.0)),
            Outcome::Infeasible => (RGBColor(150, 150, 150), top * 0.03),
            Outcome::NotLearned => (RGBColor(214, 39, 40), top),
        };
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x - 0.35, 0.0), (x + 0.35, h)],
                colour.filled(),
            )))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(i: usize, outcome: Outcome, zero: bool, motion: Option<f64>) -> WorldRun {
        WorldRun {
            index: i,
            boxes: 1,
            tallest_box_m: 0.2,
            outcome,
            reason: String::new(),
            zero_shot: Some(zero),
            change_to_motion_s: motion,
            settled_to_motion_s: motion.map(|m| m - 0.1),
            settled_to_approval_s: motion.map(|_| 0.01),
            retrain_s: (!zero).then_some(3.0),
            collisions: 0,
            executor: "policy".into(),
            run_dir: PathBuf::new(),
            scene: SceneFile {
                name: format!("world {i}"),
                table: Default::default(),
                goal: shm_schemas::scene_file::GoalSpec {
                    center_m: [0.4, 0.1, 0.025],
                    size_m: 0.05,
                },
                obstacles: Vec::new(),
            },
        }
    }

    #[test]
    fn the_aggregate_counts_outcomes_and_takes_percentiles_over_reached_worlds() {
        let rows = vec![
            row(0, Outcome::Reached, true, Some(0.4)),
            row(1, Outcome::Reached, false, Some(6.0)),
            row(2, Outcome::Infeasible, false, None),
            row(3, Outcome::NotLearned, false, Some(50.0)),
            row(4, Outcome::Reached, true, Some(0.5)),
        ];
        let a = aggregate(&rows);
        assert_eq!(
            (a.reached, a.infeasible, a.not_learned, a.zero_shot),
            (3, 1, 1, 2)
        );
        assert_eq!(a.change_to_motion_median_s, Some(0.5));
        assert_eq!(a.change_to_motion_p95_s, Some(6.0));
        assert_eq!(a.retrain_median_s, Some(3.0));
        // Settled → motion over the worlds reached without retraining (0.3 and 0.4 s): the
        // lower of the two by nearest rank.
        let settled = a.settled_to_motion_median_s.unwrap();
        assert!((settled - 0.3).abs() < 1e-9, "{settled}");
        assert_eq!(a.settled_to_approval_median_s, Some(0.01));
        let dir = std::env::temp_dir().join(format!("foresight-worlds-{}", std::process::id()));
        let md = write_benchmark(&dir, 7, &rows).unwrap();
        assert!(md.contains("| 2 | 1 | 0.20 | infeasible |"), "{md}");
        assert!(dir.join("worlds.png").metadata().unwrap().len() > 1000);
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("worlds.json")).unwrap()).unwrap();
        assert_eq!(json["aggregate"]["infeasible"], 1);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
