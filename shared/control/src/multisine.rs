//! A periodic multisine excitation on the loop's sample grid, for measuring
//! frequency responses (docs/control.md, "Measuring the loop").
//!
//! Any signal that repeats every N samples is a multisine on N's DFT bins:
//! the designed multisine of equal lines ([`Multisine::design`]), a periodic
//! logarithmic sweep ([`Multisine::swept`]) and one tone of a stepped sine
//! ([`Multisine::tone`]) are all read the same way.
//!
//! One period holds an integer number of samples and every line sits on a
//! DFT bin of it, so the DFT of a whole period in steady state has no
//! leakage: each line's response is read off its own bin. The lines are
//! log-spaced between the lowest and highest frequency asked for (snapped
//! to bins, each bin once); their phases start from Schroeder's or seeded
//! random ones and are then improved for a low crest factor (the most
//! excitation for the actuator's range). The period is computed once, at design
//! time; the per-sample source ([`MultisineSource`]) only reads it and fades
//! it in and out with a raised cosine, so that starting or stopping a
//! measurement steps the signal no more than its own sample-to-sample steps.

use nalgebra::Complex;
use realfft::{ComplexToReal, RealFftPlanner};
use std::f64::consts::PI;

/// Why a multisine cannot be made as asked.
#[derive(Debug, Clone, PartialEq)]
pub enum MultisineError {
    /// The period needs at least 4 samples (one line below Nyquist).
    PeriodTooShort { samples: usize },
    /// The band must be ordered, positive and finite.
    BadBand { f_min_hz: f64, f_max_hz: f64 },
    /// The band's top is at or above Nyquist.
    AboveNyquist { f_max_hz: f64, nyquist_hz: f64 },
    /// No DFT bin of the period lies in the band (the period is too short
    /// for its lowest frequency).
    NoLineInBand { resolution_hz: f64 },
    /// The amplitude must be positive and finite.
    BadAmplitude(f64),
}

impl std::fmt::Display for MultisineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::PeriodTooShort { samples } => {
                write!(f, "a period of {samples} samples is too short (at least 4)")
            }
            Self::BadBand { f_min_hz, f_max_hz } => write!(
                f,
                "the band {f_min_hz} Hz to {f_max_hz} Hz is not an ordered pair of positive frequencies"
            ),
            Self::AboveNyquist {
                f_max_hz,
                nyquist_hz,
            } => write!(
                f,
                "{f_max_hz} Hz is at or above the Nyquist frequency, {nyquist_hz} Hz"
            ),
            Self::NoLineInBand { resolution_hz } => write!(
                f,
                "no line of the period's {resolution_hz} Hz grid lies in the band: lengthen the period"
            ),
            Self::BadAmplitude(a) => write!(f, "the amplitude {a} is not a positive number"),
        }
    }
}

impl std::error::Error for MultisineError {}

/// Where the lines' phases start (before the crest factor is lowered).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Phases {
    /// Schroeder's, for L lines of equal power on harmonics b_i:
    /// φ_i = −2π Σ_{j<i} (b_i − b_j) / L, a low crest factor.
    Schroeder,
    /// Uniform in [0, 2π), from the seed (the same seed, the same signal).
    Random { seed: u64 },
}

/// What to excite.
#[derive(Debug, Clone, PartialEq)]
pub struct MultisineSpec {
    /// The loop's sample rate.
    pub rate_hz: f64,
    /// Samples in one period: the frequency resolution is rate / samples.
    pub period_samples: usize,
    pub f_min_hz: f64,
    pub f_max_hz: f64,
    /// At most this many lines, log-spaced (fewer where bins coincide).
    pub max_lines: usize,
    /// The largest |value| the signal takes.
    pub amplitude: f64,
    pub phases: Phases,
}

