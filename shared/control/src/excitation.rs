//! A measurement's excitation in the loop: where it enters, when it runs,
//! and its value tick by tick (docs/control.md, "Measuring the loop").
//!
//! The plan is made once from the scenario's `[measure]`: one periodic
//! signal (a multisine or a periodic sweep) or a stepped sine's tones, one
//! after another, all on one period's grid; its point, its first tick and
//! how many periods each runs. The plant adds
//! [`ScheduledExcitation::value_at`] each tick. Each signal fades in over
//! its first period and out over one period after its last measured one,
//! so starting and stopping (and stepping from one tone to the next) leave
//! the loop as it was; the fade-in period is the first of the transient
//! ones, which the estimate drops.

use crate::multisine::{Multisine, MultisineSource, SourceState};

/// Where a measurement's excitation enters the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InjectionPoint {
    /// Added to the first input, as a force beside the applied command.
    PlantInput,
    /// Added to the first measured output, as a sensor error would be.
    Sensor,
    /// Added by the controller to the first output's reference (the plant
    /// publishes it, flagged for the controller).
    Reference,
}

impl InjectionPoint {
    /// The name the scenario and the files use.
    pub fn name(self) -> &'static str {
        match self {
            InjectionPoint::PlantInput => "plant-input",
            InjectionPoint::Sensor => "sensor",
            InjectionPoint::Reference => "reference",
        }
    }
}

/// What the excitation is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExcitationShape {
    /// Every line at once, of equal amplitude.
    Multisine,
    /// A logarithmic sweep through the band each period.
    SweptSine,
    /// One line at a time, each a tone of its own.
    SteppedSine,
}

impl ExcitationShape {
    /// The name the scenario and the files use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Multisine => "multisine",
            Self::SweptSine => "swept-sine",
            Self::SteppedSine => "stepped-sine",
        }
    }
}

/// A measurement as the loop runs it.
#[derive(Debug, Clone, PartialEq)]
pub struct ExcitationPlan {
    pub point: InjectionPoint,
    pub shape: ExcitationShape,
    /// What runs, one after another: one periodic signal, or a stepped
    /// sine's tones. All have the same period length.
    pub segments: Vec<Multisine>,
    /// The tick of the excitation's first sample (the fade-in's).
    pub start_tick: u64,
    /// Periods dropped before the measured ones (the fade-in's included).
    pub transient_periods: usize,
    /// Periods measured and averaged.
    pub periods: usize,
}

impl ExcitationPlan {
    pub fn period_samples(&self) -> usize {
        self.segments[0].period_samples()
    }

    /// Ticks of one segment: its transient and measured periods and its
    /// fade-out period.
    pub fn segment_ticks(&self) -> u64 {
        ((self.transient_periods + self.periods + 1) * self.period_samples()) as u64
    }

    /// The tick segment `i` starts at (its fade-in's first).
    pub fn segment_start(&self, i: usize) -> u64 {
        self.start_tick + i as u64 * self.segment_ticks()
    }

    /// The ticks of segment `i`'s measured periods.
    pub fn measured_ticks(&self, i: usize) -> std::ops::Range<u64> {
        let n = self.period_samples();
        let first = self.segment_start(i) + (self.transient_periods * n) as u64;
        first..first + (self.periods * n) as u64
    }

    /// The first tick past the last measured period: the last fade-out
    /// starts here.
    pub fn stop_tick(&self) -> u64 {
        self.measured_ticks(self.segments.len() - 1).end
    }

    /// The first tick with nothing added any more.
    pub fn end_tick(&self) -> u64 {
        self.stop_tick() + self.period_samples() as u64
    }

    /// Every segment's lines, in the order the segments run.
    pub fn frequencies_hz(&self) -> Vec<f64> {
        self.segments
            .iter()
            .flat_map(|s| s.frequencies_hz())
            .collect()
    }
}

/// The plan's value tick by tick. Allocates nothing per tick.
#[derive(Debug, Clone)]
pub struct ScheduledExcitation {
    point: InjectionPoint,
    /// One per segment, made when the plan is scheduled.
    sources: Vec<MultisineSource>,
    start_tick: u64,
    segment_ticks: u64,
    /// Ticks into a segment at which its fade-out starts.
    stop_offset: u64,
    end_tick: u64,
}

impl ScheduledExcitation {
    pub fn new(plan: &ExcitationPlan) -> Self {
        let n = plan.period_samples();
        Self {
            point: plan.point,
            sources: plan
                .segments
                .iter()
                .map(|s| MultisineSource::new(s.clone(), n))
                .collect(),
            start_tick: plan.start_tick,
            segment_ticks: plan.segment_ticks(),
            stop_offset: ((plan.transient_periods + plan.periods) * n) as u64,
            end_tick: plan.end_tick(),
        }
    }

    /// From the next value on, at once, with no fade and no end: the
    /// in-process measurements of the tests.
    pub fn from_now(point: InjectionPoint, source: MultisineSource) -> Self {
        Self {
            point,
            sources: vec![source],
            start_tick: 0,
            segment_ticks: u64::MAX,
            stop_offset: u64::MAX,
            end_tick: u64::MAX,
        }
    }

