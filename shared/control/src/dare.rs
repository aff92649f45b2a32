//! Discrete algebraic Riccati equation (DARE), solved robustly for the badly
//! scaled problems of high-precision motion (Q/R ≈ 10¹⁴ in the thesis).
//!
//! Solves the control-form DARE
//!   X = Aᵀ X A − Aᵀ X B (R + Bᵀ X B)⁻¹ Bᵀ X A + Q
//! (the Kalman filter uses the dual: A → Aᵀ, B → Cᵀ, Q → G Q Gᵀ).
//!
//! Method: (1) normalise R to I with its Cholesky factor; (2) diagonal state
//! scaling from balancing A, so modal position and velocity states are
//! comparable; (3) scale X so that ‖B Bᵀ‖ = ‖Q‖; (4) the structure-preserving
//! doubling algorithm (SDA), which converges quadratically to the stabilising
//! solution; (5) undo the scalings, check the relative residual in the
//! original coordinates and that A − B K is Schur stable.

use crate::linalg::{LinalgError, balance, spectral_radius};
use crate::matrix_error::{MatrixError, check_matrix};
use nalgebra::DMatrix;
use std::fmt;

/// Why the DARE was not solved.
#[derive(Debug, Clone, PartialEq)]
pub enum DareError {
    /// An input does not fit or is not finite.
    Matrix(MatrixError),
    /// R is not symmetric positive definite.
    RNotPositiveDefinite,
    /// Q is not symmetric positive semi-definite.
    QNotPositiveSemiDefinite,
    /// The doubling iteration did not converge (typically (A, B) not
    /// stabilisable or (A, Q) with unobservable modes on the unit circle).
    NoConvergence { iterations: usize },
    /// A solution was found but the closed loop A − B K is not stable: there
    /// is no stabilising solution.
    NotStabilising { spectral_radius: f64 },
    /// The residual of the equation is too large for the solution to be trusted.
    LargeResidual(f64),
    /// A linear-algebra step failed.
    Linalg(LinalgError),
}

impl fmt::Display for DareError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Matrix(e) => write!(f, "DARE: {e}"),
            Self::RNotPositiveDefinite => write!(f, "DARE: R is not positive definite"),
            Self::QNotPositiveSemiDefinite => {
                write!(f, "DARE: Q is not symmetric positive semi-definite")
            }
            Self::NoConvergence { iterations } => write!(
                f,
                "DARE: doubling did not converge in {iterations} iterations (not stabilisable/detectable?)"
            ),
            Self::NotStabilising { spectral_radius } => write!(
                f,
                "DARE: no stabilising solution (closed-loop spectral radius {spectral_radius})"
            ),
            Self::LargeResidual(r) => write!(f, "DARE: relative residual {r:e} too large"),
            Self::Linalg(e) => write!(f, "DARE: {e}"),
        }
    }
}

impl std::error::Error for DareError {}

impl From<LinalgError> for DareError {
    fn from(e: LinalgError) -> Self {
        Self::Linalg(e)
    }
}

/// The stabilising DARE solution and its gain.
#[derive(Debug, Clone, PartialEq)]
pub struct DareSolution {
    /// X (symmetric, positive semi-definite).
    pub x: DMatrix<f64>,
    /// K = (R + Bᵀ X B)⁻¹ Bᵀ X A, so that A − B K is stable.
    pub k: DMatrix<f64>,
    /// ‖X − (Aᵀ X A − … + Q)‖_F relative to ‖X‖_F + ‖Q‖_F + ‖AᵀXA‖_F.
    pub residual: f64,
    /// Spectral radius of A − B K (< 1).
    pub closed_loop_radius: f64,
    /// Doubling iterations used.
    pub iterations: usize,
}

/// Largest relative residual accepted.
pub const MAX_RESIDUAL: f64 = 1e-8;
const MAX_ITERATIONS: usize = 200;

fn check(m: &DMatrix<f64>, what: &'static str, rows: usize, cols: usize) -> Result<(), DareError> {
    check_matrix(m, what, rows, cols).map_err(DareError::Matrix)
}

/// Relative residual of the DARE in the given coordinates.
pub fn dare_residual(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
    x: &DMatrix<f64>,
) -> f64 {
    let atxa = a.transpose() * x * a;
    let s = r + b.transpose() * x * b;
    let btxa = b.transpose() * x * a;
    let Some(sol) = s.clone().lu().solve(&btxa) else {
        return f64::INFINITY;
    };
    let rhs = &atxa - btxa.transpose() * sol + q;
    let res = (x - rhs).norm();
    res / (x.norm() + q.norm() + atxa.norm()).max(f64::MIN_POSITIVE)
}

