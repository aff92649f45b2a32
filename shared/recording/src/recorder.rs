//! The logger's bookkeeping over the samples: sequence gaps per channel,
//! latency histograms, the events the loop's flags and counters show; every
//! message and event goes on to a [`RecordSink`] (the sample file).

use crate::event_message::{EventMessage, Gap, GapCause, LoggerEvent};
use crate::loop_events::LoopEvents;
use crate::sample_file::SampleWriter;
use crate::storage::Storage;
use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_runtime::latency::LoopLatencies;

/// Per-channel sequence bookkeeping, tolerant of reordering: during a swap
/// two instances publish on one channel and a reader may get sample k+1 from
/// the new one before sample k from the old one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelCount {
    pub samples: u64,
    /// Highest sequence number seen.
    pub last_seq: Option<u64>,
    /// The first number seen (the numbers before it are not in the window).
    pub first_seq: Option<u64>,
    /// Missing numbers that fell out of the reorder window.
    settled_gaps: u64,
    /// Bit i: `last_seq − i` was seen (numbers before the first count as seen).
    window: u64,
    /// A run of missing numbers that left the window and may go on.
    pending: Option<(u64, u64)>,
}

impl Default for ChannelCount {
    fn default() -> Self {
        Self {
            samples: 0,
            last_seq: None,
            first_seq: None,
            settled_gaps: 0,
            window: u64::MAX,
            pending: None,
        }
    }
}

/// How far back a late sample still fills its place.
const REORDER_WINDOW: u64 = 64;

/// Adds `count` missing numbers from `first` on to the open run, reporting
/// the run before it if they do not continue it.
fn join(
    pending: &mut Option<(u64, u64)>,
    first: u64,
    count: u64,
    report: &mut impl FnMut(u64, u64),
) {
    if count == 0 {
        return;
    }
    *pending = match *pending {
        Some((start, n)) if start + n == first => Some((start, n + count)),
        Some((start, n)) => {
            report(start, n);
            Some((first, count))
        }
        None => Some((first, count)),
    };
}

/// Calls `add(number, 1)` for every unseen number of `window` (bit p stands
/// for `last − p`) at `positions`, in ascending order.
fn unseen(window: u64, last: u64, positions: std::ops::Range<u64>, mut add: impl FnMut(u64, u64)) {
    for p in positions.rev() {
        if window & (1 << p) == 0 {
            add(last - p, 1);
        }
    }
}

impl ChannelCount {
    /// Counts `seq`; `missing(first, count)` hears of every run of numbers
    /// that fell out of the reorder window unseen, once the run is complete.
    fn see(&mut self, seq: u64, mut missing: impl FnMut(u64, u64)) {
        self.samples += 1;
        if self.first_seq.is_none() {
            self.first_seq = Some(seq);
        }
        match self.last_seq {
            None => {
                self.last_seq = Some(seq);
            }
            Some(last) if seq > last => {
                let shift = seq - last;
                let mut pending = self.pending.take();
                {
                    let mut add = |first, count| join(&mut pending, first, count, &mut missing);
                    if shift >= REORDER_WINDOW {
                        // All of the window leaves, and so do the missing numbers
                        // too old for the new one; the newer missing ones stay
                        // in the new window as unseen.
                        unseen(self.window, last, 0..REORDER_WINDOW, &mut add);
                        add(last + 1, shift - REORDER_WINDOW);
                        self.settled_gaps +=
                            u64::from(self.window.count_zeros()) + shift - REORDER_WINDOW;
                        self.window = 0;
                    } else {
                        unseen(
                            self.window,
                            last,
                            REORDER_WINDOW - shift..REORDER_WINDOW,
                            &mut add,
                        );
                        let leaving = self.window >> (REORDER_WINDOW - shift);
                        self.settled_gaps += shift - u64::from(leaving.count_ones());
                        self.window <<= shift;
                    }
                }
                self.window |= 1;
                self.last_seq = Some(seq);
                // The run is complete once the number after it was seen.
                if let Some((first, n)) = pending {
                    let back = seq - (first + n);
                    if back >= REORDER_WINDOW || self.window & (1 << back) != 0 {
                        missing(first, n);
                        pending = None;
                    }
                }
                self.pending = pending;
            }
            Some(last) => {
                let back = last - seq;
                if back < REORDER_WINDOW {
                    self.window |= 1 << back;
                }
            }
        }
    }

