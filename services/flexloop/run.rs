//! `flexloop run SCENARIO`: runs a scenario's trajectory through the real
//! processes, then prints the control metrics from the log beside the timing
//! summary. `flexloop tune-ff RUN`: fits the feedforward gains from a recorded
//! run and writes them into a scenario file.

use crate::{LoopArgs, prepare, run_registered_with};
use flexloop_analysis::feedforward_fit::{FittedFeedforward, fit_from_run};
use flexloop_analysis::modal_damping::{ModeDamping, modal_damping};
use flexloop_analysis::{ControlMetrics, MetricsOptions, RunTrace};
use flexloop_components::LogReader;
use flexloop_node::logger::SAMPLES_FILE;
use flexloop_scenario::reference::Reference;
use flexloop_scenario::{LoopDesign, Mode, Overrides, Scenario};
use serde_json::{Value, json};
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The scenario as it ran, copied into every run directory.
pub const SCENARIO_COPY: &str = "scenario.toml";
pub const METRICS_FILE: &str = "metrics.json";

pub fn run(args: LoopArgs) -> Result<i32, String> {
    let prepared = prepare(&args)?;
    let run_dir = prepared.plan.run_dir.clone();
    if prepared.scenario.ticks().is_none() {
        return Err(format!(
            "{}: loop.duration_s is 0 (run until stopped); `flexloop run` needs a duration",
            args.scenario.display()
        ));
    }
    eprintln!(
        "flexloop run: {} for {} s at {} Hz ({}), run directory {}",
        prepared.scenario.name,
        prepared.scenario.timing.duration_s,
        prepared.scenario.timing.rate_hz,
        prepared.scenario.timing.mode.as_str(),
        run_dir.display()
    );
    run_registered_with(prepared, |_, _| None)?;
    let report = RunReport::load(&run_dir)?;
    report.print();
    flexloop_node::summary::write_json_atomically(&run_dir.join(METRICS_FILE), &report.to_json())
        .map_err(|e| format!("{}: {e}", run_dir.join(METRICS_FILE).display()))?;
    println!("\nmetrics: {}", run_dir.join(METRICS_FILE).display());
    Ok(0)
}

/// A finished run, read back from its directory.
pub struct RunReport {
    pub scenario: Scenario,
    pub design: LoopDesign,
    pub trace: RunTrace,
    pub summary: Value,
    pub metrics: ControlMetrics,
    pub damping: Vec<ModeDamping>,
}

impl RunReport {
    pub fn load(run_dir: &Path) -> Result<Self, String> {
        let summary = flexloop_node::summary::read_summary(run_dir)?;
        let overrides = Overrides {
            rate_hz: summary["rate_hz"].as_f64(),
            mode: summary["mode"].as_str().and_then(Mode::parse),
            duration_s: summary["duration_s"].as_f64(),
            no_realtime: false,
        };
        let scenario =
            Scenario::load(&run_dir.join(SCENARIO_COPY), &overrides).map_err(|e| e.to_string())?;
        let design = LoopDesign::from_scenario(&scenario).map_err(|e| e.to_string())?;
        let log_path = run_dir.join(SAMPLES_FILE);
        let log = LogReader::open(&log_path).map_err(|e| format!("{}: {e}", log_path.display()))?;
        let trace = RunTrace::from_log(&log, design.ts);
        let end_s = trace.rows.last().map(|r| trace.time(r)).unwrap_or_default();
        let windows = design.reference.scan_windows(end_s);
        let metrics = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
        let (from_s, to_s) = ring_down_window(&design, end_s);
        let damping = modal_damping(&design, Some(&trace), from_s, to_s);
        Ok(Self {
            scenario,
            design,
            trace,
            summary,
            metrics,
            damping,
        })
    }

