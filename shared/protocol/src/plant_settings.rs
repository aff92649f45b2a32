//! The plant's own safety settings, which the supervisor changes while the
//! loop runs (`flexloop set supervision.safe_action=zero`): the plant reads
//! them at its start from the scenario, then polls this channel at every
//! tick (no syscall, no wake-up), as it polls the activation.

use iceoryx2::prelude::*;

/// Keep the last accepted input.
pub const SAFE_HOLD: u32 = 0;
/// Apply zero input.
pub const SAFE_ZERO: u32 = 1;
/// Apply the standby controller's command (it is set at the start only:
/// the supervisor starts the standby with the loop).
pub const SAFE_STANDBY: u32 = 2;

/// What the plant does when commands stop coming.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.PlantSettings.v1")]
pub struct PlantSettings {
    pub published_ns: u64,
    /// Ticks without an accepted command before the safe action.
    pub command_watchdog_ticks: u32,
    /// [`SAFE_HOLD`], [`SAFE_ZERO`] or [`SAFE_STANDBY`].
    pub safe_action: u32,
}
