//! Input–output observer with a dynamic correction filter K(z) (Seed 001,
//! Adams & Forbes; docs/control.md §12.2).
//!
//! The plant model runs on the known input; the innovation ρ = y − ŷ drives a
//! correction filter K(z) whose output ν is fed back into the model:
//!
//!   ρ(k)     = y(k) − C x̂(k) − D u(k)
//!   K(z):      w(k+1) = A_K w(k) + B_K ρ(k),  ν(k) = C_K w(k) + D_K ρ(k)
//!   x̂(k+1)   = A x̂(k) + B u(k) + E ν(k)
//!
//! E says where ν enters: E = B makes ν an input correction (the paper's
//! structure, ν added to the model input); E = I lets K(z) correct the state
//! directly, and a static K(z) = L with E = I is the Luenberger/Kalman
//! predictor. With noise-free data the estimation error e = x − x̂ and w obey
//!
//!   [e; w](k+1) = [[A − E D_K C, −E C_K], [B_K C, A_K]] [e; w],
//!
//! so designing K(z) is an output-feedback problem on (A, E, C): the paper
//! solves it by DK-iteration for robustness over a population of plants.
//! That synthesis (H∞ plus μ) is not implemented here; instead
//! [`observer_based_correction`] builds a K(z) from any stabilising pair
//! (F, L) by separation, and [`IoObserver::new`] accepts any K(z) designed
//! elsewhere and refuses it if the error dynamics are unstable.
//!
//! # In the loop
//! With s = [x̂; w] the observer is a predictor on the model augmented with
//! K's states (see [`IoObserver::predictor`]), so [`IoObserver::compile`]
//! puts it into the loop's [`ObserverBlock`] unchanged: the observer
//! process, MC, AD and live swaps treat it as any predictor. The estimate
//! layout is the model's states first, K's states after.

use crate::design_error::{DesignError, check_matrix};
use crate::linalg::{eigenvalues, spectral_radius};
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::observer_block::{ObserverBlock, ObserverDesign, compile_observer_block};
use crate::step_error::{StepError, check_slice};
use nalgebra::{Complex, DMatrix, DVector, DVectorView};

/// A designed input–output observer (design time).
#[derive(Debug, Clone, PartialEq)]
pub struct IoObserver {
    model: DiscreteStateSpace,
    correction_input: DMatrix<f64>,
    filter: DiscreteStateSpace,
    radius: f64,
}

