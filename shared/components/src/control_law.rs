//! What a controller computes each sample, as one trait: the built-in
//! [`ControllerCore`](crate::ControllerCore) and a user's law alike
//! (docs/components.md). The process around a law (flexloop-node: ports,
//! duties, shadowing, hand-over at a boundary, timing) is the same for
//! every law, so a law is only the per-sample computation and, optionally,
//! what it hands to a successor.

pub use crate::law_setup::{LawSetup as ControllerSetup, SetupError};
use flexloop_protocol::{Command, Estimate, Handover, Measurement, flags};

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
    /// ([`save_state`](crate::law_setup::save_state) for a small one); the default hands nothing over, and a
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
