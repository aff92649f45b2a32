//! Discrete linear time-invariant systems and their allocation-free runner.
//!
//! Every per-sample block of the loop (plant emulator, observer, feedback
//! controller, filters) is compiled at design time into one
//! [`DiscreteStateSpace`]; the services then only run [`LtiRunner`]s. That keeps
//! the hot path to two matrix-vector products per block, with no branching on
//! the kind of block.

use crate::matrix_error::{MatrixError, check_matrix};
use nalgebra::{DMatrix, DVector, DVectorView};
use std::fmt;

/// x(k+1) = A x(k) + B u(k), y(k) = C x(k) + D u(k), sampled with period `ts`.
#[derive(Debug, Clone, PartialEq)]
pub struct DiscreteStateSpace {
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
    /// Sample period in seconds.
    pub ts: f64,
}

/// Why a state-space model was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum StateSpaceError {
    /// A matrix has the wrong shape for the others, or holds NaN or infinity.
    Matrix(MatrixError),
    /// The sample period is not a positive finite number.
    InvalidSamplePeriod(f64),
}

impl fmt::Display for StateSpaceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            // "matrix B is 2x3 but must be 2x2", as the message always read.
            Self::Matrix(e) => write!(f, "matrix {e}"),
            Self::InvalidSamplePeriod(ts) => {
                write!(f, "sample period {ts} s is not a positive finite number")
            }
        }
    }
}

impl std::error::Error for StateSpaceError {}

impl DiscreteStateSpace {
    /// Checks shapes and finiteness once, so that the runner never has to.
    pub fn new(
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        c: DMatrix<f64>,
        d: DMatrix<f64>,
        ts: f64,
    ) -> Result<Self, StateSpaceError> {
        let n = a.nrows();
        let m = b.ncols();
        let p = c.nrows();
        let check = |name, mat: &DMatrix<f64>, rows, cols| {
            check_matrix(mat, name, rows, cols).map_err(StateSpaceError::Matrix)
        };
        check("A", &a, n, n)?;
        check("B", &b, n, m)?;
        check("C", &c, p, n)?;
        check("D", &d, p, m)?;
        if !(ts.is_finite() && ts > 0.0) {
            return Err(StateSpaceError::InvalidSamplePeriod(ts));
        }
        Ok(Self { a, b, c, d, ts })
    }

    /// A static gain y = D u (no states).
    pub fn gain(d: DMatrix<f64>, ts: f64) -> Result<Self, StateSpaceError> {
        let (p, m) = d.shape();
        Self::new(
            DMatrix::zeros(0, 0),
            DMatrix::zeros(0, m),
            DMatrix::zeros(p, 0),
            d,
            ts,
        )
    }

    pub fn states(&self) -> usize {
        self.a.nrows()
    }
    pub fn inputs(&self) -> usize {
        self.b.ncols()
    }
    pub fn outputs(&self) -> usize {
        self.c.nrows()
    }
}

/// Runs a [`DiscreteStateSpace`] sample by sample without allocating.
///
/// One sample is split in two calls so that a service can publish the output
/// before it spends time on the state update: [`LtiRunner::output`] computes
/// y(k) = C x(k) + D u(k), [`LtiRunner::advance`] then moves to x(k+1).
#[derive(Debug, Clone)]
pub struct LtiRunner {
    sys: DiscreteStateSpace,
    x: DVector<f64>,
    x_next: DVector<f64>,
    y: DVector<f64>,
    free: DVector<f64>,
}

impl LtiRunner {
    pub fn new(sys: DiscreteStateSpace) -> Self {
        let n = sys.states();
        let p = sys.outputs();
        Self {
            x: DVector::zeros(n),
            x_next: DVector::zeros(n),
            y: DVector::zeros(p),
            free: DVector::zeros(p),
            sys,
        }
    }

    pub fn system(&self) -> &DiscreteStateSpace {
        &self.sys
    }

