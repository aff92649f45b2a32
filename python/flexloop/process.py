"""What a controller process and an observer process share, as shared/node's
``instance``, ``duty`` and ``handover`` modules give it to both: the command
line and the exit, the law made from the scenario (and its params record),
the duty sample by sample, the states other generations hand over, the
activation, the state this instance publishes.

The roles' own parts are in :mod:`flexloop.runner` (the controller) and
:mod:`flexloop.observer_runner` (the observer).
"""

import gc
import hashlib
import inspect
import os
import signal
import sys
import time
import traceback

from . import messages as msg
from . import realtime, transport
from .errors import ScenarioError, SetupError
from .launch import Setup, UsageError, load_settings, parse_args, write_params_record

#: How long start-up waits for its peers (shared/node lib.rs PEER_TIMEOUT).
PEER_TIMEOUT_S = 20.0
#: How long one wait for a measurement lasts before the loop looks at the
#: shutdown flag again.
WAKEUP_TIMEOUT_S = 0.1

MEASUREMENT = transport.channel("flexloop/measurement")
ACTIVATION = transport.channel("flexloop/activation")


class PeerError(Exception):
    """Another process did not show up, or went silent."""


class RunFileError(Exception):
    """A run file (the params record) could not be written."""


class LawError(Exception):
    """The user's law raised, or returned what is no command or estimate."""


_stop = False


def stop_requested():
    """Whether SIGTERM or SIGINT asked this process to finish."""
    return _stop


def _request_stop(_signum, _frame):
    global _stop
    _stop = True


def freeze_collector():
    """No collector pauses inside the loop: everything long-lived exists
    now, and the per-sample path makes no cycles (both roles call this
    once, before the port whose appearance lets the loop start)."""
    gc.collect()
    gc.freeze()
    gc.disable()


def serve_wakeups(measurements, standing, on_wakeup, is_over):
    """A process's loop, for both roles: wake on each measurement (or after
    :data:`WAKEUP_TIMEOUT_S`, to look at the stop flag), call
    ``on_wakeup()``, until ``is_over()``, the instance retires (``standing``)
    or a stop is asked."""
    while (
        not is_over()
        and standing.duty != Standing.RETIRING
        and not stop_requested()
    ):
        if measurements.has_samples():
            measurements.clear_events()
        else:
            try:
                measurements.wait(WAKEUP_TIMEOUT_S)
            except Exception:
                if stop_requested():
                    return
                raise
        on_wakeup()


class InstanceProcess:
    """The life a controller's and an observer's process share (shared/node
    ``instance``): open the ports; a late joiner drops what queued before it
    and follows off the loop's CPU until named, a first instance takes its
    priority at once; the rest of the handshake; then every wake-up until
    the run ends; and whatever happens, step down, report and close.

    A role gives ``_open``, ``_drop_stale``, ``_on_wakeup`` and ``_report``,
    the ports it closes (:attr:`PORTS`), and, where it needs them,
    ``_joined_late``, ``_enter`` and ``_resume``."""

    #: The ports the process opened, closed in this order at its end.
    PORTS = ()

    def serve(self):
        started = time.monotonic()
        if not self._open():
            return
        rt = self.settings.realtime
        try:
            if self.late:
                self._drop_stale()
                realtime.avoid_loop_cpu(rt)
                self._joined_late()
            else:
                realtime.raise_priority(rt)
            if not self._enter():
                return
            if self.late:
                self.program.say(
                    f"start-up {(time.monotonic() - started) * 1e3:.1f} ms, "
                    f"{time.process_time() * 1e3:.1f} ms of CPU"
                )
            self.cpu_at_start = time.process_time()
            self._resume()
            serve_wakeups(
                self.measurements, self.standing, self._on_wakeup, lambda: self.end_of_run
            )
        finally:
            gc.enable()
            realtime.step_down()
            self._report()
            self._close()

    def _joined_late(self):
        """After a late joiner moved off the loop's CPU."""

    def _enter(self):
        """The rest of the handshake; False: a shutdown came first."""
        return True

    def _resume(self):
        """Before the first wake-up: what a restart takes over."""

    def _close(self):
        for port in self.PORTS:
            p = getattr(self, port, None)
            if p is not None:
                p.close()
        if getattr(self, "activation", None) is not None:
            self.activation.close()
        self.node = None
        gc.collect()


