//! A frequency-response measurement of the running loop, from its recorded
//! signals (docs/control.md, "Measuring the loop").
//!
//! The scenario's `[measure]` added a periodic multisine at one point; the
//! sample file holds it (the measurement's `excitation`), the plant's input
//! and its outputs. With the excitation as the instrument each response is
//! a ratio of period-averaged line spectra, closed loop, with no model of
//! the controller (so a program of one's own is measured as the built-in
//! law is):
//!
//! | at the plant input (d) | at the sensor (n) | at the reference (r) |
//! |---|---|---|
//! | P = Y / (U + D) | P = Y_true / U | P = Y_true / U |
//! | S_i = (U + D) / D, the input sensitivity | S_o = Y / N, the output sensitivity | S_r = (R − Y) / R |
//! | T_i = −U / D | T_o = −Y_true / N | T_r = Y / R |
//! | PS = Y / D, the process sensitivity | CS = −U / N, the control sensitivity | CS_r = U / R |
//! | L_i = −U / (U + D), the loop gain | L_o = −Y_true / Y | L_r = Y / (R − Y) |
//!
//! (U the command applied, Y the measured output, Y_true without sensor
//! noise.) Beside each, the design's prediction: the exact discrete
//! response of the scenario's closed loop (`LoopDesign::closed_loop`, whose
//! inputs are [r; n; u_ff; w] and outputs [e_meas; y_meas; e_true; u_c]),
//! and of its plant. The command the plant applies at tick k is the one
//! computed `loop_delay_samples` ticks before, so u_c's responses are
//! delayed by as much to predict U's. A period in which the actuator reached its limit is no
//! longer the linear loop: it is left out of the averages, and said.

use crate::loop_report::PEAK_LIMIT_DB;
use flexloop_control::excitation::{ExcitationPlan, InjectionPoint};
use flexloop_control::freq::freq_response_discrete;
use flexloop_control::frf::{Frf, FrfError, LineSpectra};
use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays, ModelFileError};
use flexloop_protocol::{Measurement, flags};
use flexloop_recording::LogReader;
use nalgebra::Complex;
use std::f64::consts::PI;
use std::path::Path;

type C64 = Complex<f64>;

/// The coherence below which a line is not trusted in the verdicts.
pub const MIN_COHERENCE: f64 = 0.9;

/// Why a run's measurement cannot be computed.
#[derive(Debug, Clone, PartialEq)]
pub enum MeasurementError {
    /// The scenario has no `[measure]`.
    NotMeasured,
    /// The recording lacks samples of the measurement's ticks.
    Missing {
        first: u64,
        count: u64,
    },
    /// The run ended before the measured periods did.
    Unfinished {
        last_tick: u64,
        needed: u64,
    },
    /// Every measured period (of a stepped sine's tone) touched the
    /// actuator's limit.
    AllSaturated {
        periods: usize,
        tone_hz: Option<f64>,
    },
    Estimate(FrfError),
}

impl std::fmt::Display for MeasurementError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotMeasured => write!(f, "the run's scenario has no [measure]"),
            Self::Missing { first, count } => write!(
                f,
                "the recording misses {count} samples of the measurement's ticks, the first at \
                 tick {first}: the periods cannot be read whole"
            ),
            Self::Unfinished { last_tick, needed } => write!(
                f,
                "the run ended at tick {last_tick}, before the measured periods did (tick {needed})"
            ),
            Self::AllSaturated { periods, tone_hz } => write!(
                f,
                "the actuator reached its limit in all {periods} measured periods{}: lower \
                 measure.amplitude",
                tone_hz
                    .map(|hz| format!(" of the tone at {hz:.3} Hz"))
                    .unwrap_or_default()
            ),
            Self::Estimate(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for MeasurementError {}

/// The recorded signals over the measurement's ticks, from its start tick.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoopSignals {
    pub excitation: Vec<f64>,
    /// The command the plant applied (first input).
    pub u: Vec<f64>,
    /// The measured output (first output), sensor excitation included.
    pub y: Vec<f64>,
    /// The output without sensor noise or excitation.
    pub y_true: Vec<f64>,
}

