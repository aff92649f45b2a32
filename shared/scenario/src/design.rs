//! From a validated scenario to the loop's discrete blocks.
//!
//! Every process runs the same design from the same file, so the plant, the
//! observer and the controller agree on dimensions and on the sample period
//! without exchanging matrices. The design is checked here (stability of the
//! closed loop, dimensions, actuator limits), before any process enters its loop.

use crate::ScenarioError;
use crate::reference::{Derivatives, Reference};
use crate::schema::{FeedforwardSection, Scenario};
use crate::sensor_scan::{SensorScan, design_sensor_scan};
use flexloop_control::closed_loop::{LoopSpec, assemble_loop, discrete_modes};
use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::damping::DampingMethod;
use flexloop_control::discretise::zoh;
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::lecture::{place, place_observer};
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::modal::{ModalModel, ReducedModel};
use flexloop_control::modified_feedforward::modified_feedforward;
use flexloop_control::observer_block::{
    DampingOptions, ModalObserverOptions, design_modal_observer, state_feedback_observer_block,
};
use flexloop_control::pid::PidTuning;
use flexloop_control::setpoint::{Setpoint, SetpointParams};
use flexloop_control::{linalg, models};
use nalgebra::{Complex, DMatrix, DVector};
use std::f64::consts::PI;

pub use flexloop_control::observer_block::ObserverBlock;

/// How the observer's own output prediction is formed, for the innovation
/// y(k) − C_o x̂(k|k−1) − D_o u_a(k) that the observer reports.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputPrediction {
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
}

/// Everything the four processes run, and what the tools need to judge a run.
#[derive(Debug, Clone)]
pub struct LoopDesign {
    pub ts: f64,
    pub n_outputs: usize,
    pub n_inputs: usize,
    /// What each output measures ("y5", "sensor at 4.25", "θ1", …), for reports.
    pub output_names: Vec<String>,
    /// SI units of the outputs and inputs: "m" and "N", or "rad" and "A"
    /// for the two-inertia setup.
    pub output_unit: &'static str,
    pub input_unit: &'static str,
    /// Inputs `[u; w]` (command, then force disturbance), outputs the true y.
    pub plant: DiscreteStateSpace,
    /// Inputs `[y; u_a]` (plus `u_pending` with extra delay), outputs `[ŷ_flex; u_d]`.
    pub observer: ObserverBlock,
    pub output_prediction: OutputPrediction,
    /// e_meas → u_fb (absent when the observer block closes the loop by state feedback).
    pub feedback: Option<DiscreteStateSpace>,
    /// Tracking time constant T_t [s] of the feedback's anti-windup (back-
    /// calculation): √(T_i T_d) of the PID, as Åström and Hägglund advise
    /// (T_i = 1/ω_i = 9/ω_bw, T_d = 1/ω_d = 3/ω_bw); 0 without feedback.
    pub anti_windup_s: f64,
    /// u0,i = gains_i · derivatives of the reference profile, evaluated at
    /// the tick the command applies (one entry per input).
    pub feedforward: Vec<Derivatives>,
    /// Appendix A's modified feedforward, inputs [u0; r] (both at the tick the
    /// command applies), output u_ff; None: u_ff = u0.
    pub modified_feedforward: Option<DiscreteStateSpace>,
    /// The profile r(t); output i follows `reference_direction[i] · r(t)`.
    pub reference: Reference,
    pub reference_direction: Vec<f64>,
    pub input_limit: f64,
    pub force_noise: f64,
    pub sensor_noise: f64,
    pub reference_noise: f64,
    pub seed: u64,
    /// Samples between y(k) and the tick its command is applied at (1, or 2 with extra delay).
    pub loop_delay_samples: u32,
    /// The loop as the design sees it (closed_loop module of flexloop-control):
    /// inputs `[r; n; u_ff; w]`, outputs `[e_meas; y_meas; e_true; u_c]`.
    pub closed_loop: DiscreteStateSpace,
    /// Open-loop flexible modes of the plant: (frequency Hz, damping).
    pub flexible_modes: Vec<(f64, f64)>,
    /// Poles of the observer's error dynamics, (frequency Hz, damping), so
    /// that an analysis of the closed loop can tell them from structural modes.
    pub observer_modes: Vec<(f64, f64)>,
    /// A sensor the structure scans past (`plant.sensor_scan`): the plant's
    /// output row and the observer follow the position every tick. The
    /// blocks above are then the design frozen at the scan's start.
    pub sensor_scan: Option<SensorScan>,
}

/// How the PID of `controller.feedback = "pid"` is put on the plant.
enum FeedbackPlan {
    /// One PID tuned on 1/(m s²) (the SISO models).
    Mass(f64),
    /// One PID per rigid-body-decoupled axis (control.md (4.12)): each axis
    /// is 1/s² in modal units, u = Γ diag(C_fb) Υ e.
    Decoupled {
        gamma: DMatrix<f64>,
        upsilon: DMatrix<f64>,
    },
}

