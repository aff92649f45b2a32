//! `flexloop positions [SCENARIO...]`: Table 4.1 of the thesis. Each case
//! (scenario) runs its scan with the world-fixed sensor at 29 positions along
//! the chain, 0 = ma … 7 = m7 (docs/control.md §1.4), and the table gives min /
//! mean / max of the scan rms of e_true beside the thesis' values.
//!
//! By default the runs use the in-process loop (the processes' cores in
//! lockstep, bit-identical to `flexloop run --mode lockstep`); `--processes`
//! runs every position through the real processes in lockstep instead. The
//! feed-forward error is discussed in flexloop_analysis::positions.

use anyhow::{Context, anyhow, bail};
use flexloop_analysis::feedforward_fit::FittedFeedforward;
use flexloop_analysis::positions::{
    FeedforwardChoice, PositionError, PositionRms, PositionScan, position_scan, scenario_at,
    sensor_positions, thesis_table_4_1,
};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runtime::shutdown;
use flexloop_scenario::{Mode, Overrides, Scenario};
use flexloop_supervisor::launch::{
    LoopArgs, prepare, resolve_scenario, stamped_run_dir, supervise,
};
use serde_json::json;
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

/// `positions [SCENARIO...] [--per-span N | --at P,P...] [--feedforward F] [--processes] [--json] [--each]`.
#[derive(Debug, clap::Args)]
pub struct PositionsArgs {
    /// Scenarios of the thesis chain [default: the seven thesis cases]
    scenarios: Vec<PathBuf>,
    /// Print JSON instead of the table
    #[arg(long)]
    json: bool,
    /// Every position's rms under its case
    #[arg(long)]
    each: bool,
    /// Run every position through the processes in lockstep
    #[arg(long)]
    processes: bool,
    /// With --processes: keep every position's sample file
    #[arg(long)]
    keep_logs: bool,
    /// Positions per span between two masses: 7·N+1 in all
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=100))]
    per_span: u16,
    /// These positions instead of the grid (0 = ma, 1..7 = m1..m7)
    #[arg(long, value_name = "P,P...", value_delimiter = ',')]
    at: Option<Vec<f64>>,
    /// The feedforward at each position: compliance-shifted, as-tuned or mass-only
    #[arg(long, value_name = "F", default_value = "compliance-shifted", value_parser = feedforward_choice)]
    feedforward: FeedforwardChoice,
    /// With --processes: where the runs go [default: runs/<stamp>-positions-<pid>]
    #[arg(long, value_name = "DIR")]
    run_dir: Option<PathBuf>,
}

fn feedforward_choice(text: &str) -> Result<FeedforwardChoice, String> {
    FeedforwardChoice::parse(text).ok_or_else(|| {
        format!("--feedforward is compliance-shifted, as-tuned or mass-only, got `{text}`")
    })
}

pub fn positions(o: PositionsArgs) -> anyhow::Result<i32> {
    let given: Vec<PathBuf> = if o.scenarios.is_empty() {
        CASES.iter().map(PathBuf::from).collect()
    } else {
        o.scenarios.clone()
    };
    let paths = given
        .into_iter()
        .map(|p| resolve_scenario(Some(p)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let positions =
        o.at.clone()
            .unwrap_or_else(|| sensor_positions(usize::from(o.per_span)));
    let mut scans = Vec::new();
    for path in &paths {
        if shutdown::requested() {
            bail!("interrupted");
        }
        let s = Scenario::load(path, &Overrides::default())?;
        if s.plant.model != "thesis-chain" {
            bail!(
                "scenario {}: field `plant.model`: positions are along the thesis chain, not `{}`",
                path.display(),
                s.plant.model
            );
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
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_table(&scans, &positions, &o);
    }
    Ok(0)
}

fn in_file(path: &Path, e: PositionError) -> anyhow::Error {
    match e {
        // The design error already names the file and the field.
        PositionError::Design { .. } | PositionError::NoScan(_) => anyhow::Error::new(e),
        PositionError::Loop { .. } => anyhow::Error::new(e).context(path.display().to_string()),
    }
}

fn print_table(scans: &[PositionScan], positions: &[f64], o: &PositionsArgs) {
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
) -> anyhow::Result<PositionScan> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let root = root
        .map(Path::to_path_buf)
        .unwrap_or_else(|| stamped_run_dir("positions"));
    let mut runs = Vec::with_capacity(positions.len());
    for &position in positions {
        if shutdown::requested() {
            bail!("interrupted");
        }
        let name = format!("{}-p{position:.2}", s.name);
        let run_dir = RunDir::new(root.join(&name));
        std::fs::create_dir_all(&root).with_context(|| root.display().to_string())?;
        let file = root.join(format!("{name}.toml"));
        std::fs::write(&file, with_sensor_position(&text, position))
            .with_context(|| file.display().to_string())?;
        if feedforward != FeedforwardChoice::AsTuned {
            let ff = scenario_at(s, position, feedforward)?
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
    run_dir: &RunDir,
    name: &str,
    source: &Path,
    keep_logs: bool,
) -> anyhow::Result<f64> {
    let mut last_gaps = 0;
    for _ in 0..ATTEMPTS {
        // Each attempt starts from an empty directory.
        let _ = std::fs::remove_dir_all(run_dir.path());
        let args = LoopArgs {
            scenario: file.to_path_buf(),
            overrides: Overrides {
                mode: Some(Mode::Lockstep),
                // Lockstep results do not depend on scheduling.
                no_realtime: true,
                ..Overrides::default()
            },
            run_dir: Some(run_dir.path().to_path_buf()),
        };
        let prepared = prepare(&args)?;
        supervise(prepared, |_, _| None).with_context(|| name.to_string())?;
        let report = crate::run::RunReport::load(run_dir)?;
        let gaps = report.summary.gaps.total() + report.trace.incomplete_ticks;
        if gaps > 0 {
            last_gaps = gaps;
            eprintln!(
                "flexloop positions: {name}: the log missed {gaps} samples; running it again"
            );
            continue;
        }
        let rms = report.metrics.rms_e_true_scan.ok_or_else(|| {
            anyhow!(
                "{}: field `reference.shape`: no complete scan in the run",
                source.display()
            )
        })?;
        write_json_atomically(&run_dir.metrics(), &report.metrics_file())?;
        if !keep_logs {
            // ~5 MB per position, 1 GB for the whole table; the summary and
            // the metrics stay.
            let _ = std::fs::remove_file(run_dir.samples(0));
        }
        return Ok(rms);
    }
    bail!(
        "{name}: the log of {} missed {last_gaps} samples in each of {ATTEMPTS} runs \
         (a busy machine); the in-process table (without --processes) is the same loop",
        run_dir.path().display()
    )
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