impl LoopSignals {
    /// The plan's ticks, start to stop, out of the recorded measurements.
    pub fn from_measurements<'a>(
        plan: &ExcitationPlan,
        measurements: impl Iterator<Item = &'a Measurement>,
    ) -> Result<Self, MeasurementError> {
        let (start, stop) = (plan.start_tick, plan.stop_tick());
        let len = (stop - start) as usize;
        let mut signals = LoopSignals {
            excitation: vec![f64::NAN; len],
            u: vec![f64::NAN; len],
            y: vec![f64::NAN; len],
            y_true: vec![f64::NAN; len],
        };
        let mut last_tick = None;
        for m in measurements {
            last_tick = Some(last_tick.map_or(m.seq, |t: u64| t.max(m.seq)));
            if !(start..stop).contains(&m.seq) {
                continue;
            }
            let i = (m.seq - start) as usize;
            signals.excitation[i] = m.excitation;
            signals.u[i] = m.u_applied[0];
            signals.y[i] = m.y[0];
            signals.y_true[i] = m.y_true[0];
        }
        let last_tick = last_tick.unwrap_or(0);
        if last_tick + 1 < stop {
            return Err(MeasurementError::Unfinished {
                last_tick,
                needed: stop - 1,
            });
        }
        let missing: Vec<usize> = (0..len).filter(|&i| signals.y[i].is_nan()).collect();
        if let Some(&first) = missing.first() {
            return Err(MeasurementError::Missing {
                first: start + first as u64,
                count: missing.len() as u64,
            });
        }
        Ok(signals)
    }
}

/// One measured response and the design's prediction of it.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredResponse {
    /// `P`, `S_i`, `T_i`, `PS`, `L_i`, `S_o`, `T_o`, `CS`, `L_o`.
    pub name: &'static str,
    pub meaning: &'static str,
    pub measured: Frf,
    /// At the same lines; None when the loop is not analysed (a program of
    /// one's own serves a role) or, for P, without a plant model.
    pub predicted: Option<Vec<C64>>,
}

impl MeasuredResponse {
    /// Measured against predicted over the lines of coherence at least
    /// `min_coherence` in `band` (Hz): the largest |difference| in dB and
    /// in degrees, and the lines compared.
    pub fn deviation(&self, band: (f64, f64), min_coherence: f64) -> Option<Deviation> {
        let predicted = self.predicted.as_ref()?;
        let mut d = Deviation::default();
        for (i, f) in self.measured.frequencies_hz.iter().enumerate() {
            if !(band.0..band.1).contains(f) || self.measured.coherence[i] < min_coherence {
                continue;
            }
            let ratio = self.measured.response[i] / predicted[i];
            d.lines += 1;
            d.max_db = d.max_db.max((20.0 * ratio.norm().log10()).abs());
            d.max_degrees = d.max_degrees.max(ratio.arg().to_degrees().abs());
        }
        (d.lines > 0).then_some(d)
    }

    /// The lines of coherence at least [`MIN_COHERENCE`].
    pub fn trusted_lines(&self) -> usize {
        self.measured
            .coherence
            .iter()
            .filter(|c| **c >= MIN_COHERENCE)
            .count()
    }

    /// The largest predicted |H| in dB over the lines, and where.
    pub fn predicted_peak_db(&self) -> Option<(f64, f64)> {
        let predicted = self.predicted.as_ref()?;
        predicted
            .iter()
            .zip(&self.measured.frequencies_hz)
            .map(|(h, f)| (20.0 * h.norm().log10(), *f))
            .max_by(|a, b| a.0.total_cmp(&b.0))
    }
}

/// How far a measured response is from its prediction in a band.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Deviation {
    pub lines: usize,
    pub max_db: f64,
    pub max_degrees: f64,
}

