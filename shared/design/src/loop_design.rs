//! From a validated scenario to the loop's discrete blocks.
//!
//! Every process runs the same design from the same file, so the plant, the
//! observer and the controller agree on dimensions and on the sample period
//! without exchanging matrices. The design is checked here (stability of the
//! closed loop, dimensions, actuator limits), before any process enters its loop.

use crate::checks::{check_actuator_limit, check_protocol_limits, stable_closed_loop};
use crate::feedback::{anti_windup_time_constant, scenario_feedback};
use crate::feedforward::{feedforward_form, feedforward_gains};
use crate::observer::OutputPrediction;
use crate::pid_bandwidth::{self, PidBandwidthChoice};
use crate::plants::{model_parts, with_input_disturbance};
use crate::reference::{Derivatives, Reference};
use crate::sensor_scan::{SensorScan, design_sensor_scan};
use flexloop_control::excitation::ExcitationPlan;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::observer_block::ObserverBlock;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;

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
    /// The f_bw the PID runs ([`pid_bandwidth::resolve`]: the number given,
    /// or what `"auto"` chose); None without PID feedback.
    pub pid_bandwidth: Option<PidBandwidthChoice>,
    /// The mass the single-axis PID is tuned on [kg]
    /// ([`pid_bandwidth::siso_mass`]); None for a PID decoupled over several
    /// axes, or no PID (what a bandwidth search needs).
    pub pid_mass: Option<f64>,
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
    /// τ_d [s] when each command acts on arrival, from t_k + τ_d
    /// (`loop.command_deadline_us`, docs/deadline.md); `plant` and the
    /// blocks are then in the delayed-input form. None: one sample of delay.
    pub command_deadline_s: Option<f64>,
    /// With a command deadline: G_new (plant states × inputs), the part of
    /// the sample the input present at t_k has not yet acted over; `plant`
    /// runs z = x − G_new u_a, so the plant's state is x(k) = z(k) +
    /// G_new u_a(k) (what a replay of the plant's modes needs).
    pub plant_g_new: Option<DMatrix<f64>>,
    /// The loop as the design sees it (closed_loop module of flexloop-control):
    /// inputs `[r; n; u_ff; w]`, outputs `[e_meas; y_meas; e_true; u_c]`.
    /// None when a program of one's own serves the controller or the
    /// observer (`exec`): its law is the program's, which flexloop does not
    /// have, so neither the loop nor its stability is claimed
    /// ([`unanalysed_roles`], docs/components.md).
    pub closed_loop: Option<DiscreteStateSpace>,
    /// Open-loop flexible modes of the plant: (frequency Hz, damping).
    pub flexible_modes: Vec<(f64, f64)>,
    /// Poles of the observer's error dynamics, (frequency Hz, damping), so
    /// that an analysis of the closed loop can tell them from structural modes.
    pub observer_modes: Vec<(f64, f64)>,
    /// A sensor the structure scans past (`plant.sensor_scan`): the plant's
    /// output row and the observer follow the position every tick. The
    /// blocks above are then the design frozen at the scan's start.
    pub sensor_scan: Option<SensorScan>,
    /// The scenario's `[measure]`: the excitation the plant adds, where and
    /// when (docs/control.md, "Measuring the loop").
    pub measurement: Option<ExcitationPlan>,
}

