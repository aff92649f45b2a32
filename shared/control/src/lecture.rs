//! Pole placement for SISO discrete systems (Årzén, "State Feedback and
//! Observers", docs/control.md §12.1): reachability/observability matrices,
//! Ackermann's formula for state feedback and observers, deadbeat designs,
//! and the lecture's worked double-integrator example.

use crate::design_error::{DesignError, check_matrix};
use crate::discretise::zoh;
use crate::linalg::rank;
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::models::double_integrator;
use nalgebra::{Complex, DMatrix};

/// W_c = [Γ ΦΓ … Φⁿ⁻¹Γ].
pub fn reachability_matrix(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let n = a.nrows();
    let m = b.ncols();
    let mut w = DMatrix::zeros(n, n * m);
    let mut blk = b.clone();
    for k in 0..n {
        w.view_mut((0, k * m), (n, m)).copy_from(&blk);
        blk = a * blk;
    }
    w
}

/// W_o = [C; CΦ; …; CΦⁿ⁻¹].
pub fn observability_matrix(a: &DMatrix<f64>, c: &DMatrix<f64>) -> DMatrix<f64> {
    reachability_matrix(&a.transpose(), &c.transpose()).transpose()
}

/// Monic real polynomial [1, a1, …, an] with the given roots (complex roots
/// must come in conjugate pairs).
pub fn poly_from_roots(roots: &[Complex<f64>]) -> Result<Vec<f64>, DesignError> {
    let mut c = vec![Complex::new(1.0, 0.0)];
    for r in roots {
        if !(r.re.is_finite() && r.im.is_finite()) {
            return Err(DesignError::Matrix(MatrixError::NonFinite("pole")));
        }
        let mut next = vec![Complex::new(0.0, 0.0); c.len() + 1];
        for (i, ci) in c.iter().enumerate() {
            next[i] += *ci;
            next[i + 1] -= *ci * r;
        }
        c = next;
    }
    let scale = c.iter().map(|v| v.norm()).fold(1.0, f64::max);
    if c.iter().any(|v| v.im.abs() > 1e-9 * scale) {
        return Err(DesignError::InvalidParameter(
            "complex poles must come in conjugate pairs".into(),
        ));
    }
    Ok(c.iter().map(|v| v.re).collect())
}

/// Ackermann: L = [0 … 0 1] W_c⁻¹ P(Φ) so that eig(Φ − Γ L) are the roots of
/// `poly` = [1, a1, …, an]. SISO only; refuses an unreachable pair.
pub fn ackermann(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    poly: &[f64],
) -> Result<DMatrix<f64>, DesignError> {
    let n = a.nrows();
    check_matrix(a, "Φ", n, n)?;
    check_matrix(b, "Γ (SISO)", n, 1)?;
    if poly.len() != n + 1 || poly[0] != 1.0 || poly.iter().any(|v| !v.is_finite()) {
        return Err(DesignError::InvalidParameter(format!(
            "need a monic polynomial of degree {n}"
        )));
    }
    let wc = reachability_matrix(a, b);
    let r = rank(&wc)?;
    if r < n {
        return Err(DesignError::NotReachable { rank: r, states: n });
    }
    // P(Φ) by Horner.
    let mut p = DMatrix::<f64>::identity(n, n) * poly[0];
    for coef in &poly[1..] {
        p = a * p + DMatrix::<f64>::identity(n, n) * *coef;
    }
    let mut en = DMatrix::zeros(1, n);
    en[(0, n - 1)] = 1.0;
    let x = wc
        .transpose()
        .lu()
        .solve(&en.transpose())
        .ok_or(DesignError::NotReachable { rank: r, states: n })?;
    Ok(x.transpose() * p)
}

/// State feedback placing eig(Φ − Γ L) at `poles`.
pub fn place(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    poles: &[Complex<f64>],
) -> Result<DMatrix<f64>, DesignError> {
    ackermann(a, b, &poly_from_roots(poles)?)
}

/// Predictor observer gain K placing eig(Φ − K C) at `poles` (duality).
pub fn place_observer(
    a: &DMatrix<f64>,
    c: &DMatrix<f64>,
    poles: &[Complex<f64>],
) -> Result<DMatrix<f64>, DesignError> {
    let n = a.nrows();
    check_matrix(c, "C (SISO)", 1, n)?;
    let poly = poly_from_roots(poles)?;
    match ackermann(&a.transpose(), &c.transpose(), &poly) {
        Ok(k) => Ok(k.transpose()),
        Err(DesignError::NotReachable { rank, states }) => {
            Err(DesignError::NotObservable { rank, states })
        }
        Err(e) => Err(e),
    }
}

/// Deadbeat state feedback: all poles at 0.
pub fn deadbeat(a: &DMatrix<f64>, b: &DMatrix<f64>) -> Result<DMatrix<f64>, DesignError> {
    place(a, b, &vec![Complex::new(0.0, 0.0); a.nrows()])
}

