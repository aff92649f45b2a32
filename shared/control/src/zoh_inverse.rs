//! The continuous model behind a discrete one: inverts the exact ZOH of
//! [`crate::discretise::zoh`] (docs/control.md §3, (2.20)) for a user's
//! discrete state space (A_d, B_d) with its sample time.
//!
//! The ZOH is the exponential of the augmented matrix [[A, B], [0, 0]]·ts, so
//! its principal logarithm log [[A_d, B_d], [0, I]] = [[A, B], [0, 0]]·ts. The
//! logarithm is computed by inverse scaling and squaring: balancing, then
//! square roots (Denman–Beavers, product form) until the matrix is within
//! [`ROOT_TARGET`] of I, then the series log(I + X) = 2 atanh(X (2I + X)⁻¹)
//! summed until its remainder bound is below rounding, times 2^s.
//!
//! Only the principal logarithm is real and unique: A_d may have no
//! eigenvalue at 0 or on the negative real axis, and a continuous mode above
//! Nyquist (|ω| ts > π) comes back aliased below it, as from any sampled data.

use crate::linalg::{balance, eigenvalues};
use crate::plant_model_error::{PlantModelError, PlantModelReason as R, check_array};
use nalgebra::DMatrix;

/// Square roots are taken until ‖E^(1/2^s) − I‖₁ ≤ this; the atanh series
/// then converges like (ROOT_TARGET/2)^(2j+1).
pub const ROOT_TARGET: f64 = 0.25;
/// At most this many square roots (each halves ‖log E‖; 64 covers any
/// finite matrix).
const MAX_ROOTS: usize = 64;
/// Denman–Beavers iterations per square root (quadratic convergence: about
/// 6–10 suffice; the bound only stops a run-away).
const MAX_DB_ITERATIONS: usize = 100;
/// Series terms at most (at ‖Z‖ ≤ 1/7 the remainder is below 1e-17 after 10).
const MAX_SERIES_TERMS: usize = 100;
/// An eigenvalue of A_d whose |Im| is at most this fraction of |λ| and whose
/// real part is negative lies on the negative real axis; |λ| at most this
/// is zero.
const AXIS_TOL: f64 = 1e-12;

/// (A, B) with A_d = e^{A ts}, B_d = ∫₀^ts e^{Aτ} dτ B (A_d n×n, B_d n×m).
/// Errors name "A" (A_d's shape, finiteness, an eigenvalue with no real
/// logarithm), "B" or "ts".
pub fn continuous_from_zoh(
    a_d: &DMatrix<f64>,
    b_d: &DMatrix<f64>,
    ts: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), PlantModelError> {
    if !(ts.is_finite() && ts > 0.0) {
        return Err(PlantModelError::new(
            "ts",
            R::OutOfRange(format!("sample time {ts} is not positive and finite")),
        ));
    }
    let n = a_d.nrows();
    check_array(a_d, "A", n, n)?;
    let m = b_d.ncols();
    check_array(b_d, "B", n, m)?;
    let eig = eigenvalues(a_d).map_err(|_| {
        PlantModelError::new("A", R::NoConvergence("eigenvalues of the discrete A"))
    })?;
    for l in eig {
        let r = l.norm();
        if r <= AXIS_TOL || (l.re < 0.0 && l.im.abs() <= AXIS_TOL * r) {
            return Err(PlantModelError::new(
                "A",
                R::NoRealLogarithm { re: l.re, im: l.im },
            ));
        }
    }
    let mut aug = DMatrix::identity(n + m, n + m);
    aug.view_mut((0, 0), (n, n)).copy_from(a_d);
    aug.view_mut((0, n), (n, m)).copy_from(b_d);
    let log = real_logm(&aug)?;
    let a = log.view((0, 0), (n, n)) / ts;
    let b = log.view((0, n), (n, m)) / ts;
    Ok((a, b))
}

