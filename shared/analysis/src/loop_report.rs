//! The design report of any scenario's loop, from the discrete closed loop
//! the processes run (docs/control.md §8, §9): the plant's flexible modes with
//! the damping the loop gives them, the observer's error poles, stability,
//! and per output the peaks of |S^I| and |S^O| (the 6 dB rule) and the
//! sensitivity bandwidth. For MIMO loops the peaks of the largest singular
//! value are reported beside the per-axis (diagonal) ones.
//!
//! The thesis chain's own report (every case, the largest f_bw per case) is
//! [`crate::thesis_design`]; this one describes the single design a
//! scenario runs, whatever the model.

use flexloop_control::closed_loop::closed_loop_modes;
use flexloop_control::freq::{freq_response_discrete, log_grid_hz};
use flexloop_control::linalg::{LinalgError, spectral_radius};
use flexloop_control::lti::{DiscreteStateSpace, StateSpaceError};
use flexloop_design::LoopDesign;
use flexloop_scenario::Scenario;
use nalgebra::{Complex, DMatrix};
use serde::Serialize;
use std::f64::consts::PI;
use std::fmt::{self, Write};

/// The limit of the 6 dB rule on |S^I| and |S^O| (docs/control.md §9).
pub const PEAK_LIMIT_DB: f64 = 6.0;

/// Frequencies evaluated, log-spaced from 0.1 Hz to just below Nyquist.
const GRID_POINTS: usize = 600;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlexibleModeRow {
    pub frequency_hz: f64,
    pub open_loop: f64,
    /// Damping and frequency of the closed-loop pole that is this mode: the
    /// least damped within 5 % (as `modal_damping`), or where the loop moved
    /// it further (a low mode under a loop of similar bandwidth) the nearest
    /// within 30 %; observer error poles left out.
    pub closed_loop: Option<f64>,
    pub closed_loop_hz: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisLoop {
    pub output: String,
    /// Peak of |S^I_ii| (r_i → e_meas,i) and of |S^O_ii| (n_i → y_meas,i) [dB]
    /// and where they are [Hz].
    pub peak_si_db: f64,
    pub peak_si_hz: f64,
    pub peak_so_db: f64,
    pub peak_so_hz: f64,
    /// First frequency where |S^I_ii| reaches −3 dB (None: not below
    /// Nyquist, or no feedback on e_meas).
    pub bandwidth_hz: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopReport {
    pub scenario: String,
    pub model: String,
    pub rate_hz: f64,
    pub loop_delay_samples: u32,
    pub outputs: Vec<String>,
    pub inputs: usize,
    pub output_unit: &'static str,
    pub input_unit: &'static str,
    /// What closes the loop, in words.
    pub controller: String,
    pub observer: String,
    pub spectral_radius: f64,
    pub stable: bool,
    pub flexible_modes: Vec<FlexibleModeRow>,
    /// Poles of the observer's error dynamics (Hz, ζ), complex pairs.
    pub observer_poles: Vec<(f64, f64)>,
    pub axes: Vec<AxisLoop>,
    /// Peaks of the largest singular value of S^I and S^O [dB] (MIMO).
    pub peak_si_sigma_db: f64,
    pub peak_so_sigma_db: f64,
    /// Every peak within [`PEAK_LIMIT_DB`].
    pub meets_6db_rule: bool,
}

/// Why a loop's report could not be computed.
#[derive(Debug, Clone, PartialEq)]
pub enum LoopReportError {
    /// The closed loop's eigenvalues.
    Eigenvalues(LinalgError),
    /// The sensitivities' state space (r → e_meas, n → y_meas).
    Sensitivities(StateSpaceError),
    /// The frequency response at `hz`.
    Response { hz: f64, error: LinalgError },
}

impl fmt::Display for LoopReportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Eigenvalues(e) => write!(f, "closed-loop eigenvalues: {e}"),
            Self::Sensitivities(e) => write!(f, "{e}"),
            Self::Response { hz, error } => {
                write!(f, "frequency response at {hz:.3} Hz: {error}")
            }
        }
    }
}

impl std::error::Error for LoopReportError {}