/// The feedforward a model gets when the file gives no gains.
enum FeedforwardPlan {
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

/// The parts every model branch produces.
struct Parts {
    plant_u: DiscreteStateSpace,
    observer: ObserverBlock,
    output_prediction: OutputPrediction,
    feedforward: FeedforwardPlan,
    feedback: FeedbackPlan,
    output_names: Vec<String>,
    flexible_modes: Vec<(f64, f64)>,
    observer_modes: Vec<(f64, f64)>,
}

impl LoopDesign {
    pub fn from_scenario(s: &Scenario) -> Result<Self, ScenarioError> {
        let ts = 1.0 / s.timing.rate_hz;
        let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
        let reference = reference(s)?;
        let extra_delay = s.controller.extra_delay_samples as usize;
        let parts = match s.plant.model.as_str() {
            "double-integrator" => double_integrator(s, ts, extra_delay)?,
            "thesis-chain" => thesis_chain(s, ts, extra_delay)?,
            "mimo-example" | "oat-like" | "two-inertia" | "uniform-chain" => {
                modal_stand_in(s, ts, extra_delay)?
            }
            other => {
                return Err(err(
                    "plant.model",
                    format!(
                        "unknown model `{other}` (expected one of {})",
                        crate::schema::MODELS.join(", ")
                    ),
                ));
            }
        };
        let (n_outputs, n_inputs) = (parts.plant_u.outputs(), parts.plant_u.inputs());
        check_protocol_limits(s, &parts)?;
        let reference_direction = match &s.reference.direction {
            Some(d) if d.len() != n_outputs => {
                return Err(err(
                    "reference.direction",
                    format!(
                        "has {} entries, the plant `{}` has {n_outputs} output{}",
                        d.len(),
                        s.plant.model,
                        if n_outputs == 1 { "" } else { "s" }
                    ),
                ));
            }
            Some(d) => d.clone(),
            None => (0..n_outputs)
                .map(|i| if i == 0 { 1.0 } else { 0.0 })
                .collect(),
        };
        let feedback = match s.controller.feedback.as_str() {
            "none" => None,
            "pid" => Some(pid_feedback(s, ts, &parts.feedback)?),
            other => {
                return Err(err(
                    "controller.feedback",
                    format!("unknown feedback `{other}` (expected pid or none)"),
                ));
            }
        };
        let feedforward: Vec<Derivatives> = match (s.controller.feedforward, &parts.feedforward) {
            (Some(_), _) if n_inputs != 1 => {
                return Err(err(
                    "controller.feedforward",
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
                let d = DVector::from_column_slice(&reference_direction);
                let (acc, snap) = (inverse * &d, compliance * &d);
                acc.iter()
                    .zip(snap.iter())
                    .map(|(a, s)| [0.0, 0.0, *a, 0.0, -*s])
                    .collect()
            }
        };
        let loop_delay_samples = 1 + s.controller.extra_delay_samples;
        let zero_controller = DiscreteStateSpace::gain(DMatrix::zeros(n_inputs, n_outputs), ts)
            .map_err(|e| err("controller", e.to_string()))?;
        let closed_loop = assemble_loop(&LoopSpec {
            plant: &parts.plant_u,
            observer: Some(&parts.observer),
            controller: feedback.as_ref().unwrap_or(&zero_controller),
            loop_delay: loop_delay_samples as usize,
        })
        .map_err(|e| err("observer", format!("closed loop: {e}")))?;
        let radius = linalg::spectral_radius(&closed_loop.a)
            .map_err(|e| err("observer", format!("closed-loop eigenvalues: {e}")))?;
        if radius.is_nan() || radius >= 1.0 {
            let field = if feedback.is_some() {
                "controller.bandwidth_hz"
            } else {
                "observer"
            };
            return Err(err(
                field,
                format!(
                    "the closed loop is unstable (spectral radius {radius:.6}): \
                     retune the controller or the observer"
                ),
            ));
        }
        check_actuator_limit(s, &reference, &feedforward, loop_delay_samples, ts)?;
        let sensor_scan = design_sensor_scan(
            s,
            ts,
            extra_delay,
            &reference,
            feedback.as_ref().unwrap_or(&zero_controller),
        )?;
        let modified_feedforward = match s.controller.feedforward_form.as_str() {
            "plain" => None,
            "modified" => Some(
                modified_feedforward(
                    &parts.observer,
                    feedback.as_ref().unwrap_or(&zero_controller),
                    loop_delay_samples as usize,
                )
                .map_err(|e| {
                    err(
                        "controller.feedforward_form",
                        format!("modified feedforward: {e}"),
                    )
                })?,
            ),
            other => {
                return Err(err(
                    "controller.feedforward_form",
                    format!("unknown form `{other}` (expected plain or modified)"),
                ));
            }
        };

        // The two-inertia setup turns (rad) and is driven by a current (A).
        let rotary = s.plant.model == "two-inertia";
        let b_u = parts.plant_u.b.clone();
        let mut b_plant = DMatrix::zeros(b_u.nrows(), 2 * b_u.ncols());
        b_plant.columns_mut(0, b_u.ncols()).copy_from(&b_u);
        b_plant
            .columns_mut(b_u.ncols(), b_u.ncols())
            .copy_from(&b_u);
        let d_plant = DMatrix::zeros(parts.plant_u.outputs(), 2 * b_u.ncols());
        let plant = DiscreteStateSpace::new(
            parts.plant_u.a.clone(),
            b_plant,
            parts.plant_u.c.clone(),
            d_plant,
            ts,
        )
        .map_err(|e| err("plant", format!("plant model: {e}")))?;

        Ok(LoopDesign {
            ts,
            n_outputs,
            n_inputs,
            output_names: parts.output_names,
            output_unit: if rotary { "rad" } else { "m" },
            input_unit: if rotary { "A" } else { "N" },
            plant,
            observer: parts.observer,
            output_prediction: parts.output_prediction,
            anti_windup_s: if feedback.is_some() {
                27f64.sqrt() / (2.0 * PI * s.controller.bandwidth_hz)
            } else {
                0.0
            },
            feedback,
            feedforward,
            modified_feedforward,
            reference,
            reference_direction,
            input_limit: s.plant.input_limit,
            force_noise: s.plant.force_noise,
            sensor_noise: s.plant.sensor_noise,
            reference_noise: s.plant.reference_noise,
            seed: s.plant.seed,
            loop_delay_samples,
            closed_loop,
            flexible_modes: parts.flexible_modes,
            observer_modes: parts.observer_modes,
            sensor_scan,
        })
    }
}

/// The PID of `controller.feedback = "pid"` (Table 3.3 single-parameter
/// tuning, notches, Tustin), on one axis or on every decoupled axis.
fn pid_feedback(
    s: &Scenario,
    ts: f64,
    plan: &FeedbackPlan,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let err =
        |reason: String| ScenarioError::new(&s.source, Some("controller.bandwidth_hz"), reason);
    let notches: Vec<f64> = s
        .controller
        .notches_hz
        .iter()
        .map(|hz| 2.0 * PI * hz)
        .collect();
    let axis = |mass: f64| {
        PidTuning::single_parameter(mass, s.controller.bandwidth_hz)
            .and_then(|t| t.with_notches(&notches).discrete(ts))
            .map_err(|e| err(format!("PID design: {e}")))
    };
    match plan {
        FeedbackPlan::Mass(mass) => axis(*mass),
        FeedbackPlan::Decoupled { gamma, upsilon } => {
            // Every decoupled axis is 1/s² in modal units: the same PID on each.
            let one = axis(1.0)?;
            let axes = upsilon.nrows();
            let ns = one.states();
            let mut a = DMatrix::zeros(axes * ns, axes * ns);
            let mut b = DMatrix::zeros(axes * ns, axes);
            let mut c = DMatrix::zeros(axes, axes * ns);
            let mut d = DMatrix::zeros(axes, axes);
            for i in 0..axes {
                a.view_mut((i * ns, i * ns), (ns, ns)).copy_from(&one.a);
                b.view_mut((i * ns, i), (ns, 1)).copy_from(&one.b);
                c.view_mut((i, i * ns), (1, ns)).copy_from(&one.c);
                d[(i, i)] = one.d[(0, 0)];
            }
            DiscreteStateSpace::new(a, b * upsilon, gamma * c, gamma * d * upsilon, ts)
                .map_err(|e| err(format!("decoupled PID: {e}")))
        }
    }
}

/// The design must fit the loop's fixed-size messages.
fn check_protocol_limits(s: &Scenario, parts: &Parts) -> Result<(), ScenarioError> {
    use flexloop_protocol::{MAX_INPUTS, MAX_OUTPUTS, MAX_STATES};
    let (ny, nu) = (parts.plant_u.outputs(), parts.plant_u.inputs());
    let n_est = parts.observer.estimate_map.nrows();
    let reason = if ny > MAX_OUTPUTS {
        Some(format!(
            "{ny} outputs, the loop carries at most {MAX_OUTPUTS}"
        ))
    } else if nu > MAX_INPUTS {
        Some(format!(
            "{nu} inputs, the loop carries at most {MAX_INPUTS}"
        ))
    } else if n_est > MAX_STATES {
        Some(format!(
            "an observer of {n_est} states, the loop carries at most {MAX_STATES}"
        ))
    } else {
        None
    };
    match reason {
        Some(r) => Err(ScenarioError::new(
            &s.source,
            Some(if n_est > MAX_STATES {
                "observer.flexible_modes"
            } else {
                "plant.model"
            }),
            format!("the design has {r}"),
        )),
        None => Ok(()),
    }
}

fn reference(s: &Scenario) -> Result<Reference, ScenarioError> {
    let r = &s.reference;
    Ok(match r.shape.as_str() {
        "hold" => Reference::Hold,
        "step" => Reference::Step {
            amplitude: r.amplitude,
            start_s: r.start_s,
        },
        "sine" => Reference::Sine {
            amplitude: r.amplitude,
            omega: 2.0 * PI * r.frequency_hz,
            start_s: r.start_s,
        },
        "scan" => {
            let ts = 1.0 / s.timing.rate_hz;
            if r.start_s < ts {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("reference.start_s"),
                    format!(
                        "a scan must start at least one sample ({ts} s) after the run, \
                         so that its feedforward can be issued ahead of the motion; got {}",
                        r.start_s
                    ),
                ));
            }
            let setpoint = Setpoint::new(&SetpointParams::thesis()).map_err(|e| {
                ScenarioError::new(&s.source, Some("reference"), format!("set-point: {e}"))
            })?;
            if r.repeat_s > 0.0 && r.repeat_s < setpoint.duration() {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("reference.repeat_s"),
                    format!(
                        "a scan lasts {} s; it cannot repeat every {} s",
                        setpoint.duration(),
                        r.repeat_s
                    ),
                ));
            }
            // `amplitude` 0: the thesis' stroke, as the profile has it.
            let stroke = setpoint.evaluate(setpoint.duration()).r;
            let scale = if r.amplitude == 0.0 {
                1.0
            } else {
                r.amplitude / stroke
            };
            Reference::Scan {
                setpoint: Box::new(setpoint),
                start_s: r.start_s,
                repeat_s: r.repeat_s,
                scale,
            }
        }
        other => {
            return Err(ScenarioError::new(
                &s.source,
                Some("reference.shape"),
                format!("unknown shape `{other}` (expected hold, step, sine or scan)"),
            ));
        }
    })
}

