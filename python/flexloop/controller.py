"""The class a user's controller derives from, and what its ``step`` returns.

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


class Output:
    """A command with its parts, as the Rust ``Command`` carries them
    (shared/protocol messages.rs): what :meth:`Controller.step` may return
    instead of a plain u.

    - ``u``: the command u_c(k), one float per input (a float for one).
      None: the sum of the parts given.
    - ``u_fb``, ``u_ff``, ``u_d``: its feedback, feedforward and
      observer-based (active damping) parts, for the record; a part not
      given is 0. With none of them given, all of ``u`` is feedback (as a
      plain float or sequence returned from ``step`` is).
    - ``r``: the set-point r(k) per output (a float for one); None: the
      controller's ``self.r``.
    - ``e_meas``: the measured error per output; None: r − y.

    Each is a sequence, or a float: for u and its parts with one input,
    for r and e_meas the first output (the others 0). A law
    that keeps one ``Output`` and changes its fields each sample allocates
    nothing for it.
    """

    __slots__ = ("u", "u_fb", "u_ff", "u_d", "r", "e_meas")

    def __init__(self, u=None, u_fb=None, u_ff=None, u_d=None, r=None, e_meas=None):
        self.u = u
        self.u_fb = u_fb
        self.u_ff = u_ff
        self.u_d = u_d
        self.r = r
        self.e_meas = e_meas

    def __repr__(self):
        fields = ", ".join(
            f"{name}={getattr(self, name)!r}"
            for name in self.__slots__
            if getattr(self, name) is not None
        )
        return f"Output({fields})"


class Controller:
    """Derive, read what the law needs from ``setup`` in ``__init__``,
    implement :meth:`step`.

    ``setup.params``: the scenario's ``[controller.params]``, read with
    ``setup.params.number("kp")`` and the like (a parameter never read is
    an error); ``setup.ts``, ``setup.rate_hz``: the sample time and rate;
    ``setup.input_limit``: the plant's |u| limit; ``setup.reference()``:
    the scenario's set-point r(t) and its derivatives;
    ``setup.reference_direction``, ``setup.command_deadline_s``,
    ``setup.loop_delay_samples``: see :class:`flexloop.Setup`.
    """

    def __init__(self, setup: Setup):
        self.setup = setup
        #: Set-point per output, written into each command's ``r`` and
        #: ``e_meas`` (r - y) for the record when ``step`` returns no
        #: :class:`Output` that says them; a law that tracks a reference
        #: updates it.
        self.r = [0.0] * 8
        # The default bumpless shift: an offset added to every output.
        self._offset = [0.0] * 8
        self._shifted = False

    def step(self, measurement, estimate):
        """u(k) from ``measurement`` (y(k) in ``measurement.y``) and
        ``estimate`` (the observer's for tick k): a float for one input, a
        sequence of ``measurement.n_inputs`` floats (all of it feedback),
        or an :class:`Output` with its parts. Called once per sample in
        order; keep it lean (no allocation needed)."""
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
        The default adds an offset (to ``u`` and its feedback part); a law
        with an integrator may add it there instead."""
        for i, d in enumerate(delta):
            self._offset[i] += d
        self._shifted = True
