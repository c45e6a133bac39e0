//! `sweep`: the adversarial sweep of the production twin worker and cycle (the `sweep`
//! library), checked by the independent oracle. Prints progress, a summary table, and
//! writes `summary.json` (atomically: a temporary file renamed) into `--out`. Exit code 1
//! when any hard count is non-zero, 2 on an error. With `--dynamic`, the dynamic sweep
//! (intruders during a motion, `sweep::dynamic`; its own tables and summary; exit code 1 also
//! on any avoidable contact while moving).
//!
//! ```text
//! cargo run --release -p sweep -- --episodes 10000 --seed 1 --out runs/sweep
//! cargo run --release -p sweep -- --dynamic --episodes 1000 --seed 1 --out runs/sweep-dynamic
//! cargo run --release -p sweep -- --dynamic --kinds classic --episodes 1000 --seed 1
//! ```

#![forbid(unsafe_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use shm_schemas::cli_bounds::{f64_within, int_within};
use sweep::dynamic::{DynamicSettings, KindSet};
use sweep::{SweepAssets, SweepSettings, SweepSummary, run_sweep};

mod cli;

/// The adversarial sweep of rt-core's twin worker and cycle, checked by an independent oracle.
#[derive(Debug, Parser)]
#[command(name = "sweep", version, about)]
struct SweepArgs {
    /// Episodes to run.
    #[arg(long, default_value_t = 100, value_parser = int_within(1u64, 100_000_000), allow_negative_numbers = true)]
    episodes: u64,
    /// Seed of the sweep.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Index of the first episode (replay one with `--first-episode I --episodes 1`).
    #[arg(long, default_value_t = 0, value_parser = int_within(0u64, 1_000_000_000_000), allow_negative_numbers = true)]
    first_episode: u64,
    /// Folder for summary.json.
    #[arg(long, default_value = "sweep-out")]
    out: PathBuf,
    /// Folder with runtime.toml, xarm5.urdf, task.toml and policy-distilled/policy.blob.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Worker threads (default: the available cores).
    #[arg(long, value_parser = int_within(1usize, 1024), allow_negative_numbers = true)]
    jobs: Option<usize>,
    /// Longest episode, s (default 12; with --dynamic, the longest run with the intruder:
    /// default 30).
    #[arg(long, value_parser = f64_within(0.1, 3600.0), allow_negative_numbers = true)]
    max_episode_s: Option<f64>,
    /// The dynamic sweep: an intruder during each motion (entering and stopping on the
    /// path, crossing it, stopping then leaving, appearing at once), 60 Hz frames.
    #[arg(long)]
    dynamic: bool,
    /// The planner fallback installed in the worker, as `rt-core run --planner-fallback on`
    /// installs it (static and dynamic sweeps; its search is bounded by wall time, so
    /// counts other than the hard ones may vary with the machine's load).
    #[arg(long)]
    planner_fallback: bool,
    /// With --dynamic, the intruder kinds drawn: `all`, `classic` (the four of the sweep
    /// before issue 42, episode for episode), `grown` (issue 42's five), or a comma-separated
    /// list of letters a-e (moving at the start, near miss, parks on the path, takes the
    /// goal, appears next to the arm) and kinds' names.
    #[arg(long, default_value = "all", value_parser = parse_kinds)]
    kinds: KindSet,
}

