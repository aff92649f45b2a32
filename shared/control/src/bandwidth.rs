//! The bandwidth searches of docs/control.md §9 / §10.1: the largest f_bw of the
//! Table 3.3 PID such that every output meets the 6 dB rule (and, for MC,
//! the bound on |T_{r→e_true}|) with a stable closed loop, in continuous time
//! (the thesis's setting: [`ContinuousBandwidthProblem`]) and in discrete time
//! with loop delay ([`DiscreteBandwidthProblem`]).
//!
//! Both problems compute the plant and observer responses once on a
//! frequency grid (log-spaced, refined around every lightly damped pole of
//! the plants and observers, whose peaks are only ~1 % wide); for each f_bw
//! only the controller response (closed form, [`pid_response`]) changes. The
//! closed-loop eigenvalues are checked as well: the 6 dB bound alone does not
//! guarantee stability with 0.5 %-damped modes. What differs between the two
//! (the closed loop, the grid's end, the notches) is in [`ClosedLoops`] and
//! the two constructors; the searches are written once.

use crate::closed_loop::{LoopSpec, assemble_continuous_loop, assemble_loop};
use crate::continuous::ContinuousStateSpace;
use crate::design_error::DesignError;
use crate::freq::{
    C64, LoopMetrics, ObserverResponse, ResponseEvaluator, db, first_crossing, log_grid_hz,
    pid_response, prewarped_notch, siso_sensitivities, tustin_point,
};
use crate::linalg::{self, LinalgError};
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::observer_block::ObserverBlock;
use crate::pid::PidTuning;
use nalgebra::DMatrix;
use std::f64::consts::PI;

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
    Ok(linalg::eigenvalues(a)?
        .iter()
        .filter(|s| s.im > 0.0)
        .map(|s| (s.norm(), -s.re / s.norm()))
        .collect())
}

fn discrete_poles(a: &DMatrix<f64>, ts: f64) -> Result<Vec<(f64, f64)>, DesignError> {
    Ok(linalg::eigenvalues(a)?
        .iter()
        .filter(|z| z.im > 0.0)
        .map(|z| linalg::discrete_pole_to_continuous(*z, ts))
        .collect())
}

