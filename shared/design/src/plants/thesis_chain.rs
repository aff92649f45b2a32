//! The thesis chain (docs/control.md §1.3, §10.1), its one sensor on a mass or
//! anywhere between.

use super::Parts;
use crate::feedback::FeedbackPlan;
use crate::feedforward::FeedforwardPlan;
use crate::observer::{flexible_modes_kept, modal_observer};
use flexloop_control::discretise::zoh;
use flexloop_control::modal::{ModalModel, ModelError};
use flexloop_control::models;
use flexloop_scenario::{Scenario, ScenarioError};

/// The thesis chain (docs/control.md §1.3, §10.1): the full 8-mode model under
/// exact ZOH for the plant; a steady-state Kalman predictor on the reduced
/// model (rigid + 3 flexible modes, T_DC of modes 4–6, mode 7 unknown) with
/// MC, AD and the noise model as the scenario says.
pub fn parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let modal = seen_by_sensor(s)?;
    let plant = zoh(&modal.state_space(), ts).map_err(|e| err("plant", format!("ZOH: {e}")))?;
    let flexible_modes = modal
        .frequencies_hz()
        .into_iter()
        .filter(|f| *f > 0.0)
        .map(|f| (f, models::CHAIN_ZETA))
        .collect();
    // Output position dependency only (docs/control.md §1.4): C_t and T_DC
    // follow the sensor, B_t does not, so the AD gain K (from φ_a) is the
    // same everywhere while the Kalman gain, which depends on C, is designed
    // for this position. Retained modes: rigid + 3 flexible by default, T_DC
    // of the discarded ones up to mode 6; mode 7 stays unknown.
    let (observer, output_prediction, observer_modes) =
        modal_observer(s, ts, extra_delay, 1, 1, || {
            let keep = flexible_modes_kept(s, 3, 7)?;
            let compensate: Vec<usize> = (1 + keep..7).collect();
            let reduced = modal
                .truncate(1 + keep, &compensate)
                .map_err(|e| err(sensor_field(s), e.to_string()))?;
            Ok((reduced, None))
        })?;
    let output_names = vec![match (s.plant.sensor_position, s.plant.sensor_scan) {
        (Some(p), _) => format!("sensor at {p}"),
        (_, Some([from, to])) => format!("sensor scanned {from} -> {to}"),
        _ => format!("y{}", s.plant.output),
    }];
    Ok(Parts {
        plant_u: plant,
        observer,
        output_prediction,
        feedforward: FeedforwardPlan::Siso([0.0, 0.0, models::CHAIN_MASS, 0.0, 0.0]),
        feedback: FeedbackPlan::Mass(models::CHAIN_MASS),
        output_names,
        flexible_modes,
        observer_modes,
    })
}

/// The field that places the thesis chain's sensor.
pub fn sensor_field(s: &Scenario) -> &'static str {
    if s.plant.sensor_scan.is_some() {
        "plant.sensor_scan"
    } else if s.plant.sensor_position.is_some() {
        "plant.sensor_position"
    } else {
        "plant.output"
    }
}

/// The full chain (8 modes) as its one sensor sees it: mass m_i for
/// `output = i` (exactly [`models::thesis_plant`]), or the world-fixed sensor
/// of `sensor_position` with mode-shape rows interpolated between nodes.
/// The observer's reduced model (rigid + 3 flexible, T_DC of modes 4–6, as
/// [`models::thesis_reduced`]) is truncated from it, so C_t and T_DC follow
/// the sensor too.
pub fn seen_by_sensor(s: &Scenario) -> Result<ModalModel, ScenarioError> {
    let field = sensor_field(s);
    let err = |e: ModelError| ScenarioError::new(&s.source, Some(field), e.to_string());
    // A scanned sensor: the design frozen where the scan starts.
    match s
        .plant
        .sensor_position
        .or(s.plant.sensor_scan.map(|[from, _]| from))
    {
        Some(p) => models::thesis_chain_modal()
            .and_then(|m| m.with_sensor_positions(&[p]))
            .map_err(err),
        None => models::thesis_plant(s.plant.output).map_err(err),
    }
}
