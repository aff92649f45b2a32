//! What a law of one's own (a controller's or an observer's) is built
//! from, why it could not be, and the small state it may hand a successor
//! (docs/components.md).

use flexloop_design::LoopDesign;
use flexloop_protocol::{Handover, MAX_HANDOVER_STATES};
use flexloop_scenario::{ProgramRole, Scenario};
use std::fmt;
use std::path::PathBuf;

/// What a law is built from: the scenario as the loop runs it, its design
/// (the observer's block the estimate carries, the limits) and the law's own
/// table (`[controller.params]` or `[observer.params]`).
pub struct LawSetup<'a> {
    pub scenario: &'a Scenario,
    pub design: &'a LoopDesign,
    /// The generation this instance serves as.
    pub generation: u32,
    /// Whose law it is: which `params` table it reads.
    pub role: ProgramRole,
}

impl LawSetup<'_> {
    /// The sample period in seconds.
    pub fn ts(&self) -> f64 {
        self.design.ts
    }

    pub fn n_inputs(&self) -> usize {
        self.design.n_inputs
    }

    pub fn n_outputs(&self) -> usize {
        self.design.n_outputs
    }

    /// The set-point the scenario's `[reference]` gives (its value and four
    /// derivatives at a time in seconds: `reference().sample(seq as f64 * ts)`).
    pub fn reference(&self) -> flexloop_design::reference::Reference {
        self.design.reference.clone()
    }

    /// The actuator's limit (the scenario's `plant.input_limit`).
    pub fn input_limit(&self) -> f64 {
        self.design.input_limit
    }

    /// The law's own tunables: `[controller.params]` (or `[observer.params]`)
    /// read into `T` (serde); an error names the scenario file and the
    /// field. Without the table, `T` is read from an empty one (its
    /// defaults, or an error naming the first field it needs).
    pub fn params<T: serde::de::DeserializeOwned>(&self) -> Result<T, SetupError> {
        let table = match self.role {
            ProgramRole::Controller => &self.scenario.controller.params,
            ProgramRole::Observer => &self.scenario.observer.params,
        };
        toml::Value::Table(table.clone().unwrap_or_default())
            .try_into()
            .map_err(|e: toml::de::Error| SetupError::Params {
                file: self.scenario.source.clone(),
                section: self.role.section(),
                reason: e.message().to_string(),
            })
    }
}

/// Why a law could not be built.
#[derive(Debug)]
pub enum SetupError {
    /// `[controller.params]` does not read as the law's tunables.
    Params {
        file: PathBuf,
        section: &'static str,
        reason: String,
    },
    /// The law cannot serve this loop (another model, too many inputs, …).
    Unsupported(String),
}

impl fmt::Display for SetupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SetupError::Params {
                file,
                section,
                reason,
            } => write!(f, "{}: {section}.params: {reason}", file.display()),
            SetupError::Unsupported(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for SetupError {}

/// A small law's state in a hand-over: `state` under its design's
/// fingerprint. False if it does not fit (then nothing is handed over).
pub fn save_state(out: &mut Handover, design_hash: u64, state: &[f64]) -> bool {
    if state.len() > MAX_HANDOVER_STATES {
        out.design_hash = 0;
        out.n_states = 0;
        return false;
    }
    out.design_hash = design_hash;
    out.n_states = state.len() as u32;
    out.state[..state.len()].copy_from_slice(state);
    true
}

/// The state a predecessor of design `design_hash` handed over, if it is
/// one and every value is finite.
pub fn saved_state(from: &Handover, design_hash: u64) -> Option<&[f64]> {
    let n = from.n_states as usize;
    (from.design_hash == design_hash && n <= MAX_HANDOVER_STATES)
        .then(|| &from.state[..n])
        .filter(|s| s.iter().all(|v| v.is_finite()))
}
