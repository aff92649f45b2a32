//! A figure: lines over two axes, with horizontal and vertical reference
//! lines, shaded x spans, rows of event marks above the frame, and a legend
//! to the right, rendered as one self-contained `<svg>` element.
//!
//! Sizes are fixed (the report's pages show figures one under the other at
//! one width), so that text never scales with the data.

use crate::axis::{Axis, Tick, auto_range, ticks};
use crate::decimate::{finite_runs, min_max_per_column};
use crate::xml::escape;
use std::fmt::Write;

/// Colours for series without one (Tableau 10: distinct, colour-blind aware).
pub const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf",
];

const WIDTH: f64 = 1000.0;
const LEGEND_WIDTH: f64 = 250.0;
const LEFT: f64 = 74.0;
const PLOT_HEIGHT: f64 = 280.0;
const TITLE_HEIGHT: f64 = 30.0;
const MARK_ROW: f64 = 13.0;
const BOTTOM_MARGIN: f64 = 46.0;
const FONT: f64 = 11.0;
/// Average advance of a character at [`FONT`] in a sans-serif face: enough to
/// keep tick labels from running into each other.
const CHAR_WIDTH: f64 = 6.3;

/// A line through data points (x ascending for time series).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub color: Option<String>,
    pub dashed: bool,
}

/// A horizontal (on y) or vertical (on x) line at a data value.
#[derive(Debug, Clone, PartialEq)]
pub struct RefLine {
    pub at: f64,
    pub label: String,
    pub color: String,
}

/// A shaded range of x.
#[derive(Debug, Clone, PartialEq)]
pub struct Span {
    pub from: f64,
    pub to: f64,
    pub label: String,
    pub color: String,
}

/// Instants (x values) drawn as ticks in a row above the frame, one row per
/// kind: misses, stalls, fallbacks.
#[derive(Debug, Clone, PartialEq)]
pub struct Marks {
    pub name: String,
    pub xs: Vec<f64>,
    pub color: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Unique within a page: names the clip path.
    pub id: String,
    pub title: String,
    pub x: Axis,
    pub y: Axis,
    pub series: Vec<Series>,
    pub hlines: Vec<RefLine>,
    /// Labelled at the top of the frame (events).
    pub vlines: Vec<RefLine>,
    pub spans: Vec<Span>,
    pub marks: Vec<Marks>,
    /// Shown in the frame when there is nothing to draw.
    pub empty_note: String,
}

impl Figure {
    pub fn new(id: &str, title: &str, x: Axis, y: Axis) -> Self {
        Self {
            id: id
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
                .collect(),
            title: title.to_string(),
            x,
            y,
            series: Vec::new(),
            hlines: Vec::new(),
            vlines: Vec::new(),
            spans: Vec::new(),
            marks: Vec::new(),
            empty_note: "no data".into(),
        }
    }

    /// Adds a line in the next palette colour.
    pub fn line(&mut self, name: &str, points: Vec<(f64, f64)>) -> &mut Self {
        self.series.push(Series {
            name: name.to_string(),
            points,
            color: None,
            dashed: false,
        });
        self
    }

    pub fn colored_line(&mut self, name: &str, points: Vec<(f64, f64)>, color: &str) -> &mut Self {
        self.series.push(Series {
            name: name.to_string(),
            points,
            color: Some(color.to_string()),
            dashed: false,
        });
        self
    }

    pub fn hline(&mut self, at: f64, label: &str, color: &str) -> &mut Self {
        self.hlines.push(RefLine {
            at,
            label: label.to_string(),
            color: color.to_string(),
        });
        self
    }

    pub fn vline(&mut self, at: f64, label: &str, color: &str) -> &mut Self {
        self.vlines.push(RefLine {
            at,
            label: label.to_string(),
            color: color.to_string(),
        });
        self
    }

    pub fn span(&mut self, from: f64, to: f64, label: &str, color: &str) -> &mut Self {
        self.spans.push(Span {
            from,
            to,
            label: label.to_string(),
            color: color.to_string(),
        });
        self
    }

    /// A row of marks (left out when `xs` is empty: nothing happened).
    pub fn marks(&mut self, name: &str, xs: Vec<f64>, color: &str) -> &mut Self {
        self.marks.push(Marks {
            name: name.to_string(),
            xs,
            color: color.to_string(),
        });
        self
    }

    fn has_data(&self) -> bool {
        self.series.iter().any(|s| {
            s.points.iter().any(|(x, y)| {
                self.x.scale.position(*x).is_some() && self.y.scale.position(*y).is_some()
            })
        })
    }

