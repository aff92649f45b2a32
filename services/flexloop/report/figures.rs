//! The report's figures, each built from the run's data in display units
//! (µs, nm or µrad, N or A) with its caption.

use super::{Event, RunData};
use flexloop_analysis::flexible::FlexibleComparison;
use flexloop_analysis::latency_log::percentile_distribution;
use flexloop_plot::{Axis, Figure};
use flexloop_runtime::latency::Metric;

const RED: &str = "#d62728";
const BLACK: &str = "#222222";
const GREEN: &str = "#2ca02c";
const PURPLE: &str = "#9467bd";
const ORANGE: &str = "#ff7f0e";
const BROWN: &str = "#8c564b";
const BLUE: &str = "#1f77b4";
const CYAN: &str = "#17becf";

/// A figure, its file name beside the Markdown and its caption.
pub struct Plot {
    pub figure: Figure,
    pub file: &'static str,
    pub caption: String,
}

/// Floor of a logarithmic latency axis; smaller values sit on it.
const LOG_FLOOR_US: f64 = 0.1;
const LOG_NOTE: &str = " The y axis is logarithmic because the maximum is far above the 99th \
     percentile; values below 0.1 µs are drawn on its floor.";

/// The hops of one sample through the processes.
const HOPS: [Metric; 7] = [
    Metric::TickLateness,
    Metric::PlantPublish,
    Metric::PlantToObserver,
    Metric::ObserverCompute,
    Metric::PlantToController,
    Metric::ObserverToController,
    Metric::ControllerCompute,
];

/// The end-to-end latencies the one-sample budget applies to (or bounds).
const END_TO_END: [Metric; 3] = [
    Metric::RoundTrip,
    Metric::TickToCommand,
    Metric::ObserverDone,
];

pub fn latency_hops(data: &RunData) -> Plot {
    latency(
        data,
        "latency-hops",
        "Latency per hop: percentile distribution",
        &HOPS,
        false,
    )
}

pub fn latency_end_to_end(data: &RunData) -> Plot {
    latency(
        data,
        "latency-end-to-end",
        "Round trip and the one-sample budget: percentile distribution",
        &END_TO_END,
        true,
    )
}

fn latency(
    data: &RunData,
    id: &'static str,
    title: &str,
    metrics: &[Metric],
    budget: bool,
) -> Plot {
    let budget_us = data.period_ns as f64 / 1e3;
    let series: Vec<(&str, Vec<(f64, f64)>)> = metrics
        .iter()
        .filter_map(|m| {
            let h = data.latency.histograms.get(m.name())?;
            let points = percentile_distribution(h, 12)
                .into_iter()
                .map(|(q, ns)| (q, ns as f64 / 1e3))
                .collect();
            Some((m.name(), points))
        })
        .collect();
    // A stall puts the maximum far above the rest: then a log y axis keeps
    // the body of the distribution readable.
    let p99 = metrics
        .iter()
        .filter_map(|m| data.latency.histograms.get(m.name()))
        .map(|h| h.value_at_quantile(0.99) as f64 / 1e3)
        .fold(0.0, f64::max);
    let top = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|(_, v)| *v))
        .chain(budget.then_some(budget_us))
        .fold(0.0, f64::max);
    let log_y = top > 20.0 * p99.max(1e-3);
    let y = if log_y {
        // From 0.1 µs: below it lie only saturated zeros (tick lateness in
        // lockstep), which would stretch the axis over decades of nothing.
        Axis::log10("latency [µs] (log)").with_range(LOG_FLOOR_US, 10f64.powf(top.log10().ceil()))
    } else {
        Axis::linear("latency [µs]")
    };
    let mut figure = Figure::new(id, title, Axis::percentile("percentile"), y);
    for (name, mut points) in series {
        if log_y {
            points.iter_mut().for_each(|p| p.1 = p.1.max(LOG_FLOOR_US));
        }
        figure.line(name, points);
    }
    if budget {
        figure.hline(
            budget_us,
            &format!("one-sample budget ({budget_us:.0} µs)"),
            RED,
        );
        deadline_line(&mut figure, data);
    }
    figure.empty_note = "no histograms in the latency log".into();
    let file = if budget {
        "latency-end-to-end.svg"
    } else {
        "latency-hops.svg"
    };
    let caption = if budget {
        format!(
            "Percentile distribution of the end-to-end latencies over the whole run, from `latency.hlog` \
             (all intervals merged). x: percentile on HdrHistogram's axis, one decade per added nine; \
             the line ends at the maximum. `tick_to_command` must stay below the dashed one-sample \
             budget ({budget_us:.0} µs) for u(k) to be applied at tick k+1; `round_trip` starts at \
             y(k)'s publication, `observer_done` is when the estimate for k+1 is out.{}",
            if log_y { LOG_NOTE } else { "" }
        )
    } else {
        format!(
            "Percentile distribution of each hop of a sample (see docs/benchmarks.md, \"Reading the bench table\"), \
             from `latency.hlog`. x: percentile (50 %, 90 %, 99 %, ... one decade per nine); y: µs.{}",
            if log_y { LOG_NOTE } else { "" }
        )
    };
    Plot {
        figure,
        file,
        caption,
    }
}

