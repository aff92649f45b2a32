//! Events the logger reads off the sample stream: where a condition of the
//! loop begins and ends (a run of misses, a stall, the safe action, the
//! observer's fallback, clamping, ...), each with its tick.
//!
//! Conditions come from the flags and the cumulative counters every message
//! carries, so the events need nothing but the samples; a condition that
//! lasts gives two events (begin, end) instead of one per tick.

use crate::event_message::{Edge, EventMessage, LoggerEvent};
use flexloop_protocol::{Command, Measurement, flags};

/// A condition of the loop that the samples show.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Condition {
    Miss,
    LateCommand,
    RejectedCommand,
    Stall,
    Fallback,
    ObserverFallback,
    Clamped,
    StaleEstimate,
}

impl Condition {
    /// The condition's begin or end as the logger's event.
    pub fn at(self, edge: Edge) -> LoggerEvent {
        match self {
            Self::Miss => LoggerEvent::Miss(edge),
            Self::LateCommand => LoggerEvent::LateCommand(edge),
            Self::RejectedCommand => LoggerEvent::RejectedCommand(edge),
            Self::Stall => LoggerEvent::Stall(edge),
            Self::Fallback => LoggerEvent::Fallback(edge),
            Self::ObserverFallback => LoggerEvent::ObserverFallback(edge),
            Self::Clamped => LoggerEvent::Clamped(edge),
            Self::StaleEstimate => LoggerEvent::StaleEstimate(edge),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopEvent {
    pub condition: Condition,
    pub edge: Edge,
    /// When the message that showed it was published (CLOCK_MONOTONIC).
    pub at_ns: u64,
}

impl LoopEvent {
    pub fn message(&self) -> EventMessage {
        EventMessage::Logger(self.condition.at(self.edge))
    }
}

/// One condition: holding since which tick.
#[derive(Debug, Clone, Copy)]
struct Tracked {
    condition: Condition,
    since: Option<u64>,
}

impl Tracked {
    const fn new(condition: Condition) -> Self {
        Self {
            condition,
            since: None,
        }
    }

    fn update(&mut self, on: bool, seq: u64, at_ns: u64, emit: &mut impl FnMut(LoopEvent)) {
        let edge = match (self.since, on) {
            (None, true) => {
                self.since = Some(seq);
                Edge::Begin { seq }
            }
            (Some(since), false) => {
                self.since = None;
                Edge::End {
                    seq,
                    ticks: seq.saturating_sub(since),
                }
            }
            _ => return,
        };
        emit(LoopEvent {
            condition: self.condition,
            edge,
            at_ns,
        });
    }
}

const MEASUREMENT_CONDITIONS: usize = 5;
const COMMAND_CONDITIONS: usize = 3;

/// Tracks the conditions over the measurements and commands in order.
#[derive(Debug, Clone)]
pub struct LoopEvents {
    /// miss, late-command, rejected-command (counter rises), stall, fallback (flags).
    measurement: [Tracked; MEASUREMENT_CONDITIONS],
    /// observer-fallback, clamped, stale-estimate (flags).
    command: [Tracked; COMMAND_CONDITIONS],
    /// The previous measurement's counters (misses, late, rejected).
    counters: Option<[u64; 3]>,
    last_measurement: Option<u64>,
    last_command: Option<u64>,
}

impl Default for LoopEvents {
    fn default() -> Self {
        Self {
            measurement: [
                Tracked::new(Condition::Miss),
                Tracked::new(Condition::LateCommand),
                Tracked::new(Condition::RejectedCommand),
                Tracked::new(Condition::Stall),
                Tracked::new(Condition::Fallback),
            ],
            command: [
                Tracked::new(Condition::ObserverFallback),
                Tracked::new(Condition::Clamped),
                Tracked::new(Condition::StaleEstimate),
            ],
            counters: None,
            last_measurement: None,
            last_command: None,
        }
    }
}

impl LoopEvents {
    pub fn measurement(&mut self, m: &Measurement, mut emit: impl FnMut(LoopEvent)) {
        // Only newer ticks: a late sample does not reopen what has ended.
        if self.last_measurement.is_some_and(|last| m.seq <= last) {
            return;
        }
        self.last_measurement = Some(m.seq);
        let now = [m.misses, m.late_commands, m.rejected_commands];
        // The first sample a (restarted) logger sees: its counters are
        // totals from before, not a change.
        let previous = self.counters.replace(now).unwrap_or(now);
        let on = [
            now[0] > previous[0],
            now[1] > previous[1],
            now[2] > previous[2],
            m.flags & flags::STALLED_TICK != 0,
            m.flags & flags::FALLBACK != 0,
        ];
        for (condition, on) in self.measurement.iter_mut().zip(on) {
            condition.update(on, m.seq, m.published_ns, &mut emit);
        }
    }

    pub fn command(&mut self, c: &Command, mut emit: impl FnMut(LoopEvent)) {
        // One command per tick: during a swap a second instance may answer too.
        if self.last_command.is_some_and(|last| c.seq <= last) {
            return;
        }
        self.last_command = Some(c.seq);
        let on = [
            c.flags & flags::OBSERVER_FALLBACK != 0,
            c.flags & flags::CLAMPED != 0,
            c.flags & flags::STALE_ESTIMATE != 0,
        ];
        for (condition, on) in self.command.iter_mut().zip(on) {
            condition.update(on, c.seq, c.published_ns, &mut emit);
        }
    }

    /// Ends every condition still open, at the tick after the last one seen.
    pub fn finish(&mut self, at_ns: u64, mut emit: impl FnMut(LoopEvent)) {
        let next_m = self.last_measurement.map_or(0, |s| s + 1);
        let next_c = self.last_command.map_or(0, |s| s + 1);
        for c in &mut self.measurement {
            c.update(false, next_m, at_ns, &mut emit);
        }
        for c in &mut self.command {
            c.update(false, next_c, at_ns, &mut emit);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measurement(seq: u64, misses: u64, flags: u32) -> Measurement {
        Measurement {
            seq,
            misses,
            flags,
            ..Default::default()
        }
    }

    fn run(ms: &[Measurement]) -> Vec<(String, u64)> {
        let mut events = LoopEvents::default();
        let mut out = Vec::new();
        let mut push = |e: LoopEvent| {
            out.push((
                format!(
                    "{}:{}",
                    e.message().kind(),
                    match e.edge {
                        Edge::Begin { .. } => "begin".to_string(),
                        Edge::End { ticks, .. } => format!("end{ticks}"),
                    }
                ),
                e.edge.seq(),
            ))
        };
        for m in ms {
            events.measurement(m, &mut push);
        }
        events.finish(0, &mut push);
        out
    }

    #[test]
    fn a_run_of_misses_is_one_begin_and_one_end() {
        let out = run(&[
            measurement(0, 0, 0),
            measurement(1, 1, flags::HELD_INPUT),
            measurement(2, 2, flags::HELD_INPUT),
            measurement(3, 2, 0),
            measurement(4, 3, 0),
        ]);
        assert_eq!(
            out,
            vec![
                ("miss:begin".into(), 1),
                ("miss:end2".into(), 3),
                ("miss:begin".into(), 4),
                ("miss:end1".into(), 5),
            ]
        );
    }

    #[test]
    fn counters_at_the_first_sample_are_no_event_and_late_samples_are_ignored() {
        let out = run(&[
            measurement(100, 7, 0),
            measurement(101, 7, flags::STALLED_TICK),
            measurement(99, 3, 0),
            measurement(102, 7, 0),
        ]);
        assert_eq!(
            out,
            vec![("stall:begin".into(), 101), ("stall:end1".into(), 102)]
        );
    }

    #[test]
    fn command_flags_open_and_close_conditions() {
        let mut events = LoopEvents::default();
        let mut out = Vec::new();
        for (seq, f) in [(0, 0), (1, flags::CLAMPED), (1, 0), (2, 0)] {
            let c = Command {
                seq,
                flags: f,
                ..Default::default()
            };
            events.command(&c, |e| out.push(e.message().to_json()));
        }
        assert_eq!(
            out,
            vec![
                r#"{"source":"logger","kind":"clamped","phase":"begin","seq":1}"#,
                r#"{"source":"logger","kind":"clamped","phase":"end","seq":2,"ticks":1}"#,
            ]
        );
        let parsed: serde_json::Value = serde_json::from_str(&out[1]).unwrap();
        assert_eq!(parsed["ticks"], 1);
    }
}