/// The measurement of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopMeasurement {
    pub point: InjectionPoint,
    pub plan: ExcitationPlan,
    pub responses: Vec<MeasuredResponse>,
    /// Measured periods averaged, and those left out (0-based among the
    /// measured ones, a stepped sine's tones one after another) because
    /// the actuator reached its limit in them.
    pub periods_used: usize,
    pub periods_saturated: Vec<usize>,
}

impl LoopMeasurement {
    /// The responses of the loop `design` from its recorded `signals`.
    pub fn compute(
        design: &LoopDesign,
        plan: &ExcitationPlan,
        signals: &LoopSignals,
    ) -> Result<Self, MeasurementError> {
        let n = plan.period_samples();
        let transient = plan.transient_periods;
        // The plant's whole input: at the plant input, the command and the force.
        let input_force = plan.point == InjectionPoint::PlantInput;
        let u_total: Vec<f64> = signals
            .u
            .iter()
            .zip(&signals.excitation)
            .map(|(u, d)| if input_force { u + d } else { *u })
            .collect();
        let limit = design.input_limit * (1.0 - 1e-12);
        let tracking_error: Vec<f64> = match plan.point {
            InjectionPoint::Reference => signals
                .excitation
                .iter()
                .zip(&signals.y)
                .map(|(d, y)| d - y)
                .collect(),
            _ => Vec::new(),
        };
        // Each segment (one periodic signal, or a stepped sine's tone) is
        // read on its own; their lines are joined in the order they ran.
        let mut measured: Vec<Frf> = Vec::new();
        let mut saturated_all = Vec::new();
        for (i, segment) in plan.segments.iter().enumerate() {
            let from = (plan.segment_start(i) - plan.start_tick) as usize;
            let to = from + (transient + plan.periods) * n;
            let at = |record: &[f64]| record[from..to].to_vec();
            // A period whose input reached the actuator's limit.
            let saturated: Vec<usize> = (0..plan.periods)
                .filter(|p| {
                    let k = from + (transient + p) * n;
                    signals.u[k..k + n]
                        .iter()
                        .zip(&u_total[k..k + n])
                        .any(|(u, total)| u.abs() >= limit || total.abs() >= limit)
                })
                .collect();
            if saturated.len() == plan.periods {
                return Err(MeasurementError::AllSaturated {
                    periods: plan.periods,
                    tone_hz: (plan.segments.len() > 1).then(|| segment.frequencies_hz()[0]),
                });
            }
            saturated_all.extend(saturated.iter().map(|p| i * plan.periods + p));
            let spectra = |record: &[f64]| -> Result<LineSpectra, MeasurementError> {
                let record = without_drift(&at(record), n, transient, plan.periods);
                let mut lines = LineSpectra::of(&record, segment, transient, plan.periods)
                    .map_err(MeasurementError::Estimate)?;
                let mut index = 0;
                lines.periods.retain(|_| {
                    let keep = !saturated.contains(&index);
                    index += 1;
                    keep
                });
                Ok(lines)
            };
            let d = spectra(&signals.excitation)?;
            let u = spectra(&signals.u)?;
            let total = spectra(&u_total)?;
            let y = spectra(&signals.y)?;
            let y_true = spectra(&signals.y_true)?;
            // At the reference: the set-point's error, excitation less output
            // (the held reference is a constant, on no line).
            let error = match plan.point {
                InjectionPoint::Reference => Some(spectra(&tracking_error)?),
                _ => None,
            };
            let between = |out: &LineSpectra, input: &LineSpectra| {
                Frf::between(segment, out, input).map_err(MeasurementError::Estimate)
            };
            // −out / input: the sign flips the ratio, not its coherence.
            let against = |out: &LineSpectra, input: &LineSpectra| {
                between(out, input).map(|mut frf| {
                    frf.response.iter_mut().for_each(|h| *h = -*h);
                    frf
                })
            };
            let these = match (plan.point, &error) {
                (InjectionPoint::Reference, Some(e)) => [
                    between(&y_true, &u)?,
                    between(&y, &d)?,
                    between(e, &d)?,
                    between(&u, &d)?,
                    between(&y, e)?,
                ],
                (InjectionPoint::Reference, None) => unreachable!("read above"),
                (InjectionPoint::PlantInput, _) => [
                    between(&y, &total)?,
                    between(&total, &d)?,
                    against(&u, &d)?,
                    between(&y, &d)?,
                    against(&u, &total)?,
                ],
                (InjectionPoint::Sensor, _) => [
                    between(&y_true, &u)?,
                    between(&y, &d)?,
                    against(&y_true, &d)?,
                    against(&u, &d)?,
                    against(&y_true, &y)?,
                ],
            };
            if measured.is_empty() {
                measured = these.to_vec();
            } else {
                for (joined, more) in measured.iter_mut().zip(these) {
                    joined.frequencies_hz.extend(more.frequencies_hz);
                    joined.response.extend(more.response);
                    joined.coherence.extend(more.coherence);
                }
            }
        }
        let names = match plan.point {
            InjectionPoint::PlantInput => ["P", "S_i", "T_i", "PS", "L_i"],
            InjectionPoint::Sensor => ["P", "S_o", "T_o", "CS", "L_o"],
            InjectionPoint::Reference => ["P", "T_r", "S_r", "CS_r", "L_r"],
        };
        let lines = plan.frequencies_hz();
        let responses = names
            .into_iter()
            .zip(measured)
            .map(|(name, frf)| response(name, frf, predicted(design, plan.point, name, &lines)))
            .collect();
        let total_periods = plan.segments.len() * plan.periods;
        Ok(Self {
            point: plan.point,
            plan: plan.clone(),
            responses,
            periods_used: total_periods - saturated_all.len(),
            periods_saturated: saturated_all,
        })
    }

