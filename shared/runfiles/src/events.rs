//! `events.jsonl`: what the supervisor did and saw while the loop ran, one
//! JSON line per event. The supervisor writes it; `status`, `report`, the
//! logger (which copies each line into the sample file's `/events`,
//! docs/recording.md) and the tests read it, all through [`SupervisorEvent`].
//!
//! A line is `{"t_s", "kind", "role", "generation", "seq", "detail"}`: the
//! kind names the event and the detail's shape is the kind's
//! ([`EventKind`]), so that a reader matches on what happened instead of
//! looking keys up in free-form JSON.

use crate::supervision::{MeasureOutcome, SetOutcome, SwitchRecord};
use serde::{Deserialize, Serialize};

/// One line of `events.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SupervisorEvent {
    /// Seconds since the supervisor started the loop.
    pub t_s: f64,
    pub role: String,
    /// The instance's generation; none for a spare that has served none,
    /// and for the plant (never swapped).
    pub generation: Option<u32>,
    /// The loop's newest sample when it happened, if it had ticked.
    pub seq: Option<u64>,
    /// What happened: `kind` and `detail` in the line.
    #[serde(flatten)]
    pub kind: EventKind,
}

/// What happened, and its facts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "detail", rename_all = "kebab-case")]
pub enum EventKind {
    /// A process of the loop ended without being asked to (or was killed
    /// as hung: then a `silent` event comes first).
    Crash(Crash),
    /// A serving controller or observer sent nothing the loop could use
    /// for too long, or was found stopped: it is killed.
    Silent(Silent),
    /// A crashed role serves again: a new instance took over.
    Restart(Restart),
    /// A restart could not be made; why.
    RestartFailed(String),
    /// The standby controller took over from a crashed active one.
    PromoteStandby(SwitchRecord),
    /// `flexloop swap`: the role is served by another scenario's instance.
    Swap(Swap),
    /// `flexloop set`: tunables changed and handed over.
    Set(Set),
    /// A standby controller follows the loop.
    Standby(Standby),
    /// A standby could not be brought up; why.
    StandbyFailed(String),
    /// A warm spare idles, ready to take a role over.
    Spare(Spare),
    /// A spare could not be started; why.
    SpareFailed(String),
    /// The loop was asked to stop.
    Stop(Stop),
    /// `flexloop measure --running`: a measurement ordered on the loop.
    Measure(Measure),
}

impl EventKind {
    /// The kind's name in the file (`crash`, `promote-standby`, ...).
    pub fn name(&self) -> &'static str {
        match self {
            Self::Crash(_) => "crash",
            Self::Silent(_) => "silent",
            Self::Restart(_) => "restart",
            Self::RestartFailed(_) => "restart-failed",
            Self::PromoteStandby(_) => "promote-standby",
            Self::Swap(_) => "swap",
            Self::Set(_) => "set",
            Self::Standby(_) => "standby",
            Self::StandbyFailed(_) => "standby-failed",
            Self::Spare(_) => "spare",
            Self::SpareFailed(_) => "spare-failed",
            Self::Stop(_) => "stop",
            Self::Measure(_) => "measure",
        }
    }

    /// The switch the event made, if it handed the role to a new instance.
    pub fn switch(&self) -> Option<&SwitchRecord> {
        match self {
            Self::Restart(r) => r.switch.as_ref(),
            Self::PromoteStandby(s) => Some(s),
            Self::Swap(s) => Some(&s.switch),
            _ => None,
        }
    }
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// A `crash`: how the end was found and what follows from it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Crash {
    /// The exit code (128 + signal); none when the end was found before
    /// the kernel's exit report (in its exit, stopped, silent).
    pub exit: Option<i32>,
    /// How the end was found: `exit report`, `exiting`, `silent`, `stopped`
    /// (empty in runs recorded before it was said).
    #[serde(default)]
    pub found: String,
    /// Why: `crashed`, `silent`, `non-finite output`; none for a spare's
    /// or the standby's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<String>,
    /// The run cannot go on, and why (the restart budget is spent, the
    /// plant ended, a program never followed the loop).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fatal: Option<String>,
    /// The restart is due after this back-off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restart_in_ms: Option<u64>,
    /// It was a spare, or the standby: another takes its place.
    #[serde(default, skip_serializing_if = "is_false")]
    pub spare: bool,
    #[serde(default, skip_serializing_if = "is_false")]
    pub standby: bool,
}

