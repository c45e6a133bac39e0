//! The benchmark's tables: one printed row per world, the aggregate figures of a generator,
//! and the Markdown of `worlds.md`.

use std::fmt::Write as _;

use learner::ppo::EvalResult;

use crate::{Aggregate, GeneratorTable, PassAt, RetrainRow, SampleRow, WorldRow, median};

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn zero_shot_word(r: &WorldRow) -> &'static str {
    if r.zero_shot {
        "yes"
    } else if r.zero_shot_contact {
        "contact"
    } else {
        "timeout"
    }
}

pub(crate) fn print_row(r: &WorldRow) {
    let sampled: String = r
        .samples
        .iter()
        .map(|s| {
            format!(
                " @{}:{}",
                s.k,
                s.best_index.map_or("-".to_owned(), |i| i.to_string())
            )
        })
        .collect();
    println!(
        "{:>3} {:<20} {:>5} {:>6.2}m {:>9} {:>8} {:>10} {:>9} {:>7} {:>10}  {}{sampled}",
        r.index,
        r.kind,
        r.boxes,
        r.tallest_box_m,
        yes(r.feasible),
        yes(r.straight_line),
        yes(r.joint_line),
        zero_shot_word(r),
        r.planner.map_or("-", yes),
        r.retrained.as_ref().map_or("-".to_string(), |t| format!(
            "{} {:.1}s",
            yes(t.success),
            t.wall_s
        )),
        r.infeasible_reason.as_deref().unwrap_or("")
    );
}

pub(crate) fn aggregate(rows: &[WorldRow]) -> Aggregate {
    let feasible: Vec<&WorldRow> = rows.iter().filter(|r| r.feasible).collect();
    let nf = feasible.len().max(1) as f64;
    let count = |f: &dyn Fn(&WorldRow) -> bool| feasible.iter().filter(|r| f(r)).count();
    let re: Vec<&RetrainRow> = rows.iter().filter_map(|r| r.retrained.as_ref()).collect();
    let mut times: Vec<f64> = re.iter().map(|r| r.wall_s).collect();
    let mut steps: Vec<f64> = re.iter().map(|r| r.steps as f64).collect();
    let mut kept: Vec<f64> = re.iter().map(|r| r.kept.success_rate).collect();
    let mut library: Vec<f64> = re.iter().map(|r| r.library_kept).collect();
    let straight_line = count(&|r| r.straight_line);
    let joint_line = count(&|r| r.joint_line);
    let zero_shot = count(&|r| r.zero_shot);
    let zero_shot_contact = count(&|r| r.zero_shot_contact);
    let planner = count(&|r| r.planner == Some(true));
    let ks: Vec<usize> = feasible
        .first()
        .map(|r| r.samples.iter().map(|s| s.k).collect())
        .unwrap_or_default();
    let pass_at = ks
        .iter()
        .enumerate()
        .map(|(j, &k)| {
            let rows: Vec<&SampleRow> = feasible.iter().filter_map(|r| r.samples.get(j)).collect();
            let mut times: Vec<f64> = rows.iter().map(|s| s.elapsed_s).collect();
            let passed = rows.iter().filter(|s| s.passed).count();
            PassAt {
                k,
                passed,
                rate: passed as f64 / nf,
                rescued: rows
                    .iter()
                    .filter(|s| s.best_index.is_some_and(|i| i > 0))
                    .count(),
                max_s: times.iter().copied().reduce(f64::max),
                median_s: median(&mut times),
            }
        })
        .collect();
    Aggregate {
        worlds: rows.len(),
        feasible: feasible.len(),
        infeasible: rows.len() - feasible.len(),
        straight_line,
        joint_line,
        zero_shot,
        zero_shot_contact,
        zero_shot_timeout: count(&|r| r.zero_shot_timeout),
        planner,
        straight_line_rate: straight_line as f64 / nf,
        joint_line_rate: joint_line as f64 / nf,
        zero_shot_rate: zero_shot as f64 / nf,
        zero_shot_contact_rate: zero_shot_contact as f64 / nf,
        planner_rate: planner as f64 / nf,
        line_not_policy: count(&|r| r.straight_line && !r.zero_shot),
        retrained: re.len(),
        retrain_success: re.iter().filter(|r| r.success).count(),
        retrain_failed_undemonstrated: re.iter().filter(|r| !r.success && !r.demonstrated).count(),
        retrain_max_s: times.iter().copied().reduce(f64::max),
        retrain_median_s: median(&mut times),
        retrain_median_steps: median(&mut steps),
        kept_min: kept.iter().copied().reduce(f64::min),
        kept_median: median(&mut kept),
        library_kept_min: library.iter().copied().reduce(f64::min),
        library_kept_median: median(&mut library),
        pass_at,
    }
}

fn pct(v: f64) -> String {
    format!("{:.0} %", 100.0 * v)
}

fn of(n: usize, d: usize) -> String {
    format!("{n}/{d} ({})", pct(n as f64 / d.max(1) as f64))
}

fn opt_s(v: Option<f64>) -> String {
    v.map_or("–".to_owned(), |s| format!("{s:.1}"))
}

fn opt_pct(v: Option<f64>) -> String {
    v.map_or("–".to_owned(), pct)
}

