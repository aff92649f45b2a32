//! flexloop-design: from a validated scenario to the loop's discrete blocks,
//! identically in every process.
//!
//! `flexloop-scenario` is the file format and its validation; this crate is
//! the step after it, scenario → blocks, so the layering shows in the crate
//! graph (the scenario crate needs no control maths).
//!
//! - [`acceptance`]: the one check of a scenario every command makes.
//! - [`loop_design`]: [`LoopDesign`], everything the four processes run, and
//!   its design from a scenario, step by step.
//! - [`plants`]: the plant models and what each brings (observer, feedback
//!   and feedforward plans).
//! - [`observer`]: the modal Kalman observer of a scenario, or none.
//! - [`io_observer`]: the input–output observer with a correction filter
//!   K(z) (`observer.design = "io"`).
//! - [`feedback`]: the PID of `controller.feedback = "pid"`.
//! - [`pid_bandwidth`]: its f_bw, as given or chosen by `"auto"`.
//! - [`feedforward`]: the feedforward gains and Appendix A's modified form.
//! - [`checks`]: what a design must satisfy before a process runs it (message
//!   sizes, closed-loop stability, actuator limit).
//! - [`reference`]: set-point profiles evaluated per sample without allocating.
//! - [`sensor_scan`]: a sensor the structure scans past, and the observer
//!   scheduled on its position.

pub mod acceptance;
pub mod checks;
pub mod feedback;
pub mod feedforward;
pub mod io_observer;
pub mod loop_design;
pub mod observer;
pub mod observer_choice;
pub mod pid_bandwidth;
pub mod plants;
pub mod reference;
pub mod sensor_scan;

pub use flexloop_control::observer_block::ObserverBlock;
pub use loop_design::LoopDesign;
pub use observer::OutputPrediction;
