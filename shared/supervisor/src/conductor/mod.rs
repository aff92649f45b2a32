//! The supervisor's side of hand-overs: it owns the activation (which
//! generation of controller and observer owns which samples), swaps a
//! component on request (shadow start, boundary, drain), restarts a crashed
//! one with back-off, keeps warm spares and a standby controller, and writes
//! every event to the run's `events.jsonl`.
//!
//! - [`decide`]: the decision core, events in and actions out, no I/O.
//! - [`roster`]: its view of the processes and their duties.
//! - [`measure`]: the loop's pace and the command's step at a switch.
//! - [`shell`]: carries out the core's actions: processes, waits, files.
//! - [`ports`]: the channels it reads and publishes.
//! - [`replay`]: the measurements replayed to a restarted observer.
//! - [`record`]: the events file and the list of live processes.
//! - [`requests`]: `flexloop swap`'s and `set`'s request/answer files.
//! - [`tuning`]: the scenario as it stands, and a `set` checked and planned.

mod decide;
mod measure;
mod measuring;
mod per_role;
mod ports;
mod record;
mod replay;
mod requests;
mod roster;
mod shell;
mod switch;
mod tuning;

pub use requests::{note_stop_request, request_measure, request_set, request_swap};
pub use shell::Conductor;
pub use switch::Switch;