/// A trajectory whose feedforward alone exceeds the actuator is refused: the
/// plant would clamp it and the run would measure the limit, not the loop.
fn check_actuator_limit(
    s: &Scenario,
    reference: &Reference,
    gains: &[Derivatives],
    delay: u32,
    ts: f64,
) -> Result<(), ScenarioError> {
    let samples = (check_horizon(s, reference, delay, ts) / ts).ceil() as u64;
    let peak = feedforward_peak(reference, gains, samples, ts);
    if peak.0 > s.plant.input_limit {
        // The two-inertia setup is driven by a motor current.
        let unit = if s.plant.model == "two-inertia" {
            "A"
        } else {
            "N"
        };
        let which = if gains.len() > 1 {
            format!(" on input {}", peak.2 + 1)
        } else {
            String::new()
        };
        return Err(ScenarioError::new(
            &s.source,
            Some("plant.input_limit"),
            format!(
                "the trajectory needs {:.1} {unit} of feedforward{which} at t = {:.4} s, beyond \
                 the actuator limit of {} {unit}: slow the trajectory or raise the limit",
                peak.0, peak.1, s.plant.input_limit
            ),
        ));
    }
    Ok(())
}

/// How far into the run the feedforward is checked: to the end of the
/// motion or of the run, and for a profile that repeats a whole number of
/// samples, one period after it starts: the samples then take the same
/// values every period. (Every process designs the loop at start-up: over a
/// whole 30 s run this check was 9 ms of a replacement's start-up, beside the
/// loop, and an hour's run would have been 36 million samples.)
fn check_horizon(s: &Scenario, reference: &Reference, delay: u32, ts: f64) -> f64 {
    let lead_out = f64::from(delay + 1) * ts;
    let run = match (reference.end_s(), s.ticks()) {
        (Some(end), _) => end + lead_out,
        (None, Some(ticks)) => ticks as f64 * ts,
        (None, None) => 10.0,
    };
    let one_period = reference.repetition().and_then(|(start, period)| {
        let samples = period / ts;
        ((samples - samples.round()).abs() < 1e-6).then_some(start + period + lead_out)
    });
    one_period
        .map_or(run, |p| run.min(p))
        .min(MAX_CHECKED_SAMPLES as f64 * ts)
}

/// A bound on the check of a profile that does not repeat (1000 s at 10 kHz).
const MAX_CHECKED_SAMPLES: u64 = 10_000_000;

/// The largest |u0| the feedforward asks for on samples 0..=`samples`:
/// (|u0|, t, input).
fn feedforward_peak(
    reference: &Reference,
    gains: &[Derivatives],
    samples: u64,
    ts: f64,
) -> (f64, f64, usize) {
    let mut peak: (f64, f64, usize) = (0.0, 0.0, 0);
    for k in 0..=samples {
        let t = k as f64 * ts;
        let d = reference.sample(t);
        for (input, g) in gains.iter().enumerate() {
            let u: f64 = g.iter().zip(&d).map(|(g, v)| g * v).sum();
            if u.abs() > peak.0 {
                peak = (u.abs(), t, input);
            }
        }
    }
    peak
}

fn pole_pair(omega: f64, zeta: f64, ts: f64) -> [Complex<f64>; 2] {
    let s = if zeta < 1.0 {
        Complex::new(-zeta * omega, omega * (1.0 - zeta * zeta).sqrt())
    } else {
        Complex::new(-omega * (zeta - (zeta * zeta - 1.0).sqrt()), 0.0)
    };
    let z = (s * ts).exp();
    let z2 = if zeta < 1.0 {
        z.conj()
    } else {
        (Complex::new(-omega * (zeta + (zeta * zeta - 1.0).sqrt()), 0.0) * ts).exp()
    };
    [z, z2]
}

