//! What the report says: its text, tables and the place of each figure.
//! Every number comes from the run's own files through the library
//! functions `flexloop run` and `flexloop bench` use (summary.json for the
//! timing, the sample log's metrics for the control), never recomputed here.

use super::RunData;
use super::document::{Block, Document, FigureBlock, Table};
use super::figures::{self, Plot};
use flexloop_analysis::flexible::FlexibleComparison;
use flexloop_runfiles::{RunDir, RunSummary};
use flexloop_runtime::latency::{Metric, QUANTILE_LABELS};

pub fn document(data: &RunData) -> Document {
    let run = &data.run;
    let s = &run.summary;
    let mut doc = Document::new(format!("flexloop run report: {}", run.scenario.name));
    let description = if run.scenario.description.is_empty() {
        String::new()
    } else {
        format!("{}. ", run.scenario.description)
    };
    doc.push(Block::Paragraph(format!(
        "{description}Run directory `{}`: {} mode at {} Hz for {} s, {} ticks logged, one-sample \
         budget {:.0} µs. Sources: `summary.json` (timing tables), `latency.hlog` (latency \
         distributions), `{}` (traces and control metrics), `events.jsonl` (events), \
         `scenario.toml` (the scenario as it ran).",
        data.dir.display(),
        s.mode,
        s.rate_hz,
        s.duration_s,
        s.ticks,
        data.period_ns as f64 / 1e3,
        RunDir::SAMPLES,
    )));
    doc.push(Block::Heading("Timing".into()));
    doc.push(Block::Paragraph(verdict(s, data.lockstep)));
    doc.push(Block::Subheading("Latency [µs]".into()));
    doc.push(Block::Paragraph(
        "From `summary.json`: the logger's histograms over the whole run, the numbers \
         `flexloop bench` prints; \"over one period\" counts samples above the one-sample budget. \
         docs/benchmarks.md, \"Reading the bench table\", says what each row measures."
            .into(),
    ));
    doc.push(Block::Table(latency_table(s)));
    doc.push(Block::Paragraph(hlog_check(data)));
    doc.push(Block::Subheading("Counters".into()));
    doc.push(Block::Table(counters_table(data)));
    doc.push(figure(figures::latency_hops(data)));
    doc.push(figure(figures::latency_end_to_end(data)));
    doc.push(figure(figures::tick_timing(data)));

    doc.push(Block::Heading("Control".into()));
    doc.push(Block::Paragraph(format!(
        "From the sample log, {} complete ticks (output {}), as `flexloop run` computes them: \
         e_true = r − y_true (noise-free output); MA and MSD over an exposure time of {} ms \
         (docs/control.md §8).{}",
        run.metrics.ticks,
        match run.design.output_names.as_slice() {
            [one] => one.clone(),
            names => format!(
                "{}, the first of {}; `flexloop run` and metrics.json give every axis",
                names.first().map_or("?", String::as_str),
                names.len()
            ),
        },
        flexloop_analysis::MetricsOptions::default().exposure_s * 1e3,
        if run.trace.incomplete_ticks > 0 {
            format!(
                " {} ticks lack a command or an estimate in the log and are left out.",
                run.trace.incomplete_ticks
            )
        } else {
            String::new()
        }
    )));
    doc.push(Block::Table(control_table(data)));
    if !run.metrics.scans.is_empty() {
        doc.push(Block::Subheading("Scan windows".into()));
        doc.push(Block::Table(scans_table(data)));
    }
    if !run.damping.is_empty() {
        doc.push(Block::Subheading("Modal damping".into()));
        doc.push(Block::Table(damping_table(data)));
    }
    doc.push(figure(figures::tracking_error(data, false)));
    doc.push(figure(figures::tracking_error(data, true)));
    doc.push(figure(figures::command(data, false)));
    doc.push(figure(figures::command(data, true)));
    doc.push(Block::Subheading(
        "Estimated against true flexible output".into(),
    ));
    if let Ok(c) = &data.flexible {
        doc.push(Block::Table(flexible_table(c, data.length)));
    }
    doc.push(figure(figures::flexible(data)));
    doc.push(figure(figures::flexible_error(data)));
    for block in super::measured::section(data) {
        doc.push(block);
    }

    doc.push(Block::Heading("Events".into()));
    if data.events.is_empty() {
        doc.push(Block::Paragraph(
            "No swaps, crashes or restarts (`events.jsonl` is absent or empty).".into(),
        ));
    } else {
        doc.push(Block::Table(events_table(data)));
    }
    if !data.joined_files.is_empty() || !data.run.outages.is_empty() {
        doc.push(Block::Paragraph(format!(
            "The logger was restarted during the run: this report joins the sample files {} and \
             their latency logs in that order; {}.",
            data.joined_files
                .iter()
                .map(|f| format!("`{f}`"))
                .collect::<Vec<_>>()
                .join(", "),
            flexloop_analysis::run_log::describe_outages(&data.run.outages)
        )));
    }
    doc
}

