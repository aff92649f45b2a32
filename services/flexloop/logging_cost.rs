//! `flexloop bench --logging-cost`: the same loop run twice in one
//! invocation, with the logger recording every sample and without a logger
//! at all, both timed by the plant itself (its own histograms, from the
//! commands' stamps), so that the difference is what recording costs.

use crate::ab_table::Options;
use anyhow::{Context, bail};
use flexloop_runfiles::bench::LoggingCost;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::{PlantLatency, RunDir};
use flexloop_supervisor::launch::{prepare, resolve_scenario, stamped_run_dir, supervise};
use std::path::Path;

/// The goal for what logging may add at p99.99 (docs/benchmarks.md).
const GOAL_US: f64 = 5.0;

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
    let args = o.loop_args(scenario, run_dir);
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

    let cost = crate::ab_table::print(("logger on", &with), ("logger off", &without));
    println!(
        "\nlogging costs {:+.1} µs at the round trip's p99.99 ({:+.1} µs at p50); goal under {GOAL_US} µs: {}",
        cost.p9999_us,
        cost.p50_us,
        if cost.p9999_us < GOAL_US {
            "met"
        } else {
            "NOT met"
        }
    );
    println!("{}", crate::ab_table::NOISE_CAVEAT);
    let document = LoggingCost {
        scenario: scenario.display().to_string(),
        duration_s: o.duration_s,
        with_logger: with,
        without_logger: without,
        round_trip_p9999_cost_us: cost.p9999_us,
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
