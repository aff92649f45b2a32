//! The section "Measured frequency responses", for a run that measured
//! the loop (docs/control.md §14): its scenario's `[measure]` and each
//! measurement ordered while it ran (`flexloop measure --running`), each in
//! a subsection of its own with the responses `flexloop measure` computes
//! from the run directory, drawn and tabled against the design's. A run
//! that measured nothing has no such section; a measurement that cannot be
//! computed says why in its subsection.

use super::RunData;
use super::document::{Block, FigureBlock, Table};
use crate::run::RunReport;
use crate::run_measurements::{MeasuredRun, folder_of, ordered_label};
use flexloop_analysis::loop_measurement::{
    LoopMeasurement, MIN_COHERENCE, MeasuredResponse, predicted,
};
use flexloop_analysis::loop_report::PEAK_LIMIT_DB;
use flexloop_analysis::run_log::JoinedLog;
use flexloop_control::excitation::{ExcitationShape, InjectionPoint};
use flexloop_design::LoopDesign;
use flexloop_plot::{Axis, Figure, Marker, Stack};
use flexloop_runfiles::RunDir;
use nalgebra::Complex;
use std::f64::consts::PI;

type C64 = Complex<f64>;
use std::path::Path;

pub const HEADING: &str = "Measured frequency responses";

const MODEL: &str = "#1f77b4";
const MEASURED: &str = "#222222";
const DOUBTFUL: &str = "#a0a0a0";
const RED: &str = "#d62728";

/// Points of the design's plant drawn between the first and the last line.
const MODEL_POINTS: usize = 600;

/// One measurement of the run, as `flexloop measure` computes it, or why
/// it cannot be.
pub struct Measured {
    /// The tick an ordered measurement was ordered to start at; None for
    /// the scenario's `[measure]`.
    pub ordered_start: Option<u64>,
    /// Where `flexloop measure` writes it, relative to the run directory.
    pub folder: String,
    /// The measurement and the design of the loop it measured.
    pub result: Result<(LoopMeasurement, Box<LoopDesign>), String>,
}

impl Measured {
    /// What the subsection's words call it.
    fn name(&self) -> String {
        match self.ordered_start {
            None => "The scenario's `[measure]`".to_string(),
            Some(tick) => format!("The measurement ordered at tick {tick}"),
        }
    }

    fn heading(&self) -> String {
        match self.ordered_start {
            None => "The scenario's [measure]".to_string(),
            Some(tick) => format!("Ordered at tick {tick}"),
        }
    }

    /// Words that single out an ordered measurement in a sentence about
    /// the responses; none for the scenario's.
    pub fn ordered_words(&self) -> String {
        self.ordered_start
            .map(|tick| format!(" of the measurement ordered at tick {tick}"))
            .unwrap_or_default()
    }

    /// Appended to its figures' file names and element ids, which must
    /// differ between the measurements of one page; none for the
    /// scenario's (its files keep their names).
    fn suffix(&self) -> String {
        self.ordered_start
            .map(|tick| format!("-{}", ordered_label(tick)))
            .unwrap_or_default()
    }
}

/// Every measurement of the run as `flexloop measure` computes it: the
/// same list (`run_measurements`), each judged against the loop it
/// measured. An error only where the run directory cannot be read; a
/// measurement that cannot be computed holds why.
pub fn measure(dir: &Path, run: &RunReport) -> anyhow::Result<Vec<Measured>> {
    let reader = MeasuredRun::open(dir)?;
    let listed = reader.measurements()?;
    if listed.is_empty() {
        return Ok(Vec::new());
    }
    // `RunReport::load` keeps what it derives from the sample files, not the
    // messages: the joined log is opened once more for the excitation's ticks.
    let joined = JoinedLog::open(dir).map_err(|e| e.to_string());
    let list = listed
        .into_iter()
        .map(|m| {
            let result = match (&joined, m.judged) {
                (Err(e), _) => Err(e.clone()),
                (_, Err(e)) => Err(format!("{e:#}")),
                (Ok(joined), Ok(judged)) => {
                    // Designed again only where the loop measured is not
                    // the one the run started with (a swap or set came first).
                    let design = if judged.scenario == run.scenario {
                        Ok(run.design.clone())
                    } else {
                        LoopDesign::from_scenario(&judged.scenario).map_err(|e| {
                            format!(
                                "the design of the loop it measured ({}): {e}",
                                judged.file.display()
                            )
                        })
                    };
                    design.and_then(|design| {
                        LoopMeasurement::of_log(&design, &judged.plan, &joined.log)
                            .map(|m| (m, Box::new(design)))
                            .map_err(|e| e.to_string())
                    })
                }
            }
            // A reason goes into a paragraph (a TOML error spans lines).
            .map_err(|e| e.split_whitespace().collect::<Vec<_>>().join(" "));
            Measured {
                ordered_start: m.ordered_start,
                folder: folder_of(&RunDir::new(""), &m.label).display().to_string(),
                result,
            }
        })
        .collect();
    Ok(list)
}

