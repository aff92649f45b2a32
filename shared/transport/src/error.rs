//! The one error of this crate: which channel, which step, and why.

use std::fmt;

/// Opening or using a channel failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TransportError {
    /// Channel or node the failure concerns.
    pub subject: String,
    /// What was being done ("open publish-subscribe service", "send", ...).
    pub action: &'static str,
    /// The iceoryx2 error, as text.
    pub reason: String,
}

impl TransportError {
    pub(crate) fn new(
        subject: impl Into<String>,
        action: &'static str,
        reason: impl fmt::Debug,
    ) -> Self {
        Self {
            subject: subject.into(),
            action,
            reason: format!("{reason:?}"),
        }
    }
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} failed: {}",
            self.subject, self.action, self.reason
        )
    }
}

impl std::error::Error for TransportError {}
