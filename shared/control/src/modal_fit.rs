//! A modal model fitted to a measured plant frequency response
//! (docs/control.md §14, "A model from the measurement").
//!
//! The measurement ([`Frf`], from [`crate::frf`]) is the plant from its
//! first input (force) to its first output (position) as the loop sees it:
//! the continuous plant behind a zero-order hold at the loop's rate. The
//! model is modal,
//!
//! P(s) = c₀/s² (a rigid body, if asked) + Σᵢ cᵢ/(s² + 2ζᵢωᵢ s + ωᵢ²),
//!
//! and it is compared with the measurement as the loop sees it too: its ZOH
//! image, in closed form per term (the step-invariant transform, as in
//! Franklin, Powell and Workman, "Digital Control of Dynamic Systems"), equal
//! to [`crate::discretise::zoh`] followed by
//! [`crate::freq::freq_response_discrete`] of [`ModalFit::state_space`].
//!
//! The fit, on the lines of coherence ≥ `min_coherence`, each weighted by
//! its coherence:
//! 1. Peak picking (Ewins, "Modal Testing"): the local maxima of |P|
//!    (of |P|ω² with a rigid body, so the mass line does not hide them),
//!    ranked by prominence; the `flexible_modes` most prominent are the modes.
//! 2. A start for each mode's ω and ζ. The lines are log-spaced (about 10 %
//!    apart on the shipped grid) and a mode of ζ = 0.01 is 2 % wide between
//!    its half-power points, so half-power or curvature estimates have no
//!    lines to work on. Instead (ω, ζ) is scanned on a grid between the
//!    peak's neighbouring lines, with every gain solved by linear least
//!    squares at each point (the gains are linear in the model once the
//!    poles are fixed: variable projection, Golub and Pereyra 1973); the
//!    modes enter one at a time, most prominent first, then each is scanned
//!    again with all the others in.
//! 3. Levenberg–Marquardt on all of ln ω, ln ζ and the gains, minimising the
//!    coherence-weighted squares of the complex log error ln(P_model/P),
//!    whose real part is the magnitude error (in nepers) and imaginary part
//!    the phase error (in radians): the logarithmic least-squares estimator
//!    (Pintelon and Schoukens, "System Identification: A Frequency Domain
//!    Approach"), which weighs a decade of magnitude as evenly as a Bode
//!    plot does. The minimiser is the `levenberg-marquardt` crate (a port of
//!    MINPACK's lmder, Moré 1978), bounded in evaluations of the model.
//!
//! Asking for more flexible modes than the measurement shows peaks is an
//! error, not a model with unsupported modes: a mode without a peak has no
//! frequency the data pin down.

use crate::continuous::ContinuousStateSpace;
use crate::frf::Frf;
use crate::modal::ModalModel;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::storage::Owned;
use nalgebra::{Complex, DMatrix, DVector, Dyn};
use std::cell::Cell;
use std::f64::consts::PI;
use std::fmt;

type C64 = Complex<f64>;

/// The damping ratios a fitted mode may take: ζ = 1 is a double pole, where
/// the closed-form ZOH image divides by zero; above 0.95 a "mode" is no
/// resonance a measurement could show.
const ZETA_MIN: f64 = 1e-5;
const ZETA_MAX: f64 = 0.95;
/// The start's grid: frequencies between a peak's neighbouring lines, and
/// damping ratios from 0.001 to 0.5, log-spaced (steps of 0.25 % in ω for
/// neighbours 20 % apart, and of 30 % in ζ).
const SCAN_FREQUENCIES: usize = 81;
const SCAN_DAMPINGS: usize = 25;
const SCAN_ZETA: (f64, f64) = (1e-3, 0.5);
/// Relative step in ln ω and ln ζ of the central differences of the Jacobian
/// (the error of a central difference is O(h²) = 1e-12; round-off O(ε/h)).
const STEP: f64 = 1e-6;

/// What to fit.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalFitSpec {
    /// Number of lightly damped modes cᵢ/(s² + 2ζᵢωᵢ s + ωᵢ²).
    pub flexible_modes: usize,
    /// Whether the plant has a free rigid-body mode c₀/s².
    pub rigid_body: bool,
    /// The lines used: coherence at least this (in [0, 1]).
    pub min_coherence: f64,
    /// A peak counts as a mode when it stands at least this many dB above the
    /// higher of the lowest points on either side of it, before a higher line
    /// (its prominence): measurement noise makes small bumps.
    pub min_prominence_db: f64,
    /// The most evaluations of the model the Levenberg–Marquardt refinement
    /// may make (each a residual vector or a Jacobian).
    pub max_evaluations: usize,
}

impl ModalFitSpec {
    /// `flexible_modes` modes (and a rigid body if `rigid_body`) on the lines
    /// of coherence ≥ 0.99 (the threshold of docs/control.md §14), peaks of
    /// 1 dB prominence at least, and 2000 evaluations at most.
    pub fn new(flexible_modes: usize, rigid_body: bool) -> Self {
        Self {
            flexible_modes,
            rigid_body,
            min_coherence: 0.99,
            min_prominence_db: 1.0,
            max_evaluations: 2000,
        }
    }
}

/// One fitted flexible mode: the term gain/(s² + 2 ζ ω s + ω²), ω = 2π f.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FittedMode {
    pub frequency_hz: f64,
    pub damping: f64,
    /// cᵢ, in output per input times (rad/s)² (m/N/s² for a force to a
    /// position): the mode's static compliance is cᵢ/ωᵢ².
    pub gain: f64,
}

/// How well the fitted model matches the lines it was fitted on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitQuality {
    /// RMS over the lines used of 20 log10 |P_model/P|.
    pub rms_error_db: f64,
    /// The largest |20 log10 |P_model/P|| over the lines used.
    pub max_error_db: f64,
    /// The largest |arg(P_model/P)| over the lines used, in degrees.
    pub max_error_degrees: f64,
    /// Lines of coherence ≥ `min_coherence` (and a non-zero response).
    pub lines_used: usize,
}

