//! flexloop-components: the per-sample work of each process, without IPC.
//!
//! Each component is sized and validated in its constructor and then only
//! computes in `step`/`tick`: no allocation, no locks, no syscalls. The service
//! binaries wrap them with ports and a clock; the tests run them in one process.
//!
//! - [`plant`]: the plant emulator and its command acceptance (misses, late
//!   commands, stalls).
//! - [`observer`]: runs the observer block on y(k), u_a(k) and prepares the
//!   estimate for tick k+1.
//! - [`control_law`], [`estimation_law`]: the traits every controller's and
//!   observer's law implements, the built-in ones and a user's; [`law_setup`]:
//!   what such a law is built from (docs/components.md).
//! - [`controller`]: finishes the observer's direct term, runs feedback,
//!   feedforward and limits: u(k).
//! - [`handover`]: design fingerprints and bumpless state shifts for swaps.
//! - [`in_process`]: the whole loop in one process, as lockstep runs it.
//! - [`noise`]: the seeded disturbance generator.
//!
//! The record of the samples (the logger's recorder, the MCAP sample file)
//! is flexloop-recording's.

pub mod control_law;
pub mod controller;
pub mod estimation_law;
pub mod handover;
pub mod in_process;
pub mod law_setup;
pub mod noise;
pub mod observer;
pub mod plant;

pub use control_law::{ControlLaw, ControllerSetup};
pub use controller::ControllerCore;
pub use estimation_law::{EstimationLaw, ObserverSetup};
pub use flexloop_control::excitation::{ExcitationPlan, InjectionPoint, ScheduledExcitation};
pub use in_process::InProcessLoop;
pub use law_setup::{LawSetup, SetupError};
pub use observer::ObserverCore;
pub use plant::{CommandVerdict, PlantCore, PlantCounters};
