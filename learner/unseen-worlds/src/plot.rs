//! The benchmark's pictures (`worlds.png`, `adaptation.png`), drawn with plotters and
//! written atomically.

use std::path::Path;

use anyhow::{Context, Result};
use learner::checkpoint::write_atomic;
use plotters::prelude::*;

use crate::{Aggregate, GeneratorTable, RetrainRow};

fn plot_err(path: &Path, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("plotting {}: {e}", path.display())
}

/// Draws a PNG with `draw` into a scratch file beside `path`, then writes it to `path`
/// atomically ([`write_atomic`]): a reader never sees half a picture.
pub(crate) fn png_atomic(path: &Path, draw: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("plot.png");
    let scratch = path.with_file_name(format!(".{name}.{}.tmp.png", std::process::id()));
    let drawn = draw(&scratch).and_then(|()| {
        let bytes =
            std::fs::read(&scratch).with_context(|| format!("reading {}", scratch.display()))?;
        write_atomic(path, &bytes)?;
        Ok(())
    });
    let _ = std::fs::remove_file(&scratch);
    drawn
}

/// One series of bars: legend, colour and the rate it shows.
type Bars = (&'static str, RGBColor, fn(&Aggregate) -> f64);

/// The three rates [`plot_rates`] shows, in bar order.
const RATE_SERIES: [Bars; 3] = [
    ("policy zero-shot", RGBColor(31, 119, 180), |a| {
        a.zero_shot_rate
    }),
    ("scripted straight line", RGBColor(255, 127, 14), |a| {
        a.straight_line_rate
    }),
    ("planner path (ceiling)", RGBColor(150, 150, 150), |a| {
        a.planner_rate
    }),
];

/// The `k`-th series' bars, one per generator: the bar's left edge (the generator's slot
/// plus the series' offset) and its height, `value` in percent.
fn bar_tops(tables: &[GeneratorTable], k: usize, value: fn(&Aggregate) -> f64) -> Vec<(f64, f64)> {
    tables
        .iter()
        .enumerate()
        .map(|(i, t)| {
            (
                i as f64 + 0.15 + 0.24 * k as f64,
                100.0 * value(&t.aggregate),
            )
        })
        .collect()
}

/// Grouped bars: per generator, the policy zero-shot, the straight line and the planner
/// (success rate over the feasible worlds), each labelled with its value.
pub(crate) fn plot_rates(path: &Path, tables: &[GeneratorTable], seed: u64) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| plot_err(path, e);
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let n = tables.len().max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("Zero-shot success on feasible unseen worlds per generator (seed {seed})"),
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0f64..n as f64, 0.0f64..130.0)
        .map_err(|e| err(&e))?;
    let names: Vec<String> = tables
        .iter()
        .map(|t| format!("{} ({} worlds)", t.generator, t.aggregate.feasible))
        .collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - i as f64 - 0.5).abs() < 1e-6 {
                names.get(i).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc("success (% of feasible worlds)")
        .y_labels(14)
        .y_label_formatter(&|y| {
            if *y <= 100.0 {
                format!("{y:.0}")
            } else {
                String::new()
            }
        })
        .label_style(("sans-serif", 15))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(&e))?;
    for (k, (label, colour, value)) in RATE_SERIES.into_iter().enumerate() {
        let bars = bar_tops(tables, k, value);
        chart
            .draw_series(
                bars.iter()
                    .map(|&(x, v)| Rectangle::new([(x, 0.0), (x + 0.22, v)], colour.filled())),
            )
            .map_err(|e| err(&e))?
            .label(label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], colour.filled()));
        chart
            .draw_series(bars.iter().map(|&(x, v)| {
                Text::new(
                    format!("{v:.0}"),
                    (x + 0.04, v + 5.0),
                    ("sans-serif", 14).into_font(),
                )
            }))
            .map_err(|e| err(&e))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// One bar per retrained world: world change → learned policy (s), green learned, red not.
pub(crate) fn plot_adaptation(path: &Path, tables: &[GeneratorTable]) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| plot_err(path, e);
    let rows: Vec<(String, &RetrainRow)> = tables
        .iter()
        .flat_map(|t| {
            t.worlds.iter().filter_map(move |r| {
                r.retrained
                    .as_ref()
                    .map(|re| (format!("{}{}", &t.generator[..1], r.index), re))
            })
        })
        .collect();
    let top = rows.iter().map(|(_, r)| r.wall_s).fold(1.0f64, f64::max) * 1.15;
    let n = rows.len().max(1);
    let root = BitMapBackend::new(path, (1000, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Retraining per failed world (t task, u uniform, c cluttered, a adversarial; green learned, red not)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(70)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0f64..n as f64, 0.0f64..top)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - i as f64 - 0.5).abs() < 1e-6 {
                rows.get(i).map(|r| r.0.clone()).unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc("retraining wall time (s)")
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| err(&e))?;
    chart
        .draw_series(rows.iter().enumerate().map(|(i, (_, r))| {
            let colour = if r.success {
                RGBColor(46, 160, 67)
            } else {
                RGBColor(214, 39, 40)
            };
            Rectangle::new(
                [(i as f64 + 0.15, 0.0), (i as f64 + 0.85, r.wall_s)],
                colour.filled(),
            )
        }))
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
