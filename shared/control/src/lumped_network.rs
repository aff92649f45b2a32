//! Lumped mass–spring–damper networks written by hand (the scenario's
//! `[plant]` masses, springs, dampers, forces and positions) assembled into
//! the nodal matrices M, K, D, B, C of [`crate::second_order`]
//! (docs/control.md §1.1, (2.1)).
//!
//! One degree of freedom per mass (a translation, or a rotation with the
//! inertia as "mass"); a spring or damper joins two masses or a mass and the
//! ground.

use crate::plant_model_error::{PlantModelError, PlantModelReason as R};
use nalgebra::DMatrix;

/// Where a force acts or a position is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attach {
    /// On mass i: the force f on mass i, or the position q_i.
    At(usize),
    /// Between masses i and j: the force pair +f on j and −f on i (an
    /// actuator pushing the two apart), or the relative position q_j − q_i.
    Between(usize, usize),
}

/// An element joining mass `.0` to mass `.1` (or to the ground when `None`)
/// with stiffness [N/m] or damping [N s/m] `.2`.
pub type Element = (usize, Option<usize>, f64);

/// The nodal matrices of a lumped network: M q̈ + D q̇ + K q = B u, y = C q.
#[derive(Debug, Clone, PartialEq)]
pub struct LumpedNetwork {
    /// Diagonal mass matrix (n × n).
    pub m: DMatrix<f64>,
    /// Stiffness matrix (n × n).
    pub k: DMatrix<f64>,
    /// Damping matrix (n × n), `None` when the network has no dampers (then
    /// its damping is modal, given separately).
    pub d: Option<DMatrix<f64>>,
    /// Force inputs (n × forces).
    pub b: DMatrix<f64>,
    /// Position outputs (positions × n).
    pub c: DMatrix<f64>,
}

/// Assembles a lumped network. Errors name the list ("masses", "springs",
/// "dampers", "forces", "positions") and the entry (from 0): a mass that is
/// not positive, an element joining a mass to itself or to a mass that does
/// not exist, a negative stiffness or damping, a force or position between a
/// mass and itself.
pub fn lumped_network(
    masses: &[f64],
    springs: &[Element],
    dampers: &[Element],
    forces: &[Attach],
    positions: &[Attach],
) -> Result<LumpedNetwork, PlantModelError> {
    let n = masses.len();
    if n == 0 {
        return Err(PlantModelError::new(
            "masses",
            R::OutOfRange("the network has no masses".into()),
        ));
    }
    for (i, &mi) in masses.iter().enumerate() {
        if !mi.is_finite() {
            return Err(PlantModelError::new("masses", R::NonFinite));
        }
        if mi <= 0.0 {
            return Err(PlantModelError::new(
                "masses",
                R::OutOfRange(format!("mass {i} is {mi}: every mass must be positive")),
            ));
        }
    }
    let m = DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(masses));
    let k = assemble(n, springs, "springs", "stiffness")?;
    let d = if dampers.is_empty() {
        None
    } else {
        Some(assemble(n, dampers, "dampers", "damping")?)
    };
    let mut b = DMatrix::zeros(n, forces.len());
    for (col, at) in forces.iter().enumerate() {
        match *at {
            Attach::At(i) => b[(check_mass_index(n, i, "forces", col)?, col)] = 1.0,
            Attach::Between(i, j) => {
                let (i, j) = check_pair(n, i, j, "forces", col)?;
                b[(i, col)] = -1.0;
                b[(j, col)] = 1.0;
            }
        }
    }
    let mut c = DMatrix::zeros(positions.len(), n);
    for (row, at) in positions.iter().enumerate() {
        match *at {
            Attach::At(i) => c[(row, check_mass_index(n, i, "positions", row)?)] = 1.0,
            Attach::Between(i, j) => {
                let (i, j) = check_pair(n, i, j, "positions", row)?;
                c[(row, i)] = -1.0;
                c[(row, j)] = 1.0;
            }
        }
    }
    Ok(LumpedNetwork { m, k, d, b, c })
}

/// Adds each element's 2×2 (or 1×1, to ground) stencil.
fn assemble(
    n: usize,
    elements: &[Element],
    list: &'static str,
    quantity: &str,
) -> Result<DMatrix<f64>, PlantModelError> {
    let mut out = DMatrix::zeros(n, n);
    for (e, &(i, j, v)) in elements.iter().enumerate() {
        if !v.is_finite() {
            return Err(PlantModelError::new(list, R::NonFinite));
        }
        if v < 0.0 {
            return Err(PlantModelError::new(
                list,
                R::OutOfRange(format!("entry {e} has negative {quantity} {v}")),
            ));
        }
        let i = check_mass_index(n, i, list, e)?;
        out[(i, i)] += v;
        if let Some(j) = j {
            let j = check_mass_index(n, j, list, e)?;
            if i == j {
                return Err(PlantModelError::new(
                    list,
                    R::OutOfRange(format!("entry {e} joins mass {i} to itself")),
                ));
            }
            out[(j, j)] += v;
            out[(i, j)] -= v;
            out[(j, i)] -= v;
        }
    }
    Ok(out)
}

