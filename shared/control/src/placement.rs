//! Robust multi-input pole placement for state feedback and multi-output
//! observers (docs/control.md §3 "(4.3) … otherwise use the extra freedom",
//! §5.2 (3.33), §12.1 `place`).
//!
//! With more than one input the gain that places the poles is not unique;
//! the freedom is used, as in Kautsky, Nichols and Van Dooren (1985), to
//! make the closed-loop eigenvector matrix X as well conditioned as
//! possible: a small κ(X) means poles that move little under model error and
//! rounding, and usually a smaller gain. The method here is their "method 0"
//! (one eigenvector at a time, rank-one updates), extended to complex pairs
//! by updating one member of each pair in complex arithmetic and setting the
//! other to its conjugate, which keeps the gain real:
//!
//! 1. B = [U0 U1] [Z; 0]; eigenvector j may be any x ∈ S_j = ker U1ᵀ(A − λ_j I)
//!    (then (A − λ_j I) x ∈ range B);
//! 2. sweep over j: pick x_j ∈ S_j as orthogonal as possible to the other
//!    columns of X (closest to the complement of their span), keep the best
//!    X seen, stop when κ(X) no longer improves;
//! 3. M = X Λ X⁻¹ (real), L = B⁺ (A − M), so A − B L = M;
//! 4. check that eig(A − B L) are the requested poles.
//!
//! A pole may be repeated at most rank B times (so that the closed loop
//! stays diagonalisable). With one input the gain is unique; repeated poles
//! then go through Ackermann's formula ([`crate::lecture::place`]).

use crate::design_error::{DesignError, check_matrix};
use crate::linalg::{eigenvalues, pinv, rank};
use crate::matrix_error::MatrixError;
use nalgebra::{Complex, DMatrix, SymmetricEigen};

type C64 = Complex<f64>;

/// A pole-placement design.
#[derive(Debug, Clone, PartialEq)]
pub struct PolePlacement {
    /// State feedback: L (m × n) with eig(A − B L) = poles. Observer: L
    /// (n × p) with eig(A − L C) = poles.
    pub gain: DMatrix<f64>,
    /// κ₂ of the closed-loop eigenvector matrix (unit columns) after the
    /// sweeps; None on the single-input Ackermann path (repeated poles).
    pub eigenvector_condition: Option<f64>,
    /// κ₂ of the first eigenvector choice, before any sweep (for comparison).
    pub initial_condition: Option<f64>,
    /// KNV sweeps made.
    pub sweeps: usize,
    /// Largest distance between a requested pole and the achieved one.
    pub max_pole_error: f64,
}

const MAX_SWEEPS: usize = 30;

