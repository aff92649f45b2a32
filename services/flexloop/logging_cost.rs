//! `flexloop bench --logging-cost`: the same loop run twice in one
//! invocation, with the logger recording every sample and without a logger
//! at all, both timed by the plant itself (its own histograms, from the
//! commands' stamps), so that the difference is what recording costs.

use crate::{LoopArgs, prepare, run_registered_with};
use flexloop_node::summary::{PLANT_LATENCY_FILE, write_json_atomically};
use flexloop_runtime::latency::QUANTILE_LABELS;
use flexloop_scenario::{Mode, Overrides};
use serde_json::{Value, json};
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The goal for what logging may add at p99.99.
const GOAL_US: f64 = 5.0;

const USAGE: &str = "flexloop bench --logging-cost [SCENARIO] [--duration S (10, per run)] [--rate HZ] [--no-realtime] [--run-dir DIR]";

struct Options {
    scenario: Option<PathBuf>,
    duration_s: f64,
    rate_hz: Option<f64>,
    no_realtime: bool,
    out: Option<PathBuf>,
}

fn parse(args: Vec<OsString>) -> Result<Options, String> {
    use lexopt::prelude::*;
    let mut o = Options {
        scenario: None,
        duration_s: 10.0,
        rate_hz: None,
        no_realtime: false,
        out: None,
    };
    let mut parser = lexopt::Parser::from_args(args);
    let number = |p: &mut lexopt::Parser, flag: &str| -> Result<f64, String> {
        let v = p.value().map_err(|e| e.to_string())?;
        v.to_str()
            .and_then(|s| s.parse::<f64>().ok())
            .filter(|x| x.is_finite() && *x > 0.0)
            .ok_or_else(|| format!("{flag} needs a positive number, got {v:?}"))
    };
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("logging-cost") => {}
            Value(v) if o.scenario.is_none() => o.scenario = Some(PathBuf::from(v)),
            Long("duration") => o.duration_s = number(&mut parser, "--duration")?,
            Long("rate") => o.rate_hz = Some(number(&mut parser, "--rate")?),
            Long("no-realtime") => o.no_realtime = true,
            Long("run-dir") => {
                o.out = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?))
            }
            other => return Err(format!("{}\nusage: {USAGE}", other.unexpected())),
        }
    }
    Ok(o)
}

