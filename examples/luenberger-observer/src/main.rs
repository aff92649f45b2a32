//! An observer of one's own for a flexloop loop: the lecture's predictor
//! observer on a double integrator (docs/control.md, "the lecture's double
//! integrator"), x̂(k+1|k) = Φ x̂(k|k−1) + Γ u(k) + L (y(k) − C x̂(k|k−1)),
//! with its poles placed from `[observer.params]`; one per axis (output i
//! moved by input i: the rigid body each actuator drives), so that it
//! estimates position and velocity on any plant with as many inputs as
//! outputs.

use flexloop_sdk::{
    Estimate, EstimationLaw, Handover, MAX_INPUTS, Measurement, ObserverSetup, SetupError,
};

/// `[observer.params]`.
#[derive(serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// The moving mass (kg).
    mass_kg: f64,
    /// Natural frequency of the observer's poles (Hz).
    bandwidth_hz: f64,
    /// Their damping ratio.
    damping: f64,
}

struct Predictor {
    /// Φ = [[1, T], [0, 1]], Γ = [T²/(2m), T/m], C = [1, 0], per axis.
    ts: f64,
    gamma: [f64; 2],
    gain: [f64; 2],
    axes: usize,
    /// x̂(k|k−1): position and velocity of each axis, [p0, v0, p1, v1, …].
    x: [f64; 2 * MAX_INPUTS],
    design: u64,
}

impl EstimationLaw for Predictor {
    fn new(setup: &ObserverSetup<'_>) -> Result<Self, SetupError> {
        let p: Params = setup.params()?;
        let axes = setup.n_inputs();
        if axes != setup.n_outputs() {
            return Err(SetupError::Unsupported(format!(
                "this observer estimates output i moved by input i; the loop has {} inputs and \
                 {} outputs",
                axes,
                setup.n_outputs()
            )));
        }
        if !(p.mass_kg > 0.0 && p.bandwidth_hz > 0.0 && (0.0..1.0).contains(&p.damping)) {
            return Err(SetupError::Unsupported(
                "observer.params: mass_kg and bandwidth_hz must be positive, damping in [0, 1)"
                    .into(),
            ));
        }
        let ts = setup.ts();
        // det(zI − (Φ − L C)) = z² + (l1 − 2) z + (1 − l1 + T l2), matched to
        // the poles e^{sT} of s² + 2ζω s + ω².
        let w = 2.0 * std::f64::consts::PI * p.bandwidth_hz;
        let decay = (-p.damping * w * ts).exp();
        let a1 = -2.0 * decay * (w * ts * (1.0 - p.damping * p.damping).sqrt()).cos();
        let a2 = decay * decay;
        let l1 = a1 + 2.0;
        let l2 = (a2 - 1.0 + l1) / ts;
        let design = [p.mass_kg, p.bandwidth_hz, p.damping, ts]
            .iter()
            .fold(0xcbf2_9ce4_8422_2325_u64, |h, v| {
                (h ^ v.to_bits()).wrapping_mul(0x100_0000_01b3)
            });
        Ok(Self {
            ts,
            gamma: [ts * ts / (2.0 * p.mass_kg), ts / p.mass_kg],
            gain: [l1, l2],
            axes,
            x: [0.0; 2 * MAX_INPUTS],
            design,
        })
    }

    fn initial(&mut self, out: &mut Estimate) {
        let n = 2 * self.axes;
        out.n_states = n as u32;
        out.x_hat[..n].copy_from_slice(&self.x[..n]);
    }

    fn step(&mut self, m: &Measurement, out: &mut Estimate) {
        for i in 0..self.axes {
            let innovation = m.y[i] - self.x[2 * i];
            let u = m.u_applied[i];
            let (p, v) = (self.x[2 * i], self.x[2 * i + 1]);
            self.x[2 * i] = p + self.ts * v + self.gamma[0] * u + self.gain[0] * innovation;
            self.x[2 * i + 1] = v + self.gamma[1] * u + self.gain[1] * innovation;
            out.innovation[i] = innovation;
        }
        let n = 2 * self.axes;
        out.n_states = n as u32;
        out.x_hat[..n].copy_from_slice(&self.x[..n]);
    }

    fn save(&self, out: &mut Handover) {
        flexloop_sdk::save_state(out, self.design, &self.x[..2 * self.axes]);
    }

    fn load(&mut self, from: &Handover) -> bool {
        let n = 2 * self.axes;
        match flexloop_sdk::saved_state(from, self.design) {
            Some(state) if state.len() == n => {
                self.x[..n].copy_from_slice(state);
                true
            }
            _ => false,
        }
    }
}

fn main() {
    std::process::exit(flexloop_sdk::run_observer::<Predictor>());
}
