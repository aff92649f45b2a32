//! `flexloop report RUN [--out DIR]`: a finished run as a Markdown summary
//! (`report.md`, figures as SVG files beside it) and one self-contained HTML
//! page (`report.html`, figures inlined), by default in RUN/report/.
//!
//! - [`document`]: the report as blocks, rendered to Markdown and HTML.
//! - [`content`]: its text and tables.
//! - [`figures`]: its plots.

mod content;
mod document;
mod figures;

use crate::run::RunReport;
use flexloop_analysis::flexible::{FlexibleComparison, NoComparison};
use flexloop_analysis::latency_log::LatencyLog;
use serde_json::Value;
use std::ffi::OsString;
use std::path::{Path, PathBuf};

pub const REPORT_DIR: &str = "report";
pub const MARKDOWN_FILE: &str = "report.md";
pub const HTML_FILE: &str = "report.html";

const USAGE: &str =
    "usage: flexloop report RUN [--out DIR]  (RUN: a run directory, or a name under runs/)";

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
    /// Sample logs of restarted loggers, which this report does not read.
    pub other_generations: Vec<String>,
}

impl RunData {
    /// Reads a run directory; every error names the file it concerns.
    pub fn load(dir: &Path) -> Result<Self, String> {
        let run = RunReport::load(dir)?;
        let latency = LatencyLog::read(&dir.join(flexloop_node::logger::HISTOGRAM_LOG))
            .map_err(|e| e.to_string())?;
        let events = read_events(&dir.join(crate::conductor::EVENTS_FILE), run.design.ts)?;
        let flexible =
            FlexibleComparison::compute(&run.design, &run.trace, run.scenario.observer.mc);
        let period_ns = run.summary["period_ns"]
            .as_u64()
            .unwrap_or_else(|| (run.design.ts * 1e9).round() as u64);
        let lockstep = run.summary["mode"] == "lockstep";
        let other_generations = (1..=64)
            .flat_map(crate::logger_files)
            .filter(|f| dir.join(f).exists())
            .collect();
        Ok(Self {
            length: Length::for_unit(run.design.output_unit),
            dir: dir.to_path_buf(),
            run,
            latency,
            events,
            flexible,
            period_ns,
            lockstep,
            other_generations,
        })
    }
}

pub fn report(args: Vec<OsString>) -> Result<i32, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut run = None;
    let mut out = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Value(v) if run.is_none() => run = Some(PathBuf::from(v)),
            Long("out") => out = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            other => return Err(format!("{}\n{USAGE}", other.unexpected())),
        }
    }
    let run_dir = resolve_run(&run.ok_or(USAGE)?)?;
    let out_dir = out.unwrap_or_else(|| run_dir.join(REPORT_DIR));
    let data = RunData::load(&run_dir)?;
    let doc = content::document(&data);
    write_report(&out_dir, &doc)?;
    println!("report: {}", out_dir.join(MARKDOWN_FILE).display());
    println!("        {}", out_dir.join(HTML_FILE).display());
    Ok(0)
}

/// A run directory, or the name of one under `runs/`.
fn resolve_run(given: &Path) -> Result<PathBuf, String> {
    if given.is_dir() {
        return Ok(given.to_path_buf());
    }
    let under_runs = Path::new("runs").join(given);
    if given.components().count() == 1 && under_runs.is_dir() {
        return Ok(under_runs);
    }
    Err(format!(
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
fn write_report(out_dir: &Path, doc: &document::Document) -> Result<(), String> {
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let write = |name: &str, text: &str| -> Result<(), String> {
        let path = out_dir.join(name);
        let tmp = out_dir.join(format!(".{name}.tmp"));
        std::fs::write(&tmp, text)
            .and_then(|()| std::fs::rename(&tmp, &path))
            .map_err(|e| format!("{}: {e}", path.display()))
    };
    for f in doc.figures() {
        write(&f.file, &f.svg)?;
    }
    write(MARKDOWN_FILE, &doc.markdown())?;
    write(HTML_FILE, &doc.html())
}

/// Reads `events.jsonl` (absent: no events); `ts` places each on the tick clock.
fn read_events(path: &Path, ts: f64) -> Result<Vec<Event>, String> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(format!("{}: {e}", path.display())),
    };
    text.lines()
        .enumerate()
        .filter(|(_, line)| !line.trim().is_empty())
        .map(|(i, line)| {
            let bad = |reason: String| format!("{} line {}: {reason}", path.display(), i + 1);
            let v: Value = serde_json::from_str(line).map_err(|e| bad(e.to_string()))?;
            let kind = v["kind"]
                .as_str()
                .ok_or_else(|| bad("field kind missing".into()))?;
            let seq = v["seq"].as_u64();
            let time_s = match seq {
                Some(seq) => seq as f64 * ts,
                None => v["t_s"].as_f64().unwrap_or(0.0),
            };
            let detail = match &v["detail"] {
                Value::Null => String::new(),
                Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            Ok(Event {
                time_s,
                kind: kind.to_string(),
                role: v["role"].as_str().unwrap_or("?").to_string(),
                generation: v["generation"].as_u64().unwrap_or(0),
                seq,
                detail: shorten(&detail, 120),
            })
        })
        .collect()
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

    #[test]
    fn events_are_read_and_a_bad_line_is_named() {
        let dir =
            std::env::temp_dir().join(format!("flexloop-report-events-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("events.jsonl");
        std::fs::write(
            &path,
            "{\"t_s\":1.5,\"kind\":\"swap\",\"role\":\"controller\",\"generation\":2,\"seq\":2000,\"detail\":{\"ok\":true}}\n\
             {\"t_s\":2.5,\"kind\":\"crash\",\"role\":\"observer\",\"generation\":1,\"seq\":null,\"detail\":\"signal 9\"}\n",
        )
        .unwrap();
        let events = read_events(&path, 1e-4).unwrap();
        assert_eq!(events.len(), 2);
        assert!((events[0].time_s - 0.2).abs() < 1e-12, "placed by its tick");
        assert_eq!(events[0].detail, "{\"ok\":true}");
        assert_eq!(events[1].time_s, 2.5);
        std::fs::write(&path, "{\"kind\":\"swap\"}\nnot json\n").unwrap();
        let e = read_events(&path, 1e-4).unwrap_err();
        assert!(e.contains("events.jsonl line 2"), "{e}");
        assert!(
            read_events(&dir.join("absent.jsonl"), 1e-4)
                .unwrap()
                .is_empty()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_missing_run_is_named() {
        let e = resolve_run(Path::new("no-such-run-xyz")).unwrap_err();
        assert!(
            e.contains("no-such-run-xyz: no such run directory (nor runs/no-such-run-xyz)"),
            "{e}"
        );
    }
}
