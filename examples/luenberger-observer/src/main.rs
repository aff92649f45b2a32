//! An observer of one's own for a flexloop loop: the lecture's predictor
//! observer on a double integrator (docs/control.md, "the lecture's double
//! integrator"), x̂(k+1|k) = Φ x̂(k|k−1) + Γ u(k) + L (y(k) − C x̂(k|k−1)),
//! with its poles placed from `[observer.params]`.

use flexloop_sdk::{Estimate, EstimationLaw, Handover, Measurement, ObserverSetup, SetupError};

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
    /// Φ = [[1, T], [0, 1]], Γ = [T²/(2m), T/m], C = [1, 0].
    ts: f64,
    gamma: [f64; 2],
    gain: [f64; 2],
    /// x̂(k|k−1): position, velocity.
    x: [f64; 2],
    design: u64,
}

impl EstimationLaw for Predictor {
    fn new(setup: &ObserverSetup<'_>) -> Result<Self, SetupError> {
        let p: Params = setup.params()?;
        if setup.n_inputs() != 1 || setup.n_outputs() != 1 {
            return Err(SetupError::Unsupported(format!(
                "this observer is for one input and one output; the loop has {} and {}",
                setup.n_inputs(),
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
            x: [0.0; 2],
            design,
        })
    }

    fn initial(&mut self, out: &mut Estimate) {
        out.n_states = 2;
        out.x_hat[..2].copy_from_slice(&self.x);
    }

    fn step(&mut self, m: &Measurement, out: &mut Estimate) {
        let innovation = m.y[0] - self.x[0];
        let u = m.u_applied[0];
        let [p, v] = self.x;
        self.x = [
            p + self.ts * v + self.gamma[0] * u + self.gain[0] * innovation,
            v + self.gamma[1] * u + self.gain[1] * innovation,
        ];
        out.n_states = 2;
        out.x_hat[..2].copy_from_slice(&self.x);
        out.innovation[0] = innovation;
    }

    fn save(&self, out: &mut Handover) {
        flexloop_sdk::save_state(out, self.design, &self.x);
    }

    fn load(&mut self, from: &Handover) -> bool {
        let Some(&[p, v]) = flexloop_sdk::saved_state(from, self.design) else {
            return false;
        };
        self.x = [p, v];
        true
    }
}

fn main() {
    std::process::exit(flexloop_sdk::run_observer::<Predictor>());
}
