//! From a validated scenario to the loop's discrete blocks.
//!
//! Every process runs the same design from the same file, so the plant, the
//! observer and the controller agree on dimensions and on the sample period
//! without exchanging matrices. The design is checked here (stability of the
//! closed loop, dimensions), before any process enters its loop.

use crate::ScenarioError;
use crate::reference::{Derivatives, Reference};
use crate::schema::Scenario;
use flexloop_control::lti::DiscreteStateSpace;
use nalgebra::{Complex, DMatrix};

/// The observer as one linear block, see `flexloop_protocol::messages::Estimate`.
///
/// Inputs `[y(k); u_a(k)]`, outputs `[ŷ_flex(k); u_d(k)]`, where u_d(k) is the
/// force to be applied over [t_k+1, t_k+2) (from x̂(k+1|k), so that the
/// loop's one sample of delay is compensated) and ŷ_flex(k) comes from x̂(k|k−1).
#[derive(Debug, Clone)]
pub struct ObserverBlock {
    pub system: DiscreteStateSpace,
    /// x̂(k|k−1) = estimate_map · s(k).
    pub estimate_map: DMatrix<f64>,
}

/// Everything the four processes run.
#[derive(Debug, Clone)]
pub struct LoopDesign {
    pub ts: f64,
    pub n_outputs: usize,
    pub n_inputs: usize,
    /// Inputs `[u; w]` (command, then force disturbance), outputs the true y.
    pub plant: DiscreteStateSpace,
    pub observer: ObserverBlock,
    /// e → u_fb (absent when the observer block closes the loop by state feedback).
    pub feedback: Option<DiscreteStateSpace>,
    /// u_ff,i = gains_i · derivatives of r_i, evaluated at the tick the command applies.
    pub feedforward: Vec<Derivatives>,
    pub reference: Reference,
    pub input_limit: f64,
    pub force_noise: f64,
    pub sensor_noise: f64,
    pub seed: u64,
    /// Samples between y(k) and the tick its command is applied at (1, or 2 with extra delay).
    pub loop_delay_samples: u32,
}

impl LoopDesign {
    pub fn from_scenario(s: &Scenario) -> Result<Self, ScenarioError> {
        let ts = 1.0 / s.timing.rate_hz;
        let reference = match s.reference.shape.as_str() {
            "hold" => Reference::Hold,
            "step" => Reference::Step {
                amplitude: s.reference.amplitude,
                start_s: s.reference.start_s,
            },
            "sine" => Reference::Sine {
                amplitude: s.reference.amplitude,
                omega: 2.0 * std::f64::consts::PI * s.reference.frequency_hz,
                start_s: s.reference.start_s,
            },
            other => {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("reference.shape"),
                    format!("unknown shape `{other}` (expected hold, step or sine)"),
                ));
            }
        };
        let design = match (s.plant.model.as_str(), s.observer.design.as_str()) {
            ("double-integrator", "state-feedback") => double_integrator(s, ts, reference)?,
            ("double-integrator", other) => {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("observer.design"),
                    format!(
                        "unknown design `{other}` for a double integrator (expected state-feedback)"
                    ),
                ));
            }
            (other, _) => {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("plant.model"),
                    format!("unknown model `{other}` (expected double-integrator)"),
                ));
            }
        };
        Ok(design)
    }
}

/// Characteristic polynomial z² + a1 z + a2 of a continuous pole pair (ω, ζ)
/// mapped by z = e^{sT}.
fn discrete_pole_pair(omega: f64, zeta: f64, ts: f64) -> (f64, f64) {
    let sigma = zeta * omega;
    let a2 = (-2.0 * sigma * ts).exp();
    let a1 = if zeta < 1.0 {
        -2.0 * (-sigma * ts).exp() * (omega * (1.0 - zeta * zeta).sqrt() * ts).cos()
    } else {
        let root = omega * (zeta * zeta - 1.0).sqrt();
        -((-sigma + root) * ts).exp() - ((-sigma - root) * ts).exp()
    };
    (a1, a2)
}