    /// The axis range in positions: fixed, or from the values, widened to ticks.
    fn range(axis: &Axis, values: impl Iterator<Item = f64>, target: usize) -> (f64, f64) {
        if let Some((lo, hi)) = axis.range
            && let (Some(a), Some(b)) = (axis.scale.position(lo), axis.scale.position(hi))
            && b > a
        {
            return (a, b);
        }
        let (lo, hi) = values
            .filter_map(|v| axis.scale.position(v))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p), hi.max(p))
            });
        auto_range(axis.scale, lo, hi, target)
    }

    /// The figure as one `<svg>` element.
    pub fn to_svg(&self) -> String {
        let rows: Vec<&Marks> = self.marks.iter().filter(|m| !m.xs.is_empty()).collect();
        let top =
            TITLE_HEIGHT + MARK_ROW * rows.len() as f64 + if rows.is_empty() { 0.0 } else { 4.0 };
        let right = WIDTH - LEGEND_WIDTH;
        let bottom = top + PLOT_HEIGHT;
        let plot_width = right - LEFT;

        let xs = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.0));
        let x_range = Self::range(&self.x, xs, 8);
        let ys = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1))
            .chain(self.hlines.iter().map(|h| h.at));
        let y_range = Self::range(&self.y, ys, 6);
        let map = Mapping {
            x: x_range,
            y: y_range,
            left: LEFT,
            right,
            top,
            bottom,
        };

        let legend = self.legend_entries();
        let legend_bottom = top + 18.0 * legend.len() as f64;
        let height = (bottom + BOTTOM_MARGIN).max(legend_bottom + 10.0);

        let mut svg = String::with_capacity(16_384);
        let id = &self.id;
        let _ = write!(
            svg,
            r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH} {height}" width="{WIDTH}" height="{height}" font-family="sans-serif" font-size="{FONT}" role="img" aria-labelledby="{id}-title">"#
        );
        let _ = write!(
            svg,
            r#"<title id="{id}-title">{}</title><defs><clipPath id="{id}-clip"><rect x="{LEFT}" y="{top}" width="{plot_width}" height="{PLOT_HEIGHT}"/></clipPath></defs>"#,
            escape(&self.title)
        );
        let _ = write!(
            svg,
            r##"<rect width="{WIDTH}" height="{height}" fill="#ffffff"/><text x="{LEFT}" y="19" font-size="14" font-weight="bold">{}</text>"##,
            escape(&self.title)
        );

        // Grid and tick labels.
        let x_ticks = ticks(self.x.scale, x_range.0, x_range.1, 8);
        let y_ticks = ticks(self.y.scale, y_range.0, y_range.1, 6);
        svg.push_str(r##"<g stroke="#e4e4e4" stroke-width="1">"##);
        for t in &x_ticks {
            let x = map.px(t.position);
            let _ = write!(
                svg,
                r#"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{bottom}"/>"#
            );
        }
        for t in &y_ticks {
            let y = map.py(t.position);
            let _ = write!(
                svg,
                r#"<line x1="{LEFT}" y1="{y:.1}" x2="{right}" y2="{y:.1}"/>"#
            );
        }
        svg.push_str("</g>");
        self.tick_labels(&mut svg, &map, &x_ticks, &y_ticks);

        // Data, clipped to the frame.
        let _ = write!(svg, r#"<g clip-path="url(#{id}-clip)">"#);
        for s in &self.spans {
            if let (Some(a), Some(b)) = (self.x.scale.position(s.from), self.x.scale.position(s.to))
            {
                let (a, b) = (map.px(a), map.px(b));
                let _ = write!(
                    svg,
                    r#"<rect x="{:.1}" y="{top}" width="{:.1}" height="{PLOT_HEIGHT}" fill="{}" fill-opacity="0.13"/>"#,
                    a.min(b),
                    (b - a).abs().max(1.0),
                    escape(&s.color)
                );
            }
        }
        for h in &self.hlines {
            if let Some(p) = self.y.scale.position(h.at) {
                let y = map.py(p);
                let _ = write!(
                    svg,
                    r#"<line x1="{LEFT}" y1="{y:.1}" x2="{right}" y2="{y:.1}" stroke="{}" stroke-width="1.5" stroke-dasharray="6 4"/>"#,
                    escape(&h.color)
                );
            }
        }
        for v in &self.vlines {
            if let Some(p) = self.x.scale.position(v.at) {
                let x = map.px(p);
                let _ = write!(
                    svg,
                    r#"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{bottom}" stroke="{}" stroke-width="1" stroke-dasharray="3 3"/>"#,
                    escape(&v.color)
                );
            }
        }
        for (i, s) in self.series.iter().enumerate() {
            self.polylines(&mut svg, &map, s, &series_color(s, i));
        }
        svg.push_str("</g>");
        self.vline_labels(&mut svg, &map);

        // Mark rows above the frame.
        for (row, m) in rows.iter().enumerate() {
            let y = TITLE_HEIGHT + MARK_ROW * row as f64 + 2.0;
            let mut columns: Vec<i64> =
                m.xs.iter()
                    .filter_map(|x| self.x.scale.position(*x))
                    .map(|p| map.px(p).round() as i64)
                    .filter(|x| (LEFT as i64..=right as i64).contains(x))
                    .collect();
            columns.sort_unstable();
            columns.dedup();
            let mut d = String::new();
            for x in columns {
                let _ = write!(d, "M{x} {y:.1}v9");
            }
            if !d.is_empty() {
                let _ = write!(
                    svg,
                    r#"<path d="{d}" stroke="{}" stroke-width="1.5"/>"#,
                    escape(&m.color)
                );
            }
            // The row's name in the margin: its words before a count or colon.
            let short = m.name.split(['(', ':']).next().unwrap_or("").trim();
            let _ = write!(
                svg,
                r##"<text x="{:.1}" y="{:.1}" text-anchor="end" font-size="9" fill="#555555">{}</text>"##,
                LEFT - 4.0,
                y + 8.0,
                escape(&fit_text(short, 13.0))
            );
        }

        // Frame, axis labels, note.
        let _ = write!(
            svg,
            r##"<rect x="{LEFT}" y="{top}" width="{plot_width}" height="{PLOT_HEIGHT}" fill="none" stroke="#444444"/>"##
        );
        let _ = write!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            LEFT + plot_width / 2.0,
            bottom + 36.0,
            escape(&self.x.label)
        );
        let (lx, ly) = (14.0, top + PLOT_HEIGHT / 2.0);
        let _ = write!(
            svg,
            r#"<text x="{lx}" y="{ly:.1}" text-anchor="middle" transform="rotate(-90 {lx} {ly:.1})">{}</text>"#,
            escape(&self.y.label)
        );
        if !self.has_data() {
            let _ = write!(
                svg,
                r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="13" fill="#666666">{}</text>"##,
                LEFT + plot_width / 2.0,
                top + PLOT_HEIGHT / 2.0,
                escape(&self.empty_note)
            );
        }

        // Legend.
        let lx = right + 16.0;
        for (i, entry) in legend.iter().enumerate() {
            let y = top + 8.0 + 18.0 * i as f64;
            let color = escape(&entry.color);
            let _ = match entry.glyph {
                Glyph::Line { dashed } => write!(
                    svg,
                    r#"<line x1="{lx}" y1="{y}" x2="{}" y2="{y}" stroke="{color}" stroke-width="2"{}/>"#,
                    lx + 22.0,
                    if dashed {
                        r#" stroke-dasharray="6 4""#
                    } else {
                        ""
                    }
                ),
                Glyph::Tick => write!(
                    svg,
                    r#"<path d="M{} {}v10" stroke="{color}" stroke-width="2"/>"#,
                    lx + 11.0,
                    y - 5.0
                ),
                Glyph::Area => write!(
                    svg,
                    r#"<rect x="{lx}" y="{}" width="22" height="10" fill="{color}" fill-opacity="0.25"/>"#,
                    y - 5.0
                ),
            };
            let _ = write!(
                svg,
                r#"<text x="{}" y="{}">{}</text>"#,
                lx + 28.0,
                y + 4.0,
                escape(&fit_text(&entry.label, (LEGEND_WIDTH - 44.0) / CHAR_WIDTH))
            );
        }
        svg.push_str("</svg>");
        svg
    }

    fn tick_labels(&self, svg: &mut String, map: &Mapping, x_ticks: &[Tick], y_ticks: &[Tick]) {
        // A label that would overlap the one before it is left out.
        let mut last_end = f64::NEG_INFINITY;
        for t in x_ticks {
            let x = map.px(t.position);
            let half = CHAR_WIDTH * t.label.chars().count() as f64 / 2.0;
            if x - half < last_end + 6.0 {
                continue;
            }
            last_end = x + half;
            let _ = write!(
                svg,
                r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
                map.bottom + 15.0,
                escape(&t.label)
            );
        }
        let mut last_top = f64::INFINITY;
        for t in y_ticks {
            let y = map.py(t.position);
            if y + FONT / 2.0 > last_top - 2.0 {
                continue;
            }
            last_top = y - FONT / 2.0;
            let _ = write!(
                svg,
                r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"#,
                LEFT - 6.0,
                y + 4.0,
                escape(&t.label)
            );
        }
    }

    fn vline_labels(&self, svg: &mut String, map: &Mapping) {
        let mut last_end = f64::NEG_INFINITY;
        for v in &self.vlines {
            let Some(p) = self.x.scale.position(v.at) else {
                continue;
            };
            let x = map.px(p);
            if x < map.left || x > map.right || v.label.is_empty() {
                continue;
            }
            let width = CHAR_WIDTH * 0.9 * v.label.chars().count() as f64;
            if x < last_end + 4.0 || x + width > map.right {
                continue;
            }
            last_end = x + 3.0 + width;
            let _ = write!(
                svg,
                r#"<text x="{:.1}" y="{:.1}" font-size="10" fill="{}">{}</text>"#,
                x + 3.0,
                map.top + 11.0,
                escape(&v.color),
                escape(&v.label)
            );
        }
    }

    fn polylines(&self, svg: &mut String, map: &Mapping, s: &Series, color: &str) {
        let positions: Vec<(f64, f64)> = s
            .points
            .iter()
            .map(|(x, y)| {
                (
                    self.x.scale.position(*x).unwrap_or(f64::NAN),
                    self.y.scale.position(*y).unwrap_or(f64::NAN),
                )
            })
            .collect();
        let mut d = String::new();
        for run in finite_runs(&positions) {
            let kept = min_max_per_column(run, |x| map.px(x).floor() as i64);
            for (i, (x, y)) in kept.iter().enumerate() {
                let _ = write!(
                    d,
                    "{}{:.1} {:.1}",
                    if i == 0 { "M" } else { "L" },
                    map.px(*x),
                    map.py(*y)
                );
            }
            if kept.len() == 1 {
                // A lone point: a dot-sized segment so that it shows.
                d.push_str("h0.5");
            }
        }
        if d.is_empty() {
            return;
        }
        let _ = write!(
            svg,
            r#"<path d="{d}" fill="none" stroke="{}" stroke-width="1.3" stroke-linejoin="round"{}/>"#,
            escape(color),
            if s.dashed {
                r#" stroke-dasharray="5 3""#
            } else {
                ""
            }
        );
    }

    fn legend_entries(&self) -> Vec<LegendEntry> {
        let mut out: Vec<LegendEntry> = self
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| LegendEntry {
                label: s.name.clone(),
                color: series_color(s, i),
                glyph: Glyph::Line { dashed: s.dashed },
            })
            .collect();
        // Reference lines and spans without a label share the entry of an
        // earlier one (the second scan window).
        out.extend(
            self.hlines
                .iter()
                .filter(|h| !h.label.is_empty())
                .map(|h| LegendEntry {
                    label: h.label.clone(),
                    color: h.color.clone(),
                    glyph: Glyph::Line { dashed: true },
                }),
        );
        out.extend(
            self.spans
                .iter()
                .filter(|s| !s.label.is_empty())
                .map(|s| LegendEntry {
                    label: s.label.clone(),
                    color: s.color.clone(),
                    glyph: Glyph::Area,
                }),
        );
        out.extend(
            self.marks
                .iter()
                .filter(|m| !m.xs.is_empty())
                .map(|m| LegendEntry {
                    label: m.name.clone(),
                    color: m.color.clone(),
                    glyph: Glyph::Tick,
                }),
        );
        // Events share one entry per label kind.
        let mut seen: Vec<(&str, &str)> = Vec::new();
        for v in &self.vlines {
            let kind = v.label.split_whitespace().next().unwrap_or("");
            if !seen.contains(&(kind, v.color.as_str())) {
                seen.push((kind, v.color.as_str()));
                out.push(LegendEntry {
                    label: kind.to_string(),
                    color: v.color.clone(),
                    glyph: Glyph::Line { dashed: true },
                });
            }
        }
        out
    }
}