fn check_problem_parameters(mass: f64, limit_db: f64) -> Result<(), DesignError> {
    if !(mass.is_finite() && mass > 0.0) {
        return Err(DesignError::InvalidParameter(format!(
            "mass {mass} must be positive"
        )));
    }
    if !limit_db.is_finite() {
        return Err(DesignError::Matrix(MatrixError::NonFinite(
            "peak limit [dB]",
        )));
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

impl ObserverEval {
    /// The observer (A, B, C, D) with inputs [y; u_a], plus u_pending when
    /// `extra_delay` is 1.
    fn new(system: Abcd<'_>, extra_delay: usize) -> Result<Self, LinalgError> {
        let (a, b, c, d) = system;
        Ok(Self {
            eval: ResponseEvaluator::new(a, b, c, d)?,
            inputs: b.ncols(),
            extra_delay,
        })
    }
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

/// A plant's (A, B, C, D).
type Abcd<'a> = (
    &'a DMatrix<f64>,
    &'a DMatrix<f64>,
    &'a DMatrix<f64>,
    &'a DMatrix<f64>,
);

impl Responses {
    /// `grid` refined around the lightly damped `poles` below `w_max`, and
    /// every plant and observer response on it.
    fn prepare<'a>(
        domain: Domain,
        mut grid: Vec<f64>,
        w_max: f64,
        poles: &[(f64, f64)],
        plants: impl Iterator<Item = Abcd<'a>>,
        observers: Vec<Option<ObserverEval>>,
    ) -> Result<Self, DesignError> {
        refine_grid(&mut grid, poles, w_max);
        let plants = plants
            .map(|(a, b, c, d)| ResponseEvaluator::new(a, b, c, d))
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(domain, grid, plants, observers)
    }

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

/// The loops a bandwidth search tunes one PID on, one per output.
pub trait ClosedLoops {
    /// Closed loop of output `i` with controller `t`: (stable, poles as
    /// (ω [rad/s], ζ), continuous equivalents).
    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError>;
}

/// Continuous plants, each with its optional continuous observer (inputs
/// [y; u], outputs [ŷ_flex; u_d], e.g.
/// [`crate::observer_block::ContinuousModalObserver`]).
pub struct ContinuousLoops {
    pub plants: Vec<ContinuousStateSpace>,
    pub observers: Vec<Option<ContinuousStateSpace>>,
}

/// Sampled plants, each with its optional observer block, and the loop delay.
pub struct DiscreteLoops {
    pub plants: Vec<DiscreteStateSpace>,
    pub observers: Vec<Option<ObserverBlock>>,
    pub loop_delay: usize,
}

impl ClosedLoops for ContinuousLoops {
    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError> {
        let cl = assemble_continuous_loop(
            &self.plants[i],
            self.observers[i].as_ref(),
            &t.continuous()?,
        )?;
        let ev = linalg::eigenvalues(&cl.a)?;
        let stable = ev.iter().all(|s| s.re < 0.0);
        let poles = ev
            .iter()
            .filter(|s| s.im > 0.0)
            .map(|s| (s.norm(), -s.re / s.norm()))
            .collect();
        Ok((stable, poles))
    }
}

impl ClosedLoops for DiscreteLoops {
    fn closed_loop(&self, i: usize, t: &PidTuning) -> Result<(bool, Vec<(f64, f64)>), DesignError> {
        let ts = self.plants[0].ts;
        let cl = assemble_loop(&LoopSpec {
            plant: &self.plants[i],
            observer: self.observers[i].as_ref(),
            controller: &t.discrete(ts)?,
            loop_delay: self.loop_delay,
        })?;
        let ev = linalg::eigenvalues(&cl.a)?;
        let stable = ev.iter().all(|z| z.norm() < 1.0);
        let poles = ev
            .iter()
            .filter(|z| z.im > 0.0)
            .map(|z| linalg::discrete_pole_to_continuous(*z, ts))
            .collect();
        Ok((stable, poles))
    }
}

/// A bandwidth problem: the Table 3.3 PID (tuned on `mass`, optionally with
/// notches) on every loop of `loops`, and the 6 dB rule.
pub struct BandwidthProblem<L> {
    pub loops: L,
    pub mass: f64,
    /// Peak limit [dB] (thesis: 6).
    pub limit_db: f64,
    /// Also bound |T_{r→e_true}| (the MC constraint).
    pub bound_re: bool,
    responses: Responses,
}

/// docs/control.md §9, the thesis's setting.
pub type ContinuousBandwidthProblem = BandwidthProblem<ContinuousLoops>;
/// docs/control.md §10.1: sampled, with loop delay.
pub type DiscreteBandwidthProblem = BandwidthProblem<DiscreteLoops>;

impl<L: ClosedLoops> BandwidthProblem<L> {
    /// Metrics of every output at one f_bw.
    pub fn evaluate(&self, f_bw: f64) -> Result<Vec<LoopMetrics>, DesignError> {
        let r = &self.responses;
        let t = r.tuning(self.mass, f_bw)?;
        let cvals = self.controller_values(&t);
        (0..r.cache.len())
            .map(|i| self.output_metrics(i, &t, &cvals))
            .collect()
    }

    /// Whether every output meets the constraints at f_bw. Stops at the
    /// first output that fails; the grid peaks alone (no eigenvalues)
    /// already rule out most infeasible values.
    pub fn feasible(&self, f_bw: f64) -> Result<bool, DesignError> {
        let r = &self.responses;
        let (limit, bound_re) = (self.limit_db, self.bound_re);
        let t = r.tuning(self.mass, f_bw)?;
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

    /// Largest f_bw on the grid f_start, f_start + step, … ≤ f_stop such that
    /// it and every smaller grid value are feasible; None if f_start fails.
    pub fn max_bandwidth(
        &self,
        f_start: f64,
        f_stop: f64,
        step: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, step, step, |f| self.feasible(f))
    }

    /// [`scan_max_bandwidth`] (coarse, then fine) on this problem.
    pub fn max_bandwidth_refined(
        &self,
        f_start: f64,
        f_stop: f64,
        coarse: f64,
        fine: f64,
    ) -> Result<Option<f64>, DesignError> {
        scan_max_bandwidth(f_start, f_stop, coarse, fine, |f| self.feasible(f))
    }

    fn output_metrics(
        &self,
        i: usize,
        t: &PidTuning,
        cvals: &[C64],
    ) -> Result<LoopMetrics, DesignError> {
        let (stable, poles) = self.loops.closed_loop(i, t)?;
        let mut m = self.responses.metrics(i, t, cvals, &poles)?;
        m.stable = stable;
        Ok(m)
    }

    fn controller_values(&self, t: &PidTuning) -> Vec<C64> {
        let r = &self.responses;
        r.grid.iter().map(|&w| r.controller_at(t, w)).collect()
    }
}

/// One observer entry (or None) per plant.
fn check_loop_count(plants: usize, observers: usize) -> Result<(), DesignError> {
    if plants == 0 || observers != plants {
        return Err(DesignError::InvalidParameter(
            "need one observer entry (or None) per plant".into(),
        ));
    }
    Ok(())
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
        check_loop_count(plants.len(), observers.len())?;
        for (p, o) in plants.iter().zip(&observers) {
            if p.inputs() != 1 || p.outputs() != 1 {
                return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                    what: "SISO plant (outputs x inputs)",
                    expected: (1, 1),
                    found: (p.outputs(), p.inputs()),
                }));
            }
            if let Some(o) = o
                && (o.inputs() != 2 || o.outputs() != 2)
            {
                return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                    what: "SISO observer [y; u] → [ŷ_flex; u_d] (outputs x inputs)",
                    expected: (2, 2),
                    found: (o.outputs(), o.inputs()),
                }));
            }
        }
        let mut poles = Vec::new();
        for a in plants
            .iter()
            .map(|p| &p.a)
            .chain(observers.iter().flatten().map(|o| &o.a))
        {
            poles.extend(continuous_poles(a)?);
        }
        let observer_evals = observers
            .iter()
            .map(|o| {
                o.as_ref()
                    .map(|o| ObserverEval::new((&o.a, &o.b, &o.c, &o.d), 0))
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        let responses = Responses::prepare(
            Domain::Continuous,
            log_grid_hz(0.5, 2e4, 900),
            2.0 * PI * 2e4,
            &poles,
            plants.iter().map(|p| (&p.a, &p.b, &p.c, &p.d)),
            observer_evals,
        )?;
        Ok(Self {
            loops: ContinuousLoops { plants, observers },
            mass,
            limit_db,
            bound_re,
            responses,
        })
    }

    /// Adds notches N(s, ω) at `notches` [rad/s] to the controller.
    pub fn with_notches(mut self, notches: &[f64]) -> Self {
        self.responses.notches = notches.to_vec();
        self
    }
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
        check_loop_count(plants.len(), observers.len())?;
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
        let mut poles = Vec::new();
        for a in plants
            .iter()
            .map(|p| &p.a)
            .chain(observers.iter().flatten().map(|b| &b.system.a))
        {
            poles.extend(discrete_poles(a, ts)?);
        }
        let observer_evals = observers
            .iter()
            .map(|o| {
                o.as_ref()
                    .map(|b| {
                        let s = &b.system;
                        ObserverEval::new((&s.a, &s.b, &s.c, &s.d), b.extra_delay_samples)
                    })
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        let responses = Responses::prepare(
            Domain::Discrete { ts, loop_delay },
            log_grid_hz(0.5, 0.999 * f_nyq, 800),
            2.0 * PI * f_nyq,
            &poles,
            plants.iter().map(|p| (&p.a, &p.b, &p.c, &p.d)),
            observer_evals,
        )?;
        Ok(Self {
            loops: DiscreteLoops {
                plants,
                observers,
                loop_delay,
            },
            mass,
            limit_db,
            bound_re,
            responses,
        })
    }

    /// Adds notches at `notches` [rad/s]: the continuous notch frequencies
    /// are pre-warped ([`prewarped_notch`]) so that the Tustin controller
    /// has its notches exactly there.
    pub fn with_notches(mut self, notches: &[f64]) -> Result<Self, DesignError> {
        let ts = self.loops.plants[0].ts;
        self.responses.notches = notches
            .iter()
            .map(|&w| prewarped_notch(w, ts))
            .collect::<Result<_, _>>()?;
        Ok(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::freq::{freq_response_continuous, freq_response_discrete};
    use crate::models::{CHAIN_MASS, TS_10KHZ, thesis_plant, thesis_reduced};
    use crate::observer_block::{
        ContinuousObserverOptions, DampingOptions, ModalObserverOptions,
        design_continuous_modal_observer, design_modal_observer,
    };

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

    /// The command applied on arrival (docs/deadline.md): the plant integrated in
    /// two pieces around τ, no whole sample of delay. The original PID's
    /// largest f_bw against τ, as the independent model in docs/deadline.md has it.
    #[test]
    fn discrete_baseline_bandwidth_with_the_command_applied_on_arrival() {
        for (tau, want) in [(TS_10KHZ, 35.5), (30e-6, 35.0), (0.0, 35.5)] {
            let plants: Vec<_> = (1..=7)
                .map(|i| {
                    let sys = thesis_plant(i).unwrap().state_space();
                    crate::discretise::zoh_split(&sys, TS_10KHZ, tau)
                        .unwrap()
                        .plant(&sys.c, &sys.d, TS_10KHZ)
                        .unwrap()
                })
                .collect();
            let pb =
                DiscreteBandwidthProblem::new(plants, vec![None; 7], 0, CHAIN_MASS, 6.0, false)
                    .unwrap();
            assert_eq!(
                pb.max_bandwidth_refined(0.5, 250.0, 4.0, 0.5).unwrap(),
                Some(want),
                "τ = {tau}"
            );
        }
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

    /// The SISO formulas of docs/control.md §5.4 with the observer transfers
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
            for (k, &w) in pb.responses.grid.iter().enumerate().step_by(97) {
                let (p, ob) = pb.responses.cache[0][k];
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

    /// The evaluator's row-major `got` against the direct response `want`
    /// at `f` Hz. Near s = 0 the observer's O_uy is a cancellation of large
    /// terms: any two evaluations differ in the ~6th digit there.
    fn same_response(got: &[C64], want: &DMatrix<C64>, f: f64) {
        let want: Vec<C64> = want.transpose().iter().copied().collect();
        let tol = if f < 1.0 { 1e-5 } else { 1e-8 };
        for (g, v) in got.iter().zip(&want) {
            assert!(
                (g - v).norm() <= tol * v.norm().max(1e-30),
                "{f}: {g} vs {v}"
            );
        }
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
                same_response(&got, &freq_response_continuous(sys, w).unwrap(), f);
            }
            let e = ResponseEvaluator::new(&block.a, &block.b, &block.c, &block.d).unwrap();
            let got = e.eval(C64::new(0.0, w * TS_10KHZ).exp()).unwrap();
            same_response(&got, &freq_response_discrete(&block, w).unwrap(), f);
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
}
