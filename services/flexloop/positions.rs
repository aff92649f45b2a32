//! `flexloop positions [SCENARIO...]`: Table 4.1 of the thesis. Each case
//! (scenario) runs its scan with the world-fixed sensor at 29 positions along
//! the chain, 0 = ma … 7 = m7 (control.md §1.4), and the table gives min /
//! mean / max of the scan rms of e_true beside the thesis' values.
//!
//! By default the runs use the in-process loop (the processes' cores in
//! lockstep, bit-identical to `flexloop run --mode lockstep`); `--processes`
//! runs every position through the real processes in lockstep instead. The
//! feed-forward error is discussed in flexloop_analysis::positions.

use crate::{LoopArgs, prepare, run_registered_with};
use flexloop_analysis::feedforward_fit::FittedFeedforward;
use flexloop_analysis::positions::{
    FeedforwardChoice, PositionError, PositionRms, PositionScan, position_scan, scenario_at,
    sensor_positions, thesis_table_4_1,
};
use flexloop_runtime::shutdown;
use flexloop_scenario::{Mode, Overrides, Scenario};
use serde_json::json;
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The seven cases of Table 4.1, in the thesis' order.
const CASES: [&str; 7] = [
    "thesis-original",
    "thesis-mc",
    "thesis-ad",
    "thesis-mc-ad",
    "thesis-mc-redesigned",
    "thesis-ad-redesigned",
    "thesis-mc-ad-redesigned",
];

struct Options {
    scenarios: Vec<PathBuf>,
    json: bool,
    each: bool,
    processes: bool,
    keep_logs: bool,
    per_span: usize,
    /// Explicit positions (`--at`), in place of the grid.
    at: Option<Vec<f64>>,
    feedforward: FeedforwardChoice,
    run_dir: Option<PathBuf>,
}

fn parse(args: Vec<OsString>) -> Result<Options, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut o = Options {
        scenarios: Vec::new(),
        json: false,
        each: false,
        processes: false,
        keep_logs: false,
        per_span: 4,
        at: None,
        feedforward: FeedforwardChoice::ComplianceShifted,
        run_dir: None,
    };
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Value(v) => o.scenarios.push(PathBuf::from(v)),
            Long("json") => o.json = true,
            Long("each") => o.each = true,
            Long("processes") => o.processes = true,
            Long("keep-logs") => o.keep_logs = true,
            Long("per-span") => {
                let v = parser.value().map_err(|e| e.to_string())?;
                o.per_span = v
                    .to_str()
                    .and_then(|s| s.parse::<usize>().ok())
                    .filter(|n| (1..=100).contains(n))
                    .ok_or_else(|| format!("--per-span needs a whole number 1..=100, got {v:?}"))?;
            }
            Long("at") => {
                let v = parser.value().map_err(|e| e.to_string())?;
                let text = v.to_string_lossy();
                let list = text
                    .split(',')
                    .map(|p| p.trim().parse::<f64>())
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|_| format!("--at needs positions like 4.25,5 got `{text}`"))?;
                o.at = Some(list);
            }
            Long("feedforward") => {
                let v = parser.value().map_err(|e| e.to_string())?;
                let text = v.to_string_lossy();
                o.feedforward = FeedforwardChoice::parse(&text).ok_or_else(|| {
                    format!(
                        "--feedforward is compliance-shifted, as-tuned or mass-only, got `{text}`"
                    )
                })?;
            }
            Long("run-dir") => {
                o.run_dir = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?))
            }
            other => return Err(other.unexpected().to_string()),
        }
    }
    Ok(o)
}

