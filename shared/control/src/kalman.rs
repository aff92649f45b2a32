//! Discrete Kalman filter design: steady-state gains from the DARE,
//! predictor and filter forms, the time-varying Riccati step, and the
//! noise-model (PI observer) augmentation that keeps integral action with
//! measurement compensation (docs/control.md §3, §4.1–§4.3).
//!
//! Model: x(k+1) = A x + B u + G w, y = C x + D u + v, with D = T_DC
//! (compliance of discarded modes), E[wwᵀ] = Q, E[vvᵀ] = R.
//!
//! # Units of the weights (continuous thesis values vs per-sample values)
//! The thesis designs in continuous time with intensities Q_c = σ_w²,
//! R_c = σ_v² + σ_d² and the noise-model intensity Q_ν (docs/control.md §4). The
//! exact sampled equivalent of those intensities is, to first order in Ts,
//! (B Q_c Bᵀ Ts, R_c / Ts, Q_ν Ts); a Kalman gain does not change when all
//! weights are multiplied by one number, so multiplying by Ts gives the
//! equivalent (B Q_c Bᵀ Ts², R_c, Q_ν Ts²). [`KalmanWeights::thesis`]
//! (G = B_d ≈ B Ts on the velocity states, Q = σ_w², R = σ_v² + σ_d²) is
//! exactly that scaling for w and v, so the noise model must get the same
//! factor: per-sample Q_ν,d = Q_ν Ts² ([`NoiseModel::thesis`]). Using the
//! thesis' Q_ν = 0.03 or 10³ unscaled as a per-sample covariance makes the
//! integrator state 10⁸ times (at 10 kHz) too strong relative to w and v, and
//! was the reason earlier discrete MC and MC+AD bandwidths missed docs/control.md
//! §10.1 (MC+AD had no feasible bandwidth at all).
//!
//! The continuous design itself ([`steady_state_kalman_continuous`], CARE
//! by the Hamiltonian sign function plus Newton–Kleinman refinement) is
//! used for the continuous bandwidth checks of docs/control.md §9.