/// The section's blocks; none when the run measured nothing.
pub fn section(data: &RunData) -> Vec<Block> {
    if data.measurements.is_empty() {
        return Vec::new();
    }
    let mut blocks = vec![Block::Heading(HEADING.into())];
    if data.measurements.len() > 1 {
        let ordered = data
            .measurements
            .iter()
            .filter(|m| m.ordered_start.is_some())
            .count();
        blocks.push(Block::Paragraph(format!(
            "The run holds {} measurements: {}; each has a subsection of its own below, with its \
             own figures.",
            data.measurements.len(),
            if ordered < data.measurements.len() {
                format!(
                    "its scenario's `[measure]` and {ordered} ordered on the running loop \
                     (`flexloop measure --running`)"
                )
            } else {
                "each ordered on the running loop (`flexloop measure --running`)".to_string()
            }
        )));
    }
    for m in &data.measurements {
        blocks.extend(subsection(m));
    }
    blocks
}

/// One measurement's heading, words, tables and figures.
fn subsection(measured: &Measured) -> Vec<Block> {
    let mut blocks = vec![Block::Subheading(measured.heading())];
    let (m, design) = match &measured.result {
        Ok((m, design)) => (m, design.as_ref()),
        Err(reason) => {
            blocks.push(Block::Paragraph(format!(
                "{} excited the loop, but its frequency responses cannot be computed from this \
                 run directory: {reason}. `flexloop measure` says the same; the rest of this \
                 report does not depend on them.",
                measured.name()
            )));
            return blocks;
        }
    };
    let suffix = measured.suffix();
    blocks.push(Block::Paragraph(introduction(measured, m)));
    blocks.push(Block::Minor("The 6 dB rule, measured".into()));
    blocks.push(Block::Paragraph(rule_words(m)));
    blocks.push(Block::Table(rule_table(m)));
    blocks.push(Block::Minor("Measured against the design".into()));
    blocks.push(Block::Paragraph(format!(
        "Per response and decade band, the largest difference between the measured response \
         and the design's over the lines of coherence ≥ {MIN_COHERENCE} (as |measured / \
         design| in dB and its angle in degrees), and the number of lines compared; - where no \
         line of the band is trusted."
    )));
    blocks.push(Block::Table(deviation_table(m)));
    let grid = Grid::through(&m.plan.frequencies_hz());
    let design_loop = grid.as_ref().and_then(|g| loop_curves(design, m, g));
    blocks.push(plant_figure(m, design, &suffix));
    blocks.push(sensitivity_figure(m, design_loop.as_ref(), &suffix));
    blocks.push(loop_gain_figure(m, design_loop.as_ref(), &suffix));
    blocks
}

fn point_words(point: InjectionPoint) -> &'static str {
    match point {
        InjectionPoint::PlantInput => "plant input (a force beside the applied command)",
        InjectionPoint::Sensor => "sensor (an error added to the measured output)",
        InjectionPoint::Reference => {
            "reference (added by the controller to the first output's set-point)"
        }
    }
}

