//! `summary.json`, the logger's account of a run, and `plant_latency.json`,
//! what the plant measured itself.

use crate::latency::Histogram;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `summary.json`: written by the logger at its exit, read by every command
/// that reports on a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// The scenario's name and the file it was loaded from.
    pub scenario: String,
    pub scenario_file: String,
    /// `realtime` or `lockstep`.
    pub mode: String,
    pub rate_hz: f64,
    pub duration_s: f64,
    pub period_ns: u64,
    /// The run's ticks from the first measurement recorded to the last:
    /// recorded (`samples.measurement`) or lost (`gaps.measurement`).
    pub ticks: u64,
    pub last_seq: u64,
    pub counters: Counters,
    pub samples: PerChannel,
    /// Samples the file lacks per channel: never received, or no room in
    /// the logger's writer queue.
    pub gaps: PerChannel,
    pub logger_cpu_ns: u64,
    /// Every latency metric by its name (`flexloop_runtime::latency::Metric::name`).
    pub latency: BTreeMap<String, Histogram>,
    /// The last logger's recording (one logger: the whole run's).
    pub recording: Recording,
    /// The logger generations this summary joins, in order; empty when one
    /// logger recorded the whole run and wrote this summary itself.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub generations: Vec<GenerationAccount>,
    /// Samples no logger recorded because none was running (between one
    /// logger's last recorded sample and its successor's first, or after
    /// the last one); counted in `gaps` too.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub outages: Vec<Outage>,
}

/// What one logger generation recorded.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GenerationAccount {
    pub generation: u32,
    /// Its sample file's name in the run directory.
    pub file: String,
    /// `complete`, `stopped` (a write failed) or `killed` (the logger died
    /// before it finished; its file was closed after its last complete chunk).
    pub state: String,
    /// Distinct sequence numbers its file holds per channel (samples a
    /// predecessor also holds count once, for the one before).
    pub samples: PerChannel,
    /// Its first and last measurement.
    pub first_seq: Option<u64>,
    pub last_seq: Option<u64>,
}

/// A run of samples of one channel that no logger recorded.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Outage {
    pub channel: String,
    /// The first missing sequence number and how many follow it.
    pub seq: u64,
    pub count: u64,
    /// The generation whose logger recorded last before it.
    pub after_generation: u32,
    /// The next generation, or none after the last logger.
    pub before_generation: Option<u32>,
}

impl RunSummary {
    /// The histogram of the metric named `name` (empty if the run has none).
    pub fn latency(&self, name: &str) -> Histogram {
        self.latency.get(name).copied().unwrap_or_default()
    }
}

/// The loop's counters, as the plant's last measurement and the logger saw them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counters {
    pub misses: u64,
    pub late_commands: u64,
    pub stalled_ticks: u64,
    pub stall_misses: u64,
    pub stale_estimates: u64,
    pub fallback_ticks: u64,
    pub rejected_commands: u64,
    /// Commands the logger saw from an instance that owned neither their
    /// sample nor a standby's duty (a stray or misbehaving program): not
    /// recorded, not in the latencies; the plant rejects them too.
    #[serde(default)]
    pub foreign_commands: u64,
}

/// One count per message channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PerChannel {
    pub measurement: u64,
    pub estimate: u64,
    pub command: u64,
}

impl PerChannel {
    /// The channels' names, in the order of [`PerChannel::get`].
    pub const NAMES: [&str; 3] = ["measurement", "estimate", "command"];

    pub fn total(&self) -> u64 {
        self.measurement + self.estimate + self.command
    }

    /// The count of the channel of index `i` (see [`PerChannel::NAMES`]).
    pub fn get(&self, i: usize) -> u64 {
        [self.measurement, self.estimate, self.command][i]
    }

    /// From the counts in channel order.
    pub fn from_array([measurement, estimate, command]: [u64; 3]) -> Self {
        Self {
            measurement,
            estimate,
            command,
        }
    }

    /// The counts in channel order (measurement, estimate, command).
    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut u64> {
        [&mut self.measurement, &mut self.estimate, &mut self.command].into_iter()
    }
}

/// How the sample file was written.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Recording {
    #[serde(flatten)]
    pub sample_file: SampleFileState,
    /// The sample file's name in the run directory.
    pub file: String,
    pub latency_log_complete: bool,
    /// Messages and events the logger had no room for in its writer queue.
    pub dropped_in_logger: DroppedInLogger,
}

/// The sample file's writer's own account (`flexloop_recording::SampleWriter`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SampleFileState {
    pub format: String,
    pub compression: String,
    /// `complete`, `stopped` (a write failed) or `recording`.
    pub state: String,
    pub messages: u64,
    pub stored_messages: u64,
    pub dropped_messages: u64,
    pub bytes: u64,
    /// Why writing stopped, if it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// How the file was closed after writing stopped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed: Option<ClosedFile>,
}

impl SampleFileState {
    pub fn stopped(&self) -> bool {
        self.state == "stopped"
    }
}

/// A sample file closed at its last complete chunk, or why it could not be.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ClosedFile {
    Closed {
        bytes: u64,
        cut_bytes: u64,
        chunks: u64,
        messages: u64,
        indexed: bool,
    },
    Failed {
        error: String,
    },
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DroppedInLogger {
    pub measurement: u64,
    pub estimate: u64,
    pub command: u64,
    pub events: u64,
}

/// `plant_latency.json`: the plant's own counters and latencies, written at
/// its exit (the same metric names as [`RunSummary::latency`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PlantLatency {
    pub ticks: u64,
    pub counters: PlantCounters,
    pub latency: BTreeMap<String, Histogram>,
    /// How the plant waited for its ticks (`realtime.tick`); absent in
    /// files written before it existed and in lockstep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tick_wait: Option<TickWaitReport>,
}

/// `realtime.tick` as the plant ran it.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TickWaitReport {
    /// `sleep`, `sleep-then-spin`, or `sleep (fallback: REASON)` where the
    /// scenario asked for the spin and this machine could not give it.
    pub setting: String,
    /// With `sleep-then-spin`: the margin and what the spin did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spin: Option<SpinReport>,
}

/// The spin margin (the plant sleeps until t_k − margin) and the spins.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SpinReport {
    /// The margin at the end of the run.
    pub margin_ns: u64,
    /// The smallest and largest margin the run used.
    pub margin_lowest_ns: u64,
    pub margin_highest_ns: u64,
    /// The bounds it adapts within.
    pub margin_lower_bound_ns: u64,
    pub margin_upper_bound_ns: u64,
    /// Ticks whose sleep ended before t_k and spun the rest.
    pub spun_ticks: u64,
    /// Ticks whose sleep ended at or after t_k.
    pub late_wakeups: u64,
    /// Spins cut by the cap (margin + 50 µs) before t_k.
    pub capped_spins: u64,
    /// Time spent spinning over the run.
    pub spin_ns: u64,
}

impl PlantLatency {
    /// The histogram of the metric named `name` (empty if the plant has none).
    pub fn latency(&self, name: &str) -> Histogram {
        self.latency.get(name).copied().unwrap_or_default()
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PlantCounters {
    pub misses: u64,
    pub late_commands: u64,
    pub stalled_ticks: u64,
    pub stall_misses: u64,
    /// Commands beyond the input limit that the plant clamped (a program's:
    /// the built-in controller clamps its own and flags them).
    #[serde(default)]
    pub clamped: u64,
    /// Commands the plant refused as not finite (NaN, infinite).
    #[serde(default)]
    pub non_finite: u64,
}
