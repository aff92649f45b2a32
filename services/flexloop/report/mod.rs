//! `flexloop report RUN [--out DIR]`: a finished run as a Markdown summary
//! (`report.md`, figures as SVG files beside it) and one self-contained HTML
//! page (`report.html`, figures inlined), by default in RUN/report/.
//!
//! - [`document`]: the report as blocks, rendered to Markdown and HTML.
//! - [`content`]: its text and tables.
//! - [`figures`]: its plots.
//! - [`measured`]: the measured frequency responses, for a run that
//!   measured the loop (its scenario's `[measure]`, or one ordered while it
//!   ran).

mod content;
mod document;
mod figures;
mod measured;

use crate::run::RunReport;
use anyhow::{Context, anyhow, bail};
use flexloop_analysis::flexible::{FlexibleComparison, NoComparison};
use flexloop_analysis::latency_log::LatencyLog;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::parse_events;
use std::path::{Path, PathBuf};

/// `report RUN [--out DIR]`.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// A run directory, or its name under runs/
    run: PathBuf,
    /// Where the report goes [default: RUN/report]
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

/// A swap, crash or restart from the supervisor's `events.jsonl`.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// On the run's tick clock where the event names its tick, else the
    /// supervisor's clock.
    pub time_s: f64,
    pub kind: String,
    pub role: String,
    pub generation: u64,
    pub seq: Option<u64>,
    pub detail: String,
}

/// How the report shows the outputs' errors: nm for positions in m, µrad
/// for the two-inertia setup's angles in rad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Length {
    pub per_si: f64,
    pub unit: &'static str,
}

impl Length {
    pub fn for_unit(si_unit: &str) -> Self {
        match si_unit {
            "rad" => Self {
                per_si: 1e6,
                unit: "µrad",
            },
            _ => Self {
                per_si: 1e9,
                unit: "nm",
            },
        }
    }

    /// `v` (in the SI unit) in this unit.
    pub fn of(self, v: f64) -> f64 {
        v * self.per_si
    }
}

/// Everything the report reads from a run directory.
pub struct RunData {
    /// The unit of the outputs' errors in tables and figures.
    pub length: Length,
    pub dir: PathBuf,
    pub run: RunReport,
    pub latency: LatencyLog,
    pub events: Vec<Event>,
    pub flexible: Result<FlexibleComparison, NoComparison>,
    pub period_ns: u64,
    pub lockstep: bool,
    /// The sample files read (every logger generation's, in order), when
    /// there is more than one.
    pub joined_files: Vec<String>,
    /// Every measurement of the run (the scenario's `[measure]`, then each
    /// one ordered while it ran): the responses `flexloop measure` computes,
    /// or why they cannot be computed. Empty when the run measured nothing.
    /// Each with the design of the loop it measured.
    pub measurements: Vec<measured::Measured>,
}

impl RunData {
    /// Reads a run directory; every error names the file it concerns.
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        let run_dir = RunDir::new(dir);
        let run = RunReport::load(&run_dir)?;
        let latency = LatencyLog::read_run(dir)?;
        let events = read_events(&run_dir.events(), run.design.ts)?;
        let flexible =
            FlexibleComparison::compute(&run.design, &run.trace, run.scenario.observer.mc);
        let period_ns = run.summary.period_ns;
        let lockstep = run.summary.mode == "lockstep";
        let joined_files = if run.files.len() > 1 {
            flexloop_analysis::run_log::file_names(&run.files)
        } else {
            Vec::new()
        };
        let measurements = measured::measure(dir, &run)?;
        Ok(Self {
            length: Length::for_unit(run.design.output_unit),
            dir: dir.to_path_buf(),
            run,
            latency,
            events,
            flexible,
            period_ns,
            lockstep,
            joined_files,
            measurements,
        })
    }
}

pub fn report(args: ReportArgs) -> anyhow::Result<i32> {
    let run_dir = resolve_run(&args.run)?;
    let out_dir = args.out.unwrap_or_else(|| RunDir::new(&run_dir).report());
    let data = RunData::load(&run_dir)?;
    if let Some(joined) = &data.run.joined {
        println!("report: {joined}");
    }
    let ticks = data.run.trace.rows.len();
    if let Some(unread) = &data.run.unread {
        if ticks == 0 {
            bail!("{unread}; no sample of the run could be read: nothing to report");
        }
        eprintln!(
            "flexloop: {unread}; the report covers the {ticks} ticks before it, of the run's {}",
            data.run.summary.ticks
        );
    } else if ticks == 0 {
        bail!(
            "{}: holds no sample of the run: nothing to report",
            RunDir::new(&run_dir).samples(0).display()
        );
    }
    let recording = &data.run.summary.recording.sample_file;
    if recording.stopped() {
        let trace = &data.run.trace;
        let until_s = trace.rows.last().map_or(0.0, |r| trace.time(r));
        eprintln!(
            "flexloop: the recording stopped at t = {until_s:.3} s ({}): the report covers the run up to then",
            recording.error.as_deref().unwrap_or("a write failed")
        );
    }
    for m in &data.measurements {
        if let Err(reason) = &m.result {
            eprintln!(
                "flexloop: the measured frequency responses{} cannot be computed: {reason}; the \
                 report says so in their section",
                m.ordered_words()
            );
        }
    }
    let doc = content::document(&data);
    write_report(&out_dir, &doc)?;
    println!(
        "report: {}",
        out_dir.join(RunDir::REPORT_MARKDOWN).display()
    );
    println!("        {}", out_dir.join(RunDir::REPORT_HTML).display());
    Ok(0)
}