    /// Sequence numbers that never arrived (those still inside the reorder
    /// window count as missing too: a reader that asks now gets no more).
    pub fn gaps(&self) -> u64 {
        self.settled_gaps + u64::from(self.window.count_zeros())
    }

    /// Reports the open run and the numbers still missing inside the window
    /// (at the end: no more will come).
    fn unsettled_gaps(&mut self, mut missing: impl FnMut(u64, u64)) {
        let mut pending = self.pending.take();
        if let Some(last) = self.last_seq {
            unseen(self.window, last, 0..REORDER_WINDOW, |first, count| {
                join(&mut pending, first, count, &mut missing)
            });
        }
        if let Some((first, n)) = pending {
            missing(first, n);
        }
    }
}

/// Where the recorder hands every message and event: the sample file
/// itself, or a queue to the thread that writes it (the logger).
pub trait RecordSink {
    fn measurement(&mut self, m: &Measurement);
    fn estimate(&mut self, e: &Estimate);
    fn command(&mut self, c: &Command);
    /// One `/events` message at `at_ns` (CLOCK_MONOTONIC).
    fn event(&mut self, at_ns: u64, message: EventMessage);
}

impl<S: Storage> RecordSink for SampleWriter<S> {
    fn measurement(&mut self, m: &Measurement) {
        SampleWriter::measurement(self, m);
    }

    fn estimate(&mut self, e: &Estimate) {
        SampleWriter::estimate(self, e);
    }

    fn command(&mut self, c: &Command) {
        SampleWriter::command(self, c);
    }

    fn event(&mut self, at_ns: u64, message: EventMessage) {
        SampleWriter::event(self, at_ns, &message);
    }
}

/// Counts every message, keeps the latency histograms, writes what the
/// samples show as events, and hands everything to its sink.
pub struct Recorder<O: RecordSink> {
    out: O,
    events: LoopEvents,
    pub latencies: LoopLatencies,
    pub measurements: ChannelCount,
    pub estimates: ChannelCount,
    pub commands: ChannelCount,
    /// Commands computed with an estimate older than their tick (the observer
    /// was late and the controller went on without waiting).
    pub stale_estimates: u64,
    /// The newest measurement (its counters are the plant's totals).
    pub last_measurement: Option<Measurement>,
    /// Commands from an instance that owned neither their sample nor a
    /// standby's duty: counted, not recorded (see [`Recorder::foreign_command`]).
    pub foreign_commands: u64,
}

/// The logger's gap event: `count` samples of `channel` from `first`.
pub fn gap(channel: &str, first: u64, count: u64, cause: Option<GapCause>) -> EventMessage {
    EventMessage::Logger(LoggerEvent::Gap(Gap {
        channel: channel.into(),
        seq: first,
        count,
        cause,
        last_seq: None,
        after_generation: None,
    }))
}

impl<O: RecordSink> Recorder<O> {
    pub fn new(out: O) -> Self {
        Self {
            out,
            events: LoopEvents::default(),
            latencies: LoopLatencies::new(),
            measurements: ChannelCount::default(),
            estimates: ChannelCount::default(),
            commands: ChannelCount::default(),
            stale_estimates: 0,
            last_measurement: None,
            foreign_commands: 0,
        }
    }

    pub fn sink(&mut self) -> &mut O {
        &mut self.out
    }

    pub fn sink_ref(&self) -> &O {
        &self.out
    }

    pub fn measurement(&mut self, m: &Measurement) {
        let out = &mut self.out;
        out.measurement(m);
        self.measurements.see(m.seq, |first, count| {
            out.event(m.published_ns, gap("measurement", first, count, None))
        });
        self.events
            .measurement(m, |e| out.event(e.at_ns, e.message()));
        self.latencies.observe_measurement(m);
        self.last_measurement = Some(*m);
    }

    pub fn estimate(&mut self, e: &Estimate) {
        let out = &mut self.out;
        out.estimate(e);
        self.estimates.see(e.seq, |first, count| {
            out.event(e.published_ns, gap("estimate", first, count, None))
        });
        // The initial estimate answers no measurement.
        if e.source_published_ns != 0 {
            self.latencies.observe_estimate(e);
        }
    }

    pub fn command(&mut self, c: &Command) {
        let out = &mut self.out;
        out.command(c);
        self.commands.see(c.seq, |first, count| {
            out.event(c.published_ns, gap("command", first, count, None))
        });
        self.events.command(c, |e| out.event(e.at_ns, e.message()));
        if c.estimate_seq != c.seq {
            self.stale_estimates += 1;
        }
        self.latencies.observe_command(c);
    }

