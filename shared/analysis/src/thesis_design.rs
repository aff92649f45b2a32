//! The thesis design report: the bandwidth table of control.md §9 (in
//! continuous time, the thesis's setting) or §10.1 (discrete time with loop
//! delay), with the modal data, the MC+AD observer poles and the active
//! damping achieved in closed loop, for one chosen output position.
//!
//! Every case is the Table 3.3 single-parameter PID re-tuned to the largest
//! f_bw (the tuning parameter; the crossover is ≈ 1.05 f_bw) such that, for
//! every output y1..y7 with its own observer (designed on thesis_reduced(i)):
//! |S^I|, |S^O| ≤ limit (6 dB), plus |T_{r→e_true}| ≤ limit for "MC + r→e",
//! and the closed loop is stable.
//!
//! | case | observer | thesis crossover | reference model (f_bw / crossover) |
//! |---|---|---|---|
//! | original | none | 37 | 35.5 / 37.3 |
//! | notches | none, 3 notches at modes 1–3 | 43 | 41.0 / 43.0 |
//! | MC | MC, Q_ν 0.03 | 72–73 | 70.0 / 73.5 |
//! | MC + r→e | MC, Q_ν 0.03, T_re bound | 46 | 44.5 / 46.7 |
//! | AD | AD (3.31) +0.035, static | 65 | 60.5 / 63.5 |
//! | AD + band-pass | AD, band-pass Q = 2 | 77 | 72.5 / 76.1 |
//! | MC+AD | MC + AD static, Q_ν 0.03 | 59 | 57.5 / 60.4 |
//! | MC+AD + band-pass | MC + AD band-pass, Q_ν 10³ | 83 | 77.5 / 81.4 |
//!
//! Q_ν is the thesis intensity; discrete designs convert it
//! ([`flexloop_control::kalman::NoiseModel::thesis`]). With two samples of loop delay the
//! AD output uses one more model step (x̂(k+2|k), control.md §10.1); longer
//! delays are not compensated further (the thesis does not need them).
//!
//! # What this reproduces (tests in this module)
//! Continuous, f_bw [Hz] / first 0 dB crossing at y5 [Hz]: 35.5 / 37.5,
//! 41.0 / 43.4, 70.0 / 73.6, 44.5 / 46.7, 60.5 / 64.8, 72.5 / 78.4,
//! 57.5 / 60.4, 77.5 / 81.6: every f_bw equals the reference model's and
//! every crossover is within 3 Hz of the thesis. (The reference model quotes
//! 1.0498 f_bw, the crossover of the rigid-body loop; at y5 the observer
//! loops cross a little higher, e.g. AD 64.8 instead of 63.5.)
//!
//! Discrete at 10 kHz, f_bw for 0 / 1 / 2 samples of loop delay: original
//! 35.5 / 35.5 / 24.5, MC + r→e 44.5 / 35.0 / 24.0, AD band-pass
//! 58.5 / 36.0 / 24.5, MC+AD band-pass 69.0 / 43.5 / 26.5, exactly
//! control.md §10.1. AD damping at f_bw 35.5, one sample: 0.051 / 0.047 /
//! 0.042 (§10.1). Cases §10.1 does not list: notches 33.5 / 23.0 / 17.5
//! (the notches' phase lag below the modes costs more than they gain once
//! ZOH and delay eat the margin); MC without the T_re bound equals MC + r→e
//! with delay (S^O binds first); AD and MC+AD with static gains (no
//! band-pass) reach only ≈ 10 Hz with one sample of delay and fail at
//! 10 Hz with two: |S^O| on y1 is ≈ 6 dB from the damping loop alone,
//! whatever the PID, which is why the thesis band-passes the gains.
//!
//! The full report takes about 1 s in release (0.5–0.8 s discrete, 1.0 s
//! continuous).

use flexloop_control::bandwidth::{ContinuousBandwidthProblem, DiscreteBandwidthProblem};
use flexloop_control::closed_loop::{
    LoopSpec, assemble_continuous_loop, assemble_loop, closed_loop_modes,
    continuous_closed_loop_modes, discrete_modes,
};
use flexloop_control::damping::DampingMethod;
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::zoh;
use flexloop_control::freq::LoopMetrics;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::matrix_error::MatrixError;
use flexloop_control::models::{CHAIN_MASS, CHAIN_ZETA, thesis_plant, thesis_reduced};
use flexloop_control::observer_block::{
    ContinuousObserverOptions, DampingOptions, ModalObserverOptions, ObserverBlock,
    design_continuous_modal_observer, design_modal_observer,
};
use flexloop_control::pid::PidTuning;
use serde::Serialize;
use std::f64::consts::PI;
use std::fmt::Write as _;

/// Output positions of the thesis chain (y1..y7), all constrained.
pub const THESIS_OUTPUTS: usize = 7;
/// AD target: +0.035 on each retained flexible mode (0.005 → 0.04).
const DAMPING_INCREASE: f64 = 0.035;
/// Band-pass quality factor of the AD gains.
const BANDPASS_Q: f64 = 2.0;

/// Where the loop is designed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DesignDomain {
    /// Continuous time, no delay (the thesis, control.md §9).
    Continuous,
    /// Sampled at `ts` [s]: exact ZOH plant, Tustin controller, DARE
    /// predictor observer, and `loop_delay` samples between computing u_c(k)
    /// and applying it (control.md §10.1: 1 is the 10 kHz reference).
    Discrete { ts: f64, loop_delay: usize },
}

/// The design cases of control.md §9.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DesignCase {
    /// The Table 3.3 PID alone.
    Original,
    /// The PID with notches at flexible modes 1–3.
    Notches,
    /// Measurement compensation, Q_ν 0.03, constraints S^I and S^O only.
    Mc,
    /// MC, Q_ν 0.03, plus |T_{r→e_true}| ≤ limit.
    McRe,
    /// Active damping (3.31) +0.035, static gains.
    Ad,
    /// Active damping with band-pass Q = 2.
    AdBandpass,
    /// MC + AD (static gains), Q_ν 0.03.
    McAd,
    /// MC + AD with band-pass Q = 2, Q_ν 10³.
    McAdBandpass,
}