/// One period of the designed signal and its lines.
#[derive(Debug, Clone, PartialEq)]
pub struct Multisine {
    pub rate_hz: f64,
    /// The DFT bins measured, ascending: line i is at bins[i] · rate / N.
    pub bins: Vec<usize>,
    /// Each line's cosine amplitude and phase in the period.
    pub line_amplitudes: Vec<f64>,
    pub phases: Vec<f64>,
    /// The period, scaled so that its largest |value| is the amplitude.
    pub period: Vec<f64>,
}

impl Multisine {
    /// Designs the signal. Allocates (design time).
    pub fn design(spec: &MultisineSpec) -> Result<Self, MultisineError> {
        let n = spec.period_samples;
        let bins = line_bins(spec)?;
        let count = bins.len();
        let phases: Vec<f64> = match spec.phases {
            // Schroeder's rule for lines of equal power on any set of
            // harmonics: φ_i = −2π Σ_{j<i} (b_i − b_j) / L.
            Phases::Schroeder => (0..count)
                .map(|i| {
                    let lag: usize = bins[..i].iter().map(|&b| bins[i] - b).sum();
                    -2.0 * PI * (lag % n) as f64 / count as f64
                })
                .collect(),
            Phases::Random { seed } => {
                let mut rng = oorandom::Rand64::new(u128::from(seed));
                (0..count).map(|_| rng.rand_float() * 2.0 * PI).collect()
            }
        };
        let (phases, mut period) = lower_crest_factor(n, &bins, phases);
        let peak = period.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let scale = spec.amplitude / peak;
        for v in &mut period {
            *v *= scale;
        }
        Ok(Self {
            rate_hz: spec.rate_hz,
            line_amplitudes: vec![scale; bins.len()],
            bins,
            phases,
            period,
        })
    }

    /// A periodic logarithmic sweep from `f_min_hz` to `f_max_hz` over one
    /// period, of peak `amplitude` (crest factor √2; `phases` does not
    /// apply). The instantaneous frequency f_min · (f_max/f_min)^(t/T) is
    /// scaled by less than one cycle per period so that the period holds
    /// whole cycles: it then repeats without a step, and its DFT of a whole
    /// period has no leakage. It spends time ∝ 1/f at each frequency, so
    /// its power per line falls as 1/f across the band. The lines measured are log-spaced bins of the band where the sweep's
    /// line is at least [`SWEEP_LINE_SHARE`] of its stationary-phase level
    /// (its ripple at the band's edges dips below).
    pub fn swept(spec: &MultisineSpec) -> Result<Self, MultisineError> {
        let n = spec.period_samples;
        let (lowest, highest) = band_bins(spec)?;
        let (f1, f2) = (spec.f_min_hz, spec.f_max_hz);
        let period_s = n as f64 / spec.rate_hz;
        let ratio = f2 / f1;
        // Cycles in one period of the unscaled sweep, and the scale that
        // makes them whole (a single tone when the band is one frequency).
        let cycles = if ratio > 1.0 + 1e-12 {
            f1 * period_s * (ratio - 1.0) / ratio.ln()
        } else {
            f1 * period_s
        };
        // Under one cycle a period cannot hold the sweep (the grid check
        // of a scenario refuses such a period before this).
        if cycles < 1.0 {
            return Err(MultisineError::NoLineInBand {
                resolution_hz: spec.rate_hz / n as f64,
            });
        }
        let scale = cycles.round() / cycles;
        let phase = |t: f64| {
            let unscaled = if ratio > 1.0 + 1e-12 {
                2.0 * PI * f1 * period_s / ratio.ln() * (ratio.powf(t / period_s) - 1.0)
            } else {
                2.0 * PI * f1 * t
            };
            scale * unscaled
        };
        let period: Vec<f64> = (0..n)
            .map(|k| spec.amplitude * phase(k as f64 / spec.rate_hz).sin())
            .collect();
        let mut planner = RealFftPlanner::<f64>::new();
        let forward = planner.plan_fft_forward(n);
        let mut input = period.clone();
        let mut spectrum = forward.make_output_vec();
        forward
            .process(&mut input, &mut spectrum)
            .expect("buffers made by the plan fit it");
        // Stationary phase: a tone of amplitude A sweeping at df/dt gives a
        // line of amplitude A / (T √(df/dt)); here df/dt = f ln(ratio) / T,
        // so A / √(f T ln ratio).
        let resolution = spec.rate_hz / n as f64;
        let level = |bin: usize| {
            let f = bin as f64 * resolution;
            if ratio > 1.0 + 1e-12 {
                spec.amplitude * (1.0 / (f * period_s * ratio.ln())).sqrt().min(1.0)
            } else {
                spec.amplitude
            }
        };
        let amplitude_at = |bin: usize| 2.0 * spectrum[bin].norm() / n as f64;
        let strong: Vec<usize> = (lowest..=highest)
            .filter(|&b| amplitude_at(b) >= SWEEP_LINE_SHARE * level(b))
            .collect();
        if strong.is_empty() {
            return Err(MultisineError::NoLineInBand {
                resolution_hz: resolution,
            });
        }
        let bins = thin_log_spaced(&strong, spec.max_lines);
        Ok(Self {
            rate_hz: spec.rate_hz,
            line_amplitudes: bins.iter().map(|&b| amplitude_at(b)).collect(),
            phases: bins.iter().map(|&b| spectrum[b].arg()).collect(),
            bins,
            period,
        })
    }

