//! Frequency responses of continuous and discrete state spaces, and the
//! SISO loop analysis of control.md §5.4/§6: sensitivities S^I, S^O, the
//! r → e_true transfer, bandwidth as the first 0 dB crossing, peaks, and
//! bandwidth optimisers under the 6 dB rule, in continuous time (the
//! thesis's setting, control.md §9: [`ContinuousBandwidthProblem`]) and in
//! discrete time with loop delay (control.md §10.1:
//! [`DiscreteBandwidthProblem`]).
//!
//! Both problems compute the plant and observer responses once on a
//! frequency grid (log-spaced, refined around every lightly damped pole of
//! the plants and observers, whose peaks are only ~1 % wide); for each f_bw
//! only the controller response (closed form, [`pid_response`]) changes. The
//! closed-loop eigenvalues are checked as well: the 6 dB bound alone does not
//! guarantee stability with 0.5 %-damped modes.

use crate::closed_loop::{LoopSpec, assemble_continuous_loop, assemble_loop};
use crate::continuous::ContinuousStateSpace;
use crate::design_error::DesignError;
use crate::linalg::LinalgError;
use crate::lti::DiscreteStateSpace;
use crate::observer_block::ObserverBlock;
use crate::pid::PidTuning;
use nalgebra::{Complex, DMatrix};
use std::f64::consts::PI;

type C64 = Complex<f64>;

fn response(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: &DMatrix<f64>,
    point: C64,
) -> Result<DMatrix<C64>, LinalgError> {
    let n = a.nrows();
    let to_c = |m: &DMatrix<f64>| m.map(|v| C64::new(v, 0.0));
    let mut out = to_c(d);
    if n > 0 {
        let m = DMatrix::<C64>::identity(n, n) * point - to_c(a);
        let x = m
            .lu()
            .solve(&to_c(b))
            .ok_or(LinalgError::Singular("(sI - A) at a pole"))?;
        out += to_c(c) * x;
    }
    if out.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return Err(LinalgError::NonFinite);
    }
    Ok(out)
}

/// G(jω) = C (jωI − A)⁻¹ B + D.
pub fn freq_response_continuous(
    sys: &ContinuousStateSpace,
    w: f64,
) -> Result<DMatrix<C64>, LinalgError> {
    response(&sys.a, &sys.b, &sys.c, &sys.d, C64::new(0.0, w))
}

/// G(e^{jωTs}) = C (zI − A)⁻¹ B + D.
pub fn freq_response_discrete(
    sys: &DiscreteStateSpace,
    w: f64,
) -> Result<DMatrix<C64>, LinalgError> {
    let z = C64::new(0.0, w * sys.ts).exp();
    response(&sys.a, &sys.b, &sys.c, &sys.d, z)
}

/// Evaluates C (pI − A)⁻¹ B + D at many points p: a plain LU with partial
/// pivoting on row-major storage that skips zero multipliers, so a modal
/// (block-diagonal) plant costs O(n²) per point and a dense observer
/// O(n³/3), without the per-call overhead of a generic complex LU. (A
/// Hessenberg reduction would be O(n²) for every system but loses ~1e-3 of
/// relative accuracy at 0.3 Hz in the observer's O_uy, whose zero at s = 0
/// is a cancellation of large terms; LU keeps it to ~1e-5 there, and to
/// ~1e-9 wherever the loop's peaks are.)
#[derive(Debug, Clone)]
struct ResponseEvaluator {
    n: usize,
    m: usize,
    p: usize,
    /// A, row-major n × n.
    a: Vec<f64>,
    /// B, row-major n × m.
    b: Vec<f64>,
    /// C, row-major p × n.
    c: Vec<f64>,
    /// D, row-major p × m.
    d: Vec<f64>,
}

impl ResponseEvaluator {
    fn new(
        a: &DMatrix<f64>,
        b: &DMatrix<f64>,
        c: &DMatrix<f64>,
        d: &DMatrix<f64>,
    ) -> Result<Self, LinalgError> {
        let (n, m, p) = (a.nrows(), b.ncols(), c.nrows());
        if [a, b, c, d]
            .iter()
            .any(|x| x.iter().any(|v| !v.is_finite()))
        {
            return Err(LinalgError::NonFinite);
        }
        if a.ncols() != n || b.nrows() != n || c.ncols() != n || d.shape() != (p, m) {
            return Err(LinalgError::NotSquare {
                rows: a.nrows(),
                cols: a.ncols(),
            });
        }
        let row_major = |x: &DMatrix<f64>| x.transpose().as_slice().to_vec();
        Ok(Self {
            n,
            m,
            p,
            a: row_major(a),
            b: row_major(b),
            c: row_major(c),
            d: row_major(d),
        })
    }

