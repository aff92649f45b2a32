//! `flexloop bench --logging-cost`: the same loop run twice in one
//! invocation, with the logger recording every sample and without a logger
//! at all, both timed by the plant itself (its own histograms, from the
//! commands' stamps), so that the difference is what recording costs.

use crate::bench::BenchArgs;
use crate::launch::{LoopArgs, prepare, resolve_scenario, stamped_run_dir, supervise};
use anyhow::{Context, bail};
use flexloop_runfiles::bench::LoggingCost;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::{PlantLatency, RunDir};
use flexloop_runtime::latency::Metric;
use flexloop_scenario::{Mode, Overrides};
use std::path::{Path, PathBuf};

/// The goal for what logging may add at p99.99.
const GOAL_US: f64 = 5.0;

pub struct Options {
    scenario: Option<PathBuf>,
    duration_s: f64,
    rate_hz: Option<f64>,
    no_realtime: bool,
    tick: Option<flexloop_scenario::TickWait>,
    out: Option<PathBuf>,
}

impl Options {
    /// `bench --logging-cost`'s options, checked.
    pub fn from_args(args: &BenchArgs) -> anyhow::Result<Self> {
        let o = args.overrides;
        let positive = |flag: &str, v: Option<f64>| match v {
            Some(x) if !(x.is_finite() && x > 0.0) => {
                bail!("{flag} needs a positive number, got {x}")
            }
            _ => Ok(v),
        };
        Ok(Options {
            scenario: args.scenario.clone(),
            duration_s: positive("--duration", o.duration_s)?.unwrap_or(10.0),
            rate_hz: positive("--rate", o.rate_hz)?,
            no_realtime: o.no_realtime,
            tick: o.tick,
            out: args.run_dir.clone(),
        })
    }
}

/// The scenario with `[logger] enabled = false` and no other logger setting
/// (none applies to a loop without one: the scenario check refuses them).
fn without_logger(text: &str, scenario: &Path) -> anyhow::Result<String> {
    let mut table: toml::Table = toml::from_str(text)?;
    flexloop_scenario::plant_description::anchor_files(&mut table, scenario);
    let mut logger = toml::Table::new();
    logger.insert("enabled".into(), false.into());
    table.insert("logger".into(), logger.into());
    if let Some(realtime) = table.get_mut("realtime").and_then(|v| v.as_table_mut()) {
        realtime.remove("logger");
    }
    Ok(toml::to_string(&table)?)
}

/// One run; the plant's own figures.
fn run_once(o: &Options, scenario: &Path, run_dir: &Path) -> anyhow::Result<PlantLatency> {
    let args = LoopArgs {
        scenario: scenario.to_path_buf(),
        overrides: Overrides {
            rate_hz: o.rate_hz,
            duration_s: Some(o.duration_s),
            mode: Some(Mode::Realtime),
            no_realtime: o.no_realtime,
            tick: o.tick,
        },
        run_dir: Some(run_dir.to_path_buf()),
    };
    supervise(prepare(&args)?, |_, _| None)?;
    Ok(RunDir::new(run_dir).read_plant_latency()?)
}

pub fn logging_cost(o: Options) -> anyhow::Result<i32> {
    let scenario = resolve_scenario(o.scenario.clone())?;
    let text =
        std::fs::read_to_string(&scenario).with_context(|| scenario.display().to_string())?;
    let root = o
        .out
        .clone()
        .unwrap_or_else(|| stamped_run_dir("logging-cost"));
    std::fs::create_dir_all(&root).with_context(|| root.display().to_string())?;
    let silent = root.join("without-logger.toml");
    let silent_text =
        without_logger(&text, &scenario).with_context(|| scenario.display().to_string())?;
    std::fs::write(&silent, silent_text).with_context(|| silent.display().to_string())?;
    eprintln!(
        "flexloop bench --logging-cost: {} for {} s with the logger, then {} s without; runs in {}",
        scenario.display(),
        o.duration_s,
        o.duration_s,
        root.display()
    );
    let with = run_once(&o, &scenario, &root.join("with-logger"))?;
    if flexloop_runtime::shutdown::requested() {
        bail!("interrupted");
    }
    let without = run_once(&o, &silent, &root.join("without-logger"))?;

    println!(
        "\n{:<30}{:>9}{:>8}{:>9}{:>9}{:>9}{:>9}{:>9}{:>9}   (µs, the plant's own histograms)",
        "", "ticks", "misses", "p50", "p90", "p99", "p99.9", "p99.99", "max"
    );
    let row = |name: &str, run: &PlantLatency, metric: Metric| {
        let [p50, p90, p99, p999, p9999, max] = run
            .latency(metric.name())
            .percentiles
            .values()
            .map(|ns| ns as f64 / 1e3);
        println!(
            "{:<30}{:>9}{:>8}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}",
            name, run.ticks, run.counters.misses, p50, p90, p99, p999, p9999, max
        );
    };
    row("round trip, logger on", &with, Metric::RoundTrip);
    row("round trip, logger off", &without, Metric::RoundTrip);
    row("tick -> u(k), logger on", &with, Metric::TickToCommand);
    row("tick -> u(k), logger off", &without, Metric::TickToCommand);
    row("tick lateness, logger on", &with, Metric::TickLateness);
    row("tick lateness, logger off", &without, Metric::TickLateness);
    let round_trip = |run: &PlantLatency| run.latency(Metric::RoundTrip.name()).percentiles;
    let p9999 = |run: &PlantLatency| round_trip(run).p99_99 as f64 / 1e3;
    let p50 = |run: &PlantLatency| round_trip(run).p50 as f64 / 1e3;
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
    let document = LoggingCost {
        scenario: scenario.display().to_string(),
        duration_s: o.duration_s,
        with_logger: with,
        without_logger: without,
        round_trip_p9999_cost_us: cost,
        goal_us: GOAL_US,
    };
    let path = root.join("logging_cost.json");
    write_json_atomically(&path, &document)?;
    println!("{}", path.display());
    Ok(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_copy_turns_the_logger_off_and_drops_its_settings() {
        let plain = "name = \"x\"\n[loop]\nrate_hz = 1000\n";
        let off: toml::Table =
            toml::from_str(&without_logger(plain, Path::new("s.toml")).unwrap()).unwrap();
        assert_eq!(off["logger"]["enabled"].as_bool(), Some(false));
        let with_tables = "name = \"x\"\n[logger]\nenabled = true\n[loop]\nrate_hz = 1000\n\
                           [realtime.logger]\npriority = 10\n[realtime.plant]\npriority = 80\n";
        let off: toml::Table =
            toml::from_str(&without_logger(with_tables, Path::new("s.toml")).unwrap()).unwrap();
        assert_eq!(off["logger"].as_table().unwrap().len(), 1);
        assert_eq!(off["logger"]["enabled"].as_bool(), Some(false));
        assert!(off["realtime"].get("logger").is_none());
        assert_eq!(off["realtime"]["plant"]["priority"].as_integer(), Some(80));
        assert_eq!(off["loop"]["rate_hz"].as_integer(), Some(1000));
    }
}