/// Principal logarithm of a real matrix with no eigenvalue on the closed
/// negative real axis (checked by the caller).
fn real_logm(e: &DMatrix<f64>) -> Result<DMatrix<f64>, PlantModelError> {
    let n = e.nrows();
    let fail = |what| PlantModelError::new("A", R::NoConvergence(what));
    // log(D⁻¹ E D) = D⁻¹ log(E) D.
    let (mut x, d) = balance(e).map_err(|_| fail("balancing"))?;
    let id = DMatrix::<f64>::identity(n, n);
    let mut roots = 0;
    while norm1(&(&x - &id)) > ROOT_TARGET {
        if roots == MAX_ROOTS {
            return Err(fail("matrix logarithm (square roots)"));
        }
        x = sqrtm_db(&x).ok_or_else(|| fail("Denman–Beavers square root"))?;
        roots += 1;
    }
    // log(I + X) = 2 Σ Z^(2j+1)/(2j+1), Z = X (2I + X)⁻¹ = (E − I)(E + I)⁻¹.
    let xm = &x - &id;
    let z = (&x + &id)
        .transpose()
        .lu()
        .solve(&xm.transpose())
        .ok_or_else(|| fail("matrix logarithm (E + I singular)"))?
        .transpose();
    let z2 = &z * &z;
    let zn = norm1(&z);
    let mut term = z.clone();
    let mut sum = z.clone();
    let mut converged = zn == 0.0;
    let mut power = zn;
    for j in 1..MAX_SERIES_TERMS {
        term = &term * &z2;
        let k = (2 * j + 1) as f64;
        sum += &term / k;
        power *= zn * zn;
        // Remainder after this term ≤ Σ_{i>j} ‖Z‖^(2i+1)/(2i+1) ≤ ‖Z‖^(2j+3)/((2j+3)(1 − ‖Z‖²)).
        let bound = power * zn * zn / ((k + 2.0) * (1.0 - zn * zn));
        if bound <= f64::EPSILON * 0.1 * norm1(&sum) {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(fail("matrix logarithm (series)"));
    }
    let mut log = sum * (2.0 * 2f64.powi(roots as i32));
    for i in 0..n {
        for j in 0..n {
            log[(i, j)] *= d[i] / d[j];
        }
    }
    if log.iter().any(|v| !v.is_finite()) {
        return Err(fail("matrix logarithm"));
    }
    Ok(log)
}

/// Principal square root by the product form of the Denman–Beavers
/// iteration (Higham, Functions of Matrices, (6.17)): M₀ = Y₀ = A,
/// Y ← Y (I + M⁻¹)/2, M ← (2I + M + M⁻¹)/4; M → I, Y → A^(1/2).
fn sqrtm_db(a: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = a.nrows();
    let id = DMatrix::<f64>::identity(n, n);
    let mut y = a.clone();
    let mut mm = a.clone();
    let mut previous = f64::INFINITY;
    for _ in 0..MAX_DB_ITERATIONS {
        let minv = mm.clone().try_inverse()?;
        y = &y * (&id + &minv) * 0.5;
        mm = (&id * 2.0 + &mm + &minv) * 0.25;
        let r = norm1(&(&mm - &id));
        // Converged, or stalled at rounding after quadratic convergence.
        if r <= 4.0 * f64::EPSILON * n as f64 || (r <= 1e-10 && r >= 0.5 * previous) {
            return y.iter().all(|v| v.is_finite()).then_some(y);
        }
        previous = r;
    }
    None
}

fn norm1(m: &DMatrix<f64>) -> f64 {
    (0..m.ncols())
        .map(|j| m.column(j).iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::continuous::ContinuousStateSpace;
    use crate::discretise::zoh;

    #[test]
    fn inverts_a_damped_mode_and_a_lag() {
        let a = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, -4e4, -8.0, 0.0, 0.0, 0.0, -50.0]);
        let b = DMatrix::from_row_slice(3, 2, &[0.0, 0.0, 1.0, 0.2, 0.0, 3.0]);
        let sys = ContinuousStateSpace::new(
            a.clone(),
            b.clone(),
            DMatrix::identity(3, 3),
            DMatrix::zeros(3, 2),
        )
        .unwrap();
        let d = zoh(&sys, 1e-3).unwrap();
        let (ga, gb) = continuous_from_zoh(&d.a, &d.b, 1e-3).unwrap();
        assert!(
            (&ga - &a).norm() < 1e-11 * a.norm(),
            "{}",
            (&ga - &a).norm()
        );
        assert!((&gb - &b).norm() < 1e-11 * b.norm());
    }

    #[test]
    fn refuses_matrices_without_a_real_log() {
        let b = DMatrix::from_element(1, 1, 1.0);
        let e = continuous_from_zoh(&DMatrix::from_element(1, 1, -0.5), &b, 1e-3).unwrap_err();
        assert_eq!(e.array, "A");
        assert!(matches!(e.reason, R::NoRealLogarithm { re, .. } if re == -0.5));
        assert!(e.to_string().contains("negative real axis"));
        let e = continuous_from_zoh(&DMatrix::zeros(1, 1), &b, 1e-3).unwrap_err();
        assert!(matches!(e.reason, R::NoRealLogarithm { .. }));
        let a = DMatrix::from_element(1, 1, 0.5);
        assert_eq!(continuous_from_zoh(&a, &b, 0.0).unwrap_err().array, "ts");
        assert_eq!(
            continuous_from_zoh(&a, &DMatrix::zeros(2, 1), 1e-3)
                .unwrap_err()
                .array,
            "B"
        );
        assert_eq!(
            continuous_from_zoh(&DMatrix::zeros(2, 1), &b, 1e-3)
                .unwrap_err()
                .array,
            "A"
        );
    }
}
