//! The measurements kept for an observer restarted after a crash: it steps
//! through those after its dead predecessor's last state to reach the state
//! the dead one would have had (see `flexloop_node::replay`).

use flexloop_protocol::Measurement;
use std::collections::VecDeque;

/// The replay to one restarted observer.
#[derive(Debug, Clone, Copy)]
struct Feed {
    generation: u32,
    /// The next measurement to replay.
    next: u64,
    /// The last one the observer reported having stepped.
    progress: u64,
}

pub struct Replay {
    /// The newest measurements, oldest first.
    recent: VecDeque<Measurement>,
    feed: Option<Feed>,
    /// Replayed measurements in flight at most: the replay queue's depth.
    window: u64,
}

impl Replay {
    pub fn new(capacity: usize, window: u64) -> Self {
        Self {
            recent: VecDeque::with_capacity(capacity),
            feed: None,
            window,
        }
    }

    /// Keeps `m`, forgetting the oldest once full.
    pub fn keep(&mut self, m: Measurement) {
        if self.recent.len() == self.recent.capacity() {
            self.recent.pop_front();
        }
        self.recent.push_back(m);
    }

    /// The restarted observer `generation` reports it stepped up to `seq`.
    pub fn progress(&mut self, generation: u32, seq: u64) {
        if let Some(feed) = &mut self.feed
            && feed.generation == generation
        {
            feed.progress = feed.progress.max(seq);
        }
    }

    /// Hands `publish` the measurements after the dead predecessor's last
    /// state (after `state_seq`) not sent yet, no further than `window` past
    /// the progress the observer reported, so that its queue never
    /// overflows; stops at the first `publish` that fails. A ring that no
    /// longer holds the first of them replays from its oldest: the observer
    /// sees the hole and says so.
    pub fn feed(
        &mut self,
        generation: u32,
        state_seq: u64,
        mut publish: impl FnMut(&Measurement) -> bool,
    ) {
        let feed = match &mut self.feed {
            Some(feed) if feed.generation == generation => feed,
            _ => self.feed.insert(Feed {
                generation,
                next: state_seq + 1,
                progress: state_seq,
            }),
        };
        let limit = feed.progress + self.window;
        let first = self.recent.partition_point(|m| m.seq < feed.next);
        for m in self.recent.range(first..) {
            if m.seq > limit || !publish(m) {
                break;
            }
            feed.next = m.seq + 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measurement(seq: u64) -> Measurement {
        Measurement {
            seq,
            ..Measurement::default()
        }
    }

    fn sent(replay: &mut Replay, generation: u32, state_seq: u64) -> Vec<u64> {
        let mut seqs = Vec::new();
        replay.feed(generation, state_seq, |m| {
            seqs.push(m.seq);
            true
        });
        seqs
    }

    #[test]
    fn a_replay_starts_after_the_last_state_and_keeps_within_its_window() {
        let mut replay = Replay::new(64, 4);
        for seq in 0..20 {
            replay.keep(measurement(seq));
        }
        assert_eq!(sent(&mut replay, 2, 9), [10, 11, 12, 13]);
        // Nothing more until the observer reports progress.
        assert!(sent(&mut replay, 2, 9).is_empty());
        replay.progress(2, 11);
        assert_eq!(sent(&mut replay, 2, 9), [14, 15]);
        // Another generation's progress is not this feed's.
        replay.progress(3, 19);
        assert!(sent(&mut replay, 2, 9).is_empty());
    }

    #[test]
    fn a_replay_from_a_ring_that_moved_on_starts_at_its_oldest() {
        let mut replay = Replay::new(8, 100);
        for seq in 0..20 {
            replay.keep(measurement(seq));
        }
        assert_eq!(sent(&mut replay, 1, 3), (12..20).collect::<Vec<_>>());
    }
}
