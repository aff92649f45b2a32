//! One message of the sample file's `/events` channel: what the logger saw
//! in the samples or did itself, what flexloop found when it joined a
//! run's files, and every line of the supervisor's `events.jsonl`, copied
//! (docs/recording.md). Written and read back through [`EventMessage`]; on
//! the wire it is one JSON object whose `source` says whose it is and whose
//! `kind` names the event.

use flexloop_runfiles::events::SupervisorEvent;
use serde::{Deserialize, Serialize};

/// One `/events` message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase")]
pub enum EventMessage {
    Logger(LoggerEvent),
    /// Written by flexloop when it joins a run's files (after the loggers).
    Flexloop(JoinEvent),
    /// A line of the supervisor's `events.jsonl`, as it was written.
    Supervisor(SupervisorEvent),
}

impl EventMessage {
    /// The message as the file holds it.
    pub fn to_json(&self) -> String {
        // Every field is a string, a number or a bool (no map with
        // non-string keys): serialising cannot fail.
        serde_json::to_string(self).expect("an event message serialises")
    }

    /// The event's kind as the file names it.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Logger(e) => e.kind(),
            Self::Flexloop(JoinEvent::Gap(_)) => "gap",
            Self::Supervisor(e) => e.kind.name(),
        }
    }

    /// Whose event it is, as the file names it.
    pub fn source(&self) -> &'static str {
        match self {
            Self::Logger(_) => "logger",
            Self::Flexloop(_) => "flexloop",
            Self::Supervisor(_) => "supervisor",
        }
    }

    /// The loop's sample it is about, if any.
    pub fn seq(&self) -> Option<u64> {
        match self {
            Self::Logger(LoggerEvent::RecordingEnd { seq, .. }) => Some(*seq),
            Self::Logger(e) => e
                .edge()
                .map(|edge| edge.seq())
                .or(self.gap().map(|g| g.seq)),
            Self::Flexloop(JoinEvent::Gap(g)) => Some(g.seq),
            Self::Supervisor(e) => e.seq,
        }
    }

    /// The gap it reports, if it reports one.
    pub fn gap(&self) -> Option<&Gap> {
        match self {
            Self::Logger(LoggerEvent::Gap(g)) | Self::Flexloop(JoinEvent::Gap(g)) => Some(g),
            _ => None,
        }
    }
}

/// What the logger writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum LoggerEvent {
    /// Samples of a channel that the logger did not record.
    Gap(Gap),
    /// The logger opened its file.
    RecordingStart {
        generation: u32,
        file: String,
    },
    /// The logger closed its file: the last measurement, why, and its gaps.
    RecordingEnd {
        seq: u64,
        reason: String,
        gaps: u64,
    },
    /// A line of `events.jsonl` that was not a supervisor's event.
    UnreadableSupervisorLine {
        line: String,
    },
    // The loop's conditions, as the samples show them (crate::loop_events).
    Miss(Edge),
    LateCommand(Edge),
    RejectedCommand(Edge),
    Stall(Edge),
    Fallback(Edge),
    ObserverFallback(Edge),
    Clamped(Edge),
    StaleEstimate(Edge),
}

impl LoggerEvent {
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Gap(_) => "gap",
            Self::RecordingStart { .. } => "recording-start",
            Self::RecordingEnd { .. } => "recording-end",
            Self::UnreadableSupervisorLine { .. } => "unreadable-supervisor-line",
            Self::Miss(_) => "miss",
            Self::LateCommand(_) => "late-command",
            Self::RejectedCommand(_) => "rejected-command",
            Self::Stall(_) => "stall",
            Self::Fallback(_) => "fallback",
            Self::ObserverFallback(_) => "observer-fallback",
            Self::Clamped(_) => "clamped",
            Self::StaleEstimate(_) => "stale-estimate",
        }
    }

    /// A loop condition's begin or end, if it is one.
    pub fn edge(&self) -> Option<Edge> {
        match *self {
            Self::Miss(e)
            | Self::LateCommand(e)
            | Self::RejectedCommand(e)
            | Self::Stall(e)
            | Self::Fallback(e)
            | Self::ObserverFallback(e)
            | Self::Clamped(e)
            | Self::StaleEstimate(e) => Some(e),
            _ => None,
        }
    }
}

