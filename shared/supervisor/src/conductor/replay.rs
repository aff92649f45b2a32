//! The measurements kept for an observer restarted after a crash: it steps
//! through those after its dead predecessor's last state to reach the state
//! the dead one would have had (see `flexloop_node::replay`).
//!
//! The replay channel keeps no history, and every observer of a loop with
//! warm spares reads it (an idle spare may be ordered to serve a restart):
//! a replay begun before the restarted generation has subscribed would go
//! to those other readers only. So it begins once that generation says it
//! is catching up (its first `CATCHING_UP` state, published with its reader
//! open), and goes on paced by the progress it reports.

use flexloop_protocol::Measurement;
use std::collections::VecDeque;

/// The replay to one restarted observer.
#[derive(Debug, Clone, Copy)]
struct Feed {
    generation: u32,
    /// The next measurement to replay.
    next: u64,
}

/// The newest generation that reported catching up, and how far.
#[derive(Debug, Clone, Copy)]
struct Listening {
    generation: u32,
    /// The last measurement it reported having stepped.
    progress: u64,
}

pub struct Replay {
    /// The newest measurements, oldest first.
    recent: VecDeque<Measurement>,
    feed: Option<Feed>,
    listening: Option<Listening>,
    /// Replayed measurements in flight at most: the replay queue's depth.
    window: u64,
}

impl Replay {
    pub fn new(capacity: usize, window: u64) -> Self {
        Self {
            recent: VecDeque::with_capacity(capacity),
            feed: None,
            listening: None,
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

    /// The restarted observer `generation` reports it is catching up and
    /// has stepped up to `seq` (its first report: it reads the replay now).
    /// An older generation's report, late, changes nothing.
    pub fn progress(&mut self, generation: u32, seq: u64) {
        match &mut self.listening {
            Some(l) if l.generation == generation => l.progress = l.progress.max(seq),
            Some(l) if l.generation > generation => {}
            _ => {
                self.listening = Some(Listening {
                    generation,
                    progress: seq,
                })
            }
        }
    }

    /// Hands `publish` the measurements after the dead predecessor's last
    /// state (after `state_seq`) not sent yet, no further than `window` past
    /// the progress the observer reported, so that its queue never
    /// overflows; stops at the first `publish` that fails. Nothing before
    /// the restarted `generation` has reported catching up (before, it may
    /// not be subscribed yet). A ring that no longer holds the first of
    /// them replays from its oldest: the observer sees the hole and says so.
    pub fn feed(
        &mut self,
        generation: u32,
        state_seq: u64,
        mut publish: impl FnMut(&Measurement) -> bool,
    ) {
        let Some(progress) = self
            .listening
            .filter(|l| l.generation == generation)
            .map(|l| l.progress)
        else {
            return;
        };
        let feed = match &mut self.feed {
            Some(feed) if feed.generation == generation => feed,
            _ => self.feed.insert(Feed {
                generation,
                next: state_seq + 1,
            }),
        };
        let limit = progress.max(state_seq) + self.window;
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
        replay.progress(2, 9);
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
        replay.progress(1, 3);
        assert_eq!(sent(&mut replay, 1, 3), (12..20).collect::<Vec<_>>());
    }

    /// Other observers read the replay channel too (an idle warm spare),
    /// and it keeps no history: what goes out before the restarted
    /// generation listens never reaches it.
    #[test]
    fn nothing_is_replayed_before_the_restarted_generation_says_it_listens() {
        let mut replay = Replay::new(64, 4);
        for seq in 0..20 {
            replay.keep(measurement(seq));
        }
        assert!(sent(&mut replay, 2, 9).is_empty());
        // Another generation's report (an older restart's, late) opens
        // nothing for this one.
        replay.progress(1, 9);
        assert!(sent(&mut replay, 2, 9).is_empty());
        // Its first report: it holds the state after 9 and reads the replay.
        replay.progress(2, 9);
        assert_eq!(sent(&mut replay, 2, 9), [10, 11, 12, 13]);
        // The older generation, late again, takes nothing over.
        replay.progress(1, 15);
        replay.progress(2, 13);
        assert_eq!(sent(&mut replay, 2, 9), [14, 15, 16, 17]);
    }

    #[test]
    fn a_later_restart_gets_its_own_replay() {
        let mut replay = Replay::new(64, 100);
        for seq in 0..20 {
            replay.keep(measurement(seq));
        }
        replay.progress(1, 3);
        assert_eq!(sent(&mut replay, 1, 3), (4..20).collect::<Vec<_>>());
        replay.progress(3, 11);
        assert!(sent(&mut replay, 1, 3).is_empty());
        assert_eq!(sent(&mut replay, 3, 11), (12..20).collect::<Vec<_>>());
    }
}
