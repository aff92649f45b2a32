//! The design report of any scenario's loop, from the discrete closed loop
//! the processes run (docs/control.md §6, §10.1): the plant's flexible modes
//! with the damping the loop gives them and the observer-error poles near
//! them, the observer's error poles, stability and its margin (the spectral
//! radius, the least damped closed-loop pole), per output the peaks of
//! |S^I| and |S^O| (the 6 dB rule) and the sensitivity bandwidth, and the
//! largest PID f_bw meeting the rule on this loop (its observer, its delay,
//! its notches: flexloop-design's `pid_bandwidth`). For MIMO loops the
//! peaks of the largest singular value are reported beside the per-axis
//! (diagonal) ones.
//!
//! The frequency grid is log-spaced and refined around every lightly damped
//! closed-loop pole, where the peaks of a 0.5 %-damped structure are only
//! about 1 % wide.
//!
//! [`LoopReport::warning`] is the one line `up` and `run` print when the
//! loop breaks the rule or is close to unstable ([`CLOSE_ZETA`],
//! [`CLOSE_RADIUS`]).
//!
//! The thesis chain's study (every case, the largest f_bw per case) is
//! [`crate::thesis_design`]; this one describes the single design a
//! scenario runs, whatever the model.

use flexloop_control::closed_loop::closed_loop_modes;
use flexloop_control::freq::{freq_response_discrete, log_grid_hz};
use flexloop_control::linalg::{LinalgError, spectral_radius};
use flexloop_control::lti::{DiscreteStateSpace, StateSpaceError};
use flexloop_design::LoopDesign;
use flexloop_design::pid_bandwidth::{self, SisoLoop};
use flexloop_scenario::Scenario;
use nalgebra::{Complex, DMatrix};
use serde::Serialize;
use std::f64::consts::PI;
use std::fmt::{self, Write};

/// The limit of the 6 dB rule on |S^I| and |S^O| (docs/control.md §6).
pub const PEAK_LIMIT_DB: f64 = pid_bandwidth::PEAK_LIMIT_DB;

/// "Close to unstable": a closed-loop pole (continuous equivalent) damped
/// less than 0.1 % (a fifth of the thesis chain's structural 0.5 %: it rings
/// for more than 150 periods) where the plant's own modes are damped more
/// than twice that, i.e. the loop has taken most of a mode's damping away.
pub const CLOSE_ZETA: f64 = 0.001;
/// ... or a closed-loop spectral radius above this: a pole that decays by
/// less than 1 % in 10⁴ samples (1 s at 10 kHz), a loop on the edge.
pub const CLOSE_RADIUS: f64 = 0.999_999;

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
    /// The least damped observer-error pole within 10 % of the mode
    /// (Hz, ζ): the observer's own estimate of the mode, which the loop
    /// carries as well (separation).
    pub observer_error: Option<(f64, f64)>,
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
    /// τ_d [µs] when each command acts on arrival (`loop.command_deadline_us`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub command_deadline_us: Option<f64>,
    pub outputs: Vec<String>,
    pub inputs: usize,
    pub output_unit: &'static str,
    pub input_unit: &'static str,
    /// What closes the loop, in words.
    pub controller: String,
    pub observer: String,
    /// The f_bw the PID runs [Hz] and whether `"auto"` chose it.
    pub pid_bandwidth_hz: Option<f64>,
    pub pid_bandwidth_auto: bool,
    /// The largest f_bw on the 0.5 Hz grid meeting the 6 dB rule with a
    /// stable loop here (None: none does, or not searched: see
    /// `largest_bandwidth_note`).
    pub largest_bandwidth_hz: Option<f64>,
    /// Why the largest f_bw was not searched or found, in words.
    pub largest_bandwidth_note: Option<String>,
    pub spectral_radius: f64,
    pub stable: bool,
    /// The least damped oscillating closed-loop pole (Hz, ζ), continuous
    /// equivalent.
    pub least_damped: Option<(f64, f64)>,
    /// [`CLOSE_ZETA`] or [`CLOSE_RADIUS`] crossed (and stable).
    pub close_to_unstable: bool,
    pub flexible_modes: Vec<FlexibleModeRow>,
    /// Poles of the observer's error dynamics (Hz, ζ), complex pairs.
    pub observer_poles: Vec<(f64, f64)>,
    pub axes: Vec<AxisLoop>,
    /// Peaks of the largest singular value of S^I and S^O [dB] (MIMO).
    pub peak_si_sigma_db: f64,
    pub peak_so_sigma_db: f64,
    /// Every peak within [`PEAK_LIMIT_DB`].
    pub meets_6db_rule: bool,
    /// The largest peak (|S^I|, |S^O|, per axis or singular value) [dB],
    /// where [Hz] and on which output.
    pub worst_peak_db: f64,
    pub worst_peak_hz: f64,
    pub worst_peak_at: String,
}

