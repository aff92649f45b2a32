//! What the server asks of the loop it serves: its tunables and their
//! values, a change handed over through the swap path, and the scenario as
//! it stands. `flexloop` implements it with what `flexloop get`, `set` and
//! `status --scenario` do, so the command line and a Foxglove client change
//! the loop through one check and one hand-over.

/// A change that was made.
#[derive(Debug, Clone, PartialEq)]
pub struct SetOutcome {
    /// The fields whose values changed.
    pub fields: Vec<String>,
    /// What was done, in a line (old and new values, |Δu| at the switch).
    pub summary: String,
}

pub trait Tuner: Send + Sync + 'static {
    /// Every tunable and its current value (`None`: unset).
    fn values(&self) -> Result<Vec<(String, Option<toml::Value>)>, String>;
    /// Changes the fields (TOML value text) together, or says why not (the
    /// loop then runs on as it was).
    fn set(&self, changes: &[(String, String)]) -> Result<SetOutcome, String>;
    /// The scenario as it stands: its file and its TOML text.
    fn scenario(&self) -> Result<(String, String), String>;
    /// The design the scenario `text` (as [`Tuner::scenario`] gave it)
    /// runs, in words by part (`controller`, `observer`): what `"auto"`
    /// chose included. Asked only when the scenario changed.
    fn design(&self, file: &str, text: &str) -> Result<Vec<(String, String)>, String>;
}