/// A `silent` event: the hung process and for how long it was silent.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Silent {
    pub pid: i32,
    pub ticks_without_output: u64,
    /// Wall time without output (none for a stopped process, found at once).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seconds_without_output: Option<f64>,
    /// The kernel showed it stopped (SIGSTOP, a debugger).
    #[serde(default, skip_serializing_if = "is_false")]
    pub stopped: bool,
    /// `non-finite output`: it sent, but only what the plant refuses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub non_finite_commands_in_a_row: Option<u64>,
    /// What the supervisor did about it.
    pub action: String,
}

/// A `restart`: the new instance's switch (its fields in the detail, as a
/// promotion's), or what stands for it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Restart {
    /// Where the new instance took over (none for a logger's restart, or
    /// one before the loop's first tick).
    #[serde(flatten)]
    pub switch: Option<SwitchRecord>,
    /// A restarted logger's files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub files: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "is_false")]
    pub before_tick_0: bool,
    /// A program that failed on the loop was replaced by the scenario's
    /// built-in law (`scenario`): the program's scenario.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rolled_back_from: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenario: Option<String>,
}

/// Who sent a request: the pid its file is named by and the user who owns
/// the file (which no other user can forge).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Sender {
    pub pid: Option<u32>,
    pub uid: u32,
}

/// A `swap`: the scenario the role runs now and the switch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Swap {
    pub scenario: String,
    pub switch: SwitchRecord,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sender: Option<Sender>,
}

/// A `set`: what it did, and who asked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Set {
    #[serde(flatten)]
    pub outcome: SetOutcome,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sender: Option<Sender>,
}

/// A `measure`: the measurement ordered, where it starts and ends, and who
/// asked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Measure {
    #[serde(flatten)]
    pub outcome: MeasureOutcome,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sender: Option<Sender>,
}

/// A `standby`: the process that follows the loop, and what it replaces.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Standby {
    pub pid: i32,
    /// It was a warm spare (no process started).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warm: Option<bool>,
    /// After a swap of the controller: the new design's scenario, and the
    /// generations of the old standbys it retires.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenario: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replaces: Option<Vec<u32>>,
}

/// A `spare`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Spare {
    pub pid: i32,
}

/// A `stop`: who asked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stop {
    pub by: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sender: Option<Sender>,
}

/// Reads `events.jsonl`'s text: its complete lines, each as an event. A
/// line being written (no end yet) is left for the next read; a line that
/// is not an event is an error naming it.
pub fn parse_events(text: &str) -> Result<Vec<SupervisorEvent>, EventLineError> {
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    complete
        .lines()
        .enumerate()
        .filter(|(_, line)| !line.trim().is_empty())
        .map(|(i, line)| {
            serde_json::from_str(line).map_err(|e| EventLineError {
                line: i + 1,
                reason: e.to_string(),
            })
        })
        .collect()
}

/// A line of `events.jsonl` that is not an event.
#[derive(Debug, Clone, PartialEq)]
pub struct EventLineError {
    /// From 1.
    pub line: usize,
    pub reason: String,
}

impl std::fmt::Display for EventLineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.reason)
    }
}

impl std::error::Error for EventLineError {}

#[cfg(test)]
mod tests {
    use super::*;

    fn switch() -> SwitchRecord {
        SwitchRecord {
            role: "controller".into(),
            generation: 2,
            start_seq: 10,
            from_seq: 20,
            du_switch: 0.5,
            du_before: 0.25,
            du_after: f64::NAN,
            warm: true,
        }
    }

