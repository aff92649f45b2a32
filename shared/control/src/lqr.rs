//! Linear-quadratic (LQ) state feedback on a discrete model, from the
//! existing DARE solver, and integral action by augmentation (docs/control.md
//! §12.1: "L and K can instead come from LQ/LQG"; x_i(k+1) = x_i(k) + C x(k)).
//!
//! Convention as in the lecture: u = −L x (− L_i x_i), so the closed loop is
//! Φ − Γ L. The integrator integrates the tracking error y − r, so that any
//! stable closed loop has zero steady-state error for constant r and constant
//! input disturbances.

use crate::dare::solve_dare;
use crate::design_error::{DesignError, check_matrix};
use crate::linalg::{LinalgError, block_diag, eigenvalues};
use crate::lti::DiscreteStateSpace;
use nalgebra::{Complex, DMatrix};

type C64 = Complex<f64>;

/// An LQ state-feedback design.
#[derive(Debug, Clone, PartialEq)]
pub struct Lqr {
    /// L (m × n) minimising Σ xᵀ Q x + uᵀ R u for u = −L x.
    pub gain: DMatrix<f64>,
    /// The stabilising DARE solution X (cost-to-go xᵀ X x).
    pub cost: DMatrix<f64>,
    /// Spectral radius of Φ − Γ L (< 1).
    pub closed_loop_radius: f64,
}

