//! A restarted observer's way back to the loop's present.
//!
//! The state its crashed predecessor last published is a hundred
//! milliseconds old or more by the time the replacement runs (crash noticed,
//! back-off, start-up), and a Kalman predictor must see every measurement in
//! between: taking the old state over and going on from the newest sample
//! leaves an error transient that a lightly damped filter has not shed by
//! the switch. So the supervisor keeps a ring of recent measurements and
//! replays those after the old state (channel `flexloop/measurement-replay`,
//! begun by the observer's first `CATCHING_UP` state, which it publishes
//! with its replay reader open, and paced by the progress it reports in the
//! next ones), while the live queue holds the newest ones. [`CatchUp`]
//! merges the two into the one gapless sequence the observer steps through,
//! and says when the replay has reached the live samples.

use flexloop_protocol::Measurement;

/// Live samples a catching-up observer can hold back: its live queue's
/// depth ([`flexloop_protocol::ChannelQos::logger_buffer_size`]) and as many
/// again arriving meanwhile.
pub const STASH: usize = 1024;

/// What to do with a replayed measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Replayed {
    /// The next one: step it.
    Step,
    /// Already stepped (the replay overlaps what the observer has).
    Skip,
    /// Newer than the next one: the samples between are lost (the
    /// supervisor's ring no longer held them).
    Gap { missing_from: u64, got: u64 },
}

/// The merge of replayed and live measurements after a handed-over state.
pub struct CatchUp {
    next: u64,
    stash: Box<[Measurement; STASH]>,
    head: usize,
    len: usize,
}

impl CatchUp {
    /// After a state that had processed measurement `state_seq`.
    pub fn after(state_seq: u64) -> Self {
        Self {
            next: state_seq + 1,
            stash: Box::new([Measurement::default(); STASH]),
            head: 0,
            len: 0,
        }
    }

    /// The measurement to step next.
    pub fn next_seq(&self) -> u64 {
        self.next
    }

    /// Judges a replayed measurement; a stepped one advances the sequence.
    pub fn replayed(&mut self, m: &Measurement) -> Replayed {
        if m.seq < self.next {
            return Replayed::Skip;
        }
        if m.seq > self.next {
            return Replayed::Gap {
                missing_from: self.next,
                got: m.seq,
            };
        }
        self.next += 1;
        Replayed::Step
    }

    /// Holds back a live measurement until the replay reaches it (in the
    /// order they arrive: the live queue delivers them in order).
    pub fn hold_live(&mut self, m: &Measurement) {
        if self.len == STASH {
            // The replay is slower than the loop (a loaded machine): the
            // oldest held sample goes, and the replay brings it instead (the
            // supervisor's ring reaches further back than the stash).
            self.head = (self.head + 1) % STASH;
            self.len -= 1;
        }
        self.stash[(self.head + self.len) % STASH] = *m;
        self.len += 1;
    }

    /// True once the held live samples continue the replayed sequence
    /// (held samples older than the next one are dropped on the way): from
    /// then on [`CatchUp::take_held`] yields the rest in order.
    pub fn reached_live(&mut self) -> bool {
        while self.len > 0 && self.stash[self.head].seq < self.next {
            self.head = (self.head + 1) % STASH;
            self.len -= 1;
        }
        self.len > 0 && self.stash[self.head].seq == self.next
    }