    /// The measurement `plan` of the loop `design` from its recorded
    /// samples. The plant starts a measurement ordered on a running loop
    /// once it is designed, no earlier than planned: its `EXCITING` flag
    /// says where it did, and the periods are read from there.
    pub fn of_log(
        design: &LoopDesign,
        plan: &ExcitationPlan,
        log: &LogReader,
    ) -> Result<Self, MeasurementError> {
        let mut plan = plan.clone();
        if let Some(first) = log
            .measurements()
            .filter(|m| m.seq >= plan.start_tick && m.flags & flags::EXCITING != 0)
            .map(|m| m.seq)
            .min()
        {
            plan.start_tick = first;
        }
        let signals = LoopSignals::from_measurements(&plan, log.measurements())?;
        Self::compute(design, &plan, &signals)
    }

    pub fn response(&self, name: &str) -> Option<&MeasuredResponse> {
        self.responses.iter().find(|r| r.name == name)
    }

    /// The loop gain at the measured point (`L_i`, `L_o` or `L_r`).
    pub fn loop_gain(&self) -> &MeasuredResponse {
        let name = match self.point {
            InjectionPoint::PlantInput => "L_i",
            InjectionPoint::Sensor => "L_o",
            InjectionPoint::Reference => "L_r",
        };
        self.response(name)
            .expect("every measurement has its loop gain")
    }

    /// The sensitivity the 6 dB rule bounds at the measured point.
    pub fn sensitivity(&self) -> &MeasuredResponse {
        let name = match self.point {
            InjectionPoint::PlantInput => "S_i",
            InjectionPoint::Sensor => "S_o",
            // The set-point's error: the output sensitivity of a loop
            // without MC (with MC the error the feedback sees differs).
            InjectionPoint::Reference => "S_r",
        };
        self.response(name)
            .expect("every measurement has its sensitivity")
    }

    /// The measured sensitivity's peak (dB, Hz) over the trusted lines, and
    /// whether it keeps the 6 dB rule; None at the reference, whose S_r is
    /// the loop's sensitivity only without MC (the rule is read at the plant
    /// input or the sensor).
    pub fn rule(&self) -> Option<(f64, f64, bool)> {
        if self.point == InjectionPoint::Reference {
            return None;
        }
        let (db, hz) = self.sensitivity().measured.peak_db(MIN_COHERENCE)?;
        Some((db, hz, db <= PEAK_LIMIT_DB))
    }

