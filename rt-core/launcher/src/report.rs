//! The run report: `summary.json` (the figures a person or CI reads), PNG plots made with
//! plotters (TCP path top and side views over the obstacles and goals, reward curves of
//! pre-training and retraining from the learner's CSVs) and `report.md` linking everything.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use shm_schemas::scene_file::SceneFile;

use super::run_dir::write_atomic;

/// The run's headline figures (`summary.json`). Times are from the world change; `None`
/// when the event did not happen.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Summary {
    /// Whether the arm reached the final goal.
    pub goal_reached: bool,
    /// How the run ended: every goal reached, a world the learner proved infeasible (the
    /// arm held), or a goal not learned in time (the first scene that decides it).
    #[serde(default)]
    pub outcome: Outcome,
    /// Why, in plain words (empty when every goal was reached).
    #[serde(default)]
    pub outcome_reason: String,
    /// Whether the policy in force passed the lookahead on the last scene at the first
    /// try (no retraining); `None` when no verdict came.
    #[serde(default)]
    pub zero_shot: Option<bool>,
    /// Collisions reported by the arm (xarm-sim's ground truth, or the real controller).
    pub collisions: u64,
    /// Whether the lookahead flagged the coming collision before the arm moved in the new
    /// scene.
    pub collision_predicted_before_motion: bool,
    /// Policies swapped into the running loop.
    pub policy_swaps: u64,
    /// Times the arm stopped for an obstacle (a plan the twin revoked, or a command the
    /// shield refused, while a box moved into its way): `paused` in the timeline.
    #[serde(default)]
    pub pauses: u64,
    /// The longest such pause, stop → moving again (s); `None` when no pause ended.
    #[serde(default)]
    pub longest_pause_s: Option<f64>,
    /// The smallest separation of the arm (the datasheet's, unpadded) from the world's true
    /// boxes while it moved, m (`separation.png` plots it over time; ≤ 0 is contact).
    #[serde(default)]
    pub min_separation_moving_m: Option<f64>,
    /// The same while the arm was at rest (a box moving into a still arm), m.
    #[serde(default)]
    pub min_separation_at_rest_m: Option<f64>,
    /// World change → first detection of the new scene (s).
    pub world_change_to_detection_s: Option<f64>,
    /// World change → the first settled frame showing the new scene (s): from then on the
    /// twin may approve a plan for it.
    #[serde(default)]
    pub world_change_to_settled_s: Option<f64>,
    /// World change → the first plan the twin approved on the settled new scene (s).
    #[serde(default)]
    pub world_change_to_approval_s: Option<f64>,
    /// World change → first verdict on the new scene (s).
    pub world_change_to_verdict_s: Option<f64>,
    /// Retraining wall time: retrain request → new policy published (s).
    pub retrain_s: Option<f64>,
    /// World change → the arm moving again under an approved plan (s).
    pub world_change_to_motion_s: Option<f64>,
    /// Cycle compute time, 99th percentile (µs).
    pub cycle_p99_us: Option<f64>,
    /// Cycle compute time, 99.9th percentile (µs).
    pub cycle_p999_us: Option<f64>,
    /// What real-time set-up rt-core's cycle thread got (the launcher asks for SCHED_FIFO
    /// and a pinned core; `{"pinned": {"Ok": 1}, "fifo": {"Err": 1}, ...}`: granted, or the
    /// OS's errno), and its wake-up latency (µs); from rt-core's summary line.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rt_core_realtime: Option<serde_json::Value>,
    /// rt-core's reactions to a scene that made the running plan unsafe: how many, and
    /// from the causing frame's capture (through perception) and from its acceptance to the
    /// first changed command, µs (count, p50, max; p99 from 100 and p99.9 from 1 000
    /// reactions, else null); from rt-core's summary line.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reaction: Option<serde_json::Value>,
    /// Whether the lookahead gate was on (`--no-lookahead` turns it off).
    pub lookahead: bool,
    /// Whether the planner fallback was on (`--planner-fallback`).
    #[serde(default)]
    pub planner_fallback: bool,
    /// What moved the arm on the last scene: `policy`, `planner`, `planner, then policy`
    /// (the planner's path first, a retrained policy's plan replacing it), or empty when
    /// nothing did.
    #[serde(default)]
    pub executor: String,
    /// Perception's detector (`--detector`: `colour` or `yolo`); empty in summaries written
    /// before the option existed.
    #[serde(default)]
    pub detector: String,
    /// Where the goal came from: `camera` (the goal cube perception saw) or `action` (the
    /// ROS 2 `Reach` action); empty in summaries written before the option existed.
    #[serde(default)]
    pub goal_source: String,
    /// Seed of the scenario.
    pub seed: u64,
    /// Processes restarted by the supervisor.
    pub restarts: u64,
    /// Servo commands the simulated arm refused (out of range, or sent while it could not
    /// move); `None` on a real arm. An unsafe command reaching the arm shows up here or as
    /// a collision.
    #[serde(default)]
    pub arm_rejected_commands: Option<u64>,
    /// With `--learner-host`: where and how the remote retraining went.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remote_learner: Option<RemoteLearner>,
    /// Every act of the run (scene by scene): goals, retraining, acceptance, executor.
    #[serde(default)]
    pub acts: Vec<crate::acts::ActSummary>,
    /// Each time rt-core said a box had taken a scene's goal (issue 42 item 4), on the frame
    /// that showed it: `scene <i> (+<s> s): infeasible: <reason>` (time since the scene came
    /// into force). The goal is live again once the box leaves, so a later `reached` stands.
    #[serde(default)]
    pub goal_taken: Vec<String>,
    /// Free-form notes (e.g. what timed out).
    pub notes: Vec<String>,
}

