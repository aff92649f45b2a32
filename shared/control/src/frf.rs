//! Frequency responses estimated from records of a periodic excitation
//! (a [`crate::multisine::Multisine`]), closed loop or open (docs/control.md,
//! "Measuring the loop").
//!
//! Each signal of the loop (the excitation d, the plant input u, the output
//! y, the error e, ...) is cut into whole periods after the transient ones;
//! each period's DFT is read at the excited bins (no leakage: the lines sit
//! on bins). The response from signal a to signal b is then the ratio of
//! their period-averaged line spectra: with d as the instrument, the ratio
//! Y/U is the plant P even in closed loop, with no model of the controller
//! (the indirect estimate, (y/d)/(u/d)), and U/D the input sensitivity.
//! Each line's quality is its coherence over the periods: 1 when every
//! period showed the same spectrum, less with noise.

use crate::multisine::Multisine;
use nalgebra::Complex;
use realfft::RealFftPlanner;

type C64 = Complex<f64>;

/// Why a record cannot be read as the excitation's periods.
#[derive(Debug, Clone, PartialEq)]
pub enum FrfError {
    /// Fewer whole periods than asked for, after the transient ones.
    TooShort { samples: usize, needed: usize },
    /// The records to compare differ in lines or periods.
    Mismatch,
    /// A sample is NaN or infinite.
    NonFinite { sample: usize },
}

impl std::fmt::Display for FrfError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooShort { samples, needed } => write!(
                f,
                "the record holds {samples} samples; the periods asked for need {needed}"
            ),
            Self::Mismatch => write!(f, "the records differ in their lines or periods"),
            Self::NonFinite { sample } => write!(f, "sample {sample} is not a finite number"),
        }
    }
}

impl std::error::Error for FrfError {}

/// One signal's spectrum at the excited lines, period by period.
#[derive(Debug, Clone, PartialEq)]
pub struct LineSpectra {
    pub bins: Vec<usize>,
    /// `periods[p][i]`: period p's DFT at line i.
    pub periods: Vec<Vec<C64>>,
}

impl LineSpectra {
    /// Reads `record` (from the excitation's first sample on) as whole
    /// periods of `signal`, dropping the first `transient_periods` and
    /// keeping the next `periods`.
    pub fn of(
        record: &[f64],
        signal: &Multisine,
        transient_periods: usize,
        periods: usize,
    ) -> Result<Self, FrfError> {
        let n = signal.period_samples();
        let needed = n * (transient_periods + periods);
        if record.len() < needed || periods == 0 {
            return Err(FrfError::TooShort {
                samples: record.len(),
                needed: needed.max(n),
            });
        }
        if let Some(sample) = record[..needed].iter().position(|v| !v.is_finite()) {
            return Err(FrfError::NonFinite { sample });
        }
        let fft = RealFftPlanner::<f64>::new().plan_fft_forward(n);
        let mut input = fft.make_input_vec();
        let mut output = fft.make_output_vec();
        let spectra = (transient_periods..transient_periods + periods)
            .map(|p| {
                input.copy_from_slice(&record[p * n..(p + 1) * n]);
                fft.process(&mut input, &mut output)
                    .expect("buffers made by the plan fit it");
                signal.bins.iter().map(|&b| output[b]).collect()
            })
            .collect();
        Ok(Self {
            bins: signal.bins.clone(),
            periods: spectra,
        })
    }

    /// The period-averaged spectrum at each line.
    pub fn mean(&self) -> Vec<C64> {
        let count = self.periods.len() as f64;
        (0..self.bins.len())
            .map(|i| self.periods.iter().map(|p| p[i]).sum::<C64>() / count)
            .collect()
    }

    /// |mean|² / mean |·|² at each line: 1 when every period is the same.
    pub fn coherence(&self) -> Vec<f64> {
        let mean = self.mean();
        (0..self.bins.len())
            .map(|i| {
                let power = self.periods.iter().map(|p| p[i].norm_sqr()).sum::<f64>()
                    / self.periods.len() as f64;
                if power == 0.0 {
                    0.0
                } else {
                    mean[i].norm_sqr() / power
                }
            })
            .collect()
    }
}