fn introduction(measured: &Measured, m: &LoopMeasurement) -> String {
    let lines = m.plan.frequencies_hz();
    format!(
        "{}{} added {} of {} lines from {:.3} to {:.1} Hz at the {}: {} \
         periods of {} samples averaged{} after {} transient ones{}. Each response is a ratio of \
         period-averaged line spectra with the excitation as the instrument, in closed loop and \
         with no model of the controller (docs/control.md §14), as `flexloop measure` computes \
         it from this run directory (and writes it to `{}/frf.csv`); beside it, the design's \
         response at the same lines. Lines of coherence below {MIN_COHERENCE} are drawn as grey \
         rings and left out of the verdicts.",
        measured.name(),
        match measured.ordered_start {
            // The plant starts it once designed, no earlier than ordered.
            Some(tick) if tick != m.plan.start_tick => format!(
                " (`flexloop measure --running`; it started at tick {})",
                m.plan.start_tick
            ),
            Some(_) => " (`flexloop measure --running`)".to_string(),
            None => String::new(),
        },
        match m.plan.shape {
            ExcitationShape::Multisine => "a periodic multisine",
            ExcitationShape::SweptSine => "a periodic logarithmic sweep",
            ExcitationShape::SteppedSine => "a stepped sine",
        },
        lines.len(),
        lines.first().copied().unwrap_or_default(),
        lines.last().copied().unwrap_or_default(),
        point_words(m.point),
        m.periods_used,
        m.plan.period_samples(),
        if m.plan.segments.len() > 1 {
            " over its tones, each"
        } else {
            ""
        },
        m.plan.transient_periods,
        if m.periods_saturated.is_empty() {
            String::new()
        } else {
            format!(
                " (left out: measured periods {:?}, in which the actuator reached its limit)",
                m.periods_saturated
            )
        },
        measured.folder,
    )
}

fn verdict(keeps: bool) -> &'static str {
    if keeps {
        "keeps the 6 dB rule"
    } else {
        "breaks the 6 dB rule"
    }
}

fn rule_words(m: &LoopMeasurement) -> String {
    let s = m.sensitivity();
    let design = s
        .predicted_peak_db()
        .map(|(db, hz)| format!(" (the design, at the same lines: {db:.2} dB at {hz:.1} Hz)"))
        .unwrap_or_default();
    match m.rule() {
        Some((db, hz, keeps)) => format!(
            "The measured |{}| peaks at {db:.2} dB at {hz:.1} Hz over the lines of coherence ≥ \
             {MIN_COHERENCE}{design}: the loop {} (|S| ≤ {PEAK_LIMIT_DB} dB, a distance of at \
             least 0.5 between the loop gain and −1).",
            s.name,
            verdict(keeps)
        ),
        None => format!(
            "No line of the measured |{}| has a coherence of at least {MIN_COHERENCE}: no verdict \
             on the 6 dB rule{design}.",
            s.name
        ),
    }
}

fn rule_table(m: &LoopMeasurement) -> Table {
    let s = m.sensitivity();
    let pair = |peak: Option<(f64, f64)>| match peak {
        Some((db, hz)) => [format!("{db:.2}"), format!("{hz:.1}")],
        None => ["-".to_string(), "-".to_string()],
    };
    let rule = m.rule();
    let [measured_db, measured_hz] = pair(rule.map(|(db, hz, _)| (db, hz)));
    let [design_db, design_hz] = pair(s.predicted_peak_db());
    Table {
        header: [
            "sensitivity",
            "6 dB rule",
            "measured peak [dB]",
            "at [Hz]",
            "design's peak [dB]",
            "at [Hz]",
        ]
        .map(String::from)
        .to_vec(),
        rows: vec![vec![
            format!("{}: {}", s.name, s.meaning),
            rule.map_or("no trusted line".to_string(), |(_, _, keeps)| {
                verdict(keeps).to_string()
            }),
            measured_db,
            measured_hz,
            design_db,
            design_hz,
        ]],
        numeric_from: 2,
    }
}

/// A frequency as written in a band's name: 10, 100, 0.1.
fn hz(v: f64) -> String {
    let rounded = (v * 1e3).round() / 1e3;
    format!("{rounded}")
}