/// How a run ended (`summary.json`'s `outcome`).
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Every goal was reached.
    #[default]
    Reached,
    /// The learner's feasibility check found no safe way to a goal; the arm was held.
    Infeasible,
    /// A goal was not reached in time: the policy was not (re)learned, or a plan refused.
    NotLearned,
}

impl Outcome {
    /// The name in `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Reached => "reached",
            Self::Infeasible => "infeasible",
            Self::NotLearned => "not_learned",
        }
    }
}

/// The remote retraining of a `--learner-host` run, from the controller relay's status file.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(default)]
pub struct RemoteLearner {
    /// The learner host's name (from its relay's hellos; empty if never heard from).
    pub host: String,
    /// `--peer` endpoints used.
    pub peers: Vec<String>,
    /// `--listen` endpoints used.
    pub listen: Vec<String>,
    /// Retrain requests carried there.
    pub requests: u64,
    /// Requests answered (a policy published or the budget exhausted).
    pub answered: u64,
    /// Per answered request: request reached the relay → answer back (s).
    pub request_to_answer_s: Vec<f64>,
    /// Per answered request: the learner's own training wall time (s).
    pub remote_training_s: Vec<f64>,
    /// Requests and policies sent again after silence.
    pub resends: u64,
    /// Times the learner host fell silent.
    pub link_losses: u64,
    /// Total silence (s).
    pub link_down_s: f64,
    /// Messages refused (schema mismatch, invalid, malformed, bad signature, replay,
    /// oversize, flood, …).
    pub rejected: u64,
    /// The same by reason (the relay's names: `bad_signature`, `replay`, `flood`, …).
    pub rejected_by_reason: std::collections::BTreeMap<String, u64>,
    /// The last refusal, in words.
    pub last_rejection: Option<String>,
}

impl RemoteLearner {
    /// From the controller relay's status file.
    pub fn from_status(st: &zenoh_relay::status::RelayStatus) -> Self {
        let answered: Vec<_> = st
            .requests
            .iter()
            .filter_map(|r| r.answered_unix_s.map(|a| (a - r.submitted_unix_s, r)))
            .collect();
        Self {
            host: st.peer.as_ref().map(|p| p.host.clone()).unwrap_or_default(),
            peers: st.peers.clone(),
            listen: st.listen.clone(),
            requests: st.requests.len() as u64,
            answered: answered.len() as u64,
            request_to_answer_s: answered.iter().map(|(d, _)| *d).collect(),
            remote_training_s: answered
                .iter()
                .filter_map(|(_, r)| r.remote_wall_time_s)
                .collect(),
            resends: st.resends,
            link_losses: st.link_losses,
            link_down_s: st.link_down_s,
            rejected: st.rejected.values().sum(),
            rejected_by_reason: st.rejected.clone(),
            last_rejection: st.last_rejection.clone(),
        }
    }

