//! How a process enters the loop: the one vocabulary the supervisor's
//! command lines, its orders to warm spares ([`crate::SpareOrder::joining`])
//! and the processes' own arguments share.

/// How a process enters the loop.
///
/// The discriminants are the wire form an order carries (see
/// [`Joining::from_wire`]); they must not change while processes of
/// different builds may share a loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u32)]
pub enum Joining {
    /// With the others, at start-up: the start-up handshake.
    #[default]
    AtStart = 4,
    /// A running loop, in shadow until a boundary hands it the samples (a swap).
    Replacement = 0,
    /// A running loop, in place of an instance that crashed: its last state
    /// comes from the supervisor, which replays the measurements since to an
    /// observer.
    Restart = 1,
    /// A running loop, as the standby controller: it follows in shadow and
    /// publishes its commands for the plant's safe action.
    Standby = 2,
    /// As a warm spare: every port open, idle until ordered. Ordered to a
    /// serving standby whose design is no longer the active one's, it means
    /// retire: stop, and idle as a spare.
    Spare = 3,
}

/// A wire value that names no [`Joining`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownJoining(pub u32);

impl core::fmt::Display for UnknownJoining {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "unknown way of joining the loop: {}", self.0)
    }
}

impl std::error::Error for UnknownJoining {}

impl Joining {
    pub const ALL: [Joining; 5] = [
        Joining::AtStart,
        Joining::Replacement,
        Joining::Restart,
        Joining::Standby,
        Joining::Spare,
    ];

    /// The value an order carries.
    pub fn wire(self) -> u32 {
        self as u32
    }

    /// The way of joining a wire value names.
    pub fn from_wire(value: u32) -> Result<Self, UnknownJoining> {
        Self::ALL
            .into_iter()
            .find(|j| j.wire() == value)
            .ok_or(UnknownJoining(value))
    }

    /// Whether the process comes to a loop that may already run: it takes
    /// no part in the start-up handshake (a spare may later serve any of
    /// these).
    pub fn is_late(self) -> bool {
        self != Joining::AtStart
    }
}

impl From<Joining> for u32 {
    fn from(joining: Joining) -> u32 {
        joining.wire()
    }
}

impl TryFrom<u32> for Joining {
    type Error = UnknownJoining;

    fn try_from(value: u32) -> Result<Self, UnknownJoining> {
        Joining::from_wire(value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_way_of_joining_survives_the_wire() {
        for joining in Joining::ALL {
            assert_eq!(Joining::try_from(u32::from(joining)), Ok(joining));
        }
    }

    #[test]
    fn the_wire_values_of_older_orders_stand() {
        // Those of the constants orders carried before the enum.
        assert_eq!(Joining::Replacement.wire(), 0);
        assert_eq!(Joining::Restart.wire(), 1);
        assert_eq!(Joining::Standby.wire(), 2);
        assert_eq!(Joining::Spare.wire(), 3);
    }

    #[test]
    fn an_unknown_value_is_an_error() {
        assert_eq!(Joining::from_wire(5), Err(UnknownJoining(5)));
        assert_eq!(Joining::try_from(u32::MAX), Err(UnknownJoining(u32::MAX)));
        assert!(UnknownJoining(9).to_string().contains('9'));
    }

    #[test]
    fn only_the_start_takes_part_in_the_handshake() {
        assert!(!Joining::AtStart.is_late());
        assert!(Joining::ALL[1..].iter().all(|j| j.is_late()));
    }
}