fn deviation_table(m: &LoopMeasurement) -> Table {
    let bands = m.bands();
    let mut header = vec!["response".to_string(), "trusted lines".to_string()];
    header.extend(
        bands
            .iter()
            .map(|(lo, hi)| format!("{}–{} Hz", hz(*lo), hz(*hi))),
    );
    let rows = m
        .responses
        .iter()
        .map(|r| {
            let trusted = r.trusted_lines();
            let mut row = vec![
                format!("{}: {}", r.name, r.meaning),
                format!("{trusted} of {}", r.measured.response.len()),
            ];
            row.extend(bands.iter().map(|band| {
                if r.predicted.is_none() {
                    return "no prediction".to_string();
                }
                r.deviation(*band, MIN_COHERENCE)
                    .map_or("-".to_string(), |d| {
                        format!(
                            "{:.2} dB, {:.1}° ({} line{})",
                            d.max_db,
                            d.max_degrees,
                            d.lines,
                            if d.lines == 1 { "" } else { "s" }
                        )
                    })
            }));
            row
        })
        .collect();
    Table {
        header,
        rows,
        numeric_from: 1,
    }
}

/// |h| in dB and its angle in degrees in (−180, 180].
fn polar(re: f64, im: f64) -> (f64, f64) {
    (20.0 * re.hypot(im).log10(), im.atan2(re).to_degrees())
}

/// `degrees` moved by whole turns to lie within half a turn of `near`.
fn on_branch(degrees: f64, near: f64) -> f64 {
    degrees + 360.0 * ((near - degrees) / 360.0).round()
}

/// Angles made continuous along the sequence, the first taken in
/// (−270, 90] (a lag reads as negative).
fn unwrap(degrees: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut previous: Option<f64> = None;
    degrees
        .into_iter()
        .map(|d| {
            let d = match previous {
                Some(p) if d.is_finite() => on_branch(d, p),
                None if d > 90.0 => d - 360.0,
                _ => d,
            };
            if d.is_finite() {
                previous = Some(d);
            }
            d
        })
        .collect()
}

/// A log grid from the first line to the last that holds every line
/// exactly, for the design's curves.
struct Grid {
    hz: Vec<f64>,
    /// The index of each line in `hz`.
    at_lines: Vec<usize>,
}

impl Grid {
    fn through(lines: &[f64]) -> Option<Self> {
        let (&lo, &hi) = (lines.first()?, lines.last()?);
        let mut hz: Vec<f64> = (0..MODEL_POINTS)
            .map(|i| lo * (hi / lo).powf(i as f64 / (MODEL_POINTS - 1) as f64))
            .filter(|f| f.is_finite())
            .chain(lines.iter().copied())
            .collect();
        hz.sort_by(f64::total_cmp);
        hz.dedup();
        let at_lines = lines
            .iter()
            .map(|f| hz.binary_search_by(|g| g.total_cmp(f)).ok())
            .collect::<Option<Vec<_>>>()?;
        Some(Self { hz, at_lines })
    }
}

/// The design's plant on the grid: (Hz, dB, degrees unwrapped along it).
fn plant_curve(
    design: &LoopDesign,
    m: &LoopMeasurement,
    grid: &Grid,
) -> Option<Vec<(f64, f64, f64)>> {
    let plant = predicted(design, m.point, "P", &grid.hz)?;
    let (magnitude, angle): (Vec<f64>, Vec<f64>) = plant.iter().map(|h| polar(h.re, h.im)).unzip();
    Some(
        grid.hz
            .iter()
            .zip(magnitude.into_iter().zip(unwrap(angle)))
            .map(|(f, (db, degrees))| (*f, db, degrees))
            .collect(),
    )
}