    /// The next held live sample, oldest first (the sequence advances past it).
    pub fn take_held(&mut self) -> Option<Measurement> {
        if self.len == 0 {
            return None;
        }
        let m = self.stash[self.head];
        self.head = (self.head + 1) % STASH;
        self.len -= 1;
        self.next = self.next.max(m.seq + 1);
        Some(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_components::ObserverCore;
    use flexloop_design::LoopDesign;
    use flexloop_protocol::{Estimate, Handover};
    use flexloop_scenario::{Overrides, Scenario};
    use std::path::Path;

    fn m(seq: u64) -> Measurement {
        Measurement {
            seq,
            ..Measurement::default()
        }
    }

    /// Runs a catch-up after state `state_seq` over interleaved arrivals
    /// (Ok: replayed, Err: live) and returns the stepped sequence numbers.
    fn merge(state_seq: u64, arrivals: &[Result<u64, u64>]) -> (Vec<u64>, bool) {
        let mut c = CatchUp::after(state_seq);
        let mut stepped = Vec::new();
        for a in arrivals {
            match *a {
                Ok(seq) => match c.replayed(&m(seq)) {
                    Replayed::Step => stepped.push(seq),
                    Replayed::Skip => {}
                    Replayed::Gap { .. } => return (stepped, false),
                },
                Err(seq) => c.hold_live(&m(seq)),
            }
            if c.reached_live() {
                while let Some(h) = c.take_held() {
                    stepped.push(h.seq);
                }
                return (stepped, true);
            }
        }
        (stepped, false)
    }

    #[test]
    fn replay_and_live_merge_into_one_gapless_sequence() {
        // State after 9; live samples 14.. arrive while 10..13 are replayed,
        // the replay overlapping the live ones a little.
        let arrivals = [
            Err(14),
            Ok(10),
            Err(15),
            Ok(11),
            Ok(12),
            Err(16),
            Ok(13),
            Ok(14),
        ];
        let (stepped, reached) = merge(9, &arrivals);
        assert!(reached);
        assert_eq!(stepped, (10..=16).collect::<Vec<_>>());
    }

    #[test]
    fn older_replayed_samples_are_skipped_and_a_hole_is_a_gap() {
        let mut c = CatchUp::after(9);
        assert_eq!(c.replayed(&m(8)), Replayed::Skip);
        assert_eq!(c.replayed(&m(10)), Replayed::Step);
        assert_eq!(
            c.replayed(&m(12)),
            Replayed::Gap {
                missing_from: 11,
                got: 12
            }
        );
        assert_eq!(c.next_seq(), 11);
        // Live samples that do not continue the sequence do not end it.
        c.hold_live(&m(13));
        assert!(!c.reached_live());
    }

    #[test]
    fn a_hole_in_the_replay_that_the_live_samples_cover_is_no_hole() {
        // The supervisor's ring lost 11..15 (its queue overflowed while it
        // was descheduled); the observer's live queue, drained at the gap,
        // has held everything from 11.
        let mut c = CatchUp::after(9);
        assert_eq!(c.replayed(&m(10)), Replayed::Step);
        assert!(matches!(c.replayed(&m(16)), Replayed::Gap { .. }));
        for seq in 11..=13 {
            c.hold_live(&m(seq));
        }
        assert!(c.reached_live());
        let held: Vec<u64> = std::iter::from_fn(|| c.take_held())
            .map(|m| m.seq)
            .collect();
        assert_eq!(held, [11, 12, 13]);
    }

    #[test]
    fn a_live_sample_right_after_the_state_needs_no_replay() {
        let (stepped, reached) = merge(41, &[Err(42), Err(43)]);
        assert!(reached);
        assert_eq!(stepped, vec![42]);
    }

    /// The free response, direct gain and x̂ of an estimate, bit for bit.
    fn same(a: &Estimate, b: &Estimate) -> bool {
        a.seq == b.seq && a.free == b.free && a.direct == b.direct && a.x_hat == b.x_hat
    }

    /// The point of it all, in lockstep (one process, every step
    /// deterministic): an observer that takes over a state 150 samples old
    /// and steps through the replay publishes from then on exactly the
    /// estimates of the one that never stopped; one that goes on from the
    /// old state without the replay does not (MC + AD, whose error dynamics
    /// are lightly damped).
    #[test]
    fn a_replayed_observer_continues_bit_for_bit() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/thesis-mc-ad.toml");
        let design =
            LoopDesign::from_scenario(&Scenario::load(&path, &Overrides::default()).unwrap())
                .unwrap();
        let (ny, nu) = (design.n_outputs, design.n_inputs);
        let measurements: Vec<Measurement> = (0..400u64)
            .map(|k| {
                let mut m = Measurement {
                    seq: k,
                    n_outputs: ny as u32,
                    n_inputs: nu as u32,
                    ..Measurement::default()
                };
                let t = k as f64 * design.ts;
                m.y[..ny].fill(1e-3 * (2.0 * t).sin() + 1e-7 * (3e3 * t).sin());
                m.u_applied[..nu].fill(50.0 * (150.0 * t).cos());
                m
            })
            .collect();
        let mut uninterrupted = ObserverCore::for_design(&design).unwrap();
        let mut estimates = Vec::new();
        let mut states = Vec::new();
        for m in &measurements {
            let mut e = Estimate::default();
            uninterrupted.step(m, &mut e);
            estimates.push(e);
            let mut h = Handover::default();
            uninterrupted.save(&mut h);
            h.seq = m.seq;
            states.push(h);
        }
        // The last state the crashed one published: after sample 99. The
        // restarted one's first live sample: 250; the replay comes in
        // windows of 64 while live samples queue up.
        let (state_seq, first_live) = (99usize, 250usize);
        let mut restarted = ObserverCore::for_design(&design).unwrap();
        assert!(restarted.load(&states[state_seq]));
        let mut merge = CatchUp::after(state_seq as u64);
        merge.hold_live(&measurements[first_live]);
        let mut live = first_live + 1;
        let mut e = Estimate::default();
        let mut replay_from = state_seq - 5;
        while !merge.reached_live() {
            // The supervisor's ring is behind the live queue.
            for m in &measurements[replay_from..(replay_from + 64).min(live - 3)] {
                if merge.replayed(m) == Replayed::Step {
                    restarted.step(m, &mut e);
                }
            }
            replay_from += 64;
            merge.hold_live(&measurements[live]);
            live += 1;
        }
        let mut compared = 0;
        while let Some(m) = merge.take_held() {
            restarted.step(&m, &mut e);
            assert!(same(&e, &estimates[m.seq as usize]), "sample {}", m.seq);
            compared += 1;
        }
        for m in &measurements[live..] {
            restarted.step(m, &mut e);
            assert!(same(&e, &estimates[m.seq as usize]), "sample {}", m.seq);
            compared += 1;
        }
        assert!(compared > 100, "{compared}");

        // Without the replay: the old state meets the new sample.
        let mut stale = ObserverCore::for_design(&design).unwrap();
        assert!(stale.load(&states[state_seq]));
        stale.step(&measurements[first_live], &mut e);
        assert!(!same(&e, &estimates[first_live]));
    }

    #[test]
    fn held_samples_dropped_for_room_are_replayed_instead() {
        let mut c = CatchUp::after(0);
        for seq in 10..10 + STASH as u64 + 1 {
            c.hold_live(&m(seq));
        }
        for seq in 1..=9 {
            assert_eq!(c.replayed(&m(seq)), Replayed::Step);
        }
        assert!(!c.reached_live(), "sample 10 was dropped from the stash");
        assert_eq!(c.replayed(&m(10)), Replayed::Step);
        assert!(c.reached_live());
        assert_eq!(c.take_held().map(|m| m.seq), Some(11));
    }
}
