//! What every observer of a modal model is built from: the steady-state
//! Kalman predictor's weights and options (MC, AD and the noise model as the
//! file says), the output prediction, the modes kept, the empty observer.
//! Which observer a scenario asks for is [`crate::observer_choice`]'s.

use flexloop_control::damping::DampingMethod;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::lti::{DiscreteStateSpace, StateSpaceError};
use flexloop_control::modal::ReducedModel;
use flexloop_control::observer_block::{DampingOptions, ModalObserverOptions, ObserverBlock};
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

/// The Kalman weights the scenario sets (None: the model's own, the
/// thesis' σ_w, σ_v, σ_d unless the model brings others): the process noise
/// enters as the force does (G = B of the reduced model under ZOH, per
/// sample as the thesis' are, docs/control.md §4.1), Q = σ_w² I or the file's
/// `kalman_q`; R = σ² I or `kalman_r`. Each half defaults to the noise the
/// scenario gives the plant emulator, when it gives any, else to the
/// model's own weights (`model`, when they have that form) or the thesis'.
pub fn scenario_weights(
    s: &Scenario,
    reduced: &ReducedModel,
    ts: f64,
    model: Option<&KalmanWeights>,
) -> Result<Option<KalmanWeights>, ScenarioError> {
    let o = &s.observer;
    let p = &s.plant;
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let (n_y, n_u) = (reduced.modal.outputs(), reduced.modal.inputs());
    let square = |field: &str, rows: &Option<Vec<Vec<f64>>>, n: usize, what: &str| {
        let Some(rows) = rows else {
            return Ok(None);
        };
        let shape_ok = rows.len() == n && rows.iter().all(|r| r.len() == n);
        if !shape_ok {
            return Err(err(
                field,
                format!(
                    "must be {n}×{n} ({what}), got {} rows of lengths {:?}",
                    rows.len(),
                    rows.iter().map(Vec::len).collect::<Vec<_>>()
                ),
            ));
        }
        let m = DMatrix::from_fn(n, n, |i, j| rows[i][j]);
        if m.iter().any(|v| !v.is_finite()) {
            return Err(err(field, "holds a non-finite number".into()));
        }
        if (&m - m.transpose()).amax() > 1e-12 * m.amax() {
            return Err(err(field, "must be symmetric (a covariance)".into()));
        }
        // R must be positive definite (the filter inverts it), Q semi-definite.
        let definite = field == "observer.kalman_r";
        let eigen = m.clone().symmetric_eigenvalues();
        let tolerance = 1e-12 * m.amax();
        let bad = eigen
            .iter()
            .any(|&l| if definite { l <= 0.0 } else { l < -tolerance });
        if bad {
            return Err(err(
                field,
                format!(
                    "must be positive {}definite (a covariance), its eigenvalues are {:?}",
                    if definite { "" } else { "semi-" },
                    eigen.as_slice()
                ),
            ));
        }
        Ok(Some(m))
    };
    let q = match square("observer.kalman_q", &o.kalman_q, n_u, "one row per input")? {
        Some(q) => Some(q),
        None => o
            .process_noise
            .or((p.force_noise > 0.0).then_some(p.force_noise))
            .map(|sigma| DMatrix::identity(n_u, n_u) * (sigma * sigma)),
    };
    let r = match square("observer.kalman_r", &o.kalman_r, n_y, "one row per output")? {
        Some(r) => Some(r),
        None => match o.measurement_noise {
            Some(sigma) => Some(DMatrix::identity(n_y, n_y) * (sigma * sigma)),
            None => {
                let variance =
                    p.sensor_noise * p.sensor_noise + p.reference_noise * p.reference_noise;
                (variance > 0.0).then(|| DMatrix::identity(n_y, n_y) * variance)
            }
        },
    };
    if q.is_none() && r.is_none() {
        return Ok(None);
    }
    let base = flexloop_control::discretise::zoh(&reduced.state_space(), ts)
        .map_err(|e| err("observer", format!("ZOH: {e}")))?;
    // The half the scenario does not set keeps the model's value.
    let fallback = match model {
        Some(w) if w.g == base.b => w.clone(),
        _ => KalmanWeights::thesis(&base),
    };
    Ok(Some(KalmanWeights {
        g: base.b.clone(),
        q: q.unwrap_or(fallback.q),
        r: r.unwrap_or(fallback.r),
    }))
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
        command_deadline: s.command_deadline_s(),
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
        model: None,
        n_y,
        n_u,
        extra_delay_samples: extra_delay,
    })
}
