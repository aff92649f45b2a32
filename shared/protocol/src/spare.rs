//! Warm spares: an idle instance of a component that has opened every port
//! it would use, so that a swap creates and drops no port while the loop
//! runs (every port that appears or goes makes the loop's own `send` and
//! `receive` remap connections: about 0.1 ms, a missed sample at 10 kHz).
//!
//! - [`SpareOrder`]: the supervisor names one spare (by pid) for a
//!   generation and a scenario file; the spare designs, follows in shadow and
//!   takes over at the announced boundary like any replacement.
//! - [`SpareStatus`]: a process reports that it is idle (started as a spare,
//!   or replaced at a boundary: the old active instance becomes the next
//!   spare instead of exiting).

use crate::joining::{Joining, UnknownJoining};
use iceoryx2::prelude::*;

/// Longest scenario path an order carries.
pub const MAX_ORDER_PATH: usize = 1024;

/// The supervisor's order to one idle spare.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.SpareOrder.v1")]
pub struct SpareOrder {
    pub published_ns: u64,
    /// The spare this order is for.
    pub pid: u32,
    /// The generation it serves under.
    pub generation: u32,
    /// [`Joining::wire`]: [`Joining::Replacement`], [`Joining::Restart`],
    /// [`Joining::Standby`], or [`Joining::Spare`] (to a serving standby:
    /// retire); read it with [`SpareOrder::join_as`].
    pub joining: u32,
    pub scenario_len: u32,
    /// UTF-8 path of the scenario file, `scenario_len` bytes.
    pub scenario: [u8; MAX_ORDER_PATH],
}

impl Default for SpareOrder {
    fn default() -> Self {
        // SAFETY: integers only; all-zero bits are valid values.
        unsafe { core::mem::zeroed() }
    }
}

/// Why an order cannot be written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PathTooLong(pub usize);

impl core::fmt::Display for PathTooLong {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "scenario path of {} bytes is longer than a spare order holds ({MAX_ORDER_PATH})",
            self.0
        )
    }
}

impl SpareOrder {
    pub fn set_scenario(&mut self, path: &str) -> Result<(), PathTooLong> {
        let bytes = path.as_bytes();
        if bytes.len() > MAX_ORDER_PATH {
            return Err(PathTooLong(bytes.len()));
        }
        self.scenario[..bytes.len()].copy_from_slice(bytes);
        self.scenario_len = bytes.len() as u32;
        Ok(())
    }

    /// How the order asks the spare to join (an unknown value is an error).
    pub fn join_as(&self) -> Result<Joining, UnknownJoining> {
        Joining::from_wire(self.joining)
    }

    /// The scenario path, if the order holds valid UTF-8.
    pub fn scenario(&self) -> Option<&str> {
        let len = (self.scenario_len as usize).min(MAX_ORDER_PATH);
        core::str::from_utf8(&self.scenario[..len]).ok()
    }
}

/// A process's report that it is an idle spare (ports open, waiting for
/// an order): sent once each time it becomes one.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.SpareStatus.v2")]
pub struct SpareStatus {
    pub published_ns: u64,
    pub pid: u32,
    /// The generation it served last (none yet: its start-up one).
    pub generation: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_order_carries_its_path_or_refuses_it() {
        let mut order = SpareOrder::default();
        order.set_scenario("/runs/a b/retuned.toml").unwrap();
        assert_eq!(order.scenario(), Some("/runs/a b/retuned.toml"));
        let long = "x".repeat(MAX_ORDER_PATH + 1);
        assert_eq!(
            order.set_scenario(&long),
            Err(PathTooLong(MAX_ORDER_PATH + 1))
        );
        // The earlier path stands.
        assert_eq!(order.scenario(), Some("/runs/a b/retuned.toml"));
    }

    #[test]
    fn an_order_names_how_to_join_or_is_refused() {
        let mut order = SpareOrder {
            joining: Joining::Standby.into(),
            ..SpareOrder::default()
        };
        assert_eq!(order.join_as(), Ok(Joining::Standby));
        order.joining = 77;
        assert_eq!(order.join_as(), Err(UnknownJoining(77)));
    }
}
