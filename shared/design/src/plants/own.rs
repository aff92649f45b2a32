//! The plants a user brings (docs/own-plant.md): a lumped mass–spring–damper
//! network written in the scenario, a second-order model M, K, D, B, C or a
//! first-order state space A, B, C, D from a file (.npz, .mat) or inline,
//! each brought to the real modal form the plant emulator and the observer
//! run on (flexloop-control's `second_order`, `real_modal_form`).

use super::Parts;
use super::modal_parts::{ModalPlant, RigidBodyPlan, modal_damping, modal_parts};
use flexloop_control::lumped_network::{Attach, Element, lumped_network};
use flexloop_control::modal::{ModalDamping, ModalModel};
use flexloop_control::plant_model_error::{PlantModelError, PlantModelReason};
use flexloop_control::real_modal_form::modal_from_state_space;
use flexloop_control::second_order::modal_from_second_order;
use flexloop_control::zoh_inverse::continuous_from_zoh;
use flexloop_modelfile::{ModelArrays, VectorAs};
use flexloop_scenario::schema::{Attachment, Rayleigh};
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

/// The share of the sample rate up to which the observer keeps a user's
/// flexible modes by default (`observer.max_mode_hz`): a mode at 0.15 f_s
/// turns 54° per sample, about the most a one-sample-ahead predictor still
/// estimates usefully; above it, the static compliance (T_DC) is what is
/// worth compensating. Chosen so that the thesis' own split falls out of it:
/// at 10 kHz the chain keeps 470, 942 and 1396 Hz and compensates 1805 Hz
/// and up (docs/control.md §1.3; the thesis leaves its mode 7 "unknown", a
/// user's model compensates every discarded mode).
pub const DEFAULT_MAX_MODE_SHARE: f64 = 0.15;

/// The parts of `lumped`, `second-order` and `state-space` plants.
pub fn parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let (full, output_names) = own_modal_model(s, ts)?;
    let max_mode_hz = s
        .observer
        .max_mode_hz
        .unwrap_or(DEFAULT_MAX_MODE_SHARE * s.timing.rate_hz);
    let f_hz = full.frequencies_hz();
    let default_keep = (full.n_rigid..full.modes())
        .filter(|&i| f_hz[i] <= max_mode_hz)
        .count();
    let one_axis = full.inputs() == 1 && full.outputs() == 1 && full.n_rigid == 1;
    modal_parts(
        s,
        ts,
        extra_delay,
        ModalPlant {
            full,
            output_names,
            default_keep,
            rigid_body: if one_axis {
                RigidBodyPlan::Mass
            } else {
                RigidBodyPlan::Decoupled
            },
        },
        |_| Ok(None),
    )
}

/// The scenario's own plant in modal form, and the names of its outputs.
pub fn own_modal_model(s: &Scenario, ts: f64) -> Result<(ModalModel, Vec<String>), ScenarioError> {
    match s.plant.model.as_str() {
        "lumped" => lumped(s),
        "second-order" => second_order(s),
        _ => state_space(s, ts),
    }
}

fn attach(a: Attachment) -> Attach {
    match a {
        Attachment::At(i) => Attach::At(i),
        Attachment::Between(i, j) => Attach::Between(i, j),
    }
}

fn element(a: Attachment, value: f64) -> Element {
    match a {
        Attachment::At(i) => (i, None, value),
        Attachment::Between(i, j) => (i, Some(j), value),
    }
}

fn rayleigh(r: Rayleigh) -> ModalDamping {
    ModalDamping::Rayleigh {
        alpha: r.alpha,
        beta: r.beta,
    }
}

/// The modal damping `plant.zeta` or `plant.rayleigh` gives, if any.
fn scenario_damping(s: &Scenario) -> Option<ModalDamping> {
    s.plant
        .zeta
        .as_ref()
        .map(modal_damping)
        .or(s.plant.rayleigh.map(rayleigh))
}

/// The scenario field a lumped network's error is about.
fn lumped_field(e: &PlantModelError) -> &'static str {
    match e.array {
        "masses" => "plant.masses_kg",
        "springs" => "plant.springs",
        "dampers" => "plant.dampers",
        "forces" => "plant.forces",
        "positions" => "plant.positions",
        _ => "plant",
    }
}

