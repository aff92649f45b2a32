//! Table 4.1 of the thesis (docs/control.md §1.4, §7, §9): the scan run with the
//! world-fixed sensor at each of 29 positions along the chain, rms of e_true
//! over the scan window per position, and min / mean / max over them.
//!
//! # The feed-forward error
//! The thesis injects one fixed "feedforward error" signal (ideal minus
//! applied feedforward, Fig. 4.9, about ±30 N) at every position, precisely
//! so that a position-dependent feedforward error does not mask what the
//! observers do; the waveform and the "ideal" feedforward it starts from
//! are not given. In a linear loop e_true = G_p (P_p⁻¹ r − u_ff), with G_p
//! the loop from u_ff to e_true at position p, so the thesis measures
//! G_p (P_5⁻¹ r − u_ff,5): the error of the feedforward tuned at y5.
//!
//! Below the first resonance P_p(s) ≈ 1/(m s²) + T(p), T(p) the static
//! compliance of the flexible modes at the sensor, so P_p⁻¹ ≈ m s² − m² T(p)
//! s⁴: the ideal feedforwards at p and at y5 differ, to leading order, by
//! −m² (T(p) − T(5)) r⁗ (this predicts the fitted snap gain at y5,
//! 1.67·10⁻⁶, from T(5) alone). [`FeedforwardChoice::ComplianceShifted`], the
//! default, therefore runs every position with the scenario's fitted gains
//! and the snap gain shifted by that amount: each position then sees, to
//! leading order, y5's feed-forward error, as in the thesis. The higher
//! terms (s⁶ and up: the resonances and anti-resonances) are not shifted,
//! and near the actuator mass the shifted snap steps ring mode 1 strongly;
//! only active damping removes that.
//!
//! Two alternatives are offered for comparison. [`FeedforwardChoice::AsTuned`]
//! keeps the y5 gains everywhere ("the feedforward tuned for one position"):
//! its error then includes the compliance mismatch, a low-frequency error
//! of up to ~190 nm that no observer application reduces, which is what the
//! thesis set out to avoid. [`FeedforwardChoice::MassOnly`] (u_ff = m r̈)
//! leaves the whole flexible part, ~370 nm at every position.
//!
//! Runs go through [`InProcessLoop`], the processes' cores in lockstep, so
//! each rms is bit-identical to `flexloop run --mode lockstep` of the
//! scenario with the sensor (and the feedforward) at that position.

use crate::metrics::{ControlMetrics, MetricsOptions};
use crate::trace::RunTrace;
use flexloop_components::InProcessLoop;
use flexloop_control::modal::ModelError;
use flexloop_control::models;
use flexloop_design::LoopDesign;
use flexloop_scenario::schema::{FeedforwardSection, SENSOR_POSITION_MAX};
use flexloop_scenario::{Scenario, ScenarioError};
use serde::Serialize;
use std::fmt;

/// Which feedforward every position runs with (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeedforwardChoice {
    /// The scenario's own gains (fitted at its output): the thesis' reading.
    AsTuned,
    /// u_ff = m r̈ with the chain's 12.5 kg (snap, jerk, vel = 0).
    MassOnly,
    /// The scenario's gains with the snap gain moved by the difference in
    /// static compliance, so that the feed-forward error at every position
    /// is, to leading order, the one at the scenario's own output (module
    /// doc). The default.
    ComplianceShifted,
}

impl FeedforwardChoice {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::AsTuned => "as-tuned",
            Self::MassOnly => "mass-only",
            Self::ComplianceShifted => "compliance-shifted",
        }
    }

    pub fn parse(text: &str) -> Option<Self> {
        match text {
            "as-tuned" => Some(Self::AsTuned),
            "mass-only" => Some(Self::MassOnly),
            "compliance-shifted" => Some(Self::ComplianceShifted),
            _ => None,
        }
    }
}

/// Why a position could not be run.
#[derive(Debug, Clone, PartialEq)]
pub enum PositionError {
    /// The scenario at this position does not design (unstable, bad field).
    Design { position: f64, error: ScenarioError },
    /// The in-process loop refused the design.
    Loop { position: f64, reason: String },
    /// The scenario's reference has no complete scan window in its duration.
    NoScan(String),
}