impl DesignCase {
    /// All cases in the order of the thesis table.
    pub const ALL: [DesignCase; 8] = [
        DesignCase::Original,
        DesignCase::Notches,
        DesignCase::Mc,
        DesignCase::McRe,
        DesignCase::Ad,
        DesignCase::AdBandpass,
        DesignCase::McAd,
        DesignCase::McAdBandpass,
    ];

    /// The short name (also the serde name): `original`, `notches`, `mc`,
    /// `mc_re`, `ad`, `ad_bandpass`, `mc_ad`, `mc_ad_bandpass`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Original => "original",
            Self::Notches => "notches",
            Self::Mc => "mc",
            Self::McRe => "mc_re",
            Self::Ad => "ad",
            Self::AdBandpass => "ad_bandpass",
            Self::McAd => "mc_ad",
            Self::McAdBandpass => "mc_ad_bandpass",
        }
    }

    /// The case of a short name ([`DesignCase::name`]), e.g. for a CLI.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    /// A human-readable label.
    pub fn label(self) -> &'static str {
        match self {
            Self::Original => "original PID",
            Self::Notches => "PID + 3 notches",
            Self::Mc => "MC (S^I, S^O), Qnu 0.03",
            Self::McRe => "MC + r->e_true, Qnu 0.03",
            Self::Ad => "AD (3.31), static",
            Self::AdBandpass => "AD + band-pass Q=2",
            Self::McAd => "MC+AD, static, Qnu 0.03",
            Self::McAdBandpass => "MC+AD + band-pass, Qnu 1e3",
        }
    }

    /// The thesis's crossover [Hz] as (low, high) (one value except MC:
    /// "72 Hz" at L2843, "73 Hz" at L4364).
    pub fn thesis_crossover_hz(self) -> (f64, f64) {
        match self {
            Self::Original => (37.0, 37.0),
            Self::Notches => (43.0, 43.0),
            Self::Mc => (72.0, 73.0),
            Self::McRe => (46.0, 46.0),
            Self::Ad => (65.0, 65.0),
            Self::AdBandpass => (77.0, 77.0),
            Self::McAd => (59.0, 59.0),
            Self::McAdBandpass => (83.0, 83.0),
        }
    }

    /// Measurement compensation on.
    pub fn mc(self) -> bool {
        matches!(
            self,
            Self::Mc | Self::McRe | Self::McAd | Self::McAdBandpass
        )
    }

    /// Active damping: None (off), Some(None) static, Some(Some(Q)) band-pass.
    pub fn ad(self) -> Option<Option<f64>> {
        match self {
            Self::Ad | Self::McAd => Some(None),
            Self::AdBandpass | Self::McAdBandpass => Some(Some(BANDPASS_Q)),
            _ => None,
        }
    }

    /// The thesis noise-model intensity Q_ν (with MC only).
    pub fn q_nu(self) -> Option<f64> {
        match self {
            Self::Mc | Self::McRe | Self::McAd => Some(0.03),
            Self::McAdBandpass => Some(1e3),
            _ => None,
        }
    }

    /// |T_{r→e_true}| is bounded too.
    pub fn bounds_re(self) -> bool {
        self == Self::McRe
    }

    /// Notches at flexible modes 1–3.
    pub fn notches(self) -> bool {
        self == Self::Notches
    }
}

/// What to evaluate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ThesisDesignSpec {
    pub domain: DesignDomain,
    /// Output position y_i (1..=7) whose crossover, modal table, observer
    /// poles and AD damping are reported (thesis simulations: 5). The
    /// constraints always cover all seven outputs.
    pub output: usize,
    pub cases: Vec<DesignCase>,
    /// Peak limit [dB] on |S^I|, |S^O| (and |T_re| where bounded): 6.
    pub limit_db: f64,
    /// f_bw scan: from `f_bw_min` (must be feasible) to `f_bw_max` [Hz].
    pub f_bw_min: f64,
    pub f_bw_max: f64,
    /// Coarse step of the scan, then `fine_step` (the resolution of the
    /// result, 0.5 Hz as in the reference tables) up to the first
    /// infeasible coarse value.
    pub coarse_step: f64,
    pub fine_step: f64,
    /// f_bw [Hz] of the PID in the AD damping check (control.md §10.1: 35.5).
    pub ad_check_f_bw: f64,
}

impl ThesisDesignSpec {
    /// All cases in continuous time at y5 (control.md §9).
    pub fn continuous() -> Self {
        Self {
            domain: DesignDomain::Continuous,
            output: 5,
            cases: DesignCase::ALL.to_vec(),
            limit_db: 6.0,
            f_bw_min: 10.0,
            f_bw_max: 150.0,
            coarse_step: 4.0,
            fine_step: 0.5,
            ad_check_f_bw: 35.5,
        }
    }

    /// All cases sampled at `ts` with `loop_delay` samples (control.md §10.1
    /// uses ts = 1e-4 and delays 0, 1, 2) at y5.
    pub fn discrete(ts: f64, loop_delay: usize) -> Self {
        Self {
            domain: DesignDomain::Discrete { ts, loop_delay },
            ..Self::continuous()
        }
    }