/// The lecture's double integrator (Årzén, §12.1 of the control reference):
/// exact ZOH, state feedback by pole placement on x̂(k+1|k), and a predictor
/// observer extended with a constant input-disturbance estimate (integral
/// action: u = −L x̂ − v̂).
fn double_integrator(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    if s.observer.design != "state-feedback" {
        return Err(err(
            "observer.design",
            format!(
                "unknown design `{}` for a double integrator (expected state-feedback)",
                s.observer.design
            ),
        ));
    }
    let m = s.plant.mass_kg;
    let continuous = ContinuousStateSpace::new(
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0 / m]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        DMatrix::zeros(1, 1),
    )
    .map_err(|e| err("plant", format!("plant model: {e}")))?;
    let plant = zoh(&continuous, ts).map_err(|e| err("plant", format!("ZOH: {e}")))?;
    let w_fb = 2.0 * PI * s.observer.feedback_bandwidth_hz;
    let l = place(
        &plant.a,
        &plant.b,
        &pole_pair(w_fb, s.observer.feedback_damping, ts),
    )
    .map_err(|e| {
        err(
            "observer.feedback_bandwidth_hz",
            format!("state feedback: {e}"),
        )
    })?;
    // Extended observer [x; v]: the pole pair plus a real pole for the
    // disturbance estimate at the same speed.
    let w_ob = 2.0 * PI * s.observer.observer_bandwidth_hz;
    let mut ae = DMatrix::zeros(3, 3);
    ae.view_mut((0, 0), (2, 2)).copy_from(&plant.a);
    ae.view_mut((0, 2), (2, 1)).copy_from(&plant.b);
    ae[(2, 2)] = 1.0;
    let mut ce = DMatrix::zeros(1, 3);
    ce.view_mut((0, 0), (1, 2)).copy_from(&plant.c);
    let [p1, p2] = pole_pair(w_ob, s.observer.observer_damping, ts);
    let p3 = Complex::new((-w_ob * ts).exp(), 0.0);
    let ke = place_observer(&ae, &ce, &[p1, p2, p3])
        .map_err(|e| err("observer.observer_bandwidth_hz", format!("observer: {e}")))?;
    let k = ke.rows(0, 2).into_owned();
    let k_w = ke.rows(2, 1).into_owned();
    let block = state_feedback_observer_block(&plant, &l, &k, &k_w, extra_delay)
        .map_err(|e| err("observer", format!("observer block: {e}")))?;
    let observer_modes = discrete_modes(&(&ae - &ke * &ce), ts).unwrap_or_default();
    Ok(Parts {
        output_prediction: OutputPrediction {
            c: ce,
            d: plant.d.clone(),
        },
        observer: block,
        // u = −L(x̂ − x_ref) + m r̈: track r with zero lag in the nominal case.
        feedforward: FeedforwardPlan::Siso([l[(0, 0)], l[(0, 1)], m, 0.0, 0.0]),
        feedback: FeedbackPlan::Mass(m),
        output_names: vec!["y".into()],
        plant_u: plant,
        flexible_modes: Vec::new(),
        observer_modes,
    })
}

/// The thesis chain (control.md §1.3, §10.1): the full 8-mode model under
/// exact ZOH for the plant; a steady-state Kalman predictor on the reduced
/// model (rigid + 3 flexible modes, T_DC of modes 4–6, mode 7 unknown) with
/// MC, AD and the noise model as the scenario says.
fn thesis_chain(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let modal = thesis_chain_seen_by_sensor(s)?;
    let plant = zoh(&modal.state_space(), ts).map_err(|e| err("plant", format!("ZOH: {e}")))?;
    let flexible_modes = modal
        .frequencies_hz()
        .into_iter()
        .filter(|f| *f > 0.0)
        .map(|f| (f, models::CHAIN_ZETA))
        .collect();
    // Output position dependency only (control.md §1.4): C_t and T_DC
    // follow the sensor, B_t does not, so the AD gain K (from φ_a) is the
    // same everywhere while the Kalman gain, which depends on C, is designed
    // for this position. Retained modes: rigid + 3 flexible by default, T_DC
    // of the discarded ones up to mode 6; mode 7 stays unknown.
    let (observer, output_prediction, observer_modes) =
        modal_observer(s, ts, extra_delay, 1, 1, || {
            let keep = flexible_modes_kept(s, 3, 7)?;
            let compensate: Vec<usize> = (1 + keep..7).collect();
            let reduced = modal
                .truncate(1 + keep, &compensate)
                .map_err(|e| err(sensor_field(s), e.to_string()))?;
            Ok((reduced, None))
        })?;
    let output_names = vec![match (s.plant.sensor_position, s.plant.sensor_scan) {
        (Some(p), _) => format!("sensor at {p}"),
        (_, Some([from, to])) => format!("sensor scanned {from} -> {to}"),
        _ => format!("y{}", s.plant.output),
    }];
    Ok(Parts {
        plant_u: plant,
        observer,
        output_prediction,
        feedforward: FeedforwardPlan::Siso([0.0, 0.0, models::CHAIN_MASS, 0.0, 0.0]),
        feedback: FeedbackPlan::Mass(models::CHAIN_MASS),
        output_names,
        flexible_modes,
        observer_modes,
    })
}

