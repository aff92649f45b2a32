//! `[measure]`: the field checks, and the excitation the loop runs from it
//! (docs/control.md, "Measuring the loop").

use crate::error::{ScenarioError, number};
use crate::schema::{MeasurePhases, MeasurePoint, MeasureSection, MeasureSignal, Scenario};
use flexloop_control::excitation::{ExcitationPlan, ExcitationShape, InjectionPoint};
use flexloop_control::multisine::{Multisine, MultisineError, MultisineSpec, Phases, line_bins};
use flexloop_protocol::MeasureOrder;
use flexloop_protocol::measure_order::{
    AT_PLANT_INPUT, AT_REFERENCE, AT_SENSOR, MULTISINE, RANDOM, SCHROEDER, STEPPED_SINE, SWEPT_SINE,
};

/// The most lines a measurement excites: more than a response needs over a
/// few decades, and what an array of the frequency-response file holds
/// (`flexloop_modelfile::limits`).
const MAX_LINES: usize = 128;
/// The longest period: 8 MiB of samples, a 0.01 Hz grid at 10 kHz.
const MAX_PERIOD_SAMPLES: usize = 1 << 20;
const MAX_PERIODS: usize = 1_000;
/// At plant input the excitation takes at most this share of the input
/// limit: the controller keeps the rest for its own command.
pub const INPUT_SHARE: f64 = 0.5;

impl Scenario {
    /// The checks that need no design: ranges, and what applies.
    pub(crate) fn validate_measure(&self) -> Result<(), ScenarioError> {
        let Some(m) = &self.measure else {
            return Ok(());
        };
        if !(1..=MAX_LINES).contains(&m.lines) {
            return Err(self.err(
                "measure.lines",
                format!("must lie in 1..={MAX_LINES}, got {}", m.lines),
            ));
        }
        if !(1..=MAX_PERIODS).contains(&m.periods) {
            return Err(self.err(
                "measure.periods",
                format!("must lie in 1..={MAX_PERIODS}, got {}", m.periods),
            ));
        }
        if !(1..=MAX_PERIODS).contains(&m.transient_periods) {
            return Err(self.err(
                "measure.transient_periods",
                format!(
                    "must lie in 1..={MAX_PERIODS} (the first is the fade-in), got {}",
                    m.transient_periods
                ),
            ));
        }
        if m.phases.is_some() && m.signal != MeasureSignal::Multisine {
            return Err(self.err(
                "measure.phases",
                format!(
                    "applies to `signal = \"multisine\"` only; a {}'s phases are its own",
                    m.signal.name()
                ),
            ));
        }
        if m.seed.is_some() && m.phases != Some(MeasurePhases::Random) {
            return Err(self.err(
                "measure.seed",
                "applies to `phases = \"random\"` only; Schroeder's phases have no seed",
            ));
        }
        self.within(
            "measure.start_s",
            m.start_s,
            0.0,
            crate::limits::DURATION_S_MAX,
            "s",
        )?;
        let nyquist = 0.5 * self.timing.rate_hz;
        if !(m.f_max_hz.is_finite() && m.f_max_hz < nyquist) {
            return Err(self.err(
                "measure.f_max_hz",
                format!(
                    "{} Hz is not below the loop's Nyquist frequency, {} Hz",
                    number(m.f_max_hz),
                    number(nyquist)
                ),
            ));
        }
        if !(m.f_min_hz.is_finite() && m.f_min_hz > 0.0 && m.f_min_hz < m.f_max_hz) {
            return Err(self.err(
                "measure.f_min_hz",
                format!(
                    "{} Hz must be positive and below measure.f_max_hz ({} Hz)",
                    number(m.f_min_hz),
                    number(m.f_max_hz)
                ),
            ));
        }
        let samples = self.measure_period_samples(m);
        if !(4..=MAX_PERIOD_SAMPLES).contains(&samples) {
            return Err(self.err(
                "measure.period_samples",
                format!("must lie in 4..={MAX_PERIOD_SAMPLES}, got {samples}"),
            ));
        }
        // The grid must reach down to the band's lowest frequency.
        let resolution = self.timing.rate_hz / samples as f64;
        if resolution > m.f_min_hz * (1.0 + 1e-9) {
            return Err(self.err(
                "measure.period_samples",
                format!(
                    "a period of {samples} samples has lines every {} Hz, above \
                     measure.f_min_hz = {} Hz: lengthen it to at least {} samples",
                    number(resolution),
                    number(m.f_min_hz),
                    (self.timing.rate_hz / m.f_min_hz).ceil()
                ),
            ));
        }
        if !(m.amplitude.is_finite() && m.amplitude > 0.0) {
            return Err(self.err(
                "measure.amplitude",
                format!("must be a positive number, got {}", number(m.amplitude)),
            ));
        }
        // The built-in controller adds a reference excitation; a program's
        // law computes its own reference.
        if m.point == MeasurePoint::Reference && self.controller.exec.is_some() {
            return Err(self.err(
                "measure.point",
                "\"reference\" is added by the built-in controller to its set-point; a program \
                 of one's own computes its own reference: measure at \"plant-input\" or \
                 \"sensor\"",
            ));
        }
        let share = INPUT_SHARE * self.plant.input_limit;
        if m.point == MeasurePoint::PlantInput && m.amplitude > share {
            return Err(self.err(
                "measure.amplitude",
                format!(
                    "{} N would saturate the actuator: at the plant input the excitation may take \
                     at most half of plant.input_limit ({} N), the controller keeps the rest",
                    number(m.amplitude),
                    number(share)
                ),
            ));
        }
        // The whole measurement, fade-outs included, within the run.
        if let Some(ticks) = self.ticks() {
            let steps = self.measure_steps(m);
            let needed = self.measure_start_tick(m)
                + (steps * (m.transient_periods + m.periods + 1) * samples) as u64;
            if needed > ticks {
                let each = if steps > 1 {
                    format!(", for each of its {steps} tones")
                } else {
                    String::new()
                };
                return Err(self.err(
                    "measure.periods",
                    format!(
                        "the measurement runs until {} s (its start, then {} transient and {} \
                         measured periods of {samples} samples and the fade-out{each}), past \
                         loop.duration_s = {} s",
                        number(needed as f64 / self.timing.rate_hz),
                        m.transient_periods,
                        m.periods,
                        number(self.timing.duration_s)
                    ),
                ));
            }
        }
        Ok(())
    }