/// A run directory, or the name of one under `runs/`.
fn resolve_run(given: &Path) -> anyhow::Result<PathBuf> {
    if given.is_dir() {
        return Ok(given.to_path_buf());
    }
    let under_runs = Path::new("runs").join(given);
    if given.components().count() == 1 && under_runs.is_dir() {
        return Ok(under_runs);
    }
    Err(anyhow!(
        "{}: no such run directory{}",
        given.display(),
        if given.components().count() == 1 {
            format!(" (nor {})", under_runs.display())
        } else {
            String::new()
        }
    ))
}

/// Each file is written whole under a temporary name, then renamed, so that
/// a reader never opens a half-written report.
fn write_report(out_dir: &Path, doc: &document::Document) -> anyhow::Result<()> {
    std::fs::create_dir_all(out_dir).with_context(|| out_dir.display().to_string())?;
    let write = |name: &str, text: &str| -> anyhow::Result<()> {
        let path = out_dir.join(name);
        let tmp = out_dir.join(format!(".{name}.tmp"));
        std::fs::write(&tmp, text)
            .and_then(|()| std::fs::rename(&tmp, &path))
            .with_context(|| path.display().to_string())
    };
    for f in doc.figures() {
        write(&f.file, &f.svg)?;
    }
    write(RunDir::REPORT_MARKDOWN, &doc.markdown())?;
    write(RunDir::REPORT_HTML, &doc.html())
}

/// Reads `events.jsonl` (absent: no events); `ts` places each on the tick clock.
fn read_events(path: &Path, ts: f64) -> anyhow::Result<Vec<Event>> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| path.display().to_string()),
    };
    let events = parse_events(&text).with_context(|| path.display().to_string())?;
    Ok(events
        .into_iter()
        .map(|e| {
            let time_s = match e.seq {
                Some(seq) => seq as f64 * ts,
                None => e.t_s,
            };
            let detail = match serde_json::to_value(&e.kind) {
                Ok(serde_json::Value::Object(mut line)) => match line.remove("detail") {
                    Some(serde_json::Value::String(s)) => s,
                    Some(other) => other.to_string(),
                    None => String::new(),
                },
                _ => String::new(),
            };
            Event {
                time_s,
                kind: e.kind.name().to_string(),
                role: e.role,
                generation: e.generation.map_or(0, u64::from),
                seq: e.seq,
                detail: shorten(&detail, 120),
            }
        })
        .collect())
}

fn shorten(text: &str, max: usize) -> String {
    if text.chars().count() <= max {
        return text.to_string();
    }
    let mut s: String = text.chars().take(max - 1).collect();
    s.push('…');
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runfiles::events::{EventKind, Spare, SupervisorEvent};

    #[test]
    fn events_are_read_and_a_bad_line_is_named() {
        let dir =
            std::env::temp_dir().join(format!("flexloop-report-events-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("events.jsonl");
        let swap = SupervisorEvent {
            t_s: 1.5,
            role: "controller".into(),
            generation: Some(2),
            seq: Some(2000),
            kind: EventKind::Spare(Spare { pid: 7 }),
        };
        let crash = SupervisorEvent {
            t_s: 2.5,
            role: "observer".into(),
            generation: Some(1),
            seq: None,
            kind: EventKind::RestartFailed("signal 9".into()),
        };
        let lines = [&swap, &crash]
            .map(|e| serde_json::to_string(e).unwrap() + "\n")
            .concat();
        std::fs::write(&path, &lines).unwrap();
        let events = read_events(&path, 1e-4).unwrap();
        assert_eq!(events.len(), 2);
        assert!((events[0].time_s - 0.2).abs() < 1e-12, "placed by its tick");
        assert_eq!(events[0].kind, "spare");
        assert_eq!(events[0].detail, "{\"pid\":7}");
        assert_eq!(events[1].time_s, 2.5);
        assert_eq!(events[1].detail, "signal 9");
        let good = serde_json::to_string(&swap).unwrap();
        std::fs::write(&path, format!("{good}\nnot json\n")).unwrap();
        let e = format!("{:#}", read_events(&path, 1e-4).unwrap_err());
        assert!(e.contains("events.jsonl: line 2"), "{e}");
        assert!(
            read_events(&dir.join("absent.jsonl"), 1e-4)
                .unwrap()
                .is_empty()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_missing_run_is_named() {
        let e = resolve_run(Path::new("no-such-run-xyz"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no-such-run-xyz: no such run directory (nor runs/no-such-run-xyz)"),
            "{e}"
        );
    }
}