    fn validate(&self) -> Result<(), DesignError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !(1..=THESIS_OUTPUTS).contains(&self.output) {
            return Err(DesignError::InvalidParameter(format!(
                "output y{} (1..=7)",
                self.output
            )));
        }
        if !self.limit_db.is_finite() {
            return Err(DesignError::Matrix(MatrixError::NonFinite("limit_db")));
        }
        if !(pos(self.f_bw_min)
            && pos(self.f_bw_max)
            && pos(self.coarse_step)
            && pos(self.fine_step)
            && self.f_bw_max >= self.f_bw_min
            && self.coarse_step >= self.fine_step)
        {
            return Err(DesignError::InvalidParameter(format!(
                "f_bw scan {}..{} Hz, steps {}/{}",
                self.f_bw_min, self.f_bw_max, self.coarse_step, self.fine_step
            )));
        }
        if (self.f_bw_max - self.f_bw_min) / self.fine_step > 1e5 {
            return Err(DesignError::InvalidParameter(
                "f_bw scan has more than 1e5 points".into(),
            ));
        }
        if !pos(self.ad_check_f_bw) {
            return Err(DesignError::InvalidParameter(format!(
                "ad_check_f_bw {}",
                self.ad_check_f_bw
            )));
        }
        if let DesignDomain::Discrete { ts, loop_delay } = self.domain {
            // The slowest retained flexible mode must lie below Nyquist for
            // the pre-warped band-pass filters; 100 samples of delay is far
            // beyond anything meaningful here.
            if !(pos(ts) && ts < 1e-2) {
                return Err(DesignError::InvalidParameter(format!(
                    "sample period {ts} s (0 < Ts < 0.01)"
                )));
            }
            if loop_delay > 100 {
                return Err(DesignError::InvalidParameter(format!(
                    "loop delay {loop_delay} samples (at most 100)"
                )));
            }
        }
        Ok(())
    }
}

/// One mode of the plant seen from the reported output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModeRow {
    /// 0 = rigid, 1..7 flexible.
    pub mode: usize,
    pub frequency_hz: f64,
    pub damping: f64,
    /// Mode-shape value at the actuator (φ_a) and at the sensor (φ_s).
    pub phi_a: f64,
    pub phi_s: f64,
    /// "rigid", "retained", "T_DC" (compensated) or "unknown" (ignored).
    pub role: &'static str,
}

/// An observer pole, as a continuous-time equivalent.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoleRow {
    /// |s| / 2π [Hz] (for discrete poles s = ln(z)/Ts).
    pub frequency_hz: f64,
    /// −Re(s)/|s| (1 for a stable real pole).
    pub damping: f64,
}

/// Closed-loop damping of one retained flexible mode with AD.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModeDamping {
    pub mode: usize,
    pub frequency_hz: f64,
    /// Open-loop ζ (0.005).
    pub open_loop: f64,
    /// ζ the (3.31) gains aim for (0.04).
    pub target: f64,
    /// Least-damped closed-loop pole near the mode, observer-error poles
    /// excluded; None if no pole was found within ±5 %.
    pub achieved: Option<f64>,
}

/// The AD damping check (control.md §10.1: band-pass Q = 2, f_bw 35.5, one
/// sample of delay gives 0.051 / 0.047 / 0.042).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AdDampingCheck {
    pub f_bw: f64,
    pub bandpass_q: f64,
    pub modes: Vec<ModeDamping>,
}

/// The result of one case.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseResult {
    pub case: DesignCase,
    pub label: &'static str,
    /// Largest feasible f_bw parameter [Hz]; None if `f_bw_min` already fails.
    pub f_bw: Option<f64>,
    /// The f_bw the metrics below are evaluated at (f_bw, or f_bw_min).
    pub evaluated_at: f64,
    /// First 0 dB crossing of P_eq C_fb at the reported output [Hz].
    pub crossover_hz: Option<f64>,
    /// Largest peaks over y1..y7 [dB].
    pub peak_si_db: f64,
    pub peak_so_db: f64,
    pub peak_re_db: f64,
    /// The output (1..7) with the largest constrained peak.
    pub limiting_output: usize,
    /// Closed loop stable for all seven outputs.
    pub stable: bool,
    /// The thesis's crossover [Hz] (low, high).
    pub thesis_crossover_hz: (f64, f64),
}

/// The whole report ([`thesis_design_report`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DesignReport {
    pub spec: ThesisDesignSpec,
    /// The plant at the reported output: 1 rigid + 7 flexible modes.
    pub modes: Vec<ModeRow>,
    /// Poles of A − L C of the MC+AD observer (band-pass, Q_ν 10³) at the
    /// reported output, by frequency.
    pub observer_poles: Vec<PoleRow>,
    pub ad_damping: AdDampingCheck,
    pub cases: Vec<CaseResult>,
}

/// Builds the report (module doc). Errors (never panics) on an invalid
/// spec or a failed design; no NaN or infinity reaches the report.
pub fn thesis_design_report(spec: &ThesisDesignSpec) -> Result<DesignReport, DesignError> {
    spec.validate()?;
    let modes = modal_table(spec.output)?;
    let observer_poles = observer_poles(spec)?;
    let ad_damping = ad_damping_check(spec)?;
    let plants = Plants::new(spec.domain)?;
    let mut cases = Vec::with_capacity(spec.cases.len());
    for &case in &spec.cases {
        cases.push(evaluate_case(spec, &plants, case)?);
    }
    Ok(DesignReport {
        spec: spec.clone(),
        modes,
        observer_poles,
        ad_damping,
        cases,
    })
}

/// Largest feasible f_bw of one case and its metrics for all seven outputs
/// (at the best f_bw, or at `f_bw_min` if that fails).
pub fn evaluate_design_case(
    spec: &ThesisDesignSpec,
    case: DesignCase,
) -> Result<(Option<f64>, Vec<LoopMetrics>), DesignError> {
    spec.validate()?;
    let plants = Plants::new(spec.domain)?;
    let problem = case_problem(spec, &plants, case)?;
    let best = problem.max_bandwidth(spec)?;
    let metrics = problem.evaluate(best.unwrap_or(spec.f_bw_min))?;
    Ok((best, metrics))
}

