//! Dense linear-algebra helpers shared by the design modules: matrix
//! exponential, balancing, eigenvalues, pseudo-inverse and finiteness checks.
//!
//! These wrap nalgebra with bounded iteration counts and error returns, so that
//! no design function can hang or panic on a bad matrix.

use nalgebra::{Complex, DMatrix, DVector};
use std::fmt;

/// Why a linear-algebra helper failed.
#[derive(Debug, Clone, PartialEq)]
pub enum LinalgError {
    /// The matrix must be square.
    NotSquare { rows: usize, cols: usize },
    /// The input holds NaN or infinity.
    NonFinite,
    /// An iterative algorithm did not converge within its bound.
    NoConvergence(&'static str),
    /// A matrix that must be inverted is singular (to working precision).
    Singular(&'static str),
}

impl fmt::Display for LinalgError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NotSquare { rows, cols } => write!(f, "matrix is {rows}x{cols}, not square"),
            Self::NonFinite => write!(f, "matrix holds a non-finite number"),
            Self::NoConvergence(what) => write!(f, "{what} did not converge"),
            Self::Singular(what) => write!(f, "{what} is singular"),
        }
    }
}

impl std::error::Error for LinalgError {}

pub(crate) fn all_finite(m: &DMatrix<f64>) -> bool {
    m.iter().all(|v| v.is_finite())
}

fn check_square(m: &DMatrix<f64>) -> Result<usize, LinalgError> {
    if m.nrows() != m.ncols() {
        return Err(LinalgError::NotSquare {
            rows: m.nrows(),
            cols: m.ncols(),
        });
    }
    if !all_finite(m) {
        return Err(LinalgError::NonFinite);
    }
    Ok(m.nrows())
}

/// Diagonal similarity scaling (Parlett–Reinsch, powers of two): returns
/// (D⁻¹ A D, d) with d the diagonal of D.
///
/// Modal models mix entries of order ω² and 1; without balancing, the
/// exponential and the eigenvalues of such matrices lose most of their digits
/// in the small entries.
pub fn balance(a: &DMatrix<f64>) -> Result<(DMatrix<f64>, DVector<f64>), LinalgError> {
    let n = check_square(a)?;
    let mut m = a.clone();
    let mut d = DVector::from_element(n, 1.0);
    const RADIX: f64 = 2.0;
    // Each sweep changes the scaling by at least one power of two or stops, and
    // the exponent range of f64 bounds the useful number of sweeps.
    for _sweep in 0..200 {
        let mut converged = true;
        for i in 0..n {
            let mut c = 0.0;
            let mut r = 0.0;
            for j in 0..n {
                if j != i {
                    c += m[(j, i)].abs();
                    r += m[(i, j)].abs();
                }
            }
            if c == 0.0 || r == 0.0 {
                continue;
            }
            let s = c + r;
            let mut f = 1.0;
            let mut g = r / RADIX;
            let mut cc = c;
            let mut guard = 0;
            while cc < g && guard < 2100 {
                f *= RADIX;
                cc *= RADIX * RADIX;
                guard += 1;
            }
            g = r * RADIX;
            guard = 0;
            while cc > g && guard < 2100 {
                f /= RADIX;
                cc /= RADIX * RADIX;
                guard += 1;
            }
            if (cc + r / f) < 0.95 * s * f {
                converged = false;
                d[i] *= f;
                for j in 0..n {
                    m[(i, j)] /= f;
                }
                for j in 0..n {
                    m[(j, i)] *= f;
                }
            }
        }
        if converged {
            return Ok((m, d));
        }
    }
    Ok((m, d))
}

/// Eigenvalues of a real square matrix (balanced, then real Schur form).
pub fn eigenvalues(a: &DMatrix<f64>) -> Result<Vec<Complex<f64>>, LinalgError> {
    let n = check_square(a)?;
    if n == 0 {
        return Ok(Vec::new());
    }
    let (b, _) = balance(a)?;
    let schur = b
        .try_schur(f64::EPSILON, 200 * n.max(10))
        .ok_or(LinalgError::NoConvergence("Schur decomposition"))?;
    Ok(schur.complex_eigenvalues().iter().copied().collect())
}

/// Largest eigenvalue magnitude.
pub fn spectral_radius(a: &DMatrix<f64>) -> Result<f64, LinalgError> {
    Ok(eigenvalues(a)?.iter().map(|z| z.norm()).fold(0.0, f64::max))
}