/// (time, value) per item, with a NaN wherever ticks are missing between
/// two items, so that a line breaks at a gap in the log instead of bridging it.
fn per_tick<T>(
    items: &[T],
    seq: impl Fn(&T) -> u64,
    ts: f64,
    value: impl Fn(&T) -> f64,
) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(items.len());
    let mut previous: Option<u64> = None;
    for item in items {
        let k = seq(item);
        if previous.is_some_and(|p| k > p + 1) {
            out.push(((k - 1) as f64 * ts, f64::NAN));
        }
        out.push((k as f64 * ts, value(item)));
        previous = Some(k);
    }
    out
}

fn add_events(figure: &mut Figure, events: &[Event]) {
    for e in events {
        let color = match e.kind.as_str() {
            "crash" | "restart-failed" => RED,
            "restart" => ORANGE,
            _ => "#555555",
        };
        figure.vline(e.time_s, &format!("{} {}", e.kind, e.role), color);
    }
}

pub fn tick_timing(data: &RunData) -> Plot {
    let trace = &data.run.trace;
    let t = |seq: u64| seq as f64 * trace.ts;
    let timing = &trace.timing;
    let mut figure = Figure::new(
        "tick-timing",
        "Tick timing over the run",
        Axis::linear("time [s]"),
        Axis::linear("after the scheduled tick [µs]"),
    );
    figure.line(
        "tick lateness (plant awake)",
        per_tick(timing, |k| k.seq, trace.ts, |k| k.lateness_ns as f64 / 1e3),
    );
    figure.line(
        "u(k) published (tick_to_command)",
        per_tick(
            timing,
            |k| k.seq,
            trace.ts,
            |k| k.command_ns.map_or(f64::NAN, |ns| ns as f64 / 1e3),
        ),
    );
    let budget_us = data.period_ns as f64 / 1e3;
    figure.hline(
        budget_us,
        &format!("one-sample budget ({budget_us:.0} µs)"),
        RED,
    );
    deadline_line(&mut figure, data);
    let marks = |pick: fn(&flexloop_analysis::trace::TickTiming) -> bool| -> Vec<f64> {
        timing
            .iter()
            .filter(|k| pick(k))
            .map(|k| t(k.seq))
            .collect()
    };
    let held = marks(|k| k.held && !k.fallback);
    let stalled = marks(|k| k.stalled);
    let fallback = marks(|k| k.fallback);
    let observer_fallback = marks(|k| k.observer_fallback);
    figure
        .marks(&format!("miss: input held ({})", held.len()), held, RED)
        .marks(
            &format!("stalled tick ({})", stalled.len()),
            stalled,
            PURPLE,
        )
        .marks(
            &format!("safe action ({})", fallback.len()),
            fallback,
            BROWN,
        )
        .marks(
            &format!("no observer ({})", observer_fallback.len()),
            observer_fallback,
            CYAN,
        );
    add_events(&mut figure, &data.events);
    figure.empty_note = "no measurements in the sample log".into();
    Plot {
        figure,
        file: "tick-timing.svg",
        caption: format!(
            "Per tick, from the sample log's time stamps: when the plant woke (tick lateness) and when \
             u(k) was published, both after the scheduled tick; the dashed line is the one-sample \
             budget. Ticks above the frame: the plant held its input because u(k−1) was missing \
             (a miss), woke too late itself (a stall, the machine's fault), applied its safe action, \
             or the controller ran without the observer; rows appear only when such ticks happened. \
             Dashed verticals: swaps, crashes and restarts from `events.jsonl`.{}",
            if data.lockstep {
                " In lockstep the plant waits for every command, so lateness measures the loop's pace, not a deadline."
            } else {
                ""
            }
        ),
    }
}

