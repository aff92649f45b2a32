//! The error of the per-sample runners added next to [`crate::lti::LtiRunner`]
//! (scheduled Kalman filters, input–output observer).
//!
//! A per-sample call checks its slices and numbers instead of panicking; when
//! it refuses, the runner's state is left as it was, so a caller can skip one
//! bad sample and go on. The type is `Copy` and its construction never
//! allocates, so the check itself stays on the allocation-free path.

use std::fmt;

/// Why a per-sample call was refused (the runner's state is unchanged).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepError {
    /// A slice has the wrong number of entries.
    Length {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    /// An input holds NaN or infinity.
    NonFinite(&'static str),
    /// The scheduling position lies outside the precomputed grid.
    PositionOutOfRange { position: f64, min: f64, max: f64 },
    /// A matrix that must be positive definite is not (e.g. the innovation
    /// covariance of a time-varying Kalman filter after a numerical blow-up).
    NotPositiveDefinite(&'static str),
}

impl fmt::Display for StepError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Length {
                what,
                expected,
                found,
            } => write!(f, "{what} has {found} entries but must have {expected}"),
            Self::NonFinite(what) => write!(f, "{what} holds a non-finite number"),
            Self::PositionOutOfRange { position, min, max } => write!(
                f,
                "scheduling position {position} outside the grid [{min}, {max}]"
            ),
            Self::NotPositiveDefinite(what) => write!(f, "{what} is not positive definite"),
        }
    }
}

impl std::error::Error for StepError {}

/// Length and finiteness check of one per-sample input slice.
pub(crate) fn check_slice(v: &[f64], what: &'static str, expected: usize) -> Result<(), StepError> {
    if v.len() != expected {
        return Err(StepError::Length {
            what,
            expected,
            found: v.len(),
        });
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(StepError::NonFinite(what));
    }
    Ok(())
}
