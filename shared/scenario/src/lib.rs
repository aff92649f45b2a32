//! flexloop-scenario: what a run is, read from a TOML file and checked before
//! any process starts.
//!
//! - [`schema`]: the file format, field by field (unknown fields are refused).
//! - [`error`]: errors that name the file, the field and the reason.
//! - [`design`]: turns a validated scenario into the loop's discrete blocks
//!   (plant, observer block, feedback, reference), identically in every process.
//! - [`reference`]: set-point profiles evaluated per sample without allocating.
//! - [`sensor_scan`]: a sensor the structure scans past, and the observer
//!   scheduled on its position.

pub mod design;
pub mod error;
pub mod reference;
pub mod schema;
pub mod sensor_scan;

pub use design::{LoopDesign, ObserverBlock};
pub use error::ScenarioError;
pub use schema::{DEDICATED_CORES_MIN_CPUS, Mode, Overrides, Profile, Scenario};