use crate::continuous::ContinuousStateSpace;
use crate::dare::solve_dare;
use crate::design_error::{DesignError, check_matrix};
use crate::linalg::{LinalgError, balance, block_diag, eigenvalues, spectral_radius};
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
    /// The thesis weights (docs/control.md §4.1): G = B (w enters like the
    /// actuator force), Q = σ_w² I, R = (σ_v² + σ_d²) I = 2e-18 I.
    pub fn thesis(model: &DiscreteStateSpace) -> Self {
        let (m, p) = (model.inputs(), model.outputs());
        Self {
            g: model.b.clone(),
            q: DMatrix::identity(m, m) * SIGMA_W * SIGMA_W,
            r: DMatrix::identity(p, p) * (SIGMA_V * SIGMA_V + SIGMA_D * SIGMA_D),
        }
    }

    /// The thesis weights for a continuous model, as intensities: G = B,
    /// Q = σ_w² I, R = (σ_v² + σ_d²) I (docs/control.md §4.1).
    pub fn thesis_continuous(model: &ContinuousStateSpace) -> Self {
        let (m, p) = (model.inputs(), model.outputs());
        Self {
            g: model.b.clone(),
            q: DMatrix::identity(m, m) * SIGMA_W * SIGMA_W,
            r: DMatrix::identity(p, p) * (SIGMA_V * SIGMA_V + SIGMA_D * SIGMA_D),
        }
    }

    fn check(&self, model: &DiscreteStateSpace) -> Result<(), DesignError> {
        self.check_dims(model.states(), model.outputs())
    }

    fn check_dims(&self, n: usize, outputs: usize) -> Result<(), DesignError> {
        check_matrix(&self.g, "G", n, self.g.ncols())?;
        check_matrix(&self.q, "Q", self.g.ncols(), self.g.ncols())?;
        check_matrix(&self.r, "R", outputs, outputs)?;
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
/// (docs/control.md (3.14), §4.3): z(k+1) = z(k) + Q_ν^{1/2} ν, entering the
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
    /// U = B_t, per-sample covariance Q_ν = q_nu I, taken as given. For the
    /// thesis values (0.03, 10³), which are continuous intensities, use
    /// [`NoiseModel::thesis`] instead (module doc).
    pub fn on_inputs(model: &DiscreteStateSpace, q_nu: f64) -> Self {
        let m = model.inputs();
        Self {
            u: model.b.clone(),
            q_nu: DMatrix::identity(m, m) * q_nu,
        }
    }

    /// U = B_t with the thesis' continuous intensity `q_nu` (0.03 or 10³)
    /// converted to the per-sample covariance that matches
    /// [`KalmanWeights::thesis`]: Q_ν,d = q_nu Ts² I (module doc). This
    /// reproduces the discrete bandwidths of docs/control.md §10.1.
    pub fn thesis(model: &DiscreteStateSpace, q_nu: f64) -> Self {
        Self::on_inputs(model, q_nu * model.ts * model.ts)
    }

    /// U = B_t, intensity Q_ν = q_nu I, for a continuous model
    /// ([`with_noise_model_continuous`]).
    pub fn on_continuous_inputs(model: &ContinuousStateSpace, q_nu: f64) -> Self {
        let m = model.inputs();
        Self {
            u: model.b.clone(),
            q_nu: DMatrix::identity(m, m) * q_nu,
        }
    }

    fn sqrt_q(&self, n: usize) -> Result<DMatrix<f64>, DesignError> {
        let nz = self.u.ncols();
        check_matrix(&self.u, "U", n, nz)?;
        check_matrix(&self.q_nu, "Q_nu", nz, nz)?;
        Ok(self
            .q_nu
            .clone()
            .cholesky()
            .ok_or_else(|| DesignError::InvalidParameter("Q_nu must be positive definite".into()))?
            .l())
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
    let sqrt_q = noise.sqrt_q(n)?;
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

/// Continuous noise-model augmentation (3.14): A_o = [[A, U], [0, 0]],
/// B_o = [B; 0], C_o = [C 0], D unchanged, G_o = blockdiag(G, Q_ν^{1/2}),
/// Q_o = blockdiag(Q, I) (intensities). The extra states come last.
pub fn with_noise_model_continuous(
    model: &ContinuousStateSpace,
    weights: &KalmanWeights,
    noise: &NoiseModel,
) -> Result<(ContinuousStateSpace, KalmanWeights), DesignError> {
    let n = model.states();
    weights.check_dims(n, model.outputs())?;
    let nz = noise.u.ncols();
    let sqrt_q = noise.sqrt_q(n)?;
    let mut a = DMatrix::zeros(n + nz, n + nz);
    a.view_mut((0, 0), (n, n)).copy_from(&model.a);
    a.view_mut((0, n), (n, nz)).copy_from(&noise.u);
    let mut b = DMatrix::zeros(n + nz, model.inputs());
    b.view_mut((0, 0), (n, model.inputs())).copy_from(&model.b);
    let mut c = DMatrix::zeros(model.outputs(), n + nz);
    c.view_mut((0, 0), (model.outputs(), n)).copy_from(&model.c);
    let aug = ContinuousStateSpace::new(a, b, c, model.d.clone())?;
    let w = KalmanWeights {
        g: block_diag(&[&weights.g, &sqrt_q]),
        q: block_diag(&[&weights.q, &DMatrix::identity(nz, nz)]),
        r: weights.r.clone(),
    };
    Ok((aug, w))
}

/// Steady-state continuous Kalman filter (docs/control.md (3.3)).
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousKalmanGains {
    /// P from A P + P Aᵀ + G Q Gᵀ − P Cᵀ R⁻¹ C P = 0 (stabilising solution).
    pub p: DMatrix<f64>,
    /// L = P Cᵀ R⁻¹: x̂̇ = (A − L C) x̂ + (B − L D) u + L y.
    pub l: DMatrix<f64>,
    /// Relative CARE residual (in the scaled coordinates of the solver).
    pub residual: f64,
    /// Largest real part of eig(A − L C) [1/s] (negative).
    pub abscissa: f64,
}

/// Largest relative CARE residual accepted.
const MAX_CARE_RESIDUAL: f64 = 1e-8;

/// Steady-state continuous Kalman gain from the filter CARE.
///
/// Method: R normalised to I; diagonal state scaling from balancing A (modal
/// positions and velocities differ by ω); P scaled so that ‖C̃ᵀC̃‖ and ‖W̃‖
/// balance; stable invariant subspace of the Hamiltonian by the matrix sign
/// function (Newton with determinant scaling); then up to four
/// Newton–Kleinman steps (Lyapunov solves) to polish. Errors, never panics:
/// non-finite or mis-shaped input, R not positive definite, no convergence,
/// no stabilising solution (not detectable), or a large residual.
pub fn steady_state_kalman_continuous(
    model: &ContinuousStateSpace,
    weights: &KalmanWeights,
) -> Result<ContinuousKalmanGains, DesignError> {
    let n = model.states();
    weights.check_dims(n, model.outputs())?;
    check_matrix(&model.a, "A", n, n)?;
    check_matrix(&model.c, "C", model.outputs(), n)?;
    if n == 0 {
        return Err(DesignError::InvalidParameter(
            "Kalman filter of a model without states".into(),
        ));
    }
    let w = &weights.g * &weights.q * weights.g.transpose();
    let w = (&w + w.transpose()) * 0.5;
    let r = (&weights.r + weights.r.transpose()) * 0.5;
    let lr = r
        .clone()
        .cholesky()
        .ok_or_else(|| DesignError::InvalidParameter("R must be positive definite".into()))?
        .l();
    let c1 = lr
        .solve_lower_triangular(&model.c)
        .ok_or(LinalgError::Singular("Cholesky factor of R"))?;
    // x = T x̃, T diagonal from balancing A.
    let (_, t) = balance(&model.a)?;
    let a2 = DMatrix::from_fn(n, n, |i, j| model.a[(i, j)] * t[j] / t[i]);
    let c2 = DMatrix::from_fn(c1.nrows(), n, |i, j| c1[(i, j)] * t[j]);
    let w2 = DMatrix::from_fn(n, n, |i, j| w[(i, j)] / (t[i] * t[j]));
    let g2 = c2.transpose() * &c2;
    let (gn, wn) = (g2.norm(), w2.norm());
    let sigma = if gn > 0.0 && wn > 0.0 {
        (wn / gn).sqrt()
    } else {
        1.0
    };
    // Scaled CARE in control form: Acᵀ Y + Y Ac − Y G Y + H = 0, with
    // Ac = Ãᵀ, G = σ C̃ᵀC̃, H = W̃/σ, and P̃ = σ Y.
    let ac = a2.transpose();
    let gs = &g2 * sigma;
    let hs = &w2 / sigma;
    let mut y = care_sign(&ac, &gs, &hs)?;
    let mut residual = care_residual(&ac, &gs, &hs, &y);
    for _ in 0..4 {
        if residual < 1e-14 {
            break;
        }
        let Ok(next) = newton_kleinman_step(&ac, &gs, &hs, &y) else {
            break;
        };
        let res = care_residual(&ac, &gs, &hs, &next);
        if res < residual {
            y = next;
            residual = res;
        } else {
            break;
        }
    }
    if !residual.is_finite() || residual > MAX_CARE_RESIDUAL {
        return Err(
            LinalgError::NoConvergence("continuous Riccati equation (residual too large)").into(),
        );
    }
    let p = DMatrix::from_fn(n, n, |i, j| sigma * y[(i, j)] * t[i] * t[j]);
    let p = (&p + p.transpose()) * 0.5;
    // L = P Cᵀ R⁻¹ = P C1ᵀ Lr⁻¹.
    let pc1 = &p * c1.transpose();
    let l = lr
        .transpose()
        .solve_upper_triangular(&pc1.transpose())
        .ok_or(LinalgError::Singular("Cholesky factor of R"))?
        .transpose();
    if l.iter().any(|v| !v.is_finite()) {
        return Err(LinalgError::NonFinite.into());
    }
    let abscissa = eigenvalues(&(&model.a - &l * &model.c))?
        .iter()
        .map(|s| s.re)
        .fold(f64::NEG_INFINITY, f64::max);
    if abscissa >= 0.0 {
        return Err(DesignError::Unstable(format!(
            "continuous Kalman filter A − L C has an eigenvalue with real part {abscissa}"
        )));
    }
    Ok(ContinuousKalmanGains {
        p,
        l,
        residual,
        abscissa,
    })
}

fn care_residual(ac: &DMatrix<f64>, g: &DMatrix<f64>, h: &DMatrix<f64>, y: &DMatrix<f64>) -> f64 {
    let aty = ac.transpose() * y;
    let ygy = y * g * y;
    let res = &aty + aty.transpose() - &ygy + h;
    let scale = 2.0 * aty.norm() + ygy.norm() + h.norm();
    let r = res.norm() / scale.max(f64::MIN_POSITIVE);
    if r.is_finite() { r } else { f64::INFINITY }
}

/// Stabilising solution of Acᵀ Y + Y Ac − Y G Y + H = 0 from the sign of the
/// Hamiltonian [[Ac, −G], [−H, −Acᵀ]].
fn care_sign(
    ac: &DMatrix<f64>,
    g: &DMatrix<f64>,
    h: &DMatrix<f64>,
) -> Result<DMatrix<f64>, DesignError> {
    let n = ac.nrows();
    let nn = 2 * n;
    let mut z = DMatrix::zeros(nn, nn);
    z.view_mut((0, 0), (n, n)).copy_from(ac);
    z.view_mut((0, n), (n, n)).copy_from(&(-g));
    z.view_mut((n, 0), (n, n)).copy_from(&(-h));
    z.view_mut((n, n), (n, n)).copy_from(&(-ac.transpose()));
    let mut converged = false;
    for it in 0..100 {
        let lu = z.clone().lu();
        let log_det: f64 = lu.u().diagonal().iter().map(|v| v.abs().ln()).sum();
        let inv = lu.try_inverse().ok_or(LinalgError::Singular(
            "Hamiltonian (eigenvalue on the imaginary axis?)",
        ))?;
        // Determinant scaling while far from convergence.
        let c = if it < 30 {
            (log_det / nn as f64).exp()
        } else {
            1.0
        };
        if !c.is_finite() || c <= 0.0 {
            return Err(LinalgError::NonFinite.into());
        }
        let next = (&z / c + inv * c) * 0.5;
        if next.iter().any(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite.into());
        }
        let change = (&next - &z).norm() / next.norm();
        z = next;
        if change < 1e-12 {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(LinalgError::NoConvergence("matrix sign function of the Hamiltonian").into());
    }
    // [Z12; Z22 + I] Y = −[Z11 + I; Z21] (least squares).
    let mut m = DMatrix::zeros(nn, n);
    m.view_mut((0, 0), (n, n))
        .copy_from(&z.view((0, n), (n, n)));
    m.view_mut((n, 0), (n, n))
        .copy_from(&(z.view((n, n), (n, n)) + DMatrix::<f64>::identity(n, n)));
    let mut rhs = DMatrix::zeros(nn, n);
    rhs.view_mut((0, 0), (n, n))
        .copy_from(&(-(z.view((0, 0), (n, n)) + DMatrix::<f64>::identity(n, n))));
    rhs.view_mut((n, 0), (n, n))
        .copy_from(&(-z.view((n, 0), (n, n))));
    let svd = m
        .try_svd(true, true, f64::EPSILON, 1000 * nn)
        .ok_or(LinalgError::NoConvergence("SVD"))?;
    let y = svd
        .solve(&rhs, f64::EPSILON * nn as f64)
        .map_err(|_| LinalgError::NoConvergence("SVD least squares"))?;
    let y = (&y + y.transpose()) * 0.5;
    if y.iter().any(|v| !v.is_finite()) {
        return Err(LinalgError::NonFinite.into());
    }
    Ok(y)
}

/// One Newton–Kleinman step: with F = Ac − G Y, solve
/// Fᵀ Y' + Y' F + Y G Y + H = 0 (Kronecker form; n ≤ a few tens).
fn newton_kleinman_step(
    ac: &DMatrix<f64>,
    g: &DMatrix<f64>,
    h: &DMatrix<f64>,
    y: &DMatrix<f64>,
) -> Result<DMatrix<f64>, DesignError> {
    let n = ac.nrows();
    let f = ac - g * y;
    let ft = f.transpose();
    let id = DMatrix::<f64>::identity(n, n);
    // vec(Fᵀ X + X F) = (I ⊗ Fᵀ + Fᵀ ⊗ I) vec(X) (column-major vec).
    let k = id.kronecker(&ft) + ft.kronecker(&id);
    let rhs = -(y * g * y + h);
    let v = DMatrix::from_column_slice(n * n, 1, rhs.as_slice());
    let x = crate::linalg::solve(&k, &v, "Lyapunov operator")?;
    let x = DMatrix::from_column_slice(n, n, x.as_slice());
    Ok((&x + x.transpose()) * 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dare::dare_residual;
    use crate::discretise::zoh;
    use crate::linalg::{discrete_pole_to_continuous, eigenvalues};
    use crate::matrix_error::MatrixError;
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
        // Observer poles (docs/control.md §4.1, y5): rigid pair ≈ 119 Hz with ζ ≈ 0.73;
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
            Err(DesignError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
    }

    /// (frequency [Hz], damping) of continuous poles, upper half-plane.
    fn continuous_modes(a: &DMatrix<f64>) -> Vec<(f64, f64)> {
        eigenvalues(a)
            .unwrap()
            .iter()
            .filter(|s| s.im >= 0.0)
            .map(|s| (s.norm() / (2.0 * std::f64::consts::PI), -s.re / s.norm()))
            .collect()
    }

    fn discrete_modes(a: &DMatrix<f64>, ts: f64) -> Vec<(f64, f64)> {
        eigenvalues(a)
            .unwrap()
            .iter()
            .filter(|z| z.im >= 0.0)
            .map(|z| discrete_pole_to_continuous(*z, ts))
            .map(|(w, z)| (w / (2.0 * std::f64::consts::PI), z))
            .collect()
    }

    fn nearest(poles: &[(f64, f64)], f: f64) -> (f64, f64) {
        *poles
            .iter()
            .min_by(|a, b| (a.0 - f).abs().total_cmp(&(b.0 - f).abs()))
            .unwrap()
    }

    #[test]
    fn continuous_thesis_kalman_matches_control_md_4_1() {
        let model = thesis_reduced(5).unwrap().state_space();
        let w = KalmanWeights::thesis_continuous(&model);
        let k = steady_state_kalman_continuous(&model, &w).unwrap();
        assert!(k.residual < 1e-10, "{}", k.residual);
        assert!(k.abscissa < 0.0);
        // Unscaled residual of A P + P Aᵀ + W − P Cᵀ R⁻¹ C P, relative.
        let gq = &w.g * &w.q * w.g.transpose();
        let pct = &k.p * model.c.transpose();
        let res = &model.a * &k.p + &k.p * model.a.transpose() + &gq
            - &pct * w.r.clone().try_inverse().unwrap() * pct.transpose();
        let scale = (&model.a * &k.p).norm() + gq.norm();
        assert!(res.norm() < 1e-8 * scale, "{}", res.norm() / scale);
        // §4.1: rigid pair 119 Hz ζ 0.73, mode 1 at 472 Hz ζ 0.037, modes
        // 2 and 3 nearly unchanged (ζ ≈ 0.006).
        let poles = continuous_modes(&(&model.a - &k.l * &model.c));
        let (f, z) = nearest(&poles, 119.0);
        assert!(
            (f - 119.0).abs() < 3.0 && (z - 0.73).abs() < 0.03,
            "{f} {z}"
        );
        let (f, z) = nearest(&poles, 472.0);
        assert!(
            (f - 472.0).abs() < 3.0 && (z - 0.037).abs() < 0.004,
            "{f} {z}"
        );
        for f0 in [941.88, 1396.06] {
            let (f, z) = nearest(&poles, f0);
            assert!((f - f0).abs() < 0.01 * f0 && z < 0.01, "{f} {z}");
        }
        // The discrete thesis design at 10 kHz has the same poles (weights
        // scaled consistently, module doc).
        let dmodel = thesis_model();
        let kd = steady_state_kalman(&dmodel, &KalmanWeights::thesis(&dmodel)).unwrap();
        let dpoles = discrete_modes(&(&dmodel.a - &kd.l * &dmodel.c), TS_10KHZ);
        for (f, z) in poles {
            let (fd, zd) = nearest(&dpoles, f);
            assert!(
                (fd - f).abs() < 0.01 * f && (zd - z).abs() < 0.01,
                "{f} {z} vs {fd} {zd}"
            );
        }
    }

    #[test]
    fn noise_model_scaling_matches_the_continuous_design() {
        // The continuous noise-model observer (thesis Q_ν) and the discrete
        // one with Q_ν Ts² per sample have the same poles; the unscaled
        // per-sample Q_ν does not (the bug behind the old §10.1 mismatch).
        let cmodel = thesis_reduced(5).unwrap().state_space();
        let dmodel = thesis_model();
        for q_nu in [0.03, 1e3] {
            let (ca, cw) = with_noise_model_continuous(
                &cmodel,
                &KalmanWeights::thesis_continuous(&cmodel),
                &NoiseModel::on_continuous_inputs(&cmodel, q_nu),
            )
            .unwrap();
            let kc = steady_state_kalman_continuous(&ca, &cw).unwrap();
            let cpoles = continuous_modes(&(&ca.a - &kc.l * &ca.c));
            let dw = KalmanWeights::thesis(&dmodel);
            let check = |noise: NoiseModel| {
                let (da, dw) = with_noise_model(&dmodel, &dw, &noise).unwrap();
                let kd = steady_state_kalman(&da, &dw).unwrap();
                let dpoles = discrete_modes(&(&da.a - &kd.l * &da.c), TS_10KHZ);
                cpoles
                    .iter()
                    .map(|&(f, _)| (nearest(&dpoles, f).0 - f).abs() / f)
                    .fold(0.0, f64::max)
            };
            let scaled = check(NoiseModel::thesis(&dmodel, q_nu));
            let unscaled = check(NoiseModel::on_inputs(&dmodel, q_nu));
            assert!(scaled < 0.01, "Q_ν {q_nu}: scaled error {scaled}");
            assert!(unscaled > 0.1, "Q_ν {q_nu}: unscaled error {unscaled}");
        }
    }

    #[test]
    fn continuous_kalman_rejects_bad_input() {
        let model = thesis_reduced(5).unwrap().state_space();
        let w = KalmanWeights::thesis_continuous(&model);
        let mut bad = model.clone();
        bad.c.fill(0.0);
        assert!(steady_state_kalman_continuous(&bad, &w).is_err());
        let mut nan = model.clone();
        nan.a[(1, 0)] = f64::NAN;
        assert!(steady_state_kalman_continuous(&nan, &w).is_err());
        let wr = KalmanWeights {
            r: DMatrix::from_element(1, 1, -1.0),
            ..w.clone()
        };
        assert!(matches!(
            steady_state_kalman_continuous(&model, &wr),
            Err(DesignError::InvalidParameter(_))
        ));
        assert!(
            with_noise_model_continuous(
                &model,
                &w,
                &NoiseModel::on_continuous_inputs(&model, -1.0)
            )
            .is_err()
        );
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
