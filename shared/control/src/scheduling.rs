//! Gain scheduling over a position (docs/control.md §1.4, §3 "TVKF vs scheduled
//! steady-state KF", §10, §11.2 item 12).
//!
//! When the structure moves relative to a sensor fixed in the world, C and
//! T_DC depend on the position r_p (output position dependency); the thesis
//! schedules on the reference position. Two per-sample estimators are
//! offered, both in predictor form x̂(k+1|k) = A x̂ + B u + L (y − C x̂ − D u):
//!
//! * [`InterpolatedKalman`]: steady-state gains L(r_p) precomputed on a
//!   uniform grid (the thesis uses 5 mm) and interpolated linearly at run
//!   time, together with B, C, D. Cheap, but interpolated gains are not
//!   guaranteed to give a stable time-varying filter, so the design checks the
//!   frozen filter halfway between grid points.
//! * [`TimeVaryingKalman`]: the Riccati recursion (4.7)–(4.8) every sample on
//!   the interpolated model. Stable for arbitrarily fast scheduling; costs a
//!   few n×n products per sample.
//!
//! A is the same at every position (structural dependency is not handled,
//! docs/control.md §2), and so is the process noise G Q Gᵀ. Everything is sized in
//! the constructors; `step` and `interpolate` do not allocate.

use crate::design_error::{DesignError, check_matrix};
use crate::in_place::{cholesky_solve_in_place, mul_into, propagate_covariance};
use crate::kalman::{KalmanWeights, steady_state_kalman};
use crate::linalg::spectral_radius;
use crate::lti::DiscreteStateSpace;
use crate::step_error::{StepError, check_slice};
use nalgebra::{DMatrix, DVector, DVectorView};
use std::fmt;

/// Why a schedule was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum ScheduleError {
    /// The grid is not a finite, increasing set of at least two points.
    InvalidGrid(String),
    /// Building the model or designing the filter failed at one grid point
    /// (or halfway between two, for the stability check of interpolation).
    AtPosition { position: f64, error: DesignError },
    /// A matrix that must be the same at every position differs (A, the
    /// dimensions, or the sample period).
    StructureChanges { position: f64, what: &'static str },
    /// Weights or the initial covariance are invalid.
    Design(DesignError),
}

impl fmt::Display for ScheduleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidGrid(s) => write!(f, "invalid scheduling grid: {s}"),
            Self::AtPosition { position, error } => {
                write!(f, "at scheduling position {position}: {error}")
            }
            Self::StructureChanges { position, what } => write!(
                f,
                "{what} at scheduling position {position} differs from the first grid point; \
                 only B, C and D may depend on the position"
            ),
            Self::Design(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for ScheduleError {}

impl From<DesignError> for ScheduleError {
    fn from(e: DesignError) -> Self {
        Self::Design(e)
    }
}

/// A uniform grid start, start + step, …, start + (points − 1)·step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionGrid {
    start: f64,
    step: f64,
    points: usize,
}

impl PositionGrid {
    pub fn new(start: f64, step: f64, points: usize) -> Result<Self, ScheduleError> {
        if !(start.is_finite() && step.is_finite() && step > 0.0) {
            return Err(ScheduleError::InvalidGrid(format!(
                "start {start} and step {step} must be finite with step > 0"
            )));
        }
        if points < 2 {
            return Err(ScheduleError::InvalidGrid(format!(
                "{points} points; interpolation needs at least 2"
            )));
        }
        let end = start + step * (points - 1) as f64;
        if !end.is_finite() {
            return Err(ScheduleError::InvalidGrid(format!(
                "end {end} is not finite"
            )));
        }
        Ok(Self {
            start,
            step,
            points,
        })
    }