fn series_color(s: &Series, index: usize) -> String {
    s.color
        .clone()
        .unwrap_or_else(|| PALETTE[index % PALETTE.len()].to_string())
}

/// `text` cut to `max_chars` (with an ellipsis) so that it stays in the legend.
fn fit_text(text: &str, max_chars: f64) -> String {
    let max = max_chars.max(4.0) as usize;
    if text.chars().count() <= max {
        return text.to_string();
    }
    let mut cut: String = text.chars().take(max - 1).collect();
    cut.push('…');
    cut
}

enum Glyph {
    Line { dashed: bool },
    Tick,
    Area,
}

struct LegendEntry {
    label: String,
    color: String,
    glyph: Glyph,
}

/// Axis positions to pixels.
struct Mapping {
    x: (f64, f64),
    y: (f64, f64),
    left: f64,
    right: f64,
    top: f64,
    bottom: f64,
}

impl Mapping {
    fn px(&self, position: f64) -> f64 {
        self.left + (position - self.x.0) / (self.x.1 - self.x.0) * (self.right - self.left)
    }

    fn py(&self, position: f64) -> f64 {
        self.bottom - (position - self.y.0) / (self.y.1 - self.y.0) * (self.bottom - self.top)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::xml::check_well_formed;

    fn long_figure() -> Figure {
        let n = 100_000;
        let mut f = Figure::new(
            "t 1",
            "Lateness <&> \"quoted\"",
            Axis::linear("time [s]"),
            Axis::linear("µs"),
        );
        let mut points: Vec<(f64, f64)> =
            (0..n).map(|k| (k as f64 * 1e-4, (k % 7) as f64)).collect();
        points[500].1 = f64::NAN;
        f.line("lateness", points)
            .hline(100.0, "budget (one period)", "#d62728")
            .span(2.0, 5.0, "scan window", "#2ca02c")
            .marks("misses (3)", vec![1.0, 1.00001, 7.5], "#d62728")
            .marks("stalls (0)", vec![], "#9467bd")
            .vline(3.0, "swap controller", "#555555");
        f
    }

    #[test]
    fn svg_is_well_formed_and_self_contained() {
        let svg = long_figure().to_svg();
        check_well_formed(&svg).unwrap();
        assert!(svg.starts_with("<svg"));
        assert!(!svg.contains("href"));
        assert!(!svg.contains("<image"));
        assert!(svg.contains("Lateness &lt;&amp;&gt; &quot;quoted&quot;"));
        assert!(
            svg.contains(r#"clip-path="url(#t-1-clip)""#),
            "the id is sanitised"
        );
    }

    #[test]
    fn a_long_trace_stays_small() {
        let svg = long_figure().to_svg();
        // 100 000 samples at ~13 bytes each would be 1.3 MB.
        assert!(svg.len() < 120_000, "{} bytes", svg.len());
        // The NaN splits the line into two paths' worth of moves.
        let data_path = svg.split("<path d=\"").nth(1).unwrap();
        assert_eq!(data_path.split('"').next().unwrap().matches('M').count(), 2);
    }

    #[test]
    fn empty_mark_rows_are_left_out_and_the_budget_line_is_in_range() {
        let svg = long_figure().to_svg();
        assert!(svg.contains("misses (3)"));
        assert!(!svg.contains("stalls (0)"));
        // The y axis reaches the budget line although the data stay below 7.
        assert!(svg.contains(">100<"), "{svg}");
    }

    #[test]
    fn empty_figure_says_so() {
        let mut f = Figure::new("e", "Empty", Axis::linear("x"), Axis::log10("y"));
        f.empty_note = "no flexible modes in this plant".into();
        f.line("nothing", vec![(1.0, 0.0), (2.0, -1.0)]);
        let svg = f.to_svg();
        check_well_formed(&svg).unwrap();
        assert!(svg.contains("no flexible modes in this plant"));
    }

    #[test]
    fn percentile_axis_labels_do_not_overlap() {
        let mut f = Figure::new(
            "p",
            "Latency",
            Axis::percentile("percentile"),
            Axis::linear("µs"),
        );
        let points: Vec<(f64, f64)> = (0..60)
            .map(|i| {
                let q = 1.0 - 0.5f64.powf(i as f64 / 3.0);
                (q, 10.0 + i as f64)
            })
            .collect();
        f.line("round_trip", points);
        let svg = f.to_svg();
        check_well_formed(&svg).unwrap();
        for label in ["0 %", "90 %", "99 %", "99.9 %"] {
            assert!(svg.contains(&format!(">{label}<")), "{label}");
        }
    }
}