    /// One tone of a stepped sine: a cosine of `amplitude` on `bin` of a
    /// period of `period_samples` at `rate_hz`.
    pub fn tone(rate_hz: f64, period_samples: usize, bin: usize, amplitude: f64) -> Self {
        let n = period_samples;
        let period = (0..n)
            .map(|k| amplitude * (2.0 * PI * ((bin * k) % n) as f64 / n as f64).cos())
            .collect();
        Self {
            rate_hz,
            bins: vec![bin],
            line_amplitudes: vec![amplitude],
            phases: vec![0.0],
            period,
        }
    }

    pub fn period_samples(&self) -> usize {
        self.period.len()
    }

    /// The lines' frequencies.
    pub fn frequencies_hz(&self) -> Vec<f64> {
        let resolution = self.rate_hz / self.period.len() as f64;
        self.bins.iter().map(|&b| b as f64 * resolution).collect()
    }

    /// Peak over rms: √2 for one line; Schroeder phases keep many lines
    /// near 2 where equal phases would give √(2L).
    pub fn crest_factor(&self) -> f64 {
        crest(&self.period)
    }
}

/// The period of unit lines at `bins` with `phases`: Σ cos(2π b k / N + φ),
/// by `inverse`, a plan for the period's length.
fn synthesize(inverse: &dyn ComplexToReal<f64>, bins: &[usize], phases: &[f64]) -> Vec<f64> {
    let mut spectrum = inverse.make_input_vec();
    for (&bin, &phi) in bins.iter().zip(phases) {
        // The inverse real FFT adds each bin's conjugate twin: half each.
        spectrum[bin] = Complex::from_polar(0.5, phi);
    }
    let mut period = inverse.make_output_vec();
    inverse
        .process(&mut spectrum, &mut period)
        .expect("buffers made by the plan fit it");
    period
}

/// A sweep's line below this share of its stationary-phase level is not
/// measured: the band's edges, where the sweep's spectrum ripples down.
pub const SWEEP_LINE_SHARE: f64 = 0.3;

