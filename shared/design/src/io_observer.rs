//! The input–output observer a scenario asks for (`observer.design = "io"`,
//! docs/control.md §12.2): the Kalman design's reduced model run on the
//! plant input and corrected by a filter K(z) of the innovation, compiled
//! into the same [`ObserverBlock`] form as the Kalman observer, so that the
//! observer process, MC, AD and live swaps treat it alike. The block's
//! estimate is the model's states first and K's states after.
//!
//! K(z) comes from the scenario (`correction = "observer-based"`: the Kalman
//! predictor gain as a static K correcting the state, E = I, which is the
//! Kalman predictor itself) or from arrays A_K, B_K, C_K, D_K in a file or
//! inline (innovation in, input correction out, E = B: the paper's form).

use crate::observer::{ObserverParts, OutputPrediction, kalman_options, scenario_weights};
use flexloop_control::closed_loop::discrete_modes;
use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::damping::ActiveDamping;
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::{tustin, zoh};
use flexloop_control::io_observer::IoObserver;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::modal::ReducedModel;
use flexloop_control::observer_block::design_modal_observer;
use flexloop_modelfile::{ModelArrays, ModelFileError, VectorAs};
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// The arrays a correction filter is made of.
const FILTER_ARRAYS: [&str; 5] = ["A_K", "B_K", "C_K", "D_K", "ts"];

/// The scenario's IO observer on `reduced` (with the model's own Kalman
/// weights `model_weights`, which only `observer-based` uses).
pub fn io_observer(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    reduced: &ReducedModel,
    model_weights: Option<KalmanWeights>,
) -> Result<ObserverParts, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let (io, compensation, damping, field) = if s.observer.correction.is_some() {
        // The Kalman design, with its noise model, MC and AD; its gain L is
        // the static K and enters the state (E = I).
        let weights = scenario_weights(s, reduced, ts, model_weights.as_ref())?.or(model_weights);
        let options = kalman_options(s, ts, extra_delay, reduced, weights)?;
        let designed = design_modal_observer(reduced, &options)
            .map_err(|e| err("observer", format!("Kalman gain of the correction: {e}")))?;
        let d = designed.design;
        let gain = DiscreteStateSpace::gain(d.gain.clone(), ts)
            .map_err(|e| err("observer.correction", e.to_string()))?;
        let io = IoObserver::state_correction(d.model, gain)
            .map_err(|e| err("observer.correction", e.to_string()))?;
        (io, d.compensation, d.feedback, "observer.correction")
    } else {
        let field = correction_field(s);
        let model =
            zoh(&reduced.state_space(), ts).map_err(|e| err("observer", format!("ZOH: {e}")))?;
        let filter = correction_filter(s, ts, model.outputs(), model.inputs())?;
        let io = IoObserver::input_correction(model, filter)
            .map_err(|e| err(field, io_refusal(s, e)))?;
        let n = io.model().states();
        let compensation = s.observer.mc.then(|| reduced.flexible_output_matrix());
        // AD as the Kalman observer's, on the model's states (no noise model).
        let options = kalman_options(s, ts, extra_delay, reduced, None)?;
        let damping = match options.damping {
            Some(d) => Some(
                ActiveDamping::design(&reduced.modal, &d.increase, d.method, d.bandpass_q)
                    .and_then(|ad| ad.to_discrete(n, ts))
                    .map_err(|e| err("observer.ad", e.to_string()))?,
            ),
            None => None,
        };
        (io, compensation, damping, field)
    };
    let block = io
        .compile(compensation.as_ref(), damping.as_ref(), extra_delay)
        .map_err(|e| err(field, format!("observer block: {e}")))?;
    let (model, _) = io
        .predictor()
        .map_err(|e| err(field, format!("observer block: {e}")))?;
    let modes = discrete_modes(&io.error_dynamics(), ts).unwrap_or_default();
    let prediction = OutputPrediction {
        c: model.c,
        d: model.d,
    };
    Ok((block, prediction, modes))
}

/// The field that names where K's arrays came from.
fn correction_field(s: &Scenario) -> &'static str {
    if s.observer.correction_file.is_some() {
        "observer.correction_file"
    } else {
        "observer.correction_arrays"
    }
}