/// The design's sensitivity and loop gain at the measured point on the
/// grid (`loop_measurement::predicted`, what the tables compare with),
/// refined where the loop gain moves fast near −1 (a lightly damped mode
/// turns it through a circle within a fraction of a percent of frequency).
fn loop_curves(design: &LoopDesign, m: &LoopMeasurement, grid: &Grid) -> Option<DesignLoop> {
    let (s_name, l_name) = (m.sensitivity().name, m.loop_gain().name);
    let at = |hz: &[f64]| -> Option<Vec<(C64, C64)>> {
        let s = predicted(design, m.point, s_name, hz)?;
        let l = predicted(design, m.point, l_name, hz)?;
        Some(s.into_iter().zip(l).collect())
    };
    let mut points: Vec<(f64, (C64, C64))> = grid.hz.iter().copied().zip(at(&grid.hz)?).collect();
    for _ in 0..REFINE_PASSES {
        let mut refined = Vec::with_capacity(points.len());
        for pair in points.windows(2) {
            let ((fa, (_, la)), (fb, (_, lb))) = (pair[0], pair[1]);
            refined.push(pair[0]);
            let chord = (la - lb).norm();
            if la.norm().min(lb.norm()) > NYQUIST_REACH || chord <= NYQUIST_STEP {
                continue;
            }
            let k = ((chord / NYQUIST_STEP).ceil() as usize).min(REFINE_MAX);
            let between: Vec<f64> = (1..k)
                .map(|j| fa * (fb / fa).powf(j as f64 / k as f64))
                .collect();
            refined.extend(between.iter().copied().zip(at(&between)?));
        }
        refined.extend(points.last().copied());
        points = refined;
    }
    Some(DesignLoop {
        hz: points.iter().map(|p| p.0).collect(),
        s: points.iter().map(|p| p.1.0).collect(),
        l: points.iter().map(|p| p.1.1).collect(),
    })
}

/// Where the design's loop gain is refined: within this |L| ...
const NYQUIST_REACH: f64 = 5.0;
/// ... until consecutive points lie at most this far apart (a few pixels
/// of the Nyquist plot), in at most this many passes of at most this many
/// points between two.
const NYQUIST_STEP: f64 = 0.05;
const REFINE_PASSES: usize = 2;
const REFINE_MAX: usize = 48;

/// The design's sensitivity and loop gain at the measured point, on a grid.
struct DesignLoop {
    hz: Vec<f64>,
    s: Vec<C64>,
    l: Vec<C64>,
}

fn loop_gain_name(point: InjectionPoint) -> &'static str {
    match point {
        InjectionPoint::PlantInput => "L_i",
        InjectionPoint::Sensor => "L_o",
        InjectionPoint::Reference => "L_r",
    }
}

/// The measured lines as markers: dots where the coherence is at least
/// [`MIN_COHERENCE`], grey rings below it.
fn add_measured(figure: &mut Figure, r: &MeasuredResponse, point: impl Fn(usize) -> (f64, f64)) {
    let (mut trusted, mut doubtful) = (Vec::new(), Vec::new());
    for (i, c) in r.measured.coherence.iter().enumerate() {
        if *c >= MIN_COHERENCE {
            trusted.push(point(i));
        } else {
            doubtful.push(point(i));
        }
    }
    figure.scatter(
        &format!("measured (coherence ≥ {MIN_COHERENCE})"),
        trusted,
        MEASURED,
        Marker::Dot,
    );
    if !doubtful.is_empty() {
        figure.scatter(
            &format!("coherence < {MIN_COHERENCE} (untrusted)"),
            doubtful,
            DOUBTFUL,
            Marker::Ring,
        );
    }
}

fn block(title: &str, file: &str, svg: String, caption: String) -> Block {
    Block::Figure(FigureBlock {
        title: title.to_string(),
        file: file.to_string(),
        svg,
        caption,
    })
}

