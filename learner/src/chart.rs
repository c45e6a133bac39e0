//! A minimal hand-written SVG line chart (title, stacked panels sharing one x axis, axes,
//! numbered ticks with grid lines, polylines, legend) for the reward curve of a run
//! ([`crate::metrics::MetricsLog::plot`]). No dependencies; the output is a plain SVG 1.1
//! document that browsers and image viewers open directly.

use std::fmt::Write as _;

/// Canvas width (px).
pub const WIDTH: f64 = 900.0;
/// Canvas height (px).
pub const HEIGHT: f64 = 600.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 880.0;

/// One line of a panel.
#[derive(Debug, Clone, Copy)]
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// The polyline's `class` attribute (lets readers and tests find the line).
    pub class: &'a str,
    /// Stroke colour (any SVG colour).
    pub color: &'a str,
    /// Stroke width (px).
    pub width: f64,
    /// Points `(x, y)` in data units, in drawing order.
    pub points: &'a [(f64, f64)],
}

/// A plot area with its own y range.
#[derive(Debug, Clone, Copy)]
pub struct Panel<'a> {
    /// Top edge of the plot area (px).
    pub top: f64,
    /// Height of the plot area (px).
    pub height: f64,
    /// Y range `(min, max)` in data units.
    pub y_range: (f64, f64),
    /// Y-axis label.
    pub y_label: &'a str,
    /// The lines.
    pub series: &'a [Series<'a>],
    /// Draw a legend (lower right) naming the series.
    pub legend: bool,
}

/// A chart: title, panels stacked vertically over a shared x range.
#[derive(Debug, Clone, Copy)]
pub struct Chart<'a> {
    /// Title (escaped on output).
    pub title: &'a str,
    /// X-axis label, under the last panel.
    pub x_label: &'a str,
    /// X range `(min, max)` in data units.
    pub x_range: (f64, f64),
    /// The panels, top to bottom.
    pub panels: &'a [Panel<'a>],
}

impl Chart<'_> {
    /// The SVG document.
    pub fn to_svg(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{}" y="26" font-size="20" text-anchor="middle">{}</text>"#,
            WIDTH / 2.0,
            escape(self.title)
        );
        for p in self.panels {
            self.panel(&mut s, p);
        }
        if let Some(last) = self.panels.last() {
            let _ = writeln!(
                s,
                r#"<text x="{}" y="{:.1}" text-anchor="middle">{}</text>"#,
                (LEFT + RIGHT) / 2.0,
                last.top + last.height + 36.0,
                escape(self.x_label)
            );
        }
        s.push_str("</svg>\n");
        s
    }

    fn sx(&self, x: f64) -> f64 {
        let (x0, x1) = self.x_range;
        LEFT + (x - x0) / (x1 - x0) * (RIGHT - LEFT)
    }

    fn panel(&self, s: &mut String, p: &Panel<'_>) {
        let bottom = p.top + p.height;
        let (y0, y1) = p.y_range;
        let sy = |y: f64| bottom - (y - y0) / (y1 - y0) * p.height;
        // Grid lines and numbered ticks.
        for y in ticks(y0, y1, 5) {
            let py = sy(y);
            let _ = writeln!(
                s,
                r##"<line x1="{LEFT}" y1="{py:.1}" x2="{RIGHT}" y2="{py:.1}" stroke="#e0e0e0"/><line x1="{}" y1="{py:.1}" x2="{LEFT}" y2="{py:.1}" stroke="black"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
                LEFT - 5.0,
                LEFT - 8.0,
                py + 4.0,
                tick_label(y, y0, y1, 5)
            );
        }
        let (x0, x1) = self.x_range;
        for x in ticks(x0, x1, 8) {
            let px = self.sx(x);
            let _ = writeln!(
                s,
                r##"<line x1="{px:.1}" y1="{:.1}" x2="{px:.1}" y2="{bottom:.1}" stroke="#e0e0e0"/><line x1="{px:.1}" y1="{bottom:.1}" x2="{px:.1}" y2="{:.1}" stroke="black"/><text x="{px:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
                p.top,
                bottom + 5.0,
                bottom + 18.0,
                tick_label(x, x0, x1, 8)
            );
        }
        // Axes.
        let _ = writeln!(
            s,
            r#"<path d="M{LEFT},{:.1} V{bottom:.1} H{RIGHT}" fill="none" stroke="black"/>"#,
            p.top
        );
        let (cx, cy) = (LEFT - 60.0, p.top + p.height / 2.0);
        let _ = writeln!(
            s,
            r#"<text x="{cx}" y="{cy:.1}" text-anchor="middle" transform="rotate(-90 {cx} {cy:.1})">{}</text>"#,
            escape(p.y_label)
        );
        for line in p.series.iter().filter(|l| !l.points.is_empty()) {
            let pts: Vec<String> = line
                .points
                .iter()
                .map(|&(x, y)| format!("{:.1},{:.1}", self.sx(x), sy(y)))
                .collect();
            let _ = writeln!(
                s,
                r#"<polyline class="{}" points="{}" fill="none" stroke="{}" stroke-width="{}"/>"#,
                escape(line.class),
                pts.join(" "),
                escape(line.color),
                line.width
            );
        }
        if p.legend {
            legend(s, p.series, bottom);
        }
    }
}