fn check_mass_index(
    n: usize,
    i: usize,
    list: &'static str,
    entry: usize,
) -> Result<usize, PlantModelError> {
    if i >= n {
        return Err(PlantModelError::new(
            list,
            R::OutOfRange(format!(
                "entry {entry} names mass {i}, but the masses are 0..{}",
                n - 1
            )),
        ));
    }
    Ok(i)
}

fn check_pair(
    n: usize,
    i: usize,
    j: usize,
    list: &'static str,
    entry: usize,
) -> Result<(usize, usize), PlantModelError> {
    let i = check_mass_index(n, i, list, entry)?;
    let j = check_mass_index(n, j, list, entry)?;
    if i == j {
        return Err(PlantModelError::new(
            list,
            R::OutOfRange(format!("entry {entry} is between mass {i} and itself")),
        ));
    }
    Ok((i, j))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assembles_the_nodal_matrices() {
        // Mass 0 grounded by 5 N/m, 0–1 by 100 N/m and 2 N s/m; a force on
        // mass 0 and a pair between 0 and 1; q_1 and q_1 − q_0 measured.
        let net = lumped_network(
            &[1.0, 2.0],
            &[(0, None, 5.0), (0, Some(1), 100.0)],
            &[(1, Some(0), 2.0)],
            &[Attach::At(0), Attach::Between(0, 1)],
            &[Attach::At(1), Attach::Between(0, 1)],
        )
        .unwrap();
        assert_eq!(net.m, DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 2.0]));
        assert_eq!(
            net.k,
            DMatrix::from_row_slice(2, 2, &[105.0, -100.0, -100.0, 100.0])
        );
        assert_eq!(
            net.d,
            Some(DMatrix::from_row_slice(2, 2, &[2.0, -2.0, -2.0, 2.0]))
        );
        assert_eq!(net.b, DMatrix::from_row_slice(2, 2, &[1.0, -1.0, 0.0, 1.0]));
        assert_eq!(net.c, DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -1.0, 1.0]));
        let none = lumped_network(&[1.0], &[], &[], &[], &[]).unwrap();
        assert_eq!(none.d, None);
    }

    #[test]
    fn refuses_bad_networks() {
        let fails = |masses: &[f64],
                     springs: &[Element],
                     dampers: &[Element],
                     f: &[Attach],
                     p: &[Attach]| {
            lumped_network(masses, springs, dampers, f, p).unwrap_err()
        };
        let e = fails(&[], &[], &[], &[], &[]);
        assert_eq!(e.array, "masses");
        let e = fails(&[1.0, 0.0], &[], &[], &[], &[]);
        assert_eq!(e.array, "masses");
        assert!(e.to_string().contains("mass 1 is 0"), "{e}");
        assert_eq!(fails(&[1.0, -2.0], &[], &[], &[], &[]).array, "masses");
        assert_eq!(fails(&[f64::NAN], &[], &[], &[], &[]).reason, R::NonFinite);
        let e = fails(&[1.0, 1.0], &[(0, Some(2), 1.0)], &[], &[], &[]);
        assert_eq!(e.array, "springs");
        assert!(e.to_string().contains("names mass 2"), "{e}");
        let e = fails(&[1.0, 1.0], &[(1, Some(1), 1.0)], &[], &[], &[]);
        assert!(e.to_string().contains("joins mass 1 to itself"), "{e}");
        let e = fails(&[1.0, 1.0], &[(0, Some(1), -1.0)], &[], &[], &[]);
        assert!(e.to_string().contains("negative stiffness"), "{e}");
        let e = fails(&[1.0, 1.0], &[], &[(0, None, -1.0)], &[], &[]);
        assert_eq!(e.array, "dampers");
        assert!(e.to_string().contains("negative damping"), "{e}");
        let e = fails(&[1.0, 1.0], &[], &[], &[Attach::At(5)], &[]);
        assert_eq!(e.array, "forces");
        let e = fails(&[1.0, 1.0], &[], &[], &[], &[Attach::Between(1, 1)]);
        assert_eq!(e.array, "positions");
        assert!(e.to_string().contains("between mass 1 and itself"), "{e}");
    }
}