/// A modal model of the plant, fitted to its measured response.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalFit {
    /// c₀ of the rigid-body term c₀/s² (1/m for a free mass m), if fitted.
    pub rigid_gain: Option<f64>,
    /// The flexible modes, by frequency.
    pub modes: Vec<FittedMode>,
    pub quality: FitQuality,
    /// Evaluations the Levenberg–Marquardt refinement made.
    pub evaluations: usize,
}

/// Why no model was fitted.
#[derive(Debug, Clone, PartialEq)]
pub enum ModalFitError {
    /// The spec asks for nothing, or a field is out of range.
    InvalidSpec(String),
    /// The sample rate is not a positive finite number.
    InvalidRate(f64),
    /// The measurement's frequencies, responses and coherences differ in count.
    Mismatch {
        frequencies: usize,
        responses: usize,
        coherences: usize,
    },
    /// A frequency, response or coherence of the line is NaN or infinite.
    NonFinite { line: usize },
    /// A line's frequency is not positive, not above the previous line's,
    /// or not below the Nyquist frequency.
    BadFrequency {
        line: usize,
        frequency_hz: f64,
        nyquist_hz: f64,
    },
    /// Fewer lines of coherence ≥ `min_coherence` than the fit needs.
    TooFewLines {
        used: usize,
        needed: usize,
        min_coherence: f64,
    },
    /// Fewer peaks of the prominence asked for than flexible modes asked for.
    TooFewPeaks {
        asked: usize,
        found: usize,
        min_prominence_db: f64,
    },
    /// Levenberg–Marquardt stopped without converging.
    NotConverged { evaluations: usize, reason: String },
}

impl fmt::Display for ModalFitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidSpec(why) => write!(f, "the fit's spec is invalid: {why}"),
            Self::InvalidRate(rate) => {
                write!(f, "the sample rate {rate} Hz is not a positive number")
            }
            Self::Mismatch {
                frequencies,
                responses,
                coherences,
            } => write!(
                f,
                "the measurement has {frequencies} frequencies, {responses} responses and \
                 {coherences} coherences; they must be one per line"
            ),
            Self::NonFinite { line } => write!(
                f,
                "line {} has a frequency, response or coherence that is not a finite number",
                line + 1
            ),
            Self::BadFrequency {
                line,
                frequency_hz,
                nyquist_hz,
            } => write!(
                f,
                "line {} is at {frequency_hz} Hz: lines must be positive, increasing and below \
                 the Nyquist frequency, {nyquist_hz} Hz",
                line + 1
            ),
            Self::TooFewLines {
                used,
                needed,
                min_coherence,
            } => write!(
                f,
                "only {used} lines have coherence ≥ {min_coherence} (and a non-zero response); \
                 the fit needs {needed} (two per parameter): measure longer or louder, or lower \
                 the threshold"
            ),
            Self::TooFewPeaks {
                asked,
                found,
                min_prominence_db,
            } => write!(
                f,
                "{asked} flexible modes asked for, but the measurement shows {found} peaks of \
                 {min_prominence_db} dB prominence or more: ask for at most {found}, or measure \
                 more lines around the missing modes"
            ),
            Self::NotConverged {
                evaluations,
                reason,
            } => write!(
                f,
                "the fit did not converge within {evaluations} evaluations of the model ({reason})"
            ),
        }
    }
}

impl std::error::Error for ModalFitError {}

impl ModalFit {
    /// Fits the model of `spec` to `frf`, measured at a loop of `rate_hz`.
    /// See the module doc for the method.
    pub fn from_frf(frf: &Frf, rate_hz: f64, spec: &ModalFitSpec) -> Result<Self, ModalFitError> {
        check_spec(spec)?;
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(ModalFitError::InvalidRate(rate_hz));
        }
        let lines = usable_lines(frf, rate_hz, spec.min_coherence)?;
        let parameters = 3 * spec.flexible_modes + usize::from(spec.rigid_body);
        let needed = 2 * parameters;
        if lines.len() < needed {
            return Err(ModalFitError::TooFewLines {
                used: lines.len(),
                needed,
                min_coherence: spec.min_coherence,
            });
        }
        let peaks = pick_peaks(&lines, spec.rigid_body, spec.min_prominence_db);
        if peaks.len() < spec.flexible_modes {
            return Err(ModalFitError::TooFewPeaks {
                asked: spec.flexible_modes,
                found: peaks.len(),
                min_prominence_db: spec.min_prominence_db,
            });
        }
        let ts = 1.0 / rate_hz;
        let fitter = Fitter::new(&lines, ts, spec.rigid_body);
        let start = fitter.start(&peaks[..spec.flexible_modes]);
        let (poles, gains, evaluations) = fitter.refine(&start, spec.max_evaluations)?;
        let rigid = usize::from(spec.rigid_body);
        let mut modes: Vec<FittedMode> = (0..poles.len())
            .map(|i| FittedMode {
                frequency_hz: poles[i].0 / (2.0 * PI),
                damping: poles[i].1,
                gain: gains[rigid + i],
            })
            .collect();
        modes.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
        let mut fit = Self {
            rigid_gain: spec.rigid_body.then(|| gains[0]),
            modes,
            quality: FitQuality {
                rms_error_db: 0.0,
                max_error_db: 0.0,
                max_error_degrees: 0.0,
                lines_used: lines.len(),
            },
            evaluations,
        };
        fit.quality = fit.quality_on(&lines, ts);
        let finite = [
            fit.quality.rms_error_db,
            fit.quality.max_error_db,
            fit.quality.max_error_degrees,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite {
            return Err(ModalFitError::NotConverged {
                evaluations,
                reason: "the fitted model is not finite on the lines".into(),
            });
        }
        Ok(fit)
    }