    /// One sentence for the report.
    pub fn describe(&self) -> String {
        let host = if self.host.is_empty() {
            "a learner host that was never heard from".to_owned()
        } else {
            format!("`{}`", self.host)
        };
        let via: Vec<&str> = self
            .peers
            .iter()
            .chain(&self.listen)
            .map(String::as_str)
            .collect();
        let mut line = format!(
            "retrained on {host} (link {}): {} request(s), {} answered",
            via.join(", "),
            self.requests,
            self.answered
        );
        for (i, d) in self.request_to_answer_s.iter().enumerate() {
            let _ = write!(line, "; request → answer {d:.2} s");
            if let Some(t) = self.remote_training_s.get(i) {
                let _ = write!(line, " ({t:.2} s training there)");
            }
        }
        let _ = write!(
            line,
            "; {} re-send(s); link lost {} time(s), {:.1} s in all; {} message(s) refused",
            self.resends, self.link_losses, self.link_down_s, self.rejected
        );
        line
    }
}

/// What `xarm-sim`'s independent referee saw in the run: its `referee` object in the
/// simulator's status/summary JSON (its own kinematics and link shapes, not the twin's).
/// `None` in a run report on a real arm.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(default)]
pub struct RefereeFigures {
    /// Contacts the referee called (each raised the controller's collision error):
    /// `contacts_while_moving + contacts_at_rest`.
    pub contacts: u64,
    /// Contacts that began while the arm was moving: the controller's failure.
    pub contacts_while_moving: u64,
    /// Contacts that began with the arm at rest: a moving box walked into it.
    pub contacts_at_rest: u64,
    /// Motion steps it judged.
    pub steps: u64,
    /// The smallest clearance it saw (m); ≤ 0 is contact.
    pub min_clearance_m: Option<f64>,
    /// The link of that clearance ("link4").
    pub min_link: Option<String>,
    /// What the link was nearest to ("obstacle 2", "table", or a link name).
    pub min_other: Option<String>,
    /// The scene in force then.
    pub min_scene: Option<String>,
}

impl RefereeFigures {
    /// The figures in `xarm-sim`'s status JSON, if it has them.
    pub fn from_sim_status(status: &serde_json::Value) -> Option<Self> {
        status
            .get("referee")
            .and_then(|v| serde_json::from_value(v.clone()).ok())
    }

    /// One line: "0 collisions, minimum clearance 23.4 mm (link4–obstacle 2)".
    pub fn describe(&self) -> String {
        let plural = if self.contacts == 1 { "" } else { "s" };
        let mut line = format!("{} collision{plural}", self.contacts);
        match self.min_clearance_m {
            Some(m) if m.is_finite() => {
                let _ = write!(line, ", minimum clearance {:.1} mm", m * 1e3);
                if let (Some(a), Some(b)) = (&self.min_link, &self.min_other) {
                    let _ = write!(line, " ({a}–{b})");
                }
            }
            _ => line.push_str(", no clearance measured"),
        }
        line
    }
}

/// One sample of the executed TCP path.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct PathSample {
    /// Time since the run started (s).
    pub t_s: f64,
    /// TCP position (m).
    pub tcp_m: [f64; 3],
    /// Index of the world scene in force.
    pub scene: usize,
}

/// Why a report file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file could not be written.
    #[error("cannot write {0}: {1}")]
    Io(PathBuf, std::io::Error),
    /// A plot could not be drawn.
    #[error("cannot draw {0}: {1}")]
    Plot(PathBuf, String),
}

/// `summary.json`: the summary's fields, plus `referee` when the arm was simulated.
#[derive(Serialize)]
struct SummaryFile<'a> {
    #[serde(flatten)]
    summary: &'a Summary,
    #[serde(skip_serializing_if = "Option::is_none")]
    referee: Option<&'a RefereeFigures>,
}