    fn measure_period_samples(&self, m: &MeasureSection) -> usize {
        m.period_samples_at(self.timing.rate_hz)
    }

    /// Signals run one after another: a stepped sine's tones, else one.
    fn measure_steps(&self, m: &MeasureSection) -> usize {
        match m.signal {
            MeasureSignal::SteppedSine => line_bins(&self.multisine_spec(m)).map_or(1, |b| b.len()),
            _ => 1,
        }
    }

    /// The multisine `[measure]` asks for (a stepped sine's tones are its lines).
    fn multisine_spec(&self, m: &MeasureSection) -> MultisineSpec {
        MultisineSpec {
            rate_hz: self.timing.rate_hz,
            period_samples: self.measure_period_samples(m),
            f_min_hz: m.f_min_hz,
            f_max_hz: m.f_max_hz,
            max_lines: m.lines,
            amplitude: m.amplitude,
            phases: match m.phases.unwrap_or_default() {
                MeasurePhases::Schroeder => Phases::Schroeder,
                MeasurePhases::Random => Phases::Random {
                    seed: m.seed.unwrap_or(0),
                },
            },
        }
    }

    fn measure_start_tick(&self, m: &MeasureSection) -> u64 {
        (m.start_s * self.timing.rate_hz).round() as u64
    }

