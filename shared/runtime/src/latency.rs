//! Latency histograms of the loop.
//!
//! Every histogram has fixed bounds (1 ns to 10 s, 3 significant digits), so
//! recording never allocates; values beyond the bounds saturate instead of
//! being dropped. [`LoopLatencies`] rebuilds every hop from the timestamps the
//! messages carry, always against the *scheduled* tick time where a budget
//! applies, so that a stalled tick shows up as a long latency instead of
//! vanishing (no coordinated omission).

use flexloop_protocol::{Command, Estimate, Measurement};
use hdrhistogram::Histogram;

/// Quantiles every report shows, then the maximum.
pub const QUANTILES: [f64; 5] = [0.5, 0.9, 0.99, 0.999, 0.9999];
/// Column headers matching [`Percentiles::values_ns`].
pub const QUANTILE_LABELS: [&str; 6] = ["p50", "p90", "p99", "p99.9", "p99.99", "max"];

const LOWEST_NS: u64 = 1;
const HIGHEST_NS: u64 = 10_000_000_000;
const SIGNIFICANT_DIGITS: u8 = 3;

/// A bounded latency histogram in nanoseconds.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    histogram: Histogram<u64>,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl LatencyHistogram {
    pub fn new() -> Self {
        let histogram = Histogram::new_with_bounds(LOWEST_NS, HIGHEST_NS, SIGNIFICANT_DIGITS)
            .expect("constant histogram bounds are valid");
        Self { histogram }
    }

    /// Records one value; zero and out-of-range values saturate to the bounds.
    pub fn record(&mut self, ns: u64) {
        self.histogram
            .saturating_record(ns.clamp(LOWEST_NS, HIGHEST_NS));
    }

    /// Records `to - from` (0 if the stamps are out of order).
    pub fn record_span(&mut self, from_ns: u64, to_ns: u64) {
        self.record(to_ns.saturating_sub(from_ns));
    }

    pub fn count(&self) -> u64 {
        self.histogram.len()
    }

    /// How many recorded values exceed `limit_ns`.
    pub fn count_above(&self, limit_ns: u64) -> u64 {
        let at_or_below = self
            .histogram
            .count_between(LOWEST_NS, limit_ns.clamp(LOWEST_NS, HIGHEST_NS));
        self.count().saturating_sub(at_or_below)
    }

    pub fn percentiles(&self) -> Percentiles {
        let mut values_ns = [0u64; 6];
        if self.count() > 0 {
            for (slot, q) in values_ns.iter_mut().zip(QUANTILES) {
                *slot = self.histogram.value_at_quantile(q);
            }
            values_ns[5] = self.histogram.max();
        }
        Percentiles {
            count: self.count(),
            values_ns,
        }
    }

    pub fn histogram(&self) -> &Histogram<u64> {
        &self.histogram
    }

    pub fn reset(&mut self) {
        self.histogram.reset();
    }

    /// Adds another histogram's counts (same bounds, so this cannot fail).
    pub fn add(&mut self, other: &LatencyHistogram) {
        let _ = self.histogram.add(&other.histogram);
    }
}

/// p50, p90, p99, p99.9, p99.99 and max, in ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Percentiles {
    pub count: u64,
    pub values_ns: [u64; 6],
}

/// The latencies of one loop, each named once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    /// Plant wake-up minus scheduled tick time.
    TickLateness,
    /// Plant published y(k) minus scheduled tick time.
    PlantPublish,
    /// Observer received y(k) minus plant published it.
    PlantToObserver,
    /// Observer published its estimate minus received y(k).
    ObserverCompute,
    /// Observer published the estimate for tick k+1 minus scheduled tick k: it
    /// is due before the controller needs it at tick k+1.
    ObserverDone,
    /// Controller received y(k) minus plant published it.
    PlantToController,
    /// Controller received y(k) minus observer published the estimate it uses.
    ObserverToController,
    /// Controller published u(k) minus received y(k).
    ControllerCompute,
    /// Controller published u(k) (the plant holds it) minus plant published y(k).
    RoundTrip,
    /// Controller published u(k) minus scheduled tick k: must stay below one
    /// sample period (the one-sample budget).
    TickToCommand,
}

impl Metric {
    pub const ALL: [Metric; 10] = [
        Metric::TickLateness,
        Metric::PlantPublish,
        Metric::PlantToObserver,
        Metric::ObserverCompute,
        Metric::ObserverDone,
        Metric::PlantToController,
        Metric::ObserverToController,
        Metric::ControllerCompute,
        Metric::RoundTrip,
        Metric::TickToCommand,
    ];