/// A measured frequency response at the excitation's lines.
#[derive(Debug, Clone, PartialEq)]
pub struct Frf {
    pub frequencies_hz: Vec<f64>,
    pub response: Vec<C64>,
    /// The lower of the two signals' coherences at each line.
    pub coherence: Vec<f64>,
}

impl Frf {
    /// The response from `input` to `output`, both driven by the same
    /// periodic excitation: mean(output) / mean(input) at each line.
    pub fn between(
        signal: &Multisine,
        output: &LineSpectra,
        input: &LineSpectra,
    ) -> Result<Self, FrfError> {
        if output.bins != input.bins || output.periods.len() != input.periods.len() {
            return Err(FrfError::Mismatch);
        }
        let (num, den) = (output.mean(), input.mean());
        let response = num.iter().zip(&den).map(|(n, d)| n / d).collect();
        let coherence = output
            .coherence()
            .iter()
            .zip(input.coherence())
            .map(|(a, b)| a.min(b))
            .collect();
        Ok(Self {
            frequencies_hz: signal.frequencies_hz(),
            response,
            coherence,
        })
    }

    /// |H| in dB at each line.
    pub fn magnitude_db(&self) -> Vec<f64> {
        self.response
            .iter()
            .map(|h| 20.0 * h.norm().log10())
            .collect()
    }

