//! The observer block of [`crate::observer_block`] with its Kalman gain
//! scheduled on a position (docs/control.md §1.4, §4.3, §5.6): for a sensor fixed
//! in the world while the structure moves under it, C and T_DC depend on the
//! position r_p, and so does the Kalman gain; A, B, the noise model and the
//! AD map K(z) do not (output position dependency).
//!
//! Per tick k, with the matrices prepared for the position r_p(k):
//! * ŷ_flex(k) = C_f(r_p(k)) x̂(k|k−1) (MC; rigid and noise-model columns zero);
//! * x̂(k+1|k) = A x̂ + B u_a − L(k) (C(r_p(k)) x̂ + D(r_p(k)) u_a − y);
//! * u_d(k) = K(z) on x̂(k+1|k) (or x̂(k+2|k) = A x̂(k+1|k) + B u_pending
//!   with the extra sample of delay), as the fixed block.
//!
//! The outputs at tick k split into a free part (known once r_p(k) and the
//! state are, i.e. one tick ahead) and a direct gain on [y(k); u_a(k);
//! u_pending(k)], exactly the layout of the fixed block, so the loop's
//! processes exchange the same messages; only the direct gain now changes
//! from tick to tick.
//!
//! Two schedulings of L (the thesis compares them, §5.6: "no significant
//! difference"):
//! * [`GainScheduling::Interpolated`]: steady-state gains on a grid,
//!   interpolated linearly with C and D ([`KalmanSchedule`]);
//! * [`GainScheduling::TimeVarying`]: the Riccati recursion every tick on the
//!   interpolated model, started from the steady state at the first position.
//!
//! Everything is sized in [`ScheduledObserver::new`]; the per-tick calls do
//! not allocate.

use crate::design_error::{DesignError, check_matrix};
use crate::in_place::{cholesky_solve_in_place, mul_into, propagate_covariance};
use crate::kalman::steady_state_kalman;
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::scheduling::{KalmanSchedule, ScheduledMatrices};
use crate::step_error::{StepError, check_slice};
use nalgebra::{DMatrix, DVector, DVectorView};

/// How the Kalman gain follows the position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GainScheduling {
    /// Steady-state gains on the grid, interpolated.
    Interpolated,
    /// The Riccati recursion every tick.
    TimeVarying,
}

/// A scheduled observer's design (everything but the per-tick state).
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduledObserverDesign {
    /// Models (A fixed; B, C, D on the grid) and steady-state gains.
    pub schedule: KalmanSchedule,
    /// The state columns of C that are flexible (C_f keeps only these);
    /// None: MC off (ŷ_flex = 0).
    pub flexible_columns: Option<std::ops::Range<usize>>,
    /// K(z): estimate (n) → u_d (n_u); None: AD off.
    pub feedback: Option<DiscreteStateSpace>,
    pub extra_delay_samples: usize,
    pub gains: GainScheduling,
}

impl ScheduledObserverDesign {
    pub fn states(&self) -> usize {
        self.schedule.models().states()
    }
    pub fn outputs(&self) -> usize {
        self.schedule.models().outputs()
    }
    pub fn inputs(&self) -> usize {
        self.schedule.models().inputs()
    }
    /// Inputs of the block: [y; u_a] or [y; u_a; u_pending].
    pub fn block_inputs(&self) -> usize {
        self.outputs() + self.inputs() * (1 + self.extra_delay_samples)
    }
    /// States of the block: x̂ and the states of K(z).
    pub fn block_states(&self) -> usize {
        self.states() + self.feedback.as_ref().map_or(0, |k| k.states())
    }

    /// Checks the pieces fit together (design time).
    pub fn check(&self) -> Result<(), DesignError> {
        let (n, nu) = (self.states(), self.inputs());
        if self.extra_delay_samples > 1 {
            return Err(DesignError::InvalidParameter(format!(
                "extra_delay_samples {} (0 or 1)",
                self.extra_delay_samples
            )));
        }
        if let Some(r) = &self.flexible_columns
            && r.end > n
        {
            return Err(DesignError::InvalidParameter(format!(
                "flexible columns {r:?} beyond {n} states"
            )));
        }
        if let Some(k) = &self.feedback {
            if k.inputs() != n || k.outputs() != nu {
                return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                    what: "K(z) (outputs x inputs)",
                    expected: (nu, n),
                    found: (k.outputs(), k.inputs()),
                }));
            }
            check_matrix(&k.d, "K(z) D", nu, n)?;
        }
        Ok(())
    }
}