    /// The fitted model's response at `frequency_hz`, as the loop at
    /// `rate_hz` sees it (behind a zero-order hold): what was compared with
    /// the measurement.
    pub fn response(&self, frequency_hz: f64, rate_hz: f64) -> Complex<f64> {
        let ts = 1.0 / rate_hz;
        let z = C64::new(0.0, 2.0 * PI * frequency_hz * ts).exp();
        let rigid = self
            .rigid_gain
            .map_or(C64::new(0.0, 0.0), |c| rigid_term(z, ts) * c);
        self.modes.iter().fold(rigid, |sum, m| {
            sum + ModeTerm::new(2.0 * PI * m.frequency_hz, m.damping, ts).at(z) * m.gain
        })
    }

    /// The fitted model as a [`ModalModel`] of one input and one output: the
    /// rigid body first (ω = 0), then the modes by frequency, each gain c
    /// split as φ_a = √|c|, φ_s = sign(c) √|c| (for a collocated rigid body,
    /// 1/√m each, as the mass-normalised modes of modal.rs have it).
    pub fn modal_model(&self) -> ModalModel {
        let mut omega = Vec::with_capacity(self.modes.len() + 1);
        let mut zeta = Vec::with_capacity(self.modes.len() + 1);
        let mut gains = Vec::with_capacity(self.modes.len() + 1);
        if let Some(c) = self.rigid_gain {
            omega.push(0.0);
            zeta.push(0.0);
            gains.push(c);
        }
        for m in &self.modes {
            omega.push(2.0 * PI * m.frequency_hz);
            zeta.push(m.damping);
            gains.push(m.gain);
        }
        let n = gains.len();
        let phi_a = DMatrix::from_iterator(n, 1, gains.iter().map(|c| c.abs().sqrt()));
        let phi_s = DMatrix::from_iterator(1, n, gains.iter().map(|c| c.signum() * c.abs().sqrt()));
        ModalModel {
            omega,
            zeta,
            phi_a,
            phi_s,
            shapes: None,
            n_rigid: usize::from(self.rigid_gain.is_some()),
        }
    }

    /// The fitted model as a continuous state space in modal coordinates:
    /// per mode its position and velocity (docs/control.md (2.9)), force in,
    /// position out, D = 0; its ZOH image at the loop's rate is
    /// [`ModalFit::response`]. This is what a `state-space` plant file holds
    /// (A, B, C, D without `ts`: the model is continuous; docs/own-plant.md).
    pub fn state_space(&self) -> ContinuousStateSpace {
        self.modal_model().state_space()
    }

    fn quality_on(&self, lines: &[Line], ts: f64) -> FitQuality {
        let rate = 1.0 / ts;
        let (mut sum, mut max_db, mut max_deg) = (0.0, 0.0_f64, 0.0_f64);
        for line in lines {
            let ratio = self.response(line.frequency_hz, rate) / line.measured;
            let db = 20.0 * ratio.norm().log10();
            sum += db * db;
            max_db = max_db.max(db.abs());
            max_deg = max_deg.max(ratio.arg().to_degrees().abs());
        }
        FitQuality {
            rms_error_db: (sum / lines.len() as f64).sqrt(),
            max_error_db: max_db,
            max_error_degrees: max_deg,
            lines_used: lines.len(),
        }
    }
}

fn check_spec(spec: &ModalFitSpec) -> Result<(), ModalFitError> {
    let invalid = |why: String| Err(ModalFitError::InvalidSpec(why));
    if spec.flexible_modes == 0 && !spec.rigid_body {
        return invalid("it asks for no mode and no rigid body".into());
    }
    if !(0.0..=1.0).contains(&spec.min_coherence) {
        return invalid(format!(
            "min_coherence {} is not in [0, 1]",
            spec.min_coherence
        ));
    }
    if !(spec.min_prominence_db.is_finite() && spec.min_prominence_db >= 0.0) {
        return invalid(format!(
            "min_prominence_db {} is not a non-negative number",
            spec.min_prominence_db
        ));
    }
    if spec.max_evaluations == 0 {
        return invalid("max_evaluations is 0".into());
    }
    Ok(())
}

/// One line the fit uses.
#[derive(Debug, Clone, Copy)]
struct Line {
    frequency_hz: f64,
    /// e^{jωTs}.
    z: C64,
    measured: C64,
    /// The coherence: each line's weight in the sums of squares.
    weight: f64,
}

/// The lines of coherence ≥ `min_coherence` and a non-zero response, after
/// checking every line (a NaN coherence cannot be judged, so it is refused
/// wherever it is).
fn usable_lines(frf: &Frf, rate_hz: f64, min_coherence: f64) -> Result<Vec<Line>, ModalFitError> {
    let n = frf.frequencies_hz.len();
    if frf.response.len() != n || frf.coherence.len() != n {
        return Err(ModalFitError::Mismatch {
            frequencies: n,
            responses: frf.response.len(),
            coherences: frf.coherence.len(),
        });
    }
    let nyquist_hz = rate_hz / 2.0;
    let mut lines = Vec::with_capacity(n);
    for i in 0..n {
        let (f, p, c) = (frf.frequencies_hz[i], frf.response[i], frf.coherence[i]);
        if !(f.is_finite() && p.re.is_finite() && p.im.is_finite() && c.is_finite()) {
            return Err(ModalFitError::NonFinite { line: i });
        }
        if f <= 0.0 || f >= nyquist_hz || (i > 0 && f <= frf.frequencies_hz[i - 1]) {
            return Err(ModalFitError::BadFrequency {
                line: i,
                frequency_hz: f,
                nyquist_hz,
            });
        }
        if c >= min_coherence && p.norm() > 0.0 {
            lines.push(Line {
                frequency_hz: f,
                z: C64::new(0.0, 2.0 * PI * f / rate_hz).exp(),
                measured: p,
                weight: c.max(0.0),
            });
        }
    }
    Ok(lines)
}

