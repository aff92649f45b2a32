//! What `flexloop bench` writes: `bench.json` for one run, `logging_cost.json`
//! for `--logging-cost` and `sweep.json` for `--sweep`.

use crate::latency::{Histogram, Percentiles};
use crate::summary::{PlantLatency, RunSummary, TickWaitReport};
use crate::supervision::SwitchRecord;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `bench.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchFile {
    /// With `--swap-every`: the swaps and the misses around them.
    pub swaps: Option<SwapReport>,
    /// The run's `summary.json`, as it was.
    pub summary: RunSummary,
    /// The machine's floors, measured after the run (unless `--no-probes`).
    pub probes: Option<Floors>,
    /// CPU time per role over all its instances, ns.
    pub cpu_ns: BTreeMap<String, u64>,
    /// The loop's run, wall clock, ns.
    pub wall_ns: f64,
    /// When y(k) was published against the grid, from the sample file
    /// (absent without one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<SamplingJitter>,
    /// How the plant waited for its ticks (its `plant_latency.json`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tick_wait: Option<TickWaitReport>,
    /// The plant's CPU time per tick, ns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plant_cpu_per_tick_ns: Option<f64>,
    /// The busy share of the plant's CPU (`realtime.plant.cpu`, CPU 0 if
    /// unpinned) over the loop's run, from /proc/stat: everyone's time on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plant_cpu_busy: Option<CpuBusy>,
}

/// Sampling jitter: y(k)'s publication against its tick t_k.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SamplingJitter {
    /// published_ns − t_k, per sample.
    pub published_after_tick: Histogram,
    /// |published(k) − published(k−1) − period| over consecutive samples.
    pub interval_error: Histogram,
    /// The shortest and longest interval between consecutive publications.
    pub interval_min_ns: u64,
    pub interval_max_ns: u64,
}

/// One CPU's busy share over a window.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct CpuBusy {
    pub cpu: usize,
    /// Busy (not idle, not waiting for I/O) / all, 0..=1.
    pub share: f64,
}

/// The machine's own floors, measured in the same invocation as the loop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Floors {
    pub timer_wakeup: Histogram,
    pub iceoryx2_event_ping_pong: Histogram,
    pub iceoryx2_polling_ping_pong: Histogram,
    pub unix_socket_ring: Histogram,
}

impl Floors {
    /// Every floor with its table label, in the table's order.
    pub fn rows(&self) -> [(&'static str, &Histogram); 4] {
        [
            ("probe: timer wake-up", &self.timer_wakeup),
            ("probe: iox2 ping-pong", &self.iceoryx2_event_ping_pong),
            ("probe: iox2 polling", &self.iceoryx2_polling_ping_pong),
            ("probe: socket ring", &self.unix_socket_ring),
        ]
    }
}

/// Misses inside the swap windows apart from the rest, and every switch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapReport {
    pub count: usize,
    pub warm: usize,
    pub misses_inside: u64,
    pub misses_inside_after_stalls: u64,
    pub stalls_inside: u64,
    pub ticks_inside: u64,
    pub misses_outside: u64,
    pub misses_outside_after_stalls: u64,
    pub stalls_outside: u64,
    pub ticks_outside: u64,
    pub switches: Vec<SwitchRecord>,
}

/// `logging_cost.json`: the plant's own figures with the logger and without.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoggingCost {
    pub scenario: String,
    pub duration_s: f64,
    pub with_logger: PlantLatency,
    pub without_logger: PlantLatency,
    pub round_trip_p9999_cost_us: f64,
    pub goal_us: f64,
}

/// `sweep.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepFile {
    pub duration_s_per_point: f64,
    pub points: Vec<SweepPoint>,
    pub floors: Option<Floors>,
}

/// One run of the sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    /// `rate`, `base`, `states` or `axes`.
    pub series: String,
    pub label: String,
    pub what: String,
    pub rate_hz: f64,
    pub scenario: String,
    pub result: SweepResult,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SweepResult {
    Measured(Box<SweepMeasurement>),
    Failed { error: String },
}

/// What one point measured (the plant's counters, the logger's
/// latencies, the scheduler's CPU time past start-up).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepMeasurement {
    pub states: usize,
    pub outputs: usize,
    pub inputs: usize,
    pub ticks: u64,
    pub misses: u64,
    pub stall_misses: u64,
    pub stalled_ticks: u64,
    pub round_trip: Percentiles,
    pub tick_lateness: Percentiles,
    pub tick_to_command: Percentiles,
    pub observer_compute: Percentiles,
    pub controller_compute: Percentiles,
    /// CPU ns per sample and share of one core, per role (NaN: no window).
    #[serde(rename = "cpu_ns_per_sample")]
    pub cpu_per_sample_ns: PerRole,
    pub cpu_share: PerRole,
}

/// One value per loop process.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PerRole {
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub plant: f64,
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub observer: f64,
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub controller: f64,
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub logger: f64,
}

impl PerRole {
    /// Plant, observer and controller together: the loop's own share.
    pub fn loop_total(&self) -> f64 {
        self.plant + self.observer + self.controller
    }
}

/// `live_cost.json`: the plant's own figures with a live client subscribed
/// to everything (`bench --live-cost`) and without a live server.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LiveCost {
    pub scenario: String,
    pub duration_s: f64,
    pub with_client: PlantLatency,
    pub without_server: PlantLatency,
    /// What the server did in the run with the client.
    pub server: crate::live::LiveSummary,
    /// What the client received.
    pub client_messages: u64,
    pub client_bytes: u64,
    pub round_trip_p50_cost_us: f64,
    pub round_trip_p9999_cost_us: f64,
}