    pub fn print(&self) {
        let m = &self.metrics;
        let d = &self.design;
        // Errors in nm (or µrad), as the thesis reports them.
        let (scale, small) = match d.output_unit {
            "rad" => (1e6, "µrad"),
            _ => (1e9, "nm"),
        };
        let nm = |v: f64| v * scale;
        let (y_unit, u_unit) = (d.output_unit, d.input_unit);
        println!();
        println!(
            "control ({} ticks, output {}{}):",
            m.ticks,
            d.output_names.first().map_or("?", String::as_str),
            if d.n_outputs > 1 {
                format!(", first of {} (all axes below)", d.n_outputs)
            } else {
                String::new()
            }
        );
        match m.rms_e_true_scan {
            Some(rms) => println!(
                "  rms e_true over the scan{}      {:>10.3} {small}",
                if m.scans.len() > 1 { "s" } else { " " },
                nm(rms)
            ),
            None => println!("  (no scan window: the reference is not a scan)"),
        }
        for (i, s) in m.scans.iter().enumerate().take(8) {
            println!(
                "  scan {} [{:.3}, {:.3}] s: rms {:.3} {small}, peak {:.3} {small}, max |MA| {:.3} {small}, max MSD {:.3} {small}",
                i + 1,
                s.start_s,
                s.end_s,
                nm(s.rms_e_true),
                nm(s.peak_e_true),
                nm(s.max_abs_ma),
                nm(s.max_msd)
            );
        }
        println!(
            "  peak |e_true| over the run      {:>10.3} {small}",
            nm(m.e_true.peak)
        );
        println!(
            "  effort: u rms {:.4} {u_unit} (peak {:.4} {u_unit}); parts rms: feedback {:.4} {u_unit}, feedforward {:.4} {u_unit}, damping {:.4} {u_unit}",
            m.u.rms, m.u.peak, m.u_fb.rms, m.u_ff.rms, m.u_d.rms
        );
        println!(
            "  innovation: mean {:.3e} {y_unit}, std {:.3e} {y_unit}, lag-1 autocorrelation {:.3}",
            m.innovation.mean, m.innovation.std, m.innovation.lag1_autocorrelation
        );
        if d.n_outputs > 1 || d.n_inputs > 1 {
            println!("  per axis:");
            println!(
                "    {:<24} {:>14} {:>14} {:>14} {:>16}",
                "output",
                format!("scan rms [{small}]"),
                format!("rms [{small}]"),
                format!("peak [{small}]"),
                format!("settled [{small}]")
            );
            let opt = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{:.3}", nm(x)));
            for (name, a) in d.output_names.iter().zip(&m.axes) {
                println!(
                    "    {:<24} {:>14} {:>14.3} {:>14.3} {:>16.3}",
                    name,
                    opt(a.rms_e_true_scan),
                    nm(a.e_true.rms),
                    nm(a.e_true.peak),
                    nm(a.settled_peak_e_true)
                );
            }
            for (i, u) in m.inputs.iter().enumerate() {
                println!(
                    "    input {:<18} rms {:.4} {u_unit}, peak {:.4} {u_unit}",
                    i + 1,
                    u.rms,
                    u.peak
                );
            }
        }
        if !self.damping.is_empty() {
            println!("  modal damping (flexible modes):");
            println!(
                "    {:>4} {:>10} {:>10} {:>14} {:>14}",
                "mode", "f [Hz]", "open loop", "closed (model)", "identified"
            );
            let opt = |v: Option<f64>| v.map_or("-".to_string(), |z| format!("{z:.4}"));
            for (i, d) in self.damping.iter().enumerate() {
                println!(
                    "    {:>4} {:>10.1} {:>10.4} {:>14} {:>14}",
                    i + 1,
                    d.frequency_hz,
                    d.open_loop,
                    opt(d.closed_loop_model),
                    opt(d.identified)
                );
            }
        }
        let s = &self.summary;
        let us = |metric: &str, q: &str| {
            s["latency"][metric][format!("{q}_ns")]
                .as_u64()
                .unwrap_or(0) as f64
                / 1e3
        };
        println!();
        println!(
            "timing ({} mode at {} Hz):",
            s["mode"].as_str().unwrap_or("?"),
            s["rate_hz"]
        );
        println!(
            "  ticks {}, loop misses {}, late commands {}, stalled ticks {} ({} misses after stalls), held inputs {}, stale estimates {}",
            s["ticks"],
            s["counters"]["misses"],
            s["counters"]["late_commands"],
            s["counters"]["stalled_ticks"],
            s["counters"]["stall_misses"],
            m.held_ticks,
            m.stale_estimates
        );
        for metric in ["round_trip", "tick_to_command"] {
            println!(
                "  {metric:<16} p50 {:>8.1} µs   p99 {:>8.1} µs   p99.99 {:>8.1} µs   max {:>9.1} µs",
                us(metric, "p50"),
                us(metric, "p99"),
                us(metric, "p99.99"),
                us(metric, "max")
            );
        }
        if self.trace.incomplete_ticks > 0 {
            println!(
                "  {} ticks missing a command or an estimate in the log (left out of the metrics)",
                self.trace.incomplete_ticks
            );
        }
    }

    pub fn to_json(&self) -> Value {
        json!({
            "scenario": self.scenario.name,
            "outputs": self.design.output_names,
            "output_unit": self.design.output_unit,
            "input_unit": self.design.input_unit,
            "mode": self.summary["mode"],
            "rate_hz": self.summary["rate_hz"],
            "loop_delay_samples": self.design.loop_delay_samples,
            "control": self.metrics,
            "modal_damping": self.damping,
            "timing": {
                "counters": self.summary["counters"],
                "round_trip": self.summary["latency"]["round_trip"],
                "tick_to_command": self.summary["latency"]["tick_to_command"],
            },
            "incomplete_ticks": self.trace.incomplete_ticks,
        })
    }
}

/// After the first motion stops: until the run ends or the next scan starts.
fn ring_down_window(design: &LoopDesign, end_s: f64) -> (f64, f64) {
    match &design.reference {
        Reference::Scan {
            setpoint,
            start_s,
            repeat_s,
            ..
        } => {
            let next = if *repeat_s > 0.0 {
                start_s + repeat_s
            } else {
                f64::INFINITY
            };
            // 2 ms after the motion: the band-pass and observer transients have decayed.
            (start_s + setpoint.duration() + 0.002, end_s.min(next))
        }
        other => (other.end_s().unwrap_or(end_s), end_s),
    }
}

