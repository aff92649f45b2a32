//! The thesis design report: the bandwidth table of docs/control.md §9 (in
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
//! The chain is a parameter ([`ThesisDesignSpec::with_chain`]: seven outputs
//! y1..y7, rigid + 7 modes, and the PID's mass), the thesis chain by default,
//! so that a chain with other masses, stiffnesses or damping gets its own
//! table. `flexloop design --study` runs it; the scenario's own loop is
//! [`crate::loop_report`].
//!
//! Q_ν is the thesis intensity; discrete designs convert it
//! ([`flexloop_control::kalman::NoiseModel::thesis`]). With two samples of loop delay the
//! AD output uses one more model step (x̂(k+2|k), docs/control.md §10.1); longer
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
//! docs/control.md §10.1. AD damping at f_bw 35.5, one sample: 0.051 / 0.047 /
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
use flexloop_control::modal::{ModalModel, ReducedModel};
use flexloop_control::models::{CHAIN_MASS, thesis_chain_modal};
use flexloop_control::observer_block::{
    ContinuousObserverOptions, DampingOptions, ModalObserverOptions, ObserverBlock,
    design_continuous_modal_observer, design_modal_observer,
};
use flexloop_control::pid::PidTuning;
use serde::Serialize;
use std::f64::consts::PI;

mod observers;
mod text;

use observers::{ad_damping_check, continuous_observer, discrete_observer, observer_poles};

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
    /// Continuous time, no delay (the thesis, docs/control.md §9).
    Continuous,
    /// Sampled at `ts` [s]: exact ZOH plant, Tustin controller, DARE
    /// predictor observer, and `loop_delay` samples between computing u_c(k)
    /// and applying it (docs/control.md §10.1: 1 is the 10 kHz reference).
    /// With `command_deadline_s` = τ (and `loop_delay` 1) u_c(k) acts from
    /// t_k + τ instead: the plant is integrated in two pieces and the
    /// observer designed for it (docs/deadline.md, [`ThesisDesignSpec::on_arrival`]).
    Discrete {
        ts: f64,
        loop_delay: usize,
        #[serde(skip_serializing_if = "Option::is_none")]
        command_deadline_s: Option<f64>,
    },
}

/// The design cases of docs/control.md §9.
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
    /// f_bw [Hz] of the PID in the AD damping check (docs/control.md §10.1: 35.5).
    pub ad_check_f_bw: f64,
    /// The chain studied: a modal model whose seven outputs are y1..y7
    /// (None: the thesis chain, `models::thesis_chain_modal`), and the mass
    /// the PID is tuned on [kg], so that a chain with other parameters gets
    /// its own table ([`ThesisDesignSpec::with_chain`]).
    #[serde(skip)]
    pub chain: Option<ModalModel>,
    pub mass: f64,
}