pub fn tracking_error(data: &RunData, zoom: bool) -> Plot {
    let trace = &data.run.trace;
    let scans = &data.run.metrics.scans;
    let window = scans.first().map(|s| (s.start_s, s.end_s));
    let (id, title, file) = if zoom {
        (
            "tracking-error-scan",
            "Tracking error e_true over the first scan window",
            "tracking-error-scan.svg",
        )
    } else {
        (
            "tracking-error",
            "Tracking error e_true = r − y over the run",
            "tracking-error.svg",
        )
    };
    let mut x = Axis::linear("time [s]");
    let mut points = per_tick(
        &trace.rows,
        |r| r.seq,
        trace.ts,
        |r| data.length.of(r.e_true()),
    );
    if zoom {
        match window {
            Some((a, b)) => {
                x = x.with_range(a, b);
                points.retain(|(t, _)| *t >= a && *t <= b);
            }
            None => points.clear(),
        }
    }
    let mut figure = Figure::new(
        id,
        title,
        x,
        Axis::linear(&format!("e_true [{}]", data.length.unit)),
    );
    figure.colored_line("e_true = r − y_true", points, BLACK);
    if !zoom {
        for (i, s) in scans.iter().enumerate() {
            let label = if i == 0 { "scan window" } else { "" };
            figure.span(s.start_s, s.end_s, label, GREEN);
        }
        add_events(&mut figure, &data.events);
    }
    figure.empty_note = if zoom && window.is_none() {
        "no scan window: the reference is not a scan".into()
    } else {
        "no complete ticks in the sample log".into()
    };
    let caption = if zoom {
        "The same error over the first scan window only (the frame is the window), where the \
         report's rms, MA and MSD are taken: the scale is set by what the scan sees, not by the \
         acceleration phases."
            .to_string()
    } else {
        "e_true(k) = r(k) − y_true(k), the error the machine makes (noise-free output), over the run; \
         shaded: the scan window(s) the scenario's reference defines. The large excursions outside \
         them are the acceleration and deceleration of the set-point."
            .to_string()
    };
    Plot {
        figure,
        file,
        caption,
    }
}

pub fn command(data: &RunData, small_parts: bool) -> Plot {
    let trace = &data.run.trace;
    let series = |f: fn(&flexloop_analysis::trace::TickRow) -> f64| -> Vec<(f64, f64)> {
        per_tick(&trace.rows, |r| r.seq, trace.ts, f)
    };
    let (id, title, file) = if small_parts {
        (
            "command-feedback-damping",
            "Feedback and damping parts of the command",
            "command-feedback-damping.svg",
        )
    } else {
        ("command", "Command u and its parts", "command.svg")
    };
    let mut figure = Figure::new(
        id,
        title,
        Axis::linear("time [s]"),
        Axis::linear(&format!(
            "{} [{}]",
            if data.run.design.input_unit == "N" {
                "force"
            } else {
                "input"
            },
            data.run.design.input_unit
        )),
    );
    if !small_parts {
        figure.colored_line("u_ff (feedforward)", series(|r| r.u_ff), ORANGE);
    }
    figure
        .colored_line("u_fb (feedback)", series(|r| r.u_fb), GREEN)
        .colored_line("u_d (active damping)", series(|r| r.u_d), PURPLE);
    if !small_parts {
        // Last and dashed: u is mostly u_ff, which shows between the dashes.
        figure.colored_line("u (the sum, after limits)", series(|r| r.u), BLACK);
        if let Some(u) = figure.series.last_mut() {
            u.dashed = true;
        }
    }
    figure.empty_note = "no complete ticks in the sample log".into();
    let caption = if small_parts {
        "The feedback and active-damping parts alone, on their own scale (the feedforward dwarfs \
         them): u_fb answers the measured error, u_d = K x̂ damps the flexible modes (zero without AD)."
            .to_string()
    } else {
        "The command u(k) the controller published and its parts, as the controller logged them: \
         feedback u_fb (PID on e_meas), feedforward u_ff (from the set-point's derivatives) and active \
         damping u_d (from the observer). u (dashed) is their sum after the actuator limits."
            .to_string()
    };
    Plot {
        figure,
        file,
        caption,
    }
}

pub fn flexible(data: &RunData) -> Plot {
    let mut figure = Figure::new(
        "flexible-output",
        "Flexible output at the sensor: estimated against true",
        Axis::linear("time [s]"),
        Axis::linear(&format!("flexible output [{}]", data.length.unit)),
    );
    let caption = match &data.flexible {
        Ok(c) => {
            let line = |v: &[f64]| -> Vec<(f64, f64)> {
                c.time_s
                    .iter()
                    .zip(v)
                    .map(|(t, y)| (*t, data.length.of(*y)))
                    .collect()
            };
            figure
                .colored_line("true, all flexible modes", line(&c.true_flexible), BLACK)
                .colored_line(
                    &format!("true, modes 1–{} (observed)", c.modelled_modes),
                    line(&c.true_modelled),
                    GREEN,
                )
                .colored_line("predicted C_f x̂(k|k−1)", line(&c.predicted), BLUE);
            if let Some(comp) = &c.compensation {
                figure.colored_line("ŷ_flex(k) subtracted by MC", line(comp), RED);
            }
            for s in figure.series.iter_mut().skip(2) {
                s.dashed = true;
            }
            flexible_caption(c, data.length)
        }
        Err(reason) => {
            figure.empty_note = format!("no comparison: {reason}");
            format!("No flexible comparison for this run: {reason}.")
        }
    };
    Plot {
        figure,
        file: "flexible-output.svg",
        caption,
    }
}

