//! The error type of the observer and controller design functions (Kalman,
//! active damping, observer block, PID, pole placement, loop analysis).

use crate::dare::DareError;
use crate::discretise::DiscretiseError;
use crate::linalg::LinalgError;
use crate::lti::StateSpaceError;
use crate::matrix_error::MatrixError;
use crate::modal::ModelError;
use std::fmt;

/// Why a design was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum DesignError {
    /// A matrix or parameter does not fit or is not finite.
    Matrix(MatrixError),
    /// A parameter is outside its valid range.
    InvalidParameter(String),
    /// The pair (A, B) is not reachable (rank of W_c given).
    NotReachable {
        rank: usize,
        states: usize,
    },
    /// The pair (A, C) is not observable (rank of W_o given).
    NotObservable {
        rank: usize,
        states: usize,
    },
    /// A designed loop or observer is unstable.
    Unstable(String),
    Dare(DareError),
    Model(ModelError),
    Discretise(DiscretiseError),
    StateSpace(StateSpaceError),
    Linalg(LinalgError),
}

impl fmt::Display for DesignError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Matrix(e) => write!(f, "{e}"),
            Self::InvalidParameter(s) => write!(f, "invalid parameter: {s}"),
            Self::NotReachable { rank, states } => {
                write!(f, "not reachable: rank W_c = {rank} < {states}")
            }
            Self::NotObservable { rank, states } => {
                write!(f, "not observable: rank W_o = {rank} < {states}")
            }
            Self::Unstable(s) => write!(f, "unstable: {s}"),
            Self::Dare(e) => write!(f, "{e}"),
            Self::Model(e) => write!(f, "{e}"),
            Self::Discretise(e) => write!(f, "{e}"),
            Self::StateSpace(e) => write!(f, "{e}"),
            Self::Linalg(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DesignError {}

macro_rules! from_err {
    ($t:ty, $v:ident) => {
        impl From<$t> for DesignError {
            fn from(e: $t) -> Self {
                Self::$v(e)
            }
        }
    };
}
from_err!(MatrixError, Matrix);
from_err!(DareError, Dare);
from_err!(ModelError, Model);
from_err!(DiscretiseError, Discretise);
from_err!(StateSpaceError, StateSpace);
from_err!(LinalgError, Linalg);

/// Shape and finiteness check used by the design functions.
pub(crate) fn check_matrix(
    m: &nalgebra::DMatrix<f64>,
    what: &'static str,
    rows: usize,
    cols: usize,
) -> Result<(), DesignError> {
    Ok(crate::matrix_error::check_matrix(m, what, rows, cols)?)
}
