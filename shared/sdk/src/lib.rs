//! flexloop-sdk: what a user's controller or observer is written against
//! (docs/components.md).
//!
//! Implement [`ControlLaw`] for a type (its `new` from the scenario and its
//! own `[controller.params]`, its `step` from a measurement and the
//! observer's estimate to a command) and make it a program with
//! [`run_controller`]:
//!
//! ```no_run
//! use flexloop_sdk::{Command, ControlLaw, ControllerSetup, Estimate, Measurement, SetupError};
//!
//! struct Proportional { kp: f64 }
//!
//! impl ControlLaw for Proportional {
//!     fn new(setup: &ControllerSetup<'_>) -> Result<Self, SetupError> {
//!         #[derive(serde::Deserialize, serde::Serialize)]
//!         struct Params { kp: f64 }
//!         let Params { kp } = setup.params()?;
//!         Ok(Self { kp })
//!     }
//!     fn step(&mut self, m: &Measurement, _estimate: &Estimate, out: &mut Command) {
//!         out.u[0] = -self.kp * m.y[0];
//!     }
//! }
//!
//! fn main() {
//!     std::process::exit(flexloop_sdk::run_controller::<Proportional>());
//! }
//! ```
//!
//! An observer is the same with [`EstimationLaw`] and [`run_observer`].
//!
//! The program then is everything the built-in `flexloop-controller` is:
//! the start-up handshake, shadowing as a replacement, the hand-over at a
//! sample boundary (its own state from [`ControlLaw::save`], or a bumpless
//! shift of its output), standby duty, real-time set-up and a clean exit
//! on SIGTERM. The built-in controller is this same trait's
//! [`ControllerCore`](flexloop_components::ControllerCore).

pub use flexloop_components::control_law::{ControlLaw, ControllerSetup};
pub use flexloop_components::estimation_law::{EstimationLaw, ObserverSetup};
pub use flexloop_components::law_setup::{SetupError, save_state, saved_state};
pub use flexloop_design::LoopDesign;
pub use flexloop_design::reference::{Derivatives, Reference};
pub use flexloop_node::{own_args, run_controller, run_observer};
pub use flexloop_protocol::{
    Command, Estimate, Handover, MAX_INPUTS, MAX_OUTPUTS, MAX_STATES, Measurement,
};
pub use flexloop_scenario::{ProgramRole, Scenario};