impl fmt::Display for PositionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Design { position, error } => {
                write!(f, "sensor position {position}: {error}")
            }
            Self::Loop { position, reason } => {
                write!(f, "sensor position {position}: in-process loop: {reason}")
            }
            Self::NoScan(file) => write!(
                f,
                "scenario {file}: field `reference.shape`: a position scan needs a scan \
                 that ends within loop.duration_s"
            ),
        }
    }
}

impl std::error::Error for PositionError {}

/// Table 4.1 of the thesis, rms(e_true) [nm] min / mean / max over 29
/// positions (docs/control.md §9), by the shipped scenario that runs each case.
/// The original loop has no redesigned feedback (the thesis repeats it).
pub const THESIS_TABLE_4_1: [(&str, [f64; 3]); 7] = [
    ("thesis-original", [9.3667, 14.4019, 26.3194]),
    ("thesis-mc", [10.1388, 16.8212, 27.862]),
    ("thesis-ad", [3.3719, 4.5046, 5.7045]),
    ("thesis-mc-ad", [2.9148, 4.3243, 5.6566]),
    ("thesis-mc-redesigned", [9.75, 16.4307, 27.7159]),
    ("thesis-ad-redesigned", [1.4313, 1.8152, 3.0211]),
    ("thesis-mc-ad-redesigned", [1.4351, 1.6847, 2.1225]),
];

/// The thesis' min / mean / max [nm] for a shipped scenario name.
pub fn thesis_table_4_1(scenario: &str) -> Option<[f64; 3]> {
    THESIS_TABLE_4_1
        .iter()
        .find(|(name, _)| *name == scenario)
        .map(|(_, v)| *v)
}

/// 0, 1/per_span, …, 7: positions in node units (0 = ma … 7 = m7). Four
/// per span gives the thesis' 29 (7·4 + 1; docs/control.md §1.4).
pub fn sensor_positions(per_span: usize) -> Vec<f64> {
    let per_span = per_span.max(1);
    let n = SENSOR_POSITION_MAX as usize * per_span;
    // Exact quotients, so that integer positions are exactly the nodes.
    (0..=n).map(|i| i as f64 / per_span as f64).collect()
}

/// One position of a scan.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PositionRms {
    pub position: f64,
    /// rms of e_true over the scan window(s) [m].
    pub rms_e_true: f64,
}

/// One case (scenario) over all positions.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PositionScan {
    pub scenario: String,
    pub feedforward: FeedforwardChoice,
    pub runs: Vec<PositionRms>,
    pub min: f64,
    pub mean: f64,
    pub max: f64,
}

impl PositionScan {
    pub fn new(scenario: String, feedforward: FeedforwardChoice, runs: Vec<PositionRms>) -> Self {
        let rms = runs.iter().map(|r| r.rms_e_true);
        let min = rms.clone().fold(f64::INFINITY, f64::min);
        let max = rms.clone().fold(f64::NEG_INFINITY, f64::max);
        let mean = rms.sum::<f64>() / runs.len().max(1) as f64;
        Self {
            scenario,
            feedforward,
            runs,
            min,
            mean,
            max,
        }
    }

    /// max − min: how much the position matters.
    pub fn spread(&self) -> f64 {
        self.max - self.min
    }
}

/// Static compliance of all flexible modes of the chain seen by a sensor at
/// `position` (node units): T(p) = Σ φ_s,i(p) φ_a,i / ω_i², so that
/// P_p(s) ≈ 1/(m s²) + T(p) well below the first resonance.
pub fn chain_compliance(position: f64) -> Result<f64, ModelError> {
    let modal = models::thesis_chain_modal()?.with_sensor_positions(&[position])?;
    let flexible: Vec<usize> = (modal.n_rigid..modal.modes()).collect();
    Ok(modal.compliance(&flexible)?[(0, 0)])
}