    /// G(point), row-major p × m.
    fn eval(&self, point: C64) -> Result<Vec<C64>, LinalgError> {
        let (n, m, p) = (self.n, self.m, self.p);
        let zero = C64::new(0.0, 0.0);
        // In-place LU with partial pivoting: multipliers below the diagonal.
        let mut lu: Vec<C64> = self.a.iter().map(|&v| C64::new(-v, 0.0)).collect();
        for i in 0..n {
            lu[i * n + i] += point;
        }
        let mut perm: Vec<usize> = (0..n).collect();
        for k in 0..n {
            let mut piv_row = k;
            let mut piv_abs = lu[k * n + k].norm_sqr();
            for i in k + 1..n {
                let v = lu[i * n + k].norm_sqr();
                if v > piv_abs {
                    piv_abs = v;
                    piv_row = i;
                }
            }
            if piv_abs == 0.0 || !piv_abs.is_finite() {
                return Err(LinalgError::Singular("(sI - A) at a pole"));
            }
            if piv_row != k {
                for j in 0..n {
                    lu.swap(k * n + j, piv_row * n + j);
                }
                perm.swap(k, piv_row);
            }
            let piv = lu[k * n + k];
            for i in k + 1..n {
                let lik = lu[i * n + k];
                if lik == zero {
                    continue;
                }
                let f = lik / piv;
                lu[i * n + k] = f;
                for j in k + 1..n {
                    let v = lu[k * n + j];
                    if v != zero {
                        lu[i * n + j] -= f * v;
                    }
                }
            }
        }
        // Solves (LU) y = P rhs in place.
        let solve = |rhs: &mut Vec<C64>| {
            let permuted: Vec<C64> = (0..n * m).map(|t| rhs[perm[t / m] * m + t % m]).collect();
            *rhs = permuted;
            for i in 1..n {
                for k in 0..i {
                    let f = lu[i * n + k];
                    if f != zero {
                        for j in 0..m {
                            let v = rhs[k * m + j];
                            rhs[i * m + j] -= f * v;
                        }
                    }
                }
            }
            for k in (0..n).rev() {
                let piv = lu[k * n + k];
                for j in 0..m {
                    let mut acc = rhs[k * m + j];
                    for l in k + 1..n {
                        let v = lu[k * n + l];
                        if v != zero {
                            acc -= v * rhs[l * m + j];
                        }
                    }
                    rhs[k * m + j] = acc / piv;
                }
            }
        };
        let mut x: Vec<C64> = self.b.iter().map(|&v| C64::new(v, 0.0)).collect();
        solve(&mut x);
        let mut out: Vec<C64> = self.d.iter().map(|&v| C64::new(v, 0.0)).collect();
        for i in 0..p {
            for l in 0..n {
                let cv = self.c[i * n + l];
                if cv != 0.0 {
                    for j in 0..m {
                        out[i * m + j] += x[l * m + j] * cv;
                    }
                }
            }
        }
        if out.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
            return Err(LinalgError::NonFinite);
        }
        Ok(out)
    }
}

/// Logarithmic frequency grid [rad/s] from f_lo to f_hi Hz.
pub fn log_grid_hz(f_lo: f64, f_hi: f64, points: usize) -> Vec<f64> {
    let (l0, l1) = (f_lo.log10(), f_hi.log10());
    let n = points.max(2);
    (0..n)
        .map(|i| 2.0 * PI * 10f64.powf(l0 + (l1 - l0) * i as f64 / (n - 1) as f64))
        .collect()
}

/// The Table 3.3 PID with low-pass and notches (control.md §6) at a point s
/// of the s-plane, in closed form (the same transfer function as
/// [`PidTuning::continuous`]).
pub fn pid_response(t: &PidTuning, s: C64) -> C64 {
    let one = C64::new(1.0, 0.0);
    let w2 = t.wlp * t.wlp;
    let mut c =
        (s + t.wi) * t.kp / s * (s / t.wd + one) * w2 / (s * s + s * (2.0 * t.zlp * t.wlp) + w2);
    for &w in &t.notches {
        c *= (s * s + s * (0.002 * w) + w * w) / (s * s + s * (0.2 * w) + w * w);
    }
    c
}

/// The Tustin (no pre-warping) image of e^{jωTs}: s = (2/Ts)(z − 1)/(z + 1)
/// = j (2/Ts) tan(ωTs/2). A continuous transfer function evaluated there is
/// exactly its Tustin discretisation at ω ([`PidTuning::discrete`]).
pub fn tustin_point(w: f64, ts: f64) -> C64 {
    C64::new(0.0, 2.0 / ts * (w * ts / 2.0).tan())
}

/// Notch frequency to put into a continuous design so that, after Tustin
/// without pre-warping, the discrete notch sits at `w` [rad/s]: (2/Ts) tan(ωTs/2).
pub fn prewarped_notch(w: f64, ts: f64) -> Result<f64, DesignError> {
    if !(w.is_finite() && w > 0.0 && ts.is_finite() && ts > 0.0 && w * ts < PI) {
        return Err(DesignError::InvalidParameter(format!(
            "notch at {w} rad/s must lie below Nyquist ({} rad/s)",
            PI / ts
        )));
    }
    Ok(2.0 / ts * (w * ts / 2.0).tan())
}

/// Frequency-domain and stability summary of one SISO loop.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LoopMetrics {
    /// First 0 dB crossing of the open loop P_eq C_fb [Hz], if any.
    pub crossover_hz: Option<f64>,
    /// max |S^I| [dB] (r → e_meas).
    pub peak_si_db: f64,
    /// max |S^O| [dB] (output disturbance → measured output).
    pub peak_so_db: f64,
    /// max |T_{r→e_true}| [dB].
    pub peak_re_db: f64,
    /// Closed-loop eigenvalues all stable.
    pub stable: bool,
}

/// The four SISO observer transfers at one frequency (control.md §5):
/// ŷ_flex = O_yy y + O_yu u, u_d = O_uy y + O_uu u.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverResponse {
    pub yy: C64,
    pub yu: C64,
    pub uy: C64,
    pub uu: C64,
}

/// S^I, S^O, T_{r→e_true} and the open loop L = P_eq C at one frequency,
/// from the SISO formulas of control.md §5.4. `p` is the plant from the
/// controller output to y (including any loop delay), `o` the observer with
/// its u input referred to the same controller output.
pub fn siso_sensitivities(p: C64, c: C64, o: Option<ObserverResponse>) -> (C64, C64, C64, C64) {
    let one = C64::new(1.0, 0.0);
    let o = o.unwrap_or(ObserverResponse {
        yy: C64::new(0.0, 0.0),
        yu: C64::new(0.0, 0.0),
        uy: C64::new(0.0, 0.0),
        uu: C64::new(0.0, 0.0),
    });
    let p_eq = ((one - o.yy) * p - o.yu) / (one - o.uu - o.uy * p);
    let l = p_eq * c;
    let s_i = one / (one + l);
    let den = one - c * o.yu - o.uu;
    let c_eq = (c * (one - o.yy) - o.uy) / den;
    let s_o = one / (one + p * c_eq);
    let t_re = one - p * c / (den * (one + p * c_eq));
    (s_i, s_o, t_re, l)
}

/// |v| in dB; a non-finite value counts as +∞ (it violates any bound).
fn db(v: C64) -> f64 {
    let x = 20.0 * v.norm().log10();
    if x.is_nan() { f64::INFINITY } else { x }
}