/// The running observer (module doc).
#[derive(Debug, Clone)]
pub struct ScheduledObserver {
    design: ScheduledObserverDesign,
    /// B, C, D and L at the prepared tick's position.
    m: ScheduledMatrices,
    /// x̂(k|k−1) and the K(z) state.
    x: DVector<f64>,
    w: DVector<f64>,
    /// Scratch: x̂(k+1|k), the estimate fed to K(z), innovation, K(z) next state.
    x_next: DVector<f64>,
    v: DVector<f64>,
    innovation: DVector<f64>,
    w_next: DVector<f64>,
    /// The direct map of the estimate fed to K(z) on the block inputs.
    h_in: DMatrix<f64>,
    /// Time-varying gain only: P(k|k−1) and its scratch.
    p: DMatrix<f64>,
    w_proc: DMatrix<f64>,
    r: DMatrix<f64>,
    cp: DMatrix<f64>,
    pct: DMatrix<f64>,
    s: DMatrix<f64>,
    mt: DMatrix<f64>,
    gain_m: DMatrix<f64>,
    tmp: DMatrix<f64>,
    tmp2: DMatrix<f64>,
    a_t: DMatrix<f64>,
}

impl ScheduledObserver {
    /// Starts at rest with the matrices prepared for tick 0 at `position`.
    pub fn new(design: ScheduledObserverDesign, position: f64) -> Result<Self, DesignError> {
        design.check()?;
        let models = design.schedule.models();
        let (n, ny) = (models.states(), models.outputs());
        let nw = design.feedback.as_ref().map_or(0, |k| k.states());
        let p = match design.gains {
            GainScheduling::TimeVarying => {
                let at = models.model_at(position)?;
                steady_state_kalman(&at, models.weights())?.p
            }
            GainScheduling::Interpolated => DMatrix::zeros(0, 0),
        };
        let wts = models.weights();
        let w_proc = &wts.g * &wts.q * wts.g.transpose();
        let mut s = Self {
            m: design.schedule.matrices(),
            x: DVector::zeros(n),
            w: DVector::zeros(nw),
            x_next: DVector::zeros(n),
            v: DVector::zeros(n),
            innovation: DVector::zeros(ny),
            w_next: DVector::zeros(nw),
            h_in: DMatrix::zeros(n, design.block_inputs()),
            p,
            w_proc: (&w_proc + w_proc.transpose()) * 0.5,
            r: wts.r.clone(),
            cp: DMatrix::zeros(ny, n),
            pct: DMatrix::zeros(n, ny),
            s: DMatrix::zeros(ny, ny),
            mt: DMatrix::zeros(ny, n),
            gain_m: DMatrix::zeros(n, ny),
            tmp: DMatrix::zeros(n, n),
            tmp2: DMatrix::zeros(n, n),
            a_t: models.a().transpose(),
            design,
        };
        s.prepare(position)
            .map_err(|e| DesignError::InvalidParameter(e.to_string()))?;
        Ok(s)
    }

    pub fn design(&self) -> &ScheduledObserverDesign {
        &self.design
    }