/// The scenario with its sensor at `position` and the chosen feedforward.
pub fn scenario_at(
    base: &Scenario,
    position: f64,
    feedforward: FeedforwardChoice,
) -> Result<Scenario, ScenarioError> {
    let mut s = base.clone();
    s.set_sensor_position(position);
    let err = |e: ModelError| {
        ScenarioError::new(&base.source, Some("plant.sensor_position"), e.to_string())
    };
    match feedforward {
        FeedforwardChoice::AsTuned => {}
        FeedforwardChoice::MassOnly => {
            s.controller.feedforward = Some(FeedforwardSection {
                acc: models::CHAIN_MASS,
                ..FeedforwardSection::default()
            });
        }
        FeedforwardChoice::ComplianceShifted => {
            // P_p⁻¹ ≈ m s² − m² T(p) s⁴: the ideal feedforward at p differs
            // from the one at the scenario's own sensor by −m² ΔT r⁗, so the
            // tuned gains with that shift leave the same error at p as at home.
            let m = models::CHAIN_MASS;
            let shift = -m
                * m
                * (chain_compliance(position).map_err(err)?
                    - chain_compliance(base.plant.sensor_node()).map_err(err)?);
            let mut ff = s.controller.feedforward.unwrap_or(FeedforwardSection {
                acc: m,
                ..FeedforwardSection::default()
            });
            ff.snap += shift;
            s.controller.feedforward = Some(ff);
        }
    }
    s.validate()?;
    Ok(s)
}

/// rms of e_true over the scan window(s) of `s`, run in-process only as far
/// as the last window ends (later ticks cannot change it: the loop is causal).
pub fn scan_rms(s: &Scenario) -> Result<f64, PositionError> {
    let position = s.plant.sensor_node();
    let design =
        LoopDesign::from_scenario(s).map_err(|error| PositionError::Design { position, error })?;
    let windows = design.reference.scan_windows(s.timing.duration_s);
    let no_scan = || PositionError::NoScan(s.source.display().to_string());
    let end = windows.iter().map(|w| w.1).fold(f64::NAN, f64::max);
    if windows.is_empty() || !end.is_finite() {
        return Err(no_scan());
    }
    let ticks = ((end / design.ts).ceil() as u64 + 2).min(s.ticks().unwrap_or(u64::MAX));
    let mut run = InProcessLoop::new(&design).map_err(|e| PositionError::Loop {
        position,
        reason: e.to_string(),
    })?;
    let trace = RunTrace::simulate(&mut run, design.ts, ticks);
    ControlMetrics::compute(&trace, &windows, &MetricsOptions::default())
        .rms_e_true_scan
        .ok_or_else(no_scan)
}

/// Runs `base` with the sensor at each of `positions` (Table 4.1, one row).
pub fn position_scan(
    base: &Scenario,
    positions: &[f64],
    feedforward: FeedforwardChoice,
) -> Result<PositionScan, PositionError> {
    let runs = positions
        .iter()
        .map(|&position| {
            let s = scenario_at(base, position, feedforward)
                .map_err(|error| PositionError::Design { position, error })?;
            scan_rms(&s).map(|rms_e_true| PositionRms {
                position,
                rms_e_true,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(PositionScan::new(base.name.clone(), feedforward, runs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn twenty_nine_positions_hit_every_node_exactly() {
        let p = sensor_positions(4);
        assert_eq!(p.len(), 29);
        assert_eq!(p[0], 0.0);
        assert_eq!(p[1], 0.25);
        assert_eq!(p[20], 5.0);
        assert_eq!(p[28], 7.0);
        assert_eq!(
            sensor_positions(1),
            [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
        );
    }

    #[test]
    fn summary_statistics() {
        let runs = [3.0, 1.0, 2.0].map(|r| PositionRms {
            position: 0.0,
            rms_e_true: r,
        });
        let s = PositionScan::new("t".into(), FeedforwardChoice::AsTuned, runs.to_vec());
        assert_eq!((s.min, s.mean, s.max, s.spread()), (1.0, 2.0, 3.0, 2.0));
        assert_eq!(
            FeedforwardChoice::parse("mass-only"),
            Some(FeedforwardChoice::MassOnly)
        );
        assert_eq!(FeedforwardChoice::parse("x"), None);
    }
}