/// Why a loop's report could not be computed.
#[derive(Debug, Clone, PartialEq)]
pub enum LoopReportError {
    /// The closed loop's eigenvalues.
    Eigenvalues(LinalgError),
    /// The closed loop's modes.
    Modes(String),
    /// The sensitivities' state space (r → e_meas, n → y_meas).
    Sensitivities(StateSpaceError),
    /// The frequency response at `hz`.
    Response { hz: f64, error: LinalgError },
    /// Programs of one's own serve these roles: the closed loop is their
    /// law's, not flexloop's to analyse ([`program_loop_report`] says what
    /// was checked instead).
    NotAnalysed(Vec<&'static str>),
}

impl fmt::Display for LoopReportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Eigenvalues(e) => write!(f, "closed-loop eigenvalues: {e}"),
            Self::Modes(e) => write!(f, "closed-loop modes: {e}"),
            Self::Sensitivities(e) => write!(f, "{e}"),
            Self::Response { hz, error } => {
                write!(f, "frequency response at {hz:.3} Hz: {error}")
            }
            Self::NotAnalysed(roles) => write!(
                f,
                "the closed loop is not analysed: a program of one's own serves the {}",
                roles.join(" and the ")
            ),
        }
    }
}

impl std::error::Error for LoopReportError {}

/// `grid` [rad/s, as `log_grid_hz` gives it] in Hz, with 13 points around
/// every closed-loop pole (Hz, ζ) with ζ < 0.2 below `top` Hz, spaced
/// 0.25 ζ f (as the bandwidth searches of flexloop-control refine theirs).
fn refined_grid(grid: Vec<f64>, poles: &[(f64, f64)], top: f64) -> Vec<f64> {
    let mut hz: Vec<f64> = grid.into_iter().map(|w| w / (2.0 * PI)).collect();
    for &(f, zeta) in poles {
        if !(f.is_finite() && f > 0.0 && zeta.is_finite() && zeta < 0.2) {
            continue;
        }
        for k in -6..=6 {
            let fk = f * (1.0 + 0.25 * f64::from(k) * zeta.max(1e-4));
            if fk > 0.0 && fk < top {
                hz.push(fk);
            }
        }
    }
    hz.sort_by(|a, b| a.total_cmp(b));
    hz.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * b.abs());
    hz
}

/// The report of the loop `design` (built from `scenario`).
pub fn loop_report(
    scenario: &Scenario,
    design: &LoopDesign,
) -> Result<LoopReport, LoopReportError> {
    report(scenario, design, true)
}

/// The report without the search for the largest f_bw: what `up` and `run`
/// check before they start ([`LoopReport::warning`]).
pub fn loop_check(scenario: &Scenario, design: &LoopDesign) -> Result<LoopReport, LoopReportError> {
    report(scenario, design, false)
}