/// The lecture example (S2:L392–488).
#[derive(Debug, Clone, PartialEq)]
pub struct LectureDesign {
    /// ZOH double integrator (Φ, Γ, C).
    pub plant: DiscreteStateSpace,
    /// State feedback L (1 × 2).
    pub l: DMatrix<f64>,
    /// Observer gain K (2 × 1).
    pub k: DMatrix<f64>,
    /// Disturbance-estimate gain K_w (1 × 1).
    pub k_w: DMatrix<f64>,
}

/// Double integrator sampled at h; L from continuous poles ω = 1, ζ = 0.7
/// mapped by e^{s h}; extended observer (constant input disturbance) with all
/// three poles at 0.75.
pub fn lecture_example(h: f64) -> Result<LectureDesign, DesignError> {
    let plant = zoh(&double_integrator(), h)?;
    let (w, z) = (1.0f64, 0.7f64);
    let s = Complex::new(-z * w, w * (1.0 - z * z).sqrt());
    let p = (s * h).exp();
    let l = place(&plant.a, &plant.b, &[p, p.conj()])?;
    let mut ae = DMatrix::zeros(3, 3);
    ae.view_mut((0, 0), (2, 2)).copy_from(&plant.a);
    ae.view_mut((0, 2), (2, 1)).copy_from(&plant.b);
    ae[(2, 2)] = 1.0;
    let mut ce = DMatrix::zeros(1, 3);
    ce.view_mut((0, 0), (1, 2)).copy_from(&plant.c);
    let ke = place_observer(&ae, &ce, &[Complex::new(0.75, 0.0); 3])?;
    Ok(LectureDesign {
        l,
        k: ke.rows(0, 2).into_owned(),
        k_w: ke.rows(2, 1).into_owned(),
        plant,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::{LoopSpec, assemble_loop};
    use crate::linalg::eigenvalues;
    use crate::lti::LtiRunner;
    use crate::observer_block::state_feedback_observer_block;
    use crate::pid::zero_controller;

    #[test]
    fn lecture_gains() {
        let d = lecture_example(0.44).unwrap();
        let close = |a: f64, b: f64| (a - b).abs() < 5e-5;
        assert!(
            close(d.l[(0, 0)], 0.7347) && close(d.l[(0, 1)], 1.2069),
            "{}",
            d.l
        );
        assert!(
            close(d.k[(0, 0)], 0.7500) && close(d.k[(1, 0)], 0.4084),
            "{}",
            d.k
        );
        assert!(close(d.k_w[(0, 0)], 0.0807), "{}", d.k_w);
        // Closed-form double-integrator formulas: l1 = (1+a1+a2)/h², l2 = (3+a1−a2)/(2h).
        let h = 0.44;
        let db = deadbeat(&d.plant.a, &d.plant.b).unwrap();
        assert!((db[(0, 0)] - 1.0 / (h * h)).abs() < 1e-9 && (db[(0, 1)] - 1.5 / h).abs() < 1e-9);
        // Unreachable pair is refused.
        let b0 = DMatrix::from_column_slice(2, 1, &[1.0, 0.0]);
        assert!(matches!(
            ackermann(&d.plant.a, &b0, &[1.0, 0.0, 0.0]),
            Err(DesignError::NotReachable { rank: 1, states: 2 })
        ));
        assert!(poly_from_roots(&[Complex::new(0.5, 0.1)]).is_err());
    }

    #[test]
    fn lecture_block_rejects_a_constant_load() {
        let d = lecture_example(0.44).unwrap();
        let block = state_feedback_observer_block(&d.plant, &d.l, &d.k, &d.k_w, 0).unwrap();
        let ctrl = zero_controller(0.44).unwrap();
        let cl = assemble_loop(&LoopSpec {
            plant: &d.plant,
            observer: Some(&block),
            controller: &ctrl,
            loop_delay: 1,
        })
        .unwrap();
        // Separation: the poles are eig(Φ − ΓL), the observer's 0.75 (triple)
        // and the one-sample register at 0.
        let ev = eigenvalues(&cl.a).unwrap();
        let p = (Complex::new(-0.7, 0.51f64.sqrt()) * 0.44).exp();
        assert!(ev.iter().any(|z| (z - p).norm() < 1e-6), "{ev:?}");
        assert_eq!(
            ev.iter().filter(|z| (*z - 0.75).norm() < 2e-3).count(),
            3,
            "{ev:?}"
        );
        // A constant force disturbance is rejected: y → 0.
        let mut run = LtiRunner::new(cl);
        let mut y = 0.0;
        for _ in 0..200 {
            // inputs [r, n, u_ff, w]
            y = run.step(&[0.0, 0.0, 0.0, 1.0])[1];
        }
        assert!(y.abs() < 1e-6, "{y}");
    }
}