pub fn positions(args: Vec<OsString>) -> Result<i32, String> {
    let o = parse(args)?;
    let paths: Vec<PathBuf> = if o.scenarios.is_empty() {
        CASES
            .iter()
            .map(|name| crate::resolve_scenario(Some(PathBuf::from(name))))
            .collect::<Result<_, _>>()?
    } else {
        o.scenarios
            .iter()
            .map(|p| crate::resolve_scenario(Some(p.clone())))
            .collect::<Result<_, _>>()?
    };
    let positions = o.at.clone().unwrap_or_else(|| sensor_positions(o.per_span));
    let mut scans = Vec::new();
    for path in &paths {
        if shutdown::requested() {
            return Err("interrupted".into());
        }
        let s = Scenario::load(path, &Overrides::default()).map_err(|e| e.to_string())?;
        if s.plant.model != "thesis-chain" {
            return Err(format!(
                "scenario {}: field `plant.model`: positions are along the thesis chain, not `{}`",
                path.display(),
                s.plant.model
            ));
        }
        eprintln!(
            "flexloop positions: {} at {} positions{}",
            s.name,
            positions.len(),
            if o.processes {
                " through the processes"
            } else {
                ""
            }
        );
        let scan = if o.processes {
            through_processes(
                path,
                &s,
                &positions,
                o.feedforward,
                o.run_dir.as_deref(),
                o.keep_logs,
            )?
        } else {
            position_scan(&s, &positions, o.feedforward).map_err(|e| in_file(path, e))?
        };
        scans.push(scan);
    }
    if o.json {
        let cases: Vec<_> = scans
            .iter()
            .map(|scan| {
                json!({
                    "scan": scan,
                    "thesis_nm": thesis_table_4_1(&scan.scenario),
                })
            })
            .collect();
        let out = json!({
            "positions": positions,
            "feedforward": o.feedforward,
            "runs": if o.processes { "processes-lockstep" } else { "in-process" },
            "unit": "m",
            "cases": cases,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&scans, &positions, &o);
    }
    Ok(0)
}

fn in_file(path: &Path, e: PositionError) -> String {
    match e {
        // The design error already names the file and the field.
        PositionError::Design { .. } | PositionError::NoScan(_) => e.to_string(),
        PositionError::Loop { .. } => format!("{}: {e}", path.display()),
    }
}

fn print_table(scans: &[PositionScan], positions: &[f64], o: &Options) {
    println!(
        "rms e_true over the scan [nm], sensor at {} positions {}..{} (0 = ma, 1..7 = m1..m7), \
         feedforward {}, {}",
        positions.len(),
        positions.first().copied().unwrap_or_default(),
        positions.last().copied().unwrap_or_default(),
        match o.feedforward {
            FeedforwardChoice::AsTuned => "as tuned at the scenario's output",
            FeedforwardChoice::MassOnly => "mass only (acc = 12.5)",
            FeedforwardChoice::ComplianceShifted =>
                "as tuned, snap shifted by the compliance difference",
        },
        if o.processes {
            "processes in lockstep"
        } else {
            "in-process lockstep"
        }
    );
    println!(
        "{:<26} {:>8} {:>8} {:>8}   {:>8} {:>8} {:>8}",
        "case", "min", "mean", "max", "thesis", "", ""
    );
    let nm = |v: f64| v * 1e9;
    for scan in scans {
        let thesis = thesis_table_4_1(&scan.scenario)
            .map(|[a, b, c]| format!("{a:>8.3} {b:>8.3} {c:>8.3}"))
            .unwrap_or_default();
        println!(
            "{:<26} {:>8.3} {:>8.3} {:>8.3}   {thesis}",
            scan.scenario,
            nm(scan.min),
            nm(scan.mean),
            nm(scan.max)
        );
        if o.each {
            for run in &scan.runs {
                println!("    at {:>5.2}: {:>8.3}", run.position, nm(run.rms_e_true));
            }
        }
    }
}

/// Every position as its own `flexloop run --mode lockstep`: a copy of the
/// scenario file with `sensor_position` in its `[plant]` table, started,
/// supervised and read back by the same code as `flexloop run`.
fn through_processes(
    path: &Path,
    s: &Scenario,
    positions: &[f64],
    feedforward: FeedforwardChoice,
    root: Option<&Path>,
    keep_logs: bool,
) -> Result<PositionScan, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let root = root.map(Path::to_path_buf).unwrap_or_else(|| {
        PathBuf::from("runs").join(format!("{stamp}-positions-{}", std::process::id()))
    });
    let mut runs = Vec::with_capacity(positions.len());
    for &position in positions {
        if shutdown::requested() {
            return Err("interrupted".into());
        }
        let name = format!("{}-p{position:.2}", s.name);
        let run_dir = root.join(&name);
        std::fs::create_dir_all(&root).map_err(|e| format!("{}: {e}", root.display()))?;
        let file = root.join(format!("{name}.toml"));
        std::fs::write(&file, with_sensor_position(&text, position))
            .map_err(|e| format!("{}: {e}", file.display()))?;
        if feedforward != FeedforwardChoice::AsTuned {
            let ff = scenario_at(s, position, feedforward)
                .map_err(|e| e.to_string())?
                .controller
                .feedforward
                .unwrap_or_default();
            crate::run::write_feedforward(
                &file,
                &FittedFeedforward {
                    snap: ff.snap,
                    jerk: ff.jerk,
                    acc: ff.acc,
                    vel: ff.vel,
                    rms_before: 0.0,
                    rms_after_predicted: 0.0,
                    samples: 0,
                },
            )?;
        }
        let rms_e_true = run_position(&file, &run_dir, &name, path, keep_logs)?;
        runs.push(PositionRms {
            position,
            rms_e_true,
        });
    }
    eprintln!("flexloop positions: runs in {}", root.display());
    Ok(PositionScan::new(s.name.clone(), feedforward, runs))
}