impl ThesisDesignSpec {
    /// All cases in continuous time at y5 (docs/control.md §9).
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
            chain: None,
            mass: CHAIN_MASS,
        }
    }

    /// The study of another chain: `chain` with seven outputs y1..y7 (the
    /// observer keeps rigid + 3 flexible modes, T_DC of modes 4–6, as the
    /// thesis'), its PID tuned on `mass` [kg].
    pub fn with_chain(mut self, chain: ModalModel, mass: f64) -> Self {
        self.chain = Some(chain);
        self.mass = mass;
        self
    }

    /// The chain at output y_i (1..=7).
    pub(crate) fn plant(&self, output: usize) -> Result<ModalModel, DesignError> {
        let chain = match &self.chain {
            Some(c) => c.clone(),
            None => thesis_chain_modal()?,
        };
        Ok(chain.select_outputs(&[output - 1])?)
    }

    /// The observer's model at output y_i: rigid + 3 flexible modes, T_DC
    /// of modes 4–6 (docs/control.md §1.3).
    pub(crate) fn reduced(&self, output: usize) -> Result<ReducedModel, DesignError> {
        Ok(self.plant(output)?.truncate(4, &[4, 5, 6])?)
    }

    /// All cases sampled at `ts` with `loop_delay` samples (docs/control.md §10.1
    /// uses ts = 1e-4 and delays 0, 1, 2) at y5.
    pub fn discrete(ts: f64, loop_delay: usize) -> Self {
        Self {
            domain: DesignDomain::Discrete {
                ts,
                loop_delay,
                command_deadline_s: None,
            },
            ..Self::continuous()
        }
    }

    /// All cases sampled at `ts` with each command applied on arrival, from
    /// t_k + `deadline_s` (0 ≤ τ ≤ Ts; τ = Ts is one sample of delay).
    pub fn on_arrival(ts: f64, deadline_s: f64) -> Self {
        Self {
            domain: DesignDomain::Discrete {
                ts,
                loop_delay: 1,
                command_deadline_s: Some(deadline_s),
            },
            ..Self::continuous()
        }
    }

    /// The sampled plant at output y_i: exact ZOH, or with a command
    /// deadline the two-piece plant in the observer's coordinates
    /// ([`flexloop_control::discretise::SplitHold::delayed_input_form`]).
    pub(crate) fn discrete_plant(
        &self,
        output: usize,
        ts: f64,
    ) -> Result<DiscreteStateSpace, DesignError> {
        let sys = self.plant(output)?.state_space();
        Ok(match self.command_deadline() {
            None => zoh(&sys, ts)?,
            Some(tau) => flexloop_control::discretise::zoh_split(&sys, ts, tau)?
                .delayed_input_form(&sys.c, &sys.d, ts)?,
        })
    }

    /// τ [s] when the study's commands act on arrival.
    pub fn command_deadline(&self) -> Option<f64> {
        match self.domain {
            DesignDomain::Discrete {
                command_deadline_s, ..
            } => command_deadline_s,
            DesignDomain::Continuous => None,
        }
    }

    fn validate(&self) -> Result<(), DesignError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if let Some(c) = &self.chain
            && (c.outputs() != THESIS_OUTPUTS || c.modes() != 8)
        {
            return Err(DesignError::InvalidParameter(format!(
                "the study's chain has {} outputs and {} modes (7 and 8: y1..y7, rigid + 7)",
                c.outputs(),
                c.modes()
            )));
        }
        if !(self.mass.is_finite() && self.mass > 0.0) {
            return Err(DesignError::InvalidParameter(format!(
                "mass {} kg",
                self.mass
            )));
        }
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
        if let DesignDomain::Discrete {
            ts,
            loop_delay,
            command_deadline_s,
        } = self.domain
        {
            if let Some(tau) = command_deadline_s
                && !(tau.is_finite() && (0.0..=ts).contains(&tau) && loop_delay == 1)
            {
                return Err(DesignError::InvalidParameter(format!(
                    "command deadline {tau} s with loop delay {loop_delay} (0 ≤ τ ≤ Ts = {ts} s, \
                     one sample of delay)"
                )));
            }
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

/// The AD damping check (docs/control.md §10.1: band-pass Q = 2, f_bw 35.5, one
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
    let modes = modal_table(spec)?;
    let observer_poles = observer_poles(spec)?;
    let ad_damping = ad_damping_check(spec)?;
    let plants = Plants::new(spec)?;
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
    let plants = Plants::new(spec)?;
    let problem = case_problem(spec, &plants, case)?;
    let best = problem.max_bandwidth(spec)?;
    let metrics = problem.evaluate(best.unwrap_or(spec.f_bw_min))?;
    Ok((best, metrics))
}

fn modal_table(spec: &ThesisDesignSpec) -> Result<Vec<ModeRow>, DesignError> {
    let m = spec.plant(spec.output)?;
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
    fn new(spec: &ThesisDesignSpec) -> Result<Self, DesignError> {
        let cont = (1..=THESIS_OUTPUTS)
            .map(|i| Ok(spec.plant(i)?.state_space()))
            .collect::<Result<Vec<_>, DesignError>>()?;
        Ok(match spec.domain {
            DesignDomain::Continuous => Self::Continuous(cont),
            DesignDomain::Discrete { ts, loop_delay, .. } => Self::Discrete {
                plants: (1..=THESIS_OUTPUTS)
                    .map(|i| spec.discrete_plant(i, ts))
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

fn notch_frequencies(spec: &ThesisDesignSpec) -> Result<Vec<f64>, DesignError> {
    let m = spec.plant(5)?;
    Ok(m.omega[1..=3].to_vec())
}

fn case_problem(
    spec: &ThesisDesignSpec,
    plants: &Plants,
    case: DesignCase,
) -> Result<Problem, DesignError> {
    let observed = case.mc() || case.ad().is_some();
    let notches = if case.notches() {
        notch_frequencies(spec)?
    } else {
        Vec::new()
    };
    Ok(match plants {
        Plants::Continuous(p) => {
            let observers = (1..=THESIS_OUTPUTS)
                .map(|i| {
                    Ok(if observed {
                        Some(continuous_observer(spec, i, case)?.system)
                    } else {
                        None
                    })
                })
                .collect::<Result<Vec<_>, DesignError>>()?;
            Problem::Continuous(
                ContinuousBandwidthProblem::new(
                    p.clone(),
                    observers,
                    spec.mass,
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
                        Some(discrete_observer(spec, i, *ts, *loop_delay, case)?.block)
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
                    spec.mass,
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
mod tests;