fn report(
    scenario: &Scenario,
    design: &LoopDesign,
    search: bool,
) -> Result<LoopReport, LoopReportError> {
    let Some(cl) = &design.closed_loop else {
        return Err(LoopReportError::NotAnalysed(
            flexloop_design::loop_design::unanalysed_roles(scenario),
        ));
    };
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
    let all_poles: Vec<(f64, f64)> = closed_loop_modes(cl)
        .map_err(|e| LoopReportError::Modes(e.to_string()))?
        .into_iter()
        .filter(|(f, z)| f.is_finite() && z.is_finite())
        .collect();
    let grid = refined_grid(
        log_grid_hz(0.1, 0.999 * nyquist, GRID_POINTS),
        &all_poles,
        0.999 * nyquist,
    );
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
    let (mut sigma_si, mut sigma_so) = ((0.0f64, 0.0), (0.0f64, 0.0));
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
        let si = largest_singular_value(&g.view((0, 0), (ny, ny)).into_owned());
        let so = largest_singular_value(&g.view((ny, ny), (ny, ny)).into_owned());
        if si > sigma_si.0 {
            sigma_si = (si, f);
        }
        if so > sigma_so.0 {
            sigma_so = (so, f);
        }
    }
    let (peak_si_sigma_db, peak_so_sigma_db) = (db(sigma_si.0), db(sigma_so.0));
    let stable = radius < 1.0;
    // The worst peak, and where: per axis, then (MIMO) the singular values.
    let mut worst = (f64::NEG_INFINITY, 0.0, String::new());
    for a in &axes {
        for (v, f, which) in [
            (a.peak_si_db, a.peak_si_hz, "S^I"),
            (a.peak_so_db, a.peak_so_hz, "S^O"),
        ] {
            if v > worst.0 {
                worst = (v, f, format!("|{which}| of {}", a.output));
            }
        }
    }
    if ny > 1 {
        for (v, f, which) in [
            (peak_si_sigma_db, sigma_si.1, "S^I"),
            (peak_so_sigma_db, sigma_so.1, "S^O"),
        ] {
            if v > worst.0 {
                worst = (v, f, format!("largest singular value of {which}"));
            }
        }
    }
    let meets_6db_rule = stable && worst.0 <= PEAK_LIMIT_DB;
    let poles: Vec<(f64, f64)> = all_poles
        .iter()
        .copied()
        .filter(|(f, z)| {
            !design
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
            let observer_error = design
                .observer_modes
                .iter()
                .filter(|(f, z)| (f - fm).abs() < 0.1 * fm && z.is_finite())
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .copied();
            FlexibleModeRow {
                frequency_hz: fm,
                open_loop,
                closed_loop: pole.map(|p| p.1),
                closed_loop_hz: pole.map(|p| p.0),
                observer_error,
            }
        })
        .collect();
    let mut observer_poles = design.observer_modes.clone();
    observer_poles.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Every oscillating pole of the loop, observer-error poles included:
    // they are modes of the closed loop too.
    let least_damped = all_poles.iter().copied().min_by(|a, b| a.1.total_cmp(&b.1));
    let open_loop_least = design
        .flexible_modes
        .iter()
        .map(|m| m.1)
        .fold(f64::INFINITY, f64::min);
    let close_to_unstable = stable
        && (radius > CLOSE_RADIUS
            || least_damped.is_some_and(|(_, z)| z < CLOSE_ZETA && open_loop_least > 2.0 * z));
    let (largest_bandwidth_hz, largest_bandwidth_note) = if search {
        largest_bandwidth(scenario, design)
    } else {
        (None, Some("not searched".into()))
    };
    let pid = design.pid_bandwidth;
    let controller = controller_words(scenario, design);
    let observer = observer_words(scenario, design);
    Ok(LoopReport {
        scenario: scenario.name.clone(),
        model: scenario.plant.model.clone(),
        rate_hz: scenario.timing.rate_hz,
        loop_delay_samples: design.loop_delay_samples,
        command_deadline_us: design.command_deadline_s.map(|s| s * 1e6),
        outputs: design.output_names.clone(),
        inputs: design.n_inputs,
        output_unit: design.output_unit,
        input_unit: design.input_unit,
        controller,
        observer,
        pid_bandwidth_hz: pid.map(|p| p.hz),
        pid_bandwidth_auto: pid.is_some_and(|p| p.auto),
        largest_bandwidth_hz,
        largest_bandwidth_note,
        spectral_radius: radius,
        stable,
        least_damped,
        close_to_unstable,
        flexible_modes,
        observer_poles,
        axes,
        peak_si_sigma_db,
        peak_so_sigma_db,
        meets_6db_rule,
        worst_peak_db: worst.0,
        worst_peak_hz: worst.1,
        worst_peak_at: worst.2,
    })
}