class Program:
    """The process's name on its stderr lines (``flexloop-controller: …``)."""

    def __init__(self, role):
        self.role = role
        self.name = f"flexloop-{role}"

    def say(self, text):
        print(f"{self.name}: {text}", file=sys.stderr, flush=True)


def main_for(role, law_class, argv, process_class):
    """A role's process around ``law_class``: the command line, the
    signals, ``process_class(program, law_class, args).serve()`` and the
    stderr line and exit code of its end (0 clean, 1 an error, 2 a usage
    error)."""
    program = Program(role)
    realtime.PROGRAM = program.name
    try:
        args = parse_args(argv, role)
    except UsageError as e:
        program.say(f"usage: {e}")
        return 2
    try:
        msg.check_against_wire()
    except msg.WireMismatch as e:
        program.say(f"this flexloop package does not match its wire.json: {e}")
        return 1
    signal.signal(signal.SIGTERM, _request_stop)
    signal.signal(signal.SIGINT, _request_stop)
    try:
        process_class(program, law_class, args).serve()
    except (ScenarioError, transport.TransportError, PeerError, RunFileError) as e:
        program.say(str(e))
        return 1
    except SetupError as e:
        program.say(f"{role}: {e}" if role == "observer" else str(e))
        return 1
    except LawError as e:
        program.say(str(e))
        traceback.print_exception(e.__cause__ or e, file=sys.stderr)
        return 1
    finally:
        realtime.step_down()
    return 0


def make_law(program, law_class, args):
    """(settings, setup, law): the scenario read for the role, the law made
    from it, every parameter it was given read (one it never read is an
    error naming the field), and the params record written
    (``<run-dir>/params/<role>[.g<N>].json``)."""
    settings = load_settings(args)
    setup = Setup(settings, args.own, args.generation)
    try:
        law = law_class(setup)
    except (ScenarioError, SetupError):
        raise
    except Exception as e:
        raise LawError(f"{law_class.__qualname__}: cannot be made: {e!r}") from e
    setup.params.check_all_read()
    try:
        write_params_record(args.run_dir, setup.params, args.generation)
    except OSError as e:
        where = e.filename or args.run_dir
        raise RunFileError(f"{where}: {e.strerror or e}") from None
    except ValueError as e:
        raise RunFileError(f"{setup.params.role}.params: cannot be recorded: {e}") from None
    return settings, setup, law


def fingerprint(law_class, params, rate_hz):
    """The design's fingerprint: a replacement copies state only into an
    identical design (class, its file, parameters, rate)."""
    try:
        where = os.path.basename(inspect.getfile(law_class))
    except TypeError:
        where = ""
    text = f"{where}:{law_class.__qualname__}|{params.canonical()}|{rate_hz!r}"
    digest = hashlib.blake2b(text.encode(), digest_size=8).digest()
    # Never 0: 0 marks "no state to hand over".
    return int.from_bytes(digest, "little") | 1


def await_peers(ready, missing):
    """Polls ``ready()`` every 2 ms until it holds (True) or a shutdown is
    requested (False); after :data:`PEER_TIMEOUT_S` a :class:`PeerError`
    says what was still ``missing()``."""
    since = time.monotonic()
    while True:
        if ready():
            return True
        if _stop:
            return False
        if time.monotonic() - since > PEER_TIMEOUT_S:
            raise PeerError(f"peers did not connect within {PEER_TIMEOUT_S:.0f} s: {missing()}")
        time.sleep(0.002)


class Standing:
    """An instance's duty sample by sample (shared/node duty.rs ``Standing``)."""

    SHADOW, STANDBY, ACTIVE, RETIRING = "shadow", "standby", "active", "retiring"
    REPLAYING = "replaying"

    def __init__(self, generation, late, standby=False):
        self.generation = generation
        self.duty = self.STANDBY if standby else self.SHADOW
        self.priority_raised = not late
        self.next_seq = None
        self.skipped = 0

    def on_sample(self, seq, oldest_seq, owner, named, caught_up):
        """(duty, was, raise_priority) for the newest sample ``seq``."""
        active = owner == self.generation
        if self.next_seq is not None:
            first = seq if active else oldest_seq
            self.skipped += max(0, first - self.next_seq)
        self.next_seq = seq + 1
        raise_priority = not self.priority_raised and (
            (named == self.generation and caught_up) or active
        )
        self.priority_raised |= raise_priority
        was = self.duty
        if active:
            self.duty = self.ACTIVE
        elif was == self.ACTIVE:
            self.duty = self.RETIRING
        return self.duty, was, raise_priority

    def replaying(self):
        """A restart's replay is under way."""
        self.duty = self.REPLAYING

    def replayed(self, last_seq, duty):
        """The replay ended after measurement ``last_seq``, into ``duty``."""
        self.next_seq = last_seq + 1
        self.duty = duty

    def mark(self):
        """How a state this instance publishes is marked (duty.rs ``handover_mark``)."""
        if self.duty == self.ACTIVE:
            return msg.HandoverMark.ACTIVE
        if self.duty == self.REPLAYING:
            return msg.HandoverMark.CATCHING_UP
        return msg.HandoverMark.FOLLOWING