    /// A command from an instance that owned neither its sample nor a
    /// standby's duty (a stray or misbehaving program, which the plant
    /// rejects): counted apart, not recorded, so that the sample file's
    /// commands, the gaps and the latencies are the loop's own.
    pub fn foreign_command(&mut self) {
        self.foreign_commands += 1;
    }

    /// An event from elsewhere (the supervisor's, the logger's own).
    pub fn event(&mut self, at_ns: u64, message: EventMessage) {
        self.out.event(at_ns, message);
    }

    pub fn total_gaps(&self) -> u64 {
        self.measurements.gaps() + self.estimates.gaps() + self.commands.gaps()
    }

    /// Estimates and commands never received after the last of them, up to
    /// the last tick (the estimate for tick k + 1 follows measurement k):
    /// their producer stopped (silent, dead, not replaced) while the plant
    /// ticked on. Gaps all the same: samples + gaps = ticks on every
    /// channel. As (first, count) per channel, in [`Self::finish`]'s order.
    pub fn never_sent(&self) -> [Option<(u64, u64)>; 3] {
        let Some(last) = self.last_measurement.map(|m| m.seq) else {
            return [None; 3];
        };
        let after = |count: &ChannelCount, end: u64| {
            let first = count.last_seq.map_or(0, |s| s + 1);
            (end >= first).then(|| (first, end - first + 1))
        };
        [
            None,
            after(&self.estimates, last + 1),
            after(&self.commands, last),
        ]
    }

    /// Commands never received before the first of them, from the first
    /// measurement this recorder saw: a controller that answered late at the
    /// loop's start (a slow start on a loaded machine) left the plant's first
    /// ticks without one. As (first, count).
    pub fn never_sent_at_start(&self) -> Option<(u64, u64)> {
        let start = self.measurements.first_seq?;
        let first = self.commands.first_seq?;
        (first > start).then(|| (start, first - start))
    }

