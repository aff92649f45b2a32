//! `live.json`: where the live server of a loop (`flexloop up --live`)
//! listens and what it allows, written once it is bound (so a port chosen
//! by the system, `--live 127.0.0.1:0`, can be found).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LiveEndpoint {
    /// The address and port it is bound to (`127.0.0.1:8765`).
    pub address: String,
    pub pid: u32,
    /// Every change of the loop is refused (`--live-read-only`).
    pub read_only: bool,
    /// Changes need the token given at start (`live.token`).
    pub token_required: bool,
}

/// `live_summary.json`: what the live server did, written when it stops.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LiveSummary {
    /// Its process's CPU time (user and system) and how long it served.
    pub cpu_s: f64,
    pub wall_s: f64,
    /// Messages handed to clients (the crate drops a slow client's oldest).
    pub messages_sent: u64,
    /// Samples its own reader never got, per channel (measurement,
    /// estimate, command): its queue overflowed.
    pub lost_by_reader: [u64; 3],
    /// The most clients subscribed at once.
    pub most_clients: usize,
    /// The connections the server serves at once (one more is refused), and
    /// the most it had.
    #[serde(default)]
    pub max_connections: usize,
    #[serde(default)]
    pub most_connections: usize,
    /// Connections refused because `max_connections` were open.
    #[serde(default)]
    pub refused_connections: u64,
    /// Connections closed for a message longer than a client may send.
    #[serde(default)]
    pub oversized_messages: u64,
    /// Wrong `live.token`s compared, and attempts refused unexamined while
    /// wrong ones locked them out.
    #[serde(default)]
    pub token_failures: u64,
    #[serde(default)]
    pub token_throttled: u64,
}