/// A peak of the measurement: the line it is at, its neighbours' angular
/// frequencies (between which the resonance lies), and its prominence.
#[derive(Debug, Clone, Copy)]
struct Peak {
    omega: f64,
    bracket: (f64, f64),
    prominence_db: f64,
}

/// The local maxima of |P| (of |P|ω² with a rigid body, whose 1/ω² would
/// otherwise tilt small peaks into shoulders) of at least `min_prominence_db`
/// prominence, the most prominent first. A line at either end is no peak:
/// nothing shows that the response falls beyond it.
fn pick_peaks(lines: &[Line], rigid_body: bool, min_prominence_db: f64) -> Vec<Peak> {
    let level: Vec<f64> = lines
        .iter()
        .map(|l| {
            let w = 2.0 * PI * l.frequency_hz;
            let v = if rigid_body {
                l.measured.norm() * w * w
            } else {
                l.measured.norm()
            };
            20.0 * v.log10()
        })
        .collect();
    let n = level.len();
    let mut peaks = Vec::new();
    for k in 1..n.saturating_sub(1) {
        if !(level[k] > level[k - 1] && level[k] >= level[k + 1]) {
            continue;
        }
        // Topographic prominence: the lowest point on each side before a
        // higher line (or the end); the peak stands above the higher of them.
        let lowest = |range: &mut dyn Iterator<Item = usize>| {
            let mut low = level[k];
            for j in range {
                if level[j] > level[k] {
                    break;
                }
                low = low.min(level[j]);
            }
            low
        };
        let left = lowest(&mut (0..k).rev());
        let right = lowest(&mut (k + 1..n));
        let prominence_db = level[k] - left.max(right);
        if prominence_db >= min_prominence_db {
            let omega = |j: usize| 2.0 * PI * lines[j].frequency_hz;
            peaks.push(Peak {
                omega: omega(k),
                bracket: (omega(k - 1), omega(k + 1)),
                prominence_db,
            });
        }
    }
    peaks.sort_by(|a, b| b.prominence_db.total_cmp(&a.prominence_db));
    peaks
}

/// The ZOH image of 1/s² at z: Ts² (z + 1) / (2 (z − 1)²).
fn rigid_term(z: C64, ts: f64) -> C64 {
    let one = C64::new(1.0, 0.0);
    (z + one) * (ts * ts) / ((z - one) * (z - one) * 2.0)
}

/// The ZOH image of 1/(s² + 2ζωs + ω²) = 1/((s − p₁)(s − p₂)): with
/// H(s)/s = 1/(ω² s) + r₁/(s − p₁) + r₂/(s − p₂), rᵢ = 1/(pᵢ(pᵢ − pⱼ)),
/// G(z) = (1 − z⁻¹) Z{H(s)/s} = 1/ω² + (z − 1) Σᵢ rᵢ/(z − e^{pᵢTs}).
#[derive(Debug, Clone, Copy)]
struct ModeTerm {
    static_gain: f64,
    r: [C64; 2],
    q: [C64; 2],
}

impl ModeTerm {
    fn new(omega: f64, zeta: f64, ts: f64) -> Self {
        let zeta = zeta.clamp(ZETA_MIN, ZETA_MAX);
        let root = C64::new(zeta * zeta - 1.0, 0.0).sqrt();
        let p = [(root - zeta) * omega, (-root - zeta) * omega];
        let r = [(p[0] * (p[0] - p[1])).inv(), (p[1] * (p[1] - p[0])).inv()];
        Self {
            static_gain: 1.0 / (omega * omega),
            r,
            q: [(p[0] * ts).exp(), (p[1] * ts).exp()],
        }
    }

    fn at(&self, z: C64) -> C64 {
        let one = C64::new(1.0, 0.0);
        (z - one) * (self.r[0] / (z - self.q[0]) + self.r[1] / (z - self.q[1])) + self.static_gain
    }
}

/// The model's terms on the lines, and the fit's steps.
struct Fitter<'a> {
    lines: &'a [Line],
    ts: f64,
    /// The ZOH image of 1/s² over the measurement on the lines, if the model
    /// has a rigid body.
    rigid: Option<Vec<C64>>,
    /// The range ω is kept in: a tenth of the lowest line to Nyquist.
    omega_range: (f64, f64),
}

/// One mode's (ω, ζ).
type Pole = (f64, f64);

/// Σₗ wₗ Re(conj(aₗ) bₗ): the weighted real inner product of two columns.
fn inner(lines: &[Line], a: &[C64], b: &[C64]) -> f64 {
    lines
        .iter()
        .zip(a.iter().zip(b))
        .map(|(l, (a, b))| l.weight * (a.conj() * b).re)
        .sum()
}

/// The normal equations of the gains (Gram matrix and right-hand side)
/// solved with unit diagonal (the rigid body's and a mode's terms differ by
/// decades) by SVD, so near-collinear terms give a least-norm answer rather
/// than a blow-up; `None` for a zero or non-finite column.
fn solve_normal(mut gram: DMatrix<f64>, mut rhs: DVector<f64>) -> Option<Vec<f64>> {
    let k = rhs.len();
    let scale: Vec<f64> = (0..k).map(|i| gram[(i, i)].sqrt()).collect();
    if scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return None;
    }
    for i in 0..k {
        rhs[i] /= scale[i];
        for j in 0..k {
            gram[(i, j)] /= scale[i] * scale[j];
        }
    }
    let svd = gram.svd(true, true);
    let floor = 1e-13 * svd.singular_values.max();
    let x = svd.solve(&rhs, floor).ok()?;
    let gains: Vec<f64> = x.iter().zip(&scale).map(|(v, s)| v / s).collect();
    gains.iter().all(|g| g.is_finite()).then_some(gains)
}