    /// Decade bands over the measured lines, for the per-band comparison.
    pub fn bands(&self) -> Vec<(f64, f64)> {
        let lines = self.plan.frequencies_hz();
        let (Some(&lo), Some(&hi)) = (lines.first(), lines.last()) else {
            return Vec::new();
        };
        let mut edge = 10f64.powf(lo.log10().floor());
        let mut bands = Vec::new();
        // Bounded: 128 lines span at most a few dozen decades.
        while edge <= hi && bands.len() < 64 {
            bands.push((edge, edge * 10.0));
            edge *= 10.0;
        }
        bands
    }

    /// The file's columns: `frequency_hz`, then per response its measured
    /// real and imaginary parts and coherence, and the design's (`_model_`)
    /// parts where it predicts one.
    fn columns(&self) -> Vec<(String, Vec<f64>)> {
        let mut columns = vec![("frequency_hz".to_string(), self.plan.frequencies_hz())];
        for r in &self.responses {
            let part = |f: fn(&C64) -> f64, values: &[C64]| values.iter().map(f).collect();
            columns.push((
                format!("{}_re", r.name),
                part(|c| c.re, &r.measured.response),
            ));
            columns.push((
                format!("{}_im", r.name),
                part(|c| c.im, &r.measured.response),
            ));
            columns.push((
                format!("{}_coherence", r.name),
                r.measured.coherence.clone(),
            ));
            if let Some(predicted) = &r.predicted {
                columns.push((format!("{}_model_re", r.name), part(|c| c.re, predicted)));
                columns.push((format!("{}_model_im", r.name), part(|c| c.im, predicted)));
            }
        }
        columns
    }

    /// The responses as a CSV file, one line per excited line (written
    /// whole or not at all: a temporary file renamed).
    pub fn write_csv(&self, path: &Path) -> std::io::Result<()> {
        let columns = self.columns();
        let mut text = columns
            .iter()
            .map(|(name, _)| name.as_str())
            .collect::<Vec<_>>()
            .join(",");
        text.push('\n');
        for i in 0..columns[0].1.len() {
            let row: Vec<String> = columns.iter().map(|(_, v)| format!("{:e}", v[i])).collect();
            text += &row.join(",");
            text.push('\n');
        }
        let tmp = path.with_extension("csv.tmp");
        let written = std::fs::write(&tmp, text).and_then(|()| std::fs::rename(&tmp, path));
        if written.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        written
    }

    /// The same columns as a NumPy `.npz` (`np.load` reads it).
    pub fn write_npz(&self, path: &Path) -> Result<(), ModelFileError> {
        let columns: Vec<(String, Array)> = self
            .columns()
            .into_iter()
            .map(|(name, values)| {
                let n = values.len();
                let array = Array::new(vec![n], values).expect("a column's shape is its length");
                (name, array)
            })
            .collect();
        let named: Vec<(&str, Array)> = columns
            .iter()
            .map(|(name, array)| (name.as_str(), array.clone()))
            .collect();
        ModelArrays::write_npz(path, &named)
    }