fn modal_table(output: usize) -> Result<Vec<ModeRow>, DesignError> {
    let m = thesis_plant(output)?;
    let f = m.frequencies_hz();
    Ok((0..m.modes())
        .map(|i| ModeRow {
            mode: i,
            frequency_hz: f[i],
            damping: m.zeta[i],
            phi_a: m.phi_a[(i, 0)],
            phi_s: m.phi_s[(0, i)],
            role: match i {
                0 => "rigid",
                1..=3 => "retained",
                4..=6 => "T_DC",
                _ => "unknown",
            },
        })
        .collect())
}

fn damping_options(bandpass_q: Option<f64>) -> DampingOptions {
    DampingOptions {
        increase: vec![DAMPING_INCREASE; 3],
        method: DampingMethod::Automated,
        bandpass_q,
    }
}

/// The extra prediction step of the AD output for a loop delay (§10.1).
fn extra_delay(loop_delay: usize, ad: bool) -> usize {
    usize::from(ad && loop_delay >= 2)
}

fn discrete_observer(
    output: usize,
    ts: f64,
    loop_delay: usize,
    case: DesignCase,
) -> Result<flexloop_control::observer_block::ModalObserver, DesignError> {
    let opts = ModalObserverOptions {
        ts,
        mc: case.mc(),
        damping: case.ad().map(damping_options),
        q_nu: case.q_nu(),
        weights: None,
        extra_delay_samples: extra_delay(loop_delay, case.ad().is_some()),
    };
    design_modal_observer(&thesis_reduced(output)?, &opts)
}

fn continuous_observer(
    output: usize,
    case: DesignCase,
) -> Result<flexloop_control::observer_block::ContinuousModalObserver, DesignError> {
    let opts = ContinuousObserverOptions {
        mc: case.mc(),
        damping: case.ad().map(damping_options),
        q_nu: case.q_nu(),
        weights: None,
    };
    design_continuous_modal_observer(&thesis_reduced(output)?, &opts)
}

fn pole_row(w: f64, zeta: f64) -> Option<PoleRow> {
    let f = w / (2.0 * PI);
    (f.is_finite() && zeta.is_finite()).then_some(PoleRow {
        frequency_hz: f,
        damping: zeta,
    })
}

fn observer_poles(spec: &ThesisDesignSpec) -> Result<Vec<PoleRow>, DesignError> {
    let case = DesignCase::McAdBandpass;
    let mut rows: Vec<PoleRow> = match spec.domain {
        DesignDomain::Continuous => {
            let o = continuous_observer(spec.output, case)?;
            let f = &o.model.a - &o.kalman.l * &o.model.c;
            flexloop_control::linalg::eigenvalues(&f)?
                .iter()
                .filter(|s| s.im >= 0.0)
                .filter_map(|s| {
                    let w = s.norm();
                    pole_row(w, if w > 0.0 { -s.re / w } else { 1.0 })
                })
                .collect()
        }
        DesignDomain::Discrete { ts, loop_delay } => {
            let o = discrete_observer(spec.output, ts, loop_delay, case)?;
            let d = &o.design;
            flexloop_control::linalg::eigenvalues(&(&d.model.a - &d.gain * &d.model.c))?
                .iter()
                .filter(|z| z.im >= 0.0 && z.norm() > 0.0)
                .filter_map(|z| {
                    let (w, zeta) = flexloop_control::linalg::discrete_pole_to_continuous(*z, ts);
                    pole_row(w, zeta)
                })
                .collect()
        }
    };
    rows.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    Ok(rows)
}

/// Closed-loop damping of the retained flexible modes with AD (band-pass
/// Q = 2) at `spec.ad_check_f_bw`, output `spec.output`.
fn ad_damping_check(spec: &ThesisDesignSpec) -> Result<AdDampingCheck, DesignError> {
    let case = DesignCase::AdBandpass;
    let red = thesis_reduced(spec.output)?;
    let tuning = PidTuning::single_parameter(CHAIN_MASS, spec.ad_check_f_bw)?;
    let (modes, obs_modes) = match spec.domain {
        DesignDomain::Continuous => {
            let plant = thesis_plant(spec.output)?.state_space();
            let o = continuous_observer(spec.output, case)?;
            let cl = assemble_continuous_loop(&plant, Some(&o.system), &tuning.continuous()?)?;
            let f = &o.model.a - &o.kalman.l * &o.model.c;
            let obs = flexloop_control::linalg::eigenvalues(&f)?
                .iter()
                .filter(|s| s.im > 0.0)
                .map(|s| (s.norm() / (2.0 * PI), -s.re / s.norm()))
                .collect::<Vec<_>>();
            (continuous_closed_loop_modes(&cl)?, obs)
        }
        DesignDomain::Discrete { ts, loop_delay } => {
            let plant = zoh(&thesis_plant(spec.output)?.state_space(), ts)?;
            let o = discrete_observer(spec.output, ts, loop_delay, case)?;
            let cl = assemble_loop(&LoopSpec {
                plant: &plant,
                observer: Some(&o.block),
                controller: &tuning.discrete(ts)?,
                loop_delay,
            })?;
            let d = &o.design;
            let obs = discrete_modes(&(&d.model.a - &d.gain * &d.model.c), ts)?;
            (closed_loop_modes(&cl)?, obs)
        }
    };
    let freqs = red.modal.frequencies_hz();
    let achieved = least_damped_near(&modes, &freqs[1..], &obs_modes);
    let rows = (1..red.modal.modes())
        .zip(achieved)
        .map(|(i, achieved)| ModeDamping {
            mode: i,
            frequency_hz: freqs[i],
            open_loop: red.modal.zeta[i],
            target: CHAIN_ZETA + DAMPING_INCREASE,
            achieved,
        })
        .collect();
    Ok(AdDampingCheck {
        f_bw: spec.ad_check_f_bw,
        bandpass_q: BANDPASS_Q,
        modes: rows,
    })
}

