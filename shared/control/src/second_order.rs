//! A user's second-order model M q̈ + D q̇ + K q = B u, y = C q (a
//! finite-element export, an identified model, a lumped network) brought to
//! the mass-normalised modal form of [`crate::modal`] (docs/control.md §1.1).
//!
//! The eigen-part is [`ModalModel::from_nodal`] (actuators = B, sensors = C);
//! this module adds the checks that name the user's array, and the damping:
//! either modal ([`ModalDamping`], including Rayleigh α M + β K) or a damping
//! matrix D, whose modal form ΦᵀDΦ must be diagonal because the modal model
//! keeps one ζ per mode (docs/control.md (2.3): "damping is assumed
//! proportional").

use crate::modal::{ModalDamping, ModalModel, ModelError, NodalModel};
use crate::plant_model_error::{PlantModelError, PlantModelReason as R, check_array};
use nalgebra::{DMatrix, SymmetricEigen};

/// The largest coupling |(ΦᵀDΦ)_ij| / √(d_ii d_jj) between two modes that a
/// damping matrix may have. Dropping a coupling c moves the poles by about
/// c²·(damping) relative, i.e. by at most 1 % of the damping at 0.1; a
/// larger one means the damping is not proportional and the modal model
/// would misstate it.
pub const MAX_DAMPING_COUPLING: f64 = 0.1;

/// Modal entries of ΦᵀDΦ below this fraction of its largest diagonal entry
/// are rounding: a D built from modal data in floating point leaves about
/// 1e-13 of it on the rigid modes and between modes.
const DAMPING_ROUNDING: f64 = 1e-9;

/// Relative symmetry tolerance for M and K (as [`ModalModel::from_nodal`]).
const SYMMETRY_TOL: f64 = 1e-12;

/// M's smallest eigenvalue at or below this fraction of its largest makes
/// M singular (to working precision: Cholesky of such an M loses all digits).
const SINGULAR_MASS_TOL: f64 = 1e-12;

/// The modal model of M q̈ + D q̇ + K q = B u, y = C q: M (n×n, symmetric
/// positive definite), K (n×n, symmetric positive semi-definite), B (n×m,
/// force inputs), C (p×n, position outputs), and exactly one of a damping
/// matrix `d` (n×n) and modal `damping`. With D, flexible mode i gets
/// ζ_i = (ΦᵀDΦ)_ii / (2ω_i); a D that damps a rigid mode, couples two modes
/// by more than [`MAX_DAMPING_COUPLING`] or gives a ζ outside [0, 1) is
/// refused. Modes are numbered from 0 in the model's order (rigid first).
pub fn modal_from_second_order(
    m: &DMatrix<f64>,
    k: &DMatrix<f64>,
    d: Option<&DMatrix<f64>>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    damping: Option<ModalDamping>,
) -> Result<ModalModel, PlantModelError> {
    let n = m.nrows();
    if n == 0 {
        return Err(PlantModelError::new(
            "M",
            R::OutOfRange("has no degrees of freedom".into()),
        ));
    }
    check_array(m, "M", n, n)?;
    check_array(k, "K", n, n)?;
    check_array(b, "B", n, b.ncols())?;
    check_array(c, "C", c.nrows(), n)?;
    if let Some(d) = d {
        check_array(d, "D", n, n)?;
    }
    check_symmetric(m, "M")?;
    check_symmetric(k, "K")?;
    check_mass(m)?;
    let given = match (d, damping) {
        (None, None) => return Err(PlantModelError::new("D", R::DampingMissing)),
        (Some(_), Some(_)) => return Err(PlantModelError::new("D", R::DampingTwice)),
        (Some(_), None) => ModalDamping::Uniform(0.0),
        (None, Some(z)) => z,
    };
    let nodal = NodalModel {
        mass: m.clone(),
        stiffness: k.clone(),
        damping: given,
        actuators: b.clone(),
        sensors: c.clone(),
    };
    let mut modal = ModalModel::from_nodal(&nodal).map_err(|e| match e {
        ModelError::NegativeStiffness(l) => PlantModelError::new("K", R::NegativeStiffness(l)),
        ModelError::MassNotPositiveDefinite => PlantModelError::new("M", R::SingularMass),
        ModelError::InvalidDamping(s) => PlantModelError::new("damping", R::InvalidDamping(s)),
        other => PlantModelError::new("M", R::Model(other)),
    })?;
    if let Some(d) = d {
        align_repeated_modes(&mut modal, d, b, c);
        modal.zeta = zeta_from_damping_matrix(&modal, d)?;
    }
    Ok(modal)
}