/// `flexloop tune-ff RUN [--into SCENARIO]`.
pub fn tune_ff(args: Vec<OsString>) -> Result<i32, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut run_dir = None;
    let mut into = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Value(v) if run_dir.is_none() => run_dir = Some(PathBuf::from(v)),
            Long("into") => into = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            other => return Err(other.unexpected().to_string()),
        }
    }
    let run_dir = run_dir.ok_or("usage: flexloop tune-ff RUN_DIR [--into SCENARIO]")?;
    let report = RunReport::load(&run_dir)?;
    if report.design.n_inputs != 1 || report.design.n_outputs != 1 {
        return Err(format!(
            "{}: tune-ff fits the four-gain feedforward of a loop with one input and one \
             output; `{}` has {} and {} (it uses the rigid-body feedforward)",
            run_dir.display(),
            report.scenario.plant.model,
            report.design.n_inputs,
            report.design.n_outputs
        ));
    }
    let fit = fit_from_run(&report.design, &report.trace)
        .map_err(|e| format!("{}: cannot fit the feedforward: {e}", run_dir.display()))?;
    let target = match into {
        Some(p) => p,
        None => PathBuf::from(
            report.summary["scenario_file"]
                .as_str()
                .ok_or("the run's summary does not name its scenario file; use --into")?,
        ),
    };
    // Write before printing: a closed stdout must not lose the fit.
    write_feedforward(&target, &fit)?;
    println!(
        "fitted on {} ticks: snap {:.6e}, jerk {:.6e}, acc {:.6}, vel {:.6e}",
        fit.samples, fit.snap, fit.jerk, fit.acc, fit.vel
    );
    println!(
        "rms e_true over the run: {:.3} nm recorded, {:.3} nm predicted with these gains",
        fit.rms_before * 1e9,
        fit.rms_after_predicted * 1e9
    );
    println!("written into {}", target.display());
    Ok(0)
}

const FIT_NOTE: &str = "# Fitted by `flexloop tune-ff`";

/// Replaces (or adds) the `[controller.feedforward]` table of a scenario
/// file, keeping everything else as written; the result is parsed before it
/// replaces the file, so a failed edit leaves the file as it was.
pub fn write_feedforward(path: &Path, fit: &FittedFeedforward) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if text
        .lines()
        .any(|l| l.trim_start().starts_with("feedforward") && l.contains('{'))
    {
        return Err(format!(
            "{}: field controller.feedforward is an inline table; write it as a \
             [controller.feedforward] table so that tune-ff can replace it",
            path.display()
        ));
    }
    let mut out = String::with_capacity(text.len() + 200);
    let mut skipping = false;
    for line in text.lines() {
        let header = line.trim_start().starts_with('[');
        if header {
            skipping = line.trim() == "[controller.feedforward]";
        }
        // The note above the table is rewritten with it.
        let fit_note = line.starts_with(FIT_NOTE);
        if !skipping && !fit_note {
            out.push_str(line);
            out.push('\n');
        }
    }
    while out.ends_with("\n\n") {
        out.pop();
    }
    out.push_str(&format!(
        "\n{FIT_NOTE} on {} ticks (least squares on e_true).\n\
         [controller.feedforward]\nsnap = {:e}\njerk = {:e}\nacc = {}\nvel = {:e}\n",
        fit.samples, fit.snap, fit.jerk, fit.acc, fit.vel
    ));
    let mut check = Scenario::parse(path, &out).map_err(|e| e.to_string())?;
    check.apply(&Overrides::default());
    check.validate().map_err(|e| e.to_string())?;
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, &out).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(acc: f64) -> FittedFeedforward {
        FittedFeedforward {
            snap: 1e-6,
            jerk: 2e-4,
            acc,
            vel: 3e-3,
            rms_before: 0.0,
            rms_after_predicted: 0.0,
            samples: 100,
        }
    }

    #[test]
    fn tune_ff_replaces_the_table_and_its_note_and_keeps_the_rest() {
        let dir = std::env::temp_dir().join(format!("flexloop-tuneff-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        let source = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/thesis-ad.toml");
        std::fs::copy(source, &path).unwrap();
        write_feedforward(&path, &fit(12.0)).unwrap();
        write_feedforward(&path, &fit(12.5)).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(text.matches(FIT_NOTE).count(), 1, "{text}");
        assert_eq!(text.matches("[controller.feedforward]").count(), 1);
        let scenario = Scenario::parse(&path, &text).unwrap();
        let ff = scenario.controller.feedforward.unwrap();
        assert_eq!(ff.acc, 12.5);
        let original = std::fs::read_to_string(source).unwrap();
        assert_eq!(
            scenario.name,
            Scenario::parse(Path::new(source), &original).unwrap().name
        );
    }
}