/// State feedback L with eig(A − B L) = `poles` (complex poles in conjugate
/// pairs, each pole at most rank B times).
pub fn robust_place(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    poles: &[C64],
) -> Result<PolePlacement, DesignError> {
    let n = a.nrows();
    let m = b.ncols();
    check_matrix(a, "A", n, n)?;
    check_matrix(b, "B", n, m)?;
    if n == 0 || m == 0 {
        return Err(DesignError::InvalidParameter(format!(
            "pole placement needs states and inputs: A is {n}x{n}, B is {n}x{m}"
        )));
    }
    if poles.len() != n {
        return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
            what: "pole list (one pole per state)",
            expected: (n, 1),
            found: (poles.len(), 1),
        }));
    }
    let poles = order_poles(poles)?;
    let rb = rank(b)?;
    if rb < m {
        return Err(DesignError::InvalidParameter(format!(
            "B has rank {rb} with {m} columns: the inputs are dependent; remove the redundant ones"
        )));
    }
    check_reachable(a, b)?;
    let groups = group_poles(&poles);
    let max_mult = groups.iter().map(|g| g.len()).max().unwrap_or(1);
    if m == 1 && max_mult > 1 {
        let gain = crate::lecture::place(a, b, &poles)?;
        // Repeated poles are defective: eigenvalues of a k-fold pole are only
        // determined to about ε^(1/k).
        let scale = a.norm().max(1.0);
        let tol = 1e3 * f64::EPSILON.powf(1.0 / max_mult as f64) * scale;
        let err = pole_error(&(a - b * &gain), &poles)?;
        if err.is_nan() || err > tol {
            return Err(inaccurate(err, None));
        }
        return Ok(PolePlacement {
            gain,
            eigenvector_condition: None,
            initial_condition: None,
            sweeps: 0,
            max_pole_error: err,
        });
    }
    if let Some(g) = groups.iter().find(|g| g.len() > m) {
        return Err(DesignError::InvalidParameter(format!(
            "pole {} is requested {} times but B has rank {m}: at most {m} repeats can be placed",
            poles[g[0]],
            g.len()
        )));
    }
    // U1: orthonormal basis of the left null space of B.
    let mut bp = DMatrix::zeros(n, n);
    bp.view_mut((0, 0), (n, m)).copy_from(b);
    let svd_b = bp
        .try_svd(true, false, f64::EPSILON, 1000 * n)
        .ok_or(crate::linalg::LinalgError::NoConvergence("SVD of B"))?;
    let u_b = svd_b
        .u
        .ok_or(crate::linalg::LinalgError::NoConvergence("SVD of B"))?;
    let u1 = u_b.columns(m, n - m).into_owned();
    // Allowed eigenvector subspace per distinct pole.
    let mut basis: Vec<DMatrix<C64>> = Vec::with_capacity(poles.len());
    let mut group_of = vec![0usize; poles.len()];
    let mut occurrence = vec![0usize; poles.len()];
    let mut group_basis: Vec<DMatrix<C64>> = Vec::with_capacity(groups.len());
    for (gi, g) in groups.iter().enumerate() {
        group_basis.push(allowed_subspace(a, &u1, poles[g[0]], m)?);
        for (o, &idx) in g.iter().enumerate() {
            group_of[idx] = gi;
            occurrence[idx] = o;
        }
    }
    for idx in 0..poles.len() {
        basis.push(group_basis[group_of[idx]].clone());
    }
    // Initial X: distinct basis vectors for repeated poles, conjugates for pairs.
    let mut x = DMatrix::<C64>::zeros(n, n);
    let mut j = 0;
    while j < n {
        let nb = &basis[j];
        let v = nb.column(occurrence[j] % nb.ncols()).into_owned();
        x.set_column(j, &v);
        if poles[j].im != 0.0 {
            x.set_column(j + 1, &v.conjugate());
            j += 2;
        } else {
            j += 1;
        }
    }
    let initial = condition(&x)?;
    let mut best = (initial, x.clone());
    let mut sweeps = 0;
    let mut previous = initial;
    while sweeps < MAX_SWEEPS {
        sweeps += 1;
        let mut j = 0;
        while j < n {
            let complex = poles[j].im != 0.0;
            if let Some(v) = knv_update(&x, j, &basis[j], complex)? {
                x.set_column(j, &v);
                if complex {
                    x.set_column(j + 1, &v.conjugate());
                }
            }
            j += if complex { 2 } else { 1 };
        }
        let c = condition(&x)?;
        if c < best.0 {
            best = (c, x.clone());
        }
        if previous.is_finite() && (previous - c).abs() <= 1e-6 * previous {
            break;
        }
        previous = c;
    }
    let (kappa, x) = best;
    if !kappa.is_finite() || kappa > 1e12 {
        return Err(DesignError::InvalidParameter(format!(
            "no well-conditioned eigenvector set for these poles (κ(X) = {kappa:e}); \
             spread out repeated or clustered poles"
        )));
    }
    // M = X Λ X⁻¹ from Xᵀ Mᵀ = (X Λ)ᵀ; real up to rounding by construction.
    let mut xl = x.clone();
    for (j, p) in poles.iter().enumerate() {
        for v in xl.column_mut(j).iter_mut() {
            *v *= *p;
        }
    }
    let mt = x
        .transpose()
        .lu()
        .solve(&xl.transpose())
        .ok_or(crate::linalg::LinalgError::Singular("eigenvector matrix X"))?;
    let mc = mt.transpose();
    let m_re = mc.map(|v| v.re);
    let im = mc.map(|v| v.im.abs()).max();
    // NaN counts as failure.
    if im.is_nan() || im > 1e-8 * m_re.amax().max(1.0) {
        return Err(DesignError::InvalidParameter(format!(
            "closed-loop matrix is not real (imaginary part {im:e}): poles not in conjugate pairs"
        )));
    }
    let gain = pinv(b)? * (a - &m_re);
    let acl = a - b * &gain;
    let err = pole_error(&acl, &poles)?;
    let tol = (1e3 * kappa * f64::EPSILON).max(1e-10) * acl.norm().max(1.0);
    if err.is_nan() || err > tol {
        return Err(inaccurate(err, Some(kappa)));
    }
    Ok(PolePlacement {
        gain,
        eigenvector_condition: Some(kappa),
        initial_condition: Some(initial),
        sweeps,
        max_pole_error: err,
    })
}