    /// The grid from `start` to `end` in steps of `step`; (end − start)/step
    /// must be a whole number (e.g. 0 … 0.14 m in 5 mm steps: 29 points).
    pub fn covering(start: f64, end: f64, step: f64) -> Result<Self, ScheduleError> {
        let spans = (end - start) / step;
        let whole = spans.round();
        if !spans.is_finite() || whole < 1.0 || (spans - whole).abs() > 1e-9 * whole.max(1.0) {
            return Err(ScheduleError::InvalidGrid(format!(
                "[{start}, {end}] is not a whole number of steps of {step}"
            )));
        }
        Self::new(start, step, whole as usize + 1)
    }

    pub fn start(&self) -> f64 {
        self.start
    }
    pub fn step(&self) -> f64 {
        self.step
    }
    pub fn points(&self) -> usize {
        self.points
    }
    pub fn end(&self) -> f64 {
        self.position(self.points - 1)
    }

    /// Position of grid point i.
    pub fn position(&self, i: usize) -> f64 {
        self.start + self.step * i as f64
    }

    /// (i, f) with position = (1 − f)·p_i + f·p_{i+1}, 0 ≤ f ≤ 1. Positions
    /// within 1e-9 steps outside the grid are clamped onto it (rounding);
    /// further out is an error, not an extrapolation.
    pub fn locate(&self, position: f64) -> Result<(usize, f64), StepError> {
        if !position.is_finite() {
            return Err(StepError::NonFinite("scheduling position"));
        }
        let last = (self.points - 1) as f64;
        let t = (position - self.start) / self.step;
        if !(-1e-9..=last + 1e-9).contains(&t) {
            return Err(StepError::PositionOutOfRange {
                position,
                min: self.start,
                max: self.end(),
            });
        }
        let t = t.clamp(0.0, last);
        let i = (t.floor() as usize).min(self.points - 2);
        Ok((i, t - i as f64))
    }
}

/// (1 − f)·m[i] + f·m[i+1] into `out`, without allocating.
fn lerp_into(out: &mut DMatrix<f64>, grid: &[DMatrix<f64>], i: usize, f: f64) {
    out.copy_from(&grid[i]);
    if f != 0.0 {
        out.zip_apply(&grid[i + 1], |o, n| *o = (1.0 - f) * *o + f * n);
    }
}

/// Matrices of a scheduled model at one position (preallocated storage for
/// the per-sample interpolation). `l` is only filled by [`KalmanSchedule`].
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduledMatrices {
    pub b: DMatrix<f64>,
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
    /// Predictor gain L (n × n_y).
    pub l: DMatrix<f64>,
}

/// Discrete models x(k+1) = A x + B(r) u + G w, y = C(r) x + D(r) u + v on a
/// position grid, with fixed noise weights.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSchedule {
    grid: PositionGrid,
    a: DMatrix<f64>,
    b: Vec<DMatrix<f64>>,
    c: Vec<DMatrix<f64>>,
    d: Vec<DMatrix<f64>>,
    weights: KalmanWeights,
    ts: f64,
}

impl ModelSchedule {
    /// Evaluates `model_at` at every grid point (design time). A, the
    /// dimensions and the sample period must not change along the grid.
    pub fn new(
        grid: PositionGrid,
        weights: KalmanWeights,
        mut model_at: impl FnMut(f64) -> Result<DiscreteStateSpace, DesignError>,
    ) -> Result<Self, ScheduleError> {
        let p0 = grid.position(0);
        let first = model_at(p0).map_err(|error| ScheduleError::AtPosition {
            position: p0,
            error,
        })?;
        let (n, m, p) = (first.states(), first.inputs(), first.outputs());
        let nw = weights.g.ncols();
        check_matrix(&weights.g, "G", n, nw)?;
        check_matrix(&weights.q, "Q", nw, nw)?;
        check_matrix(&weights.r, "R", p, p)?;
        let mut b = Vec::with_capacity(grid.points());
        let mut c = Vec::with_capacity(grid.points());
        let mut d = Vec::with_capacity(grid.points());
        let a_tol = 1e-10 * first.a.amax().max(1.0);
        for i in 0..grid.points() {
            let pos = grid.position(i);
            let model = if i == 0 {
                first.clone()
            } else {
                model_at(pos).map_err(|error| ScheduleError::AtPosition {
                    position: pos,
                    error,
                })?
            };
            let changed = |what| ScheduleError::StructureChanges {
                position: pos,
                what,
            };
            if (model.states(), model.inputs(), model.outputs()) != (n, m, p) {
                return Err(changed("the model dimensions"));
            }
            if (model.ts - first.ts).abs() > 1e-12 * first.ts {
                return Err(changed("the sample period"));
            }
            if (&model.a - &first.a).amax() > a_tol {
                return Err(changed("A"));
            }
            b.push(model.b);
            c.push(model.c);
            d.push(model.d);
        }
        Ok(Self {
            grid,
            a: first.a,
            b,
            c,
            d,
            weights,
            ts: first.ts,
        })
    }

