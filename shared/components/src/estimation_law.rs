//! What an observer computes each sample, as one trait: the built-in
//! [`ObserverCore`](crate::ObserverCore) and a user's law alike
//! (docs/components.md). The process around it (flexloop-node) does the
//! ports, duties, shadowing, the hand-over and a restart's catch-up.

pub use crate::law_setup::{LawSetup as ObserverSetup, SetupError};
use flexloop_protocol::{Estimate, Handover, Measurement};

/// An observer's law: from measurement y(k) (and the input u_a(k) it
/// carries) the estimate for tick k+1.
///
/// `step` runs at the loop's priority once per sample: it must not
/// allocate, lock or make system calls.
pub trait EstimationLaw: Sized {
    /// Builds the law for the loop `setup` describes (design time).
    fn new(setup: &ObserverSetup<'_>) -> Result<Self, SetupError>;

    /// The estimate for tick 0, before any measurement: `x_hat[..n_states]`
    /// and `n_states` (and, for the built-in controller's MC and AD, the
    /// block's `free` and `direct` parts).
    fn initial(&mut self, out: &mut Estimate);

    /// From measurement `m` (tick k) the estimate for tick k+1, as
    /// [`Self::initial`] writes it (and `innovation` if it has one). The
    /// process stamps the sequence number, the counts and the times.
    fn step(&mut self, m: &Measurement, out: &mut Estimate);

    /// The state a successor of the same design continues from; the
    /// default hands nothing over.
    fn save(&self, _out: &mut Handover) {}

    /// Takes over a predecessor's state if it is of this design (its next
    /// estimate is for `from.seq + 1`); false (and nothing changed) otherwise.
    fn load(&mut self, _from: &Handover) -> bool {
        false
    }

    /// Samples an estimate started from a wrong state takes to converge:
    /// after a restart without a continuous state, the estimates are
    /// flagged `CONVERGING` this long and the built-in controller leaves
    /// their corrections out. The default, `None`: no such wait.
    fn settling_samples(&self) -> Option<u64> {
        None
    }
}

/// The process's part of an estimate: the tick it is for and the
/// measurement it came from (`m`; none for the initial estimate).
pub fn stamp_estimate(
    out: &mut Estimate,
    m: Option<&Measurement>,
    n_outputs: usize,
    n_inputs: usize,
) {
    out.seq = m.map_or(0, |m| m.seq + 1);
    if let Some(m) = m {
        out.source_tick_ns = m.tick_ns;
        out.source_published_ns = m.published_ns;
    }
    out.n_outputs = n_outputs as u32;
    out.n_inputs = n_inputs as u32;
}