/// The text of `summary.json`: the summary's fields, plus `referee` (the simulator's
/// independent referee) when given.
pub fn summary_json(summary: &Summary, referee: Option<&RefereeFigures>) -> String {
    serde_json::to_string_pretty(&SummaryFile { summary, referee }).unwrap_or_default()
}

/// Writes `summary.json` atomically ([`summary_json`]).
///
/// # Errors
/// [`ReportError::Io`].
pub fn write_summary(
    path: &Path,
    summary: &Summary,
    referee: Option<&RefereeFigures>,
) -> Result<(), ReportError> {
    let text = summary_json(summary, referee);
    write_atomic(path, text.as_bytes()).map_err(|e| ReportError::Io(path.to_path_buf(), e))
}

const SCENE_COLOURS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
];

/// An axis tick as a person writes it: `1M`, `1.5M`, `250k`, `0.25`, `-2` (never
/// `1000000.0`): thousands and millions as `k` and `M`, at most two decimals, no trailing zeros.
pub fn tick_text(v: f64) -> String {
    let (scaled, suffix) = if v.abs() >= 1e6 - 0.5 {
        (v / 1e6, "M")
    } else if v.abs() >= 1e3 - 0.5 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let text = format!("{scaled:.2}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    let text = if text == "-0" { "0" } else { text };
    format!("{text}{suffix}")
}

fn plot_err(path: &Path) -> impl Fn(String) -> ReportError + '_ {
    move |e| ReportError::Plot(path.to_path_buf(), e)
}

/// Which plane a view shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// x–y (from above).
    Top,
    /// x–z (from the side).
    Side,
}