    /// x̂(k|k−1).
    pub fn estimate(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// Values [`Self::write_state`] writes: x̂, the K(z) state and, for the
    /// time-varying gain, the covariance P (column-major).
    pub fn state_len(&self) -> usize {
        self.x.len() + self.w.len() + self.p.len()
    }

    /// The running state [x̂; w; P] into `out` (`state_len` values).
    pub fn write_state(&self, out: &mut [f64]) {
        let (n, nw) = (self.x.len(), self.w.len());
        out[..n].copy_from_slice(self.x.as_slice());
        out[n..n + nw].copy_from_slice(self.w.as_slice());
        out[n + nw..n + nw + self.p.len()].copy_from_slice(self.p.as_slice());
    }

    /// Takes over a state [x̂; w; P] written by an identical design (a
    /// hand-over between instances) whose next tick is at `position`.
    pub fn set_state(&mut self, state: &[f64], position: f64) -> Result<(), StepError> {
        check_slice(state, "observer state", self.state_len())?;
        let (n, nw, np) = (self.x.len(), self.w.len(), self.p.len());
        self.x.as_mut_slice().copy_from_slice(&state[..n]);
        self.w.as_mut_slice().copy_from_slice(&state[n..n + nw]);
        self.p
            .as_mut_slice()
            .copy_from_slice(&state[n + nw..n + nw + np]);
        self.prepare(position)
    }

    /// The predictor gain in use at the prepared tick.
    pub fn gain(&self) -> &DMatrix<f64> {
        &self.m.l
    }

    /// B, C, D (and L) for the tick at `position`: interpolated, or for the
    /// time-varying filter L = A P Cᵀ (C P Cᵀ + R)⁻¹ from the current P.
    fn prepare(&mut self, position: f64) -> Result<(), StepError> {
        match self.design.gains {
            GainScheduling::Interpolated => self.design.schedule.interpolate(position, &mut self.m),
            GainScheduling::TimeVarying => {
                self.design
                    .schedule
                    .models()
                    .interpolate(position, &mut self.m)?;
                mul_into(&mut self.cp, 1.0, &self.m.c, &self.p, 0.0);
                self.cp.transpose_to(&mut self.pct);
                self.s.copy_from(&self.r);
                mul_into(&mut self.s, 1.0, &self.m.c, &self.pct, 1.0);
                self.mt.copy_from(&self.cp);
                cholesky_solve_in_place(&mut self.s, &mut self.mt)?;
                self.mt.transpose_to(&mut self.gain_m);
                let a = self.design.schedule.models().a();
                mul_into(&mut self.m.l, 1.0, a, &self.gain_m, 0.0);
                Ok(())
            }
        }
    }

    /// The outputs [ŷ_flex; u_d] at the prepared tick: their free part into
    /// `free` (n_y + n_u) and the direct gain on the block inputs into
    /// `direct` (row i, input j at `direct[i * stride + j]`).
    pub fn outputs(&mut self, free: &mut [f64], direct: &mut [f64], stride: usize) {
        let (ny, nu) = (self.design.outputs(), self.design.inputs());
        let n = self.x.len();
        let n_in = self.design.block_inputs();
        // ŷ_flex = C_f x̂: C with only the flexible columns.
        for (i, f) in free.iter_mut().enumerate().take(ny) {
            *f = match &self.design.flexible_columns {
                Some(cols) => cols.clone().map(|j| self.m.c[(i, j)] * self.x[j]).sum(),
                None => 0.0,
            };
        }
        for i in 0..ny {
            for j in 0..n_in {
                direct[i * stride + j] = 0.0;
            }
        }
        let Some(k) = &self.design.feedback else {
            for (i, f) in free.iter_mut().enumerate().skip(ny).take(nu) {
                *f = 0.0;
                for j in 0..n_in {
                    direct[i * stride + j] = 0.0;
                }
            }
            return;
        };
        // Free part of the estimate fed to K(z): (A − L C) x̂ (then A · it
        // with the extra delay); its direct map H_in on [y; u_a; u_pending].
        let a = self.design.schedule.models().a();
        self.innovation.gemv(1.0, &self.m.c, &self.x, 0.0);
        self.x_next.gemv(1.0, a, &self.x, 0.0);
        self.x_next.gemv(-1.0, &self.m.l, &self.innovation, 1.0);
        self.h_in.fill(0.0);
        self.h_in.columns_mut(0, ny).copy_from(&self.m.l);
        {
            let mut hu = self.h_in.columns_mut(ny, nu);
            hu.copy_from(&self.m.b);
            for j in 0..nu {
                hu.column_mut(j)
                    .gemv(-1.0, &self.m.l, &self.m.d.column(j), 1.0);
            }
        }
        if self.design.extra_delay_samples == 1 {
            // x̂(k+2|k) = A x̂(k+1|k) + B u_pending.
            self.v.gemv(1.0, a, &self.x_next, 0.0);
            self.x_next.copy_from(&self.v);
            for j in 0..ny + nu {
                self.v.gemv(1.0, a, &self.h_in.column(j), 0.0);
                self.h_in.column_mut(j).copy_from(&self.v);
            }
            self.h_in.columns_mut(ny + nu, nu).copy_from(&self.m.b);
        }
        // u_d = C_k w + D_k v, v = free + H_in · inputs.
        for i in 0..nu {
            let mut f = 0.0;
            for j in 0..k.states() {
                f += k.c[(i, j)] * self.w[j];
            }
            for j in 0..n {
                f += k.d[(i, j)] * self.x_next[j];
            }
            free[ny + i] = f;
            for col in 0..n_in {
                let mut g = 0.0;
                for j in 0..n {
                    g += k.d[(i, j)] * self.h_in[(j, col)];
                }
                direct[(ny + i) * stride + col] = g;
            }
        }
    }

    /// Processes tick k's inputs [y(k); u_a(k); u_pending(k)] with the
    /// matrices prepared for it, moves to x̂(k+1|k), and prepares tick k+1
    /// at `next_position`. Writes the innovation y(k) − C x̂ − D u_a into
    /// `innovation`. On an error (position off the grid, a time-varying
    /// covariance that lost definiteness) the state has moved but the
    /// matrices of tick k stay in use.
    pub fn advance(
        &mut self,
        inputs: &[f64],
        next_position: f64,
        innovation: &mut [f64],
    ) -> Result<(), StepError> {
        let (ny, nu) = (self.design.outputs(), self.design.inputs());
        let a = self.design.schedule.models().a();
        let y = DVectorView::from_slice(&inputs[..ny], ny);
        let u = DVectorView::from_slice(&inputs[ny..ny + nu], nu);
        self.innovation.copy_from(&y);
        self.innovation.gemv(-1.0, &self.m.c, &self.x, 1.0);
        self.innovation.gemv(-1.0, &self.m.d, &u, 1.0);
        innovation[..ny].copy_from_slice(self.innovation.as_slice());
        self.x_next.gemv(1.0, a, &self.x, 0.0);
        self.x_next.gemv(1.0, &self.m.b, &u, 1.0);
        self.x_next.gemv(1.0, &self.m.l, &self.innovation, 1.0);
        if let Some(k) = &self.design.feedback {
            if self.design.extra_delay_samples == 1 {
                let pending = DVectorView::from_slice(&inputs[ny + nu..ny + 2 * nu], nu);
                self.v.gemv(1.0, a, &self.x_next, 0.0);
                self.v.gemv(1.0, &self.m.b, &pending, 1.0);
            } else {
                self.v.copy_from(&self.x_next);
            }
            self.w_next.gemv(1.0, &k.a, &self.w, 0.0);
            self.w_next.gemv(1.0, &k.b, &self.v, 1.0);
            std::mem::swap(&mut self.w, &mut self.w_next);
        }
        std::mem::swap(&mut self.x, &mut self.x_next);
        if self.design.gains == GainScheduling::TimeVarying {
            // P(k+1|k) = A (P − M C P) Aᵀ + G Q Gᵀ with M from `prepare`, kept symmetric.
            propagate_covariance(
                &mut self.p,
                a,
                &self.a_t,
                &self.gain_m,
                &self.cp,
                &self.w_proc,
                &mut self.tmp,
                &mut self.tmp2,
            );
        }
        self.prepare(next_position)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lti::LtiRunner;
    use crate::models::{TS_10KHZ, thesis_chain_modal};
    use crate::observer_block::{ModalObserverOptions, design_modal_observer};
    use crate::scheduling::PositionGrid;

    /// The thesis MC + AD observer at sensor positions 4 … 5 (0.25 apart),
    /// and the fixed block designed at `at`.
    fn designs(
        gains: GainScheduling,
        extra_delay: usize,
        at: f64,
    ) -> (
        ScheduledObserverDesign,
        crate::observer_block::ObserverBlock,
    ) {
        let chain = thesis_chain_modal().unwrap();
        let reduced = |p: f64| {
            chain
                .with_sensor_positions(&[p])
                .unwrap()
                .truncate(4, &[4, 5, 6])
                .unwrap()
        };
        let mut options = ModalObserverOptions::thesis_mc_ad(TS_10KHZ, 3);
        options.extra_delay_samples = extra_delay;
        let fixed = design_modal_observer(&reduced(at), &options).unwrap();
        let augmented = |p: f64| {
            let base = crate::discretise::zoh(&reduced(p).state_space(), TS_10KHZ).unwrap();
            let w = crate::kalman::KalmanWeights::thesis(&base);
            crate::kalman::with_noise_model(
                &base,
                &w,
                &crate::kalman::NoiseModel::thesis(&base, 1e3),
            )
            .unwrap()
        };
        let grid = PositionGrid::new(4.0, 0.25, 5).unwrap();
        let models =
            crate::scheduling::ModelSchedule::new(grid, augmented(4.0).1, |p| Ok(augmented(p).0))
                .unwrap();
        let design = ScheduledObserverDesign {
            schedule: KalmanSchedule::design(models).unwrap(),
            flexible_columns: Some(2..8),
            feedback: fixed.design.feedback.clone(),
            extra_delay_samples: extra_delay,
            gains,
        };
        (design, fixed.block)
    }

    /// Runs both on the same inputs at a fixed position: outputs (free +
    /// direct · inputs) and estimates agree with the compiled block.
    fn agree(gains: GainScheduling, extra_delay: usize) {
        let at = 4.25;
        let (design, block) = designs(gains, extra_delay, at);
        let n_in = design.block_inputs();
        let n_out = design.outputs() + design.inputs();
        let mut scheduled = ScheduledObserver::new(design, at).unwrap();
        let mut fixed = LtiRunner::new(block.system.clone());
        let (mut free, mut direct) = (vec![0.0; n_out], vec![0.0; n_out * n_in]);
        let mut innovation = [0.0];
        for k in 0..300 {
            let t = k as f64;
            let inputs: Vec<f64> = (0..n_in)
                .map(|j| {
                    let scale = if j == 0 { 1e-6 } else { 10.0 };
                    scale * (0.37 * t + j as f64).sin()
                })
                .collect();
            scheduled.outputs(&mut free, &mut direct, n_in);
            let want = fixed.step(&inputs).to_vec();
            for i in 0..n_out {
                let got = free[i]
                    + (0..n_in)
                        .map(|j| direct[i * n_in + j] * inputs[j])
                        .sum::<f64>();
                let tol = 1e-9 * want[i].abs().max(1e-9);
                assert!(
                    (got - want[i]).abs() <= tol,
                    "{k}/{i}: {got} vs {}",
                    want[i]
                );
            }
            scheduled.advance(&inputs, at, &mut innovation).unwrap();
            let x: Vec<f64> = (&block.estimate_map
                * nalgebra::DVector::from_column_slice(fixed.state()))
            .iter()
            .copied()
            .collect();
            for (a, b) in scheduled.estimate().iter().zip(&x) {
                assert!((a - b).abs() <= 1e-9 * b.abs().max(1e-12), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn at_a_fixed_position_it_is_the_fixed_block() {
        agree(GainScheduling::Interpolated, 0);
        agree(GainScheduling::Interpolated, 1);
        // From the steady-state covariance the recursion stays there.
        agree(GainScheduling::TimeVarying, 0);
    }

    #[test]
    fn a_moving_position_changes_the_gain_and_errors_off_the_grid() {
        let (design, _) = designs(GainScheduling::Interpolated, 0, 4.0);
        let n_in = design.block_inputs();
        let mut o = ScheduledObserver::new(design, 4.0).unwrap();
        let at_4 = o.gain().clone();
        let mut innovation = [0.0];
        o.advance(&vec![0.0; n_in], 5.0, &mut innovation).unwrap();
        assert!((o.gain() - &at_4).amax() > 1e-3 * at_4.amax());
        let err = o
            .advance(&vec![0.0; n_in], 5.5, &mut innovation)
            .unwrap_err();
        assert!(matches!(err, StepError::PositionOutOfRange { .. }), "{err}");
        assert!(ScheduledObserver::new(o.design().clone(), 3.0).is_err());
    }
}
