//! The run summary the logger writes (`summary.json`) and the plant's own
//! figures (`plant_latency.json`), from their counters and histograms (the
//! files' types: [`flexloop_runfiles::summary`]).

use flexloop_recording::{RecordSink, Recorder};
use flexloop_runfiles::summary::{Counters, PerChannel, PlantCounters, Recording};
use flexloop_runfiles::{Histogram, Percentiles, PlantLatency, RunSummary};
use flexloop_runtime::latency::{LatencyHistogram, LoopLatencies, Metric, PlantLatencies};
use std::collections::BTreeMap;

/// Count, percentiles and how many samples exceeded `budget_ns`.
fn histogram(h: &LatencyHistogram, budget_ns: u64) -> Histogram {
    let p = h.percentiles();
    Histogram {
        count: p.count,
        percentiles: Percentiles::from_values(p.values_ns),
        over_one_period: Some(h.count_above(budget_ns)),
    }
}

/// Count and percentiles, without a budget (the machine's floors).
pub fn floor_histogram(h: &LatencyHistogram) -> Histogram {
    let p = h.percentiles();
    Histogram {
        count: p.count,
        percentiles: Percentiles::from_values(p.values_ns),
        over_one_period: None,
    }
}

/// Every metric by name, plus how many samples exceeded `budget_ns`.
pub fn latencies(latencies: &LoopLatencies, budget_ns: u64) -> BTreeMap<String, Histogram> {
    Metric::ALL
        .iter()
        .map(|m| {
            (
                m.name().to_string(),
                histogram(latencies.get(*m), budget_ns),
            )
        })
        .collect()
}

/// What the plant measured itself: its counters and its latencies (the
/// same metric names as the logger's summary) and how it waited for its
/// ticks.
pub fn plant_latency(
    counters: &flexloop_components::plant::PlantCounters,
    latencies: &PlantLatencies,
    period_ns: u64,
    tick_wait: Option<flexloop_runfiles::TickWaitReport>,
) -> PlantLatency {
    let own = [
        (Metric::TickLateness, &latencies.tick_lateness),
        (Metric::RoundTrip, &latencies.round_trip),
        (Metric::TickToCommand, &latencies.tick_to_command),
    ];
    PlantLatency {
        ticks: counters.ticks,
        counters: PlantCounters {
            misses: counters.misses,
            late_commands: counters.late_commands,
            stalled_ticks: counters.stalled_ticks,
            stall_misses: counters.stall_misses,
            clamped: counters.clamped,
            non_finite: counters.non_finite,
        },
        latency: own
            .into_iter()
            .map(|(m, h)| (m.name().to_string(), histogram(h, period_ns)))
            .collect(),
        tick_wait,
    }
}

/// The whole summary of a run, from the logger's recorder; the recording's
/// account comes from the writer thread.
pub fn run_summary<O: RecordSink>(
    recorder: &Recorder<O>,
    scenario: &flexloop_scenario::Scenario,
    period_ns: u64,
    logger_cpu_ns: u64,
    recording: Recording,
) -> RunSummary {
    let m = recorder.last_measurement.unwrap_or_default();
    RunSummary {
        scenario: scenario.name.clone(),
        scenario_file: scenario.source.display().to_string(),
        mode: scenario.timing.mode.as_str().to_string(),
        rate_hz: scenario.timing.rate_hz,
        duration_s: scenario.timing.duration_s,
        period_ns,
        ticks: recorder.measurements.samples + recorder.measurements.gaps(),
        last_seq: m.seq,
        counters: Counters {
            misses: m.misses,
            late_commands: m.late_commands,
            stalled_ticks: m.stalled_ticks,
            stall_misses: m.stall_misses,
            stale_estimates: recorder.stale_estimates,
            fallback_ticks: m.fallback_ticks,
            rejected_commands: m.rejected_commands,
            foreign_commands: recorder.foreign_commands,
        },
        samples: PerChannel {
            measurement: recorder.measurements.samples,
            estimate: recorder.estimates.samples,
            command: recorder.commands.samples,
        },
        gaps: {
            let never_sent = recorder.never_sent().map(|r| r.map_or(0, |(_, n)| n));
            PerChannel {
                measurement: recorder.measurements.gaps(),
                estimate: recorder.estimates.gaps() + never_sent[1],
                command: recorder.commands.gaps()
                    + never_sent[2]
                    + recorder.never_sent_at_start().map_or(0, |(_, n)| n),
            }
        },
        logger_cpu_ns,
        latency: latencies(&recorder.latencies, period_ns),
        recording,
        generations: Vec::new(),
        outages: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use flexloop_runfiles::Percentiles;
    use flexloop_runfiles::summary::SampleFileState;
    use flexloop_runtime::latency::QUANTILE_LABELS;

    #[test]
    fn the_sample_writers_account_reads_as_the_summarys_type() {
        let path = std::env::temp_dir().join(format!("flexloop-state-{}.mcap", std::process::id()));
        let mut writer = flexloop_recording::SampleWriter::create(&path, 0).unwrap();
        writer.finish();
        let json = writer.recording_json();
        let _ = std::fs::remove_file(&path);
        let state: SampleFileState = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(state.state, "complete");
        assert_eq!(serde_json::to_value(&state).unwrap(), json);
    }

    #[test]
    fn the_files_percentile_keys_are_the_runtimes_labels() {
        let v = serde_json::to_value(Percentiles::from_values([1, 2, 3, 4, 5, 6])).unwrap();
        for (i, label) in QUANTILE_LABELS.iter().enumerate() {
            assert_eq!(v[format!("{label}_ns")], i as u64 + 1, "{label}");
        }
    }
}