/// Observer gain L with eig(A − L C) = `poles`, by duality (placement on
/// (Aᵀ, Cᵀ)); an unobservable pair is reported as such.
pub fn robust_place_observer(
    a: &DMatrix<f64>,
    c: &DMatrix<f64>,
    poles: &[C64],
) -> Result<PolePlacement, DesignError> {
    let n = a.nrows();
    check_matrix(a, "A", n, n)?;
    check_matrix(c, "C", c.nrows(), n)?;
    match robust_place(&a.transpose(), &c.transpose(), poles) {
        Ok(mut p) => {
            p.gain = p.gain.transpose();
            Ok(p)
        }
        Err(DesignError::NotReachable { rank, states }) => {
            Err(DesignError::NotObservable { rank, states })
        }
        Err(DesignError::InvalidParameter(s)) => Err(DesignError::InvalidParameter(
            s.replace("B has", "Cᵀ has")
                .replace("inputs are dependent", "outputs are dependent"),
        )),
        Err(e) => Err(e),
    }
}

fn inaccurate(err: f64, kappa: Option<f64>) -> DesignError {
    DesignError::InvalidParameter(format!(
        "pole placement inaccurate: a pole missed its target by {err:e} (κ(X) = {}); \
         the requested poles are too ill-conditioned for this model",
        kappa.map_or("n/a".to_string(), |k| format!("{k:e}"))
    ))
}

/// Real poles first, then conjugate pairs (λ, λ̄) with Im λ > 0; refuses
/// non-finite poles and complex poles without a partner.
fn order_poles(poles: &[C64]) -> Result<Vec<C64>, DesignError> {
    if poles
        .iter()
        .any(|p| !(p.re.is_finite() && p.im.is_finite()))
    {
        return Err(DesignError::Matrix(MatrixError::NonFinite(
            "requested pole",
        )));
    }
    let tol = |p: C64| 1e-10 * p.norm().max(1.0);
    let mut real = Vec::new();
    let mut upper = Vec::new();
    let mut lower = Vec::new();
    for &p in poles {
        if p.im.abs() <= tol(p) {
            real.push(C64::new(p.re, 0.0));
        } else if p.im > 0.0 {
            upper.push(p);
        } else {
            lower.push(p);
        }
    }
    let mut out = real;
    for p in upper {
        let k = lower
            .iter()
            .position(|q| (q.conj() - p).norm() <= tol(p))
            .ok_or_else(|| {
                DesignError::InvalidParameter(format!(
                    "complex pole {p} has no conjugate partner; a real gain needs conjugate pairs"
                ))
            })?;
        lower.swap_remove(k);
        out.push(p);
        out.push(p.conj());
    }
    if let Some(q) = lower.first() {
        return Err(DesignError::InvalidParameter(format!(
            "complex pole {q} has no conjugate partner; a real gain needs conjugate pairs"
        )));
    }
    Ok(out)
}

/// Indices of equal poles (within rounding), in order of first appearance.
fn group_poles(poles: &[C64]) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, p) in poles.iter().enumerate() {
        let tol = 1e-9 * p.norm().max(1.0);
        match groups.iter_mut().find(|g| (poles[g[0]] - p).norm() <= tol) {
            Some(g) => g.push(i),
            None => groups.push(vec![i]),
        }
    }
    groups
}