/// The seven plants in the spec's domain.
enum Plants {
    Continuous(Vec<flexloop_control::continuous::ContinuousStateSpace>),
    Discrete {
        plants: Vec<DiscreteStateSpace>,
        ts: f64,
        loop_delay: usize,
    },
}

impl Plants {
    fn new(domain: DesignDomain) -> Result<Self, DesignError> {
        let cont = (1..=THESIS_OUTPUTS)
            .map(|i| Ok(thesis_plant(i)?.state_space()))
            .collect::<Result<Vec<_>, DesignError>>()?;
        Ok(match domain {
            DesignDomain::Continuous => Self::Continuous(cont),
            DesignDomain::Discrete { ts, loop_delay } => Self::Discrete {
                plants: cont
                    .iter()
                    .map(|p| Ok(zoh(p, ts)?))
                    .collect::<Result<_, DesignError>>()?,
                ts,
                loop_delay,
            },
        })
    }
}

enum Problem {
    Continuous(ContinuousBandwidthProblem),
    Discrete(DiscreteBandwidthProblem),
}

impl Problem {
    fn max_bandwidth(&self, spec: &ThesisDesignSpec) -> Result<Option<f64>, DesignError> {
        let (a, b, c, d) = (
            spec.f_bw_min,
            spec.f_bw_max,
            spec.coarse_step,
            spec.fine_step,
        );
        match self {
            Self::Continuous(p) => p.max_bandwidth_refined(a, b, c, d),
            Self::Discrete(p) => p.max_bandwidth_refined(a, b, c, d),
        }
    }

    fn evaluate(&self, f_bw: f64) -> Result<Vec<LoopMetrics>, DesignError> {
        match self {
            Self::Continuous(p) => p.evaluate(f_bw),
            Self::Discrete(p) => p.evaluate(f_bw),
        }
    }
}

fn notch_frequencies() -> Result<Vec<f64>, DesignError> {
    let m = thesis_plant(5)?;
    Ok(m.omega[1..=3].to_vec())
}

fn case_problem(
    spec: &ThesisDesignSpec,
    plants: &Plants,
    case: DesignCase,
) -> Result<Problem, DesignError> {
    let observed = case.mc() || case.ad().is_some();
    let notches = if case.notches() {
        notch_frequencies()?
    } else {
        Vec::new()
    };
    Ok(match plants {
        Plants::Continuous(p) => {
            let observers = (1..=THESIS_OUTPUTS)
                .map(|i| {
                    Ok(if observed {
                        Some(continuous_observer(i, case)?.system)
                    } else {
                        None
                    })
                })
                .collect::<Result<Vec<_>, DesignError>>()?;
            Problem::Continuous(
                ContinuousBandwidthProblem::new(
                    p.clone(),
                    observers,
                    CHAIN_MASS,
                    spec.limit_db,
                    case.bounds_re(),
                )?
                .with_notches(&notches),
            )
        }
        Plants::Discrete {
            plants,
            ts,
            loop_delay,
        } => {
            let observers = (1..=THESIS_OUTPUTS)
                .map(|i| {
                    Ok(if observed {
                        Some(discrete_observer(i, *ts, *loop_delay, case)?.block)
                    } else {
                        None
                    })
                })
                .collect::<Result<Vec<Option<ObserverBlock>>, DesignError>>()?;
            Problem::Discrete(
                DiscreteBandwidthProblem::new(
                    plants.clone(),
                    observers,
                    *loop_delay,
                    CHAIN_MASS,
                    spec.limit_db,
                    case.bounds_re(),
                )?
                .with_notches(&notches)?,
            )
        }
    })
}

fn evaluate_case(
    spec: &ThesisDesignSpec,
    plants: &Plants,
    case: DesignCase,
) -> Result<CaseResult, DesignError> {
    let problem = case_problem(spec, plants, case)?;
    let best = problem.max_bandwidth(spec)?;
    let at = best.unwrap_or(spec.f_bw_min);
    let metrics = problem.evaluate(at)?;
    let fold = |g: fn(&LoopMetrics) -> f64| metrics.iter().map(g).fold(f64::MIN, f64::max);
    let (si, so, re) = (
        fold(|m| m.peak_si_db),
        fold(|m| m.peak_so_db),
        fold(|m| m.peak_re_db),
    );
    if ![si, so, re].iter().all(|v| v.is_finite()) {
        return Err(DesignError::Matrix(MatrixError::NonFinite(
            "sensitivity peak",
        )));
    }
    let constrained = |m: &LoopMetrics| {
        let mut v = m.peak_si_db.max(m.peak_so_db);
        if case.bounds_re() {
            v = v.max(m.peak_re_db);
        }
        v
    };
    let limiting_output = metrics
        .iter()
        .enumerate()
        .max_by(|a, b| constrained(a.1).total_cmp(&constrained(b.1)))
        .map_or(1, |(i, _)| i + 1);
    Ok(CaseResult {
        case,
        label: case.label(),
        f_bw: best,
        evaluated_at: at,
        crossover_hz: metrics[spec.output - 1].crossover_hz,
        peak_si_db: si,
        peak_so_db: so,
        peak_re_db: re,
        limiting_output,
        stable: metrics.iter().all(|m| m.stable),
        thesis_crossover_hz: case.thesis_crossover_hz(),
    })
}