/// The report of the loop `design` (built from `scenario`).
pub fn loop_report(
    scenario: &Scenario,
    design: &LoopDesign,
) -> Result<LoopReport, LoopReportError> {
    let cl = &design.closed_loop;
    let ny = design.n_outputs;
    let radius = spectral_radius(&cl.a).map_err(LoopReportError::Eigenvalues)?;
    // Only r → e_meas and n → y_meas are needed: the first 2 n_y inputs and outputs.
    let sens = DiscreteStateSpace::new(
        cl.a.clone(),
        cl.b.columns(0, 2 * ny).into_owned(),
        cl.c.rows(0, 2 * ny).into_owned(),
        cl.d.view((0, 0), (2 * ny, 2 * ny)).into_owned(),
        cl.ts,
    )
    .map_err(LoopReportError::Sensitivities)?;
    let nyquist = 0.5 / design.ts;
    let grid = log_grid_hz(0.1, 0.999 * nyquist, GRID_POINTS);
    let mut axes: Vec<AxisLoop> = design
        .output_names
        .iter()
        .map(|name| AxisLoop {
            output: name.clone(),
            peak_si_db: f64::NEG_INFINITY,
            peak_si_hz: 0.0,
            peak_so_db: f64::NEG_INFINITY,
            peak_so_hz: 0.0,
            bandwidth_hz: None,
        })
        .collect();
    let (mut sigma_si, mut sigma_so) = (0.0f64, 0.0f64);
    let has_feedback = design.feedback.is_some();
    let db = |v: f64| 20.0 * v.log10();
    for &f in &grid {
        let g = freq_response_discrete(&sens, 2.0 * PI * f)
            .map_err(|error| LoopReportError::Response { hz: f, error })?;
        for (i, axis) in axes.iter_mut().enumerate() {
            let si = db(g[(i, i)].norm());
            let so = db(g[(ny + i, ny + i)].norm());
            if si > axis.peak_si_db {
                (axis.peak_si_db, axis.peak_si_hz) = (si, f);
            }
            if so > axis.peak_so_db {
                (axis.peak_so_db, axis.peak_so_hz) = (so, f);
            }
            // Without feedback on e_meas (state feedback) S^I is 1: no bandwidth.
            if has_feedback && axis.bandwidth_hz.is_none() && si >= -3.0103 {
                axis.bandwidth_hz = Some(f);
            }
        }
        sigma_si = sigma_si.max(largest_singular_value(
            &g.view((0, 0), (ny, ny)).into_owned(),
        ));
        sigma_so = sigma_so.max(largest_singular_value(
            &g.view((ny, ny), (ny, ny)).into_owned(),
        ));
    }
    let (peak_si_sigma_db, peak_so_sigma_db) = (db(sigma_si), db(sigma_so));
    let stable = radius < 1.0;
    let meets_6db_rule = stable
        && peak_si_sigma_db <= PEAK_LIMIT_DB
        && peak_so_sigma_db <= PEAK_LIMIT_DB
        && axes
            .iter()
            .all(|a| a.peak_si_db <= PEAK_LIMIT_DB && a.peak_so_db <= PEAK_LIMIT_DB);
    let poles: Vec<(f64, f64)> = closed_loop_modes(cl)
        .unwrap_or_default()
        .into_iter()
        .filter(|(f, z)| {
            f.is_finite()
                && z.is_finite()
                && !design
                    .observer_modes
                    .iter()
                    .any(|(fo, zo)| (f - fo).abs() < 0.2 && (z - zo).abs() < 1e-3)
        })
        .collect();
    let flexible_modes = design
        .flexible_modes
        .iter()
        .map(|&(fm, open_loop)| {
            let near = |tolerance: f64| {
                poles
                    .iter()
                    .filter(move |(f, _)| (f - fm).abs() < tolerance * fm)
            };
            let pole = near(0.05)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .or_else(|| near(0.3).min_by(|a, b| (a.0 - fm).abs().total_cmp(&(b.0 - fm).abs())));
            FlexibleModeRow {
                frequency_hz: fm,
                open_loop,
                closed_loop: pole.map(|p| p.1),
                closed_loop_hz: pole.map(|p| p.0),
            }
        })
        .collect();
    let mut observer_poles = design.observer_modes.clone();
    observer_poles.sort_by(|a, b| a.0.total_cmp(&b.0));
    let c = &scenario.controller;
    let controller = match c.feedback.as_str() {
        "pid" if ny > 1 || design.n_inputs > 1 => format!(
            "PID f_bw {} Hz on each of {} rigid-body-decoupled axes",
            c.bandwidth_hz, ny
        ),
        "pid" => format!("PID f_bw {} Hz", c.bandwidth_hz),
        _ if scenario.observer.design == "state-feedback" => "state feedback".to_string(),
        _ => "none".to_string(),
    };
    let o = &scenario.observer;
    let observer = match o.design.as_str() {
        "kalman" => {
            let mut parts = vec![format!(
                "Kalman predictor, {} states",
                design.observer.estimate_map.nrows()
            )];
            if o.mc {
                parts.push("MC".into());
            }
            if o.ad {
                parts.push(match o.damping_target {
                    Some(z) => format!("AD to ζ {z}"),
                    None => format!("AD +{}", o.damping_increase),
                });
            }
            parts.join(", ")
        }
        other => other.to_string(),
    };
    Ok(LoopReport {
        scenario: scenario.name.clone(),
        model: scenario.plant.model.clone(),
        rate_hz: scenario.timing.rate_hz,
        loop_delay_samples: design.loop_delay_samples,
        outputs: design.output_names.clone(),
        inputs: design.n_inputs,
        output_unit: design.output_unit,
        input_unit: design.input_unit,
        controller,
        observer,
        spectral_radius: radius,
        stable,
        flexible_modes,
        observer_poles,
        axes,
        peak_si_sigma_db,
        peak_so_sigma_db,
        meets_6db_rule,
    })
}