    /// What `flexloop measure` prints.
    pub fn render_text(&self) -> String {
        let lines = self.plan.frequencies_hz();
        let each = if self.plan.segments.len() > 1 {
            " (over all tones)"
        } else {
            ""
        };
        let mut out = format!(
            "excitation: a {} of {} lines from {:.3} to {:.1} Hz at the {}, {} periods of {} \
             samples averaged{each} after {} transient\n",
            self.plan.shape.name(),
            lines.len(),
            lines.first().copied().unwrap_or_default(),
            lines.last().copied().unwrap_or_default(),
            self.point.name(),
            self.periods_used,
            self.plan.period_samples(),
            self.plan.transient_periods,
        );
        if !self.periods_saturated.is_empty() {
            out += &format!(
                "  left out: measured periods {:?} (the actuator reached its limit in them)\n",
                self.periods_saturated
            );
        }
        if let Some((db, hz, keeps)) = self.rule() {
            let name = self.sensitivity().name;
            let predicted = self
                .sensitivity()
                .predicted_peak_db()
                .map(|(p, f)| format!(" (the design: {p:.2} dB at {f:.1} Hz)"))
                .unwrap_or_default();
            out += &format!(
                "peak of |{name}|: {db:.2} dB at {hz:.1} Hz{predicted}: {}\n",
                if keeps {
                    "keeps the 6 dB rule"
                } else {
                    "breaks the 6 dB rule"
                }
            );
        }
        out += &format!("measured against the design (lines of coherence >= {MIN_COHERENCE}):\n");
        for r in &self.responses {
            let trusted = r.trusted_lines();
            out += &format!(
                "  {:<4} {} ({trusted} of {} lines trusted)",
                r.name,
                r.meaning,
                r.measured.response.len()
            );
            if r.predicted.is_none() {
                out += ": no prediction (the loop is not analysed)\n";
                continue;
            }
            out += "\n";
            for band in self.bands() {
                if let Some(d) = r.deviation(band, MIN_COHERENCE) {
                    out += &format!(
                        "       {:>7.1}-{:<7.1} Hz: within {:.2} dB and {:.1} deg on {} lines\n",
                        band.0, band.1, d.max_db, d.max_degrees, d.lines
                    );
                }
            }
        }
        out
    }
}

/// `record` less its drift over the measured periods: a slope that is the
/// same in every period (a rigid body moving, an integrator still
/// settling) is not periodic, and its DFT would leak into every line,
/// period after period alike (coherence cannot show it). The slope is read
/// from the differences one period apart, in which the periodic response
/// cancels, so the periodic part is left exactly as it was.
fn without_drift(record: &[f64], n: usize, transient: usize, periods: usize) -> Vec<f64> {
    let measured = transient * n..(transient + periods) * n;
    let pairs = (periods - 1) * n;
    let mut out = record.to_vec();
    if pairs == 0 || record.len() < measured.end {
        return out;
    }
    let slope = (measured.start..measured.end - n)
        .map(|k| record[k + n] - record[k])
        .sum::<f64>()
        / (pairs * n) as f64;
    for (k, v) in out.iter_mut().enumerate() {
        *v -= slope * k as f64;
    }
    out
}

fn response(name: &'static str, measured: Frf, predicted: Option<Vec<C64>>) -> MeasuredResponse {
    MeasuredResponse {
        name,
        meaning: meaning(name),
        measured,
        predicted,
    }
}

/// What a response of a measurement is.
fn meaning(name: &str) -> &'static str {
    match name {
        "P" => "the plant, y / u",
        "S_i" => "the input sensitivity 1/(1 + CP)",
        "T_i" => "the input complementary sensitivity CP/(1 + CP)",
        "PS" => "the process sensitivity P/(1 + CP)",
        "L_i" => "the loop gain CP at the plant input",
        "S_o" => "the output sensitivity 1/(1 + PC)",
        "T_o" => "the output complementary sensitivity PC/(1 + PC)",
        "CS" => "the control sensitivity C/(1 + PC)",
        "L_o" => "the loop gain PC at the sensor",
        "T_r" => "the reference's complementary sensitivity y / r",
        "S_r" => "the reference's sensitivity (r - y) / r",
        "CS_r" => "the reference's control sensitivity u / r",
        "L_r" => "T_r / S_r, the loop gain PC of a loop without MC",
        _ => "",
    }
}

