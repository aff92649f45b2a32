//! A PID controller of one's own for a flexloop loop: a discrete PID on the
//! first output's error from the scenario's set-point, with a filtered
//! derivative, gains from `[controller.params]`.
//! The Python example (python/examples/pid.py) is the same law, operation
//! for operation, so that both give the same commands to the last bit.

use flexloop_sdk::{
    Command, ControlLaw, ControllerSetup, Estimate, Handover, Measurement, Reference, SetupError,
};

/// `[controller.params]`.
#[derive(serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Proportional gain (N/m).
    kp: f64,
    /// Integral gain (N/(m s)).
    ki: f64,
    /// Derivative gain (N s/m).
    kd: f64,
    /// Derivative filter bandwidth (rad/s).
    derivative_filter_rad_s: f64,
}

struct Pid {
    reference: Reference,
    ts: f64,
    kp: f64,
    ki_ts: f64,
    /// Backward-Euler filtered derivative: d(k) = a d(k−1) + b (e(k) − e(k−1)).
    a: f64,
    b: f64,
    limit: f64,
    integral: f64,
    derivative: f64,
    last_error: f64,
    /// The gains' fingerprint: a successor with the same takes the state.
    design: u64,
}

impl ControlLaw for Pid {
    fn new(setup: &ControllerSetup<'_>) -> Result<Self, SetupError> {
        let p: Params = setup.params()?;
        if setup.n_inputs() != 1 {
            return Err(SetupError::Unsupported(format!(
                "this PID drives one input; the loop has {}",
                setup.n_inputs()
            )));
        }
        let ts = setup.ts();
        let n = p.derivative_filter_rad_s;
        let design = [p.kp, p.ki, p.kd, n, ts]
            .iter()
            .fold(0xcbf2_9ce4_8422_2325_u64, |h, v| {
                (h ^ v.to_bits()).wrapping_mul(0x100_0000_01b3)
            });
        Ok(Self {
            reference: setup.reference(),
            ts,
            kp: p.kp,
            ki_ts: p.ki * ts,
            a: 1.0 / (1.0 + n * ts),
            b: p.kd * n / (1.0 + n * ts),
            limit: setup.input_limit(),
            integral: 0.0,
            derivative: 0.0,
            last_error: 0.0,
            design,
        })
    }

    fn step(&mut self, m: &Measurement, _estimate: &Estimate, out: &mut Command) {
        let r = self.reference.sample(m.seq as f64 * self.ts)[0];
        let error = r - m.y[0];
        self.integral += self.ki_ts * error;
        self.derivative = self.a * self.derivative + self.b * (error - self.last_error);
        self.last_error = error;
        let u = self.kp * error + self.integral + self.derivative;
        out.u[0] = u.clamp(-self.limit, self.limit);
        out.u_fb[0] = u;
        out.r[0] = r;
        out.e_meas[0] = error;
    }

    fn save(&self, out: &mut Handover) {
        let state = [self.integral, self.derivative, self.last_error];
        flexloop_sdk::save_state(out, self.design, &state);
    }

    fn load(&mut self, from: &Handover) -> bool {
        let Some(&[integral, derivative, last_error]) =
            flexloop_sdk::saved_state(from, self.design)
        else {
            return false;
        };
        (self.integral, self.derivative, self.last_error) = (integral, derivative, last_error);
        true
    }

    /// Bumpless from another controller: the integrator takes the difference.
    fn shift_output(&mut self, delta_u: &[f64]) {
        self.integral += delta_u[0];
    }
}

fn main() {
    std::process::exit(flexloop_sdk::run_controller::<Pid>());
}
