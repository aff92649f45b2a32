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
use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::discretise::{zoh, zoh_split};
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::observer_block::ObserverBlock;
use flexloop_scenario::schema::MODELS;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// The parts every model branch produces.
pub struct Parts {
    /// Inputs u (the commands), outputs the true y: the exact ZOH of
    /// `continuous_plant`, or with a command deadline its two-piece
    /// integration in the delayed-input form ([`model_parts`]).
    pub plant_u: DiscreteStateSpace,
    /// With `plant.design_file`: the model the observer and the controller
    /// are designed on, sampled as `plant_u` is ([`Parts::design_plant`]).
    pub design_file_plant: Option<DiscreteStateSpace>,
    /// The plant in continuous time, what `plant_u` samples.
    pub continuous_plant: ContinuousStateSpace,
    /// With a command deadline: G_new of the plant's two-piece sample
    /// (`plant_u` runs z = x − G_new u_a); None otherwise.
    pub plant_g_new: Option<DMatrix<f64>>,
    pub observer: ObserverBlock,
    pub output_prediction: OutputPrediction,
    pub feedforward: FeedforwardPlan,
    pub feedback: FeedbackPlan,
    pub output_names: Vec<String>,
    pub flexible_modes: Vec<(f64, f64)>,
    pub observer_modes: Vec<(f64, f64)>,
}

/// The parts of the model `plant.model` names; with `plant.design_file`,
/// the observer, the feedback and the feedforward designed on that file's
/// model instead, around the plant `plant.model` names (the loop that
/// runs: docs/control.md §14).
pub fn model_parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let emulated = sampled_parts(s, ts, extra_delay)?;
    let Some(design_scenario) = design_model_scenario(s) else {
        return Ok(emulated);
    };
    // The same inputs and outputs first: a model of another shape fails
    // its own design for reasons that would not say so.
    let ours = &emulated.plant_u;
    if let Some((inputs, outputs)) = file_shape(&design_scenario)
        && (inputs, outputs) != (ours.inputs(), ours.outputs())
    {
        return Err(ScenarioError::new(
            &s.source,
            Some("plant.design_file"),
            format!(
                "the design model has {inputs} input{} and {outputs} output{}; the plant `{}` \
                 has {} and {}",
                if inputs == 1 { "" } else { "s" },
                if outputs == 1 { "" } else { "s" },
                s.plant.model,
                ours.inputs(),
                ours.outputs()
            ),
        ));
    }
    let on_file = sampled_parts(&design_scenario, ts, extra_delay).map_err(|e| {
        // The design model's errors are about the design file.
        let field = match e.field.as_deref() {
            Some("plant.file") | Some("plant") | None => "plant.design_file".to_string(),
            Some(other) => other.to_string(),
        };
        ScenarioError::new(
            &s.source,
            Some(&field),
            format!("the design model: {}", e.reason),
        )
    })?;
    Ok(Parts {
        design_file_plant: Some(on_file.plant_u.clone()),
        plant_u: emulated.plant_u,
        continuous_plant: emulated.continuous_plant,
        plant_g_new: emulated.plant_g_new,
        output_names: emulated.output_names,
        flexible_modes: emulated.flexible_modes,
        ..on_file
    })
}

/// The scenario whose plant is `plant.design_file`'s `state-space` model,
/// for the design; None without one.
fn design_model_scenario(s: &Scenario) -> Option<Scenario> {
    let file = s.design_file_path()?;
    let mut design = s.clone();
    let p = &mut design.plant;
    p.model = "state-space".into();
    p.file = Some(file);
    p.design_file = None;
    p.arrays = None;
    p.output_given = false;
    p.masses_kg = None;
    p.stiffness_n_per_m = None;
    p.actuator_node = None;
    p.zeta = None;
    p.rayleigh = None;
    p.springs.clear();
    p.dampers.clear();
    p.forces.clear();
    p.positions.clear();
    p.nodes = None;
    p.encoders = None;
    p.sensor_position = None;
    Some(design)
}

/// The inputs and outputs of a `state-space` file's B and C, when it reads.
fn file_shape(s: &Scenario) -> Option<(usize, usize)> {
    use flexloop_modelfile::{ModelArrays, VectorAs};
    let arrays = ModelArrays::read(&s.plant_file_path()?).ok()?;
    let b = arrays.matrix("B", VectorAs::Column).ok()?;
    let c = arrays.matrix("C", VectorAs::Row).ok()?;
    Some((b.ncols(), c.nrows()))
}

/// The parts of `s`'s own plant, sampled as the loop samples it.
fn sampled_parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let mut parts = model_parts_one_sample(s, ts, extra_delay)?;
    if let Some(tau) = s.command_deadline_s() {
        // The observer reads the deadline from the scenario itself
        // (`observer::kalman_options`); the plant is sampled in two pieces.
        let sys = &parts.continuous_plant;
        let err = |e: flexloop_control::discretise::DiscretiseError| {
            ScenarioError::new(
                &s.source,
                Some("loop.command_deadline_us"),
                format!("two-piece sampling: {e}"),
            )
        };
        let split = zoh_split(sys, ts, tau).map_err(err)?;
        parts.plant_u = split.delayed_input_form(&sys.c, &sys.d, ts).map_err(err)?;
        parts.plant_g_new = Some(split.g_new);
    }
    Ok(parts)
}

impl Parts {
    /// The plant the observer and the controller are designed on.
    pub fn design_plant(&self) -> &DiscreteStateSpace {
        self.design_file_plant.as_ref().unwrap_or(&self.plant_u)
    }
}

fn model_parts_one_sample(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
) -> Result<Parts, ScenarioError> {
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
/// w is a force held over whole samples (its B is the plain ZOH's); with a
/// command deadline u acts through the delayed-input form, whose output
/// depends on the input present at the tick (D = C G_new).
pub fn with_input_disturbance(
    s: &Scenario,
    parts: &Parts,
    ts: f64,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let plant_u = &parts.plant_u;
    let b_u = &plant_u.b;
    let mut b_plant = DMatrix::zeros(b_u.nrows(), 2 * b_u.ncols());
    b_plant.columns_mut(0, b_u.ncols()).copy_from(b_u);
    let mut d_plant = DMatrix::zeros(plant_u.outputs(), 2 * b_u.ncols());
    if s.command_deadline_s().is_some() {
        let plain = zoh(&parts.continuous_plant, ts)
            .map_err(|e| ScenarioError::new(&s.source, Some("plant"), format!("ZOH: {e}")))?;
        b_plant
            .columns_mut(b_u.ncols(), b_u.ncols())
            .copy_from(&plain.b);
        d_plant.columns_mut(0, b_u.ncols()).copy_from(&plant_u.d);
    } else {
        b_plant.columns_mut(b_u.ncols(), b_u.ncols()).copy_from(b_u);
    }
    DiscreteStateSpace::new(plant_u.a.clone(), b_plant, plant_u.c.clone(), d_plant, ts)
        .map_err(|e| ScenarioError::new(&s.source, Some("plant"), format!("plant model: {e}")))
}