impl<'a> Fitter<'a> {
    fn new(lines: &'a [Line], ts: f64, rigid_body: bool) -> Self {
        let rigid = rigid_body.then(|| {
            lines
                .iter()
                .map(|l| rigid_term(l.z, ts) / l.measured)
                .collect()
        });
        Self {
            lines,
            ts,
            rigid,
            omega_range: (0.2 * PI * lines[0].frequency_hz, PI / ts),
        }
    }

    /// The ZOH image of mode (ω, ζ) over the measurement on the lines:
    /// uₗ = G(zₗ)/Pₗ, so that the model over the measurement is Σⱼ cⱼ uⱼ.
    fn column(&self, (omega, zeta): Pole) -> Vec<C64> {
        let omega = omega.clamp(self.omega_range.0, self.omega_range.1);
        let term = ModeTerm::new(omega, zeta, self.ts);
        self.lines
            .iter()
            .map(|l| term.at(l.z) / l.measured)
            .collect()
    }

    /// Every column, the rigid body's first.
    fn columns(&self, poles: &[Pole]) -> Vec<Vec<C64>> {
        self.rigid
            .iter()
            .cloned()
            .chain(poles.iter().map(|&p| self.column(p)))
            .collect()
    }

    /// The gains minimising Σ w |Σⱼ cⱼ uⱼ − 1|², the relative error
    /// (P_model − P)/P, which is ln(P_model/P) to first order; `None` when
    /// the columns are degenerate.
    fn gains(&self, columns: &[Vec<C64>]) -> Option<Vec<f64>> {
        let k = columns.len();
        let one = vec![C64::new(1.0, 0.0); self.lines.len()];
        let gram = DMatrix::from_fn(k, k, |i, j| inner(self.lines, &columns[i], &columns[j]));
        let rhs = DVector::from_fn(k, |i, _| inner(self.lines, &columns[i], &one));
        solve_normal(gram, rhs)
    }

    /// Σ w |ln(Σⱼ cⱼ uⱼ)|², +∞ where the model vanishes or is not finite.
    fn cost(&self, columns: &[&[C64]], gains: &[f64]) -> f64 {
        let mut sum = 0.0;
        for (l, line) in self.lines.iter().enumerate() {
            let ratio: C64 = columns.iter().zip(gains).map(|(c, g)| c[l] * *g).sum();
            let e = ratio.ln();
            if !(e.re.is_finite() && e.im.is_finite()) {
                return f64::INFINITY;
            }
            sum += line.weight * e.norm_sqr();
        }
        sum
    }

    /// The start: each peak's (ω, ζ) scanned with the gains solved for, the
    /// modes added most prominent first, then each scanned again with all in.
    fn start(&self, peaks: &[Peak]) -> Vec<Pole> {
        let mut poles: Vec<Pole> = Vec::with_capacity(peaks.len());
        for (i, peak) in peaks.iter().enumerate() {
            poles.push((peak.omega, 0.01));
            self.scan(&mut poles, i, peak.bracket);
        }
        if peaks.len() > 1 {
            for (i, peak) in peaks.iter().enumerate() {
                self.scan(&mut poles, i, peak.bracket);
            }
        }
        poles
    }

    /// Sets mode `i` of `poles` to the grid point of least cost, the gains
    /// solved for at each point. The other terms' part of the normal
    /// equations is formed once; each point adds its own column's row.
    fn scan(&self, poles: &mut [Pole], i: usize, bracket: (f64, f64)) {
        let others: Vec<Pole> = poles
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, &pole)| pole)
            .collect();
        let fixed = self.columns(&others);
        let k = fixed.len() + 1;
        let one = vec![C64::new(1.0, 0.0); self.lines.len()];
        let mut gram = DMatrix::zeros(k, k);
        let mut rhs = DVector::zeros(k);
        for (a, column) in fixed.iter().enumerate() {
            rhs[a] = inner(self.lines, column, &one);
            for (b, other) in fixed.iter().enumerate().take(a + 1) {
                gram[(a, b)] = inner(self.lines, column, other);
                gram[(b, a)] = gram[(a, b)];
            }
        }
        let grid = |lo: f64, hi: f64, count: usize, at: usize| {
            lo * (hi / lo).powf(at as f64 / (count - 1) as f64)
        };
        let mut best = (f64::INFINITY, poles[i]);
        for a in 0..SCAN_FREQUENCIES {
            let omega = grid(bracket.0, bracket.1, SCAN_FREQUENCIES, a);
            for b in 0..SCAN_DAMPINGS {
                let zeta = grid(SCAN_ZETA.0, SCAN_ZETA.1, SCAN_DAMPINGS, b);
                let scanned = self.column((omega, zeta));
                let last = k - 1;
                for (j, column) in fixed.iter().enumerate() {
                    gram[(last, j)] = inner(self.lines, &scanned, column);
                    gram[(j, last)] = gram[(last, j)];
                }
                gram[(last, last)] = inner(self.lines, &scanned, &scanned);
                rhs[last] = inner(self.lines, &scanned, &one);
                let Some(gains) = solve_normal(gram.clone(), rhs.clone()) else {
                    continue;
                };
                let mut columns: Vec<&[C64]> = fixed.iter().map(Vec::as_slice).collect();
                columns.push(&scanned);
                let cost = self.cost(&columns, &gains);
                if cost < best.0 {
                    best = (cost, (omega, zeta));
                }
            }
        }
        poles[i] = best.1;
    }

    /// Levenberg–Marquardt from `start` (gains solved for there): the poles
    /// and the gains (rigid first, then in the order of `start`), and the
    /// evaluations made.
    fn refine(
        &self,
        start: &[Pole],
        max_evaluations: usize,
    ) -> Result<(Vec<Pole>, Vec<f64>, usize), ModalFitError> {
        let gains =
            self.gains(&self.columns(start))
                .ok_or_else(|| ModalFitError::NotConverged {
                    evaluations: 0,
                    reason: "the modes' terms are degenerate at the start".into(),
                })?;
        let modes = start.len();
        let mut x = DVector::zeros(2 * modes + gains.len());
        for (i, &(omega, zeta)) in start.iter().enumerate() {
            x[2 * i] = omega.ln();
            x[2 * i + 1] = zeta.ln();
        }
        for (j, g) in gains.iter().enumerate() {
            x[2 * modes + j] = *g;
        }
        let problem = Refinement {
            fitter: self,
            modes,
            x,
            evaluations: Cell::new(0),
            budget: max_evaluations,
        };
        // The crate's own bound, patience × (parameters + 1) evaluations, is
        // a backstop; the budget is counted exactly in the problem.
        let patience = max_evaluations.div_ceil(problem.x.len() + 1).max(1) + 1;
        let (problem, report) = LevenbergMarquardt::new()
            .with_ftol(1e-12)
            .with_xtol(1e-12)
            .with_gtol(1e-12)
            .with_patience(patience)
            .minimize(problem);
        let evaluations = problem.evaluations.get();
        // NoImprovementPossible: a tolerance below what f64 resolves was
        // reached first; the minimum is found as far as the arithmetic tells.
        let converged = report.termination.was_successful()
            || matches!(
                report.termination,
                TerminationReason::NoImprovementPossible(_)
            );
        if !converged {
            let reason = match report.termination {
                TerminationReason::User(why) | TerminationReason::Numerical(why) => why.into(),
                TerminationReason::LostPatience => "the evaluation budget was spent".into(),
                other => format!("{other:?}"),
            };
            return Err(ModalFitError::NotConverged {
                evaluations,
                reason,
            });
        }
        let poles = (0..modes).map(|i| problem.pole(i)).collect();
        let gains = problem.x.as_slice()[2 * modes..].to_vec();
        Ok((poles, gains, evaluations))
    }
}

