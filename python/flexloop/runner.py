"""A controller process's life, as shared/node's controller and instance
modules live it, around a user's :class:`flexloop.Controller`.

- Start-up: load the scenario and the law, lock memory, open the ports
  (measurements, estimates, activation, states in and out), wait for the
  plant and the observer, open the command port last (its appearance tells
  the plant the chain is ready for tick 0: the start-up handshake).
- Each wake-up: drain the measurements; the activation says which
  generation owns the newest (``Activation.controller_for``). A shadow
  steps its law through every measurement in order and publishes its
  state marked FOLLOWING (the supervisor announces a boundary once it sees
  one); named for the boundary, it moves to the loop's CPU and priority;
  at its first owned sample it takes over: it copies the predecessor's
  state (same design) or shifts its output by the predecessor's command
  minus its own at the last sample both computed (bumpless), then
  publishes one command per sample (notifying the plant in lockstep) and
  its state marked ACTIVE after each.
- It ends when another generation owns the samples (replaced: an exec
  controller exits then), with the plant's end of run, or on SIGTERM or
  SIGINT.
"""

import ctypes
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
from .launch import (
    AT_START,
    RESTART,
    STANDBY,
    ScenarioError,
    Setup,
    UsageError,
    load_settings,
    parse_args,
)

PROGRAM = "flexloop-controller"
#: How long start-up waits for the plant and the observer (shared/node lib.rs).
PEER_TIMEOUT_S = 20.0
#: Lockstep: how long a new instance waits for its predecessor's last state.
HANDOVER_WAIT_LOCKSTEP_NS = 2_000_000_000
#: Lockstep: how long to wait for the observer's estimate of a sample.
LOCKSTEP_ESTIMATE_WAIT_NS = 5_000_000_000
#: How long one wait for a measurement lasts before the loop looks at the
#: shutdown flag again.
WAKEUP_TIMEOUT_S = 0.1

_MEASUREMENT = transport.channel("flexloop/measurement")
_ESTIMATE = transport.channel("flexloop/estimate")
_COMMAND = transport.channel("flexloop/command")
_STATE = transport.channel("flexloop/controller-state")
_ACTIVATION = transport.channel("flexloop/activation")
#: A shadow may fall this many samples behind and still step through all.
FOLLOW_DEPTH = _MEASUREMENT["subscriber_max_buffer_size"]


class PeerError(Exception):
    """Another process did not show up, or went silent."""


class LawError(Exception):
    """The user's controller raised, or returned what is no command."""


_stop = False


def _request_stop(_signum, _frame):
    global _stop
    _stop = True


def _eprint(text):
    print(f"{PROGRAM}: {text}", file=sys.stderr, flush=True)


def run(controller_class, argv=None):
    """Runs ``controller_class`` as the loop's controller, with the command
    line the supervisor gives (``sys.argv[1:]`` by default); exits the
    process with 0 on a clean end, 1 on an error, 2 on a usage error."""
    sys.exit(main(controller_class, sys.argv[1:] if argv is None else argv))


def main(controller_class, argv):
    """:func:`run` without the exit: the exit code."""
    try:
        args = parse_args(argv)
    except UsageError as e:
        _eprint(f"usage: {e}")
        return 2
    try:
        msg.check_against_wire()
    except msg.WireMismatch as e:
        _eprint(f"this flexloop package does not match its wire.json: {e}")
        return 1
    signal.signal(signal.SIGTERM, _request_stop)
    signal.signal(signal.SIGINT, _request_stop)
    try:
        _Process(controller_class, args).serve()
    except (ScenarioError, transport.TransportError, PeerError) as e:
        _eprint(str(e))
        return 1
    except LawError as e:
        _eprint(str(e))
        traceback.print_exception(e.__cause__ or e, file=sys.stderr)
        return 1
    finally:
        realtime.step_down()
    return 0


def _fingerprint(controller_class, params, rate_hz):
    """The design's fingerprint: a replacement copies state only into an
    identical design (class, its file, parameters, rate)."""
    try:
        where = os.path.basename(inspect.getfile(controller_class))
    except TypeError:
        where = ""
    text = f"{where}:{controller_class.__qualname__}|{params.canonical()}|{rate_hz!r}"
    digest = hashlib.blake2b(text.encode(), digest_size=8).digest()
    # Never 0: 0 marks "no state to hand over".
    return int.from_bytes(digest, "little") | 1


class _Standing:
    """An instance's duty sample by sample (shared/node duty.rs ``Standing``)."""

    SHADOW, STANDBY, ACTIVE, RETIRING = "shadow", "standby", "active", "retiring"

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


