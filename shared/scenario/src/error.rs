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
            reason: readable_numbers(&reason.into()),
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

/// `message` with every long run of digits (a parser or a plain `{}`
/// prints 1e300 as three hundred of them) in exponent form.
fn readable_numbers(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
        let len = rest[start..]
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(rest.len() - start);
        let run = &rest[start..start + len];
        out.push_str(&rest[..start]);
        match run.parse::<f64>() {
            Ok(v) if run.len() > 20 => out.push_str(&number(v)),
            _ => out.push_str(run),
        }
        rest = &rest[start + len..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_numbers_in_a_reason_are_shown_in_exponent_form() {
        let e = ScenarioError::new("t.toml", Some("x"), format!("got {} and {}", 1e300, 5e-324));
        assert_eq!(e.reason, "got 1e300 and 5e-324");
        let e = ScenarioError::new("t.toml", Some("x"), "got 12.5 of 2000 at line 12");
        assert_eq!(e.reason, "got 12.5 of 2000 at line 12");
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(-1e300), "-1e300");
    }
}