fn lumped(s: &Scenario) -> Result<(ModalModel, Vec<String>), ScenarioError> {
    let p = &s.plant;
    let err =
        |e: PlantModelError| ScenarioError::new(&s.source, Some(lumped_field(&e)), e.to_string());
    let springs: Vec<Element> = p
        .springs
        .iter()
        .map(|k| element(k.attachment, k.stiffness))
        .collect();
    let dampers: Vec<Element> = p
        .dampers
        .iter()
        .map(|d| element(d.attachment, d.damping))
        .collect();
    let forces: Vec<Attach> = p.forces.iter().copied().map(attach).collect();
    let positions: Vec<Attach> = p.positions.iter().copied().map(attach).collect();
    let masses = p.masses_kg.clone().unwrap_or_default();
    let network = lumped_network(&masses, &springs, &dampers, &forces, &positions).map_err(err)?;
    let damping = if network.d.is_some() {
        None
    } else {
        scenario_damping(s)
    };
    let modal = modal_from_second_order(
        &network.m,
        &network.k,
        network.d.as_ref(),
        &network.b,
        &network.c,
        damping,
    )
    .and_then(checked_rigid_modes)
    .map_err(|e| {
        let field = if p.dampers.is_empty() {
            if p.zeta.is_some() {
                "plant.zeta"
            } else {
                "plant.rayleigh"
            }
        } else {
            "plant.dampers"
        };
        let field = match e.array {
            "masses" | "M" => "plant.masses_kg",
            "springs" | "K" => "plant.springs",
            "B" => "plant.forces",
            "C" => "plant.positions",
            _ => field,
        };
        ScenarioError::new(&s.source, Some(field), e.to_string())
    })?;
    let names = p
        .positions
        .iter()
        .map(|a| match a {
            Attachment::At(i) => format!("q{i}"),
            Attachment::Between(i, j) => format!("q{j} - q{i}"),
        })
        .collect();
    Ok((modal, names))
}

/// A second-order model's rigid-body modes must be moved by the forces (B)
/// and seen by the outputs (C), as the state space's are
/// (`real_modal_form`): the PID and the feedforward act on the rigid body.
/// A force pair or a relative position alone leaves it free or unseen.
fn checked_rigid_modes(modal: ModalModel) -> Result<ModalModel, PlantModelError> {
    let r = modal.n_rigid;
    let full_rank = |m: nalgebra::DMatrix<f64>, scale: f64| {
        let floor = 1e-8 * scale;
        m.svd(false, false)
            .singular_values
            .iter()
            .filter(|&&v| v > floor)
            .count()
            == r
    };
    let reach = modal.phi_a.rows(0, r).into_owned();
    if r > 0 && !full_rank(reach, modal.phi_a.amax()) {
        return Err(PlantModelError {
            array: "B",
            reason: PlantModelReason::UncontrollableRigidMode,
        });
    }
    let seen = modal.phi_s.columns(0, r).into_owned();
    if r > 0 && !full_rank(seen, modal.phi_s.amax()) {
        return Err(PlantModelError {
            array: "C",
            reason: PlantModelReason::UnobservableRigidMode,
        });
    }
    Ok(modal)
}

/// The model's arrays: `plant.file` or `[plant.arrays]`.
fn arrays(s: &Scenario) -> Result<ModelArrays, ScenarioError> {
    match (s.plant_file_path(), &s.plant.arrays) {
        (Some(path), _) => ModelArrays::read(&path)
            .map_err(|e| ScenarioError::new(&s.source, Some("plant.file"), e.to_string())),
        (None, Some(table)) => ModelArrays::from_toml(&s.source, "plant.arrays", table)
            .map_err(|e| ScenarioError::new(&s.source, Some("plant.arrays"), e.to_string())),
        (None, None) => Err(ScenarioError::new(
            &s.source,
            Some("plant.file"),
            format!(
                "`{}` reads its arrays from plant.file or [plant.arrays]",
                s.plant.model
            ),
        )),
    }
}