fn plant_figure(m: &LoopMeasurement, design: &LoopDesign, suffix: &str) -> Block {
    let p = m.response("P").expect("every measurement has the plant");
    let lines = &p.measured.frequencies_hz;
    let unit = format!("{}/{}", design.output_unit, design.input_unit);
    let grid = Grid::through(lines);
    let model = grid
        .as_ref()
        .filter(|_| p.predicted.is_some())
        .and_then(|grid| {
            plant_curve(design, m, grid).map(|points| (points, grid.at_lines.clone()))
        });
    let frequency = || Axis::log10("frequency [Hz]");
    let mut magnitude = Figure::new(
        &format!("measured-plant-magnitude{suffix}"),
        "Magnitude",
        frequency(),
        Axis::linear(&format!("|P| [dB re 1 {unit}]")),
    );
    let mut phase = Figure::new(
        &format!("measured-plant-phase{suffix}"),
        "Phase",
        frequency(),
        Axis::linear("∠P [°]"),
    );
    let measured: Vec<(f64, f64)> = p
        .measured
        .response
        .iter()
        .map(|h| polar(h.re, h.im))
        .collect();
    // Each measured angle on the model's branch at its line, else unwrapped
    // along the lines.
    let measured_degrees: Vec<f64> = match &model {
        Some((points, at_lines)) => measured
            .iter()
            .zip(at_lines)
            .map(|((_, d), i)| on_branch(*d, points[*i].2))
            .collect(),
        None => unwrap(measured.iter().map(|(_, d)| *d)),
    };
    if let Some((points, _)) = &model {
        magnitude.colored_line(
            "design (plant model)",
            points.iter().map(|(f, db, _)| (*f, *db)).collect(),
            MODEL,
        );
        phase.colored_line(
            "design (plant model)",
            points.iter().map(|(f, _, d)| (*f, *d)).collect(),
            MODEL,
        );
    }
    add_measured(&mut magnitude, p, |i| (lines[i], measured[i].0));
    add_measured(&mut phase, p, |i| (lines[i], measured_degrees[i]));
    for f in [&mut magnitude, &mut phase] {
        f.empty_note = "no line of the measurement could be drawn".into();
    }
    let title = "Bode plot of the measured plant P against the design";
    let svg = Stack::new(
        &format!("measured-plant{suffix}"),
        title,
        vec![magnitude, phase],
    )
    .to_svg();
    let caption = format!(
        "P, {}, measured at the {} excited lines (dots; grey rings: coherence below \
         {MIN_COHERENCE}, not trusted) against {}. The phase is unwrapped along the model, and \
         each measured phase drawn on the model's branch at its line.",
        p.meaning,
        lines.len(),
        if model.is_some() {
            "the design's plant model (line: its exact discrete response, the zero-order hold \
             included, through the lines and between them)"
        } else {
            "no model: the design predicts no plant response here"
        }
    );
    block(title, &format!("measured-plant{suffix}.svg"), svg, caption)
}

/// Words for the design's line in a figure of S or L.
fn design_words(r: &MeasuredResponse, dense: bool) -> &'static str {
    match (r.predicted.is_some(), dense) {
        (false, _) => ", with no prediction (the loop is not analysed)",
        (true, true) => {
            ", against the design's (line: its closed loop's exact discrete response, through the \
             lines and between them)"
        }
        (true, false) => ", against the design's at the same lines (the line joins them)",
    }
}

fn sensitivity_figure(m: &LoopMeasurement, design: Option<&DesignLoop>, suffix: &str) -> Block {
    let s = m.sensitivity();
    let lines = &s.measured.frequencies_hz;
    let title = format!(
        "Measured sensitivity |{}| against the design and the 6 dB rule",
        s.name
    );
    let mut figure = Figure::new(
        &format!("measured-sensitivity{suffix}"),
        &title,
        Axis::log10("frequency [Hz]"),
        Axis::linear(&format!("|{}| [dB]", s.name)),
    );
    let db = |h: C64| polar(h.re, h.im).0;
    match (design, &s.predicted) {
        (Some(d), _) => {
            figure.colored_line(
                "design",
                d.hz.iter().zip(&d.s).map(|(f, h)| (*f, db(*h))).collect(),
                MODEL,
            );
        }
        (None, Some(predicted)) => {
            figure.colored_line(
                "design (at the lines)",
                lines
                    .iter()
                    .zip(predicted)
                    .map(|(f, h)| (*f, polar(h.re, h.im).0))
                    .collect(),
                MODEL,
            );
        }
        (None, None) => {}
    }
    add_measured(&mut figure, s, |i| {
        let h = s.measured.response[i];
        (lines[i], polar(h.re, h.im).0)
    });
    figure.hline(
        PEAK_LIMIT_DB,
        &format!("6 dB rule: |S| ≤ {PEAK_LIMIT_DB} dB"),
        RED,
    );
    figure.empty_note = "no line of the measurement could be drawn".into();
    let caption = format!(
        "|{}|, {}, measured at the excited lines (dots; grey rings: coherence below \
         {MIN_COHERENCE}, not trusted){}; the dashed line is the 6 dB rule, under which its peak \
         must stay. {}",
        s.name,
        s.meaning,
        design_words(s, design.is_some()),
        rule_words(m)
    );
    block(
        &title,
        &format!("measured-sensitivity{suffix}.svg"),
        figure.to_svg(),
        caption,
    )
}

