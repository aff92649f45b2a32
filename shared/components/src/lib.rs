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
//! - [`controller`]: finishes the observer's direct term, runs feedback,
//!   feedforward and limits: u(k).
//! - [`handover`]: design fingerprints and bumpless state shifts for swaps.
//! - [`in_process`]: the whole loop in one process, as lockstep runs it.
//! - [`recorder`]: the logger's sample file and gap counting.
//! - [`noise`]: the seeded disturbance generator.

pub mod controller;
pub mod handover;
pub mod in_process;
pub mod noise;
pub mod observer;
pub mod plant;
pub mod recorder;

pub use controller::ControllerCore;
pub use in_process::InProcessLoop;
pub use observer::ObserverCore;
pub use plant::{CommandVerdict, PlantCore, PlantCounters};
pub use recorder::{LogReader, Record, Recorder};
