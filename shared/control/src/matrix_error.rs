//! The two ways a matrix argument is refused, one type for every error enum
//! of this crate that checks shapes and values (state spaces, models, the
//! DARE, the designs): each wraps it and says where it came from.

use nalgebra::DMatrix;
use std::fmt;

/// A matrix (or parameter) that does not fit or holds NaN or infinity.
#[derive(Debug, Clone, PartialEq)]
pub enum MatrixError {
    /// Matrix shapes do not fit together.
    DimensionMismatch {
        what: &'static str,
        expected: (usize, usize),
        found: (usize, usize),
    },
    /// A matrix or parameter holds NaN or infinity.
    NonFinite(&'static str),
}

impl fmt::Display for MatrixError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::DimensionMismatch {
                what,
                expected,
                found,
            } => write!(
                f,
                "{what} is {}x{} but must be {}x{}",
                found.0, found.1, expected.0, expected.1
            ),
            Self::NonFinite(what) => write!(f, "{what} holds a non-finite number"),
        }
    }
}

impl std::error::Error for MatrixError {}

/// `m` is `rows` × `cols` and finite.
pub fn check_matrix(
    m: &DMatrix<f64>,
    what: &'static str,
    rows: usize,
    cols: usize,
) -> Result<(), MatrixError> {
    if m.shape() != (rows, cols) {
        return Err(MatrixError::DimensionMismatch {
            what,
            expected: (rows, cols),
            found: m.shape(),
        });
    }
    if m.iter().any(|v| !v.is_finite()) {
        return Err(MatrixError::NonFinite(what));
    }
    Ok(())
}