/// Draws the executed TCP path (coloured by scene) over the obstacles (hatched per scene)
/// and goals of every scene, in one view.
///
/// # Errors
/// [`ReportError::Plot`].
pub fn plot_path(
    out: &Path,
    view: View,
    path: &[PathSample],
    scenes: &[(f64, SceneFile)],
) -> Result<(), ReportError> {
    let err = plot_err(out);
    let root = BitMapBackend::new(out, (900, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (ax, bx, title, xl, yl) = match view {
        View::Top => (0usize, 1usize, "TCP path, top view (x–y)", "x (m)", "y (m)"),
        View::Side => (0, 2, "TCP path, side view (x–z)", "x (m)", "z (m)"),
    };
    let (y_lo, y_hi) = match view {
        View::Top => (-0.5, 0.5),
        View::Side => (0.0, 0.7),
    };
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(-0.1f64..0.8f64, y_lo..y_hi)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(xl)
        .y_desc(yl)
        .x_labels(10)
        .y_labels(8)
        .x_label_formatter(&|v| tick_text(*v))
        .y_label_formatter(&|v| tick_text(*v))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (i, (at_s, scene)) in scenes.iter().enumerate() {
        let c = SCENE_COLOURS[i % SCENE_COLOURS.len()];
        for (k, b) in scene.obstacles.iter().enumerate() {
            let lo = (
                b.center_m[ax] - b.size_m[ax] / 2.0,
                b.center_m[bx] - b.size_m[bx] / 2.0,
            );
            let hi = (
                b.center_m[ax] + b.size_m[ax] / 2.0,
                b.center_m[bx] + b.size_m[bx] / 2.0,
            );
            let label = format!("scene {i} (from {at_s:.0} s) obstacle");
            let series = chart
                .draw_series(std::iter::once(Rectangle::new(
                    [lo, hi],
                    c.mix(0.25).filled(),
                )))
                .map_err(|e| err(e.to_string()))?;
            if k == 0 {
                series.label(label).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.mix(0.4).filled())
                });
            }
            chart
                .draw_series(std::iter::once(Rectangle::new([lo, hi], c.stroke_width(2))))
                .map_err(|e| err(e.to_string()))?;
        }
        let g = &scene.goal;
        let h = g.size_m / 2.0;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [
                    (g.center_m[ax] - h, g.center_m[bx] - h),
                    (g.center_m[ax] + h, g.center_m[bx] + h),
                ],
                GREEN.mix(0.6).filled(),
            )))
            .map_err(|e| err(e.to_string()))?;
        chart
            .draw_series(std::iter::once(Text::new(
                format!("goal {i}"),
                (g.center_m[ax] + h + 0.01, g.center_m[bx] + h),
                ("sans-serif", 16),
            )))
            .map_err(|e| err(e.to_string()))?;
    }
    if view == View::Side {
        let table = scenes.first().map_or(0.0, |s| s.1.table.height_m);
        chart
            .draw_series(LineSeries::new(
                [(-0.1, table), (0.8, table)],
                BLACK.stroke_width(2),
            ))
            .map_err(|e| err(e.to_string()))?
            .label("table")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 12, y)], BLACK));
    }
    let n_scenes = path.iter().map(|p| p.scene).max().map_or(0, |m| m + 1);
    for s in 0..n_scenes {
        let c = SCENE_COLOURS[s % SCENE_COLOURS.len()];
        let pts: Vec<(f64, f64)> = path
            .iter()
            .filter(|p| p.scene == s)
            .map(|p| (p.tcp_m[ax], p.tcp_m[bx]))
            .collect();
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(3)))
            .map_err(|e| err(e.to_string()))?
            .label(format!("TCP path in scene {s}"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], c.stroke_width(3)));
    }
    if let Some(p0) = path.first() {
        chart
            .draw_series(std::iter::once(Circle::new(
                (p0.tcp_m[ax], p0.tcp_m[bx]),
                6,
                BLACK.filled(),
            )))
            .map_err(|e| err(e.to_string()))?
            .label("start")
            .legend(|(x, y)| Circle::new((x + 6, y), 5, BLACK.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

/// A reward curve read from a learner CSV: `(steps, mean_return)` pairs.
///
/// The CSV needs a header naming a step column (`steps`/`step`/`total_steps`) and a return
/// column (`mean_return`/`eval_return`/`return`).
///
/// # Errors
/// A message when the file is unreadable or lacks the columns.
pub fn read_reward_curve(csv: &Path) -> Result<Vec<(f64, f64)>, String> {
    let text = std::fs::read_to_string(csv).map_err(|e| format!("{}: {e}", csv.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| format!("{}: empty", csv.display()))?
        .split(',')
        .map(str::trim)
        .collect();
    let find = |names: &[&str]| header.iter().position(|h| names.contains(h));
    let si = find(&["steps", "step", "total_steps"])
        .ok_or_else(|| format!("{}: no steps column", csv.display()))?;
    let ri = find(&["mean_return", "eval_return", "return"])
        .ok_or_else(|| format!("{}: no mean_return column", csv.display()))?;
    Ok(lines
        .filter_map(|l| {
            let cols: Vec<&str> = l.split(',').collect();
            let s = cols.get(si)?.trim().parse::<f64>().ok()?;
            let r = cols.get(ri)?.trim().parse::<f64>().ok()?;
            (s.is_finite() && r.is_finite()).then_some((s, r))
        })
        .collect())
}

/// Plots reward curves (one line per labelled curve) against environment steps.
///
/// # Errors
/// [`ReportError::Plot`].
pub fn plot_reward_curves(
    out: &Path,
    title: &str,
    curves: &[(String, Vec<(f64, f64)>)],
) -> Result<(), ReportError> {
    let err = plot_err(out);
    let (mut x_hi, mut y_lo, mut y_hi) = (1.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for (_, c) in curves {
        for (s, r) in c {
            x_hi = x_hi.max(*s);
            y_lo = y_lo.min(*r);
            y_hi = y_hi.max(*r);
        }
    }
    if !y_lo.is_finite() {
        (y_lo, y_hi) = (0.0, 1.0);
    }
    let pad = ((y_hi - y_lo) * 0.05).max(1e-3);
    let root = BitMapBackend::new(out, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..x_hi, (y_lo - pad)..(y_hi + pad))
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("environment steps")
        .y_desc("mean episode return")
        .x_labels(7)
        .y_labels(7)
        .x_label_formatter(&|v| tick_text(*v))
        .y_label_formatter(&|v| tick_text(*v))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (i, (label, c)) in curves.iter().enumerate() {
        let col = SCENE_COLOURS[i % SCENE_COLOURS.len()];
        chart
            .draw_series(LineSeries::new(c.iter().copied(), col.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?
            .label(label.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], col.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

fn on_off(b: bool) -> &'static str {
    if b { "on" } else { "off" }
}

fn fmt_opt(v: Option<f64>, unit: &str) -> String {
    v.map_or_else(|| "—".to_owned(), |x| format!("{x:.3} {unit}"))
}

/// Writes `report.md`: the summary table (with the simulator's referee line when given),
/// the timeline and links to every artefact.
///
/// # Errors
/// [`ReportError::Io`].
pub fn write_markdown(
    out: &Path,
    summary: &Summary,
    referee: Option<&RefereeFigures>,
    timeline: &[String],
    images: &[(&str, &str)],
    files: &[(&str, &str)],
) -> Result<(), ReportError> {
    let mut md = String::new();
    let verdict = if summary.collisions > 0 {
        "the arm COLLIDED".to_owned()
    } else if summary.goal_reached && summary.outcome == Outcome::Reached {
        "goal reached with no collision".to_owned()
    } else if summary.outcome == Outcome::Infeasible {
        format!(
            "no safe way found: {}; the arm was held, no collision",
            summary.outcome_reason
        )
    } else {
        format!("goal NOT reached: {}", summary.outcome_reason)
    };
    let _ = writeln!(
        md,
        "# Foresight run report\n\n**Outcome:** {verdict} (lookahead {}).\n",
        if summary.lookahead { "on" } else { "off" }
    );
    let _ = writeln!(md, "| figure | value |\n|---|---|");
    let rows = [
        ("goal reached", summary.goal_reached.to_string()),
        ("outcome", summary.outcome.name().to_owned()),
        (
            "zero-shot (no retraining)",
            summary.zero_shot.map_or("–".to_owned(), |z| z.to_string()),
        ),
        ("collisions (arm)", summary.collisions.to_string()),
        (
            "collision predicted before motion",
            summary.collision_predicted_before_motion.to_string(),
        ),
        ("policy swaps", summary.policy_swaps.to_string()),
        ("pauses for an obstacle", summary.pauses.to_string()),
        ("longest pause", fmt_opt(summary.longest_pause_s, "s")),
        (
            "smallest separation from the boxes, moving / at rest",
            format!(
                "{} / {}",
                fmt_opt(summary.min_separation_moving_m, "m"),
                fmt_opt(summary.min_separation_at_rest_m, "m")
            ),
        ),
        (
            "planner fallback",
            on_off(summary.planner_fallback).to_owned(),
        ),
        ("moved by (executor)", summary.executor.clone()),
        (
            "world change → detection",
            fmt_opt(summary.world_change_to_detection_s, "s"),
        ),
        (
            "world change → settled scene",
            fmt_opt(summary.world_change_to_settled_s, "s"),
        ),
        (
            "world change → plan approved on it",
            fmt_opt(summary.world_change_to_approval_s, "s"),
        ),
        (
            "world change → verdict",
            fmt_opt(summary.world_change_to_verdict_s, "s"),
        ),
        ("retraining", fmt_opt(summary.retrain_s, "s")),
        (
            "world change → motion resumed",
            fmt_opt(summary.world_change_to_motion_s, "s"),
        ),
        (
            "reaction: causing frame's capture → changed command (median, max; reactions)",
            summary.reaction.as_ref().map_or("–".to_owned(), |r| {
                let c = &r["capture_to_command_us"];
                format!(
                    "{:.1} ms, {:.1} ms ({})",
                    c["p50"].as_f64().unwrap_or(f64::NAN) / 1e3,
                    c["max"].as_f64().unwrap_or(f64::NAN) / 1e3,
                    r["reactions"]
                )
            }),
        ),
        ("cycle compute p99", fmt_opt(summary.cycle_p99_us, "µs")),
        ("cycle compute p99.9", fmt_opt(summary.cycle_p999_us, "µs")),
        ("process restarts", summary.restarts.to_string()),
        ("detector (perception)", summary.detector.clone()),
        ("goal source", summary.goal_source.clone()),
    ];
    for (k, v) in rows {
        let _ = writeln!(md, "| {k} | {v} |");
    }
    if let Some(r) = referee {
        let _ = writeln!(md, "| referee (xarm-sim ground truth) | {} |", r.describe());
    }
    if let Some(r) = &summary.remote_learner {
        let _ = writeln!(md, "| remote learner | {} |", r.describe());
    }
    for note in &summary.notes {
        let _ = writeln!(md, "\n> {note}");
    }
    if !summary.acts.is_empty() {
        let _ = writeln!(
            md,
            "\n## Acts\n\n{}",
            crate::acts::ActSummary::MARKDOWN_HEADER
        );
        for act in &summary.acts {
            let _ = writeln!(md, "{}", act.markdown_row());
        }
    }
    let _ = writeln!(md, "\n## Pictures\n");
    for (title, file) in images {
        let _ = writeln!(md, "### {title}\n\n![{title}]({file})\n");
    }
    let _ = writeln!(md, "## Timeline\n\n```");
    for line in timeline {
        let _ = writeln!(md, "{line}");
    }
    let _ = writeln!(md, "```\n\n## Files\n");
    for (title, file) in files {
        let _ = writeln!(md, "- [{title}]({file})");
    }
    write_atomic(out, md.as_bytes()).map_err(|e| ReportError::Io(out.to_path_buf(), e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::scene_file::{BoxSpec, GoalSpec, TableSpec};

    fn scene(h: f64) -> SceneFile {
        SceneFile {
            name: "s".into(),
            table: TableSpec::default(),
            goal: GoalSpec {
                center_m: [0.45, 0.15, 0.025],
                size_m: 0.05,
            },
            obstacles: vec![BoxSpec {
                center_m: [0.35, 0.0, h / 2.0],
                size_m: [0.06, 0.06, h],
                path: Default::default(),
            }],
        }
    }

    #[test]
    fn writes_plots_summary_and_markdown() {
        let dir = std::env::temp_dir().join(format!("foresight-report-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path: Vec<PathSample> = (0..100)
            .map(|i| {
                let s = f64::from(i) / 100.0;
                PathSample {
                    t_s: s * 10.0,
                    tcp_m: [0.2 + 0.25 * s, 0.15 * s, 0.3 - 0.25 * s],
                    scene: usize::from(i >= 50),
                }
            })
            .collect();
        let scenes = vec![(0.0, scene(0.08)), (10.0, scene(0.35))];
        plot_path(&dir.join("top.png"), View::Top, &path, &scenes).unwrap();
        plot_path(&dir.join("side.png"), View::Side, &path, &scenes).unwrap();
        std::fs::write(
            dir.join("m.csv"),
            "steps,mean_return,success_rate\n0,-5,0\n1000,-2,0.5\n2000,1.5,0.9\nbad,row\n",
        )
        .unwrap();
        let curve = read_reward_curve(&dir.join("m.csv")).unwrap();
        assert_eq!(curve, vec![(0.0, -5.0), (1000.0, -2.0), (2000.0, 1.5)]);
        plot_reward_curves(
            &dir.join("r.png"),
            "reward",
            &[("pre-training".into(), curve)],
        )
        .unwrap();
        for f in ["top.png", "side.png", "r.png"] {
            let bytes = std::fs::read(dir.join(f)).unwrap();
            assert_eq!(&bytes[1..4], b"PNG", "{f} is a PNG");
            assert!(bytes.len() > 5_000, "{f} has content");
        }
        let summary = Summary {
            acts: Vec::new(),
            goal_reached: true,
            world_change_to_detection_s: Some(0.05),
            detector: "yolo".into(),
            goal_source: "action".into(),
            ..Summary::default()
        };
        write_summary(&dir.join("summary.json"), &summary, None).unwrap();
        let back: Summary =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(back, summary);
        write_markdown(
            &dir.join("report.md"),
            &summary,
            None,
            &["0.0 s start".into()],
            &[("Top view", "top.png")],
            &[("summary", "summary.json")],
        )
        .unwrap();
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert!(
            md.contains("goal reached with no collision") && md.contains("![Top view](top.png)")
        );
        assert!(md.contains("| detector (perception) | yolo |"), "{md}");
        assert!(
            !md.contains("referee"),
            "no referee line without a simulator"
        );
        assert!(read_reward_curve(&dir.join("missing.csv")).is_err());
        if std::env::var_os("FORESIGHT_KEEP_TEST_OUTPUT").is_none() {
            std::fs::remove_dir_all(&dir).ok();
        }
    }

    #[test]
    fn the_referee_figures_reach_summary_json_and_report_md() {
        let status = serde_json::json!({
            "collisions": 0,
            "referee": {
                "steps": 1500,
                "evaluations": 3100,
                "contacts": 0,
                "unjudged": 0,
                "min_clearance_m": 0.0234,
                "min_link": "link4",
                "min_other": "obstacle 2",
                "min_scene": "tall_box",
                "min_q_rad": [0.0, 0.1, 0.2, 0.3, 0.4],
                "contact_margin_m": 0.0
            }
        });
        let r = RefereeFigures::from_sim_status(&status).unwrap();
        assert_eq!(
            r.describe(),
            "0 collisions, minimum clearance 23.4 mm (link4–obstacle 2)"
        );
        assert_eq!(
            RefereeFigures::from_sim_status(&serde_json::json!({})),
            None
        );
        let one = RefereeFigures {
            contacts: 1,
            min_clearance_m: Some(-0.003),
            min_link: Some("link1".into()),
            min_other: Some("link4".into()),
            ..RefereeFigures::default()
        };
        assert_eq!(
            one.describe(),
            "1 collision, minimum clearance -3.0 mm (link1–link4)"
        );

        let summary = Summary {
            acts: Vec::new(),
            goal_reached: true,
            ..Summary::default()
        };
        let json: serde_json::Value =
            serde_json::from_str(&summary_json(&summary, Some(&r))).unwrap();
        assert_eq!(json["referee"]["min_link"], "link4");
        assert_eq!(json["referee"]["min_clearance_m"], 0.0234);
        // Contacts while moving and at rest reach summary.json apart (0 when a simulator
        // too old to tell them apart does not say).
        assert_eq!(json["referee"]["contacts_while_moving"], 0);
        assert_eq!(json["referee"]["contacts_at_rest"], 0);
        assert_eq!(
            json["goal_reached"], true,
            "the summary's own fields stay flat"
        );
        let back: Summary = serde_json::from_value(json).unwrap();
        assert_eq!(back, summary);
        let plain: serde_json::Value = serde_json::from_str(&summary_json(&summary, None)).unwrap();
        assert!(plain.get("referee").is_none());
        let split = RefereeFigures::from_sim_status(&serde_json::json!({"referee": {
            "contacts": 3, "contacts_while_moving": 1, "contacts_at_rest": 2
        }}))
        .unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&summary_json(&summary, Some(&split))).unwrap();
        assert_eq!(
            (
                &json["referee"]["contacts"],
                &json["referee"]["contacts_while_moving"],
                &json["referee"]["contacts_at_rest"]
            ),
            (&3.into(), &1.into(), &2.into())
        );

        let dir = std::env::temp_dir().join(format!("foresight-referee-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_markdown(&dir.join("report.md"), &summary, Some(&r), &[], &[], &[]).unwrap();
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert!(
            md.contains("| referee (xarm-sim ground truth) | 0 collisions, minimum clearance 23.4 mm (link4–obstacle 2) |"),
            "{md}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}

#[cfg(test)]
mod tick_text_tests {
    use super::tick_text;

    #[test]
    fn ticks_read_as_people_write_them() {
        let t = |vs: &[f64]| vs.iter().map(|v| tick_text(*v)).collect::<Vec<_>>();
        assert_eq!(
            t(&[0.0, 250_000.0, 1_000_000.0, 1_500_000.0, 2e7]),
            ["0", "250k", "1M", "1.5M", "20M"]
        );
        assert_eq!(
            t(&[-0.1, 0.0, 0.25, 0.7, -2.0]),
            ["-0.1", "0", "0.25", "0.7", "-2"]
        );
        assert_eq!(t(&[999.0, 1000.0, 12_500.0]), ["999", "1k", "12.5k"]);
        assert_eq!(tick_text(-1e-9), "0");
    }
}
