//! The observer a scenario asks for on a modal model: the steady-state
//! Kalman predictor of the reduced model ([`crate::observer`]), the
//! input–output observer on the same reduced model ([`crate::io_observer`]),
//! or no observer at all.

use crate::observer::{
    ObserverParts, OutputPrediction, empty_observer, kalman_options, scenario_weights,
};
use flexloop_control::closed_loop::discrete_modes;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::modal::ReducedModel;
use flexloop_control::observer_block::design_modal_observer;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// The observer of a modal model with `n_y` outputs and `n_u` inputs:
/// `kalman` on the reduced model (and Kalman weights, None for the thesis')
/// that `reduced` builds, with MC, AD and the noise model as the scenario
/// says, or `none`.
pub fn modal_observer(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    n_y: usize,
    n_u: usize,
    reduced: impl FnOnce() -> Result<(ReducedModel, Option<KalmanWeights>), ScenarioError>,
) -> Result<ObserverParts, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let o = &s.observer;
    // A program serving an `io` observer has its own correction: the
    // estimate's layout is the reduced model's states, the Kalman
    // observer's (the `io` observer with the observer-based K is that one).
    let design = match o.design.as_str() {
        "io" if o.exec.is_some() => "kalman",
        other => other,
    };
    match design {
        "kalman" => {
            let (reduced, model_weights) = reduced()?;
            let weights =
                scenario_weights(s, &reduced, ts, model_weights.as_ref())?.or(model_weights);
            let options = kalman_options(s, ts, extra_delay, &reduced, weights)?;
            let designed = design_modal_observer(&reduced, &options)
                .map_err(|e| err("observer", format!("Kalman observer: {e}")))?;
            let model = &designed.design.model;
            let modes = discrete_modes(&(&model.a - &designed.design.gain * &model.c), ts)
                .unwrap_or_default();
            let prediction = OutputPrediction {
                c: model.c.clone(),
                d: model.d.clone(),
            };
            Ok((designed.block, prediction, modes))
        }
        "io" => {
            let (reduced, model_weights) = reduced()?;
            crate::io_observer::io_observer(s, ts, extra_delay, &reduced, model_weights)
        }
        "none" => {
            if o.mc || o.ad {
                return Err(err(
                    "observer.design",
                    "MC and AD need an observer: use design = \"kalman\" or \"io\"".into(),
                ));
            }
            Ok((
                empty_observer(ts, n_y, n_u, extra_delay)
                    .map_err(|e| err("observer", format!("observer block: {e}")))?,
                OutputPrediction {
                    c: DMatrix::zeros(n_y, 0),
                    d: DMatrix::zeros(n_y, n_u),
                },
                Vec::new(),
            ))
        }
        other => Err(err(
            "observer.design",
            format!(
                "unknown design `{other}` for `{}` (expected kalman, io or none)",
                s.plant.model
            ),
        )),
    }
}
