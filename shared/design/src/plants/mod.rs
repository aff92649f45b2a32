//! The plant models a scenario can name, and what each one brings: the
//! discrete plant, its observer, and how feedback and feedforward are put on
//! it.
//!
//! - [`double_integrator`]: the lecture's mass with state feedback.
//! - [`thesis_chain`]: the thesis' eight-mode chain, its sensor anywhere.
//! - [`modal_stand_in`]: the models whose data the thesis leaves incomplete.
//! - [`own`]: the plants a user brings (lumped networks, model files).
//! - [`modal_parts`]: what every modal model brings to the loop.

pub mod double_integrator;
pub mod modal_parts;
pub mod modal_stand_in;
pub mod own;
pub mod thesis_chain;

use crate::feedback::FeedbackPlan;
use crate::feedforward::FeedforwardPlan;
use crate::observer::OutputPrediction;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::observer_block::ObserverBlock;
use flexloop_scenario::schema::MODELS;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// The parts every model branch produces.
pub struct Parts {
    /// Inputs u (the commands), outputs the true y.
    pub plant_u: DiscreteStateSpace,
    pub observer: ObserverBlock,
    pub output_prediction: OutputPrediction,
    pub feedforward: FeedforwardPlan,
    pub feedback: FeedbackPlan,
    pub output_names: Vec<String>,
    pub flexible_modes: Vec<(f64, f64)>,
    pub observer_modes: Vec<(f64, f64)>,
}

/// The parts of the model `plant.model` names.
pub fn model_parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    match s.plant.model.as_str() {
        "double-integrator" => double_integrator::parts(s, ts, extra_delay),
        "thesis-chain" => thesis_chain::parts(s, ts, extra_delay),
        "mimo-example" | "oat-like" | "two-inertia" | "uniform-chain" => {
            modal_stand_in::parts(s, ts, extra_delay)
        }
        "lumped" | "second-order" | "state-space" => own::parts(s, ts, extra_delay),
        other => Err(ScenarioError::new(
            &s.source,
            Some("plant.model"),
            format!(
                "unknown model `{other}` (expected one of {})",
                MODELS.join(", ")
            ),
        )),
    }
}

/// `plant_u` with a force disturbance w on every input: inputs `[u; w]`.
pub fn with_input_disturbance(
    s: &Scenario,
    plant_u: &DiscreteStateSpace,
    ts: f64,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let b_u = &plant_u.b;
    let mut b_plant = DMatrix::zeros(b_u.nrows(), 2 * b_u.ncols());
    b_plant.columns_mut(0, b_u.ncols()).copy_from(b_u);
    b_plant.columns_mut(b_u.ncols(), b_u.ncols()).copy_from(b_u);
    let d_plant = DMatrix::zeros(plant_u.outputs(), 2 * b_u.ncols());
    DiscreteStateSpace::new(plant_u.a.clone(), b_plant, plant_u.c.clone(), d_plant, ts)
        .map_err(|e| ScenarioError::new(&s.source, Some("plant"), format!("plant model: {e}")))
}