pub fn flexible_error(data: &RunData) -> Plot {
    let mut figure = Figure::new(
        "flexible-error",
        "Estimation error of the flexible output",
        Axis::linear("time [s]"),
        Axis::linear(&format!("error [{}]", data.length.unit)),
    );
    let caption = match &data.flexible {
        Ok(c) => {
            let difference = |a: &[f64], b: &[f64]| -> Vec<(f64, f64)> {
                c.time_s
                    .iter()
                    .zip(a.iter().zip(b))
                    .map(|(t, (a, b))| (*t, data.length.of(a - b)))
                    .collect()
            };
            let modes = c.modelled_modes;
            figure.colored_line(
                &format!("C_f x̂(k|k−1) − true 1–{modes}"),
                difference(&c.predicted, &c.true_modelled),
                BLUE,
            );
            if let Some(comp) = &c.compensation {
                figure.colored_line(
                    &format!("ŷ_flex(k) − true 1–{modes}"),
                    difference(comp, &c.true_modelled),
                    RED,
                );
            }
            let own = FlexibleComparison::rms_difference(&c.predicted, &c.true_modelled);
            let left_out = FlexibleComparison::rms_difference(&c.true_flexible, &c.true_modelled);
            format!(
                "The observer's errors against the modes it models (1–{modes}) on their own scale: \
                 its estimation error proper ({:.3} {unit} rms for the prediction). Not drawn: the \
                 motion of the flexible modes its reduced model leaves out ({:.3} {unit} rms), by which \
                 even a perfect estimate differs from y − rigid motion.",
                data.length.of(own),
                data.length.of(left_out),
                unit = data.length.unit
            )
        }
        Err(reason) => {
            figure.empty_note = format!("no comparison: {reason}");
            format!("No flexible comparison for this run: {reason}.")
        }
    };
    Plot {
        figure,
        file: "flexible-error.svg",
        caption,
    }
}

fn flexible_caption(c: &FlexibleComparison, length: super::Length) -> String {
    format!(
        "What is compared (docs/control.md §5.1): ŷ_flex = C_f x̂ is the output of the flexible modes the \
         observer models (rigid columns zero, no T_DC·u). Its true counterpart, the plant's own \
         flexible motion at the sensor (y − rigid motion), is not in the log: it is rebuilt offline \
         by running the plant model (all modes, the same modal coordinates as the observer's reduced \
         model) from rest on the logged applied input u_a(k); the rebuild matches the logged y_true \
         to {:.3} {} rms{}. Black: all flexible modes; green: the modes the observer models \
         (1–{}); blue dashed: the observer's prediction C_f x̂(k|k−1) from the estimate message; \
         red dashed (with MC): the ŷ_flex(k) the controller subtracted, y + e_meas − r from the \
         command message, which also holds y(k)'s feedthrough.{}",
        // A thousandth of the report's unit: pm, or nrad.
        length.of(c.residual_rms) * 1e3,
        if length.unit == "nm" { "pm" } else { "nrad" },
        if c.residual_rms > 1e-12 {
            " (not exact: the run's force noise is not logged)"
        } else {
            ""
        },
        c.modelled_modes,
        if c.ticks_left_out > 0 {
            format!(
                " The log has a gap: the last {} ticks are left out.",
                c.ticks_left_out
            )
        } else {
            String::new()
        }
    )
}

/// With a command deadline τ_d, the line u(k) must stay below to act at
/// t_k + τ_d (docs/deadline.md); a command above it was a deadline miss.
fn deadline_line(figure: &mut Figure, data: &RunData) {
    if let Some(tau) = data.run.design.command_deadline_s {
        let us = tau * 1e6;
        figure.hline(us, &format!("command deadline τ_d ({us:.0} µs)"), ORANGE);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gap_in_the_ticks_breaks_the_line() {
        let seqs = [0u64, 1, 2, 5, 6];
        let points = per_tick(&seqs, |k| *k, 0.5, |k| *k as f64);
        assert_eq!(points.len(), 6);
        assert_eq!(points[2], (1.0, 2.0));
        assert_eq!(points[3].0, 2.0);
        assert!(points[3].1.is_nan(), "a break before tick 5");
        assert_eq!(points[4], (2.5, 5.0));
    }
}
