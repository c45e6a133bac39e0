//! `sweep --dynamic`: runs the dynamic sweep ([`sweep::dynamic`]), prints its tables and
//! writes `summary.json`. Exit code 1 on any avoidable contact while moving or static hard
//! count.

use std::process::ExitCode;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use sweep::SweepAssets;
use sweep::dynamic::{DynamicSettings, DynamicSummary, GroupFigures, run_dynamic_sweep};

/// Runs the dynamic sweep with `settings`; the summary goes to `out`.
pub(crate) fn run(
    assets: &SweepAssets,
    settings: &DynamicSettings,
    out: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    let bar = ProgressBar::new(settings.episodes);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} episodes ({per_sec}, eta {eta}) {msg}",
        )
        .context("progress template")?
        .progress_chars("=> "),
    );
    let summary = run_dynamic_sweep(assets, settings, |_, tally| {
        bar.inc(1);
        bar.set_message(format!(
            "avoidable moving contacts {} | unavoidable {} | hard {}",
            tally.avoidable_moving_contacts(),
            tally.unavoidable_moving_contacts(),
            tally.hard().total()
        ));
    });
    bar.finish();
    print_tables(&summary);
    let path = crate::write_summary(out, &summary)?;
    println!("summary written to {}", path.display());
    Ok(if summary.failures_total() == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn mm(m: f64) -> String {
    if m.is_finite() {
        format!("{:.1}", m * 1e3)
    } else {
        "-".into()
    }
}

fn rows(title: &str, cols: &[(&str, &GroupFigures)]) {
    println!("{title}");
    print!("  {:<44}", "");
    for (name, _) in cols {
        print!(" {name:>16}");
    }
    println!();
    let row = |label: &str, f: &dyn Fn(&GroupFigures) -> String| {
        print!("  {label:<44}");
        for (_, g) in cols {
            print!(" {:>16}", f(g));
        }
        println!();
    };
    row("episodes", &|g| g.episodes.to_string());
    row("unavoidable intrusions", &|g| {
        g.unavoidable_intrusions.to_string()
    });
    row("contacts while moving, AVOIDABLE (must be 0)", &|g| {
        g.contacts_while_moving_avoidable.to_string()
    });
    row("contacts while moving, unavoidable", &|g| {
        g.contacts_while_moving_unavoidable.to_string()
    });
    row("  [stricter rule: intruder moves in T_r only]", &|g| {
        format!(
            "{} / {}",
            g.unavoidable_intrusions_reaction_only_rule,
            g.contacts_while_moving_avoidable_reaction_only_rule
        )
    });
    row("contacts at rest (walked into the still arm)", &|g| {
        g.contacts_at_rest.to_string()
    });
    row(
        "min separation, mm (all poses)",
        &|g| mm(g.min_separation_m),
    );
    row("min separation, mm (moving, avoidable)", &|g| {
        mm(g.min_separation_avoidable_m)
    });
    row("near the path / command changed", &|g| {
        format!("{} / {}", g.reaction.near_path, g.reaction.changed)
    });
    row("  changed before the near frame / unchanged", &|g| {
        format!("{} / {}", g.reaction.anticipated, g.reaction.unchanged)
    });
    row("  accepted -> changed, cycles p50/p99/max (n)", &|g| {
        let s = &g.reaction.from_delivery_cycles;
        format!("{:.0}/{:.0}/{:.0} ({})", s.p50, s.p99, s.max, s.samples)
    });
    row("  same, after the near frame only (n)", &|g| {
        let s = &g.reaction.reactive_from_delivery_cycles;
        format!("{:.0}/{:.0}/{:.0} ({})", s.p50, s.p99, s.max, s.samples)
    });
    row("  capture -> changed, ms p50/p99/max, same", &|g| {
        let s = &g.reaction.reactive_from_capture_ms;
        format!("{:.0}/{:.0}/{:.0}", s.p50, s.p99, s.max)
    });
    row("intruder left or out of the way / reached", &|g| {
        format!("{} / {}", g.intruder_cleared, g.reached_after_clear)
    });
    row("  reached after it, %", &|g| {
        format!("{:.1}", 100.0 * g.reach_after_clear_fraction)
    });
    row("time lost vs no intruder, s p50/p90 (n)", &|g| {
        let s = &g.time_lost_s;
        format!("{:.2}/{:.2} ({})", s.p50, s.p90, s.samples)
    });
}

fn yes(b: bool) -> &'static str {
    if b { "MET" } else { "NOT MET" }
}

