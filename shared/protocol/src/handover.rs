//! Handing the loop over from one instance of a component to another (a
//! swap, or a restart after a crash) at a sample boundary.
//!
//! - [`Handover`]: the active instance's internal state after each sample,
//!   published every tick (no notification), so that a replacement can take
//!   it over without asking.
//! - [`Activation`]: which generation of controller and observer owns which
//!   sequence numbers, published by the supervisor and kept as history, so
//!   that the plant, the controllers and the observers agree on the boundary.

use crate::messages::{Command, MAX_INPUTS, flags};
use iceoryx2::prelude::*;

/// States a component can hand over (filter, feedforward and observer states).
pub const MAX_HANDOVER_STATES: usize = 128;

/// [`Handover::shadow`]: the state of the active instance.
pub const ACTIVE: u32 = 0;
/// [`Handover::shadow`]: an instance that follows the loop, not yet active.
pub const FOLLOWING: u32 = 1;
/// [`Handover::shadow`]: a restarted instance still replaying the past.
pub const CATCHING_UP: u32 = 2;

/// A component's state after it processed measurement `seq`.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Handover.v2")]
pub struct Handover {
    /// The measurement last processed.
    pub seq: u64,
    /// Fingerprint of the design that produced `state`: a replacement copies
    /// the state only into an identical design.
    pub design_hash: u64,
    pub generation: u32,
    /// [`ACTIVE`], [`FOLLOWING`] (a shadow or standby, not yet the active
    /// instance) or [`CATCHING_UP`] (a restarted observer replaying the
    /// measurements since its predecessor's last state; `seq` is its progress).
    pub shadow: u32,
    pub n_states: u32,
    pub n_inputs: u32,
    /// Fingerprint of the part of `state` that another design may continue
    /// from: the controller's feedforward block (its gains and reference),
    /// so that a retuned feedback takes its state instead of replaying the
    /// run; the observer's model estimate x̂ (its model and output
    /// prediction), so that another gain or active damping on the same
    /// model continues the running estimate. 0: none.
    pub carried_hash: u64,
    /// Where that part lies in `state`.
    pub carried_at: u32,
    pub carried_len: u32,
    pub state: [f64; MAX_HANDOVER_STATES],
    /// The controller's command for `seq` (total u, after limits); for a
    /// shadow instance the command it would have sent.
    pub u: [f64; MAX_INPUTS],
}

/// The current assignment of generations to sequence numbers.
///
/// Commands for seq ≥ `controller_from_seq` must come from
/// `controller_generation`, earlier ones from `previous_controller_generation`;
/// estimates likewise with the observer fields.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Activation.v1")]
pub struct Activation {
    pub published_ns: u64,
    pub controller_from_seq: u64,
    pub observer_from_seq: u64,
    pub controller_generation: u32,
    pub previous_controller_generation: u32,
    pub observer_generation: u32,
    pub previous_observer_generation: u32,
}

impl Activation {
    /// Generation 0 owns everything: the state before any swap.
    pub const INITIAL: Activation = Activation {
        published_ns: 0,
        controller_from_seq: 0,
        observer_from_seq: 0,
        controller_generation: 0,
        previous_controller_generation: 0,
        observer_generation: 0,
        previous_observer_generation: 0,
    };

    /// Whether `c` is the loop's command for its sample: from the controller
    /// generation that owns it, or the standby's (which only the standby
    /// sends). Anything else (a shadow's, a replaced one's) is foreign.
    pub fn counts_command(&self, c: &Command) -> bool {
        c.generation == self.controller_for(c.seq) || c.flags & flags::STANDBY != 0
    }

    /// The controller generation whose command for `seq` counts.
    pub fn controller_for(&self, seq: u64) -> u32 {
        if seq >= self.controller_from_seq {
            self.controller_generation
        } else {
            self.previous_controller_generation
        }
    }

    /// The observer generation whose estimate for `seq` counts.
    pub fn observer_for(&self, seq: u64) -> u32 {
        if seq >= self.observer_from_seq {
            self.observer_generation
        } else {
            self.previous_observer_generation
        }
    }
}

impl Default for Activation {
    fn default() -> Self {
        Self::INITIAL
    }
}

impl Default for Handover {
    fn default() -> Self {
        // SAFETY: integers and floats only; all-zero bits are valid values.
        unsafe { core::mem::zeroed() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn activation_splits_sequences_at_the_boundary() {
        let a = Activation {
            controller_from_seq: 100,
            controller_generation: 2,
            previous_controller_generation: 1,
            ..Activation::INITIAL
        };
        assert_eq!(a.controller_for(99), 1);
        assert_eq!(a.controller_for(100), 2);
        assert_eq!(a.observer_for(5), 0);
    }
}
