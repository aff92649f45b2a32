//! A figure: lines or markers over two axes, with horizontal and vertical
//! reference lines, shaded x spans, rows of event marks above the frame, and
//! a legend to the right, rendered as one self-contained `<svg>` element;
//! and a [`Stack`] of figures sharing one element (a Bode plot's magnitude
//! over its phase).
//!
//! Sizes are fixed (the report's pages show figures one under the other at
//! one width), so that text never scales with the data; a figure may ask for
//! a taller frame, and for equal units on both axes (a Nyquist plot).

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

/// A line through data points (x ascending for time series), or with a
/// marker a point drawn at each of them and no line.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub color: Option<String>,
    pub dashed: bool,
    /// Some: a marker at each point, no line between them.
    pub marker: Option<Marker>,
}

/// How a point of a [`Series`] of markers is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    /// A filled circle.
    Dot,
    /// A hollow circle: a point of less weight (a measured line of low
    /// coherence beside the trusted ones).
    Ring,
    /// A cross (×): a point of reference, such as −1 on a Nyquist plot.
    Cross,
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
    /// Height of the frame in pixels.
    pub plot_height: f64,
    /// One data unit as long on x as on y (both axes linear): the range
    /// that is the shorter for its side is widened about its middle, so
    /// that a circle is drawn round (a Nyquist plot).
    pub equal_aspect: bool,
}

impl Figure {
    pub fn new(id: &str, title: &str, x: Axis, y: Axis) -> Self {
        Self {
            id: sanitise_id(id),
            title: title.to_string(),
            x,
            y,
            series: Vec::new(),
            hlines: Vec::new(),
            vlines: Vec::new(),
            spans: Vec::new(),
            marks: Vec::new(),
            empty_note: "no data".into(),
            plot_height: PLOT_HEIGHT,
            equal_aspect: false,
        }
    }

    /// A frame `plot_height` pixels high with one data unit as long on x as
    /// on y (see [`equal_aspect`](Self::equal_aspect)).
    pub fn with_equal_aspect(mut self, plot_height: f64) -> Self {
        self.plot_height = plot_height;
        self.equal_aspect = true;
        self
    }

    /// Adds a line in the next palette colour.
    pub fn line(&mut self, name: &str, points: Vec<(f64, f64)>) -> &mut Self {
        self.series.push(Series {
            name: name.to_string(),
            points,
            color: None,
            dashed: false,
            marker: None,
        });
        self
    }

    pub fn colored_line(&mut self, name: &str, points: Vec<(f64, f64)>, color: &str) -> &mut Self {
        self.series.push(Series {
            name: name.to_string(),
            points,
            color: Some(color.to_string()),
            dashed: false,
            marker: None,
        });
        self
    }

