//! What the JSON channels carry: `/latency` from the logger's telemetry,
//! `/events` from the run's `events.jsonl`, `/scenario` as it stands.

use crate::counts::Counts;
use crate::error::LiveError;
use crate::gate::GateCounts;
use crate::tuning::Tuner;
use flexloop_protocol::Telemetry;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_runtime::latency::QUANTILE_LABELS;
use flexloop_transport::{Inlet, LoopNode};
use std::io::{Read, Seek, SeekFrom};
use std::path::PathBuf;
use std::sync::Arc;

/// `/latency`: each of the logger's telemetry messages (once a second), with
/// the server's counts.
pub struct LatencyFeed {
    inlet: Inlet<Telemetry>,
    previous: Option<Telemetry>,
}

impl LatencyFeed {
    pub fn open(node: &LoopNode) -> Result<Self, LiveError> {
        Ok(Self {
            inlet: Inlet::open_polling(node, &TELEMETRY, TELEMETRY.qos.loop_buffer_size)?,
            previous: None,
        })
    }

    pub fn poll(
        &mut self,
        counts: &Counts,
        clients: usize,
        gate: &GateCounts,
    ) -> Result<Option<serde_json::Value>, LiveError> {
        let mut newest = None;
        while let Some(t) = self.inlet.receive()? {
            newest = Some(*t);
        }
        let Some(t) = newest else {
            return Ok(None);
        };
        let rate_hz = self
            .previous
            .filter(|p| t.published_ns > p.published_ns && t.samples >= p.samples)
            .map(|p| {
                (t.samples - p.samples) as f64 / ((t.published_ns - p.published_ns) as f64 / 1e9)
            });
        self.previous = Some(t);
        let percentiles = |v: [u64; 6]| {
            QUANTILE_LABELS
                .iter()
                .zip(v)
                .map(|(label, ns)| ((*label).to_string(), serde_json::json!(ns as f64 / 1e3)))
                .collect::<serde_json::Map<_, _>>()
        };
        Ok(Some(serde_json::json!({
            "seq": t.seq,
            "rate_hz": rate_hz,
            "samples": t.samples,
            "misses": t.misses,
            "late_commands": t.late_commands,
            "stalled_ticks": t.stalled_ticks,
            "stall_misses": t.stall_misses,
            "stale_estimates": t.stale_estimates,
            "log_gaps": t.gaps,
            "round_trip_us": percentiles(t.round_trip),
            "tick_lateness_us": percentiles(t.tick_lateness),
            "live": {
                "clients": clients,
                "connections": gate.connected(),
                "refused_connections": gate.refused(),
                "sent": counts.sent(),
                "lost_by_reader": {
                    "measurement": counts.lost[0],
                    "estimate": counts.lost[1],
                    "command": counts.lost[2],
                },
            },
        })))
    }
}

/// New complete lines of `events.jsonl` (the supervisor's events: swaps,
/// sets, crashes, restarts) since the last call.
pub struct EventsTail {
    path: PathBuf,
    offset: u64,
    partial: String,
}

impl EventsTail {
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            offset: 0,
            partial: String::new(),
        }
    }

    pub fn new_lines(&mut self) -> Vec<String> {
        let Ok(mut file) = std::fs::File::open(&self.path) else {
            return Vec::new();
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return Vec::new();
        }
        let mut text = String::new();
        let Ok(read) = file.read_to_string(&mut text) else {
            return Vec::new();
        };
        self.offset += read as u64;
        self.partial.push_str(&text);
        let mut lines = Vec::new();
        while let Some(end) = self.partial.find('\n') {
            let line: String = self.partial.drain(..=end).collect();
            let line = line.trim();
            if !line.is_empty() {
                lines.push(line.to_string());
            }
        }
        lines
    }
}

/// `/scenario`: the loop's scenario as it stands and the design it runs
/// (`design`: what closes the loop, in words, `"auto"`'s choice included),
/// sent again when it changes.
#[derive(Default)]
pub struct ScenarioWatch {
    last: Option<String>,
    /// The text the message was last made from: the design is made again
    /// only when it changes.
    last_text: Option<String>,
}

impl ScenarioWatch {
    pub fn current(&mut self, tuner: &Arc<dyn Tuner>) -> Option<String> {
        let (file, text) = tuner.scenario().ok()?;
        if self.last_text.as_deref() == Some(text.as_str())
            && let Some(last) = &self.last
        {
            return Some(last.clone());
        }
        let design: serde_json::Map<String, serde_json::Value> = match tuner.design(&file, &text) {
            Ok(parts) => parts
                .into_iter()
                .map(|(part, words)| (part, serde_json::Value::String(words)))
                .collect(),
            Err(e) => [("error".to_string(), serde_json::Value::String(e))]
                .into_iter()
                .collect(),
        };
        let json = serde_json::json!({"file": file, "toml": text, "design": design}).to_string();
        self.last = Some(json.clone());
        self.last_text = Some(text);
        Some(json)
    }

    /// The scenario, if it changed since the last call that saw it.
    pub fn changed(&mut self, tuner: &Arc<dyn Tuner>) -> Option<String> {
        let before = self.last.clone();
        let now = self.current(tuner)?;
        (before.is_some() && before.as_deref() != Some(now.as_str())).then_some(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_are_read_line_by_line_across_partial_writes() {
        let dir = std::env::temp_dir().join(format!("flexloop-live-events-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("events.jsonl");
        let mut tail = EventsTail::new(path.clone());
        assert!(tail.new_lines().is_empty());
        std::fs::write(&path, "{\"a\":1}\n{\"b\":").unwrap();
        assert_eq!(tail.new_lines(), ["{\"a\":1}"]);
        std::fs::write(&path, "{\"a\":1}\n{\"b\":2}\n").unwrap();
        assert_eq!(tail.new_lines(), ["{\"b\":2}"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