/// Why [`IoObserver::input_correction`] refused K, in the scenario's words.
fn io_refusal(s: &Scenario, e: DesignError) -> String {
    let source = correction_source(s);
    match e {
        DesignError::Unstable(why) => format!(
            "{source}: the estimation-error loop of the model and K(z) is unstable ({why}); \
             K must stabilise the reduced model the observer runs on (docs/control.md §12.2)"
        ),
        other => format!("{source}: {other}"),
    }
}

/// The file or table K comes from, for messages.
fn correction_source(s: &Scenario) -> String {
    match s.correction_file_path() {
        Some(path) => path.display().to_string(),
        None => "[observer.correction_arrays]".into(),
    }
}

/// K(z) from `observer.correction_file` or `[observer.correction_arrays]`:
/// n_y innovations in, n_u input corrections out, at the loop's period.
/// D_K is required; A_K, B_K, C_K come together or not at all (a static K).
/// A `ts` must be the loop's period; without it the filter is continuous and
/// is discretised by Tustin, which keeps a stable K stable.
pub fn correction_filter(
    s: &Scenario,
    ts: f64,
    n_y: usize,
    n_u: usize,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let field = correction_field(s);
    let err = |reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let file_err = |e: ModelFileError| err(e.to_string());
    let arrays = match (s.correction_file_path(), &s.observer.correction_arrays) {
        (Some(path), _) => ModelArrays::read(&path).map_err(file_err)?,
        (None, Some(table)) => {
            ModelArrays::from_toml(&s.source, "observer.correction_arrays", table)
                .map_err(file_err)?
        }
        (None, None) => {
            return Err(err("an `io` observer reads K(z) from correction_file or \
                 [observer.correction_arrays]"
                .into()));
        }
    };
    let source = arrays.source().to_string();
    if let Some(reason) = arrays.not_taken(&FILTER_ARRAYS, "a correction filter") {
        return Err(err(reason));
    }
    let d = arrays.matrix("D_K", VectorAs::Row).map_err(file_err)?;
    let dynamic = ["A_K", "B_K", "C_K"].map(|n| arrays.names().contains(&n));
    let (a, b, c) = match dynamic {
        [true, true, true] => (
            arrays.matrix("A_K", VectorAs::Column).map_err(file_err)?,
            arrays.matrix("B_K", VectorAs::Column).map_err(file_err)?,
            arrays.matrix("C_K", VectorAs::Row).map_err(file_err)?,
        ),
        [false, false, false] => (
            DMatrix::zeros(0, 0),
            DMatrix::zeros(0, n_y),
            DMatrix::zeros(n_u, 0),
        ),
        _ => {
            return Err(err(format!(
                "{source}: A_K, B_K and C_K come together (a dynamic K) or not at all (a \
                 static K = D_K)"
            )));
        }
    };
    let nk = a.nrows();
    for (name, got, want) in [
        ("A_K", a.shape(), (nk, nk)),
        ("B_K", b.shape(), (nk, n_y)),
        ("C_K", c.shape(), (n_u, nk)),
        ("D_K", d.shape(), (n_u, n_y)),
    ] {
        if got != want {
            return Err(err(format!(
                "{source}: array `{name}` is {}×{}, K(z) with {nk} states maps the {n_y} \
                 innovations to the plant's {n_u} inputs and needs {}×{}",
                got.0, got.1, want.0, want.1
            )));
        }
    }
    let filter = match arrays.scalar("ts").map_err(file_err)? {
        Some(file_ts) => {
            if (file_ts - ts).abs() > 1e-9 * ts {
                return Err(err(format!(
                    "{source}: array `ts`: K(z) is discrete at {file_ts} s, the loop runs at \
                     {ts} s; a discrete filter is only exact at its own rate"
                )));
            }
            DiscreteStateSpace::new(a, b, c, d, ts).map_err(|e| err(format!("{source}: {e}")))?
        }
        None => {
            let continuous =
                ContinuousStateSpace::new(a, b, c, d).map_err(|e| err(format!("{source}: {e}")))?;
            tustin(&continuous, ts, None).map_err(|e| err(format!("{source}: Tustin: {e}")))?
        }
    };
    if nk > 0 {
        let radius = flexloop_control::linalg::spectral_radius(&filter.a)
            .map_err(|e| err(format!("{source}: {e}")))?;
        if radius >= 1.0 {
            return Err(err(format!(
                "{source}: K(z) is unstable (spectral radius of A_K {radius} at the loop's \
                 period): the observer would run it open-loop on noise"
            )));
        }
    }
    Ok(filter)
}
