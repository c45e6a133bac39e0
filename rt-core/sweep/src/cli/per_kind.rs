//! The dynamic sweep's per-kind table (issue 42 item 7) and issue 42's targets, as
//! `sweep --dynamic` prints them.

use sweep::dynamic::summary::Spread;
use sweep::dynamic::{DynamicSummary, GroupFigures, IntruderKind};

fn pct(n: u64, of: u64) -> String {
    if of == 0 {
        "-".into()
    } else {
        format!("{:.1}", 100.0 * n as f64 / of as f64)
    }
}

fn spread(s: &Spread) -> String {
    if s.samples == 0 {
        "-".into()
    } else {
        format!("{:.2}/{:.2}", s.p50, s.p90)
    }
}

fn row(name: &str, g: &GroupFigures) {
    let o = &g.outcome;
    println!(
        "  {name:<20} {:>6} {:>6} {:>6} {:>7} {:>6} {:>11} {:>11} {:>11} {:>6} {:>17}",
        g.episodes,
        g.contacts_while_moving_avoidable,
        g.contacts_while_moving_unavoidable,
        o.handled_without_stop,
        pct(o.handled_without_stop, g.episodes),
        spread(&g.time_lost_s),
        spread(&o.start_delay_s),
        format!("{}/{}", g.reached_after_clear, g.intruder_cleared),
        pct(g.reached_after_clear, g.intruder_cleared),
        format!(
            "{}/{}/{}",
            o.reached_while_in_the_way, o.infeasible_reported, o.stayed_in_the_way
        ),
    );
}

fn yes(b: bool) -> &'static str {
    if b { "MET" } else { "NOT MET" }
}

/// Prints one row per kind run, and the whole.
pub(crate) fn print(s: &DynamicSummary) {
    println!(
        "PER KIND: intrusions; contacts while moving, avoidable (must be 0) / unavoidable; handled without a protective stop;"
    );
    println!(
        "  time lost per intrusion and start delay, s p50/p90; goal reached after the intruder left / left (%);"
    );
    println!(
        "  stayed in the way: goal reached anyway / infeasible reported (rt-core said the goal taken) / stayed"
    );
    println!(
        "  {:<20} {:>6} {:>6} {:>6} {:>7} {:>6} {:>11} {:>11} {:>11} {:>6} {:>17}",
        "kind",
        "n",
        "avoid",
        "unavd",
        "no stop",
        "%",
        "lost s",
        "start s",
        "reached",
        "%",
        "stayed r/i/n"
    );
    for kind in IntruderKind::ALL {
        if let Some(g) = s.by_kind.get(kind.name()) {
            row(kind.name(), g);
        }
    }
    row("all", &s.all);
    let t = &s.moving_world_targets;
    println!(
        "MOVING-WORLD TARGETS (issue 42): >= 2000 intrusions: {} ({}); 0 avoidable contacts while moving up to 1.0 m/s: {}; >= 90 % without a stop: {} ({} %); time lost p50 <= 1.0 s: {} ({:.2} s); >= 99 % reach the goal after the intruder left: {} ({} %); goal taken said within 1 s: {} (p50 {:.2} s, max {:.2} s over {})",
        yes(t.at_least_2000_intrusions),
        s.all.episodes,
        yes(t.no_avoidable_moving_contact_up_to_1_m_s),
        yes(t.handled_without_stop_at_least_90_percent),
        pct(s.all.outcome.handled_without_stop, s.all.episodes),
        yes(t.time_lost_p50_at_most_1_s),
        s.all.time_lost_s.p50,
        yes(t.reach_after_clear_at_least_99_percent),
        pct(s.all.reached_after_clear, s.all.intruder_cleared),
        yes(t.infeasible_said_within_1_s),
        s.all.outcome.infeasible_report_delay_s.p50,
        s.all.outcome.infeasible_report_delay_s.max,
        s.all.outcome.infeasible_report_delay_s.samples,
    );
}
