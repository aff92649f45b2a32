//! flexloop-protocol: the samples the loop exchanges and where they travel.
//!
//! - [`messages`]: fixed-size `#[repr(C)]` messages (measurement, estimate,
//!   command, telemetry), sized for MIMO models so that nothing is ever
//!   reallocated.
//! - [`channels`]: every service name and every QoS setting, in one place, so
//!   that all processes open the services with identical settings.
//! - [`handover`]: component state and activation for swaps and restarts.
//! - [`joining`]: how a process enters the loop (start, swap, restart,
//!   standby, spare).
//! - [`spare`]: orders to idle warm spares and their reports.
//! - [`plant_settings`]: the plant's safe action and command watchdog, as
//!   the supervisor changes them while the loop runs.
//! - [`layout`]: every recorded message's fields as data (ROS1 definitions,
//!   export columns).
//! - [`time`]: the monotonic nanosecond clock all timestamps use.
//! - [`wire`]: all of the above as one JSON document, for components in
//!   another language (the Python package checks itself against it).

pub mod channels;
pub mod handover;
pub mod joining;
pub mod layout;
pub mod measure_order;
pub mod messages;
pub mod plant_settings;
pub mod spare;
pub mod time;
pub mod wire;

pub use channels::{Channel, ChannelQos};
pub use handover::{Activation, Handover, MAX_HANDOVER_STATES};
pub use joining::{Joining, UnknownJoining};
pub use measure_order::MeasureOrder;
pub use messages::{
    Command, Estimate, MAX_INPUTS, MAX_OBSERVER_INPUTS, MAX_OBSERVER_OUTPUTS, MAX_OUTPUTS,
    MAX_STATES, Measurement, NO_SEQ, Telemetry, WireBytes, flags,
};
pub use plant_settings::PlantSettings;
pub use spare::{SpareOrder, SpareStatus};