/// The field that names where the arrays came from.
fn arrays_field(s: &Scenario) -> &'static str {
    if s.plant.file.is_some() {
        "plant.file"
    } else {
        "plant.arrays"
    }
}

/// Refuses arrays the model does not take: an array that does not act is an
/// error, as a field that does not apply is.
fn refuse_unused(s: &Scenario, arrays: &ModelArrays, used: &[&str]) -> Result<(), ScenarioError> {
    match arrays.not_taken(used, &format!("a `{}` model", s.plant.model)) {
        None => Ok(()),
        Some(reason) => Err(ScenarioError::new(&s.source, Some(arrays_field(s)), reason)),
    }
}

/// A conversion error, prefixed with where the arrays came from.
fn model_error(s: &Scenario, arrays: &ModelArrays, e: PlantModelError) -> ScenarioError {
    ScenarioError::new(
        &s.source,
        Some(arrays_field(s)),
        format!("{}: {e}", arrays.source()),
    )
}

/// The most degrees of freedom of a second-order model (`M`, `K`, `D`):
/// each is two states, and the loop carries at most
/// [`MAX_STATES`](flexloop_protocol::MAX_STATES), as a lumped network's 64
/// masses (`plant.masses_kg`) and the uniform chain's 64 nodes are.
pub const MAX_DEGREES_OF_FREEDOM: usize = flexloop_protocol::MAX_STATES / 2;

// The model file's own bound on every array (checked as the file is read,
// before anything is inflated) is the loop's.
const _: () =
    assert!(flexloop_modelfile::limits::MAX_DIMENSION as usize == flexloop_protocol::MAX_STATES);

/// The model's size against what the loop carries, from the arrays' shapes
/// before anything is designed (a large model's eigen-decomposition and
/// Kalman design take minutes and memory, then fail on the loop's size):
/// each of `sizes` (an array, and the degrees of freedom or states its
/// shape gives) at most what the loop carries, the inputs (B's columns) and
/// outputs (C's rows) too.
fn check_model_size(
    s: &Scenario,
    arrays: &ModelArrays,
    sizes: &[(&str, &DMatrix<f64>, usize)],
    (b, c): (&DMatrix<f64>, &DMatrix<f64>),
    second_order: bool,
) -> Result<(), ScenarioError> {
    use flexloop_protocol::{MAX_INPUTS, MAX_OUTPUTS, MAX_STATES};
    let refuse = |name: &str, m: &DMatrix<f64>, why: String| {
        Err(ScenarioError::new(
            &s.source,
            Some(arrays_field(s)),
            format!(
                "{}: array `{name}` is {}×{}: {why}",
                arrays.source(),
                m.nrows(),
                m.ncols()
            ),
        ))
    };
    let max = if second_order {
        MAX_DEGREES_OF_FREEDOM
    } else {
        MAX_STATES
    };
    for &(name, m, n) in sizes {
        if n > max {
            let why = if second_order {
                format!(
                    "a model of {n} degrees of freedom ({} states); the loop carries at most \
                     {MAX_STATES} states, a second-order model of at most {max} degrees of \
                     freedom: reduce it first (keep the modes you need, or condense the nodes \
                     that are neither actuated nor measured)",
                    2 * n
                )
            } else {
                format!(
                    "a model of {n} states; the loop carries at most {MAX_STATES}: reduce it \
                     first (e.g. modal or balanced truncation)"
                )
            };
            return refuse(name, m, why);
        }
    }
    if b.ncols() > MAX_INPUTS {
        let why = format!(
            "{} inputs (columns); the loop carries at most {MAX_INPUTS}",
            b.ncols()
        );
        return refuse("B", b, why);
    }
    if c.nrows() > MAX_OUTPUTS {
        let why = format!(
            "{} outputs (rows); the loop carries at most {MAX_OUTPUTS}",
            c.nrows()
        );
        return refuse("C", c, why);
    }
    Ok(())
}

fn output_names(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("y{i}")).collect()
}