/// Matrix exponential by balancing, scaling and squaring with a degree-13 Padé
/// approximant (Higham 2005). Works for singular matrices.
pub fn expm(a: &DMatrix<f64>) -> Result<DMatrix<f64>, LinalgError> {
    let n = check_square(a)?;
    if n == 0 {
        return Ok(DMatrix::zeros(0, 0));
    }
    let (ab, d) = balance(a)?;
    const B: [f64; 14] = [
        64764752532480000.0,
        32382376266240000.0,
        7771770303897600.0,
        1187353796428800.0,
        129060195264000.0,
        10559470521600.0,
        670442572800.0,
        33522128640.0,
        1323241920.0,
        40840800.0,
        960960.0,
        16380.0,
        182.0,
        1.0,
    ];
    const THETA13: f64 = 5.371920351148152;
    let norm1 = (0..n)
        .map(|j| ab.column(j).iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let s = if norm1 > THETA13 {
        (norm1 / THETA13).log2().ceil() as i32
    } else {
        0
    };
    if !(0..=1000).contains(&s) {
        return Err(LinalgError::NonFinite);
    }
    let x = &ab * 2f64.powi(-s);
    let id = DMatrix::<f64>::identity(n, n);
    let x2 = &x * &x;
    let x4 = &x2 * &x2;
    let x6 = &x4 * &x2;
    let u_inner = &x6 * (&x6 * B[13] + &x4 * B[11] + &x2 * B[9])
        + &x6 * B[7]
        + &x4 * B[5]
        + &x2 * B[3]
        + &id * B[1];
    let u = &x * u_inner;
    let v = &x6 * (&x6 * B[12] + &x4 * B[10] + &x2 * B[8])
        + &x6 * B[6]
        + &x4 * B[4]
        + &x2 * B[2]
        + &id * B[0];
    let p = &v + &u;
    let q = &v - &u;
    let mut r = q
        .lu()
        .solve(&p)
        .ok_or(LinalgError::Singular("Padé denominator"))?;
    for _ in 0..s {
        r = &r * &r;
    }
    // Undo the balancing: e^A = D e^(D⁻¹AD) D⁻¹.
    for i in 0..n {
        for j in 0..n {
            r[(i, j)] *= d[i] / d[j];
        }
    }
    if !all_finite(&r) {
        return Err(LinalgError::NonFinite);
    }
    Ok(r)
}

/// Moore–Penrose pseudo-inverse with a relative singular-value cut-off.
pub fn pinv(a: &DMatrix<f64>) -> Result<DMatrix<f64>, LinalgError> {
    if !all_finite(a) {
        return Err(LinalgError::NonFinite);
    }
    if a.is_empty() {
        return Ok(DMatrix::zeros(a.ncols(), a.nrows()));
    }
    let svd = a
        .clone()
        .try_svd(true, true, f64::EPSILON, 1000 * a.nrows().max(a.ncols()))
        .ok_or(LinalgError::NoConvergence("SVD"))?;
    let smax = svd.singular_values.max();
    let tol = smax * f64::EPSILON * a.nrows().max(a.ncols()) as f64;
    svd.pseudo_inverse(tol)
        .map_err(|_| LinalgError::NoConvergence("SVD pseudo-inverse"))
}

/// Rank by SVD with the same cut-off as [`pinv`].
pub fn rank(a: &DMatrix<f64>) -> Result<usize, LinalgError> {
    if !all_finite(a) {
        return Err(LinalgError::NonFinite);
    }
    if a.is_empty() {
        return Ok(0);
    }
    let svd = a
        .clone()
        .try_svd(false, false, f64::EPSILON, 1000 * a.nrows().max(a.ncols()))
        .ok_or(LinalgError::NoConvergence("SVD"))?;
    let smax = svd.singular_values.max();
    let tol = smax * 1e-10;
    Ok(svd.singular_values.iter().filter(|&&s| s > tol).count())
}

/// Solves A X = B by LU, with an error for a singular A.
pub fn solve(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    what: &'static str,
) -> Result<DMatrix<f64>, LinalgError> {
    let x = a.clone().lu().solve(b).ok_or(LinalgError::Singular(what))?;
    if !all_finite(&x) {
        return Err(LinalgError::Singular(what));
    }
    Ok(x)
}

/// Block-diagonal concatenation.
pub fn block_diag(blocks: &[&DMatrix<f64>]) -> DMatrix<f64> {
    let rows = blocks.iter().map(|b| b.nrows()).sum();
    let cols = blocks.iter().map(|b| b.ncols()).sum();
    let mut m = DMatrix::zeros(rows, cols);
    let (mut r, mut c) = (0, 0);
    for b in blocks {
        m.view_mut((r, c), b.shape()).copy_from(*b);
        r += b.nrows();
        c += b.ncols();
    }
    m
}

/// Continuous pole s of a discrete pole z = e^{s Ts}: (natural frequency
/// [rad/s], relative damping).
pub fn discrete_pole_to_continuous(z: Complex<f64>, ts: f64) -> (f64, f64) {
    let s = z.ln() / ts;
    let wn = s.norm();
    let zeta = if wn > 0.0 { -s.re / wn } else { 1.0 };
    (wn, zeta)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expm_of_rotation_and_nilpotent() {
        let w = 2.0 * std::f64::consts::PI * 2556.45;
        let t = 1e-4;
        let a = DMatrix::from_row_slice(2, 2, &[0.0, t, -w * w * t, 0.0]);
        let e = expm(&a).unwrap();
        let (s, c) = (w * t).sin_cos();
        let want = DMatrix::from_row_slice(2, 2, &[c, s / w, -w * s, c]);
        for (x, y) in e.iter().zip(want.iter()) {
            assert!((x - y).abs() <= 1e-12 * y.abs().max(1e-12), "{x} vs {y}");
        }
        let n = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        let e = expm(&n).unwrap();
        assert!((e[(0, 2)] - 0.5).abs() < 1e-15);
        assert!((e[(0, 1)] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn eigenvalues_and_errors() {
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -4.0, 0.0]);
        let ev = eigenvalues(&a).unwrap();
        assert!(
            ev.iter()
                .all(|z| (z.im.abs() - 2.0).abs() < 1e-12 && z.re.abs() < 1e-12)
        );
        assert!(matches!(
            eigenvalues(&DMatrix::zeros(2, 3)),
            Err(LinalgError::NotSquare { .. })
        ));
        assert_eq!(
            expm(&DMatrix::from_element(1, 1, f64::NAN)),
            Err(LinalgError::NonFinite)
        );
    }
}