impl IoObserver {
    /// Observer on `model` with correction ν = K(z) ρ entering through
    /// `correction_input` E (n × n_ν). K(z) = `filter` maps n_y → n_ν at the
    /// model's sample period. Refused if the error dynamics are not stable.
    pub fn new(
        model: DiscreteStateSpace,
        correction_input: DMatrix<f64>,
        filter: DiscreteStateSpace,
    ) -> Result<Self, DesignError> {
        let (n, p) = (model.states(), model.outputs());
        if filter.inputs() != p {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "correction filter K(z) (outputs x inputs): its input is the innovation",
                expected: (filter.outputs(), p),
                found: (filter.outputs(), filter.inputs()),
            }));
        }
        check_matrix(
            &correction_input,
            "correction input matrix E (states x filter outputs)",
            n,
            filter.outputs(),
        )?;
        if (filter.ts - model.ts).abs() > 1e-12 * model.ts {
            return Err(DesignError::InvalidParameter(format!(
                "correction filter sample period {} s differs from the model's {} s",
                filter.ts, model.ts
            )));
        }
        let mut obs = Self {
            model,
            correction_input,
            filter,
            radius: f64::NAN,
        };
        let radius = spectral_radius(&obs.error_dynamics())?;
        if radius >= 1.0 {
            return Err(DesignError::Unstable(format!(
                "input-output observer error dynamics have spectral radius {radius}"
            )));
        }
        obs.radius = radius;
        Ok(obs)
    }

    /// ν corrects the model input (E = B), as in Adams & Forbes.
    pub fn input_correction(
        model: DiscreteStateSpace,
        filter: DiscreteStateSpace,
    ) -> Result<Self, DesignError> {
        let e = model.b.clone();
        Self::new(model, e, filter)
    }

    /// ν corrects the state directly (E = I).
    pub fn state_correction(
        model: DiscreteStateSpace,
        filter: DiscreteStateSpace,
    ) -> Result<Self, DesignError> {
        let n = model.states();
        Self::new(model, DMatrix::identity(n, n), filter)
    }

    pub fn model(&self) -> &DiscreteStateSpace {
        &self.model
    }
    pub fn filter(&self) -> &DiscreteStateSpace {
        &self.filter
    }
    pub fn correction_input(&self) -> &DMatrix<f64> {
        &self.correction_input
    }

    /// Spectral radius of the error dynamics (< 1).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// [[A − E D_K C, −E C_K], [B_K C, A_K]] (see the module doc).
    pub fn error_dynamics(&self) -> DMatrix<f64> {
        let (m, k, e) = (&self.model, &self.filter, &self.correction_input);
        let (n, nk) = (m.states(), k.states());
        let mut a = DMatrix::zeros(n + nk, n + nk);
        a.view_mut((0, 0), (n, n))
            .copy_from(&(&m.a - e * &k.d * &m.c));
        a.view_mut((0, n), (n, nk)).copy_from(&(-(e * &k.c)));
        a.view_mut((n, 0), (nk, n)).copy_from(&(&k.b * &m.c));
        a.view_mut((n, n), (nk, nk)).copy_from(&k.a);
        a
    }

    /// Eigenvalues of the error dynamics.
    pub fn error_poles(&self) -> Result<Vec<Complex<f64>>, DesignError> {
        Ok(eigenvalues(&self.error_dynamics())?)
    }

    /// The observer as one block for analysis or for [`crate::lti::LtiRunner`]:
    /// state [x̂; w], inputs [y; u], output x̂(k|k−1) (no feedthrough).
    pub fn to_state_space(&self) -> Result<DiscreteStateSpace, DesignError> {
        let (m, k, e) = (&self.model, &self.filter, &self.correction_input);
        let (n, nk, p, nu) = (m.states(), k.states(), m.outputs(), m.inputs());
        let ed = e * &k.d;
        let mut a = DMatrix::zeros(n + nk, n + nk);
        a.view_mut((0, 0), (n, n)).copy_from(&(&m.a - &ed * &m.c));
        a.view_mut((0, n), (n, nk)).copy_from(&(e * &k.c));
        a.view_mut((n, 0), (nk, n)).copy_from(&(-(&k.b * &m.c)));
        a.view_mut((n, n), (nk, nk)).copy_from(&k.a);
        let mut b = DMatrix::zeros(n + nk, p + nu);
        b.view_mut((0, 0), (n, p)).copy_from(&ed);
        b.view_mut((0, p), (n, nu)).copy_from(&(&m.b - &ed * &m.d));
        b.view_mut((n, 0), (nk, p)).copy_from(&k.b);
        b.view_mut((n, p), (nk, nu)).copy_from(&(-(&k.b * &m.d)));
        let mut c = DMatrix::zeros(n, n + nk);
        c.view_mut((0, 0), (n, n)).fill_with_identity();
        Ok(DiscreteStateSpace::new(
            a,
            b,
            c,
            DMatrix::zeros(n, p + nu),
            m.ts,
        )?)
    }

    /// Spectral radius of K(z)'s own dynamics A_K (0 for a static K).
    pub fn filter_radius(&self) -> Result<f64, DesignError> {
        if self.filter.states() == 0 {
            return Ok(0.0);
        }
        Ok(spectral_radius(&self.filter.a)?)
    }

    /// The observer as a predictor on the model augmented with K's states,
    /// s = [x̂; w]:
    ///
    ///   A_s = [[A, E C_K], [0, A_K]], B_s = [B; 0], C_s = [C, 0], D_s = D,
    ///   L_s = [E D_K; B_K],
    ///
    /// so that s(k+1) = A_s s + B_s u + L_s (y − C_s s − D_s u) is the
    /// module doc's recursion. Returns (model, gain).
    pub fn predictor(&self) -> Result<(DiscreteStateSpace, DMatrix<f64>), DesignError> {
        let (m, k, e) = (&self.model, &self.filter, &self.correction_input);
        let (n, nk, p, nu) = (m.states(), k.states(), m.outputs(), m.inputs());
        let mut a = DMatrix::zeros(n + nk, n + nk);
        a.view_mut((0, 0), (n, n)).copy_from(&m.a);
        a.view_mut((0, n), (n, nk)).copy_from(&(e * &k.c));
        a.view_mut((n, n), (nk, nk)).copy_from(&k.a);
        let mut b = DMatrix::zeros(n + nk, nu);
        b.view_mut((0, 0), (n, nu)).copy_from(&m.b);
        let mut c = DMatrix::zeros(p, n + nk);
        c.view_mut((0, 0), (p, n)).copy_from(&m.c);
        let mut l = DMatrix::zeros(n + nk, p);
        l.view_mut((0, 0), (n, p)).copy_from(&(e * &k.d));
        l.view_mut((n, 0), (nk, p)).copy_from(&k.b);
        Ok((DiscreteStateSpace::new(a, b, c, m.d.clone(), m.ts)?, l))
    }

    /// The observer as the loop's [`ObserverBlock`] (layout in
    /// [`crate::observer_block`]), block state [x̂; w; AD states], estimate
    /// [x̂; w]. `compensation` is C_f (n_y × n, over the model's states) for
    /// MC, `damping` the AD map from the model's n states to u_d; both see
    /// zeros for K's states, which are not part of the plant.
    pub fn compile(
        &self,
        compensation: Option<&DMatrix<f64>>,
        damping: Option<&DiscreteStateSpace>,
        extra_delay_samples: usize,
    ) -> Result<ObserverBlock, DesignError> {
        let (n, nk, p) = (
            self.model.states(),
            self.filter.states(),
            self.model.outputs(),
        );
        let (model, gain) = self.predictor()?;
        let compensation = match compensation {
            Some(cf) => {
                check_matrix(cf, "C_f (outputs x model states)", p, n)?;
                let mut padded = DMatrix::zeros(p, n + nk);
                padded.view_mut((0, 0), (p, n)).copy_from(cf);
                Some(padded)
            }
            None => None,
        };
        let feedback = match damping {
            Some(ad) => {
                if ad.inputs() != n {
                    return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                        what: "active-damping map (outputs x model states)",
                        expected: (ad.outputs(), n),
                        found: (ad.outputs(), ad.inputs()),
                    }));
                }
                let (na, nd) = (ad.states(), ad.outputs());
                let mut b = DMatrix::zeros(na, n + nk);
                b.view_mut((0, 0), (na, n)).copy_from(&ad.b);
                let mut d = DMatrix::zeros(nd, n + nk);
                d.view_mut((0, 0), (nd, n)).copy_from(&ad.d);
                Some(DiscreteStateSpace::new(
                    ad.a.clone(),
                    b,
                    ad.c.clone(),
                    d,
                    ad.ts,
                )?)
            }
            None => None,
        };
        let design = ObserverDesign {
            model,
            gain,
            compensation,
            feedback,
        };
        compile_observer_block(&design, extra_delay_samples)
    }

    /// The allocation-free per-sample runner, starting at x̂ = 0, w = 0.
    pub fn runner(&self) -> IoObserverRunner {
        let (n, p, nu) = (
            self.model.states(),
            self.model.outputs(),
            self.model.inputs(),
        );
        let (nk, nv) = (self.filter.states(), self.filter.outputs());
        IoObserverRunner {
            obs: self.clone(),
            x: DVector::zeros(n),
            x_next: DVector::zeros(n),
            w: DVector::zeros(nk),
            w_next: DVector::zeros(nk),
            rho: DVector::zeros(p),
            nu: DVector::zeros(nv),
            n_u: nu,
        }
    }
}