fn loop_gain_figure(m: &LoopMeasurement, design: Option<&DesignLoop>, suffix: &str) -> Block {
    let name = loop_gain_name(m.point);
    let l = m
        .response(name)
        .expect("every measurement has its loop gain");
    let title = format!("Nyquist plot of the measured loop gain {name}");
    let mut figure = Figure::new(
        &format!("measured-loop-gain{suffix}"),
        &title,
        Axis::linear(&format!("Re {name}")).with_range(-3.0, 1.0),
        Axis::linear(&format!("Im {name}")).with_range(-2.0, 2.0),
    )
    .with_equal_aspect(420.0);
    match (design, &l.predicted) {
        (Some(d), _) => {
            figure.colored_line("design", d.l.iter().map(|h| (h.re, h.im)).collect(), MODEL);
        }
        (None, Some(predicted)) => {
            figure.colored_line(
                "design (at the lines)",
                predicted.iter().map(|h| (h.re, h.im)).collect(),
                MODEL,
            );
        }
        (None, None) => {}
    }
    add_measured(&mut figure, l, |i| {
        let h = l.measured.response[i];
        (h.re, h.im)
    });
    // |S| = 1/|1 + L| is the rule's limit on this circle.
    let radius = 10f64.powf(-PEAK_LIMIT_DB / 20.0);
    let circle = (0..=180)
        .map(|i| {
            let a = i as f64 / 180.0 * 2.0 * PI;
            (-1.0 + radius * a.cos(), radius * a.sin())
        })
        .collect();
    figure.colored_line(
        &format!("|1 + L| = {radius:.2}: |S| = {PEAK_LIMIT_DB} dB"),
        circle,
        RED,
    );
    if let Some(c) = figure.series.last_mut() {
        c.dashed = true;
    }
    figure.scatter(
        "−1, the critical point",
        vec![(-1.0, 0.0)],
        RED,
        Marker::Cross,
    );
    let ((x0, x1), (y0, y1)) = figure.shown_ranges();
    let outside = l
        .measured
        .response
        .iter()
        .filter(|h| !((x0..=x1).contains(&h.re) && (y0..=y1).contains(&h.im)))
        .count();
    let caption = format!(
        "{name}, {}, measured at the excited lines (dots; grey rings: coherence below \
         {MIN_COHERENCE}, not trusted){}, positive frequencies only; the cross is −1. On the \
         dashed circle around −1, of radius {radius:.2}, |S| = 1/|1 + L| is {PEAK_LIMIT_DB} dB: \
         a loop that keeps the 6 dB rule stays outside it. The frame shows the region around −1, \
         with one unit as long on both axes{}.",
        l.meaning,
        design_words(l, design.is_some()),
        if outside > 0 {
            format!(
                "; {outside} of the {} measured lines lie beyond it (where |L| is large)",
                l.measured.response.len()
            )
        } else {
            String::new()
        }
    );
    block(
        &title,
        &format!("measured-loop-gain{suffix}.svg"),
        figure.to_svg(),
        caption,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_unwrap_and_meet_a_branch() {
        let d = unwrap([170.0, -175.0, -160.0, 175.0]);
        assert_eq!(d, vec![-190.0, -175.0, -160.0, -185.0]);
        assert_eq!(on_branch(170.0, -180.0), -190.0);
        assert_eq!(on_branch(-10.0, 350.0), 350.0);
        assert_eq!(hz(1000.0000000002), "1000");
        assert_eq!(hz(0.1), "0.1");
    }
}