/// The largest f_bw meeting the rule on this loop (flexloop-design's
/// `pid_bandwidth`, the search `"auto"` makes), or why there is none.
pub fn largest_bandwidth(
    scenario: &Scenario,
    design: &LoopDesign,
) -> (Option<f64>, Option<String>) {
    if design.pid_bandwidth.is_none() {
        return (None, Some("no PID feedback".into()));
    }
    let Some(mass) = design.pid_mass else {
        return (
            None,
            Some("not searched: the PID is decoupled over several axes".into()),
        );
    };
    if design.sensor_scan.is_some() {
        return (
            None,
            Some(
                "not searched: the sensor is scanned (the loop above is frozen at its start)"
                    .into(),
            ),
        );
    }
    let plant = match DiscreteStateSpace::new(
        design.plant.a.clone(),
        design.plant.b.columns(0, design.n_inputs).into_owned(),
        design.plant.c.clone(),
        design.plant.d.columns(0, design.n_inputs).into_owned(),
        design.ts,
    ) {
        Ok(p) => p,
        Err(e) => return (None, Some(format!("not searched: {e}"))),
    };
    let siso = SisoLoop {
        plant: &plant,
        observer: pid_bandwidth::observer_of(&design.observer),
        loop_delay: design.loop_delay_samples as usize,
        mass,
        notches_hz: &scenario.controller.notches_hz,
    };
    match siso.largest_bandwidth() {
        Ok(Some(hz)) => (Some(hz), None),
        Ok(None) => (
            None,
            Some(format!(
                "none from {} Hz up: the observer or the notches alone break the rule",
                pid_bandwidth::STEP_HZ
            )),
        ),
        Err(e) => (None, Some(format!("search failed: {e}"))),
    }
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
    /// When each command acts: "loop delay 1 sample", or on arrival.
    fn delay_words(&self) -> String {
        match self.command_deadline_us {
            Some(us) => format!("each command applied on arrival at t_k + {us} us"),
            None => format!(
                "loop delay {} sample{}",
                self.loop_delay_samples,
                if self.loop_delay_samples == 1 {
                    ""
                } else {
                    "s"
                }
            ),
        }
    }

    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Loop design of `{}` ({}): {} Hz, {}",
            self.scenario,
            self.model,
            self.rate_hz,
            self.delay_words()
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
            "  closed loop: spectral radius {:.7} ({}){}",
            self.spectral_radius,
            if !self.stable {
                "UNSTABLE"
            } else if self.close_to_unstable {
                "stable, but CLOSE TO UNSTABLE"
            } else {
                "stable"
            },
            self.least_damped.map_or(String::new(), |(f, z)| format!(
                "; least damped pole {f:.1} Hz, ζ {z:.4}"
            ))
        );
        if !self.flexible_modes.is_empty() {
            let _ = writeln!(s, "\nFlexible modes of the plant");
            let _ = writeln!(
                s,
                "  {:>4} {:>10} {:>10} {:>12} {:>10} {:>22}",
                "mode", "f [Hz]", "open loop", "closed loop", "at [Hz]", "observer error (Hz, ζ)"
            );
            for (i, m) in self.flexible_modes.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "  {:>4} {:>10.1} {:>10.4} {:>12} {:>10} {:>22}",
                    i + 1,
                    m.frequency_hz,
                    m.open_loop,
                    m.closed_loop.map_or("-".into(), |z| format!("{z:.4}")),
                    m.closed_loop_hz.map_or("-".into(), |f| format!("{f:.1}")),
                    m.observer_error
                        .map_or("-".into(), |(f, z)| format!("{f:.1}, {z:.4}"))
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
        let _ = writeln!(s, "  {}", self.rule_verdict());
        match (self.largest_bandwidth_hz, &self.largest_bandwidth_note) {
            (Some(hz), _) => {
                let _ = writeln!(
                    s,
                    "  largest f_bw meeting the 6 dB rule with a stable loop here \
                     ({}, this observer): {hz:.1} Hz",
                    self.delay_words()
                );
            }
            (None, Some(note)) => {
                let _ = writeln!(s, "  largest f_bw meeting the 6 dB rule: {note}");
            }
            (None, None) => {}
        }
        s
    }

    /// "6 dB rule met", or how it is broken.
    pub fn rule_verdict(&self) -> String {
        if self.meets_6db_rule {
            "6 dB rule met".into()
        } else if !self.stable {
            "6 dB rule NOT met: the closed loop is unstable".into()
        } else {
            format!(
                "6 dB rule NOT met: breaks the 6 dB rule with {} at {:.2} dB ({:.1} Hz)",
                self.worst_peak_at, self.worst_peak_db, self.worst_peak_hz
            )
        }
    }

    /// One line for `up` and `run` when the loop breaks the 6 dB rule or is
    /// close to unstable ([`CLOSE_ZETA`], [`CLOSE_RADIUS`]); None when it
    /// does neither.
    pub fn warning(&self) -> Option<String> {
        let mut problems = Vec::new();
        if !self.meets_6db_rule && self.stable {
            problems.push(format!(
                "breaks the 6 dB rule ({} {:.2} dB at {:.1} Hz)",
                self.worst_peak_at, self.worst_peak_db, self.worst_peak_hz
            ));
        }
        if self.close_to_unstable {
            problems.push(match self.least_damped {
                Some((f, z)) if z < CLOSE_ZETA => {
                    format!("is close to unstable (a pole at {f:.1} Hz damped ζ {z:.5})")
                }
                _ => format!(
                    "is close to unstable (spectral radius {:.7})",
                    self.spectral_radius
                ),
            });
        }
        if problems.is_empty() {
            return None;
        }
        let hint = match self.largest_bandwidth_hz {
            Some(hz) if !self.meets_6db_rule => {
                format!("; f_bw {hz:.1} Hz meets it (`flexloop design`)")
            }
            _ => "; see `flexloop design`".into(),
        };
        Some(format!(
            "the loop of `{}` {}{hint}",
            self.scenario,
            problems.join(" and ")
        ))
    }
}