/// Solves the control-form DARE (see the module doc).
pub fn solve_dare(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<DareSolution, DareError> {
    let n = a.nrows();
    let m = b.ncols();
    check(a, "A", n, n)?;
    check(b, "B", n, m)?;
    check(q, "Q", n, n)?;
    check(r, "R", m, m)?;
    let sym_tol = |x: &DMatrix<f64>| 1e-10 * x.amax().max(f64::MIN_POSITIVE);
    if (q - q.transpose()).amax() > sym_tol(q) {
        return Err(DareError::QNotPositiveSemiDefinite);
    }
    if (r - r.transpose()).amax() > sym_tol(r) {
        return Err(DareError::RNotPositiveDefinite);
    }
    if q.diagonal().iter().any(|v| *v < 0.0) {
        return Err(DareError::QNotPositiveSemiDefinite);
    }
    // (1) R = Lr Lrᵀ, B̃ = B Lr⁻ᵀ so that R̃ = I.
    let lr = r
        .clone()
        .cholesky()
        .ok_or(DareError::RNotPositiveDefinite)?
        .l();
    let lr_inv = lr.try_inverse().ok_or(DareError::RNotPositiveDefinite)?;
    let b1 = b * lr_inv.transpose();
    // (2) x = T x̂ with T from balancing A (T diagonal, powers of two).
    let (_, t) = balance(a)?;
    let tinv = t.map(|v| 1.0 / v);
    let a2 = DMatrix::from_fn(n, n, |i, j| a[(i, j)] * tinv[i] * t[j]);
    let b2 = DMatrix::from_fn(n, m, |i, j| b1[(i, j)] * tinv[i]);
    let q2 = DMatrix::from_fn(n, n, |i, j| q[(i, j)] * t[i] * t[j]);
    // (3) X̂ = s X̄ with s = sqrt(‖Q‖/‖BBᵀ‖).
    let g2 = &b2 * b2.transpose();
    let (gn, qn) = (g2.norm(), q2.norm());
    let s = if gn > 0.0 && qn > 0.0 {
        (qn / gn).sqrt()
    } else {
        1.0
    };
    let mut ak = a2.clone();
    let mut gk = &g2 * s;
    let mut hk = &q2 / s;
    let id = DMatrix::<f64>::identity(n, n);
    // (4) SDA.
    let mut iterations = 0;
    let mut converged = false;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        let w = &id + &gk * &hk;
        let lu = w.lu();
        let wa = lu
            .solve(&ak)
            .ok_or(LinalgError::Singular("I + G H in SDA"))?;
        let wg = lu
            .solve(&gk)
            .ok_or(LinalgError::Singular("I + G H in SDA"))?;
        let a_next = &ak * &wa;
        let g_next = &gk + &ak * &wg * ak.transpose();
        let h_next = &hk + ak.transpose() * &hk * &wa;
        let change = (&h_next - &hk).norm();
        let size = h_next.norm();
        if !size.is_finite() {
            return Err(DareError::NoConvergence { iterations });
        }
        ak = a_next;
        gk = (&g_next + g_next.transpose()) * 0.5;
        hk = (&h_next + h_next.transpose()) * 0.5;
        if change <= 1e-14 * size.max(f64::MIN_POSITIVE) {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(DareError::NoConvergence { iterations });
    }
    // (5) Undo scalings: X = T⁻ᵀ (s X̄) T⁻¹.
    let x = DMatrix::from_fn(n, n, |i, j| hk[(i, j)] * s * tinv[i] * tinv[j]);
    let x = (&x + x.transpose()) * 0.5;
    let sden = r + b.transpose() * &x * b;
    let k = sden
        .lu()
        .solve(&(b.transpose() * &x * a))
        .ok_or(LinalgError::Singular("R + BᵀXB"))?;
    let closed_loop_radius = spectral_radius(&(a - b * &k))?;
    if closed_loop_radius >= 1.0 {
        return Err(DareError::NotStabilising {
            spectral_radius: closed_loop_radius,
        });
    }
    // Residual in the scaled coordinates, where all terms are of similar size;
    // in the original coordinates the entries of X span many decades.
    let residual = dare_residual(
        &a2,
        &(&b2 * s.sqrt()),
        &(&q2 / s),
        &DMatrix::identity(m, m),
        &hk,
    );
    if residual.is_nan() || residual > MAX_RESIDUAL {
        return Err(DareError::LargeResidual(residual));
    }
    Ok(DareSolution {
        x,
        k,
        residual,
        closed_loop_radius,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_dare_matches_closed_form() {
        // x = a² x − a² x² b²/(r + b² x) + q, a = 1.2, b = 1, q = 1, r = 1.
        let a = DMatrix::from_element(1, 1, 1.2);
        let b = DMatrix::from_element(1, 1, 1.0);
        let q = DMatrix::from_element(1, 1, 1.0);
        let r = DMatrix::from_element(1, 1, 1.0);
        let s = solve_dare(&a, &b, &q, &r).unwrap();
        // x² − a² x − q = 0 for b = r = 1 → x = (a² + sqrt(a⁴ + 4))/2.
        let want = (1.44 + (1.44f64 * 1.44 + 4.0).sqrt()) / 2.0;
        assert!((s.x[(0, 0)] - want).abs() < 1e-12);
        assert!(s.residual < 1e-14);
        assert!(dare_residual(&a, &b, &q, &r, &s.x) < 1e-14);
    }

    #[test]
    fn no_stabilising_solution_is_an_error() {
        // Unstable mode not reachable from B.
        let a = DMatrix::from_row_slice(2, 2, &[1.5, 0.0, 0.0, 0.5]);
        let b = DMatrix::from_column_slice(2, 1, &[0.0, 1.0]);
        let q = DMatrix::identity(2, 2);
        let r = DMatrix::from_element(1, 1, 1.0);
        assert!(solve_dare(&a, &b, &q, &r).is_err());
        assert_eq!(
            solve_dare(&a, &b, &q, &DMatrix::from_element(1, 1, 0.0)),
            Err(DareError::RNotPositiveDefinite)
        );
        assert!(matches!(
            solve_dare(&a, &b, &DMatrix::identity(3, 3), &r),
            Err(DareError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
    }
}
