//! flexloop-scenario: what a run is, read from a TOML file and checked before
//! any process starts. Turning a scenario into the loop's blocks is the next
//! crate up, flexloop-design.
//!
//! - [`schema`]: the file format, field by field (unknown fields are refused).
//! - `load`: reading and parsing a file, then the command line's overrides.
//! - `validate`: ranges, consistency, and the machine's fitness for the profile.
//! - [`plant_description`]: the plant a user brings (lumped networks, model
//!   files, the chain's parameters, modal damping).
//! - [`program`]: a user's program serving a role (`controller.exec`,
//!   `observer.exec`).
//! - [`limits`]: the bounds on every number.
//! - [`swap`]: the fields a live swap may change and those it may not.
//! - [`tick`]: `realtime.tick`, where it applies and where it falls back.
//! - [`tune`]: the fields live tuning (`flexloop set`) may change.
//! - [`error`]: errors that name the file, the field and the reason.

pub mod error;
pub mod limits;
pub mod load;
pub mod plant_description;
pub mod program;
pub mod schema;
pub mod swap;
pub mod tick;
pub mod tune;
mod validate;
mod validate_measure;
mod validate_plant;

pub use error::ScenarioError;
pub use program::{ComponentProgram, ProgramRole};
pub use schema::{
    DEDICATED_CORES_MIN_CPUS, Mode, Overrides, PidBandwidth, Profile, Scenario, TickWait,
};
pub use tick::TickDecision;