    pub fn grid(&self) -> &PositionGrid {
        &self.grid
    }
    pub fn weights(&self) -> &KalmanWeights {
        &self.weights
    }
    pub fn a(&self) -> &DMatrix<f64> {
        &self.a
    }
    pub fn ts(&self) -> f64 {
        self.ts
    }
    pub fn states(&self) -> usize {
        self.a.nrows()
    }
    pub fn inputs(&self) -> usize {
        self.b[0].ncols()
    }
    pub fn outputs(&self) -> usize {
        self.c[0].nrows()
    }

    /// Storage sized for [`Self::interpolate`].
    pub fn matrices(&self) -> ScheduledMatrices {
        ScheduledMatrices {
            b: self.b[0].clone(),
            c: self.c[0].clone(),
            d: self.d[0].clone(),
            l: DMatrix::zeros(self.states(), self.outputs()),
        }
    }

    /// B, C, D at `position` by linear interpolation (allocation-free).
    pub fn interpolate(&self, position: f64, out: &mut ScheduledMatrices) -> Result<(), StepError> {
        let (i, f) = self.grid.locate(position)?;
        self.interpolate_at(i, f, out);
        Ok(())
    }

    fn interpolate_at(&self, i: usize, f: f64, out: &mut ScheduledMatrices) {
        lerp_into(&mut out.b, &self.b, i, f);
        lerp_into(&mut out.c, &self.c, i, f);
        lerp_into(&mut out.d, &self.d, i, f);
    }

    /// The model at an arbitrary position (design time, allocates).
    pub fn model_at(&self, position: f64) -> Result<DiscreteStateSpace, DesignError> {
        let mut m = self.matrices();
        self.interpolate(position, &mut m)
            .map_err(|e| DesignError::InvalidParameter(e.to_string()))?;
        Ok(DiscreteStateSpace::new(
            self.a.clone(),
            m.b,
            m.c,
            m.d,
            self.ts,
        )?)
    }
}

/// Steady-state Kalman predictor gains on the grid of a [`ModelSchedule`].
#[derive(Debug, Clone, PartialEq)]
pub struct KalmanSchedule {
    models: ModelSchedule,
    gains: Vec<DMatrix<f64>>,
    /// Largest spectral radius of the frozen A − L C, over the grid points
    /// and the midpoints between them (interpolated gains).
    pub worst_radius: f64,
}