/// The first and last DFT bins of the band that the period's grid holds,
/// or why the signal cannot be made.
fn band_bins(spec: &MultisineSpec) -> Result<(usize, usize), MultisineError> {
    let n = spec.period_samples;
    if n < 4 {
        return Err(MultisineError::PeriodTooShort { samples: n });
    }
    let ordered = spec.f_min_hz.is_finite()
        && spec.f_max_hz.is_finite()
        && spec.f_min_hz > 0.0
        && spec.f_max_hz >= spec.f_min_hz;
    if !ordered {
        return Err(MultisineError::BadBand {
            f_min_hz: spec.f_min_hz,
            f_max_hz: spec.f_max_hz,
        });
    }
    let nyquist_hz = spec.rate_hz / 2.0;
    if spec.f_max_hz >= nyquist_hz {
        return Err(MultisineError::AboveNyquist {
            f_max_hz: spec.f_max_hz,
            nyquist_hz,
        });
    }
    if !(spec.amplitude.is_finite() && spec.amplitude > 0.0) {
        return Err(MultisineError::BadAmplitude(spec.amplitude));
    }
    let resolution_hz = spec.rate_hz / n as f64;
    let lowest = (spec.f_min_hz / resolution_hz).ceil().max(1.0) as usize;
    let highest = ((spec.f_max_hz / resolution_hz).floor() as usize).min((n - 1) / 2);
    if highest < lowest {
        return Err(MultisineError::NoLineInBand { resolution_hz });
    }
    Ok((lowest, highest))
}

/// The bins a multisine of `spec` excites (a stepped sine's tones): at
/// most `max_lines`, log-spaced over the band, each once.
pub fn line_bins(spec: &MultisineSpec) -> Result<Vec<usize>, MultisineError> {
    let (lowest, highest) = band_bins(spec)?;
    Ok(log_spaced(lowest, highest, spec.max_lines))
}

/// At most `lines` bins log-spaced from `lowest` to `highest`, each once.
fn log_spaced(lowest: usize, highest: usize, lines: usize) -> Vec<usize> {
    let lines = lines.max(1);
    let mut bins: Vec<usize> = (0..lines)
        .map(|i| {
            let t = if lines == 1 {
                0.0
            } else {
                i as f64 / (lines - 1) as f64
            };
            let f = (lowest as f64).ln() + t * ((highest as f64).ln() - (lowest as f64).ln());
            (f.exp().round() as usize).clamp(lowest, highest)
        })
        .collect();
    bins.dedup();
    bins
}

/// At most `lines` of the ascending `candidates`, log-spaced: each target
/// of [`log_spaced`] takes the nearest candidate (each once).
fn thin_log_spaced(candidates: &[usize], lines: usize) -> Vec<usize> {
    let (first, last) = (candidates[0], candidates[candidates.len() - 1]);
    let mut bins: Vec<usize> = log_spaced(first, last, lines)
        .into_iter()
        .map(|target| {
            let at = candidates.partition_point(|&c| c < target);
            let above = candidates.get(at).copied();
            let below = at.checked_sub(1).map(|i| candidates[i]);
            match (below, above) {
                (Some(b), Some(a)) if target - b <= a - target => b,
                (_, Some(a)) => a,
                (Some(b), None) => b,
                (None, None) => unreachable!("candidates are not empty"),
            }
        })
        .collect();
    bins.dedup();
    bins
}

/// Peak over rms of a period.
fn crest(period: &[f64]) -> f64 {
    let peak = period.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let rms = (period.iter().map(|v| v * v).sum::<f64>() / period.len() as f64).sqrt();
    peak / rms
}

/// Lowers the crest factor from the phases given by clipping iterations
/// (Van der Ouderaa, Schoukens and Renneboog, 1988): clip the period's
/// peaks, keep the clipped signal's phases at the lines, restore the
/// lines' equal amplitudes; the best of the iterations is kept, with its
/// period of unit lines.
fn lower_crest_factor(n: usize, bins: &[usize], start: Vec<f64>) -> (Vec<f64>, Vec<f64>) {
    const ITERATIONS: usize = 200;
    let mut planner = RealFftPlanner::<f64>::new();
    let forward = planner.plan_fft_forward(n);
    let inverse = planner.plan_fft_inverse(n);
    let mut spectrum = forward.make_output_vec();
    let mut phases = start;
    let mut period = synthesize(inverse.as_ref(), bins, &phases);
    let mut best = (crest(&period), phases.clone(), period.clone());
    for _ in 0..ITERATIONS {
        let peak = period.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let level = 0.8 * peak;
        for v in &mut period {
            *v = v.clamp(-level, level);
        }
        forward
            .process(&mut period, &mut spectrum)
            .expect("buffers made by the plan fit it");
        for (phi, &bin) in phases.iter_mut().zip(bins) {
            *phi = spectrum[bin].arg();
        }
        period = synthesize(inverse.as_ref(), bins, &phases);
        let now = crest(&period);
        if now < best.0 {
            best = (now, phases.clone(), period.clone());
        }
    }
    (best.1, best.2)
}