/// `observer.flexible_modes`, or the model's `default`, checked against the
/// `available` flexible modes of the plant.
pub(crate) fn flexible_modes_kept(
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
pub(crate) type ObserverParts = (ObserverBlock, OutputPrediction, Vec<(f64, f64)>);

/// The observer of a modal model with `n_y` outputs and `n_u` inputs:
/// `kalman` on the reduced model (and Kalman weights, None for the thesis')
/// that `reduced` builds, with MC, AD and the noise model as the scenario
/// says, or `none`.
pub(crate) fn modal_observer(
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
pub(crate) fn kalman_options(
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
    // them all (control.md §4.2: dim ν ≤ n_sens).
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

/// The stand-ins for the models whose data the thesis leaves incomplete
/// (control.md §1.5, §1.7, §1.8; `models` documents what is invented): the
/// full modal model under exact ZOH for the plant, a Kalman observer on its
/// reduced model (T_DC of the discarded modes), and one PID per
/// rigid-body-decoupled axis (control.md (4.12)); the feedforward inverts
/// the rigid body and the static compliance of the flexible modes.
fn modal_stand_in(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
    let model_err = |e: flexloop_control::modal::ModelError| {
        ScenarioError::new(&s.source, Some("plant.model"), e.to_string())
    };
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
            let nodal = models::uniform_chain(nodes)
                .map_err(|e| ScenarioError::new(&s.source, Some("plant.nodes"), e.to_string()))?;
            let sensor = models::uniform_chain_sensor(nodes);
            (
                ModalModel::from_nodal(&nodal).map_err(model_err)?,
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
    let (n_y, n_u) = (full.outputs(), full.inputs());
    let plant = zoh(&full.state_space(), ts)
        .map_err(|e| ScenarioError::new(&s.source, Some("plant"), format!("ZOH: {e}")))?;
    let f_hz = full.frequencies_hz();
    let flexible_modes = (full.n_rigid..full.modes())
        .map(|i| (f_hz[i], full.zeta[i]))
        .collect();
    let (_, gamma, upsilon) = full.rigid_body_decoupled().map_err(model_err)?;
    let inverse = &gamma * &upsilon;
    let compliance = full
        .compliance(&(full.n_rigid..full.modes()).collect::<Vec<_>>())
        .map_err(model_err)?;
    let n_flex = full.modes() - full.n_rigid;
    let (observer, output_prediction, observer_modes) =
        modal_observer(s, ts, extra_delay, n_y, n_u, || {
            let keep = flexible_modes_kept(s, default_keep, n_flex)?;
            let compensate: Vec<usize> = (full.n_rigid + keep..full.modes()).collect();
            let reduced = full
                .truncate(full.n_rigid + keep, &compensate)
                .map_err(|e| {
                    ScenarioError::new(&s.source, Some("observer.flexible_modes"), e.to_string())
                })?;
            let weights = stand_in_weights(s, &reduced, ts)?;
            Ok((reduced, weights))
        })?;
    Ok(Parts {
        plant_u: plant,
        observer,
        output_prediction,
        feedforward: FeedforwardPlan::RigidBody {
            compliance: &inverse * &compliance * &inverse,
            inverse,
        },
        feedback: FeedbackPlan::Decoupled { gamma, upsilon },
        output_names,
        flexible_modes,
        observer_modes,
    })
}

/// Kalman weights of the stand-ins (None: the thesis' σ_w, σ_v, σ_d).
/// OAT (control.md §4.4): Q = 10⁻⁴ I on the inputs, R = 10⁻¹⁸ I. Two-inertia
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

/// The field that places the thesis chain's sensor.
pub(crate) fn sensor_field(s: &Scenario) -> &'static str {
    if s.plant.sensor_scan.is_some() {
        "plant.sensor_scan"
    } else if s.plant.sensor_position.is_some() {
        "plant.sensor_position"
    } else {
        "plant.output"
    }
}

/// The full chain (8 modes) as its one sensor sees it: mass m_i for
/// `output = i` (exactly [`models::thesis_plant`]), or the world-fixed sensor
/// of `sensor_position` with mode-shape rows interpolated between nodes.
/// The observer's reduced model (rigid + 3 flexible, T_DC of modes 4–6, as
/// [`models::thesis_reduced`]) is truncated from it, so C_t and T_DC follow
/// the sensor too.
fn thesis_chain_seen_by_sensor(
    s: &Scenario,
) -> Result<flexloop_control::modal::ModalModel, ScenarioError> {
    let field = sensor_field(s);
    let err = |e: flexloop_control::modal::ModelError| {
        ScenarioError::new(&s.source, Some(field), e.to_string())
    };
    // A scanned sensor: the design frozen where the scan starts.
    match s
        .plant
        .sensor_position
        .or(s.plant.sensor_scan.map(|[from, _]| from))
    {
        Some(p) => models::thesis_chain_modal()
            .and_then(|m| m.with_sensor_positions(&[p]))
            .map_err(err),
        None => models::thesis_plant(s.plant.output).map_err(err),
    }
}

/// A block without states whose outputs are zero: the loop without an observer.
pub(crate) fn empty_observer(
    ts: f64,
    n_y: usize,
    n_u: usize,
    extra_delay: usize,
) -> Result<ObserverBlock, flexloop_control::lti::StateSpaceError> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schema::Overrides;
    use std::path::Path;

    const LECTURE: &str = r#"
name = "t"
[loop]
rate_hz = 10000
[plant]
model = "double-integrator"
[observer]
design = "state-feedback"
"#;

    const THESIS: &str = r#"
name = "t"
[loop]
rate_hz = 10000
duration_s = 0.3
[plant]
model = "thesis-chain"
input_limit = 2000
[observer]
design = "kalman"
mc = true
ad = true
[controller]
feedback = "pid"
bandwidth_hz = 35.5
[reference]
shape = "scan"
start_s = 0.01
"#;

    fn design(text: &str) -> Result<LoopDesign, ScenarioError> {
        let mut s = Scenario::parse(Path::new("t.toml"), text)?;
        s.apply(&Overrides::default());
        s.validate()?;
        LoopDesign::from_scenario(&s)
    }

    #[test]
    fn design_has_consistent_dimensions() {
        for text in [LECTURE, THESIS] {
            let d = design(text).unwrap();
            assert_eq!(d.plant.inputs(), 2 * d.n_inputs);
            assert_eq!(d.plant.outputs(), d.n_outputs);
            assert_eq!(d.observer.system.inputs(), d.n_outputs + d.n_inputs);
            assert_eq!(d.observer.system.outputs(), d.n_outputs + d.n_inputs);
            assert_eq!(
                d.output_prediction.c.ncols(),
                d.observer.estimate_map.nrows()
            );
        }
    }

    #[test]
    fn thesis_chain_has_the_full_model_and_a_reduced_observer() {
        let d = design(THESIS).unwrap();
        // 8 modes in the plant, rigid + 3 flexible (+ noise model) in the observer.
        assert_eq!(d.plant.states(), 16);
        assert_eq!(d.flexible_modes.len(), 7);
        assert!((d.flexible_modes[0].0 - 470.06).abs() < 0.01);
        assert_eq!(d.observer.estimate_map.nrows(), 9);
        // The scan starts 10 ms into the run.
        assert_eq!(d.reference.scan_windows(0.3), vec![(0.05, 0.18)]);
    }

    #[test]
    fn extra_delay_adds_the_pending_input() {
        let d = design(&THESIS.replace(
            "bandwidth_hz = 35.5",
            "bandwidth_hz = 35.5\nextra_delay_samples = 1",
        ))
        .unwrap();
        assert_eq!(d.loop_delay_samples, 2);
        assert_eq!(d.observer.system.inputs(), 3);
    }

    #[test]
    fn unstable_design_names_the_tuning() {
        let err = design(&THESIS.replace("bandwidth_hz = 35.5", "bandwidth_hz = 400")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("controller.bandwidth_hz"));
        assert!(err.reason.contains("unstable"), "{err}");
    }

    #[test]
    fn trajectory_beyond_the_actuator_is_refused() {
        let err = design(&THESIS.replace("input_limit = 2000", "input_limit = 500")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.input_limit"));
        assert!(err.reason.contains("1250"), "{err}");
    }

    #[test]
    fn a_repeating_scan_is_checked_over_one_period_with_the_same_peak() {
        let text = THESIS
            .replace("duration_s = 0.3", "duration_s = 3600")
            .replace("start_s = 0.01", "start_s = 0.01\nrepeat_s = 0.25");
        let mut s = Scenario::parse(Path::new("t.toml"), &text).unwrap();
        s.apply(&Overrides::default());
        s.validate().unwrap();
        let d = LoopDesign::from_scenario(&s).unwrap();
        let horizon = check_horizon(&s, &d.reference, d.loop_delay_samples, d.ts);
        // Forth and back once after the lead-in, not the hour.
        assert!((0.51..0.52).contains(&horizon), "{horizon}");
        // Three periods hold the same peak as one, at the same place in the period.
        let one = feedforward_peak(&d.reference, &d.feedforward, (horizon / d.ts) as u64, d.ts);
        let three = feedforward_peak(&d.reference, &d.feedforward, (1.51 / d.ts) as u64, d.ts);
        assert!(one.0 > 1000.0, "{one:?}");
        assert!((one.0 - three.0).abs() <= 1e-9 * one.0, "{one:?} {three:?}");
        // A period that is not a whole number of samples: the whole run,
        // up to the bound.
        let Reference::Scan { setpoint, .. } = &d.reference else {
            panic!("a scan");
        };
        let odd = Reference::Scan {
            setpoint: setpoint.clone(),
            start_s: 0.01,
            repeat_s: 0.25003,
            scale: 1.0,
        };
        let horizon = check_horizon(&s, &odd, d.loop_delay_samples, d.ts);
        assert!(
            (horizon - MAX_CHECKED_SAMPLES as f64 * d.ts).abs() < 1e-6,
            "{horizon}"
        );
    }

    #[test]
    fn scan_needs_a_lead_in() {
        let err = design(&THESIS.replace("start_s = 0.01", "start_s = 0.0")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("reference.start_s"));
    }

    #[test]
    fn mc_without_an_observer_is_refused() {
        let err = design(&THESIS.replace("design = \"kalman\"", "design = \"none\"")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("observer.design"));
    }

    /// THESIS with the sensor moved from `output` (default 5) to a position.
    fn at_position(p: &str) -> String {
        THESIS.replace(
            "model = \"thesis-chain\"",
            &format!("model = \"thesis-chain\"\nsensor_position = {p}"),
        )
    }

    #[test]
    fn an_integer_sensor_position_is_that_output_exactly() {
        for (position, output) in [("5.0", 5), ("1", 1), ("7.0", 7)] {
            let by_output = design(&THESIS.replace(
                "model = \"thesis-chain\"",
                &format!("model = \"thesis-chain\"\noutput = {output}"),
            ))
            .unwrap();
            let by_position = design(&at_position(position)).unwrap();
            // Bit for bit: the same sensor row, hence the same Kalman gain,
            // observer block, feedforward block and closed loop.
            assert_eq!(by_position.plant, by_output.plant, "{position}");
            assert_eq!(by_position.observer, by_output.observer, "{position}");
            assert_eq!(by_position.output_prediction, by_output.output_prediction);
            assert_eq!(
                by_position.modified_feedforward,
                by_output.modified_feedforward
            );
            assert_eq!(by_position.closed_loop, by_output.closed_loop);
        }
    }

    #[test]
    fn a_sensor_between_nodes_interpolates_c_and_t_dc_but_not_b() {
        let [d4, d425, d5] = ["4", "4.25", "5"].map(|p| design(&at_position(p)).unwrap());
        // Plant: B is the actuator's (position-independent), C is 3/4 of m4's
        // row plus 1/4 of m5's.
        assert_eq!(d425.plant.b, d4.plant.b);
        let want = &d4.plant.c * 0.75 + &d5.plant.c * 0.25;
        assert!((&d425.plant.c - &want).amax() < 1e-15);
        assert!((&d425.plant.c - &d4.plant.c).amax() > 1e-3);
        // Observer model: C_t and T_DC (= D) follow the sensor linearly.
        let (p4, p425, p5) = (
            &d4.output_prediction,
            &d425.output_prediction,
            &d5.output_prediction,
        );
        assert!((&p425.c - (&p4.c * 0.75 + &p5.c * 0.25)).amax() < 1e-15);
        assert!((&p425.d - (&p4.d * 0.75 + &p5.d * 0.25)).amax() < 1e-24);
        assert!(p425.d[(0, 0)] != p4.d[(0, 0)]);
        // The actuator mass itself (collocated) is a position too.
        design(&at_position("0")).unwrap();
    }

    #[test]
    fn bad_sensor_positions_name_the_field() {
        for bad in ["7.5", "-0.25", "nan", "inf"] {
            let err = design(&at_position(bad)).unwrap_err();
            assert_eq!(err.field.as_deref(), Some("plant.sensor_position"), "{bad}");
            assert!(err.reason.contains("[0, 7]"), "{bad}: {err}");
            assert!(err.to_string().contains("t.toml"), "{err}");
        }
        // Both ways of placing the sensor at once.
        let both = at_position("4.25").replace("input_limit", "output = 5\ninput_limit");
        let err = design(&both).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.sensor_position"));
        assert!(err.reason.contains("not both"), "{err}");
        // Only the chain has positions.
        let lecture = LECTURE.replace(
            "model = \"double-integrator\"",
            "model = \"double-integrator\"\nsensor_position = 1.0",
        );
        let err = design(&lecture).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.sensor_position"));
        assert!(err.reason.contains("thesis chain"), "{err}");
        // A wrong type is a parse error that names the key.
        let err = Scenario::parse(Path::new("t.toml"), &at_position("\"m5\"")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("sensor_position"), "{err}");
    }

    #[test]
    fn set_sensor_position_overrides_a_files_output() {
        let mut s = Scenario::parse(
            Path::new("t.toml"),
            &THESIS.replace("input_limit", "output = 3\ninput_limit"),
        )
        .unwrap();
        assert!(s.plant.output_given);
        s.set_sensor_position(5.0);
        s.validate().unwrap();
        assert_eq!(s.plant.sensor_node(), 5.0);
        let d = LoopDesign::from_scenario(&s).unwrap();
        assert_eq!(d.plant, design(THESIS).unwrap().plant);
    }

    fn shipped(name: &str) -> Scenario {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios")
            .join(format!("{name}.toml"));
        Scenario::load(&path, &Overrides::default()).unwrap()
    }

    fn shipped_text(name: &str) -> String {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios")
            .join(format!("{name}.toml"));
        std::fs::read_to_string(path).unwrap()
    }

    #[test]
    fn stand_in_models_have_their_dimensions_and_a_decoupled_pid() {
        for (name, ny, nu, flexible, observer_states) in [
            // rigid + 2 flexible modes, noise model on 2 inputs
            ("mimo-example", 2, 2, 3, 10),
            // 3 rigid + 8 flexible, noise model on 3 inputs
            ("oat-like", 3, 3, 8, 25),
            // 1 rigid + 1 flexible, noise model on 1 input
            ("two-inertia", 1, 1, 1, 5),
        ] {
            let d = LoopDesign::from_scenario(&shipped(name)).unwrap();
            assert_eq!((d.n_outputs, d.n_inputs), (ny, nu), "{name}");
            assert_eq!(d.output_names.len(), ny);
            assert_eq!(d.reference_direction.len(), ny);
            assert_eq!(d.flexible_modes.len(), flexible, "{name}");
            assert_eq!(d.observer.estimate_map.nrows(), observer_states, "{name}");
            let fb = d.feedback.as_ref().unwrap();
            assert_eq!((fb.inputs(), fb.outputs()), (ny, nu));
            assert_eq!(d.feedforward.len(), nu);
            assert!(d.modified_feedforward.is_some());
        }
    }

    #[test]
    fn a_uniform_chain_has_an_observer_of_twice_its_nodes() {
        let text = shipped_text("uniform-chain");
        // 64 nodes (128 states) designs too, in 20 s of a debug build: `bench --sweep` runs it.
        for nodes in [2, 8, 24] {
            let d = design(&text.replace("nodes = 32", &format!("nodes = {nodes}"))).unwrap();
            assert_eq!(d.observer.estimate_map.nrows(), 2 * nodes);
            assert_eq!(d.flexible_modes.len(), nodes - 1);
            assert_eq!(d.plant.states(), 2 * nodes);
            let radius = flexloop_control::linalg::spectral_radius(&d.closed_loop.a).unwrap();
            assert!(radius < 1.0, "{nodes} nodes: {radius}");
        }
        for (replace, with, reason) in [
            ("nodes = 32\n", "", "needs its number of masses"),
            ("nodes = 32", "nodes = 65", "must lie in 2..=64"),
            ("nodes = 32", "nodes = 32\noutput = 3", "one sensor"),
        ] {
            let e = design(&text.replace(replace, with))
                .unwrap_err()
                .to_string();
            let field = if reason == "one sensor" {
                "plant.output"
            } else {
                "plant.nodes"
            };
            assert!(e.contains(field) && e.contains(reason), "{e}");
        }
        let e = design(&shipped_text("oat-like").replace("[plant]", "[plant]\nnodes = 4"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("plant.nodes") && e.contains("only the uniform chain"),
            "{e}"
        );
    }

    #[test]
    fn the_decoupled_pid_is_one_pid_per_rigid_axis() {
        // Υ P Γ has the identity over s² as its rigid part, so Υ⁻¹… no: the
        // controller seen through the decoupling, Γ⁻¹ C Υ⁻¹, must be the
        // single-parameter PID on 1/s² on every axis and zero across.
        let s = shipped("mimo-example");
        let d = LoopDesign::from_scenario(&s).unwrap();
        let full = models::mimo_example().unwrap();
        let (_, gamma, upsilon) = full.rigid_body_decoupled().unwrap();
        let one = PidTuning::single_parameter(1.0, s.controller.bandwidth_hz)
            .unwrap()
            .discrete(d.ts)
            .unwrap();
        let fb = d.feedback.unwrap();
        for hz in [1.0, 30.0, 300.0] {
            let w = 2.0 * PI * hz;
            let c = flexloop_control::freq::freq_response_discrete(&fb, w).unwrap();
            let to_c = |m: &DMatrix<f64>| m.map(|v| Complex::new(v, 0.0));
            let seen = to_c(&gamma.clone().try_inverse().unwrap())
                * c
                * to_c(&upsilon.clone().try_inverse().unwrap());
            let want = flexloop_control::freq::freq_response_discrete(&one, w).unwrap()[(0, 0)];
            for i in 0..2 {
                for j in 0..2 {
                    let expect = if i == j { want } else { Complex::new(0.0, 0.0) };
                    assert!(
                        (seen[(i, j)] - expect).norm() < 1e-9 * want.norm(),
                        "{hz} Hz"
                    );
                }
            }
        }
    }

    #[test]
    fn the_rigid_body_feedforward_moves_the_direction_and_holds_the_rest() {
        // u0 = Γ Υ d r̈ drives the rigid body exactly: through the rigid part
        // of the plant (φ_s,rig φ_a,rigᵀ) it gives d r̈.
        let d = LoopDesign::from_scenario(&shipped("mimo-example")).unwrap();
        let full = models::mimo_example().unwrap();
        let acc = DVector::from_iterator(2, d.feedforward.iter().map(|g| g[2]));
        let rigid = full.phi_s.columns(0, 2) * full.phi_a.rows(0, 2);
        let moved = rigid * acc;
        assert!(
            (moved[0] - 1.0).abs() < 1e-12 && moved[1].abs() < 1e-12,
            "{moved}"
        );
        // The snap gain takes out the flexible modes' static compliance.
        assert!(
            d.feedforward
                .iter()
                .all(|g| g[4] != 0.0 && g[1] == 0.0 && g[3] == 0.0)
        );
    }

    #[test]
    fn mimo_settings_that_do_not_fit_the_plant_name_their_field() {
        let cases = [
            // A MIMO reference on the SISO chain.
            (
                THESIS.replace("start_s = 0.01", "start_s = 0.01\ndirection = [1.0, 0.0]"),
                "reference.direction",
                "1 output",
            ),
            // An observer keeping more flexible modes than the plant has.
            (
                shipped_text("two-inertia").replace(
                    "design = \"kalman\"",
                    "design = \"kalman\"\nflexible_modes = 2",
                ),
                "observer.flexible_modes",
                "1 flexible mode",
            ),
            // Four-gain feedforward on a two-input plant.
            (
                format!(
                    "{}\n[controller.feedforward]\nacc = 10.0\n",
                    shipped_text("mimo-example")
                ),
                "controller.feedforward",
                "rigid-body",
            ),
            // Three output directions on two outputs.
            (
                shipped_text("mimo-example")
                    .replace("direction = [1.0, 0.0]", "direction = [1.0, 0.0, 0.0]"),
                "reference.direction",
                "2 outputs",
            ),
        ];
        for (text, field, fragment) in cases {
            let err = design(&text).unwrap_err();
            assert_eq!(err.field.as_deref(), Some(field), "{err}");
            assert!(err.reason.contains(fragment), "{err}");
        }
        // Schema-level: encoders on another model, output on a MIMO model,
        // a two-inertia output that does not exist, a zero direction.
        for (text, field) in [
            (
                THESIS.replace("input_limit", "encoders = [1, 2, 3]\ninput_limit"),
                "plant.encoders",
            ),
            (
                shipped_text("oat-like").replace("encoders = [1, 2, 3]", "encoders = [1, 2, 2]"),
                "plant.encoders",
            ),
            (
                shipped_text("mimo-example").replace("input_limit", "output = 1\ninput_limit"),
                "plant.output",
            ),
            (
                shipped_text("two-inertia").replace("output = 1", "output = 3"),
                "plant.output",
            ),
            (
                shipped_text("mimo-example")
                    .replace("direction = [1.0, 0.0]", "direction = [0.0, 0.0]"),
                "reference.direction",
            ),
        ] {
            let err = design(&text).unwrap_err();
            assert_eq!(err.field.as_deref(), Some(field), "{err}");
        }
    }

    #[test]
    fn a_mimo_design_checks_stability_and_every_actuator() {
        let text = shipped_text("mimo-example");
        let err = design(&text.replace("bandwidth_hz = 37.0", "bandwidth_hz = 400.0")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("controller.bandwidth_hz"));
        assert!(err.reason.contains("unstable"), "{err}");
        // Without MC and AD the 37 Hz loop cannot live with the 161 Hz mode.
        let bare = text
            .replace("design = \"kalman\"", "design = \"none\"")
            .replace("mc = true", "mc = false")
            .replace("ad = true", "ad = false")
            .replace("\"modified\"", "\"plain\"");
        assert!(design(&bare).unwrap_err().reason.contains("unstable"));
        let err = design(&text.replace("input_limit = 2000.0", "input_limit = 100.0")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.input_limit"));
        assert!(err.reason.contains("on input 1"), "{err}");
    }

    #[test]
    fn a_scanned_sensor_is_designed_and_checked() {
        let d = LoopDesign::from_scenario(&shipped("thesis-sensor-scan-ad")).unwrap();
        let scan = d.sensor_scan.as_ref().unwrap();
        // 29 grid points over the chain; the position follows the reference.
        let o = scan.observer.as_ref().unwrap();
        assert_eq!(o.schedule.models().grid().points(), 29);
        assert_eq!(scan.position_at(scan.r_start), 0.0);
        assert_eq!(scan.position_at(scan.r_end), 7.0);
        assert!((scan.position_at(0.5 * (scan.r_start + scan.r_end)) - 3.5).abs() < 1e-12);
        // The plant row at a node is that node's output row.
        let mut row = vec![0.0; d.plant.states()];
        scan.plant_row(5.0, &mut row);
        let y5 = models::thesis_plant(5).unwrap().state_space().c;
        assert!((DMatrix::from_row_slice(1, row.len(), &row) - y5).amax() < 1e-15);
        // Bad scans name the field.
        let text = shipped_text("thesis-sensor-scan-ad");
        for (from, to, field) in [
            (
                "sensor_scan = [0.0, 7.0]",
                "sensor_scan = [0.0, 7.5]",
                "plant.sensor_scan",
            ),
            (
                "sensor_scan = [0.0, 7.0]",
                "sensor_scan = [2.0, 2.0]",
                "plant.sensor_scan",
            ),
            (
                "sensor_scan = [0.0, 7.0]",
                "sensor_scan = [0.0, 7.0]\noutput = 5",
                "plant.sensor_scan",
            ),
            ("shape = \"scan\"", "shape = \"sine\"", "plant.sensor_scan"),
            (
                "feedforward_form = \"plain\"",
                "feedforward_form = \"modified\"",
                "controller.feedforward_form",
            ),
            (
                "\nscheduling = \"interpolated\"",
                "\nscheduling = \"nearest\"",
                "observer.scheduling",
            ),
        ] {
            let Err(err) = design(&text.replacen(from, to, 1)) else {
                panic!("{to}: accepted");
            };
            assert_eq!(err.field.as_deref(), Some(field), "{to}: {err}");
        }
    }

    #[test]
    fn lecture_design_matches_the_worked_example() {
        // Lecture: h = 0.44, ω = 1, ζ = 0.7 gives L = [0.7347 1.2069].
        let h = 0.44;
        let phi = DMatrix::from_row_slice(2, 2, &[1.0, h, 0.0, 1.0]);
        let gamma = DMatrix::from_row_slice(2, 1, &[h * h / 2.0, h]);
        let l = place(&phi, &gamma, &pole_pair(1.0, 0.7, h)).unwrap();
        assert!((l[(0, 0)] - 0.7347).abs() < 1e-4, "{l}");
        assert!((l[(0, 1)] - 1.2069).abs() < 1e-4, "{l}");
    }

    #[test]
    fn unknown_model_names_the_field() {
        let err = design(&LECTURE.replace("double-integrator", "triple-integrator")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.model"));
        assert!(err.to_string().contains("t.toml"));
    }

    #[test]
    fn unknown_field_is_refused_with_its_name_and_line() {
        let text = LECTURE.replace("[plant]\n", "[plant]\nmas_kg = 2.0\n");
        let err = Scenario::parse(Path::new("t.toml"), &text).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("mas_kg"));
        assert!(err.reason.contains("line 6"), "{}", err.reason);
    }

    #[test]
    fn dedicated_cores_needs_a_cpu_per_loop_process_and_the_machine_for_it() {
        let shared = shipped_text("default");
        let dedicated = shared.replace("[realtime]", "[realtime]\nprofile = \"dedicated-cores\"");
        // The shipped placement shares CPU 0: refused, naming the second process there.
        let e = design(&dedicated).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("realtime.observer.cpu"), "{e}");
        let own_cpus = dedicated
            .replace(
                "controller = { priority = 81, cpu = 0 }",
                "controller = { priority = 81, cpu = 2 }",
            )
            .replace(
                "observer = { priority = 80, cpu = 0 }",
                "observer = { priority = 80, cpu = 1 }",
            );
        let e = design(&own_cpus).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("realtime.logger.cpu"), "{e}");
        let placed = own_cpus.replace(
            "logger = { priority = 10, cpu = 1 }",
            "logger = { priority = 10, cpu = 3 }",
        );
        let mut s = Scenario::parse(Path::new("t.toml"), &placed).unwrap();
        s.apply(&Overrides::default());
        s.validate().unwrap();
        assert_eq!(s.realtime.profile, crate::Profile::DedicatedCores);
        let e = s.check_machine(2).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("realtime.profile"));
        assert!(
            e.to_string()
                .contains("needs at least 4 CPUs; this machine has 2"),
            "{e}"
        );
        let e = s.check_machine(3).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("realtime.profile"));
        let e = s.check_machine(4).map(|_| ()).and_then(|_| {
            let mut far = s.clone();
            far.realtime.controller.cpu = Some(7);
            far.check_machine(4)
        });
        assert_eq!(
            e.unwrap_err().field.as_deref(),
            Some("realtime.controller.cpu")
        );
        // Shared cores run anywhere.
        let mut s = Scenario::parse(Path::new("t.toml"), &shared).unwrap();
        s.apply(&Overrides::default());
        assert!(s.check_machine(1).is_ok());
        let e = Scenario::parse(
            Path::new("t.toml"),
            &shared.replace("[realtime]", "[realtime]\nprofile = \"spinning\""),
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("realtime") || e.to_string().contains("profile"),
            "{e}"
        );
    }

    #[test]
    fn out_of_range_values_name_the_field() {
        let mut s = Scenario::parse(Path::new("t.toml"), LECTURE).unwrap();
        s.observer.observer_bandwidth_hz = 6000.0;
        let err = s.validate().unwrap_err();
        assert_eq!(err.field.as_deref(), Some("observer.observer_bandwidth_hz"));
    }
}