/// The design's response `name` (one a measurement at `point` gives:
/// `P`, `S_i`, ... as [`LoopMeasurement::responses`] names them) at
/// `frequencies_hz`: what the measurement is compared with, and what a
/// report draws between the lines. None where the design predicts none (a
/// program of one's own serves a role: only P).
pub fn predicted(
    design: &LoopDesign,
    point: InjectionPoint,
    name: &str,
    frequencies_hz: &[f64],
) -> Option<Vec<C64>> {
    let at = Prediction::new(design, frequencies_hz);
    let one = C64::new(1.0, 0.0);
    match (point, name) {
        (_, "P") => at.plant(),
        (InjectionPoint::PlantInput, "S_i") => at.map(|g| one + g.u_c_from_w),
        (InjectionPoint::PlantInput, "T_i") => at.map(|g| -g.u_c_from_w),
        (InjectionPoint::PlantInput, "PS") => at.map(|g| g.y_from_w),
        (InjectionPoint::PlantInput, "L_i") => at.map(|g| -g.u_c_from_w / (one + g.u_c_from_w)),
        (InjectionPoint::Sensor, "S_o") => at.map(|g| g.y_from_n),
        (InjectionPoint::Sensor, "T_o") => at.map(|g| g.e_true_from_n),
        (InjectionPoint::Sensor, "CS") => at.map(|g| -g.u_c_from_n),
        (InjectionPoint::Sensor, "L_o") => at.map(|g| g.e_true_from_n / g.y_from_n),
        (InjectionPoint::Reference, "T_r") => at.map(|g| g.y_from_r),
        (InjectionPoint::Reference, "S_r") => at.map(|g| one - g.y_from_r),
        (InjectionPoint::Reference, "CS_r") => at.map(|g| g.u_c_from_r),
        (InjectionPoint::Reference, "L_r") => at.map(|g| g.y_from_r / (one - g.y_from_r)),
        _ => None,
    }
}

/// The design's closed loop at one line, the entries a measurement needs
/// (`u_c` delayed to the tick it is applied at).
#[derive(Debug, Clone, Copy)]
struct LoopAt {
    u_c_from_w: C64,
    y_from_w: C64,
    y_from_n: C64,
    u_c_from_n: C64,
    e_true_from_n: C64,
    y_from_r: C64,
    u_c_from_r: C64,
}

/// The design's responses at the lines.
struct Prediction {
    plant: Option<Vec<C64>>,
    closed_loop: Option<Vec<LoopAt>>,
}

impl Prediction {
    fn new(design: &LoopDesign, lines_hz: &[f64]) -> Self {
        let at = |sys: &flexloop_control::lti::DiscreteStateSpace| {
            lines_hz
                .iter()
                .map(|f| freq_response_discrete(sys, 2.0 * PI * f).ok())
                .collect::<Option<Vec<_>>>()
        };
        let plant = at(&design.plant).map(|g| g.iter().map(|m| m[(0, 0)]).collect());
        let (ny, nu) = (design.n_outputs, design.n_inputs);
        // Inputs [r; n; u_ff; w], outputs [e_meas; y_meas; e_true; u_c].
        let (n, w) = (ny, 2 * ny + nu);
        let (y_meas, e_true, u_c) = (ny, 2 * ny, 3 * ny);
        let delay = f64::from(design.loop_delay_samples) * design.ts;
        let closed_loop = design.closed_loop.as_ref().and_then(at).map(|g| {
            g.iter()
                .zip(lines_hz)
                .map(|(m, f)| {
                    let applied = C64::from_polar(1.0, -2.0 * PI * f * delay);
                    LoopAt {
                        u_c_from_w: applied * m[(u_c, w)],
                        y_from_w: m[(y_meas, w)],
                        y_from_n: m[(y_meas, n)],
                        u_c_from_n: applied * m[(u_c, n)],
                        e_true_from_n: m[(e_true, n)],
                        y_from_r: m[(y_meas, 0)],
                        u_c_from_r: applied * m[(u_c, 0)],
                    }
                })
                .collect()
        });
        Self { plant, closed_loop }
    }

    fn plant(&self) -> Option<Vec<C64>> {
        self.plant.clone()
    }

    fn map(&self, f: impl Fn(&LoopAt) -> C64) -> Option<Vec<C64>> {
        self.closed_loop
            .as_ref()
            .map(|lines| lines.iter().map(f).collect())
    }
}
