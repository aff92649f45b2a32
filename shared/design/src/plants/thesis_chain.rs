//! The thesis chain (docs/control.md §1.3, §10.1), its one sensor on a mass or
//! anywhere between.

use super::Parts;
use super::modal_parts::modal_damping;
use crate::feedback::FeedbackPlan;
use crate::feedforward::FeedforwardPlan;
use crate::observer::flexible_modes_kept;
use crate::observer_choice::modal_observer;
use flexloop_control::discretise::zoh;
use flexloop_control::modal::{ModalDamping, ModalModel, ModelError};
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
    let f_hz = modal.frequencies_hz();
    let flexible_modes = (modal.n_rigid..modal.modes())
        .map(|i| (f_hz[i], modal.zeta[i]))
        .collect();
    let mass = chain_mass(s);
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
        design_file_plant: None,
        plant_u: plant,
        continuous_plant: modal.state_space(),
        plant_g_new: None,
        observer,
        output_prediction,
        feedforward: FeedforwardPlan::Siso([0.0, 0.0, mass, 0.0, 0.0]),
        feedback: FeedbackPlan::Mass(mass),
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

/// The chain's total mass: the rigid body the PID and the feedforward act
/// on (Table 3.2's 12.5 kg unless `plant.masses_kg` says otherwise).
pub fn chain_mass(s: &Scenario) -> f64 {
    match &s.plant.masses_kg {
        Some(masses) => masses.iter().sum(),
        None => models::CHAIN_MASS,
    }
}

/// The chain with the scenario's parameters (Table 3.2 and ζ = 0.005 where
/// it gives none: then exactly [`models::thesis_chain_modal`]): the force on
/// `plant.actuator_node`, outputs y1..y7 on m1..m7.
pub fn chain_modal(s: &Scenario) -> Result<ModalModel, ScenarioError> {
    let p = &s.plant;
    let defaults = [&p.masses_kg, &p.stiffness_n_per_m]
        .iter()
        .all(|v| v.is_none())
        && p.actuator_node.is_none()
        && p.zeta.is_none();
    let field = if p.zeta.is_some() {
        "plant.zeta"
    } else {
        "plant"
    };
    let err = |e: ModelError| ScenarioError::new(&s.source, Some(field), e.to_string());
    if defaults {
        return models::thesis_chain_modal().map_err(err);
    }
    let nodal = models::thesis_chain();
    let masses = p
        .masses_kg
        .clone()
        .unwrap_or_else(|| nodal.mass.diagonal().iter().copied().collect());
    let springs = p.stiffness_n_per_m.clone().unwrap_or_else(|| {
        let mut k = vec![models::CHAIN_K; 7];
        k[0] = models::CHAIN_KA;
        k
    });
    let damping = p
        .zeta
        .as_ref()
        .map_or(ModalDamping::Uniform(models::CHAIN_ZETA), modal_damping);
    let sensors: Vec<usize> = (1..=7).collect();
    let chain = models::chain(
        &masses,
        &springs,
        damping,
        &[p.actuator_node.unwrap_or(0)],
        &sensors,
    )
    .map_err(err)?;
    ModalModel::from_nodal(&chain).map_err(err)
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
        Some(p) => chain_modal(s)?.with_sensor_positions(&[p]).map_err(err),
        None => chain_modal(s)?
            .select_outputs(&[s.plant.output - 1])
            .map_err(err),
    }
}