fn parse_kinds(text: &str) -> Result<KindSet, String> {
    KindSet::parse(text).map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    let args = SweepArgs::parse();
    match run(&args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("sweep: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &SweepArgs) -> anyhow::Result<ExitCode> {
    let assets = SweepAssets::load(&args.assets)
        .with_context(|| format!("loading assets from {}", args.assets.display()))?;
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if args.dynamic {
        let defaults = DynamicSettings::default();
        let settings = DynamicSettings {
            seed: args.seed,
            episodes: args.episodes,
            first_episode: args.first_episode,
            max_episode_s: args.max_episode_s.unwrap_or(defaults.max_episode_s),
            jobs,
            planner_fallback: args.planner_fallback,
            kinds: args.kinds,
            ..defaults
        };
        return cli::dynamic::run(&assets, &settings, &args.out);
    }
    let settings = SweepSettings {
        seed: args.seed,
        episodes: args.episodes,
        first_episode: args.first_episode,
        max_episode_s: args.max_episode_s.unwrap_or(12.0),
        jobs,
        planner_fallback: args.planner_fallback,
        ..SweepSettings::default()
    };
    let bar = ProgressBar::new(args.episodes);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} episodes ({per_sec}, eta {eta}) {msg}",
        )
        .context("progress template")?
        .progress_chars("=> "),
    );
    let summary = run_sweep(&assets, &settings, |_, tally| {
        bar.inc(1);
        let h = tally.hard();
        bar.set_message(format!(
            "hard {} | moved {} | reached {} | boxes injected ahead {}",
            h.total(),
            tally.count("episodes_that_moved"),
            tally.count("outcome_reached_goal"),
            tally.count("twist_boxes_injected_ahead_of_the_arm"),
        ));
    });
    bar.finish();
    print_table(&summary);
    let path = write_summary(&args.out, &summary)?;
    println!("summary written to {}", path.display());
    Ok(if summary.hard.total() == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn print_table(s: &SweepSummary) {
    let h = &s.hard;
    let u = &s.unavoidable;
    let b = &s.braking_horizon;
    println!();
    println!(
        "sweep seed {} episodes {} ({} cycles, {} commands checked) in {:.1} s = {:.2} episodes/s",
        s.settings.seed, s.episodes, s.cycles, s.commands_checked, s.wall_s, s.episodes_per_s
    );
    println!(
        "braking horizon {:.3} s = {} cycles (brake {:.3} s, path stop {:.3} s; cycle look-ahead {} samples)",
        b.horizon_s, b.horizon_cycles, b.brake_s, b.path_stop_s, b.cycle_lookahead_samples
    );
    println!("{:-<64}", "");
    println!("{:<44} {:>10}", "HARD COUNTS (must be 0)", "");
    for (k, v) in [
        ("box penetrations (known >= 1 horizon)", h.box_penetrations),
        ("table penetrations", h.table_penetrations),
        ("joint-step violations", h.joint_step_violations),
        ("TCP-speed violations", h.tcp_speed_violations),
        (
            "TCP-step violations (> 5 mm per target)",
            h.tcp_step_violations,
        ),
        ("joint-limit violations", h.joint_limit_violations),
        ("non-finite commands", h.non_finite_commands),
    ] {
        println!("  {k:<42} {v:>10}");
    }
    println!("{:-<64}", "");
    println!("UNAVOIDABLE INTRUSIONS (box known < 1 horizon)");
    println!("  {:<42} {:>10}", "poses", u.poses);
    println!("  {:<42} {:>10}", "boxes intruded", u.events);
    println!(
        "  {:<42} {:>10}",
        "poses held inside later (no deeper)", u.held_inside_poses
    );
    println!(
        "  {:<42} {:>10.1} {:>6.1} {:>6.1} {:>6.1}",
        "depth mm p50 p90 p99 max",
        u.depth_p50_m * 1e3,
        u.depth_p90_m * 1e3,
        u.depth_p99_m * 1e3,
        u.depth_max_m * 1e3
    );
    for (k, v) in &u.depth_histogram_mm {
        println!("    {:<40} {v:>10}", format!("{k} mm"));
    }
    println!(
        "  {:<42} {:>10.1}",
        "min clearance to a known box, mm",
        s.min_known_box_clearance_m * 1e3
    );
    println!(
        "  {:<42} {:>10.1}",
        "  of a command that moves (no hold), mm",
        s.min_known_box_clearance_moving_m * 1e3
    );
    println!(
        "  {:<42} {:>10.1}",
        "min clearance to the table, mm",
        s.min_table_clearance_m * 1e3
    );
    println!("{:-<64}", "");
    println!("INJECTED BOXES by cycles ahead: injected / intruded");
    for (k, [n, hit]) in &s.injections_by_offset {
        println!("  {k:<42} {n:>6} / {hit:<6}");
    }
    println!("{:-<64}", "");
    println!("COUNTERS");
    for (k, v) in &s.counts {
        println!("  {k:<52} {v:>10}");
    }
    if let Some(p) = &s.bundled_problem {
        println!("bundled policy not used ({p}): the goal-seeker ran in its place");
    }
    for f in &s.failures {
        println!("FAILURE {f:?}");
    }
}

/// Writes `summary.json` into `dir` through a temporary file and a rename.
fn write_summary(dir: &Path, s: &impl Serialize) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join("summary.json");
    let tmp = dir.join(".summary.json.tmp");
    let text = serde_json::to_string_pretty(s).context("serialising the summary")?;
    {
        let mut f =
            std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        f.write_all(text.as_bytes())
            .and_then(|()| f.write_all(b"\n"))
            .and_then(|()| f.sync_all())
            .with_context(|| format!("writing {}", tmp.display()))?;
    }
    std::fs::rename(&tmp, &path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(path)
}
