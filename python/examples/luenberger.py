"""An observer of one's own, in Python: the lecture's predictor observer on
a double integrator (docs/control.md, "the lecture's double integrator"),
x̂(k+1|k) = Φ x̂(k|k−1) + Γ u(k) + L (y(k) − C x̂(k|k−1)), with its poles
placed from ``[observer.params]`` (mass_kg, bandwidth_hz, damping).
The Rust example (examples/luenberger-observer) is the same law, line for
line, so that both give the same estimates to the last bit.

Run it as the observer of a loop with a scenario saying
``[observer] exec = ["/path/to/venv/bin/python", "luenberger.py"]``, or swap
it into a running one (``flexloop swap observer --exec
/path/to/venv/bin/python luenberger.py``).
"""

import math

import flexloop


class Predictor(flexloop.Observer):
    def __init__(self, setup):
        super().__init__(setup)
        p = setup.params  # [observer.params]
        mass_kg = p.number("mass_kg")  # the moving mass (kg)
        bandwidth_hz = p.number("bandwidth_hz")  # the poles' natural frequency (Hz)
        damping = p.number("damping")  # their damping ratio
        if setup.n_inputs != 1 or setup.n_outputs != 1:
            raise flexloop.SetupError(
                "this observer is for one input and one output; the loop has "
                f"{setup.n_inputs} and {setup.n_outputs}"
            )
        if not (mass_kg > 0.0 and bandwidth_hz > 0.0 and 0.0 <= damping < 1.0):
            raise flexloop.SetupError(
                "observer.params: mass_kg and bandwidth_hz must be positive, damping in [0, 1)"
            )
        ts = setup.ts
        # det(zI − (Φ − L C)) = z² + (l1 − 2) z + (1 − l1 + T l2), matched to
        # the poles e^{sT} of s² + 2ζω s + ω².
        w = 2.0 * math.pi * bandwidth_hz
        decay = math.exp(-damping * w * ts)
        a1 = -2.0 * decay * math.cos(w * ts * math.sqrt(1.0 - damping * damping))
        a2 = decay * decay
        l1 = a1 + 2.0
        l2 = (a2 - 1.0 + l1) / ts
        # Φ = [[1, T], [0, 1]], Γ = [T²/(2m), T/m], C = [1, 0].
        self.ts = ts
        self.gamma = (ts * ts / (2.0 * mass_kg), ts / mass_kg)
        self.gain = (l1, l2)
        # x̂(k|k−1): position, velocity.
        self.x = [0.0, 0.0]
        self.innovation = [0.0]
        self.out = flexloop.Estimated(x_hat=self.x, innovation=self.innovation)

    def initial(self):
        return self.x

    def step(self, m):
        innovation = m.y[0] - self.x[0]
        u = m.u_applied[0]
        p, v = self.x
        self.x[0] = p + self.ts * v + self.gamma[0] * u + self.gain[0] * innovation
        self.x[1] = v + self.gamma[1] * u + self.gain[1] * innovation
        self.innovation[0] = innovation
        return self.out

    # A successor of the same design (a swap to the same law, a restart)
    # continues from x̂.
    def save_state(self):
        return self.x

    def load_state(self, state):
        p, v = state
        self.x[0], self.x[1] = p, v


if __name__ == "__main__":
    flexloop.run_observer(Predictor)