impl KalmanSchedule {
    /// One DARE per grid point, then a check that the interpolated filter,
    /// frozen halfway between neighbouring points, is still stable.
    pub fn design(models: ModelSchedule) -> Result<Self, ScheduleError> {
        let grid = *models.grid();
        let mut gains = Vec::with_capacity(grid.points());
        let mut worst: f64 = 0.0;
        for i in 0..grid.points() {
            let pos = grid.position(i);
            let at = |error| ScheduleError::AtPosition {
                position: pos,
                error,
            };
            let model = models.model_at(pos).map_err(at)?;
            let k = steady_state_kalman(&model, models.weights()).map_err(at)?;
            worst = worst.max(k.radius);
            gains.push(k.l);
        }
        let mut s = Self {
            models,
            gains,
            worst_radius: worst,
        };
        let mut m = s.matrices();
        for i in 0..grid.points() - 1 {
            s.interpolate_at(i, 0.5, &mut m);
            let pos = grid.position(i) + 0.5 * grid.step();
            let r = spectral_radius(&(s.models.a() - &m.l * &m.c)).map_err(|e| {
                ScheduleError::AtPosition {
                    position: pos,
                    error: e.into(),
                }
            })?;
            if r >= 1.0 {
                return Err(ScheduleError::AtPosition {
                    position: pos,
                    error: DesignError::Unstable(format!(
                        "interpolated Kalman gain gives spectral radius {r}; refine the grid"
                    )),
                });
            }
            worst = worst.max(r);
        }
        s.worst_radius = worst;
        Ok(s)
    }

    pub fn models(&self) -> &ModelSchedule {
        &self.models
    }

    /// The steady-state predictor gain at grid point i.
    pub fn gain_at_point(&self, i: usize) -> Option<&DMatrix<f64>> {
        self.gains.get(i)
    }

    /// Storage sized for [`Self::interpolate`].
    pub fn matrices(&self) -> ScheduledMatrices {
        self.models.matrices()
    }

    /// B, C, D and L at `position` (allocation-free).
    pub fn interpolate(&self, position: f64, out: &mut ScheduledMatrices) -> Result<(), StepError> {
        let (i, f) = self.models.grid().locate(position)?;
        self.interpolate_at(i, f, out);
        Ok(())
    }

    fn interpolate_at(&self, i: usize, f: f64, out: &mut ScheduledMatrices) {
        self.models.interpolate_at(i, f, out);
        lerp_into(&mut out.l, &self.gains, i, f);
    }
}

/// Steady-state Kalman predictor with gains interpolated from a
/// [`KalmanSchedule`] (the thesis lookup table, §5.6).
#[derive(Debug, Clone)]
pub struct InterpolatedKalman {
    schedule: KalmanSchedule,
    m: ScheduledMatrices,
    x: DVector<f64>,
    x_next: DVector<f64>,
    innovation: DVector<f64>,
}

impl InterpolatedKalman {
    pub fn new(schedule: KalmanSchedule) -> Self {
        let (n, p) = (schedule.models.states(), schedule.models.outputs());
        Self {
            m: schedule.matrices(),
            x: DVector::zeros(n),
            x_next: DVector::zeros(n),
            innovation: DVector::zeros(p),
            schedule,
        }
    }

    pub fn schedule(&self) -> &KalmanSchedule {
        &self.schedule
    }

