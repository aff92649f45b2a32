//! The run summary the logger writes (`summary.json`) and `flexloop` reads.

use flexloop_components::{RecordSink, Recorder};
use flexloop_runtime::latency::{
    LatencyHistogram, LoopLatencies, Metric, PlantLatencies, QUANTILE_LABELS,
};
use serde_json::{Value, json};
use std::io::Write;

/// The plant's own latency file in the run directory (written at its exit).
pub const PLANT_LATENCY_FILE: &str = "plant_latency.json";

/// Count, percentiles and how many samples exceeded `budget_ns`.
fn histogram_json(h: &LatencyHistogram, budget_ns: u64) -> Value {
    let p = h.percentiles();
    let mut entry = serde_json::Map::new();
    entry.insert("count".into(), json!(p.count));
    for (label, value) in QUANTILE_LABELS.iter().zip(p.values_ns) {
        entry.insert(format!("{label}_ns"), json!(value));
    }
    entry.insert("over_one_period".into(), json!(h.count_above(budget_ns)));
    Value::Object(entry)
}

/// Percentiles of every metric, plus how many samples exceeded `budget_ns`.
pub fn latencies_json(latencies: &LoopLatencies, budget_ns: u64) -> Value {
    let mut map = serde_json::Map::new();
    for metric in Metric::ALL {
        map.insert(
            metric.name().into(),
            histogram_json(latencies.get(metric), budget_ns),
        );
    }
    Value::Object(map)
}

/// What the plant measured itself: its counters and its latencies (the
/// same metric names as the logger's summary).
pub fn plant_latency_json(
    counters: &flexloop_components::plant::PlantCounters,
    latencies: &PlantLatencies,
    period_ns: u64,
) -> Value {
    json!({
        "ticks": counters.ticks,
        "counters": {
            "misses": counters.misses,
            "late_commands": counters.late_commands,
            "stalled_ticks": counters.stalled_ticks,
            "stall_misses": counters.stall_misses,
        },
        "latency": {
            Metric::TickLateness.name(): histogram_json(&latencies.tick_lateness, period_ns),
            Metric::RoundTrip.name(): histogram_json(&latencies.round_trip, period_ns),
            Metric::TickToCommand.name(): histogram_json(&latencies.tick_to_command, period_ns),
        },
    })
}

/// The whole summary of a run, from the logger's recorder.
pub fn run_summary<O: RecordSink>(
    recorder: &Recorder<O>,
    scenario: &flexloop_scenario::Scenario,
    period_ns: u64,
    logger_cpu_ns: u64,
) -> Value {
    let m = recorder.last_measurement.unwrap_or_default();
    json!({
        "scenario": scenario.name,
        "scenario_file": scenario.source.display().to_string(),
        "mode": scenario.timing.mode.as_str(),
        "rate_hz": scenario.timing.rate_hz,
        "duration_s": scenario.timing.duration_s,
        "period_ns": period_ns,
        "ticks": recorder.measurements.samples,
        "last_seq": m.seq,
        "counters": {
            "misses": m.misses,
            "late_commands": m.late_commands,
            "stalled_ticks": m.stalled_ticks,
            "stall_misses": m.stall_misses,
            "stale_estimates": recorder.stale_estimates,
            "fallback_ticks": m.fallback_ticks,
            "rejected_commands": m.rejected_commands,
        },
        "samples": {
            "measurement": recorder.measurements.samples,
            "estimate": recorder.estimates.samples,
            "command": recorder.commands.samples,
        },
        "gaps": {
            "measurement": recorder.measurements.gaps(),
            "estimate": recorder.estimates.gaps(),
            "command": recorder.commands.gaps(),
        },
        "logger_cpu_ns": logger_cpu_ns,
        "latency": latencies_json(&recorder.latencies, period_ns),
    })
}

/// Reads a run directory's `summary.json`; the error names the file.
pub fn read_summary(run_dir: &std::path::Path) -> Result<Value, String> {
    let path = run_dir.join(crate::logger::SUMMARY_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// Writes `value` to `path` atomically (temporary file, then rename), so that
/// a reader never sees a half-written summary.
pub fn write_json_atomically(path: &std::path::Path, value: &Value) -> std::io::Result<()> {
    let tmp = path.with_extension("json.tmp");
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(serde_json::to_string_pretty(value)?.as_bytes())?;
        f.write_all(b"\n")?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}
