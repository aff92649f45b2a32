//! Allocation-free dense kernels for per-sample filter updates.

use crate::step_error::StepError;
use nalgebra::DMatrix;

/// out = α A B + β out, column by column with gemv. nalgebra's `gemm` hands
/// dynamic matrices larger than 5×5 to `matrixmultiply`, which allocates
/// packing buffers; this stays on the allocation-free path.
pub(crate) fn mul_into(
    out: &mut DMatrix<f64>,
    alpha: f64,
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    beta: f64,
) {
    for j in 0..b.ncols() {
        out.column_mut(j).gemv(alpha, a, &b.column(j), beta);
    }
}

/// Solves S X = B in place (X overwrites B) by a Cholesky factorisation that
/// overwrites the lower triangle of S. No allocation: the innovation
/// covariance is small (n_y × n_y) and factorised every sample.
pub(crate) fn cholesky_solve_in_place(
    s: &mut DMatrix<f64>,
    b: &mut DMatrix<f64>,
) -> Result<(), StepError> {
    let p = s.nrows();
    for j in 0..p {
        let mut d = s[(j, j)];
        for k in 0..j {
            d -= s[(j, k)] * s[(j, k)];
        }
        if !(d > 0.0 && d.is_finite()) {
            return Err(StepError::NotPositiveDefinite(
                "innovation covariance C P Cᵀ + R",
            ));
        }
        let d = d.sqrt();
        s[(j, j)] = d;
        for i in j + 1..p {
            let mut v = s[(i, j)];
            for k in 0..j {
                v -= s[(i, k)] * s[(j, k)];
            }
            s[(i, j)] = v / d;
        }
    }
    for col in 0..b.ncols() {
        // Forward: L z = b; backward: Lᵀ x = z.
        for i in 0..p {
            let mut v = b[(i, col)];
            for k in 0..i {
                v -= s[(i, k)] * b[(k, col)];
            }
            b[(i, col)] = v / s[(i, i)];
        }
        for i in (0..p).rev() {
            let mut v = b[(i, col)];
            for k in i + 1..p {
                v -= s[(k, i)] * b[(k, col)];
            }
            b[(i, col)] = v / s[(i, i)];
        }
    }
    Ok(())
}

/// The Kalman filter's covariance time update in place:
/// P ← A (P − M C P) Aᵀ + W, then symmetrised. `cp` holds C P and `gain_m`
/// the measurement-update gain M; `posterior` and `scratch` are n×n work space.
#[allow(clippy::too_many_arguments)]
pub(crate) fn propagate_covariance(
    p: &mut DMatrix<f64>,
    a: &DMatrix<f64>,
    a_t: &DMatrix<f64>,
    gain_m: &DMatrix<f64>,
    cp: &DMatrix<f64>,
    process_noise: &DMatrix<f64>,
    posterior: &mut DMatrix<f64>,
    scratch: &mut DMatrix<f64>,
) {
    posterior.copy_from(p);
    mul_into(posterior, -1.0, gain_m, cp, 1.0);
    mul_into(scratch, 1.0, a, posterior, 0.0);
    p.copy_from(process_noise);
    mul_into(p, 1.0, scratch, a_t, 1.0);
    let n = p.nrows();
    for i in 0..n {
        for j in i + 1..n {
            let v = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = v;
            p[(j, i)] = v;
        }
    }
}
