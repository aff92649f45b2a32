//! Discrete Kalman filter design: steady-state gains from the DARE,
//! predictor and filter forms, the time-varying Riccati step, and the
//! noise-model (PI observer) augmentation that keeps integral action with
//! measurement compensation (control.md §3, §4.1–§4.3).
//!
//! Model: x(k+1) = A x + B u + G w, y = C x + D u + v, with D = T_DC
//! (compliance of discarded modes), E[wwᵀ] = Q, E[vvᵀ] = R.

use crate::dare::solve_dare;
use crate::design_error::{DesignError, check_matrix};
use crate::linalg::{block_diag, spectral_radius};
use crate::lti::DiscreteStateSpace;
use crate::models::{SIGMA_D, SIGMA_V, SIGMA_W};
use nalgebra::DMatrix;

/// Noise weights of a Kalman design.
#[derive(Debug, Clone, PartialEq)]
pub struct KalmanWeights {
    /// G: how the process noise w enters the state (n × n_w).
    pub g: DMatrix<f64>,
    /// Q = E[w wᵀ] per sample (n_w × n_w).
    pub q: DMatrix<f64>,
    /// R = E[v vᵀ] (n_y × n_y).
    pub r: DMatrix<f64>,
}

impl KalmanWeights {
    /// The thesis weights (control.md §4.1): G = B (w enters like the
    /// actuator force), Q = σ_w² I, R = (σ_v² + σ_d²) I = 2e-18 I.
    pub fn thesis(model: &DiscreteStateSpace) -> Self {
        let (m, p) = (model.inputs(), model.outputs());
        Self {
            g: model.b.clone(),
            q: DMatrix::identity(m, m) * SIGMA_W * SIGMA_W,
            r: DMatrix::identity(p, p) * (SIGMA_V * SIGMA_V + SIGMA_D * SIGMA_D),
        }
    }

    fn check(&self, model: &DiscreteStateSpace) -> Result<(), DesignError> {
        let n = model.states();
        check_matrix(&self.g, "G", n, self.g.ncols())?;
        check_matrix(&self.q, "Q", self.g.ncols(), self.g.ncols())?;
        check_matrix(&self.r, "R", model.outputs(), model.outputs())?;
        Ok(())
    }
}

/// Steady-state Kalman gains.
#[derive(Debug, Clone, PartialEq)]
pub struct KalmanGains {
    /// Prior covariance P = P(k|k−1) (DARE solution).
    pub p: DMatrix<f64>,
    /// Predictor gain L = A P Cᵀ (C P Cᵀ + R)⁻¹:
    /// x̂(k+1|k) = (A − L C) x̂(k|k−1) + (B − L D) u(k) + L y(k).
    pub l: DMatrix<f64>,
    /// Filter gain M = P Cᵀ (C P Cᵀ + R)⁻¹:
    /// x̂(k|k) = x̂(k|k−1) + M (y(k) − C x̂(k|k−1) − D u(k)).
    pub m: DMatrix<f64>,
    /// Relative DARE residual.
    pub residual: f64,
    /// Spectral radius of A − L C.
    pub radius: f64,
}

/// Steady-state Kalman filter from the dual DARE.
pub fn steady_state_kalman(
    model: &DiscreteStateSpace,
    weights: &KalmanWeights,
) -> Result<KalmanGains, DesignError> {
    weights.check(model)?;
    let w = &weights.g * &weights.q * weights.g.transpose();
    let w = (&w + w.transpose()) * 0.5;
    let sol = solve_dare(&model.a.transpose(), &model.c.transpose(), &w, &weights.r)?;
    let p = sol.x;
    let s = &model.c * &p * model.c.transpose() + &weights.r;
    let pct = &p * model.c.transpose();
    let m = s
        .clone()
        .lu()
        .solve(&pct.transpose())
        .ok_or(crate::linalg::LinalgError::Singular("C P Cᵀ + R"))?
        .transpose();
    let l = &model.a * &m;
    let radius = spectral_radius(&(&model.a - &l * &model.c))?;
    if radius >= 1.0 {
        return Err(DesignError::Unstable(format!(
            "Kalman predictor A − L C has spectral radius {radius}"
        )));
    }
    Ok(KalmanGains {
        p,
        l,
        m,
        residual: sol.residual,
        radius,
    })
}