    /// The excitation the loop runs, designed (milliseconds: the crest
    /// factor's iterations), or None without `[measure]`.
    pub fn measurement_plan(&self) -> Result<Option<ExcitationPlan>, ScenarioError> {
        let Some(m) = &self.measure else {
            return Ok(None);
        };
        let spec = self.multisine_spec(m);
        let designed = match m.signal {
            MeasureSignal::Multisine => Multisine::design(&spec).map(|s| vec![s]),
            MeasureSignal::SweptSine => Multisine::swept(&spec).map(|s| vec![s]),
            // The multisine's lines, one tone each at the full amplitude.
            MeasureSignal::SteppedSine => Multisine::design(&spec).map(|lines| {
                lines
                    .bins
                    .iter()
                    .map(|&bin| {
                        Multisine::tone(spec.rate_hz, spec.period_samples, bin, spec.amplitude)
                    })
                    .collect()
            }),
        };
        let segments = designed.map_err(|e| {
            let field = match e {
                MultisineError::PeriodTooShort { .. } | MultisineError::NoLineInBand { .. } => {
                    "measure.period_samples"
                }
                MultisineError::BadBand { .. } => "measure.f_min_hz",
                MultisineError::AboveNyquist { .. } => "measure.f_max_hz",
                MultisineError::BadAmplitude(_) => "measure.amplitude",
            };
            self.err(field, e.to_string())
        })?;
        Ok(Some(ExcitationPlan {
            point: match m.point {
                MeasurePoint::PlantInput => InjectionPoint::PlantInput,
                MeasurePoint::Sensor => InjectionPoint::Sensor,
                MeasurePoint::Reference => InjectionPoint::Reference,
            },
            shape: match m.signal {
                MeasureSignal::Multisine => ExcitationShape::Multisine,
                MeasureSignal::SweptSine => ExcitationShape::SweptSine,
                MeasureSignal::SteppedSine => ExcitationShape::SteppedSine,
            },
            segments,
            start_tick: self.measure_start_tick(m),
            transient_periods: m.transient_periods,
            periods: m.periods,
        }))
    }
}

impl MeasureSection {
    /// Samples in one period at `rate_hz`: as given, else the rate over
    /// `f_min_hz`, so that the lowest line is the period's first bin.
    pub fn period_samples_at(&self, rate_hz: f64) -> usize {
        self.period_samples
            .unwrap_or_else(|| (rate_hz / self.f_min_hz).round() as usize)
    }

    /// A `[measure]` table on its own (the text of a request or of a
    /// `measure` event), read as a scenario's is.
    pub fn from_table(text: &str) -> Result<Self, toml::de::Error> {
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Table {
            measure: MeasureSection,
        }
        Ok(toml::from_str::<Table>(text)?.measure)
    }

    /// The order that starts this measurement on a running loop at
    /// `start_seq` (its `start_s` is then that sample's time).
    pub fn order(&self, rate_hz: f64, start_seq: u64) -> MeasureOrder {
        MeasureOrder {
            published_ns: 0,
            start_seq,
            seed: self.seed.unwrap_or(0),
            f_min_hz: self.f_min_hz,
            f_max_hz: self.f_max_hz,
            amplitude: self.amplitude,
            lines: self.lines as u32,
            period_samples: self.period_samples_at(rate_hz) as u32,
            transient_periods: self.transient_periods as u32,
            periods: self.periods as u32,
            point: match self.point {
                MeasurePoint::PlantInput => AT_PLANT_INPUT,
                MeasurePoint::Sensor => AT_SENSOR,
                MeasurePoint::Reference => AT_REFERENCE,
            },
            phases: match self.phases.unwrap_or_default() {
                MeasurePhases::Schroeder => SCHROEDER,
                MeasurePhases::Random => RANDOM,
            },
            signal: match self.signal {
                MeasureSignal::Multisine => MULTISINE,
                MeasureSignal::SweptSine => SWEPT_SINE,
                MeasureSignal::SteppedSine => STEPPED_SINE,
            },
            _reserved: 0,
        }
    }

    /// The measurement an order names (the supervisor checked its fields
    /// against the scenario before it sent it).
    pub fn from_order(order: &MeasureOrder, rate_hz: f64) -> Self {
        let random = order.phases == RANDOM;
        Self {
            point: match order.point {
                AT_SENSOR => MeasurePoint::Sensor,
                AT_REFERENCE => MeasurePoint::Reference,
                _ => MeasurePoint::PlantInput,
            },
            f_min_hz: order.f_min_hz,
            f_max_hz: order.f_max_hz,
            lines: order.lines as usize,
            period_samples: Some(order.period_samples as usize),
            amplitude: order.amplitude,
            signal: match order.signal {
                SWEPT_SINE => MeasureSignal::SweptSine,
                STEPPED_SINE => MeasureSignal::SteppedSine,
                _ => MeasureSignal::Multisine,
            },
            // A multisine's only: the others' are their own.
            phases: (order.signal == MULTISINE).then_some(if random {
                MeasurePhases::Random
            } else {
                MeasurePhases::Schroeder
            }),
            seed: random.then_some(order.seed),
            transient_periods: order.transient_periods as usize,
            periods: order.periods as usize,
            start_s: order.start_seq as f64 / rate_hz,
        }
    }
}