/// Where the source is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceState {
    /// Ramping up over the fade; its periods are transients, not measured.
    FadingIn,
    /// At full amplitude.
    Steady,
    /// Ramping down after [`MultisineSource::stop`].
    FadingOut,
    /// Done: it adds nothing from here on.
    Off,
}

/// The multisine sample by sample, faded in at its start and out at its
/// stop. Allocates nothing per sample (the period is the design's).
#[derive(Debug, Clone)]
pub struct MultisineSource {
    signal: Multisine,
    /// Samples of each fade.
    fade_samples: usize,
    /// Samples since the start.
    k: u64,
    state: SourceState,
    /// The envelope when the stop came, and samples since.
    fading_from: f64,
    since_stop: usize,
}

impl MultisineSource {
    /// `fade_samples`: how long the raised-cosine fades last (0: none).
    pub fn new(signal: Multisine, fade_samples: usize) -> Self {
        let state = if fade_samples == 0 {
            SourceState::Steady
        } else {
            SourceState::FadingIn
        };
        Self {
            signal,
            fade_samples,
            k: 0,
            state,
            fading_from: 1.0,
            since_stop: 0,
        }
    }

    pub fn signal(&self) -> &Multisine {
        &self.signal
    }

    pub fn state(&self) -> SourceState {
        self.state
    }

    /// Samples since the start: with the period, where each period begins.
    pub fn samples(&self) -> u64 {
        self.k
    }

    /// Begins the fade out (at once off without a fade).
    pub fn stop(&mut self) {
        match self.state {
            SourceState::Off | SourceState::FadingOut => {}
            _ if self.fade_samples == 0 => self.state = SourceState::Off,
            _ => {
                self.fading_from = self.envelope();
                self.since_stop = 0;
                self.state = SourceState::FadingOut;
            }
        }
    }

    fn envelope(&self) -> f64 {
        let ramp = |t: f64| 0.5 - 0.5 * (PI * t.clamp(0.0, 1.0)).cos();
        match self.state {
            SourceState::FadingIn => ramp(self.k as f64 / self.fade_samples as f64),
            SourceState::Steady => 1.0,
            SourceState::FadingOut => {
                self.fading_from * (1.0 - ramp(self.since_stop as f64 / self.fade_samples as f64))
            }
            SourceState::Off => 0.0,
        }
    }

    /// This sample's value; then the next sample.
    pub fn next_value(&mut self) -> f64 {
        let n = self.signal.period.len() as u64;
        let value = self.signal.period[(self.k % n) as usize] * self.envelope();
        self.k += 1;
        match self.state {
            SourceState::FadingIn if self.k >= self.fade_samples as u64 => {
                self.state = SourceState::Steady;
            }
            SourceState::FadingOut => {
                self.since_stop += 1;
                if self.since_stop >= self.fade_samples {
                    self.state = SourceState::Off;
                }
            }
            _ => {}
        }
        value
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> MultisineSpec {
        MultisineSpec {
            rate_hz: 10_000.0,
            period_samples: 2_000,
            f_min_hz: 5.0,
            f_max_hz: 2_000.0,
            max_lines: 60,
            amplitude: 0.5,
            phases: Phases::Schroeder,
        }
    }

    /// |DFT| of one period at every bin below Nyquist, by the definition.
    fn spectrum(x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n / 2)
            .map(|bin| {
                let (mut re, mut im) = (0.0, 0.0);
                for (k, v) in x.iter().enumerate() {
                    let a = 2.0 * PI * (bin * k % n) as f64 / n as f64;
                    re += v * a.cos();
                    im -= v * a.sin();
                }
                (re * re + im * im).sqrt()
            })
            .collect()
    }