/// The design the scenario `text` (read from `path`) runs, by part: what
/// closes the loop and the observer, in words (`flexloop status`, the live
/// view): the file accepted as every command accepts it, then its words.
pub fn design_words(
    path: &std::path::Path,
    text: &str,
) -> Result<Vec<(String, String)>, flexloop_scenario::ScenarioError> {
    let accepted = flexloop_design::acceptance::accept_text(
        path,
        text,
        &flexloop_scenario::Overrides::default(),
        flexloop_runtime::realtime::online_cpus(),
    )?;
    let (s, d) = (&accepted.scenario, &accepted.design);
    Ok(vec![
        ("controller".into(), controller_words(s, d)),
        ("observer".into(), observer_words(s, d)),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_scenario::Overrides;
    use std::path::Path;

    /// A shipped scenario with `controller.bandwidth_hz` set to `f_bw`.
    fn retuned(name: &str, from: &str, f_bw: f64) -> (Scenario, LoopDesign) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios")
            .join(format!("{name}.toml"));
        let text = std::fs::read_to_string(&path)
            .unwrap()
            .replace(from, &format!("bandwidth_hz = {f_bw:?}"));
        let s = Scenario::from_text(&path, &text, &Overrides::default()).unwrap();
        let d = LoopDesign::from_scenario(&s).unwrap();
        (s, d)
    }

    #[test]
    fn a_loop_near_instability_is_close_to_unstable_and_warned_about() {
        // The original PID at 160 Hz: stable (170 Hz is not), mode 3 left
        // at ζ ≈ 0.0006 of its 0.005.
        let (s, d) = retuned("thesis-original", "bandwidth_hz = 35.5", 160.0);
        let r = loop_check(&s, &d).unwrap();
        assert!(r.stable && r.close_to_unstable, "{r:?}");
        let (f, z) = r.least_damped.unwrap();
        assert!(z < CLOSE_ZETA && (f - 1396.1).abs() < 20.0, "{f} Hz, ζ {z}");
        let line = r.warning().unwrap();
        assert!(line.contains("close to unstable"), "{line}");
        assert!(!line.contains('\n'), "{line}");
        // As shipped: neither broken nor close, no warning.
        let (s, d) = retuned("thesis-original", "bandwidth_hz = 35.5", 35.5);
        let r = loop_check(&s, &d).unwrap();
        assert!(r.meets_6db_rule && !r.close_to_unstable, "{r:?}");
        assert_eq!(r.warning(), None);
    }

    #[test]
    fn a_broken_6_db_rule_is_reported_with_its_peak_and_the_bandwidth_that_meets_it() {
        // MC+AD at the thesis' continuous-time 77.5 Hz, 10 kHz, one sample:
        // |S^O| 6.81 dB (docs/control.md §10.1); 44.0 Hz meets the rule at y5.
        let (s, d) = retuned("thesis-mc-ad-redesigned", "bandwidth_hz = 43.5", 77.5);
        let r = loop_report(&s, &d).unwrap();
        assert!(r.stable && !r.meets_6db_rule);
        assert!((r.worst_peak_db - 6.81).abs() < 0.02, "{}", r.worst_peak_db);
        assert_eq!(r.largest_bandwidth_hz, Some(44.0));
        assert!(r.rule_verdict().contains("breaks the 6 dB rule"));
        let line = r.warning().unwrap();
        assert!(
            line.contains("breaks the 6 dB rule") && line.contains("44.0 Hz meets it"),
            "{line}"
        );
        assert!(r.render_text().contains("|S^O| of y5 at 6.81 dB"));
    }
}

/// What `design` reports of a loop a program of one's own serves: what is
/// checked before it starts (the plant, a built-in observer's design, the
/// messages' limits, the program's launch), and not the closed loop, whose
/// law is the program's (docs/components.md, "What flexloop checks").
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProgramLoopReport {
    pub scenario: String,
    pub model: String,
    pub rate_hz: f64,
    pub loop_delay_samples: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub command_deadline_us: Option<f64>,
    pub outputs: Vec<String>,
    pub inputs: usize,
    pub output_unit: &'static str,
    pub input_unit: &'static str,
    /// The roles programs serve (`controller`, `observer`).
    pub program_roles: Vec<&'static str>,
    /// The plant's flexible modes, open loop (Hz, ζ).
    pub flexible_modes: Vec<(f64, f64)>,
    /// The built-in observer's design and its error poles (Hz, ζ); None
    /// when a program serves the observer.
    pub observer: Option<String>,
    pub observer_poles: Vec<(f64, f64)>,
}

/// The report of a loop served by programs of one's own (`design` prints
/// it where [`loop_report`] says [`LoopReportError::NotAnalysed`]).
pub fn program_loop_report(scenario: &Scenario, design: &LoopDesign) -> ProgramLoopReport {
    let program_roles = flexloop_design::loop_design::unanalysed_roles(scenario);
    let built_in_observer = !program_roles.contains(&"observer");
    let mut observer_poles = if built_in_observer {
        design.observer_modes.clone()
    } else {
        Vec::new()
    };
    observer_poles.sort_by(|a, b| a.0.total_cmp(&b.0));
    ProgramLoopReport {
        scenario: scenario.name.clone(),
        model: scenario.plant.model.clone(),
        rate_hz: scenario.timing.rate_hz,
        loop_delay_samples: design.loop_delay_samples,
        command_deadline_us: design.command_deadline_s.map(|s| s * 1e6),
        outputs: design.output_names.clone(),
        inputs: design.n_inputs,
        output_unit: design.output_unit,
        input_unit: design.input_unit,
        program_roles,
        flexible_modes: design.flexible_modes.clone(),
        observer: built_in_observer.then(|| observer_words(scenario, design)),
        observer_poles,
    }
}

impl ProgramLoopReport {
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let delay = match self.command_deadline_us {
            Some(us) => format!("each command applied on arrival, {us} us after its tick"),
            None => format!("{} sample(s) of loop delay", self.loop_delay_samples),
        };
        let _ = writeln!(
            s,
            "Loop of `{}` ({}): {} Hz, {delay}",
            self.scenario, self.model, self.rate_hz
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
        let _ = writeln!(
            s,
            "  served by a program of one's own: the {}",
            self.program_roles.join(" and the ")
        );
        match &self.observer {
            Some(o) => {
                let _ = writeln!(s, "  observer (built-in): {o}");
            }
            None => {
                let _ = writeln!(s, "  observer: the program's");
            }
        }
        let _ = writeln!(
            s,
            "  closed loop: NOT ANALYSED. Its stability, the 6 dB rule and the largest f_bw \
             need the program's law, which flexloop does not have. Checked before start: the \
             plant model, the built-in observer's design, the loop's message limits and the \
             program's launch (docs/components.md#what-flexloop-checks)."
        );
        if !self.flexible_modes.is_empty() {
            let _ = writeln!(s, "\nFlexible modes of the plant (open loop)");
            let _ = writeln!(s, "  {:>10} {:>10}", "f [Hz]", "ζ");
            for (f, z) in &self.flexible_modes {
                let _ = writeln!(s, "  {f:>10.2} {z:>10.4}");
            }
        }
        if !self.observer_poles.is_empty() {
            let _ = writeln!(s, "\nObserver error poles (built-in observer)");
            for (f, z) in &self.observer_poles {
                let _ = writeln!(s, "  {f:>10.2} Hz, ζ {z:.4}");
            }
        }
        s
    }
}

/// What closes the loop, in words: the PID and its f_bw (and whether
/// `"auto"` chose it) with its notches, state feedback, none, or the
/// program that serves the controller.
pub fn controller_words(scenario: &Scenario, design: &LoopDesign) -> String {
    if let Some(exec) = &scenario.controller.exec {
        return format!("program {}", exec.join(" "));
    }
    let c = &scenario.controller;
    let ny = design.n_outputs;
    let f_bw = match design.pid_bandwidth {
        Some(p) if p.auto => format!(
            "{:.1} Hz (\"auto\": the largest meeting the 6 dB rule)",
            p.hz
        ),
        Some(p) => format!("{:.1} Hz", p.hz),
        None => String::new(),
    };
    let controller = match c.feedback.as_str() {
        "pid" if ny > 1 || design.n_inputs > 1 => {
            format!("PID f_bw {f_bw} on each of {ny} rigid-body-decoupled axes")
        }
        "pid" => format!("PID f_bw {f_bw}"),
        _ if scenario.observer.design == "state-feedback" => "state feedback".to_string(),
        _ => "none".to_string(),
    };
    if c.notches_hz.is_empty() || c.feedback != "pid" {
        controller
    } else {
        let hz: Vec<String> = c.notches_hz.iter().map(|h| format!("{h}")).collect();
        format!("{controller}, notches at {} Hz (pre-warped)", hz.join(", "))
    }
}

/// The observer in words: its design and tuning (MC, AD, band-pass), or
/// the program that serves it.
pub fn observer_words(scenario: &Scenario, design: &LoopDesign) -> String {
    let o = &scenario.observer;
    if let Some(exec) = &o.exec {
        return format!("program {}", exec.join(" "));
    }
    match o.design.as_str() {
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
                if o.bandpass_q > 0.0 {
                    parts.push(format!("band-pass Q {}", o.bandpass_q));
                }
            }
            parts.join(", ")
        }
        other => other.to_string(),
    }
}