/// rms values of the flexible comparison, in the report's unit of length.
fn flexible_table(c: &FlexibleComparison, length: super::Length) -> Table {
    let nm = |v: f64| number(length.of(v));
    let modes = c.modelled_modes;
    let mut rows = vec![
        vec![
            "true flexible output, all modes".to_string(),
            nm(FlexibleComparison::rms(&c.true_flexible)),
        ],
        vec![
            format!("true flexible output, modes 1–{modes}"),
            nm(FlexibleComparison::rms(&c.true_modelled)),
        ],
    ];
    let mut error = |name: &str, estimate: &[f64]| {
        rows.push(vec![
            format!("{name} − true 1–{modes}"),
            nm(FlexibleComparison::rms_difference(
                estimate,
                &c.true_modelled,
            )),
        ]);
        rows.push(vec![
            format!("{name} − true, all modes"),
            nm(FlexibleComparison::rms_difference(
                estimate,
                &c.true_flexible,
            )),
        ]);
    };
    error("C_f x̂(k|k−1)", &c.predicted);
    if let Some(comp) = &c.compensation {
        error("ŷ_flex(k) subtracted by MC", comp);
    }
    rows.push(vec![
        "residual of the rebuilt y_true".into(),
        nm(c.residual_rms),
    ]);
    Table {
        header: vec![
            format!("rms over {} ticks", c.time_s.len()),
            length.unit.into(),
        ],
        rows,
        numeric_from: 1,
    }
}

fn figure(plot: Plot) -> Block {
    Block::Figure(FigureBlock {
        title: plot.figure.title.clone(),
        file: plot.file.to_string(),
        svg: plot.figure.to_svg(),
        caption: plot.caption,
    })
}

/// Three decimals, or three significant decimals of a power of ten once a
/// value is too large to read that way (a run that diverged).
fn number(v: f64) -> String {
    if v.is_finite() && v.abs() >= 1e6 {
        format!("{v:.3e}")
    } else {
        format!("{v:.3}")
    }
}

fn verdict(s: &RunSummary, lockstep: bool) -> String {
    let c = &s.counters;
    let ticks = s.ticks;
    let misses = c.misses;
    let stall_misses = c.stall_misses;
    let over = s
        .latency(Metric::TickToCommand.name())
        .over_one_period
        .unwrap_or(0);
    format!(
        "u(k) was available before tick k+1 in {} of {} ticks: {} loop misses, {} misses after \
         machine stalls ({} stalled ticks); {} commands were published later than one period \
         after their tick.{}",
        ticks.saturating_sub(misses + stall_misses),
        ticks,
        misses,
        stall_misses,
        c.stalled_ticks,
        over,
        if lockstep {
            " In lockstep the plant waits for every command, so there is no deadline to miss: \
             the latencies show how fast the processes went on this machine, and the budget \
             line is for comparison with a realtime run."
        } else {
            ""
        }
    )
}

/// One row per histogram, in µs: the same values as the bench table.
pub fn latency_table(s: &RunSummary) -> Table {
    let mut header = vec!["histogram".to_string(), "count".to_string()];
    header.extend(QUANTILE_LABELS.iter().map(|l| l.to_string()));
    header.push("over one period".into());
    let rows = Metric::ALL
        .iter()
        .map(|m| {
            let h = s.latency(m.name());
            let mut row = vec![m.name().to_string(), h.count.to_string()];
            row.extend(
                h.percentiles
                    .values()
                    .iter()
                    .map(|ns| format!("{:.1}", *ns as f64 / 1e3)),
            );
            row.push(h.over_one_period.unwrap_or(0).to_string());
            row
        })
        .collect();
    Table {
        header,
        rows,
        numeric_from: 1,
    }
}

/// Whether the interval log adds up to the summary's histograms.
fn hlog_check(data: &RunData) -> String {
    let differing: Vec<String> = Metric::ALL
        .iter()
        .filter_map(|m| {
            let logged = data.latency.histograms.get(m.name()).map_or(0, |h| h.len());
            let summary = data.run.summary.latency(m.name()).count;
            (logged != summary).then(|| format!("{} ({logged} against {summary})", m.name()))
        })
        .collect();
    format!(
        "`latency.hlog`: {} intervals{}; {}.",
        data.latency.intervals,
        if data.latency.torn_tail {
            ", the last line torn (its writer was stopped mid-line)"
        } else {
            ""
        },
        if differing.is_empty() {
            "merged, every histogram's count equals the summary's".to_string()
        } else {
            format!(
                "merged counts differ from the summary's for {}",
                differing.join(", ")
            )
        }
    )
}

fn counters_table(data: &RunData) -> Table {
    let s = &data.run.summary;
    let c = &s.counters;
    let rows: Vec<(&str, u64)> = vec![
        ("ticks", s.ticks),
        ("loop misses", c.misses),
        ("late commands (dropped)", c.late_commands),
        ("stalled ticks", c.stalled_ticks),
        ("misses after stalls", c.stall_misses),
        ("stale estimates", c.stale_estimates),
        ("ticks under the safe action", c.fallback_ticks),
        ("rejected commands", c.rejected_commands),
        ("log gaps: measurements", s.gaps.measurement),
        ("log gaps: estimates", s.gaps.estimate),
        ("log gaps: commands", s.gaps.command),
        (
            "ticks missing a command or estimate",
            data.run.trace.incomplete_ticks,
        ),
    ];
    Table {
        header: vec!["counter".into(), "value".into()],
        rows: rows
            .into_iter()
            .map(|(name, v)| vec![name.to_string(), v.to_string()])
            .collect(),
        numeric_from: 1,
    }
}