fn largest_singular_value(m: &DMatrix<Complex<f64>>) -> f64 {
    if m.nrows() == 1 {
        return m[(0, 0)].norm();
    }
    m.clone()
        .svd(false, false)
        .singular_values
        .iter()
        .fold(0.0, |a, b| a.max(*b))
}

impl LoopReport {
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Loop design of `{}` ({}): {} Hz, loop delay {} sample{}",
            self.scenario,
            self.model,
            self.rate_hz,
            self.loop_delay_samples,
            if self.loop_delay_samples == 1 {
                ""
            } else {
                "s"
            }
        );
        let _ = writeln!(
            s,
            "  outputs [{}]: {}; {} input{} [{}]",
            self.output_unit,
            self.outputs.join(", "),
            self.inputs,
            if self.inputs == 1 { "" } else { "s" },
            self.input_unit
        );
        let _ = writeln!(s, "  controller: {}", self.controller);
        let _ = writeln!(s, "  observer: {}", self.observer);
        let _ = writeln!(
            s,
            "  closed loop: spectral radius {:.6} ({})",
            self.spectral_radius,
            if self.stable { "stable" } else { "UNSTABLE" }
        );
        if !self.flexible_modes.is_empty() {
            let _ = writeln!(s, "\nFlexible modes of the plant");
            let _ = writeln!(
                s,
                "  {:>4} {:>10} {:>10} {:>12} {:>14}",
                "mode", "f [Hz]", "open loop", "closed loop", "at [Hz]"
            );
            for (i, m) in self.flexible_modes.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "  {:>4} {:>10.1} {:>10.4} {:>12} {:>14}",
                    i + 1,
                    m.frequency_hz,
                    m.open_loop,
                    m.closed_loop.map_or("-".into(), |z| format!("{z:.4}")),
                    m.closed_loop_hz.map_or("-".into(), |f| format!("{f:.1}"))
                );
            }
        }
        if !self.observer_poles.is_empty() {
            let _ = writeln!(s, "\nObserver error poles (complex pairs)");
            for (f, z) in &self.observer_poles {
                let _ = writeln!(s, "  {f:>10.1} Hz  ζ {z:.4}");
            }
        }
        let _ = writeln!(
            s,
            "\nSensitivities (6 dB rule: peaks of |S^I| and |S^O| <= {PEAK_LIMIT_DB} dB)"
        );
        let _ = writeln!(
            s,
            "  {:<24} {:>18} {:>18} {:>16}",
            "output", "|S^I| peak", "|S^O| peak", "|S^I| = -3 dB"
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "  {:<24} {:>7.2} dB @{:>6.1} {:>7.2} dB @{:>6.1} {:>13}",
                a.output,
                a.peak_si_db,
                a.peak_si_hz,
                a.peak_so_db,
                a.peak_so_hz,
                a.bandwidth_hz.map_or("-".into(), |f| format!("{f:.1} Hz"))
            );
        }
        if self.axes.len() > 1 {
            let _ = writeln!(
                s,
                "  largest singular value: |S^I| {:.2} dB, |S^O| {:.2} dB",
                self.peak_si_sigma_db, self.peak_so_sigma_db
            );
        }
        let _ = writeln!(
            s,
            "  6 dB rule {}",
            if self.meets_6db_rule {
                "met"
            } else {
                "NOT met"
            }
        );
        s
    }
}
