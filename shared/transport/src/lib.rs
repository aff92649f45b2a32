//! flexloop-transport: the loop's channels on iceoryx2.
//!
//! A [`Domain`] isolates one run (its own iceoryx2 prefix). On it, an
//! [`Outlet`] is a publisher paired with a notifier, an [`Inlet`] a
//! subscriber paired with a listener whose file descriptor a loop can `ppoll`
//! with a precise timeout. All services are opened with the QoS of
//! [`flexloop_protocol::channels`], so that every process agrees.

mod domain;
mod error;
mod ports;

pub use domain::{
    Domain, cleanup_dead_nodes, dead_prefixes, leftover_files, leftover_files_for_prefix,
    remove_dead_prefixes, remove_leftovers,
};
pub use error::TransportError;
/// A process's iceoryx2 node, as [`Domain::node`] returns it.
pub type LoopNode = iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>;
/// The bound every message type of an [`Inlet`] or [`Outlet`] carries.
pub use iceoryx2::prelude::ZeroCopySend;
pub use ports::{ChannelHold, Inlet, Outlet, Wakeup, WakeupListener};