    /// x̂(k|k−1).
    pub fn estimate(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// The matrices used by the last successful step.
    pub fn matrices(&self) -> &ScheduledMatrices {
        &self.m
    }

    pub fn set_estimate(&mut self, x: &[f64]) -> Result<(), StepError> {
        check_slice(x, "estimate", self.x.len())?;
        self.x.as_mut_slice().copy_from_slice(x);
        Ok(())
    }

    /// From y(k), u(k) at position r_p(k): x̂(k+1|k) = A x̂ + B u + L ε,
    /// ε = y − C x̂ − D u, with B, C, D, L interpolated at r_p(k).
    pub fn step(&mut self, position: f64, y: &[f64], u: &[f64]) -> Result<&[f64], StepError> {
        let models = &self.schedule.models;
        check_slice(y, "y", models.outputs())?;
        check_slice(u, "u", models.inputs())?;
        self.schedule.interpolate(position, &mut self.m)?;
        let y = DVectorView::from_slice(y, y.len());
        let u = DVectorView::from_slice(u, u.len());
        self.innovation.copy_from(&y);
        self.innovation.gemv(-1.0, &self.m.c, &self.x, 1.0);
        self.innovation.gemv(-1.0, &self.m.d, &u, 1.0);
        self.x_next.gemv(1.0, models.a(), &self.x, 0.0);
        self.x_next.gemv(1.0, &self.m.b, &u, 1.0);
        self.x_next.gemv(1.0, &self.m.l, &self.innovation, 1.0);
        std::mem::swap(&mut self.x, &mut self.x_next);
        Ok(self.x.as_slice())
    }
}

/// Time-varying Kalman predictor: the Riccati recursion (4.7)–(4.8) every
/// sample on the model interpolated at the current position.
#[derive(Debug, Clone)]
pub struct TimeVaryingKalman {
    models: ModelSchedule,
    m: ScheduledMatrices,
    a_t: DMatrix<f64>,
    /// G Q Gᵀ.
    w: DMatrix<f64>,
    r: DMatrix<f64>,
    /// P(k|k−1).
    p: DMatrix<f64>,
    x: DVector<f64>,
    x_next: DVector<f64>,
    innovation: DVector<f64>,
    cp: DMatrix<f64>,
    pct: DMatrix<f64>,
    s: DMatrix<f64>,
    mt: DMatrix<f64>,
    gain_m: DMatrix<f64>,
    p_post: DMatrix<f64>,
    tmp: DMatrix<f64>,
}

impl TimeVaryingKalman {
    /// Starts from the prior covariance `p0` = P(0|−1) (symmetric, n × n).
    pub fn new(models: ModelSchedule, p0: DMatrix<f64>) -> Result<Self, ScheduleError> {
        let (n, p) = (models.states(), models.outputs());
        check_matrix(&p0, "initial covariance P0", n, n)?;
        let scale = p0.amax().max(f64::MIN_POSITIVE);
        if (&p0 - p0.transpose()).amax() > 1e-10 * scale || p0.diagonal().iter().any(|v| *v < 0.0) {
            return Err(DesignError::InvalidParameter(
                "initial covariance P0 must be symmetric positive semi-definite".into(),
            )
            .into());
        }
        let wts = models.weights();
        let q = &wts.q;
        if (q - q.transpose()).amax() > 1e-10 * q.amax().max(f64::MIN_POSITIVE)
            || q.diagonal().iter().any(|v| *v < 0.0)
        {
            return Err(DesignError::InvalidParameter(
                "process noise Q must be symmetric positive semi-definite".into(),
            )
            .into());
        }
        if wts.r.clone().cholesky().is_none() {
            return Err(DesignError::InvalidParameter(
                "measurement noise R must be symmetric positive definite".into(),
            )
            .into());
        }
        let w = &wts.g * q * wts.g.transpose();
        Ok(Self {
            m: models.matrices(),
            a_t: models.a().transpose(),
            w: (&w + w.transpose()) * 0.5,
            r: wts.r.clone(),
            p: p0,
            x: DVector::zeros(n),
            x_next: DVector::zeros(n),
            innovation: DVector::zeros(p),
            cp: DMatrix::zeros(p, n),
            pct: DMatrix::zeros(n, p),
            s: DMatrix::zeros(p, p),
            mt: DMatrix::zeros(p, n),
            gain_m: DMatrix::zeros(n, p),
            p_post: DMatrix::zeros(n, n),
            tmp: DMatrix::zeros(n, n),
            models,
        })
    }

    /// Starts from the steady-state (DARE) covariance of the model frozen at
    /// `position`, so that the filter starts converged.
    pub fn from_steady_state(models: ModelSchedule, position: f64) -> Result<Self, ScheduleError> {
        let at = |error| ScheduleError::AtPosition { position, error };
        let model = models.model_at(position).map_err(at)?;
        let k = steady_state_kalman(&model, models.weights()).map_err(at)?;
        Self::new(models, k.p)
    }

    /// x̂(k|k−1).
    pub fn estimate(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// P(k|k−1).
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.p
    }

    /// The matrices used by the last successful step; `l` is the predictor
    /// gain L(k) = A P Cᵀ (C P Cᵀ + R)⁻¹ it applied.
    pub fn matrices(&self) -> &ScheduledMatrices {
        &self.m
    }