fn check_symmetric(m: &DMatrix<f64>, array: &'static str) -> Result<(), PlantModelError> {
    let scale = m.amax().max(f64::MIN_POSITIVE);
    if (m - m.transpose()).amax() > SYMMETRY_TOL * scale {
        return Err(PlantModelError::new(array, R::NotSymmetric));
    }
    Ok(())
}

/// Tells a singular M (a massless degree of freedom, common in finite-element
/// exports with rotational DOFs) from an indefinite one.
fn check_mass(m: &DMatrix<f64>) -> Result<(), PlantModelError> {
    let n = m.nrows();
    let sym = (m + m.transpose()) * 0.5;
    let eig = SymmetricEigen::try_new(sym, f64::EPSILON, 1000 * n).ok_or(PlantModelError::new(
        "M",
        R::NoConvergence("eigenvalues of M"),
    ))?;
    let max = eig.eigenvalues.iter().copied().fold(0.0, f64::max);
    let min = eig
        .eigenvalues
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    if min < -SINGULAR_MASS_TOL * max {
        return Err(PlantModelError::new("M", R::IndefiniteMass));
    }
    if min <= SINGULAR_MASS_TOL * max {
        return Err(PlantModelError::new("M", R::SingularMass));
    }
    Ok(())
}

/// Flexible modes whose frequencies agree to this fraction are one repeated
/// frequency, within which the mode shapes are any orthonormal (in M) basis.
const REPEATED_FREQUENCY_TOL: f64 = 1e-9;

/// Within each repeated flexible frequency, turns the mode shapes to the
/// eigenvectors of that block of ΦᵀDΦ: the symmetric eigen-solver returns an
/// arbitrary basis of a repeated eigenspace (two equal bending directions),
/// in which a D that is proportional in the structure's own directions (e.g.
/// different dampers along two equal springs) would look coupled. The
/// rotation is orthogonal, so Φ stays mass-normalised and Ω unchanged; the
/// sign of each mode follows [`crate::modal`] again.
fn align_repeated_modes(
    modal: &mut ModalModel,
    d: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
) {
    let Some(mut phi) = modal.shapes.clone() else {
        return;
    };
    let n = modal.modes();
    let mut start = modal.n_rigid;
    let mut changed = false;
    while start < n {
        let mut end = start + 1;
        while end < n
            && modal.omega[end] - modal.omega[start] <= REPEATED_FREQUENCY_TOL * modal.omega[start]
        {
            end += 1;
        }
        if end - start > 1 {
            let group = phi.columns(start, end - start).into_owned();
            let block = group.transpose() * d * &group;
            let sym = (&block + block.transpose()) * 0.5;
            if let Some(eig) = SymmetricEigen::try_new(sym, f64::EPSILON, 1000 * (end - start)) {
                let mut order: Vec<usize> = (0..end - start).collect();
                order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
                let turned = &group * eig.eigenvectors.select_columns(&order);
                for (col, v) in turned.column_iter().enumerate() {
                    let mut v = v.into_owned();
                    let gain = if b.ncols() > 0 {
                        b.column(0).dot(&v)
                    } else {
                        0.0
                    };
                    let reference = if gain.abs() > 1e-9 * v.amax() {
                        gain
                    } else {
                        v[v.iamax()]
                    };
                    if reference < 0.0 {
                        v = -v;
                    }
                    phi.set_column(start + col, &v);
                }
                changed = true;
            }
        }
        start = end;
    }
    if changed {
        modal.phi_a = phi.transpose() * b;
        modal.phi_s = c * &phi;
        modal.shapes = Some(phi);
    }
}