    /// Stable name, used as the HdrHistogram log tag and JSON key.
    pub fn name(self) -> &'static str {
        match self {
            Metric::TickLateness => "tick_lateness",
            Metric::PlantPublish => "plant_publish",
            Metric::PlantToObserver => "plant_to_observer",
            Metric::ObserverCompute => "observer_compute",
            Metric::ObserverDone => "observer_done",
            Metric::PlantToController => "plant_to_controller",
            Metric::ObserverToController => "observer_to_controller",
            Metric::ControllerCompute => "controller_compute",
            Metric::RoundTrip => "round_trip",
            Metric::TickToCommand => "tick_to_command",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// What the plant measures itself, from its own clock and the stamps of the
/// commands it receives (the spans the logger rebuilds): a run without a
/// logger still has its round trip.
#[derive(Debug, Clone, Default)]
pub struct PlantLatencies {
    /// Scheduled tick → plant awake.
    pub tick_lateness: LatencyHistogram,
    /// y(k) published → u(k) published (available to the plant).
    pub round_trip: LatencyHistogram,
    /// Scheduled tick k → u(k) available.
    pub tick_to_command: LatencyHistogram,
}

impl PlantLatencies {
    pub fn observe_command(&mut self, c: &Command) {
        self.round_trip
            .record_span(c.measurement_published_ns, c.published_ns);
        self.tick_to_command.record_span(c.tick_ns, c.published_ns);
    }
}

/// One histogram per [`Metric`], fed from the messages themselves.
#[derive(Debug, Clone, Default)]
pub struct LoopLatencies {
    histograms: [LatencyHistogram; 10],
}

impl LoopLatencies {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn get(&self, metric: Metric) -> &LatencyHistogram {
        &self.histograms[metric.index()]
    }

    pub fn get_mut(&mut self, metric: Metric) -> &mut LatencyHistogram {
        &mut self.histograms[metric.index()]
    }

    pub fn observe_measurement(&mut self, m: &Measurement) {
        self.get_mut(Metric::TickLateness)
            .record_span(m.tick_ns, m.woke_ns);
        self.get_mut(Metric::PlantPublish)
            .record_span(m.tick_ns, m.published_ns);
    }

    pub fn observe_estimate(&mut self, e: &Estimate) {
        self.get_mut(Metric::PlantToObserver)
            .record_span(e.source_published_ns, e.received_ns);
        self.get_mut(Metric::ObserverCompute)
            .record_span(e.received_ns, e.published_ns);
        self.get_mut(Metric::ObserverDone)
            .record_span(e.source_tick_ns, e.published_ns);
    }

    pub fn observe_command(&mut self, c: &Command) {
        self.get_mut(Metric::PlantToController)
            .record_span(c.measurement_published_ns, c.received_ns);
        self.get_mut(Metric::ObserverToController)
            .record_span(c.estimate_published_ns, c.received_ns);
        self.get_mut(Metric::ControllerCompute)
            .record_span(c.received_ns, c.published_ns);
        self.get_mut(Metric::RoundTrip)
            .record_span(c.measurement_published_ns, c.published_ns);
        self.get_mut(Metric::TickToCommand)
            .record_span(c.tick_ns, c.published_ns);
    }

    pub fn reset(&mut self) {
        self.histograms.iter_mut().for_each(LatencyHistogram::reset);
    }

    pub fn add(&mut self, other: &LoopLatencies) {
        for (a, b) in self.histograms.iter_mut().zip(&other.histograms) {
            a.add(b);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_known_values() {
        let mut h = LatencyHistogram::new();
        for v in 1..=10_000u64 {
            h.record(v * 1_000);
        }
        let p = h.percentiles();
        assert_eq!(p.count, 10_000);
        // 3 significant digits: within 0.1 %.
        let p50 = p.values_ns[0] as f64;
        assert!((p50 - 5_000_000.0).abs() / 5_000_000.0 < 1e-3, "{p50}");
        assert!(p.values_ns[5] >= 9_990_000);
        // Bucket edges at 9 ms are 8 µs wide: a few values near the edge may fall either side.
        let above = h.count_above(9_000_000);
        assert!((990..=1_000).contains(&above), "{above}");
    }

    #[test]
    fn out_of_range_values_saturate_instead_of_vanishing() {
        let mut h = LatencyHistogram::new();
        h.record(0);
        h.record(u64::MAX);
        assert_eq!(h.count(), 2);
        assert!(h.percentiles().values_ns[5] >= HIGHEST_NS / 2);
    }

    #[test]
    fn loop_latencies_measure_against_the_tick() {
        let mut l = LoopLatencies::new();
        let c = Command {
            tick_ns: 1_000,
            measurement_published_ns: 1_020,
            received_ns: 1_030,
            published_ns: 1_050,
            estimate_published_ns: 900,
            ..Default::default()
        };
        l.observe_command(&c);
        assert_eq!(l.get(Metric::RoundTrip).percentiles().values_ns[5], 30);
        assert_eq!(l.get(Metric::TickToCommand).percentiles().values_ns[5], 50);
        assert_eq!(
            l.get(Metric::ControllerCompute).percentiles().values_ns[5],
            20
        );
        assert_eq!(
            l.get(Metric::ObserverToController).percentiles().values_ns[5],
            130
        );
    }
}