class HandoverRing:
    """The last states other generations published as the active instance."""

    SIZE = 8

    def __init__(self):
        self.slots = [msg.Handover() for _ in range(self.SIZE)]
        self.valid = [False] * self.SIZE
        self.newest_slot = None
        self.scratch = msg.Handover()

    def take(self, inlet, own_generation):
        while inlet.receive_into(self.scratch):
            h = self.scratch
            if h.generation == own_generation or h.shadow != msg.HandoverMark.ACTIVE:
                continue
            slot = h.seq % self.SIZE
            self.slots[slot], self.scratch = h, self.slots[slot]
            self.valid[slot] = True
            if self.newest_slot is None or self.slots[self.newest_slot].seq <= h.seq:
                self.newest_slot = slot

    def find(self, seq):
        if seq < 0:
            return None
        slot = seq % self.SIZE
        h = self.slots[slot]
        return h if self.valid[slot] and h.seq == seq else None

    def newest(self):
        return None if self.newest_slot is None else self.slots[self.newest_slot]


class ActivationView:
    """The newest activation (polled each sample: no wake-up)."""

    def __init__(self, node):
        self.inlet = transport.Inlet(
            node, ACTIVATION, msg.Activation, ACTIVATION["loop_buffer_size"], listen=False
        )
        self.current = msg.Activation()
        self.scratch = msg.Activation()

    def refresh(self):
        while self.inlet.receive_into(self.scratch):
            if self.scratch.published_ns >= self.current.published_ns:
                self.current, self.scratch = self.scratch, self.current
        return self.current

    def close(self):
        self.inlet.close()


class StateOut:
    """This instance's state after each sample, for a successor: the law's
    own (``save_state``, under the design's fingerprint) and the command
    it sent (the controller's)."""

    def __init__(self, node, channel, generation, design_hash):
        self.outlet = transport.Outlet(node, channel, msg.Handover)
        self.generation = generation
        self.design_hash = design_hash
        self.h = msg.Handover()

    def publish(self, seq, mark, state, extra=(), u=None, n_inputs=0):
        """Publishes the state after sample ``seq``: ``state`` (what the
        law saved, or None) followed by ``extra[:n_inputs]`` (the
        controller's default shift); ``u[:n_inputs]``."""
        h = self.h
        h.seq = seq
        h.generation = self.generation
        h.shadow = mark
        h.n_inputs = n_inputs
        h.carried_hash = 0
        h.carried_at = 0
        h.carried_len = 0
        n_extra = n_inputs if extra else 0
        if state is None or len(state) + n_extra > msg.MAX_HANDOVER_STATES:
            h.design_hash = 0
            h.n_states = 0
        else:
            h.design_hash = self.design_hash
            k = len(state)
            for i in range(k):
                h.state[i] = state[i]
            for i in range(n_extra):
                h.state[k + i] = extra[i]
            h.n_states = k + n_extra
        if u is not None:
            for i in range(n_inputs):
                h.u[i] = u[i]
        self.outlet.publish(h)

    def connect(self):
        self.outlet.connect()

    def close(self):
        self.outlet.close()


def saved_state(h, design_hash):
    """The values a predecessor of this design handed over in ``h``, if
    it is one and every value is finite (law_setup.rs ``saved_state``)."""
    n = h.n_states
    if h.design_hash != design_hash or n > msg.MAX_HANDOVER_STATES:
        return None
    values = h.state[:n]
    for v in values:
        if v != v or v in (float("inf"), float("-inf")):
            return None
    return values