/// One step of the time-varying Riccati recursion (4.7)–(4.8), for a
/// scheduled model: returns (P(k+1|k), L(k)) from P(k|k−1).
pub fn riccati_step(
    model: &DiscreteStateSpace,
    weights: &KalmanWeights,
    p: &DMatrix<f64>,
) -> Result<(DMatrix<f64>, DMatrix<f64>), DesignError> {
    weights.check(model)?;
    let n = model.states();
    check_matrix(p, "P", n, n)?;
    let s = &model.c * p * model.c.transpose() + &weights.r;
    let pct = p * model.c.transpose();
    let m = s
        .lu()
        .solve(&pct.transpose())
        .ok_or(crate::linalg::LinalgError::Singular("C P Cᵀ + R"))?
        .transpose();
    let l = &model.a * &m;
    let post = p - &m * &pct.transpose();
    let next =
        &model.a * post * model.a.transpose() + &weights.g * &weights.q * weights.g.transpose();
    Ok(((&next + next.transpose()) * 0.5, l))
}

/// Integrated-noise states z that keep integral action under MC
/// (control.md (3.14), §4.3): z(k+1) = z(k) + Q_ν^{1/2} ν, entering the
/// state through U (U = B_t makes O_yu(1) = 0, Theorem 3.2.4).
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    /// U (n × n_z).
    pub u: DMatrix<f64>,
    /// Q_ν (n_z × n_z), symmetric positive definite; the per-sample
    /// covariance of the increment of z.
    pub q_nu: DMatrix<f64>,
}

impl NoiseModel {
    /// U = B_t, Q_ν = q_nu I (the thesis choice: 0.03 or 10³).
    pub fn on_inputs(model: &DiscreteStateSpace, q_nu: f64) -> Self {
        let m = model.inputs();
        Self {
            u: model.b.clone(),
            q_nu: DMatrix::identity(m, m) * q_nu,
        }
    }
}

