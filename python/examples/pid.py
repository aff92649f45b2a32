"""A PID controller of one's own, in Python: a discrete PID on the first
output's error from the scenario's set-point, with a filtered derivative,
gains from ``[controller.params]`` (kp, ki, kd, derivative_filter_rad_s).
The Rust example (examples/pid-controller) is the same law, operation for
operation, so that both give the same commands to the last bit.

Run it as the controller of a loop with a scenario saying
``[controller] exec = ["python3", "pid.py"]``, or swap it into a running one
(``flexloop swap controller SCENARIO``).
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
        self.integral = self.derivative = self.last_error = 0.0

    def step(self, m, estimate):
        r = self.r[0] = self.reference.sample(m.seq * self.ts)
        error = r - m.y[0]
        self.integral += self.ki_ts * error
        self.derivative = self.a * self.derivative + self.b * (error - self.last_error)
        self.last_error = error
        u = self.kp * error + self.integral + self.derivative
        return min(max(u, -self.limit), self.limit)

    # A successor of the same design takes the state; another one's
    # difference at the switch goes into the integrator (bumpless).
    def save_state(self):
        return (self.integral, self.derivative, self.last_error)

    def load_state(self, state):
        self.integral, self.derivative, self.last_error = state

    def shift_output(self, delta):
        self.integral += delta[0]


if __name__ == "__main__":
    flexloop.run(Pid)