/// First frequency [Hz] where |L| falls through 1 (log interpolation).
fn first_crossing(grid: &[f64], l_abs: &[f64]) -> Option<f64> {
    for i in 1..grid.len() {
        if l_abs[i - 1] >= 1.0 && l_abs[i] < 1.0 && l_abs[i] > 0.0 {
            let (a, b) = (l_abs[i - 1].ln(), l_abs[i].ln());
            let frac = a / (a - b);
            let w = (grid[i - 1].ln() + frac * (grid[i].ln() - grid[i - 1].ln())).exp();
            let f = w / (2.0 * PI);
            return f.is_finite().then_some(f);
        }
    }
    None
}

/// Metrics of a continuous SISO loop P(s), C(s) without observer.
pub fn continuous_loop_metrics(
    plant: &ContinuousStateSpace,
    controller: &ContinuousStateSpace,
    grid: &[f64],
) -> Result<LoopMetrics, DesignError> {
    let mut l_abs = Vec::with_capacity(grid.len());
    let (mut si, mut so, mut re) = (f64::MIN, f64::MIN, f64::MIN);
    for &w in grid {
        let p = freq_response_continuous(plant, w)?[(0, 0)];
        let c = freq_response_continuous(controller, w)?[(0, 0)];
        let (s_i, s_o, t_re, l) = siso_sensitivities(p, c, None);
        l_abs.push(l.norm());
        si = si.max(db(s_i));
        so = so.max(db(s_o));
        re = re.max(db(t_re));
    }
    let cl = assemble_continuous_loop(plant, None, controller)?;
    Ok(LoopMetrics {
        crossover_hz: first_crossing(grid, &l_abs),
        peak_si_db: si,
        peak_so_db: so,
        peak_re_db: re,
        stable: continuous_stable(&cl.a)?,
    })
}

fn continuous_stable(a: &DMatrix<f64>) -> Result<bool, DesignError> {
    Ok(crate::linalg::eigenvalues(a)?.iter().all(|s| s.re < 0.0))
}

/// Adds points around every pole (ω_n [rad/s], ζ) with ζ < 0.2 and
/// 0 < ω_n < w_max: 13 points spaced 0.5 ζ ω_n (ζ at least 1e-4).
fn refine_grid(grid: &mut Vec<f64>, poles: &[(f64, f64)], w_max: f64) {
    for &(w, zeta) in poles {
        if !(w.is_finite() && w > 0.0 && zeta < 0.2) {
            continue;
        }
        for k in -6..=6 {
            let wk = w * (1.0 + 0.5 * k as f64 * zeta.max(1e-4));
            if wk > 0.0 && wk < w_max {
                grid.push(wk);
            }
        }
    }
    grid.sort_by(|a, b| a.total_cmp(b));
    grid.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs());
}

fn continuous_poles(a: &DMatrix<f64>) -> Result<Vec<(f64, f64)>, DesignError> {
    Ok(crate::linalg::eigenvalues(a)?
        .iter()
        .filter(|s| s.im > 0.0)
        .map(|s| (s.norm(), -s.re / s.norm()))
        .collect())
}

fn discrete_poles(a: &DMatrix<f64>, ts: f64) -> Result<Vec<(f64, f64)>, DesignError> {
    Ok(crate::linalg::eigenvalues(a)?
        .iter()
        .filter(|z| z.im > 0.0)
        .map(|z| crate::linalg::discrete_pole_to_continuous(*z, ts))
        .collect())
}

fn check_problem_parameters(mass: f64, limit_db: f64) -> Result<(), DesignError> {
    if !(mass.is_finite() && mass > 0.0) {
        return Err(DesignError::InvalidParameter(format!(
            "mass {mass} must be positive"
        )));
    }
    if !limit_db.is_finite() {
        return Err(DesignError::NonFinite("peak limit [dB]"));
    }
    Ok(())
}

/// Continuous-time or sampled loop (how a frequency maps to a point of the
/// complex plane, and where the delays are).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Domain {
    Continuous,
    Discrete { ts: f64, loop_delay: usize },
}

/// The observer of one output, ready to evaluate.
#[derive(Debug, Clone)]
struct ObserverEval {
    eval: ResponseEvaluator,
    /// Block inputs: 2, or 3 with the extra-delay input u_pending.
    inputs: usize,
    extra_delay: usize,
}

/// What the two bandwidth problems share: the grid, the cached plant and
/// observer responses per output, and the evaluators for points off the grid
/// (around the closed-loop resonances of each f_bw).
#[derive(Debug, Clone)]
struct Responses {
    domain: Domain,
    grid: Vec<f64>,
    /// Per output, per grid point: (P, observer transfers), both referred to
    /// the controller output u_c.
    cache: Vec<Vec<(C64, Option<ObserverResponse>)>>,
    plants: Vec<ResponseEvaluator>,
    observers: Vec<Option<ObserverEval>>,
    /// Continuous notch frequencies [rad/s] of the controller (pre-warped
    /// in the discrete problem).
    notches: Vec<f64>,
}

impl Responses {
    fn new(
        domain: Domain,
        grid: Vec<f64>,
        plants: Vec<ResponseEvaluator>,
        observers: Vec<Option<ObserverEval>>,
    ) -> Result<Self, DesignError> {
        let mut r = Self {
            domain,
            grid,
            cache: Vec::new(),
            plants,
            observers,
            notches: Vec::new(),
        };
        let mut cache = Vec::with_capacity(r.plants.len());
        for i in 0..r.plants.len() {
            let row = r
                .grid
                .iter()
                .map(|&w| r.point(i, w))
                .collect::<Result<Vec<_>, _>>()?;
            cache.push(row);
        }
        r.cache = cache;
        Ok(r)
    }

