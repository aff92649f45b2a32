//! A measurement's excitation in the loop: where it enters, when it runs,
//! and its value tick by tick (docs/control.md, "Measuring the loop").
//!
//! The plan is made once from the scenario's `[measure]` (a multisine,
//! its point, its first tick and how many periods); the plant adds
//! [`ScheduledExcitation::value_at`] each tick. The multisine fades in over
//! its first period and out over one period after the last measured one, so
//! starting and stopping leave the loop as it was; the fade-in period is
//! the first of the transient ones, which the estimate drops.

use crate::multisine::{Multisine, MultisineSource, SourceState};

/// Where a measurement's excitation enters the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InjectionPoint {
    /// Added to the first input, as a force beside the applied command.
    PlantInput,
    /// Added to the first measured output, as a sensor error would be.
    Sensor,
}

impl InjectionPoint {
    /// The name the scenario and the files use.
    pub fn name(self) -> &'static str {
        match self {
            InjectionPoint::PlantInput => "plant-input",
            InjectionPoint::Sensor => "sensor",
        }
    }
}

/// A measurement as the loop runs it.
#[derive(Debug, Clone, PartialEq)]
pub struct ExcitationPlan {
    pub point: InjectionPoint,
    pub signal: Multisine,
    /// The tick of the excitation's first sample (the fade-in's).
    pub start_tick: u64,
    /// Periods dropped before the measured ones (the fade-in's included).
    pub transient_periods: usize,
    /// Periods measured and averaged.
    pub periods: usize,
}

impl ExcitationPlan {
    pub fn period_samples(&self) -> usize {
        self.signal.period_samples()
    }

    /// The first tick past the measured periods: the fade-out starts here.
    pub fn stop_tick(&self) -> u64 {
        self.start_tick + ((self.transient_periods + self.periods) * self.period_samples()) as u64
    }

    /// The first tick with nothing added any more.
    pub fn end_tick(&self) -> u64 {
        self.stop_tick() + self.period_samples() as u64
    }

    /// The ticks of the measured periods.
    pub fn measured_ticks(&self) -> std::ops::Range<u64> {
        let first = self.start_tick + (self.transient_periods * self.period_samples()) as u64;
        first..self.stop_tick()
    }
}

/// The plan's value tick by tick. Allocates nothing per tick.
#[derive(Debug, Clone)]
pub struct ScheduledExcitation {
    point: InjectionPoint,
    source: MultisineSource,
    start_tick: u64,
    stop_tick: u64,
}

impl ScheduledExcitation {
    pub fn new(plan: &ExcitationPlan) -> Self {
        Self {
            point: plan.point,
            source: MultisineSource::new(plan.signal.clone(), plan.period_samples()),
            start_tick: plan.start_tick,
            stop_tick: plan.stop_tick(),
        }
    }

    /// From the next value on, at once, with no fade and no end: the
    /// in-process measurements of the tests.
    pub fn from_now(point: InjectionPoint, source: MultisineSource) -> Self {
        Self {
            point,
            source,
            start_tick: 0,
            stop_tick: u64::MAX,
        }
    }

    pub fn point(&self) -> InjectionPoint {
        self.point
    }

    /// Whether it runs at tick `k`: from its start to the end of its
    /// fade-out (asked before [`Self::value_at`] for the same tick).
    pub fn runs_at(&self, k: u64) -> bool {
        k >= self.start_tick && self.source.state() != SourceState::Off
    }

    /// What is added at tick `k` (ticks come in order, each once).
    pub fn value_at(&mut self, k: u64) -> f64 {
        if k < self.start_tick || self.source.state() == SourceState::Off {
            return 0.0;
        }
        if k == self.stop_tick {
            self.source.stop();
        }
        self.source.next_value()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multisine::{MultisineSpec, Phases};

    fn plan() -> ExcitationPlan {
        let signal = Multisine::design(&MultisineSpec {
            rate_hz: 1_000.0,
            period_samples: 100,
            f_min_hz: 10.0,
            f_max_hz: 200.0,
            max_lines: 10,
            amplitude: 2.0,
            phases: Phases::Schroeder,
        })
        .unwrap();
        ExcitationPlan {
            point: InjectionPoint::PlantInput,
            signal,
            start_tick: 50,
            transient_periods: 2,
            periods: 3,
        }
    }

    #[test]
    fn it_runs_from_its_start_through_its_periods_and_fades_out_to_nothing() {
        let plan = plan();
        assert_eq!(plan.stop_tick(), 50 + 500);
        assert_eq!(plan.end_tick(), 650);
        assert_eq!(plan.measured_ticks(), 250..550);
        let mut excitation = ScheduledExcitation::new(&plan);
        let values: Vec<f64> = (0..800).map(|k| excitation.value_at(k)).collect();
        assert!(
            values[..50].iter().all(|&v| v == 0.0),
            "not before its start"
        );
        // The measured periods repeat the design's period exactly.
        for k in plan.measured_ticks() {
            let i = ((k - plan.start_tick) % 100) as usize;
            assert_eq!(values[k as usize], plan.signal.period[i]);
        }
        assert!(
            values[650..].iter().all(|&v| v == 0.0),
            "off after the fade"
        );
        // Faded: no step at either end larger than the signal's own.
        let largest_step = plan
            .signal
            .period
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        for w in values.windows(2) {
            assert!((w[1] - w[0]).abs() <= largest_step + 1e-12);
        }
    }
}
