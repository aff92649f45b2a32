"""A PID controller of one's own, in Python: a discrete PID per axis
(output i drives input i; one axis on a single-input loop) on the error
from the scenario's set-point, with a filtered derivative, gains from
``[controller.params]`` (kp, ki, kd, derivative_filter_rad_s). The Rust
example (examples/pid-controller) is the same law, operation for
operation, so that both give the same commands to the last bit, with the
same parts for the record: the clamped command u, its feedback part u_fb
(before the limit), the set-point r and the error e_meas. (The Rust
example's optional model feedforward, ``feedforward = true``, needs the
loop's design, which a Python program does not have; a law of one's own
takes its gains as parameters and the reference's derivatives from
``setup.reference().derivatives(setup.actuation_time(seq))``.)

Run it as the controller of a loop with a scenario saying
``[controller] exec = ["/path/to/venv/bin/python", "pid.py"]``, or swap it
into a running one (``flexloop swap controller --exec PYTHON pid.py``).
"""

import flexloop


class Pid(flexloop.Controller):
    def __init__(self, setup):
        super().__init__(setup)
        p, ts = setup.params, setup.ts
        n = p.number("derivative_filter_rad_s", positive=True)
        self.reference, self.ts = setup.reference(), ts
        self.kp, self.ki_ts = p.number("kp"), p.number("ki") * ts
        # Backward-Euler filtered derivative: d(k) = a d(k-1) + b (e(k) - e(k-1)).
        self.a, self.b = 1.0 / (1.0 + n * ts), p.number("kd") * n / (1.0 + n * ts)
        self.limit = setup.input_limit
        self.direction = setup.reference_direction or (1.0,)
        # Sized at the first sample (a model from a file says its inputs there).
        self.axes = 0
        self.integral, self.derivative, self.last_error = [], [], []
        # One command, its fields changed each sample.
        self.out = flexloop.Output(u=[], u_fb=[], r=[], e_meas=[])

    def _size(self, m):
        if m.n_inputs != m.n_outputs:
            raise flexloop.SetupError(
                f"this PID drives input i from output i; the loop has {m.n_inputs} inputs "
                f"and {m.n_outputs} outputs"
            )
        n = self.axes = m.n_inputs
        self.direction = tuple(self.direction) + (0.0,) * (n - len(self.direction))
        for values in (self.integral, self.derivative, self.last_error):
            values.extend([0.0] * (n - len(values)))
        out = self.out
        out.u, out.u_fb, out.r, out.e_meas = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n

    def step(self, m, estimate):
        if self.axes == 0:
            self._size(m)
        r = self.reference.sample(m.seq * self.ts)
        out = self.out
        for i in range(self.axes):
            r_i = self.direction[i] * r
            error = r_i - m.y[i]
            self.integral[i] += self.ki_ts * error
            self.derivative[i] = self.a * self.derivative[i] + self.b * (
                error - self.last_error[i]
            )
            self.last_error[i] = error
            u = self.kp * error + self.integral[i] + self.derivative[i]
            out.u[i] = min(max(u, -self.limit), self.limit)
            out.u_fb[i], out.r[i], out.e_meas[i] = u, r_i, error
        return out

    # A successor of the same design takes the state; another one's
    # difference at the switch goes into the integrator (bumpless).
    def save_state(self):
        return (*self.integral, *self.derivative, *self.last_error)

    def load_state(self, state):
        n = len(state) // 3
        if self.axes == 0:
            self.axes = n
            self.out.u, self.out.u_fb = [0.0] * n, [0.0] * n
            self.out.r, self.out.e_meas = [0.0] * n, [0.0] * n
            self.direction = tuple(self.direction) + (0.0,) * (n - len(self.direction))
        self.integral = list(state[:n])
        self.derivative = list(state[n : 2 * n])
        self.last_error = list(state[2 * n :])

    def shift_output(self, delta):
        if self.axes == 0:
            self.integral = [0.0] * len(delta)
            self.derivative = [0.0] * len(delta)
            self.last_error = [0.0] * len(delta)
        for i, d in enumerate(delta):
            self.integral[i] += d


if __name__ == "__main__":
    flexloop.run(Pid)