    /// Plant and observer transfers of output `i` at ω [rad/s], referred to
    /// the controller output (loop delay included).
    fn point(&self, i: usize, w: f64) -> Result<(C64, Option<ObserverResponse>), LinalgError> {
        let (x, z_d, ts, delay) = match self.domain {
            Domain::Continuous => (C64::new(0.0, w), C64::new(1.0, 0.0), 0.0, 0),
            Domain::Discrete { ts, loop_delay } => (
                C64::new(0.0, w * ts).exp(),
                C64::new(0.0, -w * ts * loop_delay as f64).exp(),
                ts,
                loop_delay,
            ),
        };
        let p = self.plants[i].eval(x)?[0] * z_d;
        let o = match &self.observers[i] {
            Some(o) => {
                // Row-major 2 × inputs: [ŷ_flex; u_d] from [y; u_a (; u_pending)].
                let h = o.eval.eval(x)?;
                let ni = o.inputs;
                let (mut yu, mut uu) = (h[1] * z_d, h[ni + 1] * z_d);
                if o.extra_delay == 1 {
                    // u_pending(k) = u_c(k − d + 1).
                    let z_p = C64::new(0.0, -w * ts * (delay as f64 - 1.0)).exp();
                    yu += h[2] * z_p;
                    uu += h[ni + 2] * z_p;
                }
                Some(ObserverResponse {
                    yy: h[0],
                    yu,
                    uy: h[ni],
                    uu,
                })
            }
            None => None,
        };
        Ok((p, o))
    }

    /// The controller at ω (exact Tustin image in discrete time).
    fn controller_at(&self, t: &PidTuning, w: f64) -> C64 {
        match self.domain {
            Domain::Continuous => pid_response(t, C64::new(0.0, w)),
            Domain::Discrete { ts, .. } => pid_response(t, tustin_point(w, ts)),
        }
    }

    /// Peaks and crossover of output `i`: the cached grid with controller
    /// values `cvals`, plus 13 points around each lightly damped closed-loop
    /// pole (ω [rad/s], ζ) in `cl_poles`, where the narrow peaks are.
    fn metrics(
        &self,
        i: usize,
        t: &PidTuning,
        cvals: &[C64],
        cl_poles: &[(f64, f64)],
    ) -> Result<LoopMetrics, DesignError> {
        let (mut si, mut so, mut re) = (f64::MIN, f64::MIN, f64::MIN);
        let mut acc = |p: C64, c: C64, o: Option<ObserverResponse>| {
            let (s_i, s_o, t_re, l) = siso_sensitivities(p, c, o);
            si = si.max(db(s_i));
            so = so.max(db(s_o));
            re = re.max(db(t_re));
            l.norm()
        };
        let mut l_abs = Vec::with_capacity(self.grid.len());
        for (k, &(p, o)) in self.cache[i].iter().enumerate() {
            l_abs.push(acc(p, cvals[k], o));
        }
        let w_max = self.grid.last().copied().unwrap_or(0.0);
        for &(wp, zeta) in cl_poles {
            if !(wp.is_finite() && wp > 0.0 && zeta < 0.2) {
                continue;
            }
            for k in -6..=6 {
                let w = wp * (1.0 + 0.25 * k as f64 * zeta.max(1e-4));
                if w > 0.0 && w <= w_max {
                    let (p, o) = self.point(i, w)?;
                    acc(p, self.controller_at(t, w), o);
                }
            }
        }
        Ok(LoopMetrics {
            crossover_hz: first_crossing(&self.grid, &l_abs),
            peak_si_db: si,
            peak_so_db: so,
            peak_re_db: re,
            stable: false,
        })
    }

    fn tuning(&self, mass: f64, f_bw: f64) -> Result<PidTuning, DesignError> {
        Ok(PidTuning::single_parameter(mass, f_bw)?.with_notches(&self.notches))
    }
}

fn peaks_ok(m: &LoopMetrics, limit_db: f64, bound_re: bool) -> bool {
    m.peak_si_db <= limit_db && m.peak_so_db <= limit_db && (!bound_re || m.peak_re_db <= limit_db)
}

/// One of the bandwidth problems (private: the shared evaluate/scan code).
trait BandwidthCore {
    fn responses(&self) -> &Responses;
    /// (mass, peak limit [dB], bound |T_re| too).
    fn constraints(&self) -> (f64, f64, bool);
    /// Closed loop of output `i` with controller `t`: (stable, poles as
    /// (ω [rad/s], ζ), continuous equivalents).
    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError>;

    fn output_metrics(
        &self,
        i: usize,
        t: &PidTuning,
        cvals: &[C64],
    ) -> Result<LoopMetrics, DesignError> {
        let (stable, poles) = self.closed_loop(i, t)?;
        let mut m = self.responses().metrics(i, t, cvals, &poles)?;
        m.stable = stable;
        Ok(m)
    }

    fn controller_values(&self, t: &PidTuning) -> Vec<C64> {
        let r = self.responses();
        r.grid.iter().map(|&w| r.controller_at(t, w)).collect()
    }

    fn evaluate_all(&self, f_bw: f64) -> Result<Vec<LoopMetrics>, DesignError> {
        let r = self.responses();
        let t = r.tuning(self.constraints().0, f_bw)?;
        let cvals = self.controller_values(&t);
        (0..r.cache.len())
            .map(|i| self.output_metrics(i, &t, &cvals))
            .collect()
    }

    /// Stops at the first output that fails; the grid peaks alone (no
    /// eigenvalues) already rule out most infeasible values.
    fn is_feasible(&self, f_bw: f64) -> Result<bool, DesignError> {
        let r = self.responses();
        let (mass, limit, bound_re) = self.constraints();
        let t = r.tuning(mass, f_bw)?;
        let cvals = self.controller_values(&t);
        for i in 0..r.cache.len() {
            if !peaks_ok(&r.metrics(i, &t, &cvals, &[])?, limit, bound_re) {
                return Ok(false);
            }
        }
        for i in 0..r.cache.len() {
            let m = self.output_metrics(i, &t, &cvals)?;
            if !(m.stable && peaks_ok(&m, limit, bound_re)) {
                return Ok(false);
            }
        }
        Ok(true)
    }
}