class _EstimateRing:
    """The last estimates by sequence number (the controller needs the one
    for its tick, not merely the newest); filled by swapping preallocated
    structures, never by allocating."""

    def __init__(self, size):
        self.size = size
        self.slots = [msg.Estimate() for _ in range(size)]
        self.valid = [False] * size
        self.scratch = msg.Estimate()

    def take(self, inlet, activation):
        inlet.clear_events()
        while inlet.receive_into(self.scratch):
            e = self.scratch
            if e.generation != activation.observer_for(e.seq):
                continue
            slot = e.seq % self.size
            self.slots[slot], self.scratch = e, self.slots[slot]
            self.valid[slot] = True

    def any(self):
        return any(self.valid)

    def find(self, seq):
        slot = seq % self.size
        e = self.slots[slot]
        return e if self.valid[slot] and e.seq == seq else None

    def newest_before(self, seq):
        best = None
        for e, valid in zip(self.slots, self.valid):
            if valid and e.seq < seq and (best is None or e.seq > best.seq):
                best = e
        return best


class _HandoverRing:
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


class _ActivationView:
    """The newest activation (polled each sample: no wake-up)."""

    def __init__(self, node):
        self.inlet = transport.Inlet(
            node, _ACTIVATION, msg.Activation, _ACTIVATION["loop_buffer_size"], listen=False
        )
        self.current = msg.Activation()
        self.scratch = msg.Activation()

    def refresh(self):
        while self.inlet.receive_into(self.scratch):
            if self.scratch.published_ns >= self.current.published_ns:
                self.current, self.scratch = self.scratch, self.current
        return self.current