impl DesignReport {
    /// The report as aligned plain-text tables.
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let spec = &self.spec;
        let domain = match spec.domain {
            DesignDomain::Continuous => "continuous time".to_string(),
            DesignDomain::Discrete { ts, loop_delay } => format!(
                "discrete, Ts = {:.1} us ({:.1} kHz), loop delay {} sample{}",
                ts * 1e6,
                1e-3 / ts,
                loop_delay,
                if loop_delay == 1 { "" } else { "s" }
            ),
        };
        let _ = writeln!(
            s,
            "Thesis design report: {domain}; output y{}; |S^I|, |S^O| <= {:.1} dB on y1..y7",
            spec.output, spec.limit_db
        );
        let _ = writeln!(s);
        let _ = writeln!(s, "Plant modes at y{}", spec.output);
        let _ = writeln!(
            s,
            "  {:>4}  {:>9}  {:>7}  {:>8}  {:>8}  role",
            "mode", "f [Hz]", "zeta", "phi_a", "phi_s"
        );
        for m in &self.modes {
            let _ = writeln!(
                s,
                "  {:>4}  {:>9.2}  {:>7.4}  {:>8.4}  {:>8.4}  {}",
                m.mode, m.frequency_hz, m.damping, m.phi_a, m.phi_s, m.role
            );
        }
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Observer poles (MC+AD, band-pass Q=2, Qnu 1e3), continuous equivalent"
        );
        let _ = writeln!(s, "  {:>9}  {:>7}", "f [Hz]", "zeta");
        for p in &self.observer_poles {
            let _ = writeln!(s, "  {:>9.2}  {:>7.4}", p.frequency_hz, p.damping);
        }
        let _ = writeln!(s);
        let ad = &self.ad_damping;
        let _ = writeln!(
            s,
            "AD closed-loop damping (3.31) +{DAMPING_INCREASE}, band-pass Q={}, PID f_bw {:.1} Hz",
            ad.bandpass_q, ad.f_bw
        );
        let _ = writeln!(
            s,
            "  {:>4}  {:>9}  {:>9}  {:>7}  {:>8}",
            "mode", "f [Hz]", "open loop", "target", "achieved"
        );
        for m in &ad.modes {
            let achieved = m
                .achieved
                .map_or_else(|| "-".to_string(), |z| format!("{z:.4}"));
            let _ = writeln!(
                s,
                "  {:>4}  {:>9.2}  {:>9.4}  {:>7.4}  {:>8}",
                m.mode, m.frequency_hz, m.open_loop, m.target, achieved
            );
        }
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Bandwidth (largest f_bw meeting the rule; crossover at y{})",
            spec.output
        );
        let _ = writeln!(
            s,
            "  {:<28}  {:>9}  {:>10}  {:>7}  {:>7}  {:>7}  {:>7}  {:>6}  {:>5}",
            "case",
            "f_bw [Hz]",
            "cross [Hz]",
            "thesis",
            "S^I dB",
            "S^O dB",
            "Tre dB",
            "stable",
            "worst"
        );
        for c in &self.cases {
            let f_bw = c
                .f_bw
                .map_or_else(|| format!("<{:.1}", spec.f_bw_min), |f| format!("{f:.1}"));
            let cross = c
                .crossover_hz
                .map_or_else(|| "-".to_string(), |f| format!("{f:.1}"));
            let (lo, hi) = c.thesis_crossover_hz;
            let thesis = if lo == hi {
                format!("{lo:.0}")
            } else {
                format!("{lo:.0}-{hi:.0}")
            };
            let _ = writeln!(
                s,
                "  {:<28}  {:>9}  {:>10}  {:>7}  {:>7.2}  {:>7.2}  {:>7.2}  {:>6}  {:>5}",
                c.label,
                f_bw,
                cross,
                thesis,
                c.peak_si_db,
                c.peak_so_db,
                c.peak_re_db,
                if c.stable { "yes" } else { "NO" },
                format!("y{}", c.limiting_output)
            );
        }
        s
    }
}