impl LoopDesign {
    /// The design of `s`, step by step; each step refuses what it cannot
    /// design with the field to blame, in this order.
    pub fn from_scenario(s: &Scenario) -> Result<Self, ScenarioError> {
        let ts = 1.0 / s.timing.rate_hz;
        let extra_delay = s.controller.extra_delay_samples as usize;
        let loop_delay_samples = 1 + s.controller.extra_delay_samples;
        let reference = Reference::from_scenario(s)?;
        check_deadline_applies(s)?;
        let parts = model_parts(s, ts, extra_delay)?;
        let (n_outputs, n_inputs) = (parts.plant_u.outputs(), parts.plant_u.inputs());
        check_protocol_limits(s, &parts)?;
        let reference_direction = reference_direction(s, n_outputs)?;
        let pid_bandwidth = pid_bandwidth::resolve(s, &parts, loop_delay_samples as usize)?;
        let feedback = scenario_feedback(s, ts, &parts.feedback, pid_bandwidth.map(|p| p.hz))?;
        let pid_mass = pid_bandwidth.and_then(|_| pid_bandwidth::siso_mass(&parts.feedback));
        let feedforward = feedforward_gains(s, &parts.feedforward, n_inputs, &reference_direction)?;
        // Without feedback the loop is analysed with a zero controller.
        let zero_controller = DiscreteStateSpace::gain(DMatrix::zeros(n_inputs, n_outputs), ts)
            .map_err(|e| ScenarioError::new(&s.source, Some("controller"), e.to_string()))?;
        let controller = feedback.as_ref().unwrap_or(&zero_controller);
        // What runs is checked: the plant, a built-in observer's design, the
        // messages' limits. The closed loop is a claim about both laws, and
        // a program's law is not flexloop's to analyse.
        let analysed = unanalysed_roles(s).is_empty();
        let closed_loop = if analysed {
            Some(stable_closed_loop(
                s,
                &parts,
                controller,
                feedback.is_some(),
                loop_delay_samples,
            )?)
        } else {
            None
        };
        if s.controller.exec.is_none() {
            // A program computes its own feedforward, from the reference it is given.
            check_actuator_limit(s, &reference, &feedforward, loop_delay_samples, ts)?;
        }
        let stability = analysed.then_some(controller);
        let sensor_scan = design_sensor_scan(s, ts, extra_delay, &reference, stability)?;
        let modified_feedforward =
            feedforward_form(s, &parts.observer, controller, loop_delay_samples)?;
        let plant = with_input_disturbance(s, &parts, ts)?;
        // The two-inertia setup turns (rad) and is driven by a current (A).
        let rotary = s.plant.model == "two-inertia";
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
            anti_windup_s: match (&feedback, pid_bandwidth) {
                (Some(_), Some(p)) => anti_windup_time_constant(p.hz),
                _ => 0.0,
            },
            feedback,
            pid_bandwidth,
            pid_mass,
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
            command_deadline_s: s.command_deadline_s(),
            plant_g_new: parts.plant_g_new.clone(),
            closed_loop,
            flexible_modes: parts.flexible_modes,
            observer_modes: parts.observer_modes,
            sensor_scan,
            measurement: s.measurement_plan()?,
        })
    }
}

/// The roles a program of one's own serves (`controller`, `observer`):
/// with any, the closed loop is not analysed ([`LoopDesign::closed_loop`]).
pub fn unanalysed_roles(s: &Scenario) -> Vec<&'static str> {
    let mut roles = Vec::new();
    if s.controller.exec.is_some() {
        roles.push("controller");
    }
    if s.observer.exec.is_some() {
        roles.push("observer");
    }
    roles
}

/// `reference.direction`, one entry per output; by default the first output.
fn reference_direction(s: &Scenario, n_outputs: usize) -> Result<Vec<f64>, ScenarioError> {
    match &s.reference.direction {
        Some(d) if d.len() != n_outputs => Err(ScenarioError::new(
            &s.source,
            Some("reference.direction"),
            format!(
                "has {} entries, the plant `{}` has {n_outputs} output{}",
                d.len(),
                s.plant.model,
                if n_outputs == 1 { "" } else { "s" }
            ),
        )),
        Some(d) => Ok(d.clone()),
        None => Ok((0..n_outputs)
            .map(|i| if i == 0 { 1.0 } else { 0.0 })
            .collect()),
    }
}

/// A command deadline needs a loop designed for it: a Kalman observer (or
/// none) on a modal model with a fixed sensor (the scenario's own check
/// refuses programs of one's own).
fn check_deadline_applies(s: &Scenario) -> Result<(), ScenarioError> {
    if s.command_deadline_s().is_none() {
        return Ok(());
    }
    let refuse = |reason: String| {
        Err(ScenarioError::new(
            &s.source,
            Some("loop.command_deadline_us"),
            reason,
        ))
    };
    if s.plant.model == "double-integrator" {
        return refuse(
            "the double integrator's state feedback is placed for one sample of delay; \
             a deadline needs a modal model"
                .into(),
        );
    }
    if !matches!(s.observer.design.as_str(), "kalman" | "none") {
        return refuse(format!(
            "observer.design = \"{}\" is designed for one sample of delay; \
             a deadline needs \"kalman\" or \"none\"",
            s.observer.design
        ));
    }
    if s.plant.sensor_scan.is_some() {
        return refuse(
            "a scanned sensor's scheduled observer is designed for one sample of delay".into(),
        );
    }
    Ok(())
}