/// Largest f = f_start + k·fine ≤ f_stop such that f and every smaller value
/// visited are feasible, found by a coarse scan (step ≈ `coarse`, a multiple
/// of `fine`) up to the first infeasible value, then a fine scan between the
/// last feasible coarse value and it. None if f_start is infeasible. A
/// feasibility gap narrower than `coarse` can be stepped over; use
/// coarse = fine for the exhaustive scan.
pub fn scan_max_bandwidth(
    f_start: f64,
    f_stop: f64,
    coarse: f64,
    fine: f64,
    mut feasible: impl FnMut(f64) -> Result<bool, DesignError>,
) -> Result<Option<f64>, DesignError> {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(f_start) && ok(fine) && ok(coarse) && f_stop.is_finite() && f_stop >= f_start) {
        return Err(DesignError::InvalidParameter(format!(
            "bandwidth scan {f_start}..{f_stop} Hz, steps {coarse}/{fine}"
        )));
    }
    let n_total = ((f_stop - f_start) / fine + 1e-9).floor();
    if n_total > 1e6 {
        return Err(DesignError::InvalidParameter(
            "bandwidth scan has more than 10⁶ points".into(),
        ));
    }
    let n = n_total as usize;
    let k = ((coarse / fine).round() as usize).max(1);
    let at = |i: usize| f_start + i as f64 * fine;
    if !feasible(at(0))? {
        return Ok(None);
    }
    let mut good = 0;
    let mut bad = None;
    let mut i = k;
    while i <= n {
        if feasible(at(i))? {
            good = i;
        } else {
            bad = Some(i);
            break;
        }
        i += k;
    }
    let upper = bad.map_or(n, |b| b - 1);
    for j in good + 1..=upper {
        if feasible(at(j))? {
            good = j;
        } else {
            break;
        }
    }
    Ok(Some(at(good)))
}

/// A continuous bandwidth problem (control.md §9, the thesis's setting): the
/// Table 3.3 PID (optionally with notches) on several plant outputs, each
/// with its own optional continuous observer (inputs [y; u], outputs
/// [ŷ_flex; u_d], e.g. [`crate::observer_block::ContinuousModalObserver`]),
/// and the 6 dB rule.
pub struct ContinuousBandwidthProblem {
    pub plants: Vec<ContinuousStateSpace>,
    pub observers: Vec<Option<ContinuousStateSpace>>,
    pub mass: f64,
    /// Peak limit [dB] (thesis: 6).
    pub limit_db: f64,
    /// Also bound |T_{r→e_true}| (the MC constraint).
    pub bound_re: bool,
    core: Responses,
}

impl ContinuousBandwidthProblem {
    /// Prepares the responses on a log grid from 0.5 Hz to 20 kHz, refined
    /// around the lightly damped poles of the plants and observers.
    pub fn new(
        plants: Vec<ContinuousStateSpace>,
        observers: Vec<Option<ContinuousStateSpace>>,
        mass: f64,
        limit_db: f64,
        bound_re: bool,
    ) -> Result<Self, DesignError> {
        check_problem_parameters(mass, limit_db)?;
        if plants.is_empty() || observers.len() != plants.len() {
            return Err(DesignError::InvalidParameter(
                "need one observer entry (or None) per plant".into(),
            ));
        }
        for (p, o) in plants.iter().zip(&observers) {
            if p.inputs() != 1 || p.outputs() != 1 {
                return Err(DesignError::DimensionMismatch {
                    what: "SISO plant (outputs x inputs)",
                    expected: (1, 1),
                    found: (p.outputs(), p.inputs()),
                });
            }
            if let Some(o) = o
                && (o.inputs() != 2 || o.outputs() != 2)
            {
                return Err(DesignError::DimensionMismatch {
                    what: "SISO observer [y; u] → [ŷ_flex; u_d] (outputs x inputs)",
                    expected: (2, 2),
                    found: (o.outputs(), o.inputs()),
                });
            }
        }
        let w_max = 2.0 * PI * 2e4;
        let mut grid = log_grid_hz(0.5, 2e4, 900);
        let mut poles = Vec::new();
        for p in &plants {
            poles.extend(continuous_poles(&p.a)?);
        }
        for o in observers.iter().flatten() {
            poles.extend(continuous_poles(&o.a)?);
        }
        refine_grid(&mut grid, &poles, w_max);
        let plant_evals = plants
            .iter()
            .map(|p| ResponseEvaluator::new(&p.a, &p.b, &p.c, &p.d))
            .collect::<Result<Vec<_>, _>>()?;
        let obs_evals = observers
            .iter()
            .map(|o| {
                o.as_ref()
                    .map(|o| {
                        Ok::<_, LinalgError>(ObserverEval {
                            eval: ResponseEvaluator::new(&o.a, &o.b, &o.c, &o.d)?,
                            inputs: 2,
                            extra_delay: 0,
                        })
                    })
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        let core = Responses::new(Domain::Continuous, grid, plant_evals, obs_evals)?;
        Ok(Self {
            plants,
            observers,
            mass,
            limit_db,
            bound_re,
            core,
        })
    }

    /// Adds notches N(s, ω) at `notches` [rad/s] to the controller.
    pub fn with_notches(mut self, notches: &[f64]) -> Self {
        self.core.notches = notches.to_vec();
        self
    }

    /// Metrics of every output at one f_bw.
    pub fn evaluate(&self, f_bw: f64) -> Result<Vec<LoopMetrics>, DesignError> {
        self.evaluate_all(f_bw)
    }

    /// Whether every output meets the constraints at f_bw.
    pub fn feasible(&self, f_bw: f64) -> Result<bool, DesignError> {
        self.is_feasible(f_bw)
    }

    /// Largest f_bw on the grid f_start, f_start + step, … ≤ f_stop such that
    /// it and every smaller grid value are feasible; None if f_start fails.
    pub fn max_bandwidth(
        &self,
        f_start: f64,
        f_stop: f64,
        step: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, step, step, |f| self.is_feasible(f))
    }

    /// [`scan_max_bandwidth`] (coarse, then fine) on this problem.
    pub fn max_bandwidth_refined(
        &self,
        f_start: f64,
        f_stop: f64,
        coarse: f64,
        fine: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, coarse, fine, |f| self.is_feasible(f))
    }
}

impl BandwidthCore for ContinuousBandwidthProblem {
    fn responses(&self) -> &Responses {
        &self.core
    }