fn control_table(data: &RunData) -> Table {
    let m = &data.run.metrics;
    let length = data.length.unit;
    let input = data.run.design.input_unit;
    // A row: what, its value (already formatted), its unit.
    let row = |name: &str, value: String, unit: &str| [name.to_string(), value, unit.to_string()];
    let nm = |name: &str, v: f64| row(name, number(data.length.of(v)), length);
    let effort = |name: &str, v: f64| row(name, number(v), input);
    let mut rows: Vec<[String; 3]> = Vec::new();
    if let Some(rms) = m.rms_e_true_scan {
        let windows = if m.scans.len() > 1 { "s" } else { "" };
        rows.push(nm(
            &format!("rms e_true over the scan window{windows}"),
            rms,
        ));
        let largest = |f: fn(&flexloop_analysis::metrics::ScanMetrics) -> f64| {
            m.scans.iter().map(f).fold(0.0, f64::max)
        };
        rows.push(nm("largest |MA| in a scan", largest(|s| s.max_abs_ma)));
        rows.push(nm("largest MSD in a scan", largest(|s| s.max_msd)));
        rows.push(nm("peak |e_true| in a scan", largest(|s| s.peak_e_true)));
    } else {
        rows.push(row("rms e_true over the scan", "-".into(), "no scan"));
    }
    rows.extend([
        nm("peak |e_true| over the run", m.e_true.peak),
        nm("rms e_true over the run", m.e_true.rms),
        effort("effort: rms u", m.u.rms),
        effort("effort: peak |u|", m.u.peak),
        effort("rms u_fb (feedback)", m.u_fb.rms),
        effort("rms u_ff (feedforward)", m.u_ff.rms),
        effort("rms u_d (active damping)", m.u_d.rms),
        row("innovation mean", format!("{:.3e}", m.innovation.mean), "m"),
        row(
            "innovation standard deviation",
            format!("{:.3e}", m.innovation.std),
            "m",
        ),
        row(
            "innovation lag-1 autocorrelation",
            format!("{:.3}", m.innovation.lag1_autocorrelation),
            "",
        ),
        row("ticks with the input held", m.held_ticks.to_string(), ""),
        row(
            "commands from a stale estimate",
            m.stale_estimates.to_string(),
            "",
        ),
    ]);
    Table {
        header: vec!["quantity".into(), "value".into(), "unit".into()],
        rows: rows.into_iter().map(Vec::from).collect(),
        numeric_from: 1,
    }
}

fn scans_table(data: &RunData) -> Table {
    let nm = |v: f64| number(data.length.of(v));
    Table {
        header: [
            "scan", "from [s]", "to [s]", "samples", "rms", "peak", "max |MA|", "max MSD",
        ]
        .iter()
        .enumerate()
        .map(|(i, h)| {
            if i >= 4 {
                format!("{h} [{}]", data.length.unit)
            } else {
                h.to_string()
            }
        })
        .collect(),
        rows: data
            .run
            .metrics
            .scans
            .iter()
            .enumerate()
            .map(|(i, s)| {
                vec![
                    (i + 1).to_string(),
                    format!("{:.4}", s.start_s),
                    format!("{:.4}", s.end_s),
                    s.samples.to_string(),
                    nm(s.rms_e_true),
                    nm(s.peak_e_true),
                    nm(s.max_abs_ma),
                    nm(s.max_msd),
                ]
            })
            .collect(),
        numeric_from: 1,
    }
}

fn damping_table(data: &RunData) -> Table {
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |z| format!("{z:.4}"));
    Table {
        header: [
            "mode",
            "f [Hz]",
            "ζ open loop",
            "ζ closed loop (model)",
            "ζ identified from the run",
        ]
        .map(String::from)
        .to_vec(),
        rows: data
            .run
            .damping
            .iter()
            .enumerate()
            .map(|(i, d)| {
                vec![
                    (i + 1).to_string(),
                    format!("{:.1}", d.frequency_hz),
                    format!("{:.4}", d.open_loop),
                    opt(d.closed_loop_model),
                    opt(d.identified),
                ]
            })
            .collect(),
        numeric_from: 1,
    }
}

fn events_table(data: &RunData) -> Table {
    Table {
        header: ["t [s]", "tick", "event", "role", "generation", "detail"]
            .map(String::from)
            .to_vec(),
        rows: data
            .events
            .iter()
            .map(|e| {
                vec![
                    format!("{:.4}", e.time_s),
                    e.seq.map_or("-".into(), |s| s.to_string()),
                    e.kind.clone(),
                    e.role.clone(),
                    e.generation.to_string(),
                    e.detail.clone(),
                ]
            })
            .collect(),
        numeric_from: 6,
    }
}