    pub fn point(&self) -> InjectionPoint {
        self.point
    }

    /// Starts at tick `k` if its planned start has passed (a measurement
    /// ordered on a running loop starts once designed), its whole length
    /// kept. Allocates nothing.
    pub fn start_no_earlier_than(&mut self, k: u64) {
        if k > self.start_tick {
            let shift = k - self.start_tick;
            self.start_tick = k;
            self.end_tick = self.end_tick.saturating_add(shift);
        }
    }

    /// Whether it runs at tick `k`: from its start to the end of its last
    /// fade-out.
    pub fn runs_at(&self, k: u64) -> bool {
        (self.start_tick..self.end_tick).contains(&k)
    }

    /// What is added at tick `k` (ticks come in order, each once).
    pub fn value_at(&mut self, k: u64) -> f64 {
        if !self.runs_at(k) {
            return 0.0;
        }
        let offset = k - self.start_tick;
        let Some(source) = self.sources.get_mut((offset / self.segment_ticks) as usize) else {
            return 0.0;
        };
        if offset % self.segment_ticks == self.stop_offset {
            source.stop();
        }
        if source.state() == SourceState::Off {
            return 0.0;
        }
        source.next_value()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multisine::{MultisineSpec, Phases};
    use std::f64::consts::PI;

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
            shape: ExcitationShape::Multisine,
            segments: vec![signal],
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
        assert_eq!(plan.measured_ticks(0), 250..550);
        let mut excitation = ScheduledExcitation::new(&plan);
        let values: Vec<f64> = (0..800).map(|k| excitation.value_at(k)).collect();
        assert!(
            values[..50].iter().all(|&v| v == 0.0),
            "not before its start"
        );
        // The measured periods repeat the design's period exactly.
        for k in plan.measured_ticks(0) {
            let i = ((k - plan.start_tick) % 100) as usize;
            assert_eq!(values[k as usize], plan.segments[0].period[i]);
        }
        assert!(
            values[650..].iter().all(|&v| v == 0.0),
            "off after the fade"
        );
        // Faded: no step at either end larger than the signal's own.
        let largest_step = plan.segments[0]
            .period
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        for w in values.windows(2) {
            assert!((w[1] - w[0]).abs() <= largest_step + 1e-12);
        }
    }

    /// A stepped sine: each tone runs its periods in turn, faded in and out,
    /// and the switch from one to the next steps no more than a tone does.
    #[test]
    fn a_stepped_sine_runs_its_tones_one_after_another() {
        let tones: Vec<Multisine> = [3, 11, 29]
            .iter()
            .map(|&bin| Multisine::tone(1_000.0, 100, bin, 2.0))
            .collect();
        let plan = ExcitationPlan {
            point: InjectionPoint::Sensor,
            shape: ExcitationShape::SteppedSine,
            segments: tones.clone(),
            start_tick: 10,
            transient_periods: 2,
            periods: 3,
        };
        assert_eq!(plan.segment_ticks(), 600);
        assert_eq!(plan.measured_ticks(1), 10 + 600 + 200..10 + 600 + 500);
        assert_eq!(plan.stop_tick(), 10 + 1200 + 500);
        assert_eq!(plan.end_tick(), 10 + 1800);
        assert_eq!(plan.frequencies_hz(), vec![30.0, 110.0, 290.0]);
        let mut excitation = ScheduledExcitation::new(&plan);
        let values: Vec<f64> = (0..2_000).map(|k| excitation.value_at(k)).collect();
        for (i, tone) in tones.iter().enumerate() {
            for k in plan.measured_ticks(i) {
                let at = ((k - plan.segment_start(i)) % 100) as usize;
                assert_eq!(values[k as usize], tone.period[at], "tone {i} at {k}");
            }
            // Its fade-out ends at nothing before the next one starts.
            let next = plan.segment_start(i + 1) as usize;
            assert!(
                values[next - 1].abs() < 1e-3,
                "tone {i}: {}",
                values[next - 1]
            );
        }
        assert!(values[..10].iter().all(|&v| v == 0.0));
        assert!(values[1810..].iter().all(|&v| v == 0.0));
        let largest_tone_step = 2.0 * 2.0 * (PI * 29.0 / 100.0).sin();
        for w in values.windows(2) {
            assert!((w[1] - w[0]).abs() <= largest_tone_step + 1e-12);
        }
    }

    /// Started later than planned (a running loop's order, designed after
    /// its planned start): the same excitation, shifted whole.
    #[test]
    fn a_late_start_shifts_the_whole_excitation() {
        let plan = plan();
        let mut on_time = ScheduledExcitation::new(&plan);
        let mut late = ScheduledExcitation::new(&plan);
        late.start_no_earlier_than(80);
        for k in 0..700 {
            let expected = on_time.value_at(k);
            assert_eq!(late.value_at(k + 30), expected, "tick {k}");
        }
        assert!(!late.runs_at(680) && late.runs_at(679));
    }
}