    fn constraints(&self) -> (f64, f64, bool) {
        (self.mass, self.limit_db, self.bound_re)
    }

    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError> {
        let cl = assemble_continuous_loop(
            &self.plants[i],
            self.observers[i].as_ref(),
            &t.continuous()?,
        )?;
        let ev = crate::linalg::eigenvalues(&cl.a)?;
        let stable = ev.iter().all(|s| s.re < 0.0);
        let poles = ev
            .iter()
            .filter(|s| s.im > 0.0)
            .map(|s| (s.norm(), -s.re / s.norm()))
            .collect();
        Ok((stable, poles))
    }
}

/// A discrete bandwidth problem: the thesis PID (Table 3.3 tuning on
/// `mass`, Tustin, optional notches pre-warped onto the given frequencies)
/// on several plant outputs, each with its own optional observer block, a
/// loop delay, and the 6 dB rule. The plant and observer responses do not
/// depend on f_bw and are computed once.
pub struct DiscreteBandwidthProblem {
    pub plants: Vec<DiscreteStateSpace>,
    pub observers: Vec<Option<ObserverBlock>>,
    pub loop_delay: usize,
    pub mass: f64,
    /// Peak limit [dB] (thesis: 6).
    pub limit_db: f64,
    /// Also bound |T_{r→e_true}| (the MC constraint).
    pub bound_re: bool,
    core: Responses,
}

impl DiscreteBandwidthProblem {
    /// Prepares the responses on a log grid from 0.5 Hz to Nyquist, refined
    /// around every lightly damped plant and observer pole.
    pub fn new(
        plants: Vec<DiscreteStateSpace>,
        observers: Vec<Option<ObserverBlock>>,
        loop_delay: usize,
        mass: f64,
        limit_db: f64,
        bound_re: bool,
    ) -> Result<Self, DesignError> {
        check_problem_parameters(mass, limit_db)?;
        if plants.is_empty() || observers.len() != plants.len() {
            return Err(DesignError::InvalidParameter(
                "need one observer entry (or None) per plant".into(),
            ));
        }
        let ts = plants[0].ts;
        for (p, o) in plants.iter().zip(&observers) {
            if p.inputs() != 1 || p.outputs() != 1 || (p.ts - ts).abs() > 1e-12 * ts {
                return Err(DesignError::InvalidParameter(
                    "plants must be SISO with one sample period".into(),
                ));
            }
            if let Some(b) = o {
                if b.n_y != 1 || b.n_u != 1 || (b.system.ts - ts).abs() > 1e-12 * ts {
                    return Err(DesignError::InvalidParameter(
                        "observer blocks must be SISO with the plants' sample period".into(),
                    ));
                }
                if b.extra_delay_samples > 0 && loop_delay < 2 {
                    return Err(DesignError::InvalidParameter(
                        "an extra-delay observer block needs a loop delay of at least 2".into(),
                    ));
                }
            }
        }
        let f_nyq = 0.5 / ts;
        let w_nyq = 2.0 * PI * f_nyq;
        let mut grid = log_grid_hz(0.5, 0.999 * f_nyq, 800);
        let mut poles = Vec::new();
        for p in &plants {
            poles.extend(discrete_poles(&p.a, ts)?);
        }
        for b in observers.iter().flatten() {
            poles.extend(discrete_poles(&b.system.a, ts)?);
        }
        refine_grid(&mut grid, &poles, w_nyq);
        let plant_evals = plants
            .iter()
            .map(|p| ResponseEvaluator::new(&p.a, &p.b, &p.c, &p.d))
            .collect::<Result<Vec<_>, _>>()?;
        let obs_evals = observers
            .iter()
            .map(|o| {
                o.as_ref()
                    .map(|b| {
                        let s = &b.system;
                        Ok::<_, LinalgError>(ObserverEval {
                            eval: ResponseEvaluator::new(&s.a, &s.b, &s.c, &s.d)?,
                            inputs: s.inputs(),
                            extra_delay: b.extra_delay_samples,
                        })
                    })
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        let core = Responses::new(
            Domain::Discrete { ts, loop_delay },
            grid,
            plant_evals,
            obs_evals,
        )?;
        Ok(Self {
            plants,
            observers,
            loop_delay,
            mass,
            limit_db,
            bound_re,
            core,
        })
    }

    /// Adds notches at `notches` [rad/s]: the continuous notch frequencies
    /// are pre-warped ([`prewarped_notch`]) so that the Tustin controller
    /// has its notches exactly there.
    pub fn with_notches(mut self, notches: &[f64]) -> Result<Self, DesignError> {
        let ts = self.plants[0].ts;
        self.core.notches = notches
            .iter()
            .map(|&w| prewarped_notch(w, ts))
            .collect::<Result<_, _>>()?;
        Ok(self)
    }

    /// Metrics of every output at one f_bw.
    pub fn evaluate(&self, f_bw: f64) -> Result<Vec<LoopMetrics>, DesignError> {
        self.evaluate_all(f_bw)
    }

    /// Whether every output meets the constraints at f_bw.
    pub fn feasible(&self, f_bw: f64) -> Result<bool, DesignError> {
        self.is_feasible(f_bw)
    }

    /// Largest f_bw on the grid f_start, f_start + step, … ≤ f_stop such that
    /// it and every smaller grid value are feasible; None if f_start fails.
    pub fn max_bandwidth(
        &self,
        f_start: f64,
        f_stop: f64,
        step: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, step, step, |f| self.is_feasible(f))
    }

    /// [`scan_max_bandwidth`] (coarse, then fine) on this problem.
    pub fn max_bandwidth_refined(
        &self,
        f_start: f64,
        f_stop: f64,
        coarse: f64,
        fine: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, coarse, fine, |f| self.is_feasible(f))
    }
}

impl BandwidthCore for DiscreteBandwidthProblem {
    fn responses(&self) -> &Responses {
        &self.core
    }