/// Dimension of the reachable subspace by an orthogonal staircase (Krylov
/// with re-orthonormalisation at every step), reported as the rank of W_c.
/// Unlike the rank of W_c itself this does not lose the small directions of
/// badly scaled models. B's columns are scaled to unit norm and the rank
/// threshold is relative to A − μI (μ = trace A / n), because a ZOH model at
/// a high sample rate is I plus a small matrix.
fn check_reachable(a: &DMatrix<f64>, b: &DMatrix<f64>) -> Result<(), DesignError> {
    let n = a.nrows();
    let mu = a.trace() / n as f64;
    let scale = (a - DMatrix::<f64>::identity(n, n) * mu)
        .norm()
        .max(f64::MIN_POSITIVE);
    let mut bs = b.clone();
    for mut col in bs.column_iter_mut() {
        let nrm = col.norm();
        if nrm > 0.0 {
            col /= nrm;
        }
    }
    let basis_of = |m: &DMatrix<f64>, tol: f64| -> Result<DMatrix<f64>, DesignError> {
        let svd = m
            .clone()
            .try_svd(true, false, f64::EPSILON, 1000 * n)
            .ok_or(crate::linalg::LinalgError::NoConvergence(
                "SVD in the reachability staircase",
            ))?;
        let r = svd.singular_values.iter().filter(|&&s| s > tol).count();
        let u = svd.u.ok_or(crate::linalg::LinalgError::NoConvergence(
            "SVD in the reachability staircase",
        ))?;
        Ok(u.columns(0, r).into_owned())
    };
    let mut q = basis_of(&bs, 1e-10)?;
    let mut new = q.clone();
    while q.ncols() < n && new.ncols() > 0 {
        let mut w = a * &new;
        for _ in 0..2 {
            let proj = &q * (q.transpose() * &w);
            w -= proj;
        }
        new = basis_of(&w, 1e-10 * scale)?;
        let mut grown = DMatrix::zeros(n, q.ncols() + new.ncols());
        grown.columns_mut(0, q.ncols()).copy_from(&q);
        grown.columns_mut(q.ncols(), new.ncols()).copy_from(&new);
        q = grown;
    }
    if q.ncols() < n {
        return Err(DesignError::NotReachable {
            rank: q.ncols(),
            states: n,
        });
    }
    Ok(())
}

/// Orthonormal basis (n × q, q ≥ m) of S = ker U1ᵀ(A − λI); real for a real λ,
/// so that real poles get real eigenvectors.
fn allowed_subspace(
    a: &DMatrix<f64>,
    u1: &DMatrix<f64>,
    lam: C64,
    m: usize,
) -> Result<DMatrix<C64>, DesignError> {
    let n = a.nrows();
    let nm = n - m;
    if nm == 0 {
        return Ok(DMatrix::identity(n, n));
    }
    let no_conv = crate::linalg::LinalgError::NoConvergence("SVD of U1ᵀ(A − λI)");
    if lam.im == 0.0 {
        let mut w = DMatrix::zeros(n, n);
        let shifted = a - DMatrix::<f64>::identity(n, n) * lam.re;
        w.view_mut((0, 0), (nm, n))
            .copy_from(&(u1.transpose() * shifted));
        let vt = w
            .try_svd(false, true, f64::EPSILON, 1000 * n)
            .ok_or(no_conv.clone())?
            .v_t
            .ok_or(no_conv)?;
        Ok(vt.rows(nm, m).transpose().map(|v| C64::new(v, 0.0)))
    } else {
        let ac = a.map(|v| C64::new(v, 0.0));
        let shifted = ac - DMatrix::<C64>::identity(n, n) * lam;
        let mut w = DMatrix::<C64>::zeros(n, n);
        w.view_mut((0, 0), (nm, n))
            .copy_from(&(u1.transpose().map(|v| C64::new(v, 0.0)) * shifted));
        let vt = w
            .try_svd(false, true, f64::EPSILON, 1000 * n)
            .ok_or(no_conv.clone())?
            .v_t
            .ok_or(no_conv)?;
        Ok(vt.rows(nm, m).adjoint())
    }
}