class _Process:
    def __init__(self, controller_class, args):
        self.args = args
        self.generation = args.generation
        self.late = args.joining != AT_START
        self.settings = load_settings(args)
        self.lockstep = self.settings.lockstep
        self.period_ns = self.settings.period_ns
        setup = Setup(self.settings, args.own)
        params = setup.params
        try:
            self.law = controller_class(setup)
        except ScenarioError:
            raise
        except Exception as e:
            raise LawError(f"{controller_class.__qualname__}: cannot be made: {e!r}") from e
        params.check_all_read()
        self.design_hash = _fingerprint(controller_class, params, self.settings.rate_hz)
        self.standing = _Standing(self.generation, self.late, args.joining == STANDBY)
        self.handovers = _HandoverRing()
        self.estimates_ring = _EstimateRing(FOLLOW_DEPTH)
        # Bumpless hand-over (shared/node controller.rs ``Takeover``).
        self.copied = False
        self.shadow_u = [0.0] * msg.MAX_INPUTS
        self.shadow_seq = None
        self.u = [0.0] * msg.MAX_INPUTS
        self.n_inputs = 0
        self.first_stepped = None
        self.stale_estimates = 0
        self.stepped = 0
        self.commanded = 0
        self.last_stepped = None
        self.law_skipped = 0
        self.first_law_gap = None
        self.end_of_run = False
        self.backlog = [msg.Measurement() for _ in range(FOLLOW_DEPTH + 1)]
        self.command = msg.Command()
        self.state = msg.Handover()

    # ---- start-up ----

    def _open(self):
        rt = self.settings.realtime
        # Locked before the ports exist, so their memory is populated now.
        realtime.lock_memory(rt)
        realtime.set_timer_slack(rt)
        domain = transport.Domain(self.args.prefix)
        self.node = domain.node("controller")
        self.measurements = transport.Inlet(
            self.node, _MEASUREMENT, msg.Measurement, FOLLOW_DEPTH
        )
        self.activation = _ActivationView(self.node)
        self.states_in = transport.Inlet(
            self.node, _STATE, msg.Handover, _STATE["loop_buffer_size"], listen=False
        )
        self.states_out = transport.Outlet(self.node, _STATE, msg.Handover)
        self.estimates = transport.Inlet(self.node, _ESTIMATE, msg.Estimate, FOLLOW_DEPTH)
        since = time.monotonic()
        while True:
            if self.measurements.publishers() >= 1 and self.estimates.publishers() >= 1:
                self.estimates_ring.take(self.estimates, self.activation.refresh())
                # A replacement joins a running loop: its estimates come
                # with the next sample.
                if self.estimates_ring.any() or self.late:
                    break
            if _stop:
                return False
            if time.monotonic() - since > PEER_TIMEOUT_S:
                raise PeerError(
                    f"peers did not connect within {PEER_TIMEOUT_S:.0f} s: "
                    f"{self.measurements.publishers()} measurement publishers (plant), "
                    f"{self.estimates.publishers()} estimate publishers (observer), "
                    "no first estimate yet"
                )
            time.sleep(0.002)
        # No collector pauses inside the loop: everything long-lived exists
        # now, and the per-sample path makes no cycles. Done before the
        # command port opens: the plant's tick 0 follows it by 2 ms.
        gc.collect()
        gc.freeze()
        gc.disable()
        # The command port opens last: its appearance tells the plant that
        # the chain is ready for tick 0.
        self.commands = transport.Outlet(self.node, _COMMAND, msg.Command)
        self.commands.connect()
        self.states_out.connect()
        return True

    def _drop_stale(self):
        """A late joiner drops what queued up before it joined (a restart
        keeps the states: its dead predecessor's last ones are among them)."""
        self.measurements.clear_events()
        while self.measurements.receive_into(self.backlog[0]):
            pass
        if self.args.joining != RESTART:
            while self.states_in.receive_into(self.state):
                pass
        self.estimates.clear_events()
        while self.estimates.receive_into(self.estimates_ring.scratch):
            pass
        self.estimates_ring = _EstimateRing(FOLLOW_DEPTH)

    def serve(self):
        started = time.monotonic()
        if not self._open():
            return
        rt = self.settings.realtime
        try:
            if self.late:
                self._drop_stale()
                # Follows off the loop's CPU, without priority, until named;
                # a standby keeps its priority: its commands are the plant's
                # safe action and must be on time.
                realtime.avoid_loop_cpu(rt)
                if self.args.joining == STANDBY:
                    realtime.raise_priority(rt, cpu=False)
                _eprint(
                    f"start-up {(time.monotonic() - started) * 1e3:.1f} ms, "
                    f"{time.process_time() * 1e3:.1f} ms of CPU"
                )
            else:
                realtime.raise_priority(rt)
            self._loop()
        finally:
            gc.enable()
            realtime.step_down()
            self._report()
            self._close()

    def _loop(self):
        self.cpu_at_start = time.process_time()
        measurements = self.measurements
        while not self.end_of_run and self.standing.duty != _Standing.RETIRING and not _stop:
            if measurements.has_samples():
                measurements.clear_events()
            else:
                try:
                    measurements.wait(WAKEUP_TIMEOUT_S)
                except Exception:
                    if _stop:
                        return
                    raise
            self._on_wakeup()

    def _report(self):
        if self.stepped:
            # What the process costs its CPU per sample, all included
            # (waits, ports, the law): the loop's budget is one period.
            cpu_s = time.process_time() - self.cpu_at_start
            _eprint(
                f"generation {self.generation}: {self.stepped} samples stepped, "
                f"{self.commanded} commanded, {cpu_s / self.stepped * 1e6:.1f} µs of CPU per sample"
            )
        if self.law_skipped:
            _eprint(
                f"generation {self.generation}: law skipped {self.law_skipped} samples, "
                f"the first after sample {self.first_law_gap}"
            )
        skipped = self.standing.skipped
        if self.stale_estimates + skipped > 0:
            _eprint(
                f"generation {self.generation}: {self.stale_estimates} stale estimates, "
                f"{skipped} measurements skipped"
            )

    def _close(self):
        for port in ("commands", "estimates", "states_out", "states_in", "measurements"):
            p = getattr(self, port, None)
            if p is not None:
                p.close()
        if getattr(self, "activation", None) is not None:
            self.activation.inlet.close()
        self.node = None
        gc.collect()

    # ---- each wake-up ----

    def _on_wakeup(self):
        backlog = self.backlog
        n = 0
        while self.measurements.receive_into(backlog[n]):
            if n == FOLLOW_DEPTH:
                # Keep the newest FOLLOW_DEPTH (the queue holds no more).
                backlog.append(backlog.pop(0))
            else:
                n += 1
        if n == 0:
            return
        m = backlog[n - 1]
        received_ns = time.monotonic_ns()
        activation = self.activation.refresh()
        duty, was, raise_priority = self.standing.on_sample(
            m.seq,
            backlog[0].seq,
            activation.controller_for(m.seq),
            activation.controller_generation,
            n == 1,
        )
        if raise_priority:
            realtime.raise_priority(self.settings.realtime)
        if duty == _Standing.RETIRING:
            # Replaced at a boundary: the new instance owns this sample.
            return
        active = duty == _Standing.ACTIVE
        ring = self.estimates_ring
        ring.take(self.estimates, activation)
        standby = duty == _Standing.STANDBY
        if (
            (active or standby or not self.copied)
            and ring.find(m.seq) is None
            and not self._await_estimate(m, received_ns)
        ):
            return
        estimate = ring.find(m.seq) or ring.newest_before(m.seq)
        if estimate is None:
            # No estimate at all yet (the observer not started): skip.
            return
        if not active or was != _Standing.ACTIVE:
            # (The active instance needs no one else's state: off its
            # round trip.)
            self.handovers.take(self.states_in, self.generation)
        activation = self.activation.current
        if was != _Standing.ACTIVE and not self.copied:
            # A law of its own steps through every sample it missed.
            for i in range(n - 1):
                older = backlog[i]
                if activation.controller_for(older.seq) == self.generation:
                    continue
                e = ring.find(older.seq) or ring.newest_before(older.seq)
                if e is not None:
                    self._follow(older.seq, newest_too=False)
                    self._step(older, e, self.shadow_u)
                    self.shadow_seq = older.seq
        if not active:
            self._follow(m.seq, newest_too=True)
            self._step(m, estimate, self.shadow_u)
            self.shadow_seq = m.seq
            if standby:
                # For the plant's safe action only (it applies it when the
                # active controller falls silent).
                self._publish_command(m, estimate, received_ns, self.shadow_u, msg.Flags.STANDBY)
            # Following once a handed-over state is there (the supervisor
            # announces the boundary once it sees this instance follow).
            if self.handovers.newest() is not None:
                self._publish_state(m.seq, self.shadow_u, msg.HandoverMark.FOLLOWING)
            self.end_of_run |= bool(m.flags & msg.Flags.END_OF_RUN)
            return
        if was != _Standing.ACTIVE:
            self._take_over(m)
        self._step(m, estimate, self.u)
        self._publish_command(m, estimate, received_ns, self.u, 0)
        self._publish_state(m.seq, self.u, msg.HandoverMark.ACTIVE)
        self.end_of_run |= bool(m.flags & msg.Flags.END_OF_RUN)

    def _await_estimate(self, m, received_ns):
        """Waits for the estimate of ``m``: in lockstep as long as the
        observer may take, in realtime until half a period after the tick.
        False: a shutdown came."""
        if self.lockstep:
            deadline = received_ns + LOCKSTEP_ESTIMATE_WAIT_NS
        else:
            deadline = m.tick_ns + self.period_ns // 2
        ring = self.estimates_ring
        while True:
            now = time.monotonic_ns()
            if now >= deadline:
                self.stale_estimates += 1
                break
            if not self.estimates.has_samples():
                self.estimates.wait(min((deadline - now) / 1e9, WAKEUP_TIMEOUT_S))
            # Refreshed: an observer's boundary may be announced meanwhile.
            ring.take(self.estimates, self.activation.refresh())
            if ring.find(m.seq) is not None:
                break
            if _stop:
                return False
        if self.lockstep and ring.find(m.seq) is None and not self.late:
            raise PeerError(f"lockstep: no estimate for tick {m.seq} from the observer")
        return True

    def _step(self, m, estimate, out):
        """The law's command for ``m`` into ``out`` (with the offset a
        default bumpless shift left)."""
        if self.first_stepped is None:
            self.first_stepped = m.seq
            self.n_inputs = n_inputs = m.n_inputs
            if not 1 <= n_inputs <= msg.MAX_INPUTS:
                raise PeerError(f"measurement {m.seq}: {n_inputs} inputs")
            # The sample the law's history starts at (tests recompute the
            # law from here).
            _eprint(f"generation {self.generation}: law stepped from sample {m.seq}")
        law = self.law
        self.stepped += 1
        if self.last_stepped is not None and m.seq != self.last_stepped + 1:
            # A sample the law never saw (a shadow more than a queue
            # behind, an active instance answering only the newest).
            if self.law_skipped == 0:
                self.first_law_gap = self.last_stepped
            self.law_skipped += m.seq - self.last_stepped - 1
        self.last_stepped = m.seq
        try:
            u = law.step(m, estimate)
        except Exception as e:
            raise LawError(f"{type(law).__qualname__}.step at sample {m.seq} raised {e!r}") from e
        offset = law._offset
        if type(u) is float and self.n_inputs == 1:
            out[0] = u + offset[0]
            return
        try:
            for i in range(self.n_inputs):
                out[i] = float(u[i]) + offset[i]
        except (TypeError, IndexError, ValueError) as e:
            raise LawError(
                f"{type(law).__qualname__}.step at sample {m.seq} returned {u!r}, "
                f"not a float or {self.n_inputs} floats"
            ) from e

    def _publish_command(self, m, estimate, received_ns, u, flags):
        """Command ``u`` for ``m``; the active instance's (``flags`` 0)
        wakes the plant in lockstep."""
        c = self.command
        c.seq = m.seq
        c.tick_ns = m.tick_ns
        c.measurement_published_ns = m.published_ns
        c.received_ns = received_ns
        c.estimate_seq = estimate.seq
        c.estimate_published_ns = estimate.published_ns
        c.flags = flags | (msg.Flags.STALE_ESTIMATE if estimate.seq != m.seq else 0)
        c.generation = self.generation
        c.n_inputs = self.n_inputs
        c.n_outputs = n_outputs = m.n_outputs
        for i in range(self.n_inputs):
            c.u[i] = u[i]
            c.u_fb[i] = u[i]
        r = self.law.r
        for i in range(n_outputs):
            c.r[i] = r[i]
            c.e_meas[i] = r[i] - m.y[i]
        c.published_ns = time.monotonic_ns()
        self.commands.publish(c)
        if flags == 0:
            self.commanded += 1
            if self.lockstep:
                self.commands.notify()

    def _publish_state(self, seq, u, mark):
        h = self.state
        h.seq = seq
        h.generation = self.generation
        h.shadow = mark
        n = self.n_inputs
        h.n_inputs = n
        h.carried_hash = 0
        h.carried_at = 0
        h.carried_len = 0
        state = self.law.save_state()
        if state is None or len(state) + n > msg.MAX_HANDOVER_STATES:
            h.design_hash = 0
            h.n_states = 0
        else:
            h.design_hash = self.design_hash
            k = len(state)
            for i in range(k):
                h.state[i] = state[i]
            offset = self.law._offset
            for i in range(n):
                h.state[k + i] = offset[i]
            h.n_states = k + n
        for i in range(n):
            h.u[i] = u[i]
        self.states_out.publish(h)

    # ---- hand-over ----

    def _load(self, h):
        """Copies ``h`` into the law if it is of this design."""
        n = h.n_inputs
        if (
            h.design_hash != self.design_hash
            or h.n_states < n
            or h.n_states > msg.MAX_HANDOVER_STATES
            or n != self.n_inputs
        ):
            return False
        values = h.state[: h.n_states]
        if any(v != v or v in (float("inf"), float("-inf")) for v in values):
            return False
        k = h.n_states - n
        self.law.load_state(values[:k])
        offset = self.law._offset
        for i in range(n):
            offset[i] = values[k + i]
        return True

    def _follow(self, seq, newest_too):
        """Before sample ``seq``: copy the active state after seq-1 (same
        design). With ``newest_too``, a restart takes the newest state once."""
        h = self.handovers.find(seq - 1)
        if h is not None:
            self.copied |= self._load(h)
            return
        if self.copied or not newest_too:
            return
        h = self.handovers.newest()
        if h is not None and h.seq < seq and self._load(h):
            self.copied = True

    def _take_over(self, m):
        """``m`` is this instance's first sample: continue the old command."""
        if self.lockstep:
            deadline = time.monotonic_ns() + HANDOVER_WAIT_LOCKSTEP_NS
        else:
            deadline = m.tick_ns + self.period_ns // 4
        restart = self.args.joining == RESTART
        while (
            not restart
            and m.seq > 0
            and self.handovers.find(m.seq - 1) is None
            and time.monotonic_ns() < deadline
        ):
            time.sleep(20e-6)
            self.handovers.take(self.states_in, self.generation)
        last = self.handovers.find(m.seq - 1) if m.seq > 0 else None
        if not restart and m.seq > 0 and last is None:
            _eprint(
                f"generation {self.generation} active from sample {m.seq} without its "
                f"predecessor's state after sample {m.seq - 1}"
            )
        if last is not None:
            if self._load(last):
                self.copied = True
            elif self.shadow_seq == last.seq:
                # Another design: shift the output so that it continues the
                # old command at the sample both computed.
                delta = [last.u[i] - self.shadow_u[i] for i in range(self.n_inputs)]
                try:
                    self.law.shift_output(delta)
                except Exception as e:
                    raise LawError(
                        f"{type(self.law).__qualname__}.shift_output raised {e!r}"
                    ) from e
                _eprint(
                    f"generation {self.generation} active from sample {m.seq}, output "
                    f"shifted by {' '.join(f'{d:.17g}' for d in delta)}"
                )
        if not self.copied:
            self._follow(m.seq, newest_too=True)
