//! A PID controller of one's own for a flexloop loop: a discrete PID per
//! axis (output i drives input i; one axis on a single-input loop) on the
//! error from the scenario's set-point, with a filtered derivative, gains
//! from `[controller.params]`, and optionally the model's feedforward on
//! the reference's derivatives at the instant each command acts.
//! The Python example (python/examples/pid.py) is the same law, operation
//! for operation, so that both give the same commands to the last bit.

use flexloop_sdk::{
    Command, ControlLaw, ControllerSetup, Derivatives, Estimate, Handover, MAX_INPUTS, Measurement,
    Reference, SetupError,
};

/// `[controller.params]`.
#[derive(serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct Params {
    kp: f64,
    ki: f64,
    kd: f64,
    derivative_filter_rad_s: f64,
    /// Add the model's feedforward (`setup.feedforward_gains()`, the
    /// rigid-body mass on the acceleration) to each axis; off by default.
    #[serde(default)]
    feedforward: bool,
}

struct Pid {
    reference: Reference,
    direction: [f64; MAX_INPUTS],
    /// Per input, the gains on (r, ṙ, r̈, r⃛, snap); zero without feedforward.
    feedforward: [Derivatives; MAX_INPUTS],
    /// When each sample's command acts (the feedforward's instant): the
    /// tick `delay` samples on, or t_k + τ_d with a command deadline.
    delay: u64,
    deadline_s: Option<f64>,
    axes: usize,
    ts: f64,
    kp: f64,
    ki_ts: f64,
    a: f64,
    b: f64,
    limit: f64,
    integral: [f64; MAX_INPUTS],
    derivative: [f64; MAX_INPUTS],
    last_error: [f64; MAX_INPUTS],
    design: u64,
}

impl Pid {
    /// The instant sample `seq`'s command acts (`setup.actuation_time`).
    fn actuation_time(&self, seq: u64) -> f64 {
        match self.deadline_s {
            Some(tau) => seq as f64 * self.ts + tau,
            None => (seq + self.delay) as f64 * self.ts,
        }
    }
}

impl ControlLaw for Pid {
    fn new(setup: &ControllerSetup<'_>) -> Result<Self, SetupError> {
        let p: Params = setup.params()?;
        let axes = setup.n_inputs();
        if axes != setup.n_outputs() {
            return Err(SetupError::Unsupported(format!(
                "this PID drives input i from output i; the loop has {} inputs and {} outputs",
                axes,
                setup.n_outputs()
            )));
        }
        let ts = setup.ts();
        let n = p.derivative_filter_rad_s;
        let mut direction = [0.0; MAX_INPUTS];
        direction[..axes].copy_from_slice(setup.reference_direction());
        let mut feedforward = [[0.0; 5]; MAX_INPUTS];
        if p.feedforward {
            feedforward[..axes].copy_from_slice(setup.feedforward_gains());
        }
        let design = [p.kp, p.ki, p.kd, n, ts, f64::from(u8::from(p.feedforward))]
            .iter()
            .fold(0xcbf2_9ce4_8422_2325_u64, |h, v| {
                (h ^ v.to_bits()).wrapping_mul(0x100_0000_01b3)
            });
        Ok(Self {
            reference: setup.reference(),
            direction,
            feedforward,
            delay: u64::from(setup.loop_delay_samples()),
            deadline_s: setup.command_deadline_s(),
            axes,
            ts,
            kp: p.kp,
            ki_ts: p.ki * ts,
            a: 1.0 / (1.0 + n * ts),
            b: p.kd * n / (1.0 + n * ts),
            limit: setup.input_limit(),
            integral: [0.0; MAX_INPUTS],
            derivative: [0.0; MAX_INPUTS],
            last_error: [0.0; MAX_INPUTS],
            design,
        })
    }

    fn step(&mut self, m: &Measurement, _estimate: &Estimate, out: &mut Command) {
        let r = self.reference.sample(m.seq as f64 * self.ts)[0];
        let ahead = self.reference.sample(self.actuation_time(m.seq));
        for i in 0..self.axes {
            let r_i = self.direction[i] * r;
            let error = r_i - m.y[i];
            self.integral[i] += self.ki_ts * error;
            self.derivative[i] =
                self.a * self.derivative[i] + self.b * (error - self.last_error[i]);
            self.last_error[i] = error;
            let u_fb = self.kp * error + self.integral[i] + self.derivative[i];
            let u_ff: f64 = self.feedforward[i]
                .iter()
                .zip(&ahead)
                .map(|(g, d)| g * d)
                .sum();
            out.u[i] = (u_fb + u_ff).clamp(-self.limit, self.limit);
            out.u_fb[i] = u_fb;
            out.u_ff[i] = u_ff;
            out.r[i] = r_i;
            out.e_meas[i] = error;
        }
    }

    fn save(&self, out: &mut Handover) {
        let n = self.axes;
        let mut state = [0.0; 3 * MAX_INPUTS];
        state[..n].copy_from_slice(&self.integral[..n]);
        state[n..2 * n].copy_from_slice(&self.derivative[..n]);
        state[2 * n..3 * n].copy_from_slice(&self.last_error[..n]);
        flexloop_sdk::save_state(out, self.design, &state[..3 * n]);
    }

    fn load(&mut self, from: &Handover) -> bool {
        let n = self.axes;
        let Some(state) = flexloop_sdk::saved_state(from, self.design) else {
            return false;
        };
        if state.len() != 3 * n {
            return false;
        }
        self.integral[..n].copy_from_slice(&state[..n]);
        self.derivative[..n].copy_from_slice(&state[n..2 * n]);
        self.last_error[..n].copy_from_slice(&state[2 * n..]);
        true
    }

    fn shift_output(&mut self, delta_u: &[f64]) {
        for (integral, delta) in self.integral.iter_mut().zip(delta_u) {
            *integral += delta;
        }
    }
}

fn main() {
    std::process::exit(flexloop_sdk::run_controller::<Pid>());
}
