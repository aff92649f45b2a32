//! The live server's own counts: what it sent to each client, and what its
//! reader of the loop's channels lost.

use crate::clients::Route;
use crate::gate::MAX_CLIENTS;
use foxglove::{RawChannel, SinkId};
use std::collections::HashMap;

/// The server's own counts: messages sent, and samples its reader never
/// got (its queue overflowed: it was not scheduled for 51 ms).
#[derive(Debug, Default)]
pub(crate) struct Counts {
    /// Messages handed to each client (of clients no longer subscribed to
    /// anything, kept until there are more than [`KEPT_GONE`]).
    pub(crate) handed_to: HashMap<SinkId, u64>,
    /// Messages handed to clients forgotten since.
    pub(crate) handed_to_gone: u64,
    pub(crate) last_seq: [Option<u64>; 3],
    pub(crate) lost: [u64; 3],
    pub(crate) most_clients: usize,
}

/// Counts of clients without a route kept before they are forgotten: the
/// count of each connection the server ever served would grow without end
/// under clients that connect again and again.
const KEPT_GONE: usize = 4 * MAX_CLIENTS;

impl Counts {
    pub(crate) fn handed(&mut self, sink: SinkId) {
        *self.handed_to.entry(sink).or_insert(0) += 1;
    }

    /// Forgets the counts of clients without a route once there are many.
    pub(crate) fn forget_gone(&mut self, routes: &[Route<SinkId>]) {
        if self.handed_to.len() <= routes.len() + KEPT_GONE {
            return;
        }
        let mut gone = 0;
        self.handed_to.retain(|sink, n| {
            let keep = routes.iter().any(|r| r.sink == *sink);
            if !keep {
                gone += *n;
            }
            keep
        });
        self.handed_to_gone += gone;
    }

    /// Messages handed to all clients.
    pub(crate) fn sent(&self) -> u64 {
        self.handed_to_gone + self.handed_to.values().sum::<u64>()
    }

    pub(crate) fn handed_to(&self, sink: SinkId) -> u64 {
        self.handed_to.get(&sink).copied().unwrap_or(0)
    }

    /// To every client subscribed to `channel`, counted.
    pub(crate) fn log_to_subscribers(
        &mut self,
        channel: &RawChannel,
        routes: &[Route<SinkId>],
        bytes: &[u8],
    ) {
        let id = u64::from(channel.id());
        for route in routes.iter().filter(|r| r.channels.contains(&id)) {
            channel.log_to_sink(bytes, Some(route.sink));
            self.handed(route.sink);
        }
    }

    pub(crate) fn read(&mut self, channel: usize, seq: u64) {
        if let Some(last) = self.last_seq[channel]
            && seq > last + 1
        {
            self.lost[channel] += seq - last - 1;
        }
        if self.last_seq[channel].is_none_or(|last| seq > last) {
            self.last_seq[channel] = Some(seq);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reader_counts_what_its_queue_lost_and_not_reordering() {
        let mut counts = Counts::default();
        for seq in [0, 1, 2, 5, 4, 6] {
            counts.read(0, seq);
        }
        assert_eq!(counts.lost[0], 2);
        assert_eq!(counts.last_seq[0], Some(6));
    }
}
