//! Scenario errors: file, field, reason.

use std::fmt;
use std::path::PathBuf;

/// A scenario that cannot be run, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioError {
    pub file: PathBuf,
    /// Dotted path of the offending field (`plant.mass_kg`), if one is to blame.
    pub field: Option<String>,
    pub reason: String,
}

impl ScenarioError {
    pub fn new(file: impl Into<PathBuf>, field: Option<&str>, reason: impl Into<String>) -> Self {
        Self {
            file: file.into(),
            field: field.map(str::to_string),
            reason: reason.into(),
        }
    }
}

impl fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.field {
            Some(field) => write!(
                f,
                "scenario {}: field `{}`: {}",
                self.file.display(),
                field,
                self.reason
            ),
            None => write!(f, "scenario {}: {}", self.file.display(), self.reason),
        }
    }
}

impl std::error::Error for ScenarioError {}

/// `v` as a reader wants it in a message: plainly for everyday magnitudes,
/// in exponent form beyond them (1e300, not three hundred digits).
pub fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e7).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}
