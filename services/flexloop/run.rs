//! `flexloop run SCENARIO`: runs a scenario's trajectory through the real
//! processes, then prints the control metrics from the log beside the timing
//! summary. `flexloop fit-ff RUN`: fits the feedforward gains from a recorded
//! run and writes them into a scenario file.

use crate::loop_command::{LoopFlags, VERDICT_FAILED};
use anyhow::{Context, bail};
use flexloop_analysis::feedforward_fit::{FittedFeedforward, fit_from_run};
use flexloop_analysis::modal_damping::{ModeDamping, modal_damping};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_analysis::verdict::{FigureFaults, GridCounts, invalid_reasons, judged_spans};
use flexloop_analysis::{ControlMetrics, MetricsOptions, RunTrace};
use flexloop_design::LoopDesign;
use flexloop_design::reference::Reference;
use flexloop_protocol::flags;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::metrics::{MetricsFile, MetricsTiming};
use flexloop_runfiles::{RunDir, RunSummary};
use flexloop_runtime::latency::Metric;
use flexloop_scenario::{Mode, Overrides, Scenario};
use flexloop_supervisor::launch::{prepare, supervise};
use std::path::{Path, PathBuf};

/// `run [SCENARIO] [loop flags] [--allow-invalid]`.
#[derive(Debug, clap::Args)]
pub struct RunFlags {
    #[command(flatten)]
    pub run: LoopFlags,
    /// Exit 0 even when the figures are not the design's (held inputs,
    /// safe actions or missing ticks where they are measured, dominating stalls)
    #[arg(long)]
    pub allow_invalid: bool,
}

pub fn run(flags: RunFlags) -> anyhow::Result<i32> {
    let args = flags.run.into_loop_args()?;
    let prepared = prepare(&args)?;
    let run_dir = prepared.run_dir();
    if prepared.scenario.ticks().is_none() {
        bail!(
            "{}: loop.duration_s is 0 (run until stopped); `flexloop run` needs a duration",
            args.scenario.display()
        );
    }
    crate::loop_command::warn_about_design(&prepared);
    eprintln!(
        "flexloop run: {} for {} s at {} Hz ({}{}), run directory {}",
        prepared.scenario.name,
        prepared.scenario.timing.duration_s,
        prepared.scenario.timing.rate_hz,
        prepared.scenario.timing.mode.as_str(),
        crate::loop_command::pid_words(&prepared.design)
            .map_or(String::new(), |w| format!(", {w}")),
        run_dir.path().display()
    );
    supervise(prepared, |_, _| None)?;
    let report = RunReport::load(&run_dir)?;
    report.print();
    write_json_atomically(&run_dir.metrics(), &report.metrics_file())?;
    println!("\nmetrics: {}", run_dir.metrics().display());
    if report.invalid_reasons.is_empty() {
        return Ok(0);
    }
    eprintln!(
        "flexloop run: the control figures are NOT the design's (metrics.json: valid false): {}",
        report.invalid_reasons.join("; ")
    );
    if flags.allow_invalid {
        return Ok(0);
    }
    eprintln!("flexloop run: exit {VERDICT_FAILED}; --allow-invalid exits 0 all the same");
    Ok(VERDICT_FAILED)
}

/// A finished run, read back from its directory.
pub struct RunReport {
    pub scenario: Scenario,
    pub design: LoopDesign,
    pub trace: RunTrace,
    pub summary: RunSummary,
    pub metrics: ControlMetrics,
    pub damping: Vec<ModeDamping>,
    /// The sample files read (every logger generation's, in order) and the
    /// samples no logger recorded.
    pub files: Vec<PathBuf>,
    pub outages: Vec<flexloop_runfiles::summary::Outage>,
    /// What joining the files did, if there was more than one file or an
    /// outage (for the user).
    pub joined: Option<String>,
    /// The plant's counts of the run.
    pub grid: GridCounts,
    /// Commands clamped at the input limit, and refused as not finite.
    pub clamps: Clamps,
    /// Why the figures are not the design's; empty when they are.
    pub invalid_reasons: Vec<String>,
    /// What of the sample file could not be read (a torn or damaged tail).
    pub unread: Option<String>,
}