    pub fn state(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// Overwrites the state, e.g. to take over from another instance.
    ///
    /// # Panics
    /// If `x` does not have one entry per state (a design-time error).
    pub fn set_state(&mut self, x: &[f64]) {
        self.x.as_mut_slice().copy_from_slice(x);
    }

    /// Overwrites the leading `x.len()` states and keeps the rest (a
    /// block whose first states another design shares).
    ///
    /// # Panics
    /// If `x` is longer than the state (a design-time error).
    pub fn set_leading_state(&mut self, x: &[f64]) {
        self.x.as_mut_slice()[..x.len()].copy_from_slice(x);
    }

    pub fn reset(&mut self) {
        self.x.fill(0.0);
    }

    /// y(k) = C x(k) + D u(k).
    ///
    /// # Panics
    /// If `u` has fewer entries than the system has inputs.
    pub fn output(&mut self, u: &[f64]) -> &[f64] {
        let u = DVectorView::from_slice(&u[..self.sys.inputs()], self.sys.inputs());
        self.y.gemv(1.0, &self.sys.c, &self.x, 0.0);
        self.y.gemv(1.0, &self.sys.d, &u, 1.0);
        self.y.as_slice()
    }

    /// The free response C x(k): the part of y(k) that is known before u(k).
    pub fn free_output(&mut self) -> &[f64] {
        self.free.gemv(1.0, &self.sys.c, &self.x, 0.0);
        self.free.as_slice()
    }

    /// x(k+1) = A x(k) + B u(k).
    pub fn advance(&mut self, u: &[f64]) {
        let u = DVectorView::from_slice(&u[..self.sys.inputs()], self.sys.inputs());
        self.x_next.gemv(1.0, &self.sys.a, &self.x, 0.0);
        self.x_next.gemv(1.0, &self.sys.b, &u, 1.0);
        std::mem::swap(&mut self.x, &mut self.x_next);
    }

    /// Output then advance: one whole sample.
    pub fn step(&mut self, u: &[f64]) -> &[f64] {
        let u = DVectorView::from_slice(&u[..self.sys.inputs()], self.sys.inputs());
        self.y.gemv(1.0, &self.sys.c, &self.x, 0.0);
        self.y.gemv(1.0, &self.sys.d, &u, 1.0);
        self.x_next.gemv(1.0, &self.sys.a, &self.x, 0.0);
        self.x_next.gemv(1.0, &self.sys.b, &u, 1.0);
        std::mem::swap(&mut self.x, &mut self.x_next);
        self.y.as_slice()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn integrator() -> DiscreteStateSpace {
        DiscreteStateSpace::new(
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 0.5),
            DMatrix::from_element(1, 1, 2.0),
            DMatrix::from_element(1, 1, 1.0),
            1e-4,
        )
        .unwrap()
    }

    #[test]
    fn step_matches_hand_computation() {
        let mut r = LtiRunner::new(integrator());
        assert_eq!(r.step(&[1.0]), &[1.0]); // x=0: y = D u
        assert_eq!(r.state(), &[0.5]);
        assert_eq!(r.output(&[0.0]), &[1.0]); // y = 2 * 0.5
        r.advance(&[2.0]);
        assert_eq!(r.state(), &[1.5]);
        assert_eq!(r.free_output(), &[3.0]);
    }

    #[test]
    fn rejects_wrong_shapes_and_non_finite() {
        let err = DiscreteStateSpace::new(
            DMatrix::zeros(2, 2),
            DMatrix::zeros(3, 1),
            DMatrix::zeros(1, 2),
            DMatrix::zeros(1, 1),
            1e-4,
        )
        .unwrap_err();
        assert!(matches!(
            err,
            StateSpaceError::Matrix(MatrixError::DimensionMismatch { what: "B", .. })
        ));
        let err = DiscreteStateSpace::new(
            DMatrix::from_element(1, 1, f64::NAN),
            DMatrix::zeros(1, 1),
            DMatrix::zeros(1, 1),
            DMatrix::zeros(1, 1),
            1e-4,
        )
        .unwrap_err();
        assert_eq!(err, StateSpaceError::Matrix(MatrixError::NonFinite("A")));
        assert!(DiscreteStateSpace::gain(DMatrix::zeros(1, 1), 0.0).is_err());
    }
}