    /// Adds points drawn as markers, with no line between them.
    pub fn scatter(
        &mut self,
        name: &str,
        points: Vec<(f64, f64)>,
        color: &str,
        marker: Marker,
    ) -> &mut Self {
        self.series.push(Series {
            name: name.to_string(),
            points,
            color: Some(color.to_string()),
            dashed: false,
            marker: Some(marker),
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

    /// The axes' ranges in positions, for a frame of this many pixels.
    fn ranges(&self, plot_width: f64, plot_height: f64) -> ((f64, f64), (f64, f64)) {
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
        if self.equal_aspect {
            equal_units(x_range, y_range, plot_width, plot_height)
        } else {
            (x_range, y_range)
        }
    }

    /// The data ranges (x, y) the frame shows as the figure stands: what
    /// falls outside them is clipped.
    pub fn shown_ranges(&self) -> ((f64, f64), (f64, f64)) {
        let (x, y) = self.ranges(WIDTH - LEGEND_WIDTH - LEFT, self.frame_height());
        let value = |axis: &Axis, r: (f64, f64)| (axis.scale.value(r.0), axis.scale.value(r.1));
        (value(&self.x, x), value(&self.y, y))
    }

    fn frame_height(&self) -> f64 {
        if self.plot_height.is_finite() && self.plot_height > 0.0 {
            self.plot_height
        } else {
            PLOT_HEIGHT
        }
    }

    /// The figure as one `<svg>` element.
    pub fn to_svg(&self) -> String {
        let (body, height) = self.body();
        root_svg(&self.id, height, &body)
    }

    /// The figure's elements (its `<title>` first) and its height in pixels,
    /// to go inside an `<svg>` element of [`WIDTH`].
    fn body(&self) -> (String, f64) {
        let rows: Vec<&Marks> = self.marks.iter().filter(|m| !m.xs.is_empty()).collect();
        let top =
            TITLE_HEIGHT + MARK_ROW * rows.len() as f64 + if rows.is_empty() { 0.0 } else { 4.0 };
        let right = WIDTH - LEGEND_WIDTH;
        let plot_height = self.frame_height();
        let bottom = top + plot_height;
        let plot_width = right - LEFT;

        let (x_range, y_range) = self.ranges(plot_width, plot_height);
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
            r#"<title id="{id}-title">{}</title><defs><clipPath id="{id}-clip"><rect x="{LEFT}" y="{top}" width="{plot_width}" height="{plot_height}"/></clipPath></defs>"#,
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
                    r#"<rect x="{:.1}" y="{top}" width="{:.1}" height="{plot_height}" fill="{}" fill-opacity="0.13"/>"#,
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
            match s.marker {
                None => self.polylines(&mut svg, &map, s, &series_color(s, i)),
                Some(marker) => self.markers(&mut svg, &map, s, marker, &series_color(s, i)),
            }
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
            r##"<rect x="{LEFT}" y="{top}" width="{plot_width}" height="{plot_height}" fill="none" stroke="#444444"/>"##
        );
        let _ = write!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            LEFT + plot_width / 2.0,
            bottom + 36.0,
            escape(&self.x.label)
        );
        let (lx, ly) = (14.0, top + plot_height / 2.0);
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
                top + plot_height / 2.0,
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
                Glyph::Marker(marker) => {
                    write_marker(&mut svg, marker, lx + 11.0, y, &color);
                    Ok(())
                }
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
        (svg, height)
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

    fn markers(&self, svg: &mut String, map: &Mapping, s: &Series, marker: Marker, color: &str) {
        let color = escape(color);
        let mut drawn = String::new();
        for (x, y) in &s.points {
            if let (Some(px), Some(py)) = (self.x.scale.position(*x), self.y.scale.position(*y)) {
                write_marker(&mut drawn, marker, map.px(px), map.py(py), &color);
            }
        }
        if !drawn.is_empty() {
            let _ = write!(svg, "<g>{drawn}</g>");
        }
    }

    fn legend_entries(&self) -> Vec<LegendEntry> {
        let mut out: Vec<LegendEntry> = self
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| LegendEntry {
                label: s.name.clone(),
                color: series_color(s, i),
                glyph: match s.marker {
                    Some(marker) => Glyph::Marker(marker),
                    None => Glyph::Line { dashed: s.dashed },
                },
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

/// Figures one under the other in one `<svg>` element, under one title:
/// a Bode plot's magnitude over its phase. Each keeps its own axes and
/// legend; their ids must differ (each names its clip path).
#[derive(Debug, Clone, PartialEq)]
pub struct Stack {
    /// Unique within a page, and unlike its panels' ids.
    pub id: String,
    pub title: String,
    pub panels: Vec<Figure>,
}

impl Stack {
    pub fn new(id: &str, title: &str, panels: Vec<Figure>) -> Self {
        Self {
            id: sanitise_id(id),
            title: title.to_string(),
            panels,
        }
    }

    /// The stack as one `<svg>` element.
    pub fn to_svg(&self) -> String {
        let id = &self.id;
        let mut body = String::with_capacity(32_768);
        let mut y = TITLE_HEIGHT;
        for panel in &self.panels {
            let (panel_body, height) = panel.body();
            let _ = write!(body, r#"<g transform="translate(0 {y})">{panel_body}</g>"#);
            y += height;
        }
        let head = format!(
            r##"<title id="{id}-title">{}</title><rect width="{WIDTH}" height="{y}" fill="#ffffff"/><text x="{LEFT}" y="20" font-size="15" font-weight="bold">{}</text>"##,
            escape(&self.title),
            escape(&self.title)
        );
        root_svg(id, y, &(head + &body))
    }
}

/// An `<svg>` element of [`WIDTH`] and `height` holding `body`, labelled by
/// the `<title>` of id `{id}-title` it holds.
fn root_svg(id: &str, height: f64, body: &str) -> String {
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH} {height}" width="{WIDTH}" height="{height}" font-family="sans-serif" font-size="{FONT}" role="img" aria-labelledby="{id}-title">{body}</svg>"#
    )
}

fn sanitise_id(id: &str) -> String {
    id.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect()
}

/// The ranges (positions) widened so that one unit takes as many pixels
/// on x (`width` pixels) as on y (`height`): the one whose side holds more
/// units per pixel is kept, the other widened about its middle.
fn equal_units(x: (f64, f64), y: (f64, f64), width: f64, height: f64) -> ((f64, f64), (f64, f64)) {
    let (per_x, per_y) = ((x.1 - x.0) / width, (y.1 - y.0) / height);
    if !(per_x.is_finite() && per_y.is_finite() && per_x > 0.0 && per_y > 0.0) {
        return (x, y);
    }
    let widen = |r: (f64, f64), span: f64| {
        let middle = (r.0 + r.1) / 2.0;
        (middle - span / 2.0, middle + span / 2.0)
    };
    if per_x > per_y {
        (x, widen(y, per_x * height))
    } else {
        (widen(x, per_y * width), y)
    }
}

/// One marker centred at pixel (x, y).
fn write_marker(svg: &mut String, marker: Marker, x: f64, y: f64, color: &str) {
    let _ = match marker {
        Marker::Dot => write!(
            svg,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="3.2" fill="{color}"/>"#
        ),
        Marker::Ring => write!(
            svg,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="3.2" fill="none" stroke="{color}" stroke-width="1.2"/>"#
        ),
        Marker::Cross => write!(
            svg,
            r#"<path d="M{:.1} {:.1}l10 10m0 -10l-10 10" stroke="{color}" stroke-width="2"/>"#,
            x - 5.0,
            y - 5.0
        ),
    };
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
    Marker(Marker),
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
    fn markers_are_drawn_without_a_line_and_shown_in_the_legend() {
        let mut f = Figure::new("m", "Markers", Axis::log10("f [Hz]"), Axis::linear("dB"));
        f.colored_line(
            "model",
            vec![(1.0, 0.0), (10.0, 1.0), (100.0, 2.0)],
            "#1f77b4",
        )
        .scatter(
            "trusted",
            vec![(2.0, 0.5), (20.0, 1.5)],
            "#222222",
            Marker::Dot,
        )
        .scatter("doubtful", vec![(50.0, 1.8)], "#999999", Marker::Ring)
        .scatter("reference", vec![(5.0, f64::NAN)], "#d62728", Marker::Cross);
        let svg = f.to_svg();
        check_well_formed(&svg).unwrap();
        // Two dots and a ring in the frame, one of each in the legend; the
        // NaN point is left out, the cross only in the legend.
        assert_eq!(svg.matches(r##"fill="#222222""##).count(), 3, "{svg}");
        assert_eq!(svg.matches(r##"fill="none" stroke="#999999""##).count(), 2);
        assert_eq!(svg.matches("l10 10m0 -10l-10 10").count(), 1);
        // One data line only: the model's.
        assert_eq!(svg.matches(r#"stroke-linejoin="round""#).count(), 1);
        for name in ["trusted", "doubtful", "reference"] {
            assert!(svg.contains(&format!(">{name}<")), "{name}");
        }
    }

    #[test]
    fn equal_aspect_draws_a_circle_round() {
        let mut f = Figure::new("n", "Nyquist", Axis::linear("Re"), Axis::linear("Im"))
            .with_equal_aspect(400.0);
        let circle: Vec<(f64, f64)> = (0..=64)
            .map(|i| {
                let a = i as f64 / 64.0 * std::f64::consts::TAU;
                (-1.0 + 0.5 * a.cos(), 0.5 * a.sin())
            })
            .collect();
        f.colored_line("circle", circle, "#d62728");
        let svg = f.to_svg();
        check_well_formed(&svg).unwrap();
        let path = svg.split("<path d=\"").nth(1).unwrap();
        let path = path.split('"').next().unwrap();
        let points: Vec<(f64, f64)> = path
            .split(['M', 'L'])
            .filter(|p| !p.is_empty())
            .map(|p| {
                let (x, y) = p.split_once(' ').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        let extent = |f: fn(&(f64, f64)) -> f64| {
            let v: Vec<f64> = points.iter().map(f).collect();
            v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                - v.iter().cloned().fold(f64::INFINITY, f64::min)
        };
        let (w, h) = (extent(|p| p.0), extent(|p| p.1));
        assert!(w > 50.0 && (w - h).abs() < 0.02 * w, "{w} x {h}");
        assert!(svg.contains(r#"height="400""#), "the taller frame");
        let ((x0, x1), (y0, y1)) = f.shown_ranges();
        let per_pixel = ((x1 - x0) / (WIDTH - LEGEND_WIDTH - LEFT), (y1 - y0) / 400.0);
        assert!((per_pixel.0 - per_pixel.1).abs() < 1e-9, "{per_pixel:?}");
        assert!(x0 <= -1.5 && x1 >= -0.5 && y0 <= -0.5 && y1 >= 0.5);
    }

    #[test]
    fn a_stack_is_one_svg_with_each_panel_clipped_on_its_own() {
        let panel = |id: &str, title: &str| {
            let mut f = Figure::new(id, title, Axis::log10("f [Hz]"), Axis::linear("v"));
            f.line("model", vec![(1.0, 0.0), (100.0, 1.0)]);
            f
        };
        let stack = Stack::new(
            "bode plot",
            "Bode <P>",
            vec![panel("bode-mag", "magnitude"), panel("bode-phase", "phase")],
        );
        let svg = stack.to_svg();
        check_well_formed(&svg).unwrap();
        assert_eq!(svg.matches("<svg").count(), 1);
        assert!(svg.contains(r#"aria-labelledby="bode-plot-title""#));
        assert!(svg.contains(r#"<title id="bode-plot-title">Bode &lt;P&gt;</title>"#));
        for id in ["bode-mag", "bode-phase"] {
            assert!(
                svg.contains(&format!(r#"clip-path="url(#{id}-clip)""#)),
                "{id}"
            );
        }
        // The second panel sits under the first.
        let offsets: Vec<&str> = svg
            .match_indices("translate(0 ")
            .map(|(at, _)| svg[at + 12..].split(')').next().unwrap())
            .collect();
        assert_eq!(offsets.len(), 2);
        let (a, b): (f64, f64) = (offsets[0].parse().unwrap(), offsets[1].parse().unwrap());
        assert!(b > a + PLOT_HEIGHT, "{offsets:?}");
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