/// K(z) for an input correction (E = B) by separation: with the error seen
/// as a plant e(k+1) = A e − B ν, ρ = C e, the filter is an observer of e
/// (gain L) with state feedback ν = F ê:
///
///   K(z) = (A − B F − L C, L, F, 0),
///
/// and the error dynamics have exactly the poles eig(A − B F) ∪ eig(A − L C).
/// F (n_u × n) may come from [`crate::lqr::lqr`] or
/// [`crate::placement::robust_place`], L (n × n_y) from a Kalman or
/// placement design.
pub fn observer_based_correction(
    model: &DiscreteStateSpace,
    f: &DMatrix<f64>,
    l: &DMatrix<f64>,
) -> Result<DiscreteStateSpace, DesignError> {
    let (n, m, p) = (model.states(), model.inputs(), model.outputs());
    check_matrix(f, "state-feedback gain F of the correction filter", m, n)?;
    check_matrix(l, "observer gain L of the correction filter", n, p)?;
    Ok(DiscreteStateSpace::new(
        &model.a - &model.b * f - l * &model.c,
        l.clone(),
        f.clone(),
        DMatrix::zeros(m, p),
        model.ts,
    )?)
}

/// Runs an [`IoObserver`] sample by sample without allocating.
#[derive(Debug, Clone)]
pub struct IoObserverRunner {
    obs: IoObserver,
    x: DVector<f64>,
    x_next: DVector<f64>,
    w: DVector<f64>,
    w_next: DVector<f64>,
    rho: DVector<f64>,
    nu: DVector<f64>,
    n_u: usize,
}