/// LQ gain for x(k+1) = Φ x + Γ u with weights Q (n × n, ⪰ 0) and
/// R (m × m, ≻ 0). A mode with |z| ≥ 1 that the inputs cannot move is
/// reported by name (PBH test) before the DARE is tried; other failures (e.g.
/// (Φ, Q) with unobservable modes on the unit circle) come as the DARE's error.
pub fn lqr(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<Lqr, DesignError> {
    let (n, m) = (a.nrows(), b.ncols());
    check_matrix(a, "Φ", n, n)?;
    check_matrix(b, "Γ", n, m)?;
    check_matrix(q, "LQ state weight Q", n, n)?;
    check_matrix(r, "LQ input weight R", m, m)?;
    if let Some(z) = unstabilisable_mode(a, b)? {
        // Rounded, so that z = 1 from an eigen-solver reads as 1.
        let z_text = if z.im == 0.0 {
            format!("{:.6}", z.re)
        } else {
            format!(
                "{:.6} {} {:.6}i",
                z.re,
                if z.im < 0.0 { '-' } else { '+' },
                z.im.abs()
            )
        };
        return Err(DesignError::InvalidParameter(format!(
            "(Φ, Γ) is not stabilisable: the mode at z = {z_text} (|z| = {:.6}) cannot be \
             moved by the inputs, so the DARE has no stabilising solution",
            z.norm()
        )));
    }
    let sol = solve_dare(a, b, q, r)?;
    Ok(Lqr {
        gain: sol.k,
        cost: sol.x,
        closed_loop_radius: sol.closed_loop_radius,
    })
}

/// A mode with |z| ≥ 1 at which [Φ − zI, Γ] loses rank (PBH test), if any.
/// Γ's columns are scaled to the size of Φ so that small actuator gains of a
/// fast-sampled model are not mistaken for none.
fn unstabilisable_mode(a: &DMatrix<f64>, b: &DMatrix<f64>) -> Result<Option<C64>, DesignError> {
    let (n, m) = (a.nrows(), b.ncols());
    let scale = a.norm().max(1.0);
    for z in eigenvalues(a)? {
        if z.norm() < 1.0 - 1e-12 {
            continue;
        }
        let mut pbh = DMatrix::<C64>::zeros(n, n + m);
        for i in 0..n {
            for j in 0..n {
                pbh[(i, j)] = C64::new(a[(i, j)], 0.0);
            }
            pbh[(i, i)] -= z;
        }
        for j in 0..m {
            let col = b.column(j);
            let nrm = col.norm();
            let f = if nrm > 0.0 { scale / nrm } else { 0.0 };
            for i in 0..n {
                pbh[(i, n + j)] = C64::new(col[i] * f, 0.0);
            }
        }
        let sv = pbh
            .try_svd(false, false, f64::EPSILON, 1000 * n.max(1))
            .ok_or(LinalgError::NoConvergence("PBH stabilisability test"))?
            .singular_values;
        if sv.min() <= 1e-9 * scale {
            return Ok(Some(z));
        }
    }
    Ok(None)
}

/// The plant augmented with the integrated tracking error (lecture §12.1):
/// [x; x_i](k+1) = [[Φ, 0], [C, I]] [x; x_i] + [Γ; D] u (− [0; I] r).
/// Returns (Φ_aug, Γ_aug).
pub fn integral_augmentation(plant: &DiscreteStateSpace) -> (DMatrix<f64>, DMatrix<f64>) {
    let (n, m, p) = (plant.states(), plant.inputs(), plant.outputs());
    let mut a = block_diag(&[&plant.a, &DMatrix::identity(p, p)]);
    a.view_mut((n, 0), (p, n)).copy_from(&plant.c);
    let mut b = DMatrix::zeros(n + p, m);
    b.view_mut((0, 0), (n, m)).copy_from(&plant.b);
    b.view_mut((n, 0), (p, m)).copy_from(&plant.d);
    (a, b)
}

/// LQ state feedback with integral action: u = −L x − L_i x_i.
#[derive(Debug, Clone, PartialEq)]
pub struct IntegralLqr {
    /// L (m × n), on the plant state.
    pub state_gain: DMatrix<f64>,
    /// L_i (m × p), on the integrated error x_i.
    pub integral_gain: DMatrix<f64>,
    /// Spectral radius of the augmented closed loop (< 1).
    pub closed_loop_radius: f64,
    pub ts: f64,
}

/// LQ design on the augmented plant with weights blockdiag(Q_x, Q_i) and R.
/// The augmentation is stabilisable only if the plant has no transmission
/// zero at z = 1 and at least as many inputs as outputs; otherwise [`lqr`]
/// names the integrator mode (z = 1) that cannot be stabilised.
pub fn lqr_with_integral_action(
    plant: &DiscreteStateSpace,
    q_x: &DMatrix<f64>,
    q_i: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<IntegralLqr, DesignError> {
    let (n, m, p) = (plant.states(), plant.inputs(), plant.outputs());
    check_matrix(q_x, "LQ state weight Q_x", n, n)?;
    check_matrix(q_i, "LQ integral weight Q_i", p, p)?;
    check_matrix(r, "LQ input weight R", m, m)?;
    let (a, b) = integral_augmentation(plant);
    let design = lqr(&a, &b, &block_diag(&[q_x, q_i]), r)?;
    Ok(IntegralLqr {
        state_gain: design.gain.columns(0, n).into_owned(),
        integral_gain: design.gain.columns(n, p).into_owned(),
        closed_loop_radius: design.closed_loop_radius,
        ts: plant.ts,
    })
}

impl IntegralLqr {
    /// The controller as one discrete block: inputs [r (p); y (p); x (n)],
    /// output u (m), state x_i (p) with x_i(k+1) = x_i(k) + y(k) − r(k) and
    /// u(k) = −L_i x_i(k) − L x(k). Feed it the measured y and the state (or
    /// an estimate of it).
    pub fn controller(&self) -> Result<DiscreteStateSpace, DesignError> {
        let (m, n) = self.state_gain.shape();
        let p = self.integral_gain.ncols();
        let mut b = DMatrix::zeros(p, 2 * p + n);
        b.view_mut((0, 0), (p, p))
            .copy_from(&(-DMatrix::<f64>::identity(p, p)));
        b.view_mut((0, p), (p, p)).fill_with_identity();
        let mut d = DMatrix::zeros(m, 2 * p + n);
        d.view_mut((0, 2 * p), (m, n))
            .copy_from(&(-&self.state_gain));
        Ok(DiscreteStateSpace::new(
            DMatrix::identity(p, p),
            b,
            -&self.integral_gain,
            d,
            self.ts,
        )?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dare::DareError;
    use crate::discretise::zoh;
    use crate::linalg::{solve, spectral_radius};
    use crate::lti::LtiRunner;
    use crate::matrix_error::MatrixError;
    use crate::models::double_integrator;

    #[test]
    fn lqr_is_the_dare_gain_and_stabilises() {
        let plant = zoh(&double_integrator(), 0.1).unwrap();
        let q = DMatrix::identity(2, 2);
        let r = DMatrix::from_element(1, 1, 0.1);
        let d = lqr(&plant.a, &plant.b, &q, &r).unwrap();
        let rho = spectral_radius(&(&plant.a - &plant.b * &d.gain)).unwrap();
        assert!((rho - d.closed_loop_radius).abs() < 1e-12 && rho < 1.0);
        // Optimality: the gain is stationary, K = (R + ΓᵀXΓ)⁻¹ ΓᵀXΦ.
        let x = &d.cost;
        let k = solve(
            &(&r + plant.b.transpose() * x * &plant.b),
            &(plant.b.transpose() * x * &plant.a),
            "test",
        )
        .unwrap();
        assert!((&k - &d.gain).amax() < 1e-10 * k.amax());
    }

    #[test]
    fn integral_action_gives_zero_dc_tracking_error_on_the_double_integrator() {
        let h = 0.1;
        let plant = zoh(&double_integrator(), h).unwrap();
        let design = lqr_with_integral_action(
            &plant,
            &DMatrix::identity(2, 2),
            &DMatrix::from_element(1, 1, 1.0),
            &DMatrix::from_element(1, 1, 0.1),
        )
        .unwrap();
        // Closed loop [x; x_i] with inputs [r, load force w].
        let (l, li) = (&design.state_gain, &design.integral_gain);
        let mut a = DMatrix::zeros(3, 3);
        a.view_mut((0, 0), (2, 2))
            .copy_from(&(&plant.a - &plant.b * l));
        a.view_mut((0, 2), (2, 1)).copy_from(&(-&plant.b * li));
        a.view_mut((2, 0), (1, 2)).copy_from(&plant.c);
        a[(2, 2)] = 1.0;
        let mut b = DMatrix::zeros(3, 2);
        b[(2, 0)] = -1.0;
        b.view_mut((0, 1), (2, 1)).copy_from(&plant.b);
        let rho = spectral_radius(&a).unwrap();
        assert!(rho < 1.0 && (rho - design.closed_loop_radius).abs() < 1e-12);
        // DC gains: r → y is exactly 1, a constant load force → y is 0.
        let x_dc = solve(&(DMatrix::identity(3, 3) - &a), &b, "I − A_cl").unwrap();
        let y_dc = &plant.c * x_dc.rows(0, 2);
        assert!((y_dc[(0, 0)] - 1.0).abs() < 1e-12, "r → y at DC {}", y_dc);
        assert!(y_dc[(0, 1)].abs() < 1e-12, "w → y at DC {}", y_dc);
        // The same with the compiled controller block, in the time domain:
        // a unit step in r plus a constant load of 0.5 from k = 0.
        let mut ctrl = LtiRunner::new(design.controller().unwrap());
        let mut p = LtiRunner::new(plant.clone());
        let mut e = f64::NAN;
        for _ in 0..600 {
            let x = p.state().to_vec();
            let y = p.free_output()[0];
            e = 1.0 - y;
            let u = ctrl.step(&[1.0, y, x[0], x[1]])[0];
            p.advance(&[u + 0.5]);
        }
        assert!(e.abs() < 1e-9, "tracking error after 60 s: {e}");
    }

    #[test]
    fn no_stabilising_solution_is_an_error() {
        // A plant with a zero at z = 1 (G(z) = (z − 1)/(z − 0.5), no DC gain)
        // cannot get integral action: the integrator mode is not stabilisable.
        let plant = DiscreteStateSpace::new(
            DMatrix::from_element(1, 1, 0.5),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, -0.5),
            DMatrix::from_element(1, 1, 1.0),
            0.1,
        )
        .unwrap();
        let err = lqr_with_integral_action(
            &plant,
            &DMatrix::identity(1, 1),
            &DMatrix::identity(1, 1),
            &DMatrix::identity(1, 1),
        )
        .unwrap_err();
        assert!(
            matches!(&err, DesignError::InvalidParameter(s)
                if s.contains("not stabilisable") && s.contains("z = 1.000000")),
            "{err}"
        );
        // An unreachable unstable mode: named by the PBH test.
        let a = DMatrix::from_row_slice(2, 2, &[1.5, 0.0, 0.0, 0.5]);
        let b = DMatrix::from_column_slice(2, 1, &[0.0, 1.0]);
        let err = lqr(&a, &b, &DMatrix::identity(2, 2), &DMatrix::identity(1, 1)).unwrap_err();
        assert!(err.to_string().contains("z = 1.500000"), "{err}");
        // With everything reachable, a DARE failure still comes through:
        // R not positive definite.
        assert_eq!(
            lqr(
                &a,
                &DMatrix::identity(2, 2),
                &DMatrix::identity(2, 2),
                &(-DMatrix::identity(2, 2))
            ),
            Err(DesignError::Dare(DareError::RNotPositiveDefinite))
        );
        let bad = lqr(
            &DMatrix::identity(2, 2),
            &DMatrix::zeros(3, 1),
            &DMatrix::identity(2, 2),
            &DMatrix::identity(1, 1),
        );
        assert!(matches!(
            bad,
            Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "Γ",
                ..
            }))
        ));
    }
}
