//! The observer a scenario asks for on a modal model: the steady-state
//! Kalman predictor of the reduced model with MC, AD and the noise model as
//! the file says, or no observer at all.

use flexloop_control::closed_loop::discrete_modes;
use flexloop_control::damping::DampingMethod;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::lti::{DiscreteStateSpace, StateSpaceError};
use flexloop_control::modal::ReducedModel;
use flexloop_control::observer_block::{
    DampingOptions, ModalObserverOptions, ObserverBlock, design_modal_observer,
};
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// How the observer's own output prediction is formed, for the innovation
/// y(k) − C_o x̂(k|k−1) − D_o u_a(k) that the observer reports.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputPrediction {
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
}

/// `observer.flexible_modes`, or the model's `default`, checked against the
/// `available` flexible modes of the plant.
pub fn flexible_modes_kept(
    s: &Scenario,
    default: usize,
    available: usize,
) -> Result<usize, ScenarioError> {
    let keep = s.observer.flexible_modes.unwrap_or(default);
    if keep > available {
        return Err(ScenarioError::new(
            &s.source,
            Some("observer.flexible_modes"),
            format!(
                "the plant `{}` has {available} flexible mode{}; the observer cannot keep {keep}",
                s.plant.model,
                if available == 1 { "" } else { "s" }
            ),
        ));
    }
    Ok(keep)
}

/// An observer block, its output prediction and its error poles (Hz, ζ).
pub type ObserverParts = (ObserverBlock, OutputPrediction, Vec<(f64, f64)>);

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
    match o.design.as_str() {
        "kalman" => {
            let (reduced, weights) = reduced()?;
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
        "none" => {
            if o.mc || o.ad {
                return Err(err(
                    "observer.design",
                    "MC and AD need an observer: use design = \"kalman\"".into(),
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
                "unknown design `{other}` for `{}` (expected kalman or none)",
                s.plant.model
            ),
        )),
    }
}

/// The options of the scenario's Kalman observer on `reduced`.
pub fn kalman_options(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    reduced: &ReducedModel,
    weights: Option<KalmanWeights>,
) -> Result<ModalObserverOptions, ScenarioError> {
    let o = &s.observer;
    let (n_y, n_u) = (reduced.modal.outputs(), reduced.modal.inputs());
    let q_nu = match o.q_nu {
        Some(0.0) => None,
        Some(q) => Some(q),
        None => Some(if o.ad { 1e3 } else { 0.03 }),
    };
    // The noise model adds one integrator per input; the sensors must see
    // them all (docs/control.md §4.2: dim ν ≤ n_sens).
    if o.mc && q_nu.is_some() && n_u > n_y {
        return Err(ScenarioError::new(
            &s.source,
            Some("observer.q_nu"),
            format!(
                "a noise model on {n_u} inputs is not observable from {n_y} sensors; set q_nu = 0"
            ),
        ));
    }
    let modal = &reduced.modal;
    let increase: Vec<f64> = (modal.n_rigid..modal.modes())
        .map(|i| match o.damping_target {
            Some(target) => (target - modal.zeta[i]).max(0.0),
            None => o.damping_increase,
        })
        .collect();
    Ok(ModalObserverOptions {
        ts,
        mc: o.mc,
        damping: o.ad.then(|| DampingOptions {
            increase,
            method: DampingMethod::Automated,
            bandpass_q: (o.bandpass_q > 0.0).then_some(o.bandpass_q),
        }),
        q_nu,
        weights,
        extra_delay_samples: extra_delay,
    })
}

/// A block without states whose outputs are zero: the loop without an observer.
pub fn empty_observer(
    ts: f64,
    n_y: usize,
    n_u: usize,
    extra_delay: usize,
) -> Result<ObserverBlock, StateSpaceError> {
    let inputs = n_y + n_u * (1 + extra_delay);
    Ok(ObserverBlock {
        system: DiscreteStateSpace::new(
            DMatrix::zeros(0, 0),
            DMatrix::zeros(0, inputs),
            DMatrix::zeros(n_y + n_u, 0),
            DMatrix::zeros(n_y + n_u, inputs),
            ts,
        )?,
        estimate_map: DMatrix::zeros(0, 0),
        n_y,
        n_u,
        extra_delay_samples: extra_delay,
    })
}