fn print_tables(s: &DynamicSummary) {
    print_header(s);
    let h = &s.hard;
    println!(
        "HARD COUNTS (must be 0): still boxes {}, table {}, joint steps {}, TCP speed {}, TCP step {}, joint limits {}, non-finite {}",
        h.box_penetrations,
        h.table_penetrations,
        h.joint_step_violations,
        h.tcp_speed_violations,
        h.tcp_step_violations,
        h.joint_limit_violations,
        h.non_finite_commands
    );
    println!("{:-<112}", "");
    let mut cols = vec![("all", &s.all)];
    for (k, g) in &s.by_speed_band {
        cols.push((k.as_str(), g));
    }
    rows("BY INTRUDER SPEED (m/s)", &cols);
    println!("{:-<112}", "");
    let cols: Vec<(&str, &GroupFigures)> = s.by_kind.iter().map(|(k, g)| (k.as_str(), g)).collect();
    rows("BY KIND", &cols);
    println!("{:-<112}", "");
    println!("AVOIDABLE / UNAVOIDABLE CONTACTS WHILE MOVING / EPISODES, by kind and speed band");
    for (k, g) in &s.by_kind_and_band {
        println!(
            "  {k:<32} {:>4} / {:>4} / {:>5}   at rest {:>4}",
            g.contacts_while_moving_avoidable,
            g.contacts_while_moving_unavoidable,
            g.episodes,
            g.contacts_at_rest
        );
    }
    println!("{:-<112}", "");
    let env = |e: &sweep::dynamic::summary::Envelope| match e.slowest_avoidable_contact_m_s {
        None => format!(
            "0 avoidable contacts while moving at every speed drawn (up to {:.2} m/s)",
            e.zero_avoidable_contacts_below_m_s
        ),
        Some(v) => format!("0 avoidable contacts while moving below {v:.2} m/s"),
    };
    println!("ENVELOPE: {}", env(&s.envelope));
    for (k, e) in &s.envelope_by_kind {
        println!("  {k:<20} {}", env(e));
    }
    let t = &s.targets;
    println!(
        "TARGETS: 0 avoidable contacts while moving up to 1.0 m/s: {}; >= 95 % reach the goal after the intruder left: {} ({:.1} %); accepted frame -> changed command <= 1 cycle at p99: {} (p99 {:.0})",
        yes(t.no_avoidable_moving_contact_up_to_1_m_s),
        yes(t.reach_after_clear_at_least_95_percent),
        100.0 * s.all.reach_after_clear_fraction,
        yes(t.reaction_p99_at_most_1_cycle),
        s.all.reaction.from_delivery_cycles.p99
    );
    println!("{:-<112}", "");
    super::per_kind::print(s);
    print_contact_examples(s);
    for e in s.late_infeasible_examples.iter().take(8) {
        println!(
            "goal said taken late: episode {} ({}), {} {:.2} s after the box came to rest; stops {}, retreats {}",
            e.episode,
            e.replay,
            e.kind.name(),
            e.delay_s,
            e.stops,
            e.backing_out
        );
    }
    println!("{:-<112}", "");
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

/// The run's settings: seed, episodes, frames, intruders and the brake's limits.
fn print_header(s: &DynamicSummary) {
    let st = &s.settings;
    let b = &s.brake;
    println!();
    println!(
        "dynamic sweep seed {} episodes {} (run {}, {} worlds redrawn, {} without a reached world; {} cycles, {} commands checked) in {:.1} s = {:.2} episodes/s",
        st.seed,
        s.episodes,
        s.episodes_run,
        s.world_redraws,
        s.episodes_without_a_reached_world,
        s.cycles,
        s.commands_checked,
        s.wall_s,
        s.episodes_per_s
    );
    println!(
        "frames {:.0} Hz, latency {:.0}-{:.0} ms; intruders {:.1}-{:.1} m/s; settled {:.1} s after the last change; goal within {:.0} s after the intruder left",
        st.frame_rate_hz,
        st.latency_min_s * 1e3,
        st.latency_max_s * 1e3,
        st.min_speed_m_s,
        st.max_speed_m_s,
        st.settle_quiet_s,
        st.reach_limit_s
    );
    println!(
        "brake limits: {:?} rad/s, {:?} rad/s2 (path stop at 80 %), {:?} rad/s3; stop from full speed {:.3} s (+1 period)",
        b.max_velocity_rad_s,
        b.max_acceleration_rad_s2,
        b.max_jerk_rad_s3,
        b.braking_horizon.horizon_s
    );
    println!("{:-<112}", "");
}

/// Up to 8 examples of avoidable and of unavoidable contacts while moving, with the onset
/// of each (what came too close, when, and why it was or was not avoidable).
fn print_contact_examples(s: &DynamicSummary) {
    for (title, list) in [
        (
            "AVOIDABLE CONTACT WHILE MOVING",
            &s.avoidable_contact_examples,
        ),
        (
            "unavoidable contact while moving",
            &s.unavoidable_contact_examples,
        ),
    ] {
        for e in list.iter().take(8) {
            let o = e.onset.map_or(String::from("no onset seen"), |o| {
                format!(
                    "{} at {:.3} s: distance {} mm < stopping {} mm? {} (arm {:.2} m/s, intruder {:.2} m/s, reaction {:.0} ms, stop {:.0} ms)",
                    o.what,
                    o.at_s,
                    mm(o.distance_m),
                    mm(o.stopping_distance_m),
                    o.unavoidable,
                    o.arm_speed_m_s,
                    o.intruder_speed_m_s,
                    o.reaction_s * 1e3,
                    o.arm_stop_s * 1e3
                )
            });
            println!(
                "{title}: episode {} ({}), {} {:.2} m/s size {:.0}x{:.0}x{:.0} mm, {}; contact at {:.3} s depth {} mm; {o}",
                e.episode,
                e.replay,
                e.kind.name(),
                e.speed_m_s,
                e.size_m[0] * 1e3,
                e.size_m[1] * 1e3,
                e.size_m[2] * 1e3,
                e.policy.name(),
                e.contact.at_s,
                mm(e.contact.depth_m)
            );
        }
    }
}