    /// The largest |H| in dB over the lines whose coherence is at least
    /// `min_coherence`, and its frequency (None: no such line).
    pub fn peak_db(&self, min_coherence: f64) -> Option<(f64, f64)> {
        self.magnitude_db()
            .into_iter()
            .zip(&self.frequencies_hz)
            .zip(&self.coherence)
            .filter(|(_, c)| **c >= min_coherence)
            .map(|((db, f), _)| (db, *f))
            .max_by(|a, b| a.0.total_cmp(&b.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::freq::freq_response_discrete;
    use crate::lti::DiscreteStateSpace;
    use crate::multisine::{MultisineSpec, Phases};
    use nalgebra::DMatrix;
    use std::f64::consts::PI;

    const RATE: f64 = 10_000.0;

    fn signal() -> Multisine {
        Multisine::design(&MultisineSpec {
            rate_hz: RATE,
            period_samples: 1_000,
            f_min_hz: 10.0,
            f_max_hz: 3_000.0,
            max_lines: 40,
            amplitude: 1.0,
            phases: Phases::Schroeder,
        })
        .unwrap()
    }

    /// A lightly damped mode at 300 Hz (static gain 1), exact ZOH: a
    /// flexible plant in miniature.
    fn plant() -> DiscreteStateSpace {
        let ts = 1.0 / RATE;
        let (w, zeta) = (2.0 * PI * 300.0, 0.02);
        // x+ = A x + B u by the matrix exponential's series (short step).
        let ac = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -w * w, -2.0 * zeta * w]);
        let bc = DMatrix::from_row_slice(2, 1, &[0.0, w * w]);
        let mut a = DMatrix::identity(2, 2);
        let mut term = DMatrix::identity(2, 2);
        let mut integral = DMatrix::identity(2, 2) * ts;
        let mut iterm = DMatrix::identity(2, 2) * ts;
        for k in 1..30 {
            term = &term * &ac * (ts / k as f64);
            a += &term;
            iterm = &iterm * &ac * (ts / (k + 1) as f64);
            integral += &iterm;
        }
        DiscreteStateSpace {
            a,
            b: integral * bc,
            c: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            d: DMatrix::zeros(1, 1),
            ts,
        }
    }

    fn response_at(sys: &DiscreteStateSpace, f_hz: f64) -> C64 {
        freq_response_discrete(sys, 2.0 * PI * f_hz).unwrap()[(0, 0)]
    }

    /// The plant in closed loop with a proportional controller on y, acting
    /// one sample late (the loop's delay); `d` added to the plant input,
    /// `noise(k)` to the measured y. Returns (u, y_measured). Stable by the
    /// small gain: |k P| ≤ 0.03 · 25 < 1 at the resonance.
    fn closed_loop(d: &[f64], noise: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>) {
        let p = plant();
        let kp = 0.03;
        let mut x = DMatrix::zeros(2, 1);
        let mut u_c = 0.0;
        let (mut u_rec, mut y_rec) = (Vec::new(), Vec::new());
        for (k, dk) in d.iter().enumerate() {
            let y = (&p.c * &x)[(0, 0)] + noise(k);
            let u = u_c + dk;
            u_rec.push(u);
            y_rec.push(y);
            x = &p.a * &x + &p.b * u;
            // The command for the next sample (one sample of delay).
            u_c = -kp * y;
        }
        (u_rec, y_rec)
    }

    fn record(s: &Multisine, periods: usize) -> Vec<f64> {
        (0..periods * s.period_samples())
            .map(|k| s.period[k % s.period_samples()])
            .collect()
    }

    #[test]
    fn in_closed_loop_the_plant_is_measured_exactly_without_noise() {
        let s = signal();
        let d = record(&s, 14);
        let (u, y) = closed_loop(&d, |_| 0.0);
        // The mode's transient (τ = 1/(ζω) = 27 ms) is gone after 6 periods
        // (0.6 s, e^-22): 8 periods averaged.
        let y_lines = LineSpectra::of(&y, &s, 6, 8).unwrap();
        let u_lines = LineSpectra::of(&u, &s, 6, 8).unwrap();
        let measured = Frf::between(&s, &y_lines, &u_lines).unwrap();
        let p = plant();
        for ((f, h), c) in measured
            .frequencies_hz
            .iter()
            .zip(&measured.response)
            .zip(&measured.coherence)
        {
            let exact = response_at(&p, *f);
            assert!(
                (h - exact).norm() <= 1e-6 * exact.norm(),
                "{f} Hz: {h} against {exact}"
            );
            assert!(*c > 1.0 - 1e-9, "{f} Hz: coherence {c}");
        }
        // The input sensitivity U/D: 1 / (1 + C P), the controller's own.
        let d_lines = LineSpectra::of(&d, &s, 6, 8).unwrap();
        let si = Frf::between(&s, &u_lines, &d_lines).unwrap();
        assert!(
            si.peak_db(0.99).unwrap().0 > 0.0,
            "a loop amplifies somewhere"
        );
    }

    #[test]
    fn noise_lowers_the_coherence_and_averaging_keeps_the_estimate_close() {
        let s = signal();
        let d = record(&s, 26);
        let mut rng = oorandom::Rand64::new(3);
        let noise: Vec<f64> = (0..d.len())
            .map(|_| (rng.rand_float() - 0.5) * 2e-3)
            .collect();
        let (u, y) = closed_loop(&d, |k| noise[k]);
        let y_lines = LineSpectra::of(&y, &s, 6, 20).unwrap();
        let u_lines = LineSpectra::of(&u, &s, 6, 20).unwrap();
        let measured = Frf::between(&s, &y_lines, &u_lines).unwrap();
        let p = plant();
        let mut below_one = 0;
        for ((f, h), c) in measured
            .frequencies_hz
            .iter()
            .zip(&measured.response)
            .zip(&measured.coherence)
        {
            assert!(*c <= 1.0 + 1e-12);
            if *c < 1.0 - 1e-9 {
                below_one += 1;
            }
            if *c >= 0.99 {
                let exact = response_at(&p, *f);
                let db = 20.0 * (h.norm() / exact.norm()).log10();
                assert!(db.abs() < 0.5, "{f} Hz: {db} dB off at coherence {c}");
            }
        }
        assert!(below_one > 0, "noise shows in the coherence");
    }

    #[test]
    fn a_record_too_short_or_not_finite_is_refused() {
        let s = signal();
        let short = record(&s, 3);
        assert!(matches!(
            LineSpectra::of(&short, &s, 2, 2),
            Err(FrfError::TooShort { .. })
        ));
        let mut bad = record(&s, 4);
        bad[1_234] = f64::NAN;
        assert_eq!(
            LineSpectra::of(&bad, &s, 0, 4),
            Err(FrfError::NonFinite { sample: 1_234 })
        );
        let a = LineSpectra::of(&record(&s, 4), &s, 0, 4).unwrap();
        let b = LineSpectra::of(&record(&s, 4), &s, 0, 3).unwrap();
        assert_eq!(Frf::between(&s, &a, &b), Err(FrfError::Mismatch));
    }
}