/// The mode damping of a closed loop, for callers that assemble their own
/// loops: least-damped pole within ±5 % of each `mode_hz`, ignoring poles
/// that match `exclude` (within 0.2 Hz and 1e-3 in ζ). Poles as (Hz, ζ).
pub fn least_damped_near(
    poles: &[(f64, f64)],
    mode_hz: &[f64],
    exclude: &[(f64, f64)],
) -> Vec<Option<f64>> {
    mode_hz
        .iter()
        .map(|&fm| {
            poles
                .iter()
                .filter(|(f, z)| (f - fm).abs() < 0.05 * fm && f.is_finite() && z.is_finite())
                .filter(|(f, z)| {
                    !exclude
                        .iter()
                        .any(|(fo, zo)| (f - fo).abs() < 0.2 && (z - zo).abs() < 1e-3)
                })
                .map(|(_, z)| *z)
                .reduce(f64::min)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_control::models::TS_10KHZ;

    /// control.md §9/§11.2: best f_bw of the continuous reference model.
    const CONTINUOUS_F_BW: [(DesignCase, f64); 8] = [
        (DesignCase::Original, 35.5),
        (DesignCase::Notches, 41.0),
        (DesignCase::Mc, 70.0),
        (DesignCase::McRe, 44.5),
        (DesignCase::Ad, 60.5),
        (DesignCase::AdBandpass, 72.5),
        (DesignCase::McAd, 57.5),
        (DesignCase::McAdBandpass, 77.5),
    ];

    /// control.md §10.1, "Bandwidth under the strict 6 dB rule in discrete
    /// time": f_bw at 10 kHz for 0, 1, 2 samples of loop delay.
    const DISCRETE_F_BW: [(DesignCase, [f64; 3]); 4] = [
        (DesignCase::Original, [35.5, 35.5, 24.5]),
        (DesignCase::McRe, [44.5, 35.0, 24.0]),
        (DesignCase::AdBandpass, [58.5, 36.0, 24.5]),
        (DesignCase::McAdBandpass, [69.0, 43.5, 26.5]),
    ];

    /// The scan near the expected answer (the full range from 5 Hz is
    /// monotone and gives the same values: `full_reports_match_every_table`):
    /// f_bw − 1 must be feasible, and the result must be within ±1 Hz.
    fn near(spec: &ThesisDesignSpec, case: DesignCase, f_ref: f64) -> (f64, Vec<LoopMetrics>) {
        let mut s = spec.clone();
        s.f_bw_min = f_ref - 1.0;
        s.f_bw_max = f_ref + 1.5;
        s.coarse_step = 0.5;
        let (best, m) = evaluate_design_case(&s, case).unwrap();
        let best = best.unwrap_or_else(|| panic!("{case:?}: infeasible at {}", s.f_bw_min));
        assert!(
            (best - f_ref).abs() <= 1.0,
            "{case:?}: f_bw {best} vs {f_ref}"
        );
        assert!(m.iter().all(|m| m.stable), "{case:?}");
        let worst = m
            .iter()
            .map(|m| {
                let mut v = m.peak_si_db.max(m.peak_so_db);
                if case.bounds_re() {
                    v = v.max(m.peak_re_db);
                }
                v
            })
            .fold(f64::MIN, f64::max);
        assert!(worst <= 6.0 && worst > 5.0, "{case:?}: {worst}");
        (best, m)
    }

    /// Continuous crossover at y5 within ±3 Hz of the thesis (and the f_bw
    /// within ±1 Hz of the reference model); returns the crossover.
    fn continuous_case(case: DesignCase) -> f64 {
        let f_ref = CONTINUOUS_F_BW.iter().find(|c| c.0 == case).unwrap().1;
        let (best, m) = near(&ThesisDesignSpec::continuous(), case, f_ref);
        let cross = m[4].crossover_hz.unwrap();
        let (lo, hi) = case.thesis_crossover_hz();
        assert!(
            cross >= lo - 3.0 && cross <= hi + 3.0,
            "{case:?}: crossover {cross} Hz (f_bw {best}) vs thesis {lo}-{hi}"
        );
        cross
    }

    #[test]
    fn continuous_pid_and_notch_bandwidths() {
        // f_bw 35.5 / 41.0, crossover 37.5 / 43.4 Hz (thesis 37 / 43).
        let pid = continuous_case(DesignCase::Original);
        let notch = continuous_case(DesignCase::Notches);
        assert!(pid < notch);
    }

    #[test]
    fn continuous_mc_bandwidths() {
        // f_bw 70.0 / 44.5, crossover 73.6 / 46.7 Hz (thesis 72-73 / 46).
        let mc = continuous_case(DesignCase::Mc);
        let mc_re = continuous_case(DesignCase::McRe);
        assert!(mc_re < mc);
    }

    #[test]
    fn continuous_ad_bandwidths() {
        // f_bw 60.5 / 72.5, crossover 64.8 / 78.4 Hz (thesis 65 / 77).
        let ad = continuous_case(DesignCase::Ad);
        let ad_bp = continuous_case(DesignCase::AdBandpass);
        assert!(ad < ad_bp);
    }

    #[test]
    fn continuous_mc_ad_bandwidths_and_table_3_5_order() {
        // f_bw 57.5 / 77.5, crossover 60.4 / 81.6 Hz (thesis 59 / 83).
        let mc_ad = continuous_case(DesignCase::McAd);
        let mc_ad_bp = continuous_case(DesignCase::McAdBandpass);
        assert!(mc_ad < mc_ad_bp);
        // Table 3.5 order PID < MC (46) < AD (77) < MC+AD (83): the other
        // three are asserted above within ±1 Hz of f_bw 35.5, 44.5, 72.5
        // (crossover ≤ 1.08 f_bw + 0.5), all below this one.
        for f in [35.5, 44.5, 72.5] {
            assert!(1.08 * (f + 1.0) < mc_ad_bp, "{f} vs {mc_ad_bp}");
        }
    }

    fn discrete_case(case: DesignCase) {
        let want = DISCRETE_F_BW.iter().find(|c| c.0 == case).unwrap().1;
        for delay in [1, 2] {
            let spec = ThesisDesignSpec::discrete(TS_10KHZ, delay);
            let (best, _) = near(&spec, case, want[delay]);
            assert!(
                (best - want[delay]).abs() <= 1.0,
                "{case:?} delay {delay}: {best}"
            );
        }
    }

    #[test]
    fn discrete_mc_bandwidth_with_loop_delay() {
        // §10.1: MC (Q_ν 0.03, r→e_true bound) 35.0 / 24.0 at 1 / 2 samples.
        discrete_case(DesignCase::McRe);
    }

    #[test]
    fn discrete_ad_bandwidth_with_loop_delay() {
        // §10.1: AD (band-pass) 36.0 / 24.5.
        discrete_case(DesignCase::AdBandpass);
    }

    #[test]
    fn discrete_mc_ad_bandwidth_with_loop_delay() {
        // §10.1: MC+AD (band-pass, Q_ν 10³) 43.5 / 26.5.
        discrete_case(DesignCase::McAdBandpass);
    }

    #[test]
    fn report_parts_with_one_sample_of_delay() {
        let mut spec = ThesisDesignSpec::discrete(TS_10KHZ, 1);
        spec.cases = vec![DesignCase::Original];
        spec.f_bw_min = 34.0;
        spec.f_bw_max = 40.0;
        let r = thesis_design_report(&spec).unwrap();
        // Modal table (control.md §1.3).
        assert_eq!(r.modes.len(), 8);
        for (m, f) in r.modes.iter().zip([
            0.0, 470.06, 941.88, 1396.06, 1805.13, 2145.46, 2399.72, 2556.45,
        ]) {
            assert!((m.frequency_hz - f).abs() < 0.01, "{m:?}");
        }
        assert_eq!(r.modes[7].role, "unknown");
        assert!((r.modes[0].phi_a - 0.2828).abs() < 1e-4);
        // AD damping (§10.1): 0.051 / 0.047 / 0.042.
        for (m, want) in r.ad_damping.modes.iter().zip([0.051, 0.047, 0.042]) {
            let z = m.achieved.unwrap();
            assert!((z - want).abs() < 0.002, "{m:?}");
            assert!((m.target - 0.04).abs() < 1e-12);
        }
        // Observer poles: stable, finite; the lightly damped modes 2 and 3
        // stay near the plant, mode 1 gets ζ ≈ 0.05.
        assert!(r.observer_poles.iter().all(|p| p.damping > 0.0));
        let near = |f: f64| {
            r.observer_poles
                .iter()
                .min_by(|a, b| {
                    (a.frequency_hz - f)
                        .abs()
                        .total_cmp(&(b.frequency_hz - f).abs())
                })
                .unwrap()
        };
        assert!((near(941.88).frequency_hz - 941.88).abs() < 5.0);
        assert!((near(470.0).damping - 0.05).abs() < 0.01);
        // The case row and the text.
        let c = &r.cases[0];
        assert_eq!(c.f_bw, Some(35.5));
        assert!(c.stable && c.peak_si_db <= 6.0);
        assert!((c.crossover_hz.unwrap() - 37.5).abs() < 0.5);
        let text = r.render_text();
        for needle in [
            "Plant modes at y5",
            "Observer poles",
            "original PID",
            "35.5",
            "yes",
        ] {
            assert!(text.contains(needle), "{needle}\n{text}");
        }
        // Every line of a table has the same width as its header.
        assert!(
            text.lines()
                .all(|l| !l.contains("NaN") && !l.contains("inf"))
        );
    }

    #[test]
    fn continuous_ad_damping_and_poles() {
        let mut spec = ThesisDesignSpec::continuous();
        spec.cases.clear();
        let r = thesis_design_report(&spec).unwrap();
        assert!(r.cases.is_empty());
        // No delay: a little above the 0.04 target on every mode.
        for m in &r.ad_damping.modes {
            let z = m.achieved.unwrap();
            assert!(z > 0.045 && z < 0.06, "{m:?}");
        }
        // Rigid-body pair of the MC+AD observer (noise model, Q_ν 10³).
        assert!(
            r.observer_poles
                .iter()
                .any(|p| (p.frequency_hz - 199.0).abs() < 5.0)
        );
    }

    #[test]
    fn bad_specs_are_errors() {
        let base = ThesisDesignSpec::discrete(TS_10KHZ, 1);
        let mut bad = Vec::new();
        for output in [0, 8] {
            bad.push(ThesisDesignSpec {
                output,
                ..base.clone()
            });
        }
        for ts in [0.0, -1e-4, f64::NAN, f64::INFINITY, 0.5] {
            bad.push(ThesisDesignSpec::discrete(ts, 1));
        }
        bad.push(ThesisDesignSpec::discrete(TS_10KHZ, 1000));
        bad.push(ThesisDesignSpec {
            limit_db: f64::NAN,
            ..base.clone()
        });
        bad.push(ThesisDesignSpec {
            f_bw_min: 50.0,
            f_bw_max: 40.0,
            ..base.clone()
        });
        bad.push(ThesisDesignSpec {
            fine_step: 0.0,
            ..base.clone()
        });
        bad.push(ThesisDesignSpec {
            fine_step: 1e-9,
            ..base.clone()
        });
        bad.push(ThesisDesignSpec {
            ad_check_f_bw: -1.0,
            ..base.clone()
        });
        for s in &bad {
            assert!(thesis_design_report(s).is_err(), "{s:?}");
            assert!(
                evaluate_design_case(s, DesignCase::Original).is_err(),
                "{s:?}"
            );
        }
        // An infeasible start is a None bandwidth, not an error.
        let mut s = base.clone();
        s.cases = vec![DesignCase::Original];
        s.f_bw_min = 60.0;
        s.f_bw_max = 61.0;
        let r = thesis_design_report(&s).unwrap();
        assert_eq!(r.cases[0].f_bw, None);
        assert_eq!(r.cases[0].evaluated_at, 60.0);
        assert!(r.render_text().contains("<60.0"));
    }

    #[test]
    fn case_names_round_trip() {
        for c in DesignCase::ALL {
            assert_eq!(DesignCase::from_name(c.name()), Some(c));
        }
        assert_eq!(DesignCase::from_name("nope"), None);
        fn serializable<T: Serialize>() {}
        serializable::<DesignReport>();
    }

    /// The complete tables with full scans from 5 Hz in 0.5 Hz steps (no
    /// coarse step), in all four domains of §10.1. About 12 s in release;
    /// the narrow-scan tests above assert the same values in the dev profile.
    #[test]
    #[ignore = "slow in the dev profile; run with --release -- --ignored"]
    fn full_reports_match_every_table() {
        let mut spec = ThesisDesignSpec::continuous();
        spec.f_bw_min = 5.0;
        spec.coarse_step = 0.5;
        let r = thesis_design_report(&spec).unwrap();
        for (c, (case, f)) in r.cases.iter().zip(CONTINUOUS_F_BW) {
            assert_eq!((c.case, c.f_bw), (case, Some(f)));
            let (lo, hi) = case.thesis_crossover_hz();
            let x = c.crossover_hz.unwrap();
            assert!(x >= lo - 3.0 && x <= hi + 3.0, "{c:?}");
        }
        for delay in 0..=2 {
            let mut spec = ThesisDesignSpec::discrete(TS_10KHZ, delay);
            spec.f_bw_min = 5.0;
            spec.coarse_step = 0.5;
            spec.cases = DISCRETE_F_BW.iter().map(|c| c.0).collect();
            let r = thesis_design_report(&spec).unwrap();
            for (c, (case, f)) in r.cases.iter().zip(DISCRETE_F_BW) {
                assert_eq!((c.case, c.f_bw), (case, Some(f[delay])), "delay {delay}");
            }
        }
    }
}
