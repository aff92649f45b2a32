//! What every modal model brings to the loop, whatever it came from: the
//! full model under exact ZOH for the plant emulator, the scenario's Kalman
//! observer on its reduced model (T_DC of the discarded modes), and the PID
//! and feedforward put on its rigid body.

use super::Parts;
use crate::feedback::FeedbackPlan;
use crate::feedforward::FeedforwardPlan;
use crate::observer::flexible_modes_kept;
use crate::observer_choice::modal_observer;
use flexloop_control::discretise::zoh;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::modal::{ModalDamping, ModalModel, ReducedModel};
use flexloop_scenario::schema::ModalZeta;
use flexloop_scenario::{Scenario, ScenarioError};

/// `plant.zeta` as the modal model's damping.
pub fn modal_damping(zeta: &ModalZeta) -> ModalDamping {
    match zeta {
        ModalZeta::Uniform(z) => ModalDamping::Uniform(*z),
        ModalZeta::PerMode(z) => ModalDamping::PerFlexibleMode(z.clone()),
    }
}

/// How the PID and the feedforward are put on the rigid body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RigidBodyPlan {
    /// One input, one output, one rigid mode: a PID on 1/(m s²) with m from
    /// the rigid mode (m = 1/(φ_s φ_a), the total mass for a free chain),
    /// and the four-gain feedforward with m on the acceleration, so that
    /// `[controller.feedforward]` and `fit-ff` work as on the thesis chain.
    Mass,
    /// One PID per rigid-body-decoupled axis and the rigid-body inverse as
    /// feedforward (docs/control.md (4.12)).
    Decoupled,
}

/// A modal model and what a scenario needs to know about it.
pub struct ModalPlant {
    pub full: ModalModel,
    pub output_names: Vec<String>,
    /// Flexible modes the observer keeps when `observer.flexible_modes`
    /// (or `max_mode_hz`) does not say.
    pub default_keep: usize,
    pub rigid_body: RigidBodyPlan,
}

/// The loop's parts for `plant`; `weights` gives the model's own Kalman
/// weights for its reduced model (None: the thesis').
pub fn modal_parts(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    plant: ModalPlant,
    weights: impl FnOnce(&ReducedModel) -> Result<Option<KalmanWeights>, ScenarioError>,
) -> Result<Parts, ScenarioError> {
    let ModalPlant {
        full,
        output_names,
        default_keep,
        rigid_body,
    } = plant;
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let (n_y, n_u) = (full.outputs(), full.inputs());
    let plant_u = zoh(&full.state_space(), ts).map_err(|e| err("plant", format!("ZOH: {e}")))?;
    let f_hz = full.frequencies_hz();
    let flexible_modes = (full.n_rigid..full.modes())
        .map(|i| (f_hz[i], full.zeta[i]))
        .collect();
    if full.n_rigid == 0 {
        return Err(err(
            "plant",
            "the model has no rigid-body mode: the PID and the feedforward are designed on \
             the rigid body (docs/own-plant.md)"
                .into(),
        ));
    }
    let (feedback, feedforward) = match rigid_body {
        RigidBodyPlan::Mass => {
            let gain = full.phi_s[(0, 0)] * full.phi_a[(0, 0)];
            if full.n_rigid != 1 || n_y != 1 || n_u != 1 || gain <= 0.0 {
                return Err(err(
                    "plant",
                    format!(
                        "a PID on one mass needs one input, one output and one rigid mode \
                         seen with a positive gain ({n_u} inputs, {n_y} outputs, {} rigid \
                         modes, gain {gain:e})",
                        full.n_rigid
                    ),
                ));
            }
            let mass = 1.0 / gain;
            (
                FeedbackPlan::Mass(mass),
                FeedforwardPlan::Siso([0.0, 0.0, mass, 0.0, 0.0]),
            )
        }
        RigidBodyPlan::Decoupled => {
            let (_, gamma, upsilon) = full
                .rigid_body_decoupled()
                .map_err(|e| err("plant", e.to_string()))?;
            let inverse = &gamma * &upsilon;
            let compliance = full
                .compliance(&(full.n_rigid..full.modes()).collect::<Vec<_>>())
                .map_err(|e| err("plant", e.to_string()))?;
            (
                FeedbackPlan::Decoupled { gamma, upsilon },
                FeedforwardPlan::RigidBody {
                    compliance: &inverse * &compliance * &inverse,
                    inverse,
                },
            )
        }
    };
    let n_flex = full.modes() - full.n_rigid;
    let (observer, output_prediction, observer_modes) =
        modal_observer(s, ts, extra_delay, n_y, n_u, || {
            let keep = flexible_modes_kept(s, default_keep, n_flex)?;
            let compensate: Vec<usize> = (full.n_rigid + keep..full.modes()).collect();
            let reduced = full
                .truncate(full.n_rigid + keep, &compensate)
                .map_err(|e| err("observer.flexible_modes", e.to_string()))?;
            let model_weights = weights(&reduced)?;
            Ok((reduced, model_weights))
        })?;
    Ok(Parts {
        design_file_plant: None,
        plant_u,
        continuous_plant: full.state_space(),
        plant_g_new: None,
        observer,
        output_prediction,
        feedforward,
        feedback,
        output_names,
        flexible_modes,
        observer_modes,
    })
}