    #[test]
    fn every_line_is_on_a_bin_in_the_band_and_nothing_else_is_excited() {
        let m = Multisine::design(&spec()).unwrap();
        assert!(m.bins.len() > 40 && m.bins.len() <= 60, "{}", m.bins.len());
        assert!(m.bins.windows(2).all(|w| w[0] < w[1]));
        let f = m.frequencies_hz();
        assert!(f[0] >= 5.0 && *f.last().unwrap() <= 2_000.0, "{f:?}");
        let spectrum = spectrum(&m.period);
        let n = m.period_samples() as f64;
        for (bin, magnitude) in spectrum.iter().enumerate() {
            let expected = if m.bins.contains(&bin) {
                m.line_amplitudes[m.bins.iter().position(|&b| b == bin).unwrap()] * n / 2.0
            } else {
                0.0
            };
            assert!(
                (magnitude - expected).abs() < 1e-9 * n,
                "bin {bin}: {magnitude} against {expected}"
            );
        }
        let peak = m.period.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        assert!((peak - 0.5).abs() < 1e-12);
    }

    #[test]
    fn the_crest_factor_is_lowered_from_either_start_and_a_seed_gives_one_signal() {
        let s = spec();
        let n = s.period_samples;
        for phases in [Phases::Schroeder, Phases::Random { seed: 7 }] {
            let m = Multisine::design(&MultisineSpec { phases, ..spec() }).unwrap();
            let start = match phases {
                Phases::Schroeder => schroeder(&m.bins, n),
                Phases::Random { seed } => {
                    let mut rng = oorandom::Rand64::new(u128::from(seed));
                    m.bins.iter().map(|_| rng.rand_float() * 2.0 * PI).collect()
                }
            };
            let inverse = RealFftPlanner::<f64>::new().plan_fft_inverse(n);
            let start = crest(&synthesize(inverse.as_ref(), &m.bins, &start));
            assert!(
                m.crest_factor() < 2.5 && m.crest_factor() < start,
                "{phases:?}: {} from {start}",
                m.crest_factor()
            );
        }
        let random = |seed| {
            Multisine::design(&MultisineSpec {
                phases: Phases::Random { seed },
                ..spec()
            })
            .unwrap()
        };
        assert_eq!(random(7), random(7));
        assert_ne!(random(7).phases, random(8).phases);
    }

    fn schroeder(bins: &[usize], n: usize) -> Vec<f64> {
        (0..bins.len())
            .map(|i| {
                let lag: usize = bins[..i].iter().map(|&b| bins[i] - b).sum();
                -2.0 * PI * (lag % n) as f64 / bins.len() as f64
            })
            .collect()
    }

    #[test]
    fn a_band_the_period_or_the_rate_cannot_hold_is_refused() {
        let refused = |s: MultisineSpec| Multisine::design(&s).unwrap_err();
        assert!(matches!(
            refused(MultisineSpec {
                f_max_hz: 5_000.0,
                ..spec()
            }),
            MultisineError::AboveNyquist { .. }
        ));
        assert!(matches!(
            refused(MultisineSpec {
                f_min_hz: 1.0,
                f_max_hz: 2.0,
                ..spec()
            }),
            MultisineError::NoLineInBand { .. }
        ));
        assert!(matches!(
            refused(MultisineSpec {
                f_min_hz: 100.0,
                f_max_hz: 10.0,
                ..spec()
            }),
            MultisineError::BadBand { .. }
        ));
        assert!(matches!(
            refused(MultisineSpec {
                amplitude: f64::NAN,
                ..spec()
            }),
            MultisineError::BadAmplitude(_)
        ));
        assert!(matches!(
            refused(MultisineSpec {
                period_samples: 3,
                ..spec()
            }),
            MultisineError::PeriodTooShort { .. }
        ));
    }