/// The least-squares problem of the refinement: parameters
/// [ln ω₁, ln ζ₁, …, ln ωₙ, ln ζₙ, c₀ (with a rigid body), c₁, …, cₙ],
/// residuals √wₗ (Re, Im) ln(P_model,ₗ/Pₗ) line by line. The logarithms keep
/// ω and ζ positive; ω and ζ are held within range where they are used.
struct Refinement<'a> {
    fitter: &'a Fitter<'a>,
    modes: usize,
    x: DVector<f64>,
    /// Residual vectors and Jacobians evaluated so far, and the most allowed
    /// (beyond it the problem answers `None`, which stops the minimiser).
    evaluations: Cell<usize>,
    budget: usize,
}

impl Refinement<'_> {
    fn pole(&self, i: usize) -> Pole {
        let (lo, hi) = self.fitter.omega_range;
        (
            self.x[2 * i].exp().clamp(lo, hi),
            self.x[2 * i + 1].exp().clamp(ZETA_MIN, ZETA_MAX),
        )
    }

    fn gain(&self, j: usize) -> f64 {
        self.x[2 * self.modes + j]
    }

    /// Counts one evaluation; false once the budget is spent.
    fn spend(&self) -> bool {
        let spent = self.evaluations.get() + 1;
        self.evaluations.set(spent);
        spent <= self.budget
    }

    /// Every column (rigid first) and the model over the measurement.
    fn model(&self) -> (Vec<Vec<C64>>, Vec<C64>) {
        let poles: Vec<Pole> = (0..self.modes).map(|i| self.pole(i)).collect();
        let columns = self.fitter.columns(&poles);
        let ratio = (0..self.fitter.lines.len())
            .map(|l| {
                columns
                    .iter()
                    .enumerate()
                    .map(|(j, c)| c[l] * self.gain(j))
                    .sum()
            })
            .collect();
        (columns, ratio)
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Refinement<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        if !self.spend() {
            return None;
        }
        let (_, ratio) = self.model();
        let lines = self.fitter.lines;
        let mut r = DVector::zeros(2 * lines.len());
        for (l, line) in lines.iter().enumerate() {
            let e = ratio[l].ln() * line.weight.sqrt();
            if !(e.re.is_finite() && e.im.is_finite()) {
                return None;
            }
            r[2 * l] = e.re;
            r[2 * l + 1] = e.im;
        }
        Some(r)
    }

    /// ∂ ln P_model/∂θ = (∂P_model/∂θ)/P_model: the gains' columns exactly,
    /// ln ω and ln ζ by central differences of their mode's column.
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        if !self.spend() {
            return None;
        }
        let (columns, ratio) = self.model();
        let f = self.fitter;
        let rigid = usize::from(f.rigid.is_some());
        let mut jac = DMatrix::zeros(2 * f.lines.len(), self.x.len());
        let mut put = |col: usize, derivative: &dyn Fn(usize) -> C64| {
            for (l, line) in f.lines.iter().enumerate() {
                let d = derivative(l) / ratio[l] * line.weight.sqrt();
                jac[(2 * l, col)] = d.re;
                jac[(2 * l + 1, col)] = d.im;
            }
        };
        for i in 0..self.modes {
            let gain = self.gain(rigid + i);
            for which in 0..2 {
                let shifted = |sign: f64| {
                    let mut x = [self.x[2 * i], self.x[2 * i + 1]];
                    x[which] += sign * STEP;
                    f.column((x[0].exp(), x[1].exp()))
                };
                let (up, down) = (shifted(1.0), shifted(-1.0));
                put(2 * i + which, &|l| {
                    (up[l] - down[l]) * (gain / (2.0 * STEP))
                });
            }
        }
        for (j, column) in columns.iter().enumerate() {
            put(2 * self.modes + j, &|l| column[l]);
        }
        jac.iter().all(|v| v.is_finite()).then_some(jac)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::freq::freq_response_discrete;
    use crate::multisine::{Multisine, MultisineSpec, Phases};
    use crate::real_modal_form::modal_from_state_space;

    const RATE: f64 = 10_000.0;

    /// 1/(m s²) with m = 10 kg, and modes at 120 Hz (ζ = 0.02) and 450 Hz
    /// (ζ = 0.01): (frequency Hz, ζ, gain) after the rigid gain 0.1.
    const RIGID_GAIN: f64 = 0.1;
    const MODES: [(f64, f64, f64); 2] = [(120.0, 0.02, 0.05), (450.0, 0.01, 0.02)];

    fn known_plant() -> ContinuousStateSpace {
        let w: Vec<f64> = MODES.iter().map(|m| 2.0 * PI * m.0).collect();
        ModalModel::new(
            vec![0.0, w[0], w[1]],
            vec![0.0, MODES[0].1, MODES[1].1],
            DMatrix::from_column_slice(3, 1, &[1.0; 3]),
            DMatrix::from_row_slice(1, 3, &[RIGID_GAIN, MODES[0].2, MODES[1].2]),
        )
        .unwrap()
        .state_space()
    }

    /// The lines of the shipped measurement grid (docs/control.md §14): 60
    /// log-spaced lines from 5 Hz to 2 kHz on the bins of N = 2000 at 10 kHz.
    fn grid() -> Vec<f64> {
        Multisine::design(&MultisineSpec {
            rate_hz: RATE,
            period_samples: 2_000,
            f_min_hz: 5.0,
            f_max_hz: 2_000.0,
            max_lines: 60,
            amplitude: 1.0,
            phases: Phases::Schroeder,
        })
        .unwrap()
        .frequencies_hz()
    }

    /// The exact ZOH response of `plant`, through the state-space path the
    /// loop's design takes (discretise.rs, then freq.rs).
    fn measured(plant: &ContinuousStateSpace, frequencies: &[f64]) -> Frf {
        let discrete = zoh(plant, 1.0 / RATE).unwrap();
        Frf {
            frequencies_hz: frequencies.to_vec(),
            response: frequencies
                .iter()
                .map(|f| freq_response_discrete(&discrete, 2.0 * PI * f).unwrap()[(0, 0)])
                .collect(),
            coherence: vec![1.0; frequencies.len()],
        }
    }

    fn relative(found: f64, truth: f64) -> f64 {
        (found - truth).abs() / truth.abs()
    }

    #[test]
    fn modal_fit_closed_form_is_the_zoh_of_its_state_space() {
        let fit = ModalFit {
            rigid_gain: Some(0.1),
            modes: vec![
                FittedMode {
                    frequency_hz: 120.0,
                    damping: 0.02,
                    gain: 0.05,
                },
                FittedMode {
                    frequency_hz: 450.0,
                    damping: 0.3,
                    gain: -0.02,
                },
            ],
            quality: FitQuality {
                rms_error_db: 0.0,
                max_error_db: 0.0,
                max_error_degrees: 0.0,
                lines_used: 0,
            },
            evaluations: 0,
        };
        let discrete = zoh(&fit.state_space(), 1.0 / RATE).unwrap();
        for f in [0.5, 5.0, 119.0, 120.0, 450.0, 2_000.0, 4_900.0] {
            let exact = freq_response_discrete(&discrete, 2.0 * PI * f).unwrap()[(0, 0)];
            let closed = fit.response(f, RATE);
            assert!(
                (closed - exact).norm() < 1e-9 * exact.norm(),
                "{f} Hz: {closed} vs {exact}"
            );
        }
    }

    #[test]
    fn modal_fit_recovers_a_known_plant() {
        let frf = measured(&known_plant(), &grid());
        let fit = ModalFit::from_frf(&frf, RATE, &ModalFitSpec::new(2, true)).unwrap();
        eprintln!("noise-free fit: {fit:?}");
        assert_eq!(fit.modes.len(), 2);
        assert!(relative(fit.rigid_gain.unwrap(), RIGID_GAIN) < 0.02);
        for (mode, (f, zeta, gain)) in fit.modes.iter().zip(MODES) {
            assert!(relative(mode.frequency_hz, f) < 0.005, "{mode:?}");
            assert!(relative(mode.damping, zeta) < 0.1, "{mode:?}");
            assert!(relative(mode.gain, gain) < 0.02, "{mode:?}");
        }
        assert_eq!(fit.quality.lines_used, frf.response.len());
        assert!(fit.quality.rms_error_db < 0.1, "{:?}", fit.quality);
    }

    /// A complex Gaussian of `sigma` rms in each of the real and imaginary
    /// parts (Box–Muller), seeded.
    fn gaussian(rng: &mut oorandom::Rand64, sigma: f64) -> C64 {
        let u1 = 1.0 - rng.rand_float();
        let u2 = rng.rand_float();
        let radius = sigma * (-2.0 * u1.ln()).sqrt();
        C64::from_polar(radius, 2.0 * PI * u2)
    }

    #[test]
    fn modal_fit_with_noise_keeps_the_frequencies() {
        let mut frf = measured(&known_plant(), &grid());
        let mut rng = oorandom::Rand64::new(7);
        for p in &mut frf.response {
            *p *= C64::new(1.0, 0.0) + gaussian(&mut rng, 0.01);
        }
        frf.coherence.fill(0.99);
        let fit = ModalFit::from_frf(&frf, RATE, &ModalFitSpec::new(2, true)).unwrap();
        eprintln!("fit with 1 % noise: {fit:?}");
        for (mode, (f, _, _)) in fit.modes.iter().zip(MODES) {
            assert!(relative(mode.frequency_hz, f) < 0.02, "{mode:?}");
        }
        // The noise is the misfit: about 1.4 % (0.12 dB) rms in magnitude.
        assert!(fit.quality.rms_error_db < 0.3, "{:?}", fit.quality);
    }

    #[test]
    fn modal_fit_refuses_what_it_cannot_fit() {
        let frf = measured(&known_plant(), &grid());
        let spec = ModalFitSpec::new(2, true);
        // More modes than peaks: an error, not a model with invented modes.
        assert_eq!(
            ModalFit::from_frf(&frf, RATE, &ModalFitSpec::new(5, true)),
            Err(ModalFitError::TooFewPeaks {
                asked: 5,
                found: 2,
                min_prominence_db: 1.0
            })
        );
        // Too few lines above the coherence threshold.
        let mut poor = frf.clone();
        for c in poor.coherence.iter_mut().skip(10) {
            *c = 0.5;
        }
        let e = ModalFit::from_frf(&poor, RATE, &spec).unwrap_err();
        assert_eq!(
            e,
            ModalFitError::TooFewLines {
                used: 10,
                needed: 14,
                min_coherence: 0.99
            }
        );
        assert!(
            e.to_string()
                .starts_with("only 10 lines have coherence ≥ 0.99")
        );
        // Non-finite input, wherever it is.
        for at in [0, 30] {
            let mut bad = frf.clone();
            bad.response[at] = C64::new(f64::NAN, 0.0);
            assert_eq!(
                ModalFit::from_frf(&bad, RATE, &spec),
                Err(ModalFitError::NonFinite { line: at })
            );
        }
        let mut bad = frf.clone();
        bad.coherence[3] = f64::INFINITY;
        assert_eq!(
            ModalFit::from_frf(&bad, RATE, &spec),
            Err(ModalFitError::NonFinite { line: 3 })
        );
        // Lines out of order or beyond Nyquist; counts that differ.
        let mut bad = frf.clone();
        bad.frequencies_hz.swap(4, 5);
        assert!(matches!(
            ModalFit::from_frf(&bad, RATE, &spec),
            Err(ModalFitError::BadFrequency { line: 5, .. })
        ));
        assert!(matches!(
            ModalFit::from_frf(&frf, 3_000.0, &spec),
            Err(ModalFitError::BadFrequency { .. })
        ));
        let mut bad = frf.clone();
        bad.coherence.pop();
        assert!(matches!(
            ModalFit::from_frf(&bad, RATE, &spec),
            Err(ModalFitError::Mismatch { .. })
        ));
        for rate in [f64::NAN, 0.0] {
            assert!(matches!(
                ModalFit::from_frf(&frf, rate, &spec),
                Err(ModalFitError::InvalidRate(_))
            ));
        }
        assert!(matches!(
            ModalFit::from_frf(&frf, RATE, &ModalFitSpec::new(0, false)),
            Err(ModalFitError::InvalidSpec(_))
        ));
        // An evaluation budget too small to converge in.
        let tight = ModalFitSpec {
            max_evaluations: 2,
            ..spec
        };
        let e = ModalFit::from_frf(&frf, RATE, &tight).unwrap_err();
        assert!(matches!(e, ModalFitError::NotConverged { .. }), "{e:?}");
        assert!(
            e.to_string().starts_with("the fit did not converge within"),
            "{e}"
        );
    }

    #[test]
    fn modal_fit_written_as_a_plant_file_reads_back_the_same_response() {
        use flexloop_modelfile::{Array, ModelArrays, VectorAs};
        let frf = measured(&known_plant(), &grid());
        let fit = ModalFit::from_frf(&frf, RATE, &ModalFitSpec::new(2, true)).unwrap();
        let ss = fit.state_space();
        let dir = std::env::temp_dir().join(format!("flexloop-modal-fit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("fitted.npz");
        ModelArrays::write_npz(
            &path,
            &[
                ("A", Array::from_matrix(&ss.a)),
                ("B", Array::from_matrix(&ss.b)),
                ("C", Array::from_matrix(&ss.c)),
                ("D", Array::from_matrix(&ss.d)),
            ],
        )
        .unwrap();
        let read = ModelArrays::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // As the `state-space` plant reads it (shared/design plants/own.rs).
        let a = read.matrix("A", VectorAs::Column).unwrap();
        let b = read.matrix("B", VectorAs::Column).unwrap();
        let c = read.matrix("C", VectorAs::Row).unwrap();
        let d = read.optional_matrix("D", VectorAs::Row).unwrap().unwrap();
        assert_eq!((&a, &b, &c, &d), (&ss.a, &ss.b, &ss.c, &ss.d));
        let back = zoh(
            &ContinuousStateSpace::new(a.clone(), b.clone(), c.clone(), d.clone()).unwrap(),
            1.0 / RATE,
        )
        .unwrap();
        for f in &frf.frequencies_hz {
            let read_back = freq_response_discrete(&back, 2.0 * PI * f).unwrap()[(0, 0)];
            let fitted = fit.response(*f, RATE);
            assert!((read_back - fitted).norm() < 1e-9 * fitted.norm(), "{f} Hz");
        }
        // And flexloop takes it as a plant: the modal form of the file is
        // the fit's (real_modal_form.rs, what a `state-space` plant becomes).
        let modal = modal_from_state_space(&a, &b, &c, Some(&d)).unwrap();
        assert_eq!(modal.n_rigid, 1);
        let fitted = fit.modal_model();
        for i in 0..3 {
            let product = |m: &ModalModel| m.phi_a[(i, 0)] * m.phi_s[(0, i)];
            assert!((modal.omega[i] - fitted.omega[i]).abs() <= 1e-9 * fitted.omega[i]);
            assert!((modal.zeta[i] - fitted.zeta[i]).abs() <= 1e-9);
            assert!((product(&modal) - product(&fitted)).abs() <= 1e-9 * product(&fitted).abs());
        }
    }
}