impl IoObserverRunner {
    /// x̂(k|k−1).
    pub fn estimate(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// The innovation ρ(k) of the last step.
    pub fn innovation(&self) -> &[f64] {
        self.rho.as_slice()
    }

    /// The correction ν(k) of the last step.
    pub fn correction(&self) -> &[f64] {
        self.nu.as_slice()
    }

    pub fn set_estimate(&mut self, x: &[f64]) -> Result<(), StepError> {
        check_slice(x, "estimate", self.x.len())?;
        self.x.as_mut_slice().copy_from_slice(x);
        Ok(())
    }

    pub fn reset(&mut self) {
        self.x.fill(0.0);
        self.w.fill(0.0);
    }

    /// From y(k) and u(k): returns x̂(k+1|k). Refuses wrong lengths and
    /// non-finite inputs, leaving the state unchanged.
    pub fn step(&mut self, y: &[f64], u: &[f64]) -> Result<&[f64], StepError> {
        let m = &self.obs.model;
        let k = &self.obs.filter;
        check_slice(y, "y", self.rho.len())?;
        check_slice(u, "u", self.n_u)?;
        let y = DVectorView::from_slice(y, y.len());
        let u = DVectorView::from_slice(u, u.len());
        self.rho.copy_from(&y);
        self.rho.gemv(-1.0, &m.c, &self.x, 1.0);
        self.rho.gemv(-1.0, &m.d, &u, 1.0);
        self.nu.gemv(1.0, &k.c, &self.w, 0.0);
        self.nu.gemv(1.0, &k.d, &self.rho, 1.0);
        self.w_next.gemv(1.0, &k.a, &self.w, 0.0);
        self.w_next.gemv(1.0, &k.b, &self.rho, 1.0);
        self.x_next.gemv(1.0, &m.a, &self.x, 0.0);
        self.x_next.gemv(1.0, &m.b, &u, 1.0);
        self.x_next
            .gemv(1.0, &self.obs.correction_input, &self.nu, 1.0);
        std::mem::swap(&mut self.x, &mut self.x_next);
        std::mem::swap(&mut self.w, &mut self.w_next);
        Ok(self.x.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::kalman::{KalmanWeights, steady_state_kalman};
    use crate::lti::LtiRunner;
    use crate::modal::ModalModel;
    use crate::models::flexible_joint;
    use crate::placement::{robust_place, robust_place_observer};

    /// The 2-DOF flexible joint (modal form, 8 states, 2 currents in, 2 hub
    /// angles out), ZOH at the paper's 200 Hz.
    fn joint() -> DiscreteStateSpace {
        let modal = ModalModel::from_nodal(&flexible_joint()).unwrap();
        zoh(&modal.state_space(), 1.0 / 200.0).unwrap()
    }

    fn kalman_gain(model: &DiscreteStateSpace) -> DMatrix<f64> {
        let w = KalmanWeights {
            g: model.b.clone(),
            q: DMatrix::identity(2, 2),
            r: DMatrix::identity(2, 2) * 1e-6,
        };
        steady_state_kalman(model, &w).unwrap().l
    }

    /// The known input [A].
    fn excitation(k: usize) -> [f64; 2] {
        let t = k as f64 / 200.0;
        [0.3 * (2.0 * t).sin(), -0.2 * (3.1 * t).cos()]
    }

    #[test]
    fn static_gain_is_the_luenberger_predictor() {
        let model = joint();
        let l = kalman_gain(&model);
        let obs = IoObserver::state_correction(
            model.clone(),
            DiscreteStateSpace::gain(l.clone(), model.ts).unwrap(),
        )
        .unwrap();
        // Predictor x̂(k+1) = (A − LC) x̂ + (B − LD) u + L y as a plain LTI block.
        let mut b = DMatrix::zeros(8, 4);
        b.columns_mut(0, 2).copy_from(&l);
        b.columns_mut(2, 2).copy_from(&(&model.b - &l * &model.d));
        let pred = DiscreteStateSpace::new(
            &model.a - &l * &model.c,
            b,
            DMatrix::identity(8, 8),
            DMatrix::zeros(8, 4),
            model.ts,
        )
        .unwrap();
        let mut reference = LtiRunner::new(pred);
        let mut run = obs.runner();
        let mut plant = LtiRunner::new(model.clone());
        plant.set_state(&[0.1, 0.0, -0.05, 0.2, 0.01, 0.0, 0.0, -0.02]);
        for k in 0..400 {
            let u = excitation(k);
            let y = plant.step(&u).to_vec();
            reference.advance(&[y[0], y[1], u[0], u[1]]);
            let x = run.step(&y, &u).unwrap();
            let want = reference.state();
            let err = x
                .iter()
                .zip(want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(err <= 1e-12 * want.iter().fold(1e-12f64, |m, v| m.max(v.abs())));
        }
    }

    #[test]
    fn designed_dynamic_correction_is_stable_on_the_flexible_joint() {
        let model = joint();
        // Poles of s² + 2ζω s + ω² (ω = 2π f) mapped by z = e^{sT}.
        let poles = |spec: [(f64, f64); 4]| -> Vec<Complex<f64>> {
            let mut p = Vec::new();
            for (f_hz, zeta) in spec {
                let w = 2.0 * std::f64::consts::PI * f_hz;
                let s = Complex::new(-zeta * w, w * (1.0 - zeta * zeta).sqrt());
                let z = (s * model.ts).exp();
                p.extend([z, z.conj()]);
            }
            p
        };
        // F: rigid modes to 2 and 2.5 Hz (ζ 0.7), flexible modes kept at their
        // frequency with ζ 0.5. L: faster, 6–9 Hz. (A steady-state Kalman gain
        // also works but leaves a flexible mode with |z| = 0.9986, too slow
        // for a short test.)
        let f = robust_place(
            &model.a,
            &model.b,
            &poles([(2.0, 0.7), (2.5, 0.7), (4.88, 0.5), (5.81, 0.5)]),
        )
        .unwrap()
        .gain;
        let l = robust_place_observer(
            &model.a,
            &model.c,
            &poles([(6.0, 0.7), (7.0, 0.7), (8.0, 0.6), (9.0, 0.6)]),
        )
        .unwrap()
        .gain;
        let k = observer_based_correction(&model, &f, &l).unwrap();
        assert_eq!((k.states(), k.inputs(), k.outputs()), (8, 2, 2));
        let obs = IoObserver::input_correction(model.clone(), k).unwrap();
        assert!(obs.radius() < 1.0);
        eprintln!("error-dynamics spectral radius {:.6}", obs.radius());
        // Separation: error poles = eig(A − BF) ∪ eig(A − LC).
        let mut want = eigenvalues(&(&model.a - &model.b * &f)).unwrap();
        want.extend(eigenvalues(&(&model.a - &l * &model.c)).unwrap());
        let got = obs.error_poles().unwrap();
        for w in &want {
            let d = got
                .iter()
                .map(|z| (z - w).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(d < 1e-8, "error pole {w} missing ({d})");
        }
        // In the time domain the estimate converges from a wrong start, and
        // the runner agrees with the compiled block.
        let mut plant = LtiRunner::new(model.clone());
        let x0 = [0.1, 0.0, -0.05, 0.2, 0.01, 0.0, 0.0, -0.02];
        plant.set_state(&x0);
        let mut run = obs.runner();
        let mut block = LtiRunner::new(obs.to_state_space().unwrap());
        let e0 = x0.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut e = f64::NAN;
        for k in 0..600 {
            let u = excitation(k);
            let x_true = plant.state().to_vec();
            e = x_true
                .iter()
                .zip(run.estimate())
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            let y = plant.step(&u).to_vec();
            let blk = block.step(&[y[0], y[1], u[0], u[1]]).to_vec();
            for (a, b) in blk.iter().zip(run.estimate()) {
                assert!((a - b).abs() <= 1e-9 * e0);
            }
            run.step(&y, &u).unwrap();
        }
        assert!(
            e < 1e-8 * e0,
            "estimation error after 3 s: {e} (start {e0})"
        );
        // The paper's use: one K(z) for a population, each device's observer
        // pairing it with that device's own model. Joint stiffness −20 % … +20 %.
        let k = obs.filter().clone();
        for factor in [0.8, 0.9, 1.1, 1.2] {
            let mut nodal = flexible_joint();
            nodal.stiffness *= factor;
            let device = zoh(
                &ModalModel::from_nodal(&nodal).unwrap().state_space(),
                model.ts,
            )
            .unwrap();
            let o = IoObserver::input_correction(device, k.clone()).unwrap();
            eprintln!(
                "stiffness x{factor}: error-dynamics radius {:.6}",
                o.radius()
            );
            assert!(o.radius() < 1.0);
        }
    }

    #[test]
    fn compiled_block_runs_the_observer_with_the_filter_states_after_the_model() {
        let model = joint();
        let l = kalman_gain(&model);
        let f = robust_place(
            &model.a,
            &model.b,
            &[
                Complex::new(0.95, 0.02),
                Complex::new(0.95, -0.02),
                Complex::new(0.96, 0.03),
                Complex::new(0.96, -0.03),
                Complex::new(0.9, 0.1),
                Complex::new(0.9, -0.1),
                Complex::new(0.92, 0.12),
                Complex::new(0.92, -0.12),
            ],
        )
        .unwrap()
        .gain;
        let k = observer_based_correction(&model, &f, &l).unwrap();
        let obs = IoObserver::input_correction(model.clone(), k).unwrap();
        // MC reads the first output row of C, AD feeds back −0.1 of state 1.
        let cf = model.c.clone();
        let mut ad_gain = DMatrix::zeros(2, 8);
        ad_gain[(0, 1)] = -0.1;
        let ad = DiscreteStateSpace::gain(ad_gain.clone(), model.ts).unwrap();
        let block = obs.compile(Some(&cf), Some(&ad), 0).unwrap();
        assert_eq!(block.estimate_map.shape(), (16, 16));
        assert_eq!((block.n_y, block.n_u), (2, 2));
        let mut run = obs.runner();
        let mut lti = LtiRunner::new(block.system.clone());
        let mut plant = LtiRunner::new(model.clone());
        plant.set_state(&[0.1, 0.0, -0.05, 0.2, 0.01, 0.0, 0.0, -0.02]);
        for k in 0..400 {
            let u = excitation(k);
            let y = plant.step(&u).to_vec();
            let est = &block.estimate_map * DVector::from_column_slice(lti.state());
            let scale = est.amax().max(1e-12);
            for (a, b) in est.iter().zip(run.estimate()) {
                assert!((a - b).abs() <= 1e-12 * scale, "{k}: {a} vs {b}");
            }
            // ŷ_flex = C_f x̂(k|k−1), u_d = K_AD x̂(k+1|k).
            let out = lti.step(&[y[0], y[1], u[0], u[1]]).to_vec();
            let x = run.step(&y, &u).unwrap().to_vec();
            let x = DVector::from_column_slice(&x);
            let yf = &cf * DVector::from_column_slice(&est.as_slice()[..8]);
            let ud = &ad_gain * &x;
            for (a, b) in out.iter().zip(yf.iter().chain(ud.iter())) {
                assert!((a - b).abs() <= 1e-12 * scale, "{k}: {a} vs {b}");
            }
        }
        // AD that does not read the model's states is refused.
        let wrong = DiscreteStateSpace::gain(DMatrix::zeros(2, 16), model.ts).unwrap();
        assert!(obs.compile(None, Some(&wrong), 0).is_err());
    }

    #[test]
    fn refuses_bad_filters_and_inputs() {
        let model = joint();
        // K(z) with the wrong input count.
        let bad = DiscreteStateSpace::gain(DMatrix::zeros(8, 3), model.ts).unwrap();
        assert!(matches!(
            IoObserver::state_correction(model.clone(), bad),
            Err(DesignError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
        // No correction at all: the rigid modes make the error dynamics
        // marginally stable, which is refused.
        let none = DiscreteStateSpace::gain(DMatrix::zeros(8, 2), model.ts).unwrap();
        assert!(matches!(
            IoObserver::state_correction(model.clone(), none),
            Err(DesignError::Unstable(_))
        ));
        let l = kalman_gain(&model);
        let obs = IoObserver::state_correction(
            model.clone(),
            DiscreteStateSpace::gain(l, model.ts).unwrap(),
        )
        .unwrap();
        let mut run = obs.runner();
        assert_eq!(
            run.step(&[0.0], &[0.0, 0.0]),
            Err(StepError::Length {
                what: "y",
                expected: 2,
                found: 1
            })
        );
        assert_eq!(
            run.step(&[0.0, f64::NAN], &[0.0, 0.0]),
            Err(StepError::NonFinite("y"))
        );
        assert!(run.estimate().iter().all(|v| *v == 0.0));
    }
}
