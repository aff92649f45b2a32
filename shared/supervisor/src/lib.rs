//! The supervisor of a loop: it starts the loop's processes, watches them,
//! replaces the ones that crash or hang, carries out swaps and sets, and
//! finishes the run's files (docs/architecture.md, "Standby, restarts and
//! swaps"). The commands in `services/flexloop` parse and print; what they
//! ask of a loop is here:
//!
//! - start one and supervise it to its end: [`launch::prepare`], [`launch::supervise`];
//! - attach to a running one: [`registry`] finds it, [`attach`] reads its
//!   scenario and tunables and orders a set, [`conductor::request_swap`] a
//!   swap, [`registry::stop`] its stop;
//! - finish the loops whose supervisor died: [`dead_loops`].
//!
//! The supervisor's decisions are [`conductor`]'s decision core, a pure
//! function of events tested without processes; [`children`] launches and
//! reaps the processes and [`process_state`] reads the kernel's view of them.

pub mod attach;
pub mod children;
pub mod conductor;
pub mod dead_loops;
pub mod finish;
pub mod launch;
pub mod live_server;
pub mod process_state;
pub mod progress;
pub mod registry;