/// The per-generator table (Markdown).
pub(crate) fn summary_table(tables: &[GeneratorTable]) -> String {
    let mut s = String::from(
        "| generator | feasible worlds | infeasible skipped | policy zero-shot | contact | timeout | straight line | joint straight line | line, not policy | planner (path re-tracked) | retrained: learned | retraining median / max (s) | kept in library (min) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for t in tables {
        let a = &t.aggregate;
        let skipped = if t.generator == "task" {
            format!("{} (kept as rows)", a.infeasible)
        } else {
            t.skipped_infeasible.to_string()
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} |",
            t.generator,
            a.feasible,
            skipped,
            of(a.zero_shot, a.feasible),
            a.zero_shot_contact,
            a.zero_shot_timeout,
            of(a.straight_line, a.feasible),
            of(a.joint_line, a.feasible),
            a.line_not_policy,
            of(a.planner, a.feasible),
            if a.retrain_failed_undemonstrated > 0 {
                format!(
                    "{}/{} ({} not: no demonstration in the action space)",
                    a.retrain_success, a.retrained, a.retrain_failed_undemonstrated
                )
            } else if a.retrained > 0 {
                format!("{}/{}", a.retrain_success, a.retrained)
            } else {
                "–".into()
            },
            opt_s(a.retrain_median_s),
            opt_s(a.retrain_max_s),
            opt_pct(a.library_kept_min),
        );
    }
    s
}

/// Verified sampling per generator: pass@K and the wall time of the K rollouts.
pub(crate) fn sampling_table(tables: &[GeneratorTable], threads: usize) -> String {
    let Some(ks) = tables
        .first()
        .map(|t| t.aggregate.pass_at.iter().map(|p| p.k).collect::<Vec<_>>())
        .filter(|k| !k.is_empty())
    else {
        return String::new();
    };
    let mut s = String::from("| generator | feasible |");
    for k in &ks {
        let _ = write!(s, " pass@{k} | K = {k}: median / max (ms) |");
    }
    s += " planner path |\n|---|---|";
    for _ in &ks {
        s += "---|---|";
    }
    s += "---|\n";
    for t in tables {
        let a = &t.aggregate;
        let _ = write!(s, "| {} | {} |", t.generator, a.feasible);
        for p in &a.pass_at {
            let _ = write!(
                s,
                " {} | {} / {} |",
                of(p.passed, a.feasible),
                p.median_s.map_or("–".into(), |v| format!("{:.1}", 1e3 * v)),
                p.max_s.map_or("–".into(), |v| format!("{:.1}", 1e3 * v)),
            );
        }
        let _ = writeln!(s, " {} |", of(a.planner, a.feasible));
    }
    let _ = writeln!(
        s,
        "\nCandidate 0 is the deterministic rollout of the exported blob; the others add AR(1) action noise; {threads} threads."
    );
    s
}

/// The adaptation table: every retrained world.
fn adaptation_table(tables: &[GeneratorTable]) -> String {
    let mut s = String::from(
        "| generator | world | kind | boxes | tallest (m) | zero-shot | world change → learned policy (s) | steps | learned | stop | demonstrated in the action space | kept alone | kept in library |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for t in tables {
        for r in &t.worlds {
            if let Some(re) = &r.retrained {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {:.2} | {} | {:.1} | {} | {} | {:?} | {} | {} | {} |",
                    t.generator,
                    r.index,
                    r.kind,
                    r.boxes,
                    r.tallest_box_m,
                    zero_shot_word(r),
                    re.wall_s,
                    re.steps,
                    yes(re.success),
                    re.stop,
                    yes(re.demonstrated),
                    pct(re.kept.success_rate),
                    pct(re.library_kept),
                );
            }
        }
    }
    s
}

pub(crate) fn markdown(tables: &[GeneratorTable], base_kept: &EvalResult, seed: u64) -> String {
    let mut s = format!(
        "# Unseen worlds per generator (seed {seed})\n\n\
         `task` is the task's own `[world]` sampler (the generalist's training distribution); \
         `uniform`, `cluttered` and `adversarial` are the independent generators of the \
         `worldgen` crate, each world proven feasible by the twin's planner. Rates are over \
         the feasible worlds. The planner column re-tracks the feasibility proof's path in \
         the twin: 100 % by construction, the ceiling of the planner fallback. The base \
         policy solves {} of the pre-training scenes.\n\n",
        pct(base_kept.success_rate)
    );
    s += &summary_table(tables);
    s += "\n![policy vs straight line vs planner per generator](worlds.png)\n";
    if tables.iter().any(|t| t.aggregate.retrained > 0) {
        s += "\n## Adaptation: the worlds the policy does not solve zero-shot\n\n";
        s += &adaptation_table(tables);
        s += "\n![retraining time per world](adaptation.png)\n";
    }
    for t in tables {
        let _ = write!(
            s,
            "\n## {} ({} worlds, {} infeasible draws skipped, generated and proven in {:.1} s)\n\n",
            t.generator,
            t.worlds.len(),
            t.skipped_infeasible,
            t.generation_s
        );
        s += "| # | kind | boxes | tallest (m) | feasible | straight line | zero-shot | planner | retrained (s) | kept in library | note |\n";
        s += "|---|---|---|---|---|---|---|---|---|---|---|\n";
        for r in &t.worlds {
            let (re, library) = match &r.retrained {
                Some(x) => (
                    format!("{} ({:.1})", yes(x.success), x.wall_s),
                    pct(x.library_kept),
                ),
                None => ("–".into(), "–".into()),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} |",
                r.index,
                r.kind,
                r.boxes,
                r.tallest_box_m,
                yes(r.feasible),
                yes(r.straight_line),
                zero_shot_word(r),
                r.planner.map_or("–", yes),
                re,
                library,
                r.infeasible_reason
                    .as_deref()
                    .unwrap_or("")
                    .replace('|', "/")
            );
        }
        if !t.skipped_reasons.is_empty() {
            s += "\nSkipped as infeasible:\n\n";
            for why in &t.skipped_reasons {
                let _ = writeln!(s, "- {why}");
            }
        }
    }
    s
}