/// One KNV rank-one update of column j: the unit vector of S_j (basis `nb`)
/// closest to the orthogonal complement of the other columns of X.
fn knv_update(
    x: &DMatrix<C64>,
    j: usize,
    nb: &DMatrix<C64>,
    complex: bool,
) -> Result<Option<nalgebra::DVector<C64>>, DesignError> {
    let n = x.nrows();
    let mut others = x.clone();
    others.column_mut(j).fill(C64::new(0.0, 0.0));
    let no_conv = crate::linalg::LinalgError::NoConvergence("SVD in the KNV update");
    let svd = others
        .try_svd(true, false, f64::EPSILON, 1000 * n)
        .ok_or(no_conv.clone())?;
    let u = svd.u.ok_or(no_conv)?;
    let smax = svd.singular_values.max();
    let comp: Vec<usize> = (0..n)
        .filter(|&k| k == n - 1 || svd.singular_values[k] <= 1e-10 * smax)
        .collect();
    let uc = u.select_columns(&comp);
    let g = uc.adjoint() * nb;
    let h: nalgebra::DVector<C64> = if complex {
        let gh = g.adjoint() * &g;
        let gh = (&gh + gh.adjoint()) * C64::new(0.5, 0.0);
        top_eigenvector_hermitian(&gh)?
    } else {
        // Real pole: restrict to real combinations of the (real) basis.
        let h = (g.adjoint() * &g).map(|v| v.re);
        let h = (&h + h.transpose()) * 0.5;
        let e = SymmetricEigen::try_new(h, f64::EPSILON, 1000 * n).ok_or(
            crate::linalg::LinalgError::NoConvergence("eigen in KNV update"),
        )?;
        let k = e.eigenvalues.imax();
        e.eigenvectors.column(k).map(|v| C64::new(v, 0.0))
    };
    let v = nb * h;
    let nrm = v.norm();
    if nrm.is_nan() || nrm <= 1e-12 {
        return Ok(None);
    }
    Ok(Some(v.unscale(nrm)))
}

/// Unit eigenvector of the largest eigenvalue of a Hermitian matrix (via
/// the SVD, whose first right singular vector it is for a PSD matrix).
fn top_eigenvector_hermitian(h: &DMatrix<C64>) -> Result<nalgebra::DVector<C64>, DesignError> {
    let n = h.nrows();
    let no_conv = crate::linalg::LinalgError::NoConvergence("SVD in the KNV update");
    let vt = h
        .clone()
        .try_svd(false, true, f64::EPSILON, 1000 * n.max(1))
        .ok_or(no_conv.clone())?
        .v_t
        .ok_or(no_conv)?;
    Ok(vt.row(0).adjoint())
}

/// κ₂ of X (columns are unit vectors).
fn condition(x: &DMatrix<C64>) -> Result<f64, DesignError> {
    if x.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return Err(DesignError::Matrix(MatrixError::NonFinite(
            "eigenvector matrix",
        )));
    }
    let sv = x
        .clone()
        .try_svd(false, false, f64::EPSILON, 1000 * x.nrows())
        .ok_or(crate::linalg::LinalgError::NoConvergence("SVD of X"))?
        .singular_values;
    let smin = sv.min();
    Ok(if smin > 0.0 {
        sv.max() / smin
    } else {
        f64::INFINITY
    })
}