impl RunReport {
    pub fn load(run_dir: &RunDir) -> anyhow::Result<Self> {
        let summary = run_dir.read_summary()?;
        // The run's own rate, mode and duration, whatever the file says now.
        let overrides = Overrides {
            rate_hz: Some(summary.rate_hz),
            mode: Mode::parse(&summary.mode),
            duration_s: Some(summary.duration_s),
            no_realtime: false,
            // How the plant waited does not change the analysis.
            tick: None,
        };
        let scenario = Scenario::load(&run_dir.scenario_copy(), &overrides)?;
        let design = LoopDesign::from_scenario(&scenario)?;
        // Every logger generation's file, in order.
        let joined = JoinedLog::open(run_dir.path())?;
        let trace = RunTrace::from_log(&joined.log, design.ts);
        // A torn or damaged file is read up to its last intact chunk: say so.
        let unread = (!joined.torn.is_empty()).then(|| {
            joined
                .torn
                .iter()
                .map(|(path, e)| {
                    format!("{}: read up to its last intact chunk: {e}", path.display())
                })
                .collect::<Vec<_>>()
                .join("; ")
        });
        let end_s = trace.rows.last().map(|r| trace.time(r)).unwrap_or_default();
        let windows = design.reference.scan_windows(end_s);
        let metrics = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
        let (from_s, to_s) = ring_down_window(&design, end_s);
        let damping = modal_damping(&design, Some(&trace), from_s, to_s);
        let lead_s = match &design.reference {
            Reference::Scan { setpoint, .. } => setpoint.scan_window().0,
            _ => 0.0,
        };
        let row_seqs: Vec<u64> = trace.rows.iter().map(|r| r.seq).collect();
        let faults = FigureFaults::of(
            &trace.timing,
            &row_seqs,
            design.ts,
            &judged_spans(&windows, lead_s),
        );
        let grid = grid_counts(run_dir, &summary);
        let invalid_reasons = invalid_reasons(&faults, &grid);
        let plant = run_dir.read_plant_latency().ok();
        let clamps = Clamps {
            by_controller: joined
                .log
                .commands()
                .filter(|c| c.flags & flags::CLAMPED != 0)
                .count() as u64,
            by_plant: plant.as_ref().map(|p| p.counters.clamped),
            non_finite: plant.as_ref().map(|p| p.counters.non_finite),
        };
        Ok(Self {
            scenario,
            design,
            trace,
            summary,
            metrics,
            damping,
            joined: joined.describe(),
            files: joined.files,
            outages: joined.outages,
            grid,
            clamps,
            invalid_reasons,
            unread,
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
        if let Some(joined) = &self.joined {
            println!("  sample log: {joined}");
        }
        // Beside the figure: whether it is the design's at all.
        let mark = if self.invalid_reasons.is_empty() {
            String::new()
        } else {
            "   NOT the design's: see \"invalid\" below".to_string()
        };
        match m.rms_e_true_scan {
            Some(rms) => println!(
                "  rms e_true over the scan{}      {:>10.3} {small}{mark}",
                if m.scans.len() > 1 { "s" } else { " " },
                nm(rms)
            ),
            None => println!("  (no scan window: the reference is not a scan){mark}"),
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
        println!();
        println!(
            "timing ({} mode at {} Hz):",
            s.mode,
            serde_json::Value::from(s.rate_hz)
        );
        println!(
            "  ticks {}, loop misses {}, late commands {}, stalled ticks {} ({} misses after stalls), held inputs {}, stale estimates {}",
            s.ticks,
            s.counters.misses,
            s.counters.late_commands,
            s.counters.stalled_ticks,
            s.counters.stall_misses,
            m.held_ticks,
            m.stale_estimates
        );
        let c = &self.clamps;
        let plant_count = |n: Option<u64>| {
            n.map_or("unknown (the plant wrote no counts)".into(), |n| {
                n.to_string()
            })
        };
        println!(
            "  commands clamped at the input limit: {} by the controller, {} by the plant; refused as not finite: {}",
            c.by_controller,
            plant_count(c.by_plant),
            plant_count(c.non_finite)
        );
        for metric in [Metric::RoundTrip, Metric::TickToCommand] {
            let us = s
                .latency(metric.name())
                .percentiles
                .values()
                .map(|ns| ns as f64 / 1e3);
            println!(
                "  {:<16} p50 {:>8.1} µs   p99 {:>8.1} µs   p99.99 {:>8.1} µs   max {:>9.1} µs",
                metric.name(),
                us[0],
                us[2],
                us[4],
                us[5]
            );
        }
        if self.trace.incomplete_ticks > 0 {
            println!(
                "  {} ticks missing a command or an estimate in the log (left out of the metrics)",
                self.trace.incomplete_ticks
            );
        }
        println!("  verdict: {}", self.grid.verdict());
        if !self.invalid_reasons.is_empty() {
            println!("\ninvalid: the control figures above are not the design's:");
            for reason in &self.invalid_reasons {
                println!("  - {reason}");
            }
        }
    }

    pub fn metrics_file(&self) -> MetricsFile<&ControlMetrics, &ModeDamping> {
        MetricsFile {
            scenario: self.scenario.name.clone(),
            outputs: self.design.output_names.clone(),
            output_unit: self.design.output_unit.into(),
            input_unit: self.design.input_unit.into(),
            mode: self.summary.mode.clone(),
            rate_hz: self.summary.rate_hz,
            loop_delay_samples: self.design.loop_delay_samples,
            valid: self.invalid_reasons.is_empty(),
            invalid_reasons: self.invalid_reasons.clone(),
            control: &self.metrics,
            modal_damping: self.damping.iter().collect(),
            timing: MetricsTiming {
                counters: self.summary.counters,
                round_trip: self.summary.latency(Metric::RoundTrip.name()),
                tick_to_command: self.summary.latency(Metric::TickToCommand.name()),
            },
            incomplete_ticks: self.trace.incomplete_ticks,
        }
    }
}

/// Every clamp of the run, whoever's command it was: the built-in
/// controller clamps its own (and flags them), the plant any other's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Clamps {
    /// Recorded commands flagged clamped by the controller that sent them.
    pub by_controller: u64,
    /// The plant's own counts (`None`: it wrote none, it crashed).
    pub by_plant: Option<u64>,
    pub non_finite: Option<u64>,
}

/// The plant's own counts (`plant_latency.json`); the logger's view of
/// them when the plant wrote none (it crashed).
pub fn grid_counts(run_dir: &RunDir, summary: &RunSummary) -> GridCounts {
    match run_dir.read_plant_latency() {
        Ok(p) => GridCounts {
            ticks: p.ticks,
            stalled_ticks: p.counters.stalled_ticks,
            late_commands: p.counters.late_commands,
            misses: p.counters.misses,
            stall_misses: p.counters.stall_misses,
        },
        Err(_) => GridCounts {
            ticks: summary.last_seq + u64::from(summary.ticks > 0),
            stalled_ticks: summary.counters.stalled_ticks,
            late_commands: summary.counters.late_commands,
            misses: summary.counters.misses,
            stall_misses: summary.counters.stall_misses,
        },
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

/// `fit-ff RUN_DIR [--into SCENARIO]`.
#[derive(Debug, clap::Args)]
pub struct FitFfArgs {
    /// The recorded run's directory
    pub run_dir: PathBuf,
    /// The scenario file to write the gains into [default: the one the run used]
    #[arg(long, value_name = "SCENARIO")]
    pub into: Option<PathBuf>,
}

pub fn fit_ff(args: FitFfArgs) -> anyhow::Result<i32> {
    let run_dir = args.run_dir;
    let report = RunReport::load(&RunDir::new(&run_dir))?;
    if let Some(joined) = &report.joined {
        eprintln!("flexloop fit-ff: {joined}");
    }
    let programs = flexloop_design::loop_design::unanalysed_roles(&report.scenario);
    if !programs.is_empty() {
        bail!(
            "{}: fit-ff fits the built-in controller's four feedforward gains through the \
             built-in loop; a program of one's own served the {} of this run (its feedforward \
             is its own)",
            run_dir.display(),
            programs.join(" and the ")
        );
    }
    if report.design.n_inputs != 1 || report.design.n_outputs != 1 {
        bail!(
            "{}: fit-ff fits the four-gain feedforward of a loop with one input and one \
             output; `{}` has {} and {} (it uses the rigid-body feedforward)",
            run_dir.display(),
            report.scenario.plant.model,
            report.design.n_inputs,
            report.design.n_outputs
        );
    }
    let fit = fit_from_run(&report.design, &report.trace)
        .with_context(|| format!("{}: cannot fit the feedforward", run_dir.display()))?;
    let target = args
        .into
        .unwrap_or_else(|| PathBuf::from(&report.summary.scenario_file));
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

const FIT_NOTE: &str = "# Fitted by `flexloop fit-ff`";
/// The note a fit wrote before the command was named `fit-ff`.
const EARLIER_FIT_NOTE: &str = "# Fitted by `flexloop tune-ff`";

/// Replaces (or adds) the `[controller.feedforward]` table of a scenario
/// file, keeping everything else as written; the result is parsed before it
/// replaces the file, so a failed edit leaves the file as it was.
pub fn write_feedforward(path: &Path, fit: &FittedFeedforward) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    if text
        .lines()
        .any(|l| l.trim_start().starts_with("feedforward") && l.contains('{'))
    {
        bail!(
            "{}: field controller.feedforward is an inline table; write it as a \
             [controller.feedforward] table so that fit-ff can replace it",
            path.display()
        );
    }
    let mut out = String::with_capacity(text.len() + 200);
    let mut skipping = false;
    for line in text.lines() {
        let header = line.trim_start().starts_with('[');
        if header {
            skipping = line.trim() == "[controller.feedforward]";
        }
        // The note above the table is rewritten with it.
        let fit_note = line.starts_with(FIT_NOTE) || line.starts_with(EARLIER_FIT_NOTE);
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
    let mut check = Scenario::parse(path, &out)?;
    check.apply(&Overrides::default());
    check.validate()?;
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, &out).with_context(|| tmp.display().to_string())?;
    std::fs::rename(&tmp, path).with_context(|| path.display().to_string())
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
    fn fit_ff_replaces_the_table_and_its_note_and_keeps_the_rest() {
        let dir =
            std::env::temp_dir().join(format!("flexloop-fitff-replace-{}", std::process::id()));
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

    #[test]
    fn a_fit_under_the_command_s_earlier_name_is_replaced_too() {
        let dir = std::env::temp_dir().join(format!("flexloop-fitff-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        let source = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/thesis-ad.toml");
        let earlier = std::fs::read_to_string(source)
            .unwrap()
            .replace(FIT_NOTE, EARLIER_FIT_NOTE);
        assert_eq!(earlier.matches(EARLIER_FIT_NOTE).count(), 1);
        std::fs::write(&path, earlier).unwrap();
        write_feedforward(&path, &fit(12.5)).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(text.matches(EARLIER_FIT_NOTE).count(), 0, "{text}");
        assert_eq!(text.matches(FIT_NOTE).count(), 1, "{text}");
    }
}