/// ζ per mode from the modal damping matrix ΦᵀDΦ (docs/control.md (2.3)).
fn zeta_from_damping_matrix(
    modal: &ModalModel,
    d: &DMatrix<f64>,
) -> Result<Vec<f64>, PlantModelError> {
    let phi = modal.shapes.as_ref().ok_or(PlantModelError::new(
        "D",
        R::Model(ModelError::NoModeShapes),
    ))?;
    let dm = phi.transpose() * d * phi;
    let n = dm.nrows();
    let floor = DAMPING_ROUNDING * dm.diagonal().amax();
    for i in 0..modal.n_rigid {
        if dm[(i, i)].abs() > floor {
            return Err(PlantModelError::new("D", R::RigidModeDamped { mode: i }));
        }
    }
    for i in 0..n {
        for j in i + 1..n {
            let off = dm[(i, j)].abs().max(dm[(j, i)].abs());
            let bound = MAX_DAMPING_COUPLING * (dm[(i, i)] * dm[(j, j)]).abs().sqrt();
            if off > bound + floor {
                let scale = (dm[(i, i)] * dm[(j, j)]).abs().sqrt();
                return Err(PlantModelError::new(
                    "D",
                    R::NonProportionalDamping {
                        modes: (i, j),
                        coupling: off / scale,
                    },
                ));
            }
        }
    }
    let mut zeta = vec![0.0; n];
    for i in modal.n_rigid..n {
        let z = dm[(i, i)] / (2.0 * modal.omega[i]);
        if !(0.0..1.0).contains(&z) {
            return Err(PlantModelError::new(
                "D",
                R::DampingOutOfRange { mode: i, zeta: z },
            ));
        }
        zeta[i] = z;
    }
    Ok(zeta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant_model_error::PlantModelReason;

    /// Two masses (1 and 2 kg) on a 100 N/m spring; `grounded` adds a
    /// 50 N/m spring from mass 0 to the ground (no rigid mode then).
    fn two_mass(grounded: bool) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
        let m = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 2.0]);
        let g = if grounded { 50.0 } else { 0.0 };
        let k = DMatrix::from_row_slice(2, 2, &[100.0 + g, -100.0, -100.0, 100.0]);
        let b = DMatrix::from_column_slice(2, 1, &[1.0, 0.0]);
        let c = DMatrix::identity(2, 2);
        (m, k, b, c)
    }

    fn refused(
        m: &DMatrix<f64>,
        k: &DMatrix<f64>,
        d: Option<&DMatrix<f64>>,
        damping: Option<ModalDamping>,
    ) -> PlantModelError {
        let (_, _, b, c) = two_mass(false);
        modal_from_second_order(m, k, d, &b, &c, damping).unwrap_err()
    }

    #[test]
    fn exactly_one_damping() {
        let (m, k, _, _) = two_mass(false);
        let e = refused(&m, &k, None, None);
        assert_eq!(
            e,
            PlantModelError::new("D", PlantModelReason::DampingMissing)
        );
        assert!(e.to_string().starts_with("D: no damping"));
        let d = DMatrix::zeros(2, 2);
        let e = refused(&m, &k, Some(&d), Some(ModalDamping::Uniform(0.01)));
        assert_eq!(e, PlantModelError::new("D", PlantModelReason::DampingTwice));
    }

    #[test]
    fn mass_and_stiffness_checks_name_the_array() {
        let z = Some(ModalDamping::Uniform(0.01));
        let (m, k, _, _) = two_mass(false);
        let mut bad = m.clone();
        bad[(0, 1)] = 0.5;
        assert_eq!(refused(&bad, &k, None, z.clone()).array, "M");
        assert_eq!(
            refused(&bad, &k, None, z.clone()).reason,
            PlantModelReason::NotSymmetric
        );
        let mut bad = k.clone();
        bad[(0, 1)] = -90.0;
        assert_eq!(
            refused(&m, &bad, None, z.clone()),
            PlantModelError::new("K", PlantModelReason::NotSymmetric)
        );
        let mut bad = m.clone();
        bad[(1, 1)] = 0.0;
        let e = refused(&bad, &k, None, z.clone());
        assert_eq!(e, PlantModelError::new("M", PlantModelReason::SingularMass));
        assert!(e.to_string().contains("M: is singular"));
        bad[(1, 1)] = -1.0;
        assert_eq!(
            refused(&bad, &k, None, z.clone()).reason,
            PlantModelReason::IndefiniteMass
        );
        let bad = -&k;
        assert!(matches!(
            refused(&m, &bad, None, z.clone()),
            PlantModelError {
                array: "K",
                reason: PlantModelReason::NegativeStiffness(_)
            }
        ));
        let mut bad = k.clone();
        bad[(0, 0)] = f64::NAN;
        assert_eq!(
            refused(&m, &bad, None, z.clone()),
            PlantModelError::new("K", PlantModelReason::NonFinite)
        );
        let e = refused(&m, &DMatrix::zeros(3, 3), None, z.clone());
        assert_eq!(e.array, "K");
        assert!(e.to_string().contains("is 3x3 but must be 2x2"));
        let (_, _, b, c) = two_mass(false);
        let e = modal_from_second_order(&m, &k, None, &b.transpose(), &c, z.clone());
        assert_eq!(e.unwrap_err().array, "B");
        let e = modal_from_second_order(&m, &k, None, &b, &DMatrix::zeros(1, 3), z);
        assert_eq!(e.unwrap_err().array, "C");
    }

    #[test]
    fn damping_matrix_gives_modal_zeta() {
        // Rayleigh D = αM + βK on the grounded pair: ζ_i = α/(2ω_i) + βω_i/2,
        // the same as the modal Rayleigh variant.
        let (m, k, b, c) = two_mass(true);
        let (alpha, beta) = (0.3, 2e-3);
        let d = &m * alpha + &k * beta;
        let got = modal_from_second_order(&m, &k, Some(&d), &b, &c, None).unwrap();
        let want = modal_from_second_order(
            &m,
            &k,
            None,
            &b,
            &c,
            Some(ModalDamping::Rayleigh { alpha, beta }),
        )
        .unwrap();
        assert_eq!(got.n_rigid, 0);
        for i in 0..2 {
            let z = alpha / (2.0 * got.omega[i]) + beta * got.omega[i] / 2.0;
            assert!((got.zeta[i] - z).abs() < 1e-12);
            assert!((want.zeta[i] - z).abs() < 1e-12);
        }
    }

    #[test]
    fn refuses_damping_the_modal_model_cannot_hold() {
        // A damper from mass 0 to the ground damps the rigid mode.
        let (m, k, _, _) = two_mass(false);
        let d = DMatrix::from_row_slice(2, 2, &[3.0, 0.0, 0.0, 0.0]);
        let e = refused(&m, &k, Some(&d), None);
        assert_eq!(
            e,
            PlantModelError::new("D", PlantModelReason::RigidModeDamped { mode: 0 })
        );
        assert!(e.to_string().contains("damper to ground"));
        // The same damper on the grounded pair couples its two modes.
        let (m, k, b, c) = two_mass(true);
        let e = modal_from_second_order(&m, &k, Some(&d), &b, &c, None).unwrap_err();
        match e.reason {
            PlantModelReason::NonProportionalDamping { modes, coupling } => {
                assert_eq!(modes, (0, 1));
                assert!((coupling - 1.0).abs() < 1e-9, "coupling {coupling}");
            }
            other => panic!("{other:?}"),
        }
        assert!(e.to_string().contains("Rayleigh"));
        // A damper so large that a mode is overdamped.
        let d = &k * 10.0;
        let e = modal_from_second_order(&m, &k, Some(&d), &b, &c, None).unwrap_err();
        assert!(matches!(
            e.reason,
            PlantModelReason::DampingOutOfRange { mode: 0, .. }
        ));
        // Rayleigh α on a free structure damps its rigid mode.
        let (m, k, b, c) = two_mass(false);
        let r = Some(ModalDamping::Rayleigh {
            alpha: 0.1,
            beta: 0.0,
        });
        let e = modal_from_second_order(&m, &k, None, &b, &c, r).unwrap_err();
        assert_eq!(e.array, "damping");
        assert!(e.to_string().contains("α = 0"), "{e}");
    }
}