/// Largest distance from a requested pole to its achieved eigenvalue
/// (greedy nearest matching).
fn pole_error(acl: &DMatrix<f64>, poles: &[C64]) -> Result<f64, DesignError> {
    let mut ev = eigenvalues(acl)?;
    let mut worst: f64 = 0.0;
    for p in poles {
        let (k, d) = ev
            .iter()
            .enumerate()
            .map(|(k, z)| (k, (z - p).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .ok_or(DesignError::InvalidParameter(
                "no closed-loop eigenvalues".into(),
            ))?;
        worst = worst.max(d);
        ev.swap_remove(k);
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::linalg::discrete_pole_to_continuous;
    use crate::models::mimo_example;
    use std::f64::consts::PI;

    /// The 2×2 MIMO example (2 rigid + 3 flexible modes, 161/517/760 Hz),
    /// ZOH at 5 kHz.
    fn mimo() -> crate::lti::DiscreteStateSpace {
        zoh(&mimo_example().unwrap().state_space(), 2e-4).unwrap()
    }

    /// z = e^{s Ts} for the poles of s² + 2ζω s + ω², ω = 2π f.
    fn pair(f: f64, zeta: f64, ts: f64) -> [C64; 2] {
        let w = 2.0 * PI * f;
        let s = C64::new(-zeta * w, w * (1.0 - zeta * zeta).sqrt());
        let z = (s * ts).exp();
        [z, z.conj()]
    }

    #[test]
    fn mimo_state_feedback_lands_the_poles() {
        let p = mimo();
        let ts = p.ts;
        // Rigid modes to 40 and 60 Hz (ζ 0.7), flexible modes damped to ζ 0.1.
        let mut poles = Vec::new();
        for (f, z) in [
            (40.0, 0.7),
            (60.0, 0.7),
            (161.0, 0.1),
            (517.0, 0.1),
            (760.0, 0.1),
        ] {
            poles.extend(pair(f, z, ts));
        }
        let d = robust_place(&p.a, &p.b, &poles).unwrap();
        let acl = &p.a - &p.b * &d.gain;
        let ev = eigenvalues(&acl).unwrap();
        for want in &poles {
            let best = ev
                .iter()
                .map(|z| (z - want).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-9, "pole {want} missed by {best}");
        }
        let (w, zeta) = discrete_pole_to_continuous(poles[4], ts);
        assert!((w / (2.0 * PI) - 161.0).abs() < 1e-9 && (zeta - 0.1).abs() < 1e-12);
        let (k0, k) = (
            d.initial_condition.unwrap(),
            d.eigenvector_condition.unwrap(),
        );
        eprintln!(
            "MIMO placement: κ(X) {k0:.3e} → {k:.3e} in {} sweeps, max pole error {:.2e}, |L| {:.3e}",
            d.sweeps,
            d.max_pole_error,
            d.gain.norm()
        );
        // Measured: κ(X) = 7.5e3 after 6 sweeps (the first choice is singular,
        // because the example splits into two single-input subsystems).
        assert!(k <= k0 && k < 1e5, "κ(X) = {k:e}");
    }

    #[test]
    fn repeated_poles_up_to_rank_b_and_observers() {
        let p = mimo();
        // A double real pole and a double complex pair (2 inputs): allowed.
        let mut poles = vec![C64::new(0.5, 0.0); 2];
        poles.extend(pair(50.0, 0.6, p.ts));
        poles.extend(pair(50.0, 0.6, p.ts));
        poles.extend(pair(200.0, 0.6, p.ts));
        poles.extend(pair(300.0, 0.6, p.ts));
        let d = robust_place(&p.a, &p.b, &poles).unwrap();
        assert!(d.max_pole_error < 1e-8, "{}", d.max_pole_error);
        // Three times is more than rank B = 2.
        let mut three = poles.clone();
        three[9] = C64::new(0.5, 0.0);
        three[8] = C64::new(0.2, 0.0);
        let err = robust_place(&p.a, &p.b, &three).unwrap_err();
        assert!(
            matches!(&err, DesignError::InvalidParameter(s) if s.contains("3 times")),
            "{err}"
        );
        // Every pole twice is impossible here: the example's inputs drive a
        // symmetric (6-state) and an antisymmetric (4-state) subsystem
        // separately, and each double pole needs one eigenvector in each, so
        // five would have to fit in the 4-dimensional antisymmetric part.
        let mut twice = vec![C64::new(0.5, 0.0); 2];
        for f in [50.0, 200.0] {
            twice.extend(pair(f, 0.6, p.ts));
            twice.extend(pair(f, 0.6, p.ts));
        }
        let err = robust_place(&p.a, &p.b, &twice).unwrap_err();
        assert!(
            matches!(&err, DesignError::InvalidParameter(s) if s.contains("κ(X)")),
            "{err}"
        );
        // Observer on (A, C): two outputs.
        let mut obs = Vec::new();
        for (f, z) in [
            (300.0, 0.7),
            (350.0, 0.7),
            (161.0, 0.3),
            (517.0, 0.3),
            (760.0, 0.3),
        ] {
            obs.extend(pair(f, z, p.ts));
        }
        let o = robust_place_observer(&p.a, &p.c, &obs).unwrap();
        assert_eq!(o.gain.shape(), (10, 2));
        let ev = eigenvalues(&(&p.a - &o.gain * &p.c)).unwrap();
        for want in &obs {
            let best = ev
                .iter()
                .map(|z| (z - want).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-9, "observer pole {want} missed by {best}");
        }
    }

    #[test]
    fn single_input_matches_ackermann() {
        let d = crate::lecture::lecture_example(0.44).unwrap();
        let poles = pair(1.0 / (2.0 * PI), 0.7, 0.44);
        let r = robust_place(&d.plant.a, &d.plant.b, &poles).unwrap();
        assert!((&r.gain - &d.l).amax() < 1e-9, "{} vs {}", r.gain, d.l);
        // Deadbeat (a repeated pole) goes through Ackermann.
        let db = robust_place(&d.plant.a, &d.plant.b, &[C64::new(0.0, 0.0); 2]).unwrap();
        let h = 0.44;
        assert!((db.gain[(0, 0)] - 1.0 / (h * h)).abs() < 1e-9);
        assert!(db.eigenvector_condition.is_none());
    }

    #[test]
    fn bad_input_is_refused() {
        let p = mimo();
        let ok: Vec<C64> = (0..10).map(|k| C64::new(0.1 * k as f64, 0.0)).collect();
        // Wrong count.
        assert!(matches!(
            robust_place(&p.a, &p.b, &ok[..9]),
            Err(DesignError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
        // Lonely complex pole.
        let mut lonely = ok.clone();
        lonely[0] = C64::new(0.1, 0.2);
        assert!(matches!(
            robust_place(&p.a, &p.b, &lonely),
            Err(DesignError::InvalidParameter(s)) if s.contains("conjugate")
        ));
        // NaN pole and NaN matrix.
        let mut nan = ok.clone();
        nan[3] = C64::new(f64::NAN, 0.0);
        assert_eq!(
            robust_place(&p.a, &p.b, &nan),
            Err(DesignError::Matrix(MatrixError::NonFinite(
                "requested pole"
            )))
        );
        let mut a = p.a.clone();
        a[(0, 0)] = f64::INFINITY;
        assert_eq!(
            robust_place(&a, &p.b, &ok),
            Err(DesignError::Matrix(MatrixError::NonFinite("A")))
        );
        // An actuator pair that cannot move the second rigid mode.
        let mut b = p.b.clone();
        let col0 = b.column(0).into_owned();
        b.set_column(1, &(col0 * 2.0));
        assert!(matches!(
            robust_place(&p.a, &b, &ok),
            Err(DesignError::InvalidParameter(s)) if s.contains("dependent")
        ));
        let mut b1 = p.b.columns(0, 1).into_owned();
        b1.rows_mut(2, 2).fill(0.0); // mode 1 (rotation) no longer actuated
        assert!(matches!(
            robust_place(&p.a, &b1, &ok),
            Err(DesignError::NotReachable {
                rank: 8,
                states: 10
            })
        ));
        // Observer without the second sensor's rotation information.
        let c = p.c.rows(0, 1).into_owned();
        let mut c0 = c.clone();
        c0.columns_mut(2, 2).fill(0.0);
        assert!(matches!(
            robust_place_observer(&p.a, &c0, &ok),
            Err(DesignError::NotObservable {
                rank: 8,
                states: 10
            })
        ));
    }
}