    /// Starting and stopping step the signal no more than its own largest
    /// sample-to-sample step at full amplitude, and it ends at exactly 0.
    #[test]
    fn the_fades_start_and_stop_without_a_step() {
        let signal = Multisine::design(&spec()).unwrap();
        let n = signal.period_samples();
        let ordinary = (0..n)
            .map(|k| (signal.period[(k + 1) % n] - signal.period[k]).abs())
            .fold(0.0_f64, f64::max);
        let mut source = MultisineSource::new(signal.clone(), n);
        let mut previous = 0.0;
        let mut largest_step = 0.0_f64;
        for k in 0..5 * n {
            if k == 3 * n + 17 {
                source.stop();
            }
            let v = source.next_value();
            largest_step = largest_step.max((v - previous).abs());
            previous = v;
            if (n..3 * n).contains(&k) {
                assert_eq!(source.state(), SourceState::Steady);
                assert_eq!(v, signal.period[k % n], "steady: the period itself");
            }
        }
        assert_eq!(source.state(), SourceState::Off);
        assert_eq!(source.next_value(), 0.0);
        assert!(
            largest_step <= ordinary * (1.0 + 1e-12),
            "{largest_step} > {ordinary}"
        );
    }

    /// A periodic sweep: whole cycles in its period (no step where it
    /// repeats), peak = amplitude, crest factor √2, and its measured lines
    /// are in the band and excited as the stationary phase says.
    #[test]
    fn a_swept_sine_repeats_without_a_step_and_excites_its_band() {
        let s = spec();
        let m = Multisine::swept(&s).unwrap();
        let n = m.period_samples();
        assert_eq!(n, 2_000);
        let peak = m.period.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        assert!(peak <= 0.5 + 1e-12 && peak > 0.49, "{peak}");
        assert!((m.crest_factor() - 2.0_f64.sqrt()).abs() < 0.05);
        // The wrap from the last sample to the first is an ordinary step.
        let ordinary = m
            .period
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        assert!((m.period[0] - m.period[n - 1]).abs() <= ordinary);
        assert!(m.bins.len() > 40 && m.bins.len() <= 60, "{}", m.bins.len());
        let f = m.frequencies_hz();
        assert!(f[0] >= 5.0 && *f.last().unwrap() <= 2_000.0, "{f:?}");
        // Each line's amplitude is the DFT's, and near the 1/√f level.
        let spectrum = spectrum(&m.period);
        let ln_ratio = (2_000.0_f64 / 5.0).ln();
        for (i, &bin) in m.bins.iter().enumerate() {
            let dft = 2.0 * spectrum[bin] / n as f64;
            assert!((dft - m.line_amplitudes[i]).abs() < 1e-9, "bin {bin}");
            let level = 0.5 / (f[i] * 0.2 * ln_ratio).sqrt();
            assert!(
                dft >= SWEEP_LINE_SHARE * level,
                "bin {bin}: {dft} vs {level}"
            );
        }
        // Most of its power is in the band.
        let power = |bins: std::ops::Range<usize>| bins.map(|b| spectrum[b].powi(2)).sum::<f64>();
        let (low, high) = (1, 400);
        let inside = power(low..high + 1);
        assert!(inside > 0.95 * power(1..n / 2), "{inside}");
    }

    #[test]
    fn a_tone_is_one_line_on_its_bin() {
        let m = Multisine::tone(10_000.0, 2_000, 37, 3.0);
        assert_eq!(m.frequencies_hz(), vec![185.0]);
        let spectrum = spectrum(&m.period);
        for (bin, magnitude) in spectrum.iter().enumerate() {
            let expected = if bin == 37 { 3.0 * 1_000.0 } else { 0.0 };
            assert!((magnitude - expected).abs() < 1e-8, "bin {bin}");
        }
    }
}