    pub fn set_estimate(&mut self, x: &[f64]) -> Result<(), StepError> {
        check_slice(x, "estimate", self.x.len())?;
        self.x.as_mut_slice().copy_from_slice(x);
        Ok(())
    }

    /// One sample: gain from P(k|k−1) at r_p(k), x̂(k+1|k), then P(k+1|k).
    pub fn step(&mut self, position: f64, y: &[f64], u: &[f64]) -> Result<&[f64], StepError> {
        check_slice(y, "y", self.models.outputs())?;
        check_slice(u, "u", self.models.inputs())?;
        self.models.interpolate(position, &mut self.m)?;
        let a = self.models.a();
        // S = C P Cᵀ + R, Mᵀ = S⁻¹ C P (P symmetric), L = A M.
        mul_into(&mut self.cp, 1.0, &self.m.c, &self.p, 0.0);
        self.cp.transpose_to(&mut self.pct);
        self.s.copy_from(&self.r);
        mul_into(&mut self.s, 1.0, &self.m.c, &self.pct, 1.0);
        self.mt.copy_from(&self.cp);
        cholesky_solve_in_place(&mut self.s, &mut self.mt)?;
        self.mt.transpose_to(&mut self.gain_m);
        mul_into(&mut self.m.l, 1.0, a, &self.gain_m, 0.0);
        let y = DVectorView::from_slice(y, y.len());
        let u = DVectorView::from_slice(u, u.len());
        self.innovation.copy_from(&y);
        self.innovation.gemv(-1.0, &self.m.c, &self.x, 1.0);
        self.innovation.gemv(-1.0, &self.m.d, &u, 1.0);
        self.x_next.gemv(1.0, a, &self.x, 0.0);
        self.x_next.gemv(1.0, &self.m.b, &u, 1.0);
        self.x_next.gemv(1.0, &self.m.l, &self.innovation, 1.0);
        std::mem::swap(&mut self.x, &mut self.x_next);
        // P(k+1|k) = A (P − M C P) Aᵀ + G Q Gᵀ, kept symmetric.
        propagate_covariance(
            &mut self.p,
            a,
            &self.a_t,
            &self.gain_m,
            &self.cp,
            &self.w,
            &mut self.p_post,
            &mut self.tmp,
        );
        Ok(self.x.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::kalman::riccati_step;
    use crate::models::{TS_10KHZ, thesis_chain_modal};

    /// Thesis chain seen by a sensor fixed in the world (docs/control.md §1.4):
    /// nodes ma, m1..m7 at a 20 mm pitch, so 0…0.14 m in 5 mm steps is 29
    /// positions. Reduced model (rigid + 3 flexible, T_DC of modes 4–6).
    fn node(pos: f64) -> f64 {
        // Clamped: 0.14 / 0.02 rounds to 7.000000000000001.
        (pos / 0.02).clamp(0.0, 7.0)
    }

    fn chain_schedule() -> ModelSchedule {
        let modal = thesis_chain_modal().unwrap();
        let grid = PositionGrid::covering(0.0, 0.14, 0.005).unwrap();
        let base = modal
            .select_outputs(&[0])
            .unwrap()
            .truncate(4, &[])
            .unwrap();
        let disc = zoh(&base.state_space(), TS_10KHZ).unwrap();
        let weights = KalmanWeights::thesis(&disc);
        ModelSchedule::new(grid, weights, |pos| {
            let red = modal
                .with_sensor_positions(&[node(pos)])?
                .truncate(4, &[4, 5, 6])?;
            let ss = red.state_space();
            Ok(DiscreteStateSpace::new(
                disc.a.clone(),
                disc.b.clone(),
                ss.c,
                ss.d,
                TS_10KHZ,
            )?)
        })
        .unwrap()
    }

    #[test]
    fn grid_locates_and_refuses() {
        let g = PositionGrid::covering(0.0, 0.14, 0.005).unwrap();
        assert_eq!(g.points(), 29);
        let (i, f) = g.locate(0.0125).unwrap();
        assert_eq!(i, 2);
        assert!((f - 0.5).abs() < 1e-12);
        assert_eq!(g.locate(0.14).unwrap(), (27, 1.0));
        assert!(matches!(
            g.locate(0.15),
            Err(StepError::PositionOutOfRange { .. })
        ));
        assert_eq!(
            g.locate(f64::NAN),
            Err(StepError::NonFinite("scheduling position"))
        );
        assert!(PositionGrid::covering(0.0, 0.14, 0.003).is_err());
        assert!(PositionGrid::new(0.0, -1.0, 3).is_err());
    }

    #[test]
    fn interpolation_between_nodes_is_exact() {
        // sensor_row_at and T_DC are linear in the position between nodes, so
        // a grid aligned with the nodes reproduces C and D exactly.
        let s = chain_schedule();
        let modal = thesis_chain_modal().unwrap();
        let mut m = s.matrices();
        s.interpolate(0.0337, &mut m).unwrap();
        let red = modal
            .with_sensor_positions(&[node(0.0337)])
            .unwrap()
            .truncate(4, &[4, 5, 6])
            .unwrap();
        let ss = red.state_space();
        assert!((&m.c - &ss.c).amax() < 1e-14);
        assert!((&m.d - &ss.d).amax() < 1e-24);
    }

    #[test]
    fn time_varying_filter_converges_to_the_steady_state_gain() {
        let s = chain_schedule();
        let pos = 0.1;
        let model = s.model_at(pos).unwrap();
        let ss = steady_state_kalman(&model, s.weights()).unwrap();
        // Start far from the DARE solution and let the recursion converge.
        let p0 = &ss.p * 100.0;
        let mut tv = TimeVaryingKalman::new(s.clone(), p0.clone()).unwrap();
        // Same first step as kalman::riccati_step.
        let (p1, l0) = riccati_step(&model, s.weights(), &p0).unwrap();
        tv.step(pos, &[0.0], &[0.0]).unwrap();
        assert!((&tv.matrices().l - &l0).amax() <= 1e-12 * l0.amax());
        assert!((tv.covariance() - &p1).amax() <= 1e-9 * p1.amax());
        for _ in 0..2000 {
            tv.step(pos, &[0.0], &[0.0]).unwrap();
        }
        let err = (&tv.matrices().l - &ss.l).amax() / ss.l.amax();
        assert!(err < 1e-6, "relative gain error {err}");
    }

    /// Deterministic N(0, 1) samples (xorshift64* + Box–Muller), so that the
    /// test needs no random-number crate and is reproducible.
    pub(crate) struct Gauss(u64);
    impl Gauss {
        pub(crate) fn new(seed: u64) -> Self {
            Self(seed.max(1))
        }
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
            ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        pub(crate) fn sample(&mut self) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        }
    }

    #[test]
    fn tvkf_and_interpolated_filter_are_indistinguishable_on_a_moving_sensor() {
        use crate::models::{SIGMA_D, SIGMA_V, SIGMA_W};
        use std::f64::consts::PI;
        // True plant: all 8 modes, sensor at the exact (not interpolated)
        // position. The structure sweeps 0 → 0.14 m → 0 in 0.2 s
        // (r_p = 0.07 (1 − cos 2π·5 t): up to 2.2 m/s and 69 m/s²).
        let modal = thesis_chain_modal().unwrap();
        let plant = zoh(&modal.select_outputs(&[0]).unwrap().state_space(), TS_10KHZ).unwrap();
        let schedule = chain_schedule();
        let mut ss = InterpolatedKalman::new(KalmanSchedule::design(schedule.clone()).unwrap());
        // Positive control: the same filter NOT scheduled (model and gain
        // frozen at mid-stroke), to show that the metric can tell filters apart.
        let frozen_model = schedule.model_at(0.07).unwrap();
        let frozen = ModelSchedule::new(*schedule.grid(), schedule.weights().clone(), |_| {
            Ok(frozen_model.clone())
        })
        .unwrap();
        let mut fixed = InterpolatedKalman::new(KalmanSchedule::design(frozen).unwrap());
        let mut tv = TimeVaryingKalman::from_steady_state(schedule, 0.0).unwrap();
        let mut g = Gauss::new(7);
        let mut x = DVector::<f64>::zeros(16);
        let n = 8;
        let mut acc = [[0.0; 8]; 4]; // TVKF error, interpolated error, difference, unscheduled error
        let sigma_y = (SIGMA_V * SIGMA_V + SIGMA_D * SIGMA_D).sqrt();
        let steps = 2000;
        let skip = 100;
        for k in 0..steps {
            let t = k as f64 * TS_10KHZ;
            let pos = 0.07 * (1.0 - (2.0 * PI * 5.0 * t).cos());
            let row = modal.sensor_row_at(node(pos)).unwrap();
            let y = (0..8).map(|i| row[(0, i)] * x[2 * i]).sum::<f64>() + sigma_y * g.sample();
            let u = 10.0 * (2.0 * PI * 30.0 * t).sin();
            if k >= skip {
                for j in 0..n {
                    let (a, b, c) = (tv.estimate()[j], ss.estimate()[j], fixed.estimate()[j]);
                    acc[0][j] += (x[j] - a).powi(2);
                    acc[1][j] += (x[j] - b).powi(2);
                    acc[2][j] += (a - b).powi(2);
                    acc[3][j] += (x[j] - c).powi(2);
                }
            }
            tv.step(pos, &[y], &[u]).unwrap();
            ss.step(pos, &[y], &[u]).unwrap();
            fixed.step(pos, &[y], &[u]).unwrap();
            let f = u + SIGMA_W * g.sample();
            x = &plant.a * &x + &plant.b * f;
        }
        let rms = acc.map(|v| v.map(|s| (s / (steps - skip) as f64).sqrt()));
        let [e_tv, e_ss, diff, e_fixed] = rms;
        for j in 0..n {
            eprintln!(
                "state {j}: rms error TVKF {:.4e}, interpolated {:.4e}, difference {:.4e} \
                 ({:.4} of the error), unscheduled {:.4e}",
                e_tv[j],
                e_ss[j],
                diff[j],
                diff[j] / e_tv[j],
                e_fixed[j]
            );
            // Indistinguishable: the estimates differ by far less than either
            // misses the truth, and the error levels agree within 3 %.
            assert!(diff[j] < 0.15 * e_tv[j], "state {j}");
            assert!((e_tv[j] - e_ss[j]).abs() < 0.03 * e_tv[j], "state {j}");
        }
        // Not scheduling at all costs far more than the choice between the two
        // ways of scheduling (measured: 37 to 2.5e5 times more, per state).
        for j in 0..n {
            let cost_of_freezing = e_fixed[j] - e_tv[j];
            let cost_of_interpolating = (e_ss[j] - e_tv[j]).abs();
            assert!(cost_of_freezing > 10.0 * cost_of_interpolating, "state {j}");
        }
    }

    #[test]
    fn kalman_schedule_is_stable_between_grid_points() {
        let k = KalmanSchedule::design(chain_schedule()).unwrap();
        assert!(k.worst_radius < 1.0);
        let mut f = InterpolatedKalman::new(k);
        assert!(matches!(
            f.step(0.2, &[0.0], &[0.0]),
            Err(StepError::PositionOutOfRange { .. })
        ));
        assert!(matches!(
            f.step(0.1, &[0.0, 1.0], &[0.0]),
            Err(StepError::Length { what: "y", .. })
        ));
        assert_eq!(
            f.step(0.1, &[f64::INFINITY], &[0.0]),
            Err(StepError::NonFinite("y"))
        );
        assert!(f.estimate().iter().all(|v| *v == 0.0));
    }
}
