//! From a validated scenario to the loop's discrete blocks.
//!
//! Every process runs the same design from the same file, so the plant, the
//! observer and the controller agree on dimensions and on the sample period
//! without exchanging matrices. The design is checked here (stability of the
//! closed loop, dimensions, actuator limits), before any process enters its loop.

use crate::ScenarioError;
use crate::reference::{Derivatives, Reference};
use crate::schema::{FeedforwardSection, Scenario};
use flexloop_control::closed_loop::{LoopSpec, assemble_loop, discrete_modes};
use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::damping::DampingMethod;
use flexloop_control::discretise::zoh;
use flexloop_control::lecture::{place, place_observer};
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::modified_feedforward::modified_feedforward;
use flexloop_control::observer_block::{
    DampingOptions, ModalObserverOptions, design_modal_observer, state_feedback_observer_block,
};
use flexloop_control::pid::PidTuning;
use flexloop_control::setpoint::{Setpoint, SetpointParams};
use flexloop_control::{linalg, models};
use nalgebra::{Complex, DMatrix};
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
    /// Inputs `[u; w]` (command, then force disturbance), outputs the true y.
    pub plant: DiscreteStateSpace,
    /// Inputs `[y; u_a]` (plus `u_pending` with extra delay), outputs `[ŷ_flex; u_d]`.
    pub observer: ObserverBlock,
    pub output_prediction: OutputPrediction,
    /// e_meas → u_fb (absent when the observer block closes the loop by state feedback).
    pub feedback: Option<DiscreteStateSpace>,
    /// u0,i = gains_i · derivatives of r_i, evaluated at the tick the command applies.
    pub feedforward: Vec<Derivatives>,
    /// Appendix A's modified feedforward, inputs [u0; r] (both at the tick the
    /// command applies), output u_ff; None: u_ff = u0.
    pub modified_feedforward: Option<DiscreteStateSpace>,
    pub reference: Reference,
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
}