/// The legend box in the lower right corner of a panel whose plot area ends at `bottom`.
fn legend(s: &mut String, series: &[Series<'_>], bottom: f64) {
    let (w, row) = (280.0, 18.0);
    let h = row * series.len() as f64 + 8.0;
    let (x, y) = (RIGHT - w - 10.0, bottom - h - 10.0);
    let _ = writeln!(
        s,
        r#"<rect x="{x}" y="{y:.1}" width="{w}" height="{h:.1}" fill="white" fill-opacity="0.8" stroke="black"/>"#
    );
    for (k, line) in series.iter().enumerate() {
        let ly = y + 4.0 + row * (k as f64 + 0.5);
        let _ = writeln!(
            s,
            r#"<line x1="{}" y1="{ly:.1}" x2="{}" y2="{ly:.1}" stroke="{}" stroke-width="{}"/><text x="{}" y="{:.1}">{}</text>"#,
            x + 8.0,
            x + 28.0,
            escape(line.color),
            line.width,
            x + 34.0,
            ly + 4.0,
            escape(line.name)
        );
    }
}

/// The step between "nice" ticks (1, 2 or 5 × 10^k) for about `target` ticks over `lo..=hi`.
fn tick_step(lo: f64, hi: f64, target: usize) -> f64 {
    let span = hi - lo;
    if !(span.is_finite() && span > 0.0) {
        return 1.0;
    }
    let raw = span / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let nice = if norm < 1.5 {
        1.0
    } else if norm < 3.0 {
        2.0
    } else if norm < 7.0 {
        5.0
    } else {
        10.0
    };
    nice * mag
}

/// Nice tick values within `lo..=hi` (about `target` of them).
pub fn ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    let step = tick_step(lo, hi, target);
    if !(hi - lo).is_finite() || hi <= lo {
        return vec![lo];
    }
    let first = (lo / step).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    // `+ 0.0` turns -0.0 into 0.0.
    (first..=last).map(|k| k as f64 * step + 0.0).collect()
}

/// The text of tick `v` of an axis over `lo..=hi` with about `target` ticks: as many decimals
/// as the step needs, with a `k`/`M` suffix for large values.
pub fn tick_label(v: f64, lo: f64, hi: f64, target: usize) -> String {
    let step = tick_step(lo, hi, target);
    let big = lo.abs().max(hi.abs());
    let (scale, suffix) = if big >= 1e6 {
        (1e6, "M")
    } else if big >= 1e4 {
        (1e3, "k")
    } else {
        (1.0, "")
    };
    if v == 0.0 && !suffix.is_empty() {
        return "0".into();
    }
    let s = step / scale;
    let decimals = if s >= 1.0 {
        0
    } else {
        (-s.log10()).ceil() as usize
    };
    format!("{:.*}{suffix}", decimals, v / scale + 0.0)
}

/// `text` with the XML special characters escaped.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(lo: f64, hi: f64, target: usize) -> Vec<String> {
        ticks(lo, hi, target)
            .into_iter()
            .map(|v| tick_label(v, lo, hi, target))
            .collect()
    }

    #[test]
    fn ticks_are_round_numbers_inside_the_range() {
        assert_eq!(
            labels(0.0, 1.05, 5),
            ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]
        );
        assert_eq!(labels(-3.2, 7.9, 5), ["-2", "0", "2", "4", "6"]);
        assert_eq!(labels(0.0, 50_000.0, 8)[..3], ["0", "5k", "10k"]);
        let big = labels(0.0, 1_000_000.0, 8);
        assert_eq!(big.len(), 11);
        assert_eq!((big[3].as_str(), big[10].as_str()), ("0.3M", "1.0M"));
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(escape(r#"a<b & "c""#), "a&lt;b &amp; &quot;c&quot;");
    }
}
