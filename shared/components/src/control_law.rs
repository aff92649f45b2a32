//! What a controller computes each sample, as one trait: the built-in
//! [`ControllerCore`](crate::ControllerCore) and a user's law alike
//! (docs/components.md). The process around a law (flexloop-node: ports,
//! duties, shadowing, hand-over at a boundary, timing) is the same for
//! every law, so a law is only the per-sample computation and, optionally,
//! what it hands to a successor.

use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, Handover, MAX_HANDOVER_STATES, Measurement, flags};
use flexloop_scenario::Scenario;
use std::fmt;
use std::path::PathBuf;

/// A controller's law: u(k) from y(k) and the observer's estimate for tick k.
///
/// `step` runs at the loop's priority once per sample: it must not
/// allocate, lock or make system calls (the built-in laws are checked with
/// `assert_no_alloc`). Everything else runs before the loop or between
/// samples of a shadow.
pub trait ControlLaw: Sized {
    /// Builds the law for the loop `setup` describes (design time: may
    /// allocate, may fail with a reason that names the field).
    fn new(setup: &ControllerSetup<'_>) -> Result<Self, SetupError>;

    /// Writes the command for measurement `m` into `out.u[..n_inputs]` (and,
    /// if it has them, its parts `u_fb`, `u_ff`, `u_d`, the set-point `r`
    /// and the error `e_meas` for the record). The process stamps the rest
    /// (sequence number, generation, counts, times) after it returns.
    fn step(&mut self, m: &Measurement, estimate: &Estimate, out: &mut Command);

    /// Writes the state a successor of the same design continues from
    /// ([`save_state`] for a small one); the default hands nothing over, and a
    /// successor starts from its own state, shifted by [`Self::shift_output`].
    fn save(&self, _out: &mut Handover) {}

    /// Takes over a predecessor's state if it is of this design; false (and
    /// nothing changed) otherwise.
    fn load(&mut self, _from: &Handover) -> bool {
        false
    }

    /// Bumpless transfer from another design: from now on, the law's output
    /// should be larger by `delta_u` (the old command minus this law's own
    /// at the last sample both computed), e.g. by moving an integrator.
    fn shift_output(&mut self, _delta_u: &[f64]) {}

    /// A law whose state depends on the samples since the start alone (a
    /// feedforward block) takes it from a predecessor of the same
    /// feedforward; false if it has none to take.
    fn load_feedforward(&mut self, _from: &Handover) -> bool {
        false
    }

    /// Brings such state to sample `seq` before a late join (design-time
    /// work); returns how many samples that was (0: nothing to do).
    fn fast_forward(&mut self, _seq: u64) -> u64 {
        0
    }
}

/// What a law is built from: the scenario as the loop runs it, its design
/// (the observer's block the estimate carries, the limits) and the law's own
/// table `[controller.params]`.
pub struct ControllerSetup<'a> {
    pub scenario: &'a Scenario,
    pub design: &'a LoopDesign,
    /// The generation this instance serves as.
    pub generation: u32,
}

impl ControllerSetup<'_> {
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

    /// The law's own tunables: `[controller.params]` read into `T` (serde);
    /// an error names the scenario file and the field. Without the table,
    /// `T` is read from an empty one (its defaults, or an error naming the
    /// first field it needs).
    pub fn params<T: serde::de::DeserializeOwned>(&self) -> Result<T, SetupError> {
        let table = self.scenario.controller.params.clone().unwrap_or_default();
        toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| SetupError::Params {
                file: self.scenario.source.clone(),
                reason: e.message().to_string(),
            })
    }
}

/// Why a law could not be built.
#[derive(Debug)]
pub enum SetupError {
    /// `[controller.params]` does not read as the law's tunables.
    Params { file: PathBuf, reason: String },
    /// The law cannot serve this loop (another model, too many inputs, …).
    Unsupported(String),
}

impl fmt::Display for SetupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SetupError::Params { file, reason } => {
                write!(f, "{}: controller.params: {reason}", file.display())
            }
            SetupError::Unsupported(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for SetupError {}

/// The process's part of a command: which sample, which instance, how many
/// values, and the times and conditions the law does not know. The same for
/// every law, so that a user's law cannot get them wrong.
pub fn stamp_command(
    out: &mut Command,
    m: &Measurement,
    estimate: &Estimate,
    generation: u32,
    n_inputs: usize,
    n_outputs: usize,
) {
    out.seq = m.seq;
    out.tick_ns = m.tick_ns;
    out.measurement_published_ns = m.published_ns;
    out.estimate_seq = estimate.seq;
    out.estimate_published_ns = estimate.published_ns;
    if m.seq > estimate.seq {
        out.flags |= flags::STALE_ESTIMATE;
    }
    out.flags |= m.flags & flags::LOCKSTEP;
    out.generation = generation;
    out.n_inputs = n_inputs as u32;
    out.n_outputs = n_outputs as u32;
}

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
