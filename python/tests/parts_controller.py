"""A controller whose every command carries all its parts, for
tests/integration/python_sdk.rs: feedback u_fb = kp (r - y), feedforward
u_ff = m r̈, an observer-based part u_d = kd (ṙ - x̂₂) from the estimate's
velocity, the set-point r; u (their sum) and e_meas (r - y) left to the
runner. ``mass_kg`` has a default, so that the params record lists it as
defaulted unless the scenario gives it."""

import flexloop


class Parts(flexloop.Controller):
    def __init__(self, setup):
        super().__init__(setup)
        p = setup.params
        self.kp = p.number("kp")
        self.kd = p.number("kd")
        self.mass = p.number("mass_kg", default=1.0, positive=True)
        self.reference = setup.reference()
        self.ts = setup.ts
        self.derivatives = [0.0] * 5
        self.out = flexloop.Output()

    def step(self, m, estimate):
        r, v, a, _, _ = self.reference.derivatives(m.seq * self.ts, self.derivatives)
        out = self.out
        out.u_fb = self.kp * (r - m.y[0])
        out.u_ff = self.mass * a
        out.u_d = self.kd * (v - estimate.x_hat[1])
        out.r = r
        return out


if __name__ == "__main__":
    flexloop.run(Parts)