    fn constraints(&self) -> (f64, f64, bool) {
        (self.mass, self.limit_db, self.bound_re)
    }

    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError> {
        let ts = self.plants[0].ts;
        let cl = assemble_loop(&LoopSpec {
            plant: &self.plants[i],
            observer: self.observers[i].as_ref(),
            controller: &t.discrete(ts)?,
            loop_delay: self.loop_delay,
        })?;
        let ev = crate::linalg::eigenvalues(&cl.a)?;
        let stable = ev.iter().all(|z| z.norm() < 1.0);
        let poles = ev
            .iter()
            .filter(|z| z.im > 0.0)
            .map(|z| crate::linalg::discrete_pole_to_continuous(*z, ts))
            .collect();
        Ok((stable, poles))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::models::{CHAIN_MASS, TS_10KHZ, thesis_plant, thesis_reduced};
    use crate::observer_block::{
        ContinuousObserverOptions, DampingOptions, ModalObserverOptions,
        design_continuous_modal_observer, design_modal_observer,
    };

    #[test]
    fn continuous_baseline_crossover_and_peak() {
        let grid = log_grid_hz(1.0, 5000.0, 3000);
        let pid = PidTuning::single_parameter(CHAIN_MASS, 35.5)
            .unwrap()
            .continuous()
            .unwrap();
        let mut worst = f64::MIN;
        for out in 1..=7 {
            let p = thesis_plant(out).unwrap().state_space();
            let m = continuous_loop_metrics(&p, &pid, &grid).unwrap();
            assert!(m.stable, "y{out}");
            if out == 5 {
                // Flexible modes shift the y5 crossover slightly above 37.3.
                assert!((m.crossover_hz.unwrap() - 37.3).abs() < 0.3, "{m:?}");
            }
            worst = worst.max(m.peak_si_db);
        }
        // The 6 dB rule is met at 35.5 (nominal rigid peak 5.4 dB).
        assert!(worst <= 6.0 && worst > 5.3, "{worst}");
        // Rigid-body plant alone: peak 5.4 dB.
        let rigid = thesis_plant(5)
            .unwrap()
            .select_modes(&[0])
            .unwrap()
            .state_space();
        let m = continuous_loop_metrics(&rigid, &pid, &grid).unwrap();
        assert!((m.peak_si_db - 5.4).abs() < 0.06, "{m:?}");
        // Crossover = 1.0498 f_bw = 37.27 Hz on the rigid plant.
        assert!(
            (m.crossover_hz.unwrap() - 1.0498 * 35.5).abs() < 0.02,
            "{m:?}"
        );
    }

    #[test]
    fn discrete_baseline_bandwidth_versus_loop_delay() {
        let plants: Vec<_> = (1..=7)
            .map(|i| zoh(&thesis_plant(i).unwrap().state_space(), TS_10KHZ).unwrap())
            .collect();
        // §10: 1 sample → 35.5 (crossover ≈ 37 Hz); 2 samples → 24.5.
        let one =
            DiscreteBandwidthProblem::new(plants.clone(), vec![None; 7], 1, CHAIN_MASS, 6.0, false)
                .unwrap();
        assert_eq!(one.max_bandwidth(34.0, 40.0, 0.5).unwrap(), Some(35.5));
        let cross = one.evaluate(35.5).unwrap()[4].crossover_hz.unwrap();
        assert!((cross - 37.3).abs() < 0.5, "{cross}");
        let two = DiscreteBandwidthProblem::new(plants, vec![None; 7], 2, CHAIN_MASS, 6.0, false)
            .unwrap();
        assert_eq!(two.max_bandwidth(23.0, 30.0, 0.5).unwrap(), Some(24.5));
        assert_eq!(
            two.max_bandwidth_refined(10.0, 30.0, 4.0, 0.5).unwrap(),
            Some(24.5)
        );
    }

    fn mc_ad_options() -> (ContinuousObserverOptions, ModalObserverOptions) {
        let damping = Some(DampingOptions {
            increase: vec![0.035; 3],
            method: crate::damping::DampingMethod::Automated,
            bandpass_q: Some(2.0),
        });
        (
            ContinuousObserverOptions {
                mc: true,
                damping,
                q_nu: Some(1e3),
                weights: None,
            },
            ModalObserverOptions::thesis_mc_ad(TS_10KHZ, 3),
        )
    }

    /// The SISO formulas of control.md §5.4 with the observer transfers
    /// (u referred to the controller output, delays included) equal the
    /// transfers of the assembled state-space loop: r → e_meas = S^I,
    /// n → y_meas = S^O, r → e_true = T_re.
    #[test]
    fn siso_formulas_match_the_assembled_loop() {
        let (copts, dopts) = mc_ad_options();
        let red = thesis_reduced(3).unwrap();
        let t = PidTuning::single_parameter(CHAIN_MASS, 60.0).unwrap();
        let check = |want: (C64, C64, C64), cl: &DMatrix<C64>| {
            // Loop inputs [r; n; u_ff; w], outputs [e_meas; y_meas; e_true; u_c].
            for (g, w) in [
                (cl[(0, 0)], want.0),
                (cl[(1, 1)], want.1),
                (cl[(2, 0)], want.2),
            ] {
                assert!((g - w).norm() < 1e-6 * w.norm().max(1e-3), "{g} vs {w}");
            }
        };
        // Continuous.
        let plant = thesis_plant(3).unwrap().state_space();
        let obs = design_continuous_modal_observer(&red, &copts).unwrap();
        let pid = t.continuous().unwrap();
        let cl = assemble_continuous_loop(&plant, Some(&obs.system), &pid).unwrap();
        for f in [3.0, 80.0, 470.0, 950.0] {
            let w = 2.0 * PI * f;
            let h = freq_response_continuous(&obs.system, w).unwrap();
            let o = ObserverResponse {
                yy: h[(0, 0)],
                yu: h[(0, 1)],
                uy: h[(1, 0)],
                uu: h[(1, 1)],
            };
            let p = freq_response_continuous(&plant, w).unwrap()[(0, 0)];
            let c = pid_response(&t, C64::new(0.0, w));
            let (si, so, re, _) = siso_sensitivities(p, c, Some(o));
            check((si, so, re), &freq_response_continuous(&cl, w).unwrap());
        }
        // Discrete, one and two samples of delay (the latter with the extra
        // prediction step, whose third block input must enter the formulas).
        let dplant = zoh(&plant, TS_10KHZ).unwrap();
        let pid = t.discrete(TS_10KHZ).unwrap();
        for (delay, extra) in [(1, 0), (2, 1), (2, 0)] {
            let mut o = dopts.clone();
            o.extra_delay_samples = extra;
            let block = design_modal_observer(&red, &o).unwrap().block;
            let pb = DiscreteBandwidthProblem::new(
                vec![dplant.clone()],
                vec![Some(block.clone())],
                delay,
                CHAIN_MASS,
                6.0,
                true,
            )
            .unwrap();
            let cl = assemble_loop(&LoopSpec {
                plant: &dplant,
                observer: Some(&block),
                controller: &pid,
                loop_delay: delay,
            })
            .unwrap();
            let cvals = pb.controller_values(&t);
            for (k, &w) in pb.core.grid.iter().enumerate().step_by(97) {
                let (p, ob) = pb.core.cache[0][k];
                let (si, so, re, _) = siso_sensitivities(p, cvals[k], ob);
                check((si, so, re), &freq_response_discrete(&cl, w).unwrap());
            }
        }
    }

    #[test]
    fn scan_finds_the_boundary_and_rejects_bad_ranges() {
        let f = |limit: f64| move |x: f64| -> Result<bool, DesignError> { Ok(x <= limit) };
        assert_eq!(
            scan_max_bandwidth(10.0, 100.0, 4.0, 0.5, f(37.3)).unwrap(),
            Some(37.0)
        );
        assert_eq!(
            scan_max_bandwidth(10.0, 100.0, 4.0, 0.5, f(500.0)).unwrap(),
            Some(100.0)
        );
        assert_eq!(
            scan_max_bandwidth(10.0, 100.0, 4.0, 0.5, f(5.0)).unwrap(),
            None
        );
        assert_eq!(
            scan_max_bandwidth(10.0, 12.0, 4.0, 0.5, f(11.2)).unwrap(),
            Some(11.0)
        );
        for (a, b, c, d) in [
            (0.0, 10.0, 1.0, 0.5),
            (10.0, 5.0, 1.0, 0.5),
            (10.0, 20.0, 1.0, 0.0),
            (f64::NAN, 20.0, 1.0, 0.5),
            (1.0, 1e9, 1.0, 1e-6),
        ] {
            assert!(scan_max_bandwidth(a, b, c, d, f(1.0)).is_err());
        }
        assert!(prewarped_notch(2.0 * PI * 6000.0, TS_10KHZ).is_err());
        let w = 2.0 * PI * 1396.06;
        let pw = prewarped_notch(w, TS_10KHZ).unwrap();
        assert!((tustin_point(w, TS_10KHZ).im - pw).abs() < 1e-9 * pw);
    }

    #[test]
    fn response_evaluator_matches_the_direct_response() {
        let (copts, dopts) = mc_ad_options();
        let red = thesis_reduced(6).unwrap();
        let obs = design_continuous_modal_observer(&red, &copts)
            .unwrap()
            .system;
        let plant = thesis_plant(6).unwrap().state_space();
        let block = design_modal_observer(&red, &dopts).unwrap().block.system;
        for f in [0.3, 37.0, 470.06, 941.0, 2556.45, 4000.0] {
            let w = 2.0 * PI * f;
            for sys in [&obs, &plant] {
                let e = ResponseEvaluator::new(&sys.a, &sys.b, &sys.c, &sys.d).unwrap();
                let got = e.eval(C64::new(0.0, w)).unwrap();
                let want = freq_response_continuous(sys, w).unwrap();
                let want: Vec<C64> = want.transpose().iter().copied().collect();
                // Near s = 0 the observer's O_uy is a cancellation of large
                // terms: any two evaluations differ in the ~6th digit there.
                let tol = if f < 1.0 { 1e-5 } else { 1e-8 };
                for (g, v) in got.iter().zip(&want) {
                    assert!(
                        (g - v).norm() <= tol * v.norm().max(1e-30),
                        "{f}: {g} vs {v}"
                    );
                }
            }
            let e = ResponseEvaluator::new(&block.a, &block.b, &block.c, &block.d).unwrap();
            let got = e.eval(C64::new(0.0, w * TS_10KHZ).exp()).unwrap();
            let want = freq_response_discrete(&block, w).unwrap();
            let want: Vec<C64> = want.transpose().iter().copied().collect();
            let tol = if f < 1.0 { 1e-5 } else { 1e-8 };
            for (g, v) in got.iter().zip(&want) {
                assert!(
                    (g - v).norm() <= tol * v.norm().max(1e-30),
                    "{f}: {g} vs {v}"
                );
            }
        }
        let empty = ResponseEvaluator::new(
            &DMatrix::zeros(0, 0),
            &DMatrix::zeros(0, 1),
            &DMatrix::zeros(1, 0),
            &DMatrix::from_element(1, 1, 2.0),
        )
        .unwrap();
        assert_eq!(
            empty.eval(C64::new(0.0, 1.0)).unwrap()[0],
            C64::new(2.0, 0.0)
        );
        // A pole on the imaginary axis is an error, not a NaN.
        let di = crate::models::double_integrator();
        let e = ResponseEvaluator::new(&di.a, &di.b, &di.c, &di.d).unwrap();
        assert!(e.eval(C64::new(0.0, 0.0)).is_err());
    }

    #[test]
    fn analytic_controller_response_matches_the_state_space() {
        let t = PidTuning::single_parameter(CHAIN_MASS, 41.0)
            .unwrap()
            .with_notches(&[2.0 * PI * 470.06, 2.0 * PI * 941.88]);
        let c = t.continuous().unwrap();
        let d = t.discrete(TS_10KHZ).unwrap();
        for f in [0.7, 37.0, 470.06, 2000.0, 4900.0] {
            let w = 2.0 * PI * f;
            let hc = freq_response_continuous(&c, w).unwrap()[(0, 0)];
            let ac = pid_response(&t, C64::new(0.0, w));
            assert!((hc - ac).norm() < 1e-9 * ac.norm(), "{f}: {hc} vs {ac}");
            let hd = freq_response_discrete(&d, w).unwrap()[(0, 0)];
            let ad = pid_response(&t, tustin_point(w, TS_10KHZ));
            assert!((hd - ad).norm() < 1e-7 * ad.norm(), "{f}: {hd} vs {ad}");
        }
    }
}
