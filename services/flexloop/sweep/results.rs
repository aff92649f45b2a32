//! The sweep's tables, findings and figures.

use super::{BASE_RATE_HZ, MISS_GOAL, Measured, Point, Series, keeps_the_grid, miss_ratio};
use flexloop_plot::{Axis, Figure};
use flexloop_runfiles::bench::Floors;
use std::fmt::Write as _;

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

/// Least-squares slope of log y over log x: the exponent of y ∝ x^slope.
fn growth_exponent(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = (
        logs.iter().map(|p| p.0).sum::<f64>() / n,
        logs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// The tables and findings as Markdown (printed, and the head of sweep.md).
pub fn tables(results: &[(Point, Result<Measured, String>)], floors: Option<&Floors>) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "\n### Latency per point (µs; misses: u(k) not there by tick k+1, stalled ticks apart)\n"
    );
    let _ = writeln!(
        t,
        "| series | point | rate kHz | states | axes | ticks | misses | per 10⁴ | stalled | round trip p50 | p99 | p99.9 | p99.99 | max | tick→u p99.99 | budget |"
    );
    let _ = writeln!(
        t,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for (p, r) in results {
        match r {
            Ok(m) => {
                let _ = writeln!(
                    t,
                    "| {} | {} | {} | {} | {}×{} | {} | {} | {:.2} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} |",
                    p.series.name(),
                    p.what,
                    p.rate_hz / 1e3,
                    m.states,
                    m.outputs,
                    m.inputs,
                    m.ticks,
                    m.misses,
                    1e4 * miss_ratio(m),
                    m.stalled_ticks,
                    us(m.round_trip.p50),
                    us(m.round_trip.p99),
                    us(m.round_trip.p99_9),
                    us(m.round_trip.p99_99),
                    us(m.round_trip.max),
                    us(m.tick_to_command.p99_99),
                    1e6 / p.rate_hz
                );
            }
            Err(e) => {
                let _ = writeln!(
                    t,
                    "| {} | {} | {} | | | | | | | failed: {} | | | | | | |",
                    p.series.name(),
                    p.what,
                    p.rate_hz / 1e3,
                    e.lines().next().unwrap_or("").replace('|', "/")
                );
            }
        }
    }
    let _ = writeln!(
        t,
        "\n### Cost per point (compute: message received → published, µs; CPU: the scheduler's time per sample past start-up, µs, and share of one core)\n"
    );
    let _ = writeln!(
        t,
        "| point | observer compute p50 | p99 | controller compute p50 | p99 | CPU/sample plant | observer | controller | logger | CPU share plant | observer | controller | logger | loop CPU (plant+observer+controller) |"
    );
    let _ = writeln!(
        t,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for (p, r) in results {
        let Ok(m) = r else { continue };
        let _ = writeln!(
            t,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.0} % |",
            p.what,
            us(m.observer_compute.p50),
            us(m.observer_compute.p99),
            us(m.controller_compute.p50),
            us(m.controller_compute.p99),
            m.cpu_per_sample_ns.plant / 1e3,
            m.cpu_per_sample_ns.observer / 1e3,
            m.cpu_per_sample_ns.controller / 1e3,
            m.cpu_per_sample_ns.logger / 1e3,
            100.0 * m.cpu_share.plant,
            100.0 * m.cpu_share.observer,
            100.0 * m.cpu_share.controller,
            100.0 * m.cpu_share.logger,
            100.0 * m.cpu_share.loop_total()
        );
    }
    let _ = writeln!(t, "\n### Findings\n");
    let rate_points: Vec<(&Point, &Measured)> = results
        .iter()
        .filter(|(p, _)| p.series == Series::Rate)
        .filter_map(|(p, r)| Some((p, r.as_ref().ok()?)))
        .collect();
    // The highest rate that meets the goal with the plant on its grid; the
    // rates below it that did not are named (on a shared machine a stall
    // can cost one of them its point).
    let fits = |p: &Point, m: &Measured| miss_ratio(m) < MISS_GOAL && keeps_the_grid(m, p.rate_hz);
    let highest = rate_points
        .iter()
        .filter(|(p, m)| fits(p, m))
        .map(|(p, _)| p.rate_hz)
        .fold(None, |best: Option<f64>, r| {
            Some(best.map_or(r, |b| b.max(r)))
        });
    match highest {
        Some(r) => {
            let below: Vec<String> = rate_points
                .iter()
                .filter(|(p, m)| p.rate_hz < r && !fits(p, m))
                .map(|(p, m)| {
                    format!(
                        "{} kHz ({} misses in {} ticks)",
                        p.rate_hz / 1e3,
                        m.misses,
                        m.ticks
                    )
                })
                .collect();
            let _ = writeln!(
                t,
                "- Highest rate with loop misses under 1 in 10 000 and the plant on its grid: **{} kHz**{}.",
                r / 1e3,
                if below.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; below it, {} did not meet the goal in this run",
                        below.join(", ")
                    )
                }
            );
        }
        None if !rate_points.is_empty() => {
            let _ = writeln!(
                t,
                "- No rate of the sweep kept loop misses under 1 in 10 000."
            );
        }
        None => {}
    }
    for (p, m) in rate_points
        .iter()
        .filter(|(p, m)| !keeps_the_grid(m, p.rate_hz))
    {
        let _ = writeln!(
            t,
            "- At {} kHz the plant does not keep its tick grid: median wake-up {:.1} µs after the tick, more than half the {:.0} µs period (every such tick counts as stalled, its misses apart); plant, observer and controller together use {:.0} % of a CPU.",
            p.rate_hz / 1e3,
            us(m.tick_lateness.p50),
            1e6 / p.rate_hz,
            100.0 * m.cpu_share.loop_total()
        );
    }
    let size_points: Vec<(f64, &Measured)> = results
        .iter()
        .filter(|(p, _)| p.series == Series::States)
        .filter_map(|(_, r)| r.as_ref().ok())
        .map(|m| (m.states as f64, m))
        .collect();
    let exponent = |get: &dyn Fn(&Measured) -> f64| {
        growth_exponent(
            &size_points
                .iter()
                .map(|(n, m)| (*n, get(m)))
                .collect::<Vec<_>>(),
        )
    };
    if let Some(compute) = exponent(&|m| m.observer_compute.p50 as f64) {
        let mut sorted = size_points.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let top = &sorted[sorted.len().saturating_sub(2)..];
        let local = growth_exponent(
            &top.iter()
                .map(|(n, m)| (*n, m.observer_compute.p50 as f64))
                .collect::<Vec<_>>(),
        );
        let _ = writeln!(
            t,
            "- Observer cost against its states (log-log slope over the uniform chains): compute p50 ∝ n^{compute:.2}{}{}{}.",
            exponent(&|m| m.cpu_per_sample_ns.observer)
                .map(|c| format!(", its CPU per sample ∝ n^{c:.2}"))
                .unwrap_or_default(),
            exponent(&|m| m.controller_compute.p50 as f64)
                .map(|c| format!(", controller compute p50 ∝ n^{c:.2}"))
                .unwrap_or_default(),
            local
                .filter(|_| top.len() == 2 && sorted.len() > 2)
                .map(|c| format!(
                    "; between the two largest ({} and {} states) compute p50 grows as n^{c:.2}",
                    top[0].0, top[1].0
                ))
                .unwrap_or_default()
        );
        if let Some((_, m)) = size_points.iter().max_by(|a, b| a.0.total_cmp(&b.0)) {
            let _ = writeln!(
                t,
                "- At {} states: observer compute p50 {:.2} µs, CPU {:.2} µs per sample; controller compute p50 {:.2} µs.",
                m.states,
                us(m.observer_compute.p50),
                m.cpu_per_sample_ns.observer / 1e3,
                us(m.controller_compute.p50)
            );
        }
    }
    let base = [Series::Base, Series::Rate].iter().find_map(|series| {
        results.iter().find_map(|(p, r)| {
            (p.series == *series && p.rate_hz == BASE_RATE_HZ)
                .then_some(r.as_ref().ok())
                .flatten()
        })
    });
    if let Some(f) = floors {
        let _ = writeln!(
            t,
            "\n### Floors at 10 kHz (µs, measured after the runs)\n\n| probe | p50 | p99 | p99.99 | max |\n|---|---|---|---|---|"
        );
        for (label, h) in f.rows() {
            let v = h.percentiles;
            let _ = writeln!(
                t,
                "| {} | {:.1} | {:.1} | {:.1} | {:.1} |",
                label.trim_start_matches("probe: "),
                us(v.p50),
                us(v.p99),
                us(v.p99_99),
                us(v.max)
            );
        }
        if let Some(m) = base {
            let p50 = |h: &flexloop_runfiles::Histogram| h.percentiles.p50.max(1) as f64;
            let rt = m.round_trip.p50 as f64;
            let _ = writeln!(
                t,
                "\nThe loop at 10 kHz (default scenario, else thesis-mc), round trip p50 against each floor: {:.2}× the timer wake-up, {:.2}× the event ping-pong (two wake-ups, as the loop's plant → controller → plant), {:.2}× the Unix-socket ring, {:.1}× the polling ping-pong (no wake-up at all).",
                rt / p50(&f.timer_wakeup),
                rt / p50(&f.iceoryx2_event_ping_pong),
                rt / p50(&f.unix_socket_ring),
                rt / p50(&f.iceoryx2_polling_ping_pong)
            );
        }
    }
    t
}

