//! What the supervisor writes while the loop runs: `processes.json`, and
//! the swap and set requests and answers under `requests/` (its events are
//! [`crate::events`]).

use serde::{Deserialize, Serialize};

/// `processes.json`: the loop's live processes and their duties.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Processes {
    pub processes: Vec<ProcessEntry>,
    /// Set once the loop is over though its supervisor could not say so
    /// (it died): why, and who finished the run. No process is listed then.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProcessEntry {
    pub role: String,
    pub pid: i32,
    /// `active`, `standby` or `spare`.
    pub duty: String,
    pub generation: Option<u32>,
    pub scenario: String,
}

/// What one swap or restart did, as the events, `bench.json` and the swap
/// answer record it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwitchRecord {
    pub role: String,
    pub generation: u32,
    /// The loop's sample when the replacement was started.
    pub start_seq: u64,
    /// The first sample the new instance's command acts on.
    pub from_seq: u64,
    /// |u(from) − u(from−1)|, the largest over the inputs (NaN: unknown).
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub du_switch: f64,
    /// The largest ordinary |u(k) − u(k−1)| before and after the switch.
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub du_before: f64,
    #[serde(deserialize_with = "crate::json::f64_or_nan")]
    pub du_after: f64,
    /// Served by a warm spare (no process started or stopped).
    pub warm: bool,
}

/// A `flexloop swap` request (`requests/*.request`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapRequest {
    pub role: String,
    pub scenario: String,
}

/// The supervisor's answer to a [`SwapRequest`] (`requests/*.answer`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapAnswer {
    pub ok: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub switch: Option<SwitchRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl SwapAnswer {
    /// The swap was done.
    pub fn done(switch: SwitchRecord) -> Self {
        Self {
            ok: true,
            switch: Some(switch),
            error: None,
        }
    }

    /// The swap was refused or failed, and why.
    pub fn refused(error: String) -> Self {
        Self {
            ok: false,
            switch: None,
            error: Some(error),
        }
    }
}

/// A `flexloop set` request (`requests/*.set`): tunables and their new
/// values as TOML text (`controller.bandwidth_hz`, `60`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetRequest {
    pub changes: Vec<FieldValue>,
}

/// `flexloop measure --running` (`requests/*.measure`): the `[measure]`
/// fields (scenarios/README.md) but its start, which the supervisor sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasureRequest {
    pub fields: Vec<FieldValue>,
}

/// A measurement ordered on a running loop: its `[measure]` table as the
/// supervisor checked it (its `start_s` the sample `start_seq`'s time), and
/// the samples it spans, fade-out included.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasureOutcome {
    /// The `[measure]` table, TOML.
    pub table: String,
    pub start_seq: u64,
    pub end_seq: u64,
}

/// The supervisor's answer to a [`MeasureRequest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasureAnswer {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outcome: Option<MeasureOutcome>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// A dotted field and a value in TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldValue {
    pub field: String,
    pub value: String,
}

/// One field a set changed: its value before and after, in TOML (`unset`
/// for an optional field that was not given).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldChange {
    pub field: String,
    pub old: String,
    pub new: String,
}

/// What a set did: the fields, the scenario file written for it, and the
/// swaps that handed the loop over (none when nothing changed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetOutcome {
    pub fields: Vec<FieldChange>,
    /// The changed scenario (`tuned/NNN.toml`); None when nothing changed.
    pub file: Option<String>,
    pub switches: Vec<SwitchRecord>,
    /// Seconds the supervisor took to design and check the changed loop,
    /// and then to hand the loop over (the last switch passed).
    #[serde(default)]
    pub check_s: f64,
    #[serde(default)]
    pub handover_s: f64,
}

/// The supervisor's answer to a [`SetRequest`] (`requests/*.answer`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetAnswer {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outcome: Option<SetOutcome>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_step_reads_back_as_nan() {
        let record = SwitchRecord {
            role: "controller".into(),
            generation: 1,
            start_seq: 10,
            from_seq: 20,
            du_switch: f64::NAN,
            du_before: 0.5,
            du_after: 0.25,
            warm: false,
        };
        let text = serde_json::to_string(&record).unwrap();
        assert!(text.contains("\"du_switch\":null"), "{text}");
        let back: SwitchRecord = serde_json::from_str(&text).unwrap();
        assert!(back.du_switch.is_nan() && back.du_before == 0.5);
    }
}