/// The parts every model branch produces.
struct Parts {
    plant_u: DiscreteStateSpace,
    observer: ObserverBlock,
    output_prediction: OutputPrediction,
    feedforward: Derivatives,
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
            other => {
                return Err(err(
                    "plant.model",
                    format!("unknown model `{other}` (expected double-integrator or thesis-chain)"),
                ));
            }
        };
        let feedback = match s.controller.feedback.as_str() {
            "none" => None,
            "pid" => {
                let mass = match s.plant.model.as_str() {
                    "thesis-chain" => models::CHAIN_MASS,
                    _ => s.plant.mass_kg,
                };
                let notches: Vec<f64> = s
                    .controller
                    .notches_hz
                    .iter()
                    .map(|hz| 2.0 * PI * hz)
                    .collect();
                let pid = PidTuning::single_parameter(mass, s.controller.bandwidth_hz)
                    .and_then(|t| t.with_notches(&notches).discrete(ts))
                    .map_err(|e| err("controller.bandwidth_hz", format!("PID design: {e}")))?;
                Some(pid)
            }
            other => {
                return Err(err(
                    "controller.feedback",
                    format!("unknown feedback `{other}` (expected pid or none)"),
                ));
            }
        };
        let feedforward = match s.controller.feedforward {
            Some(FeedforwardSection {
                snap,
                jerk,
                acc,
                vel,
            }) => [0.0, vel, acc, jerk, snap],
            None => parts.feedforward,
        };
        let loop_delay_samples = 1 + s.controller.extra_delay_samples;
        let zero_controller = DiscreteStateSpace::gain(DMatrix::zeros(1, 1), ts)
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
            n_outputs: parts.plant_u.outputs(),
            n_inputs: parts.plant_u.inputs(),
            plant,
            observer: parts.observer,
            output_prediction: parts.output_prediction,
            feedback,
            feedforward: vec![feedforward],
            modified_feedforward,
            reference,
            input_limit: s.plant.input_limit,
            force_noise: s.plant.force_noise,
            sensor_noise: s.plant.sensor_noise,
            reference_noise: s.plant.reference_noise,
            seed: s.plant.seed,
            loop_delay_samples,
            closed_loop,
            flexible_modes: parts.flexible_modes,
            observer_modes: parts.observer_modes,
        })
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
            Reference::Scan {
                setpoint: Box::new(setpoint),
                start_s: r.start_s,
                repeat_s: r.repeat_s,
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
    gains: &Derivatives,
    delay: u32,
    ts: f64,
) -> Result<(), ScenarioError> {
    let horizon = match (reference.end_s(), s.ticks()) {
        (Some(end), _) => end + delay as f64 * ts,
        (None, Some(ticks)) => ticks as f64 * ts,
        (None, None) => 10.0,
    };
    let samples = ((horizon / ts).ceil() as u64).min(10_000_000);
    let mut peak: (f64, f64) = (0.0, 0.0);
    for k in 0..=samples {
        let t = k as f64 * ts;
        let d = reference.sample(t);
        let u: f64 = gains.iter().zip(&d).map(|(g, v)| g * v).sum();
        if u.abs() > peak.0 {
            peak = (u.abs(), t);
        }
    }
    if peak.0 > s.plant.input_limit {
        return Err(ScenarioError::new(
            &s.source,
            Some("plant.input_limit"),
            format!(
                "the trajectory needs {:.1} N of feedforward at t = {:.4} s, beyond the \
                 actuator limit of {} N: slow the trajectory or raise the limit",
                peak.0, peak.1, s.plant.input_limit
            ),
        ));
    }
    Ok(())
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
        feedforward: [l[(0, 0)], l[(0, 1)], m, 0.0, 0.0],
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
    let o = &s.observer;
    let (observer, output_prediction, observer_modes) = match o.design.as_str() {
        "kalman" => {
            // Output position dependency only (control.md §1.4): C_t and
            // T_DC follow the sensor, B_t does not, so the AD gain K (from
            // φ_a) is the same everywhere while the Kalman gain, which
            // depends on C, is designed for this position.
            let reduced = modal
                .truncate(4, &[4, 5, 6])
                .map_err(|e| err(sensor_field(s), e.to_string()))?;
            let q_nu = match o.q_nu {
                Some(0.0) => None,
                Some(q) => Some(q),
                None => Some(if o.ad { 1e3 } else { 0.03 }),
            };
            let options = ModalObserverOptions {
                ts,
                mc: o.mc,
                damping: o.ad.then(|| DampingOptions {
                    increase: vec![o.damping_increase; reduced.modal.modes() - 1],
                    method: DampingMethod::Automated,
                    bandpass_q: (o.bandpass_q > 0.0).then_some(o.bandpass_q),
                }),
                q_nu,
                weights: None,
                extra_delay_samples: extra_delay,
            };
            let designed = design_modal_observer(&reduced, &options)
                .map_err(|e| err("observer", format!("Kalman observer: {e}")))?;
            let model = &designed.design.model;
            let modes = discrete_modes(&(&model.a - &designed.design.gain * &model.c), ts)
                .unwrap_or_default();
            let prediction = OutputPrediction {
                c: model.c.clone(),
                d: model.d.clone(),
            };
            (designed.block, prediction, modes)
        }
        "none" => {
            if o.mc || o.ad {
                return Err(err(
                    "observer.design",
                    "MC and AD need an observer: use design = \"kalman\"".into(),
                ));
            }
            (
                empty_observer(ts, extra_delay)
                    .map_err(|e| err("observer", format!("observer block: {e}")))?,
                OutputPrediction {
                    c: DMatrix::zeros(1, 0),
                    d: DMatrix::zeros(1, 1),
                },
                Vec::new(),
            )
        }
        other => {
            return Err(err(
                "observer.design",
                format!("unknown design `{other}` for the thesis chain (expected kalman or none)"),
            ));
        }
    };
    Ok(Parts {
        plant_u: plant,
        observer,
        output_prediction,
        feedforward: [0.0, 0.0, models::CHAIN_MASS, 0.0, 0.0],
        flexible_modes,
        observer_modes,
    })
}

/// The field that places the thesis chain's sensor.
fn sensor_field(s: &Scenario) -> &'static str {
    if s.plant.sensor_position.is_some() {
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
    match s.plant.sensor_position {
        Some(p) => models::thesis_chain_modal()
            .and_then(|m| m.with_sensor_positions(&[p]))
            .map_err(err),
        None => models::thesis_plant(s.plant.output).map_err(err),
    }
}

/// A block without states whose outputs are zero: the loop without an observer.
fn empty_observer(
    ts: f64,
    extra_delay: usize,
) -> Result<ObserverBlock, flexloop_control::lti::StateSpaceError> {
    let inputs = 2 + extra_delay;
    Ok(ObserverBlock {
        system: DiscreteStateSpace::new(
            DMatrix::zeros(0, 0),
            DMatrix::zeros(0, inputs),
            DMatrix::zeros(2, 0),
            DMatrix::zeros(2, inputs),
            ts,
        )?,
        estimate_map: DMatrix::zeros(0, 0),
        n_y: 1,
        n_u: 1,
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
    fn out_of_range_values_name_the_field() {
        let mut s = Scenario::parse(Path::new("t.toml"), LECTURE).unwrap();
        s.observer.observer_bandwidth_hz = 6000.0;
        let err = s.validate().unwrap_err();
        assert_eq!(err.field.as_deref(), Some("observer.observer_bandwidth_hz"));
    }
}
