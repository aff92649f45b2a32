//! Set-point profiles: r and its first four derivatives at any time.
//!
//! Evaluated once per sample by the controller, so [`Reference::sample`] is
//! closed-form and allocation-free.

/// r, ṙ, r̈, r⃛ and the snap, in that order.
pub type Derivatives = [f64; 5];

#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// r = 0.
    Hold,
    /// A step of `amplitude` at `start_s` (derivatives are zero: a step has no
    /// feedforward).
    Step { amplitude: f64, start_s: f64 },
    /// amplitude · sin(ω (t − start)) from `start_s` on.
    Sine {
        amplitude: f64,
        omega: f64,
        start_s: f64,
    },
}

impl Reference {
    pub fn sample(&self, t: f64) -> Derivatives {
        match *self {
            Reference::Hold => [0.0; 5],
            Reference::Step { amplitude, start_s } => [
                if t >= start_s { amplitude } else { 0.0 },
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            Reference::Sine {
                amplitude,
                omega,
                start_s,
            } => {
                if t < start_s {
                    return [0.0; 5];
                }
                let phase = omega * (t - start_s);
                let (s, c) = phase.sin_cos();
                let a = amplitude;
                [
                    a * s,
                    a * omega * c,
                    -a * omega.powi(2) * s,
                    -a * omega.powi(3) * c,
                    a * omega.powi(4) * s,
                ]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sine_derivatives_match_finite_differences() {
        let r = Reference::Sine {
            amplitude: 2.0,
            omega: 3.0,
            start_s: 0.0,
        };
        let h = 1e-6;
        let t = 0.4;
        for i in 0..4 {
            let numeric = (r.sample(t + h)[i] - r.sample(t - h)[i]) / (2.0 * h);
            let exact = r.sample(t)[i + 1];
            assert!((numeric - exact).abs() < 1e-4 * exact.abs().max(1.0), "{i}");
        }
    }

    #[test]
    fn step_switches_at_its_time() {
        let r = Reference::Step {
            amplitude: 1.0,
            start_s: 0.5,
        };
        assert_eq!(r.sample(0.49)[0], 0.0);
        assert_eq!(r.sample(0.5)[0], 1.0);
    }
}
