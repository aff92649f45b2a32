//! `metrics.json`: `flexloop run`'s control metrics beside its timing, and
//! whether they are the design's.

use crate::latency::Histogram;
use crate::summary::Counters;
use serde::{Deserialize, Serialize};

/// The file. The control metrics and the modal damping are the analysis
/// crate's types when written; a reader that does not need them typed
/// reads them as JSON values (the defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsFile<Control = serde_json::Value, Damping = serde_json::Value> {
    pub scenario: String,
    pub outputs: Vec<String>,
    pub output_unit: String,
    pub input_unit: String,
    pub mode: String,
    pub rate_hz: f64,
    pub loop_delay_samples: u32,
    /// Whether the control figures are the design's: false when ticks they
    /// rest on held the input, applied the safe action, ran without the
    /// observer or are missing from the log, or when stalls dominated the
    /// run (`flexloop_analysis::verdict`).
    pub valid: bool,
    /// Why they are not (empty when valid).
    pub invalid_reasons: Vec<String>,
    pub control: Control,
    pub modal_damping: Vec<Damping>,
    pub timing: MetricsTiming,
    pub incomplete_ticks: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsTiming {
    pub counters: Counters,
    pub round_trip: Histogram,
    pub tick_to_command: Histogram,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_invalid_run_reads_back_with_its_reasons_and_untyped_figures() {
        let written = MetricsFile {
            scenario: "default".into(),
            outputs: vec!["y5".into()],
            output_unit: "m".into(),
            input_unit: "N".into(),
            mode: "realtime".into(),
            rate_hz: 10_000.0,
            loop_delay_samples: 1,
            valid: false,
            invalid_reasons: vec!["3 of 1300 ticks the figures rest on held the input".into()],
            control: serde_json::json!({"rms_e_true_scan": 1.2e-7}),
            modal_damping: vec![],
            timing: MetricsTiming {
                counters: Counters::default(),
                round_trip: Histogram::default(),
                tick_to_command: Histogram::default(),
            },
            incomplete_ticks: 0,
        };
        let text = serde_json::to_string(&written).unwrap();
        assert!(text.contains("\"valid\":false"), "{text}");
        let back: MetricsFile = serde_json::from_str(&text).unwrap();
        assert_eq!(back, written);
    }
}