/// The lecture's double integrator (Årzén, §12.1 of the control reference):
/// exact ZOH, state feedback by pole placement, predictor observer.
fn double_integrator(
    s: &Scenario,
    ts: f64,
    reference: Reference,
) -> Result<LoopDesign, ScenarioError> {
    let m = s.plant.mass_kg;
    let h = ts;
    let phi = DMatrix::from_row_slice(2, 2, &[1.0, h, 0.0, 1.0]);
    let gamma = DMatrix::from_row_slice(2, 1, &[h * h / (2.0 * m), h / m]);
    let c = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);

    // Closed-form pole placement (lecture): l1 = (1+a1+a2)/h², l2 = (3+a1−a2)/(2h),
    // scaled by m because Γ carries 1/m.
    let w_fb = 2.0 * std::f64::consts::PI * s.observer.feedback_bandwidth_hz;
    let (a1, a2) = discrete_pole_pair(w_fb, s.observer.feedback_damping, h);
    let l = DMatrix::from_row_slice(
        1,
        2,
        &[
            m * (1.0 + a1 + a2) / (h * h),
            m * (3.0 + a1 - a2) / (2.0 * h),
        ],
    );
    let w_ob = 2.0 * std::f64::consts::PI * s.observer.observer_bandwidth_hz;
    let (p1, p2) = discrete_pole_pair(w_ob, s.observer.observer_damping, h);
    let k = DMatrix::from_row_slice(2, 1, &[2.0 + p1, (1.0 + p1 + p2) / h]);

    let a_err = &phi - &k * &c;
    // Block state s(k) = x̂(k|k−1); inputs [y; u_a].
    let mut b_o = DMatrix::zeros(2, 2);
    b_o.set_column(0, &k.column(0));
    b_o.set_column(1, &gamma.column(0));
    let mut c_o = DMatrix::zeros(2, 2);
    // Row 0: ŷ_flex = 0 (a rigid body has no flexible part to compensate).
    c_o.set_row(1, &(-&l * &a_err).row(0));
    let mut d_o = DMatrix::zeros(2, 2);
    d_o[(1, 0)] = -(&l * &k)[(0, 0)];
    d_o[(1, 1)] = -(&l * &gamma)[(0, 0)];
    let observer = ObserverBlock {
        system: DiscreteStateSpace::new(a_err.clone(), b_o, c_o, d_o, ts).map_err(|e| {
            ScenarioError::new(&s.source, Some("observer"), format!("observer block: {e}"))
        })?,
        estimate_map: DMatrix::identity(2, 2),
    };

    let mut b_plant = DMatrix::zeros(2, 2);
    b_plant.set_column(0, &gamma.column(0));
    b_plant.set_column(1, &gamma.column(0));
    let plant = DiscreteStateSpace::new(phi.clone(), b_plant, c.clone(), DMatrix::zeros(1, 2), ts)
        .map_err(|e| ScenarioError::new(&s.source, Some("plant"), format!("plant model: {e}")))?;

    // Separation: the loop is stable iff Φ − ΓL and Φ − KC are.
    for (field, matrix) in [
        ("observer.feedback_bandwidth_hz", &phi - &gamma * &l),
        ("observer.observer_bandwidth_hz", a_err),
    ] {
        let radius = spectral_radius(&matrix);
        if radius.is_nan() || radius >= 1.0 {
            return Err(ScenarioError::new(
                &s.source,
                Some(field),
                format!("the design is unstable (spectral radius {radius:.6})"),
            ));
        }
    }

    Ok(LoopDesign {
        ts,
        n_outputs: 1,
        n_inputs: 1,
        plant,
        observer,
        feedback: None,
        // u = −L(x̂ − x_ref) + m r̈: track r with zero lag in the nominal case.
        feedforward: vec![[l[(0, 0)], l[(0, 1)], m, 0.0, 0.0]],
        reference,
        input_limit: s.plant.input_limit,
        force_noise: s.plant.force_noise,
        sensor_noise: s.plant.sensor_noise,
        seed: s.plant.seed,
        loop_delay_samples: 1 + s.controller.extra_delay_samples,
    })
}

fn spectral_radius(a: &DMatrix<f64>) -> f64 {
    a.clone()
        .complex_eigenvalues()
        .iter()
        .map(|z: &Complex<f64>| z.norm())
        .fold(0.0, f64::max)
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

    #[test]
    fn lecture_design_matches_the_worked_example() {
        // Lecture: h = 0.44, ω = 1, ζ = 0.7 gives L = [0.7347 1.2069].
        let (a1, a2) = discrete_pole_pair(1.0, 0.7, 0.44);
        let h: f64 = 0.44;
        let l1 = (1.0 + a1 + a2) / (h * h);
        let l2 = (3.0 + a1 - a2) / (2.0 * h);
        assert!((l1 - 0.7347).abs() < 1e-4, "{l1}");
        assert!((l2 - 1.2069).abs() < 1e-4, "{l2}");
    }

    #[test]
    fn design_has_consistent_dimensions() {
        let mut s = Scenario::parse(Path::new("t.toml"), LECTURE).unwrap();
        s.apply(&Overrides::default());
        s.validate().unwrap();
        let d = LoopDesign::from_scenario(&s).unwrap();
        assert_eq!(d.plant.inputs(), 2 * d.n_inputs);
        assert_eq!(d.plant.outputs(), d.n_outputs);
        assert_eq!(d.observer.system.inputs(), d.n_outputs + d.n_inputs);
        assert_eq!(d.observer.system.outputs(), d.n_outputs + d.n_inputs);
    }

    #[test]
    fn unknown_model_names_the_field() {
        let text = LECTURE.replace("double-integrator", "triple-integrator");
        let s = Scenario::parse(Path::new("t.toml"), &text).unwrap();
        let err = LoopDesign::from_scenario(&s).unwrap_err();
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
