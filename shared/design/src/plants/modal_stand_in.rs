//! The stand-ins for the models whose data the thesis leaves incomplete:
//! `mimo-example`, `oat-like`, `two-inertia` and `uniform-chain`.

use super::Parts;
use super::modal_parts::{ModalPlant, RigidBodyPlan, modal_damping, modal_parts};
use flexloop_control::discretise::zoh;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::modal::{ModalModel, ModelError, ReducedModel};
use flexloop_control::models;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::{DMatrix, DVector};

/// The stand-ins for the models whose data the thesis leaves incomplete
/// (docs/control.md §1.5, §1.7, §1.8; `models` documents what is invented): the
/// full modal model under exact ZOH for the plant, a Kalman observer on its
/// reduced model (T_DC of the discarded modes), and one PID per
/// rigid-body-decoupled axis (docs/control.md (4.12)); the feedforward inverts
/// the rigid body and the static compliance of the flexible modes.
pub fn parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let model_err =
        |e: ModelError| ScenarioError::new(&s.source, Some("plant.model"), e.to_string());
    let (full, output_names, default_keep) = match s.plant.model.as_str() {
        "mimo-example" => (
            models::mimo_example().map_err(model_err)?,
            vec![
                "y1 (x = -0.25 m)".to_string(),
                "y2 (x = +0.25 m)".to_string(),
            ],
            2,
        ),
        "oat-like" => {
            let encoders = s.plant.oat_encoders();
            let picked = [encoders[0] - 1, encoders[1] - 1, encoders[2] - 1];
            let corner = ["-x -y", "+x -y", "+x +y", "-x +y"];
            (
                models::oat_like(picked).map_err(|e| {
                    ScenarioError::new(&s.source, Some("plant.encoders"), e.to_string())
                })?,
                picked
                    .iter()
                    .map(|&e| format!("encoder {} ({})", e + 1, corner[e]))
                    .collect(),
                models::OAT_FREQ_HZ.len(),
            )
        }
        "uniform-chain" => {
            let nodes = s.plant.nodes.unwrap_or_default();
            let mut nodal = models::uniform_chain(nodes)
                .map_err(|e| ScenarioError::new(&s.source, Some("plant.nodes"), e.to_string()))?;
            if let Some(zeta) = &s.plant.zeta {
                nodal.damping = modal_damping(zeta);
            }
            let sensor = models::uniform_chain_sensor(nodes);
            (
                ModalModel::from_nodal(&nodal).map_err(|e| {
                    ScenarioError::new(&s.source, Some("plant.zeta"), e.to_string())
                })?,
                vec![format!("node {sensor} of 0..{}", nodes - 1)],
                nodes - 1,
            )
        }
        _ => {
            let output = s.plant.two_inertia_output();
            let both = ModalModel::from_nodal(&models::two_inertia()).map_err(model_err)?;
            let name = if output == 1 {
                "θ1 (load)"
            } else {
                "θ2 (motor)"
            };
            (
                both.select_outputs(&[output - 1]).map_err(model_err)?,
                vec![name.to_string()],
                1,
            )
        }
    };
    modal_parts(
        s,
        ts,
        extra_delay,
        ModalPlant {
            full,
            output_names,
            default_keep,
            rigid_body: RigidBodyPlan::Decoupled,
        },
        |reduced| stand_in_weights(s, reduced, ts),
    )
}

/// Kalman weights of the stand-ins (None: the thesis' σ_w, σ_v, σ_d).
/// OAT (docs/control.md §4.4): Q = 10⁻⁴ I on the inputs, R = 10⁻¹⁸ I. Two-inertia
/// (§1.7, Table 3.8's setup): the continuous Q = diag(0.1, 0.1, 1, 1) on the
/// physical state [θ1, θ2, θ̇1, θ̇2] and R = 5·10⁻⁵, brought to the modal
/// state by η = Φᵀ M q and to per-sample weights as the thesis' are
/// (G = T Ts, see the kalman module's note on units).
fn stand_in_weights(
    s: &Scenario,
    reduced: &ReducedModel,
    ts: f64,
) -> Result<Option<KalmanWeights>, ScenarioError> {
    let (n_y, n_u) = (reduced.modal.outputs(), reduced.modal.inputs());
    match s.plant.model.as_str() {
        "oat-like" => {
            let base = zoh(&reduced.state_space(), ts).map_err(|e| {
                ScenarioError::new(&s.source, Some("observer"), format!("ZOH: {e}"))
            })?;
            Ok(Some(KalmanWeights {
                g: base.b.clone(),
                q: DMatrix::identity(n_u, n_u) * 1e-4,
                r: DMatrix::identity(n_y, n_y) * 1e-18,
            }))
        }
        "two-inertia" => {
            let nodal = models::two_inertia();
            let shapes = ModalModel::from_nodal(&nodal)
                .ok()
                .and_then(|m| m.shapes)
                .ok_or_else(|| {
                    ScenarioError::new(&s.source, Some("plant.model"), "no mode shapes")
                })?;
            let to_modal = shapes.transpose() * &nodal.mass;
            let (modes, nodes) = to_modal.shape();
            let n = 2 * modes;
            if reduced.modal.modes() != modes || 2 * nodes != 4 {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("observer.flexible_modes"),
                    "the two-inertia weights are for the full model (1 rigid + 1 flexible mode)",
                ));
            }
            let mut g = DMatrix::zeros(n, 2 * nodes);
            for i in 0..modes {
                for j in 0..nodes {
                    g[(2 * i, j)] = to_modal[(i, j)] * ts;
                    g[(2 * i + 1, nodes + j)] = to_modal[(i, j)] * ts;
                }
            }
            Ok(Some(KalmanWeights {
                g,
                q: DMatrix::from_diagonal(&DVector::from_column_slice(&[0.1, 0.1, 1.0, 1.0])),
                r: DMatrix::identity(n_y, n_y) * 5e-5,
            }))
        }
        _ => Ok(None),
    }
}
