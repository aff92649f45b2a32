//! What a design must satisfy before any process runs it: it fits the
//! loop's fixed-size messages, its closed loop is stable, and the
//! trajectory's feedforward stays within the actuator.

use crate::plants::Parts;
use crate::reference::{Derivatives, Reference};
use flexloop_control::closed_loop::{LoopSpec, assemble_loop};
use flexloop_control::linalg;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_scenario::{Scenario, ScenarioError};

/// The design must fit the loop's fixed-size messages.
pub fn check_protocol_limits(s: &Scenario, parts: &Parts) -> Result<(), ScenarioError> {
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

/// A trajectory whose feedforward alone exceeds the actuator is refused: the
/// plant would clamp it and the run would measure the limit, not the loop.
pub fn check_actuator_limit(
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
pub fn check_horizon(s: &Scenario, reference: &Reference, delay: u32, ts: f64) -> f64 {
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
pub const MAX_CHECKED_SAMPLES: u64 = 10_000_000;

/// The largest |u0| the feedforward asks for on samples 0..=`samples`:
/// (|u0|, t, input).
pub fn feedforward_peak(
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

/// The loop as the design sees it (inputs `[r; n; u_ff; w]`, outputs
/// `[e_meas; y_meas; e_true; u_c]`), refused unless it is stable. An
/// instability is blamed on the controller's bandwidth when there is
/// feedback, else on the observer.
pub fn stable_closed_loop(
    s: &Scenario,
    parts: &Parts,
    controller: &DiscreteStateSpace,
    has_feedback: bool,
    loop_delay_samples: u32,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let err = |field: &str, reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let closed_loop = assemble_loop(&LoopSpec {
        plant: &parts.plant_u,
        observer: Some(&parts.observer),
        controller,
        loop_delay: loop_delay_samples as usize,
    })
    .map_err(|e| err("observer", format!("closed loop: {e}")))?;
    let radius = linalg::spectral_radius(&closed_loop.a)
        .map_err(|e| err("observer", format!("closed-loop eigenvalues: {e}")))?;
    if radius.is_nan() || radius >= 1.0 {
        let field = if has_feedback {
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
    Ok(closed_loop)
}
