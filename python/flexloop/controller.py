"""The class a user's controller derives from.

A controller turns the plant's measurement y(k) (and the observer's
estimate for tick k) into the command u(k). :func:`flexloop.run` gives it
the rest of a flexloop controller's life: ports, start-up, shadow following,
the hand-over at a boundary, the exit.

Bumpless hand-over (docs/architecture.md, swaps): a replacement of the same
design (same class, same parameters, same rate) copies the active
instance's state before each sample (:meth:`Controller.save_state` /
:meth:`Controller.load_state`); any other replacement runs on its own in
shadow and, at its first sample, shifts its output by the old command minus
its own at the last sample both computed (:meth:`Controller.shift_output`).
"""

from .launch import Setup


class Controller:
    """Derive, read what the law needs from ``setup`` in ``__init__``,
    implement :meth:`step`.

    ``setup.params``: the scenario's ``[controller.params]``, read with
    ``setup.params.number("kp")`` and the like (a parameter never read is
    an error); ``setup.ts``, ``setup.rate_hz``: the sample time and rate;
    ``setup.input_limit``: the plant's |u| limit; ``setup.reference()``:
    the scenario's set-point r(t).
    """

    def __init__(self, setup: Setup):
        self.setup = setup
        #: Set-point per output, written into each command's ``r`` and
        #: ``e_meas`` (r - y) for the record; a law that tracks a reference
        #: updates it.
        self.r = [0.0] * 8
        # The default bumpless shift: an offset added to every output.
        self._offset = [0.0] * 8
        self._shifted = False

    def step(self, measurement, estimate):
        """u(k) from ``measurement`` (y(k) in ``measurement.y``) and
        ``estimate`` (the observer's for tick k): a float for one input, or
        a sequence of ``measurement.n_inputs`` floats. Called once per
        sample in order; keep it lean (no allocation needed)."""
        raise NotImplementedError("a Controller must implement step(measurement, estimate)")

    def save_state(self):
        """The law's state after the sample just stepped, as a sequence of at
        most 120 floats, for a replacement of the same design; ``None``
        (the default): no state to hand over."""
        return None

    def load_state(self, state):
        """Takes over ``state`` (what :meth:`save_state` returned in
        another instance of the same design)."""

    def shift_output(self, delta):
        """Shifts every later output by ``delta`` (one float per input).
        The default adds an offset; a law with an integrator may add it
        there instead."""
        for i, d in enumerate(delta):
            self._offset[i] += d
        self._shifted = True