/// Lockstep runs are deterministic, but the logger is not part of the lockstep:
/// on a busy machine it can miss samples, and metrics over a log with holes
/// would not be the run's. Such a run is repeated.
const ATTEMPTS: u32 = 3;

/// One position through the processes; rms of e_true over the scan [m].
fn run_position(
    file: &Path,
    run_dir: &Path,
    name: &str,
    source: &Path,
    keep_logs: bool,
) -> Result<f64, String> {
    let mut last_gaps = 0;
    for _ in 0..ATTEMPTS {
        // Each attempt starts from an empty directory.
        let _ = std::fs::remove_dir_all(run_dir);
        let args = LoopArgs {
            scenario: file.to_path_buf(),
            overrides: Overrides {
                mode: Some(Mode::Lockstep),
                // Lockstep results do not depend on scheduling.
                no_realtime: true,
                ..Overrides::default()
            },
            run_dir: Some(run_dir.to_path_buf()),
            probes: false,
            swap_every_s: None,
        };
        let prepared = prepare(&args)?;
        run_registered_with(prepared, |_, _| None).map_err(|e| format!("{name}: {e}"))?;
        let report = crate::run::RunReport::load(run_dir)?;
        let gaps: u64 = ["measurement", "estimate", "command"]
            .iter()
            .map(|k| report.summary["gaps"][k].as_u64().unwrap_or(0))
            .sum::<u64>()
            + report.trace.incomplete_ticks;
        if gaps > 0 {
            last_gaps = gaps;
            eprintln!(
                "flexloop positions: {name}: the log missed {gaps} samples; running it again"
            );
            continue;
        }
        let rms = report.metrics.rms_e_true_scan.ok_or_else(|| {
            format!(
                "{}: field `reference.shape`: no complete scan in the run",
                source.display()
            )
        })?;
        let metrics = run_dir.join(crate::run::METRICS_FILE);
        flexloop_node::summary::write_json_atomically(&metrics, &report.to_json())
            .map_err(|e| format!("{}: {e}", metrics.display()))?;
        if !keep_logs {
            // ~5 MB per position, 1 GB for the whole table; the summary and
            // the metrics stay.
            let _ = std::fs::remove_file(run_dir.join(flexloop_node::logger::SAMPLES_FILE));
        }
        return Ok(rms);
    }
    Err(format!(
        "{name}: the log of {} missed {last_gaps} samples in each of {ATTEMPTS} runs \
         (a busy machine); the in-process table (without --processes) is the same loop",
        run_dir.display()
    ))
}

/// The scenario text with the sensor at `position`: `output` and any
/// `sensor_position` of the `[plant]` table replaced (everything else as
/// written, so that the run's copy reads like the original).
fn with_sensor_position(text: &str, position: f64) -> String {
    let mut out = String::with_capacity(text.len() + 40);
    let mut in_plant = false;
    for line in text.lines() {
        let trimmed = line.trim_start();
        if trimmed.starts_with('[') {
            in_plant = trimmed.trim_end() == "[plant]";
            out.push_str(line);
            out.push('\n');
            if in_plant {
                out.push_str(&format!("sensor_position = {position:?}\n"));
            }
            continue;
        }
        let key = trimmed.split('=').next().unwrap_or("").trim();
        if in_plant && (key == "output" || key == "sensor_position") {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_copy_names_the_position_instead_of_the_output() {
        let text = "name = \"t\"\n[loop]\nrate_hz = 10000\n[plant]\nmodel = \"thesis-chain\"\n\
                    output = 5\ninput_limit = 2000\n[observer]\ndesign = \"none\"\nmc = false\n";
        let out = with_sensor_position(text, 4.25);
        assert!(
            out.contains("[plant]\nsensor_position = 4.25\nmodel"),
            "{out}"
        );
        assert!(!out.contains("output = 5"), "{out}");
        // Only the plant table is touched.
        assert!(
            out.contains("[observer]\ndesign = \"none\"\nmc = false\n"),
            "{out}"
        );
        let s = Scenario::parse(Path::new("t.toml"), &out).unwrap();
        assert_eq!(s.plant.sensor_position, Some(4.25));
        assert!(!s.plant.output_given);
        // Whole numbers stay floats in TOML.
        assert!(with_sensor_position(text, 5.0).contains("sensor_position = 5.0\n"));
    }
}