fn second_order(s: &Scenario) -> Result<(ModalModel, Vec<String>), ScenarioError> {
    let arrays = arrays(s)?;
    refuse_unused(s, &arrays, &["M", "K", "D", "B", "C"])?;
    let file_err = |e: flexloop_modelfile::ModelFileError| {
        ScenarioError::new(&s.source, Some(arrays_field(s)), e.to_string())
    };
    let m = arrays.matrix("M", VectorAs::Column).map_err(file_err)?;
    let k = arrays.matrix("K", VectorAs::Column).map_err(file_err)?;
    let d = arrays
        .optional_matrix("D", VectorAs::Column)
        .map_err(file_err)?;
    let b = arrays.matrix("B", VectorAs::Column).map_err(file_err)?;
    let c = arrays.matrix("C", VectorAs::Row).map_err(file_err)?;
    let square = |m: &DMatrix<f64>| m.nrows().max(m.ncols());
    let mut sizes = vec![("M", &m, square(&m)), ("K", &k, square(&k))];
    if let Some(d) = &d {
        sizes.push(("D", d, square(d)));
    }
    sizes.extend([("B", &b, b.nrows()), ("C", &c, c.ncols())]);
    check_model_size(s, &arrays, &sizes, (&b, &c), true)?;
    let damping = scenario_damping(s);
    if d.is_some() && damping.is_some() {
        let field = if s.plant.zeta.is_some() {
            "plant.zeta"
        } else {
            "plant.rayleigh"
        };
        return Err(ScenarioError::new(
            &s.source,
            Some(field),
            format!(
                "{} gives a damping matrix D: the modal damping comes from it",
                arrays.source()
            ),
        ));
    }
    if d.is_none() && damping.is_none() {
        return Err(ScenarioError::new(
            &s.source,
            Some("plant.zeta"),
            format!(
                "{} has no damping matrix D: give the modal damping (plant.zeta or \
                 plant.rayleigh)",
                arrays.source()
            ),
        ));
    }
    let modal = modal_from_second_order(&m, &k, d.as_ref(), &b, &c, damping)
        .and_then(checked_rigid_modes)
        .map_err(|e| model_error(s, &arrays, e))?;
    let names = output_names(modal.outputs());
    Ok((modal, names))
}

fn state_space(s: &Scenario, ts: f64) -> Result<(ModalModel, Vec<String>), ScenarioError> {
    let arrays = arrays(s)?;
    refuse_unused(s, &arrays, &["A", "B", "C", "D", "ts"])?;
    let file_err = |e: flexloop_modelfile::ModelFileError| {
        ScenarioError::new(&s.source, Some(arrays_field(s)), e.to_string())
    };
    let a = arrays.matrix("A", VectorAs::Column).map_err(file_err)?;
    let b = arrays.matrix("B", VectorAs::Column).map_err(file_err)?;
    let c = arrays.matrix("C", VectorAs::Row).map_err(file_err)?;
    let d = arrays
        .optional_matrix("D", VectorAs::Row)
        .map_err(file_err)?;
    let sizes = [
        ("A", &a, a.nrows().max(a.ncols())),
        ("B", &b, b.nrows()),
        ("C", &c, c.ncols()),
    ];
    check_model_size(s, &arrays, &sizes, (&b, &c), false)?;
    let (a, b) = match arrays.scalar("ts").map_err(file_err)? {
        None => (a, b),
        Some(file_ts) => {
            // A discrete model is only exact at its own rate: resampling it
            // to another would invent what happens between its samples.
            if (file_ts - ts).abs() > 1e-9 * ts {
                return Err(ScenarioError::new(
                    &s.source,
                    Some(arrays_field(s)),
                    format!(
                        "{}: `ts` = {file_ts} s makes the model discrete at {:.6} Hz, the loop \
                         runs at {} Hz: give the continuous model (no `ts`), or one sampled \
                         at the loop's rate",
                        arrays.source(),
                        1.0 / file_ts,
                        s.timing.rate_hz
                    ),
                ));
            }
            continuous_from_zoh(&a, &b, file_ts).map_err(|e| model_error(s, &arrays, e))?
        }
    };
    let modal =
        modal_from_state_space(&a, &b, &c, d.as_ref()).map_err(|e| model_error(s, &arrays, e))?;
    let names = output_names(modal.outputs());
    Ok((modal, names))
}
