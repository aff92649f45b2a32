//! The PID of `controller.feedback = "pid"` (Table 3.3 single-parameter
//! tuning, notches, Tustin), on one axis or on every decoupled axis.
//!
//! The notches are pre-warped before Tustin ([`prewarped_notch`]), so that
//! the running controller's discrete notch sits exactly at the asked
//! frequency, as in the design report's and the bandwidth search's
//! controller (flexloop-control's `bandwidth`); the PID itself is not
//! pre-warped (docs/control.md §10.1).

use flexloop_control::freq::prewarped_notch;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::pid::PidTuning;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;
use std::f64::consts::PI;

/// How the PID of `controller.feedback = "pid"` is put on the plant.
pub enum FeedbackPlan {
    /// One PID tuned on 1/(m s²) (the SISO models).
    Mass(f64),
    /// One PID per rigid-body-decoupled axis (docs/control.md (4.12)): each axis
    /// is 1/s² in modal units, u = Γ diag(C_fb) Υ e.
    Decoupled {
        gamma: DMatrix<f64>,
        upsilon: DMatrix<f64>,
    },
}

/// The PID of `controller.feedback = "pid"` at `f_bw` [Hz] (Table 3.3
/// single-parameter tuning, pre-warped notches, Tustin), on one axis or on
/// every decoupled axis.
pub fn pid_feedback(
    s: &Scenario,
    ts: f64,
    plan: &FeedbackPlan,
    f_bw: f64,
) -> Result<DiscreteStateSpace, ScenarioError> {
    let err =
        |reason: String| ScenarioError::new(&s.source, Some("controller.bandwidth_hz"), reason);
    let notches = prewarped_notches(s, ts)?;
    let axis = |mass: f64| {
        PidTuning::single_parameter(mass, f_bw)
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

/// `controller.notches_hz` as the continuous notch frequencies [rad/s]
/// whose Tustin images sit at the asked ones.
pub fn prewarped_notches(s: &Scenario, ts: f64) -> Result<Vec<f64>, ScenarioError> {
    s.controller
        .notches_hz
        .iter()
        .enumerate()
        .map(|(i, hz)| {
            prewarped_notch(2.0 * PI * hz, ts).map_err(|e| {
                ScenarioError::new(
                    &s.source,
                    Some(&format!("controller.notches_hz[{i}]")),
                    e.to_string(),
                )
            })
        })
        .collect()
}

/// `controller.feedback`: the PID on `plan` at `f_bw` [Hz] (resolved by
/// [`crate::pid_bandwidth::resolve`]), or none.
pub fn scenario_feedback(
    s: &Scenario,
    ts: f64,
    plan: &FeedbackPlan,
    f_bw: Option<f64>,
) -> Result<Option<DiscreteStateSpace>, ScenarioError> {
    match (s.controller.feedback.as_str(), f_bw) {
        ("none", _) => Ok(None),
        ("pid", Some(f_bw)) => pid_feedback(s, ts, plan, f_bw).map(Some),
        ("pid", None) => Err(ScenarioError::new(
            &s.source,
            Some("controller.bandwidth_hz"),
            "the PID has no f_bw",
        )),
        (other, _) => Err(ScenarioError::new(
            &s.source,
            Some("controller.feedback"),
            format!("unknown feedback `{other}` (expected pid or none)"),
        )),
    }
}

/// Tracking time constant T_t [s] of the feedback's anti-windup (back-
/// calculation): √(T_i T_d) of the PID, as Åström and Hägglund advise
/// (T_i = 1/ω_i = 9/ω_bw, T_d = 1/ω_d = 3/ω_bw).
pub fn anti_windup_time_constant(bandwidth_hz: f64) -> f64 {
    27f64.sqrt() / (2.0 * PI * bandwidth_hz)
}