/// Augments a model and its weights with a noise model (§4.3):
/// A_o = [[A, U], [0, I]], B_o = [B; 0], C_o = [C 0], D unchanged,
/// G_o = blockdiag(G, Q_ν^{1/2}), Q_o = blockdiag(Q, I). The extra states
/// come last.
pub fn with_noise_model(
    model: &DiscreteStateSpace,
    weights: &KalmanWeights,
    noise: &NoiseModel,
) -> Result<(DiscreteStateSpace, KalmanWeights), DesignError> {
    weights.check(model)?;
    let n = model.states();
    let nz = noise.u.ncols();
    check_matrix(&noise.u, "U", n, nz)?;
    check_matrix(&noise.q_nu, "Q_nu", nz, nz)?;
    let sqrt_q = noise
        .q_nu
        .clone()
        .cholesky()
        .ok_or_else(|| DesignError::InvalidParameter("Q_nu must be positive definite".into()))?
        .l();
    let mut a = block_diag(&[&model.a, &DMatrix::identity(nz, nz)]);
    a.view_mut((0, n), (n, nz)).copy_from(&noise.u);
    let mut b = DMatrix::zeros(n + nz, model.inputs());
    b.view_mut((0, 0), (n, model.inputs())).copy_from(&model.b);
    let mut c = DMatrix::zeros(model.outputs(), n + nz);
    c.view_mut((0, 0), (model.outputs(), n)).copy_from(&model.c);
    let aug = DiscreteStateSpace::new(a, b, c, model.d.clone(), model.ts)?;
    let w = KalmanWeights {
        g: block_diag(&[&weights.g, &sqrt_q]),
        q: block_diag(&[&weights.q, &DMatrix::identity(nz, nz)]),
        r: weights.r.clone(),
    };
    Ok((aug, w))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dare::dare_residual;
    use crate::discretise::zoh;
    use crate::linalg::{discrete_pole_to_continuous, eigenvalues};
    use crate::models::{TS_10KHZ, thesis_reduced};

    fn thesis_model() -> DiscreteStateSpace {
        zoh(&thesis_reduced(5).unwrap().state_space(), TS_10KHZ).unwrap()
    }

    #[test]
    fn thesis_kalman_is_well_solved() {
        let model = thesis_model();
        let w = KalmanWeights::thesis(&model);
        let k = steady_state_kalman(&model, &w).unwrap();
        assert!(k.residual < 1e-10, "residual {}", k.residual);
        assert!(k.radius < 1.0);
        // Residual in original coordinates, relative, for the dual DARE.
        let gq = &w.g * &w.q * w.g.transpose();
        let res = dare_residual(&model.a.transpose(), &model.c.transpose(), &gq, &w.r, &k.p);
        assert!(res < 1e-8, "original-coordinate residual {res}");
        // Riccati recursion started at the DARE solution stays there.
        let (p1, l1) = riccati_step(&model, &w, &k.p).unwrap();
        assert!((&p1 - &k.p).norm() < 1e-6 * k.p.norm());
        assert!((&l1 - &k.l).norm() < 1e-6 * k.l.norm());
        // Observer poles (control.md §4.1, y5): rigid pair ≈ 119 Hz with ζ ≈ 0.73;
        // flexible mode 1 at ≈ 472 Hz with ζ ≈ 0.037.
        let ev = eigenvalues(&(&model.a - &k.l * &model.c)).unwrap();
        let poles: Vec<(f64, f64)> = ev
            .iter()
            .filter(|z| z.im >= 0.0)
            .map(|z| discrete_pole_to_continuous(*z, TS_10KHZ))
            .map(|(w, z)| (w / (2.0 * std::f64::consts::PI), z))
            .collect();
        let near = |f: f64| {
            *poles
                .iter()
                .min_by(|a, b| (a.0 - f).abs().total_cmp(&(b.0 - f).abs()))
                .unwrap()
        };
        let (f_r, z_r) = near(119.0);
        assert!(
            (f_r - 119.0).abs() < 6.0 && (z_r - 0.73).abs() < 0.04,
            "rigid {f_r} {z_r}"
        );
        let (f_1, z_1) = near(472.0);
        assert!(
            (f_1 - 472.0).abs() < 5.0 && (z_1 - 0.037).abs() < 0.006,
            "mode 1 {f_1} {z_1}"
        );
    }

    #[test]
    fn unobservable_pair_is_an_error() {
        let mut model = thesis_model();
        // Measure nothing of the rigid mode or mode 1: not detectable.
        model.c.fill(0.0);
        model.c[(0, 6)] = 0.3;
        let w = KalmanWeights::thesis(&model);
        assert!(steady_state_kalman(&model, &w).is_err());
        let bad = KalmanWeights {
            r: DMatrix::zeros(2, 2),
            ..w
        };
        assert!(matches!(
            steady_state_kalman(&model, &bad),
            Err(DesignError::DimensionMismatch { .. })
        ));
    }

    #[test]
    fn noise_model_augmentation() {
        let model = thesis_model();
        let w = KalmanWeights::thesis(&model);
        let (aug, wa) = with_noise_model(&model, &w, &NoiseModel::on_inputs(&model, 0.03)).unwrap();
        assert_eq!(aug.states(), 9);
        assert_eq!(aug.a[(8, 8)], 1.0);
        assert_eq!(aug.a.view((0, 8), (8, 1)), model.b.columns(0, 1));
        let k = steady_state_kalman(&aug, &wa).unwrap();
        assert!(k.residual < 1e-10);
        assert!(with_noise_model(&model, &w, &NoiseModel::on_inputs(&model, -1.0)).is_err());
    }
}