pub fn figures(results: &[(Point, Result<Measured, String>)]) -> Vec<(String, Figure)> {
    let ok = |series: Series| -> Vec<(&Point, &Measured)> {
        results
            .iter()
            .filter(|(p, _)| p.series == series)
            .filter_map(|(p, r)| Some((p, r.as_ref().ok()?)))
            .collect()
    };
    let mut out = Vec::new();
    let rate = ok(Series::Rate);
    if rate.len() >= 2 {
        let mut f = Figure::new(
            "sweep-rate",
            "Round trip against the sample rate (thesis-mc)",
            Axis::log10("rate [kHz]"),
            Axis::log10("latency [µs]"),
        );
        let series = |q: usize| -> Vec<(f64, f64)> {
            rate.iter()
                .map(|(p, m)| (p.rate_hz / 1e3, us(m.round_trip.values()[q]).max(0.1)))
                .collect()
        };
        f.line("round trip p50", series(0));
        f.line("round trip p99.99", series(4));
        f.line(
            "tick → u(k) p99.99",
            rate.iter()
                .map(|(p, m)| (p.rate_hz / 1e3, us(m.tick_to_command.p99_99).max(0.1)))
                .collect(),
        );
        f.colored_line(
            "one sample period (the budget)",
            rate.iter()
                .map(|(p, _)| (p.rate_hz / 1e3, 1e6 / p.rate_hz))
                .collect(),
            "#d62728",
        );
        out.push(("sweep-rate.svg".to_string(), f));
    }
    let states = ok(Series::States);
    if states.len() >= 2 {
        let mut f = Figure::new(
            "sweep-states",
            "Cost against the observer's states (uniform chain, 10 kHz)",
            Axis::log10("observer states"),
            Axis::log10("time per sample [µs]"),
        );
        let line = |get: &dyn Fn(&Measured) -> f64| -> Vec<(f64, f64)> {
            states
                .iter()
                .map(|(_, m)| (m.states as f64, get(m).max(0.01)))
                .collect()
        };
        f.line(
            "observer CPU",
            line(&|m| m.cpu_per_sample_ns.observer / 1e3),
        );
        f.line(
            "controller CPU",
            line(&|m| m.cpu_per_sample_ns.controller / 1e3),
        );
        f.line("plant CPU", line(&|m| m.cpu_per_sample_ns.plant / 1e3));
        f.line(
            "observer compute p50",
            line(&|m| us(m.observer_compute.p50)),
        );
        f.line("round trip p50", line(&|m| us(m.round_trip.p50)));
        out.push(("sweep-states.svg".to_string(), f));
    }
    let axes: Vec<(&Point, &Measured)> = ok(Series::Base)
        .into_iter()
        .chain(ok(Series::Axes))
        .collect();
    if axes.len() >= 2 {
        let mut f = Figure::new(
            "sweep-axes",
            "Cost against the number of axes (10 kHz: SISO chain, 2×2, 3-DOF OAT-like)",
            Axis::linear("axes (inputs)"),
            Axis::log10("µs"),
        );
        let line = |get: &dyn Fn(&Measured) -> f64| -> Vec<(f64, f64)> {
            let mut v: Vec<(f64, f64)> = axes
                .iter()
                .map(|(_, m)| (m.inputs as f64, get(m).max(0.01)))
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v
        };
        f.line("round trip p50", line(&|m| us(m.round_trip.p50)));
        f.line("round trip p99.99", line(&|m| us(m.round_trip.p99_99)));
        f.line(
            "observer CPU per sample",
            line(&|m| m.cpu_per_sample_ns.observer / 1e3),
        );
        f.line(
            "controller CPU per sample",
            line(&|m| m.cpu_per_sample_ns.controller / 1e3),
        );
        out.push(("sweep-axes.svg".to_string(), f));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_growth_exponent_of_a_power_law_is_its_power() {
        let points: Vec<(f64, f64)> = [16.0, 32.0, 64.0, 128.0]
            .iter()
            .map(|n: &f64| (*n, 3.0 * n.powf(1.7)))
            .collect();
        assert!((growth_exponent(&points).unwrap() - 1.7).abs() < 1e-12);
        assert_eq!(growth_exponent(&points[..1]), None);
    }
}
