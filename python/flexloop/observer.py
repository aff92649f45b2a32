"""The class a user's observer derives from, and what it returns.

An observer turns the plant's measurement y(k) (with the input u_a(k) it
carries, ``measurement.u_applied``) into the estimate for tick k+1, as the
Rust SDK's ``EstimationLaw`` does. :func:`flexloop.run_observer` gives it
the rest of a flexloop observer's life: ports, the start-up handshake (the
estimate for tick 0 from :meth:`Observer.initial`), shadow following, the
hand-over at a boundary, a restart's catch-up from its dead predecessor's
state, the exit.

A replacement of the same design (same class, same parameters, same rate)
copies the active instance's state before each sample
(:meth:`Observer.save_state` / :meth:`Observer.load_state`); so does a
restart, which then steps through every measurement since that state.
"""

from .launch import Setup


class Estimated:
    """An estimate with all its parts, as the Rust ``Estimate`` carries
    them (shared/protocol messages.rs): what :meth:`Observer.initial` and
    :meth:`Observer.step` may return instead of x̂ alone.

    - ``x_hat``: the state estimate, a sequence of at most 128 floats.
    - ``innovation``: y(k) − ŷ(k|k−1) per output (a float for one), for
      the record; None: zero.
    - ``free``, ``direct``: the observer block's free response and direct
      gain, which the built-in controller's measurement compensation and
      active damping read (row-major, as shared/protocol lays them out);
      None: zero, and the built-in controller's feedback acts on y alone.

    A law that keeps one ``Estimated`` and changes its fields each sample
    allocates nothing for it.
    """

    __slots__ = ("x_hat", "innovation", "free", "direct")

    def __init__(self, x_hat=(), innovation=None, free=None, direct=None):
        self.x_hat = x_hat
        self.innovation = innovation
        self.free = free
        self.direct = direct

    def __repr__(self):
        fields = ", ".join(
            f"{name}={getattr(self, name)!r}"
            for name in self.__slots__
            if getattr(self, name) is not None
        )
        return f"Estimated({fields})"


class Observer:
    """Derive, read what the law needs from ``setup`` in ``__init__``,
    implement :meth:`initial` and :meth:`step`.

    ``setup.params``: the scenario's ``[observer.params]``, read with
    ``setup.params.number("bandwidth_hz")`` and the like (a parameter
    never read is an error); ``setup.ts``, ``setup.n_inputs``,
    ``setup.n_outputs``, ``setup.input_limit``, ``setup.reference()``: see
    :class:`flexloop.Setup`.
    """

    def __init__(self, setup: Setup):
        self.setup = setup

    def initial(self):
        """The estimate for tick 0, before any measurement: x̂ (a sequence
        of floats) or an :class:`Estimated`."""
        raise NotImplementedError("an Observer must implement initial()")

    def step(self, measurement):
        """From ``measurement`` (tick k: ``measurement.y``,
        ``measurement.u_applied``) the estimate for tick k+1: x̂ (a
        sequence of floats), ``(x̂, innovation)``, or an
        :class:`Estimated`. Called once per measurement, in order, none
        skipped; keep it lean (no allocation needed)."""
        raise NotImplementedError("an Observer must implement step(measurement)")

    def settling_samples(self):
        """How many samples an estimate started from a wrong state takes to
        converge, or None (the default). After a restart without its
        predecessor's continuous state (none handed on, or a hole in the
        replayed measurements), the next that many estimates are flagged
        converging, and the built-in controller leaves their corrections
        (``free``, ``direct``) out meanwhile, as for the built-in observer."""
        return None

    def save_state(self):
        """The law's state after the measurement just stepped, as a
        sequence of at most 128 floats, for a successor of the same design
        (a swap to the same law, a restart after a crash); ``None`` (the
        default): no state to hand over."""
        return None

    def load_state(self, state):
        """Takes over ``state`` (what :meth:`save_state` returned in
        another instance of the same design): the next :meth:`step` is the
        measurement after the one it was saved at."""
