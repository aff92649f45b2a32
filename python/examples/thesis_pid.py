"""The thesis' controller written in Python (docs/control.md §3, §6, §10.1):
the Table 3.3 single-parameter PID at f_bw on the measured error with
measurement compensation (MC), the observer's active damping (AD) added to
the command, and a four-gain feedforward on the reference's derivatives at
the instant each command acts. It is the built-in controller's law with
the plain feedforward form, written from the documents rather than from
its code; on the thesis' MC + AD scan its scan error matches the built-in
controller's at the same gains (tests/integration/python_sdk.rs).

- MC and AD come from the estimate: the observer block's outputs
  [ŷ_flex; u_d] = free + direct · [y(k); u_a(k)] (docs/components.md,
  "An observer of one's own"): the flexible part of the measurement to
  subtract, and the damping force to add.
- The PID is Table 3.3's C(s) = K_p (s + ω_i)/s · (ω²/ω_d s + ω²)/(s² +
  2 ζ ω s + ω²) with K_p = m ω_bw²/3, ω_i = ω_bw/9, ω_d = ω_bw/3,
  ω = 3 ω_bw, ζ = 0.7, each section discretised by Tustin (no pre-warping).
- The feedforward is snap · r⁗ + jerk · r⃛ + acc · r̈ + vel · ṙ at
  ``setup.actuation_time(seq)``.

``[controller.params]``: ``bandwidth_hz``, ``mass_kg`` (the mass the PID is
tuned on), and the feedforward gains ``ff_snap``, ``ff_jerk``, ``ff_acc``,
``ff_vel`` (0 by default). One input and one output.
"""

import math

import flexloop
from flexloop.messages import MAX_OBSERVER_INPUTS


class Section:
    """A discrete second-order section b(z)/a(z), a0 = 1, in direct form II
    transposed."""

    def __init__(self, b, a):
        self.b0, self.b1, self.b2 = b
        self.a1, self.a2 = a
        self.s1 = self.s2 = 0.0

    def step(self, x):
        y = self.b0 * x + self.s1
        self.s1 = self.b1 * x - self.a1 * y + self.s2
        self.s2 = self.b2 * x - self.a2 * y
        return y

    def state(self):
        return (self.s1, self.s2)

    def load(self, state):
        self.s1, self.s2 = state


def tustin(num, den, ts):
    """b(z)/a(z) of the continuous num(s)/den(s) (second order at most,
    coefficients from s² down) by s = (2/T)(z - 1)/(z + 1)."""
    num = [0.0] * (3 - len(num)) + list(num)
    den = [0.0] * (3 - len(den)) + list(den)
    k = 2.0 / ts

    def poly(c):
        c2, c1, c0 = c
        # c2 k²(z-1)² + c1 k (z-1)(z+1) + c0 (z+1)², by powers of z.
        return (
            c2 * k * k + c1 * k + c0,
            -2.0 * c2 * k * k + 2.0 * c0,
            c2 * k * k - c1 * k + c0,
        )

    b, a = poly(num), poly(den)
    return [v / a[0] for v in b], [a[1] / a[0], a[2] / a[0]]


class ThesisPid(flexloop.Controller):
    def __init__(self, setup):
        super().__init__(setup)
        p = setup.params
        f_bw = p.number("bandwidth_hz", positive=True)
        mass = p.number("mass_kg", positive=True)
        # Gains on (r, ṙ, r̈, r⃛, r⁗), as flexloop's Derivatives order them.
        self.gains = (
            0.0,
            p.number("ff_vel", default=0.0),
            p.number("ff_acc", default=0.0),
            p.number("ff_jerk", default=0.0),
            p.number("ff_snap", default=0.0),
        )
        if setup.n_inputs not in (None, 1) or setup.n_outputs not in (None, 1):
            raise flexloop.SetupError("this controller is for one input and one output")
        if setup.loop_delay_samples != 1:
            raise flexloop.SetupError("this controller is for one sample of loop delay")
        ts = self.ts = setup.ts
        w = 2.0 * math.pi * f_bw
        kp, wi, wd, wlp, zlp = mass * w * w / 3.0, w / 9.0, w / 3.0, 3.0 * w, 0.7
        self.pi = Section(*tustin([kp, kp * wi], [1.0, 0.0], ts))
        w2 = wlp * wlp
        self.lead = Section(*tustin([w2 / wd, w2], [1.0, 2.0 * zlp * wlp, w2], ts))
        self.reference = setup.reference()
        self.direction = (setup.reference_direction or (1.0,))[0]
        self.limit = setup.input_limit
        self.setup_ = setup
        self.out = flexloop.Output(u=[0.0], u_fb=[0.0], u_ff=[0.0], u_d=[0.0], r=[0.0], e_meas=[0.0])

    def step(self, m, estimate):
        # The observer block's outputs: ŷ_flex (MC) and u_d (AD); a
        # program observer that leaves free and direct zero turns both off.
        inputs = (m.y[0], m.u_applied[0])
        block = [0.0, 0.0]
        for i in range(2):
            row = i * MAX_OBSERVER_INPUTS
            block[i] = estimate.free[i] + estimate.direct[row] * inputs[0] + estimate.direct[
                row + 1
            ] * inputs[1]
        r = self.direction * self.reference.sample(m.seq * self.ts)
        error = r - (m.y[0] - block[0])
        u_fb = self.lead.step(self.pi.step(error))
        d = self.reference.derivatives(self.setup_.actuation_time(m.seq))
        u_ff = sum(g * v for g, v in zip(self.gains, d))
        u_d = block[1]
        out = self.out
        out.u[0] = min(max(u_fb + u_ff + u_d, -self.limit), self.limit)
        out.u_fb[0], out.u_ff[0], out.u_d[0] = u_fb, u_ff, u_d
        out.r[0], out.e_meas[0] = r, error
        return out

    def save_state(self):
        return (*self.pi.state(), *self.lead.state())

    def load_state(self, state):
        self.pi.load(state[:2])
        self.lead.load(state[2:])


if __name__ == "__main__":
    flexloop.run(ThesisPid)