/// What flexloop writes when it joins a run's files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum JoinEvent {
    Gap(Gap),
}

/// A run of samples of one channel that the file does not hold.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Gap {
    /// `measurement`, `estimate` or `command`.
    pub channel: String,
    /// The first missing sample.
    pub seq: u64,
    pub count: u64,
    /// Why, when it is known; none: lost on its way to the logger.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<GapCause>,
    /// The last missing sample, where the gap was not contiguous in time
    /// (the logger's queue dropped samples from `seq` to here).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_seq: Option<u64>,
    /// A logger outage: the generation whose logger recorded last before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after_generation: Option<u32>,
}

/// Why samples are missing from the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GapCause {
    /// The logger's writer queue had no room.
    LoggerQueue,
    /// The process never sent them (it ended, or was hung, before).
    NotSent,
    /// No logger ran then (between a logger's death and its restart).
    LoggerOutage,
    /// Missing, and no logger said so (a killed logger's last gaps).
    Unreported,
}

/// Where a condition of the loop began or ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "phase", rename_all = "lowercase")]
pub enum Edge {
    Begin {
        seq: u64,
    },
    /// `ticks`: how long it held.
    End {
        seq: u64,
        ticks: u64,
    },
}

impl Edge {
    pub fn seq(&self) -> u64 {
        match *self {
            Self::Begin { seq } | Self::End { seq, .. } => seq,
        }
    }

    /// `begin` or `end`, as the file names it.
    pub fn phase(&self) -> &'static str {
        match self {
            Self::Begin { .. } => "begin",
            Self::End { .. } => "end",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runfiles::events::{EventKind, Spare};

    fn round_trip(message: EventMessage) -> serde_json::Value {
        let json = message.to_json();
        let back: EventMessage = serde_json::from_str(&json).unwrap();
        assert_eq!(back, message, "{json}");
        serde_json::from_str(&json).unwrap()
    }

    #[test]
    fn a_condition_is_source_kind_phase_and_its_ticks() {
        let v = round_trip(EventMessage::Logger(LoggerEvent::Clamped(Edge::End {
            seq: 2,
            ticks: 1,
        })));
        assert_eq!(
            v,
            serde_json::json!({"source": "logger", "kind": "clamped", "phase": "end", "seq": 2, "ticks": 1})
        );
    }

    #[test]
    fn gaps_keep_their_cause_and_leave_out_what_they_lack() {
        let v = round_trip(EventMessage::Logger(LoggerEvent::Gap(Gap {
            channel: "command".into(),
            seq: 10,
            count: 3,
            cause: Some(GapCause::LoggerQueue),
            last_seq: Some(14),
            after_generation: None,
        })));
        assert_eq!(v["cause"], "logger-queue");
        assert!(v.get("after_generation").is_none());
        let outage = EventMessage::Flexloop(JoinEvent::Gap(Gap {
            channel: "estimate".into(),
            seq: 5,
            count: 7,
            cause: Some(GapCause::LoggerOutage),
            last_seq: None,
            after_generation: Some(0),
        }));
        assert_eq!(outage.gap().unwrap().count, 7);
        assert_eq!(round_trip(outage)["source"], "flexloop");
    }

    #[test]
    fn a_supervisor_line_is_copied_with_its_source() {
        let event = SupervisorEvent {
            t_s: 0.5,
            role: "observer".into(),
            generation: None,
            seq: Some(3),
            kind: EventKind::Spare(Spare { pid: 12 }),
        };
        let message = EventMessage::Supervisor(event);
        assert_eq!(message.kind(), "spare");
        let v = round_trip(message);
        assert_eq!(v["source"], "supervisor");
        assert_eq!(v["detail"]["pid"], 12);
    }

    #[test]
    fn the_logger_s_own_events_read_back() {
        for e in [
            LoggerEvent::RecordingStart {
                generation: 1,
                file: "samples.g1.mcap".into(),
            },
            LoggerEvent::RecordingEnd {
                seq: 99,
                reason: "end-of-run".into(),
                gaps: 0,
            },
            LoggerEvent::UnreadableSupervisorLine { line: "{".into() },
            LoggerEvent::Miss(Edge::Begin { seq: 4 }),
        ] {
            let kind = e.kind();
            assert_eq!(round_trip(EventMessage::Logger(e))["kind"], kind);
        }
    }
}
