//! The lecture's double integrator (Årzén, §12.1 of the control reference).

use super::Parts;
use crate::feedback::FeedbackPlan;
use crate::feedforward::FeedforwardPlan;
use crate::observer::OutputPrediction;
use flexloop_control::closed_loop::discrete_modes;
use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::discretise::zoh;
use flexloop_control::lecture::{place, place_observer};
use flexloop_control::observer_block::state_feedback_observer_block;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::{Complex, DMatrix};
use std::f64::consts::PI;

/// The discrete poles of ω², 2ζω (continuous s², s coefficients) under
/// sampling at `ts`: a complex pair, or two real poles when overdamped.
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
pub fn parts(s: &Scenario, ts: f64, extra_delay: usize) -> Result<Parts, ScenarioError> {
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
        design_file_plant: None,
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
        continuous_plant: continuous,
        plant_g_new: None,
        flexible_modes: Vec::new(),
        observer_modes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
