//! What a law of one's own (a controller's or an observer's) is built
//! from, why it could not be, and the small state it may hand a successor
//! (docs/components.md).

use flexloop_design::LoopDesign;
use flexloop_design::reference::Derivatives;
use flexloop_protocol::{Handover, MAX_HANDOVER_STATES};
use flexloop_scenario::{ProgramRole, Scenario};
use std::cell::RefCell;
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
    /// The parameters as [`LawSetup::params`] last read them, defaults
    /// included ([`LawSetup::params_read`]).
    read: RefCell<Option<ParamsRead>>,
}

/// What a law read of its `params` table: every value it uses, and which
/// of them the scenario did not give (the law's defaults).
#[derive(Debug, Clone, PartialEq)]
pub struct ParamsRead {
    pub values: serde_json::Map<String, serde_json::Value>,
    pub defaulted: Vec<String>,
}

impl<'a> LawSetup<'a> {
    pub fn new(
        scenario: &'a Scenario,
        design: &'a LoopDesign,
        generation: u32,
        role: ProgramRole,
    ) -> Self {
        Self {
            scenario,
            design,
            generation,
            role,
            read: RefCell::new(None),
        }
    }
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

    /// The set-point the scenario's `[reference]` gives, every shape (its
    /// value and four derivatives, r, ṙ, r̈, r⃛ and the snap, at a time in
    /// seconds: `reference().sample(t)`). With a command deadline the
    /// profile starts τ_d later, as the built-in controller's does
    /// (docs/deadline.md): sample it at [`LawSetup::actuation_time`].
    pub fn reference(&self) -> flexloop_design::reference::Reference {
        self.design.reference.clone()
    }

    /// `reference.direction`: output i follows `direction[i] · r(t)`.
    pub fn reference_direction(&self) -> &[f64] {
        &self.design.reference_direction
    }

    /// τ_d [s] when each command acts on arrival (`loop.command_deadline_us`):
    /// the command for sample k acts from t_k + τ_d and must be published
    /// by then (a later one is a miss, held). None: one sample of delay.
    pub fn command_deadline_s(&self) -> Option<f64> {
        self.design.command_deadline_s
    }

    /// Samples from y(k) to the tick its command is applied at (1, or 2
    /// with `controller.extra_delay_samples = 1`).
    pub fn loop_delay_samples(&self) -> u32 {
        self.design.loop_delay_samples
    }

    /// When the command computed from sample `seq` starts to act [s]:
    /// t_seq + τ_d with a command deadline, else the tick it is applied at,
    /// t_{seq + delay}. The built-in controller's feedforward is the
    /// reference's derivatives there.
    pub fn actuation_time(&self, seq: u64) -> f64 {
        match self.design.command_deadline_s {
            Some(tau) => seq as f64 * self.design.ts + tau,
            None => (seq + u64::from(self.design.loop_delay_samples)) as f64 * self.design.ts,
        }
    }

    /// The model's feedforward gains per input, on (r, ṙ, r̈, r⃛, snap):
    /// the rigid-body mass on the acceleration, as the built-in controller
    /// has them without `controller.feedforward` (u_ff,i = gains_i ·
    /// derivatives at [`LawSetup::actuation_time`]).
    pub fn feedforward_gains(&self) -> &[Derivatives] {
        &self.design.feedforward
    }

    /// The actuator's limit (the scenario's `plant.input_limit`).
    pub fn input_limit(&self) -> f64 {
        self.design.input_limit
    }

    /// The law's own tunables: `[controller.params]` (or `[observer.params]`)
    /// read into `T` (serde); an error names the scenario file and the
    /// field. Without the table, `T` is read from an empty one (its
    /// defaults, or an error naming the first field it needs).
    ///
    /// `T` also serialises: what it read, its defaults included, is what
    /// the program reports it runs with (`params/<role>.json` in the run
    /// directory, `flexloop get`).
    pub fn params<T: serde::de::DeserializeOwned + serde::Serialize>(
        &self,
    ) -> Result<T, SetupError> {
        let given = self.given_params().cloned().unwrap_or_default();
        let params: T =
            toml::Value::Table(given.clone())
                .try_into()
                .map_err(|e: toml::de::Error| SetupError::Params {
                    file: self.scenario.source.clone(),
                    section: self.role.section(),
                    reason: e.message().to_string(),
                })?;
        let values = match serde_json::to_value(&params) {
            Ok(serde_json::Value::Object(values)) => values,
            Ok(other) => {
                return Err(SetupError::Unsupported(format!(
                    "{}.params: the law's parameters serialise as {other}, not as a table",
                    self.role.section()
                )));
            }
            Err(e) => {
                return Err(SetupError::Unsupported(format!(
                    "{}.params: the law's parameters do not serialise: {e}",
                    self.role.section()
                )));
            }
        };
        let defaulted = values
            .keys()
            .filter(|k| !given.contains_key(*k))
            .cloned()
            .collect();
        *self.read.borrow_mut() = Some(ParamsRead { values, defaulted });
        Ok(params)
    }

    /// The scenario's own `params` table for this role, as written.
    fn given_params(&self) -> Option<&toml::Table> {
        match self.role {
            ProgramRole::Controller => self.scenario.controller.params.as_ref(),
            ProgramRole::Observer => self.scenario.observer.params.as_ref(),
        }
    }

    /// What [`LawSetup::params`] last read (None: the law read no
    /// parameters).
    pub fn params_read(&self) -> Option<ParamsRead> {
        self.read.borrow().clone()
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