    #[test]
    fn a_line_keeps_its_shape_kind_and_detail_beside_the_common_fields() {
        let event = SupervisorEvent {
            t_s: 1.5,
            role: "controller".into(),
            generation: Some(2),
            seq: Some(20),
            kind: EventKind::Crash(Crash {
                exit: Some(137),
                found: "exit report".into(),
                cause: Some("crashed".into()),
                restart_in_ms: Some(0),
                ..Crash::default()
            }),
        };
        let line = serde_json::to_string(&event).unwrap();
        let value: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(value["kind"], "crash");
        assert_eq!(value["detail"]["exit"], 137);
        assert_eq!(value["detail"]["restart_in_ms"], 0);
        assert!(value["detail"].get("fatal").is_none(), "{line}");
        assert!(value["detail"].get("spare").is_none(), "{line}");
        assert_eq!(parse_events(&format!("{line}\n")).unwrap(), vec![event]);
    }

    #[test]
    fn every_kind_reads_back_as_written() {
        let kinds = [
            EventKind::Silent(Silent {
                pid: 7,
                ticks_without_output: 30,
                stopped: true,
                action: "killed".into(),
                ..Silent::default()
            }),
            EventKind::Restart(Restart {
                switch: Some(switch()),
                rolled_back_from: Some("own.toml".into()),
                scenario: Some("default.toml".into()),
                ..Restart::default()
            }),
            EventKind::RestartFailed("no luck".into()),
            EventKind::PromoteStandby(switch()),
            EventKind::Swap(Swap {
                scenario: "b.toml".into(),
                switch: switch(),
                sender: Some(Sender {
                    pid: Some(42),
                    uid: 1000,
                }),
            }),
            EventKind::Set(Set {
                outcome: SetOutcome {
                    fields: Vec::new(),
                    file: None,
                    switches: vec![switch()],
                    check_s: 0.5,
                    handover_s: 0.25,
                },
                sender: None,
            }),
            EventKind::Standby(Standby {
                pid: 8,
                replaces: Some(vec![1]),
                ..Standby::default()
            }),
            EventKind::StandbyFailed("no".into()),
            EventKind::Spare(Spare { pid: 9 }),
            EventKind::SpareFailed("no".into()),
            EventKind::Stop(Stop {
                by: "flexloop down".into(),
                sender: None,
            }),
        ];
        for kind in kinds {
            let event = SupervisorEvent {
                t_s: 0.25,
                role: "observer".into(),
                generation: None,
                seq: None,
                kind,
            };
            let line = serde_json::to_string(&event).unwrap();
            let value: serde_json::Value = serde_json::from_str(&line).unwrap();
            assert_eq!(value["kind"], event.kind.name(), "{line}");
            let back: SupervisorEvent = serde_json::from_str(&line).unwrap();
            // NaN is not equal to itself: compare the lines again.
            assert_eq!(serde_json::to_string(&back).unwrap(), line);
        }
    }

    #[test]
    fn a_restart_s_switch_sits_in_its_detail_as_a_promotion_s_does() {
        let restart = EventKind::Restart(Restart {
            switch: Some(switch()),
            ..Restart::default()
        });
        let value = serde_json::to_value(&restart).unwrap();
        assert_eq!(value["detail"]["from_seq"], 20, "{value}");
        let promotion = serde_json::to_value(EventKind::PromoteStandby(switch())).unwrap();
        assert_eq!(promotion["detail"]["from_seq"], 20, "{promotion}");
        let logger: EventKind = serde_json::from_str(
            r#"{"kind":"restart","detail":{"files":["samples.g1.mcap","latency.g1.hlog"]}}"#,
        )
        .unwrap();
        assert_eq!(
            logger,
            EventKind::Restart(Restart {
                files: Some(vec!["samples.g1.mcap".into(), "latency.g1.hlog".into()]),
                ..Restart::default()
            })
        );
    }

    #[test]
    fn a_line_being_written_waits_and_a_foreign_line_is_named() {
        let whole = r#"{"t_s":0.1,"kind":"spare","role":"observer","generation":null,"seq":null,"detail":{"pid":3}}"#;
        let text = format!("{whole}\n{}", &whole[..20]);
        assert_eq!(parse_events(&text).unwrap().len(), 1);
        let err = parse_events(&format!("{whole}\n{{\"kind\":\"lunch\"}}\n")).unwrap_err();
        assert_eq!(err.line, 2);
    }
}
