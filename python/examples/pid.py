"""A discrete PID in parallel form on e = r - y[0], r = 0, for flexloop.

With T = 1 / rate_hz, from the first sample it steps (e(-1) = e(0), I = D = 0):
    I(k) = I(k-1) + ki*T*e(k)
    D(k) = (D(k-1) + kd*n*(e(k) - e(k-1))) / (1 + n*T)
    u(k) = clamp(kp*e(k) + I(k) + D(k), -input_limit, input_limit)
A bumpless hand-over adds the old command's difference to I.
[controller.params]: kp, ki, kd, n (derivative filter, 1/s), input_limit.
"""

import flexloop


class Pid(flexloop.Controller):
    def __init__(self, params, rate_hz):
        super().__init__(params, rate_hz)
        self.kp = params.number("kp")
        self.ki_t = params.number("ki") * (1.0 / rate_hz)
        self.kd_n = params.number("kd") * params.number("n", positive=True)
        self.d_pole = 1.0 + params.number("n", positive=True) * (1.0 / rate_hz)
        self.limit = params.number("input_limit", positive=True)
        self.i = self.d = 0.0
        self.e_prev = None

    def step(self, measurement, estimate):
        e = self.r[0] - measurement.y[0]
        e_prev = e if self.e_prev is None else self.e_prev
        self.i += self.ki_t * e
        self.d = (self.d + self.kd_n * (e - e_prev)) / self.d_pole
        self.e_prev = e
        return min(max(self.kp * e + self.i + self.d, -self.limit), self.limit)

    def save_state(self):
        return (self.i, self.d, self.e_prev)

    def load_state(self, state):
        self.i, self.d, self.e_prev = state

    def shift_output(self, delta):
        self.i += delta[0]


if __name__ == "__main__":
    flexloop.run(Pid)