    /// At the end: writes the conditions still open and the gaps still in
    /// the reorder windows as events (no more samples will come).
    pub fn finish(&mut self, at_ns: u64) {
        let never_sent = self.never_sent();
        if let Some((first, n)) = self.never_sent_at_start() {
            self.out
                .event(at_ns, gap("command", first, n, Some(GapCause::NotSent)));
        }
        let out = &mut self.out;
        self.events
            .finish(at_ns, |e| out.event(e.at_ns, e.message()));
        for (i, (name, count)) in [
            ("measurement", &mut self.measurements),
            ("estimate", &mut self.estimates),
            ("command", &mut self.commands),
        ]
        .into_iter()
        .enumerate()
        {
            count.unsettled_gaps(|first, n| out.event(at_ns, gap(name, first, n, None)));
            if let Some((first, n)) = never_sent[i] {
                out.event(at_ns, gap(name, first, n, Some(GapCause::NotSent)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event_message::Edge;
    use crate::sample_file::LogReader;
    use std::collections::BTreeMap;
    use std::io::Cursor;

    #[test]
    fn records_every_message_and_writes_gaps_and_conditions_as_events() {
        let mut r = Recorder::new(SampleWriter::new(Cursor::new(Vec::new()), 1_000).unwrap());
        r.sink()
            .metadata(BTreeMap::from([("scenario".into(), "t".into())]));
        for seq in [0u64, 1, 2, 5] {
            r.measurement(&Measurement {
                seq,
                published_ns: 10 + seq,
                misses: u64::from(seq >= 2),
                y: [seq as f64; 8],
                ..Default::default()
            });
        }
        r.command(&Command {
            seq: 0,
            ..Default::default()
        });
        r.sink().flush();
        assert_eq!(r.measurements.gaps(), 2);
        assert_eq!(r.measurements.samples, 4);
        assert_eq!(r.total_gaps(), 2);
        r.finish(99);
        let bytes = r.sink().finish().unwrap().into_inner();
        assert_eq!(r.sink().recording_json()["state"], "complete");
        let log = LogReader::parse(&bytes).unwrap();
        assert!(!log.torn_tail, "{:?}", log.tail_error);
        assert_eq!(log.meta("scenario"), Some("t"));
        let seqs: Vec<u64> = log.measurements().map(|m| m.seq).collect();
        assert_eq!(seqs, vec![0, 1, 2, 5]);
        assert_eq!(log.measurements().last().unwrap().y[3], 5.0);
        assert_eq!(log.commands().count(), 1);
        let messages: Vec<&EventMessage> = log.events.iter().map(|e| &e.message).collect();
        let miss = EventMessage::Logger(LoggerEvent::Miss(Edge::Begin { seq: 2 }));
        assert!(messages.contains(&&miss), "{messages:?}");
        // The gap 3..=4 is still inside the reorder window at the end.
        assert!(
            messages.contains(&&gap("measurement", 3, 2, None)),
            "{messages:?}"
        );
        // No command after 0, no estimate at all, up to the last tick (5):
        // never sent, and gaps all the same.
        assert_eq!(r.never_sent(), [None, Some((0, 7)), Some((1, 5))]);
        // The first command was for the first tick: nothing missing before it.
        assert_eq!(r.never_sent_at_start(), None);
        let not_sent: Vec<&EventMessage> = messages
            .iter()
            .copied()
            .filter(|m| m.gap().is_some_and(|g| g.cause == Some(GapCause::NotSent)))
            .collect();
        assert_eq!(
            not_sent,
            [
                &gap("estimate", 0, 7, Some(GapCause::NotSent)),
                &gap("command", 1, 5, Some(GapCause::NotSent))
            ]
        );
        // Log time: the message's publish stamp plus the offset.
        assert_eq!(
            log.events
                .iter()
                .find(|e| e.message == miss)
                .unwrap()
                .log_time_ns,
            1_012
        );
    }

    /// A controller whose first command came for tick 3 (a slow start):
    /// the commands for ticks 0..=2 were never sent, gaps all the same, so
    /// samples + gaps = ticks from the start too.
    #[test]
    fn commands_missing_before_the_first_are_never_sent() {
        let mut r = Recorder::new(SampleWriter::new(Cursor::new(Vec::new()), 1_000).unwrap());
        for seq in 0..6 {
            r.measurement(&Measurement {
                seq,
                ..Default::default()
            });
        }
        for seq in 3..6 {
            r.command(&Command {
                seq,
                ..Default::default()
            });
        }
        assert_eq!(r.never_sent_at_start(), Some((0, 3)));
        assert_eq!(r.never_sent()[2], None);
        let gaps = r.commands.gaps() + 3;
        assert_eq!(r.commands.samples + gaps, 6);
    }
}

#[cfg(test)]
mod channel_count_tests {
    use super::ChannelCount;

    fn count(seqs: &[u64]) -> ChannelCount {
        let mut c = ChannelCount::default();
        for s in seqs {
            c.see(*s, |_, _| {});
        }
        c
    }

    /// Runs of missing numbers: (first, count).
    type Runs = Vec<(u64, u64)>;

    /// Runs reported as settled, then those still in the window.
    fn runs(seqs: &[u64]) -> (Runs, Runs) {
        let mut c = ChannelCount::default();
        let mut settled = Vec::new();
        for s in seqs {
            c.see(*s, |first, n| settled.push((first, n)));
        }
        let mut open = Vec::new();
        c.unsettled_gaps(|first, n| open.push((first, n)));
        assert!(c.pending.is_none());
        (settled, open)
    }

    #[test]
    fn reordering_within_the_window_is_not_a_gap() {
        assert_eq!(count(&[0, 1, 3, 2, 4]).gaps(), 0);
        assert_eq!(count(&[5, 6, 8, 9]).gaps(), 1);
        assert_eq!(count(&[0, 1, 200, 2]).gaps(), 198);
        // A sample that comes back after the window was already counted missing.
        let mut late = count(&(0..100).filter(|s| *s != 10).collect::<Vec<_>>());
        late.see(10, |_, _| {});
        assert_eq!(late.gaps(), 1);
    }

    #[test]
    fn missing_runs_are_reported_once_each_and_add_up_to_the_gaps() {
        let seqs: Vec<u64> = (0..300)
            .filter(|s| !(10..13).contains(s) && *s != 50 && *s != 290)
            .chain([400, 401, 470])
            .collect();
        let (settled, open) = runs(&seqs);
        assert_eq!(settled, vec![(10, 3), (50, 1), (290, 1), (300, 100)]);
        // 402..=406 left the window when 470 came, 407..=469 are still in
        // it: one run, reported at the end.
        assert_eq!(open, vec![(402, 68)]);
        let reported: u64 = settled.iter().chain(&open).map(|(_, n)| n).sum();
        assert_eq!(reported, count(&seqs).gaps());
        // A late number inside the window is not reported.
        let (settled, open) = runs(&[0, 1, 3, 2, 4]);
        assert!(settled.is_empty() && open.is_empty());
    }
}