/// The scenario text with `[logger] enabled = false` (an existing
/// `enabled` line of that table is replaced).
fn without_logger(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 32);
    let mut in_logger = false;
    let mut had_table = false;
    for line in text.lines() {
        let trimmed = line.trim_start();
        if trimmed.starts_with('[') {
            in_logger = trimmed.trim_end() == "[logger]";
            out.push_str(line);
            out.push('\n');
            if in_logger {
                had_table = true;
                out.push_str("enabled = false\n");
            }
            continue;
        }
        let key = trimmed.split('=').next().unwrap_or("").trim();
        if in_logger && key == "enabled" {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    if !had_table {
        out.push_str("\n[logger]\nenabled = false\n");
    }
    out
}

/// One run; the plant's own figures.
fn run_once(o: &Options, scenario: &Path, run_dir: &Path) -> Result<Value, String> {
    let args = LoopArgs {
        scenario: scenario.to_path_buf(),
        overrides: Overrides {
            rate_hz: o.rate_hz,
            duration_s: Some(o.duration_s),
            mode: Some(Mode::Realtime),
            no_realtime: o.no_realtime,
        },
        run_dir: Some(run_dir.to_path_buf()),
        probes: false,
        swap_every_s: None,
    };
    run_registered_with(prepare(&args)?, |_, _| None)?;
    let path = run_dir.join(PLANT_LATENCY_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

pub fn logging_cost(args: Vec<OsString>) -> Result<i32, String> {
    let o = parse(args)?;
    let scenario = crate::resolve_scenario(o.scenario.clone())?;
    let text =
        std::fs::read_to_string(&scenario).map_err(|e| format!("{}: {e}", scenario.display()))?;
    let root = o
        .out
        .clone()
        .unwrap_or_else(|| crate::stamped_run_dir("logging-cost"));
    std::fs::create_dir_all(&root).map_err(|e| format!("{}: {e}", root.display()))?;
    let silent = root.join("without-logger.toml");
    std::fs::write(&silent, without_logger(&text))
        .map_err(|e| format!("{}: {e}", silent.display()))?;
    eprintln!(
        "flexloop bench --logging-cost: {} for {} s with the logger, then {} s without; runs in {}",
        scenario.display(),
        o.duration_s,
        o.duration_s,
        root.display()
    );
    let with = run_once(&o, &scenario, &root.join("with-logger"))?;
    if flexloop_runtime::shutdown::requested() {
        return Err("interrupted".into());
    }
    let without = run_once(&o, &silent, &root.join("without-logger"))?;

    println!(
        "\n{:<30}{:>9}{:>8}{:>9}{:>9}{:>9}{:>9}{:>9}{:>9}   (µs, the plant's own histograms)",
        "", "ticks", "misses", "p50", "p90", "p99", "p99.9", "p99.99", "max"
    );
    let row = |name: &str, run: &Value, metric: &str| {
        let v = &run["latency"][metric];
        let us = |q: &str| v[format!("{q}_ns")].as_u64().unwrap_or(0) as f64 / 1e3;
        println!(
            "{:<30}{:>9}{:>8}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}",
            name,
            run["ticks"].as_u64().unwrap_or(0),
            run["counters"]["misses"].as_u64().unwrap_or(0),
            us(QUANTILE_LABELS[0]),
            us(QUANTILE_LABELS[1]),
            us(QUANTILE_LABELS[2]),
            us(QUANTILE_LABELS[3]),
            us(QUANTILE_LABELS[4]),
            us(QUANTILE_LABELS[5])
        );
    };
    row("round trip, logger on", &with, "round_trip");
    row("round trip, logger off", &without, "round_trip");
    row("tick -> u(k), logger on", &with, "tick_to_command");
    row("tick -> u(k), logger off", &without, "tick_to_command");
    row("tick lateness, logger on", &with, "tick_lateness");
    row("tick lateness, logger off", &without, "tick_lateness");
    let p9999 = |run: &Value| {
        run["latency"]["round_trip"]["p99.99_ns"]
            .as_u64()
            .unwrap_or(0) as f64
            / 1e3
    };
    let p50 =
        |run: &Value| run["latency"]["round_trip"]["p50_ns"].as_u64().unwrap_or(0) as f64 / 1e3;
    let cost = p9999(&with) - p9999(&without);
    println!(
        "\nlogging costs {:+.1} µs at the round trip's p99.99 ({:+.1} µs at p50); goal under {GOAL_US} µs: {}",
        cost,
        p50(&with) - p50(&without),
        if cost < GOAL_US { "met" } else { "NOT met" }
    );
    println!(
        "(one run each, one after the other: on a shared machine a stall in either moves p99.99 by more than this)"
    );
    let document = json!({
        "scenario": scenario.display().to_string(),
        "duration_s": o.duration_s,
        "with_logger": with,
        "without_logger": without,
        "round_trip_p9999_cost_us": cost,
        "goal_us": GOAL_US,
    });
    let path = root.join("logging_cost.json");
    write_json_atomically(&path, &document).map_err(|e| format!("{}: {e}", path.display()))?;
    println!("{}", path.display());
    Ok(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_copy_turns_the_logger_off_with_or_without_its_table() {
        let plain = "name = \"x\"\n[loop]\nrate_hz = 1000\n";
        let off = without_logger(plain);
        assert!(off.ends_with("[logger]\nenabled = false\n"), "{off}");
        let with_table = "name = \"x\"\n[logger]\nenabled = true\n[loop]\nrate_hz = 1000\n";
        let off = without_logger(with_table);
        assert_eq!(off.matches("enabled").count(), 1, "{off}");
        assert!(off.contains("[logger]\nenabled = false\n[loop]"), "{off}");
    }
}
