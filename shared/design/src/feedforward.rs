//! The feedforward: gains on the reference's derivatives per input, and
//! Appendix A's modified feedforward that runs them through the loop's own
//! observer and controller.

use crate::reference::Derivatives;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::modified_feedforward::modified_feedforward;
use flexloop_control::observer_block::ObserverBlock;
use flexloop_scenario::schema::FeedforwardSection;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::{DMatrix, DVector};

/// The feedforward a model gets when the file gives no gains.
pub enum FeedforwardPlan {
    /// Gains on the profile's derivatives, for the model's single input.
    Siso(Derivatives),
    /// The model's inverse to second order, u0 = Γ Υ d r̈ − Γ Υ T Γ Υ d r⁗
    /// (d: the reference direction; T: the static compliance of every
    /// flexible mode): exact for the decoupled rigid body, and the snap term
    /// takes out the deflection the acceleration causes (the thesis' snap
    /// gain −m² T for one input).
    RigidBody {
        /// Γ Υ (n_u × n_y).
        inverse: DMatrix<f64>,
        /// Γ Υ T Γ Υ (n_u × n_y).
        compliance: DMatrix<f64>,
    },
}

/// u0,i = gains_i · derivatives of r, one entry per input: the file's four
/// gains (one input only), or the model's `plan` along `reference_direction`.
pub fn feedforward_gains(
    s: &Scenario,
    plan: &FeedforwardPlan,
    n_inputs: usize,
    reference_direction: &[f64],
) -> Result<Vec<Derivatives>, ScenarioError> {
    Ok(match (s.controller.feedforward, plan) {
        (Some(_), _) if n_inputs != 1 => {
            return Err(ScenarioError::new(
                &s.source,
                Some("controller.feedforward"),
                format!(
                    "the four-gain feedforward is for one input; `{}` has {n_inputs} \
                     and gets the rigid-body feedforward Γ Υ d r̈",
                    s.plant.model
                ),
            ));
        }
        (
            Some(FeedforwardSection {
                snap,
                jerk,
                acc,
                vel,
            }),
            _,
        ) => vec![[0.0, vel, acc, jerk, snap]],
        (None, FeedforwardPlan::Siso(gains)) => vec![*gains],
        (
            None,
            FeedforwardPlan::RigidBody {
                inverse,
                compliance,
            },
        ) => {
            let d = DVector::from_column_slice(reference_direction);
            let (acc, snap) = (inverse * &d, compliance * &d);
            acc.iter()
                .zip(snap.iter())
                .map(|(a, s)| [0.0, 0.0, *a, 0.0, -*s])
                .collect()
        }
    })
}

/// `controller.feedforward_form`: plain (None, u_ff = u0) or Appendix A's
/// modified feedforward through `observer` and `controller`.
pub fn feedforward_form(
    s: &Scenario,
    observer: &ObserverBlock,
    controller: &DiscreteStateSpace,
    loop_delay_samples: u32,
) -> Result<Option<DiscreteStateSpace>, ScenarioError> {
    let err =
        |reason: String| ScenarioError::new(&s.source, Some("controller.feedforward_form"), reason);
    match s.controller.feedforward_form.as_str() {
        "plain" => Ok(None),
        "modified" => modified_feedforward(observer, controller, loop_delay_samples as usize)
            .map(Some)
            .map_err(|e| err(format!("modified feedforward: {e}"))),
        other => Err(err(format!(
            "unknown form `{other}` (expected plain or modified)"
        ))),
    }
}
