//! Two runs of the same loop side by side, by the plant's own histograms
//! (`bench --logging-cost`, `bench --live-cost`): their options, the table
//! they print and the difference at the round trip's p50 and p99.99.

use anyhow::bail;
use flexloop_node::overrides::OverrideFlags;
use flexloop_runfiles::PlantLatency;
use flexloop_runtime::latency::Metric;
use flexloop_scenario::{Mode, Overrides};
use flexloop_supervisor::launch::LoopArgs;
use std::path::{Path, PathBuf};

/// A two-run comparison's options (`bench --logging-cost`, `--live-cost`).
pub struct Options {
    pub scenario: Option<PathBuf>,
    pub duration_s: f64,
    pub rate_hz: Option<f64>,
    pub no_realtime: bool,
    pub tick: Option<flexloop_scenario::TickWait>,
    pub out: Option<PathBuf>,
}

impl Options {
    /// One of the two runs: realtime, for the options' duration.
    pub fn loop_args(&self, scenario: &Path, run_dir: &Path) -> LoopArgs {
        LoopArgs {
            scenario: scenario.to_path_buf(),
            overrides: Overrides {
                rate_hz: self.rate_hz,
                duration_s: Some(self.duration_s),
                mode: Some(Mode::Realtime),
                no_realtime: self.no_realtime,
                tick: self.tick,
            },
            run_dir: Some(run_dir.to_path_buf()),
        }
    }

    /// The bench's options for a comparison (its scenario, overrides and
    /// run directory flags), checked.
    pub fn from_args(
        scenario: Option<PathBuf>,
        o: &OverrideFlags,
        run_dir: Option<PathBuf>,
    ) -> anyhow::Result<Self> {
        let positive = |flag: &str, v: Option<f64>| match v {
            Some(x) if !(x.is_finite() && x > 0.0) => {
                bail!("{flag} needs a positive number, got {x}")
            }
            _ => Ok(v),
        };
        Ok(Options {
            scenario,
            duration_s: positive("--duration", o.duration_s)?.unwrap_or(10.0),
            rate_hz: positive("--rate", o.rate_hz)?,
            no_realtime: o.no_realtime,
            tick: o.tick,
            out: run_dir,
        })
    }
}

/// What the two runs' difference is worth on a shared machine.
pub const NOISE_CAVEAT: &str = "(one run each, one after the other: on a shared machine a stall in either moves p99.99 by more than this)";

/// The round trip's percentile differences `with − without` [µs].
pub struct Cost {
    pub p50_us: f64,
    pub p9999_us: f64,
}

/// Prints the round trip, tick → u(k) and tick lateness of both runs, each
/// row named by its metric and the run's label; returns the cost.
pub fn print(with: (&str, &PlantLatency), without: (&str, &PlantLatency)) -> Cost {
    let width = 18 + with.0.len().max(without.0.len());
    println!(
        "\n{:<width$}{:>9}{:>8}{:>9}{:>9}{:>9}{:>9}{:>9}{:>9}   (µs, the plant's own histograms)",
        "", "ticks", "misses", "p50", "p90", "p99", "p99.9", "p99.99", "max"
    );
    for (metric, name) in [
        (Metric::RoundTrip, "round trip"),
        (Metric::TickToCommand, "tick -> u(k)"),
        (Metric::TickLateness, "tick lateness"),
    ] {
        for (label, run) in [with, without] {
            let [p50, p90, p99, p999, p9999, max] = run
                .latency(metric.name())
                .percentiles
                .values()
                .map(|ns| ns as f64 / 1e3);
            println!(
                "{:<width$}{:>9}{:>8}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}",
                format!("{name}, {label}"),
                run.ticks,
                run.counters.misses,
                p50,
                p90,
                p99,
                p999,
                p9999,
                max
            );
        }
    }
    let round_trip = |run: &PlantLatency| run.latency(Metric::RoundTrip.name()).percentiles;
    let (a, b) = (round_trip(with.1), round_trip(without.1));
    Cost {
        p50_us: (a.p50 as f64 - b.p50 as f64) / 1e3,
        p9999_us: (a.p99_99 as f64 - b.p99_99 as f64) / 1e3,
    }
}
