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

import math
import sys
import time

from . import messages as msg
from . import realtime, transport
from .controller import Output
from .launch import RESTART, STANDBY
from .process import (
    InstanceProcess,
    WAKEUP_TIMEOUT_S,
    ActivationView,
    HandoverRing,
    LawError,
    PeerError,
    Standing,
    StateOut,
    await_peers,
    fingerprint,
    main_for,
    make_law,
    freeze_collector,
    saved_state,
    stop_requested,
)

#: Lockstep: how long a new instance waits for its predecessor's last state.
HANDOVER_WAIT_LOCKSTEP_NS = 2_000_000_000
#: Lockstep: how long to wait for the observer's estimate of a sample.
LOCKSTEP_ESTIMATE_WAIT_NS = 5_000_000_000

_MEASUREMENT = transport.channel("flexloop/measurement")
_ESTIMATE = transport.channel("flexloop/estimate")
_COMMAND = transport.channel("flexloop/command")
_STATE = transport.channel("flexloop/controller-state")
#: A shadow may fall this many samples behind and still step through all.
FOLLOW_DEPTH = _MEASUREMENT["subscriber_max_buffer_size"]

# The duty bookkeeping's old name (python/tests).
_Standing = Standing


def run(controller_class, argv=None):
    """Runs ``controller_class`` as the loop's controller, with the command
    line the supervisor gives (``sys.argv[1:]`` by default); exits the
    process with 0 on a clean end, 1 on an error, 2 on a usage error."""
    sys.exit(main(controller_class, sys.argv[1:] if argv is None else argv))


def main(controller_class, argv):
    """:func:`run` without the exit: the exit code."""
    return main_for("controller", controller_class, argv, _Process)


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


class _Process(InstanceProcess):
    PORTS = ("commands", "estimates", "states_out", "states_in", "measurements")

    def __init__(self, program, controller_class, args):
        self.program = program
        self.args = args
        self.generation = args.generation
        self.late = args.late
        self.settings, self.setup, self.law = make_law(program, controller_class, args)
        self.lockstep = self.settings.lockstep
        self.period_ns = self.settings.period_ns
        self.design_hash = fingerprint(
            controller_class, self.setup.params, self.settings.rate_hz
        )
        self.standing = Standing(self.generation, self.late, args.joining == STANDBY)
        self.handovers = HandoverRing()
        self.estimates_ring = _EstimateRing(FOLLOW_DEPTH)
        # Bumpless hand-over (shared/node controller.rs ``Takeover``).
        self.copied = False
        self.shadow_u = [0.0] * msg.MAX_INPUTS
        self.shadow_seq = None
        self.u = [0.0] * msg.MAX_INPUTS
        # The parts of the command the law last stepped.
        self.parts = CommandParts()
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
        self.activation = ActivationView(self.node)
        self.states_in = transport.Inlet(
            self.node, _STATE, msg.Handover, _STATE["loop_buffer_size"], listen=False
        )
        self.states_out = StateOut(self.node, _STATE, self.generation, self.design_hash)
        self.estimates = transport.Inlet(self.node, _ESTIMATE, msg.Estimate, FOLLOW_DEPTH)

        def ready():
            if self.measurements.publishers() >= 1 and self.estimates.publishers() >= 1:
                self.estimates_ring.take(self.estimates, self.activation.refresh())
                # A replacement joins a running loop: its estimates come
                # with the next sample.
                return self.estimates_ring.any() or self.late
            return False

        if not await_peers(
            ready,
            lambda: f"{self.measurements.publishers()} measurement publishers (plant), "
            f"{self.estimates.publishers()} estimate publishers (observer), "
            "no first estimate yet",
        ):
            return False
        # Before the command port opens: the plant's tick 0 follows it by 2 ms.
        freeze_collector()
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
            while self.states_in.receive_into(self.handovers.scratch):
                pass
        self.estimates.clear_events()
        while self.estimates.receive_into(self.estimates_ring.scratch):
            pass
        self.estimates_ring = _EstimateRing(FOLLOW_DEPTH)

    def _joined_late(self):
        # A standby keeps its priority: its commands are the plant's safe
        # action and must be on time.
        if self.args.joining == STANDBY:
            realtime.raise_priority(self.settings.realtime, cpu=False)

    def _report(self):
        if self.stepped:
            # What the process costs its CPU per sample, all included
            # (waits, ports, the law): the loop's budget is one period.
            cpu_s = time.process_time() - self.cpu_at_start
            self.program.say(
                f"generation {self.generation}: {self.stepped} samples stepped, "
                f"{self.commanded} commanded, {cpu_s / self.stepped * 1e6:.1f} µs of CPU per sample"
            )
        if self.law_skipped:
            self.program.say(
                f"generation {self.generation}: law skipped {self.law_skipped} samples, "
                f"the first after sample {self.first_law_gap}"
            )
        skipped = self.standing.skipped
        if self.stale_estimates + skipped > 0:
            self.program.say(
                f"generation {self.generation}: {self.stale_estimates} stale estimates, "
                f"{skipped} measurements skipped"
            )

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
        if duty == Standing.RETIRING:
            # Replaced at a boundary: the new instance owns this sample.
            return
        active = duty == Standing.ACTIVE
        ring = self.estimates_ring
        ring.take(self.estimates, activation)
        standby = duty == Standing.STANDBY
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
        if not active or was != Standing.ACTIVE:
            # (The active instance needs no one else's state: off its
            # round trip.)
            self.handovers.take(self.states_in, self.generation)
        activation = self.activation.current
        if was != Standing.ACTIVE and not self.copied:
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
        if was != Standing.ACTIVE:
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
            if stop_requested():
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
            self.program.say(f"generation {self.generation}: law stepped from sample {m.seq}")
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
        try:
            self.parts.take(u, m, out, self.n_inputs, law._offset)
        except (TypeError, IndexError, ValueError) as e:
            raise LawError(
                f"{type(law).__qualname__}.step at sample {m.seq} returned {u!r}: {e} "
                f"(a float, {self.n_inputs} floats or a flexloop.Output are commands)"
            ) from e

    def _publish_command(self, m, estimate, received_ns, u, flags):
        """Command ``u`` for ``m`` with the parts the law said; the active
        instance's (``flags`` 0) wakes the plant in lockstep."""
        c = self.command
        c.seq = m.seq
        c.tick_ns = m.tick_ns
        c.measurement_published_ns = m.published_ns
        c.received_ns = received_ns
        c.estimate_seq = estimate.seq
        c.estimate_published_ns = estimate.published_ns
        c.flags = (
            flags
            | (msg.Flags.STALE_ESTIMATE if m.seq > estimate.seq else 0)
            | (m.flags & msg.Flags.LOCKSTEP)
        )
        c.generation = self.generation
        c.n_inputs = self.n_inputs
        c.n_outputs = m.n_outputs
        self.parts.write(c, u, m, self.n_inputs, self.law.r)
        c.published_ns = time.monotonic_ns()
        self.commands.publish(c)
        if flags == 0:
            self.commanded += 1
            if self.lockstep:
                self.commands.notify()

    def _publish_state(self, seq, u, mark):
        """The law's state after ``seq`` (with the default shift's offset
        after it) and the command ``u``."""
        n = self.n_inputs
        self.states_out.publish(seq, mark, self.law.save_state(), self.law._offset, u, n)

    # ---- hand-over ----

    def _load(self, h):
        """Copies ``h`` into the law if it is of this design."""
        n = h.n_inputs
        if h.n_states < n or n != self.n_inputs:
            return False
        values = saved_state(h, self.design_hash)
        if values is None:
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
            self.program.say(
                f"generation {self.generation} active from sample {m.seq} without its "
                f"predecessor's state after sample {m.seq - 1}"
            )
        if last is not None:
            if self._load(last):
                self.copied = True
            elif self.shadow_seq == last.seq:
                # Another design: shift the output so that it continues the
                # old command at the sample both computed.
                # From what the law asked for before any clamp (the sum of
                # its parts when it gives them), as the Rust process does: a
                # shadow saturated at the limit would otherwise shift by the
                # wrong amount and step the actuator at the switch.
                own = self.parts.unclamped(self.shadow_u, self.n_inputs)
                delta = [last.u[i] - own[i] for i in range(self.n_inputs)]
                try:
                    self.law.shift_output(delta)
                except Exception as e:
                    raise LawError(
                        f"{type(self.law).__qualname__}.shift_output raised {e!r}"
                    ) from e
                self.program.say(
                    f"generation {self.generation} active from sample {m.seq}, output "
                    f"shifted by {' '.join(f'{d:.17g}' for d in delta)}"
                )
        if not self.copied:
            self._follow(m.seq, newest_too=True)



class CommandParts:
    """What a law's ``step`` returned, as a command and its parts for the
    record (shared/protocol ``Command``): a plain float or sequence is all
    feedback, with r the law's ``r`` and e_meas r - y; an :class:`Output`
    says its parts (preallocated: nothing is allocated per sample)."""

    def __init__(self):
        #: All of u is feedback, r and e_meas are the defaults.
        self.plain = True
        self.u_fb = [0.0] * msg.MAX_INPUTS
        self.u_ff = [0.0] * msg.MAX_INPUTS
        self.u_d = [0.0] * msg.MAX_INPUTS
        self.r_given = False
        self.r = [0.0] * msg.MAX_OUTPUTS
        self.e_given = False
        self.e_meas = [0.0] * msg.MAX_OUTPUTS

    def take(self, result, m, out, n, offset):
        """The command ``result`` for ``m`` into ``out[:n]``, its parts
        kept, the default shift's ``offset`` added to u (and to its
        feedback part); TypeError, IndexError or ValueError for what is
        no command."""
        kind = type(result)
        if (kind is float or kind is int) and n == 1:
            out[0] = float(result) + offset[0]
            self.plain = True
            return
        if not isinstance(result, Output):
            self.plain = True
            if isinstance(result, (str, bytes)):
                raise TypeError("a string is no command")
            for i in range(n):
                out[i] = float(result[i]) + offset[i]
            return
        fb = _fill(result.u_fb, n, self.u_fb, False)
        ff = _fill(result.u_ff, n, self.u_ff, False)
        d = _fill(result.u_d, n, self.u_d, False)
        if result.u is not None:
            _fill(result.u, n, out, False)
        elif fb or ff or d:
            for i in range(n):
                out[i] = self.u_fb[i] + self.u_ff[i] + self.u_d[i]
        else:
            raise ValueError("an Output with neither u nor any of its parts")
        n_outputs = m.n_outputs
        self.r_given = _fill(result.r, n_outputs, self.r, True)
        self.e_given = _fill(result.e_meas, n_outputs, self.e_meas, True)
        # Without parts all of u is feedback, as a plain u is.
        self.plain = not (fb or ff or d)
        for i in range(n):
            out[i] += offset[i]
            self.u_fb[i] += offset[i]

    def unclamped(self, u, n):
        """What the law last asked for before any clamp: the sum of its
        parts when it gave any (u_fb + u_ff + u_d), else ``u[:n]``."""
        if self.plain:
            return list(u[:n])
        sums = [self.u_fb[i] + self.u_ff[i] + self.u_d[i] for i in range(n)]
        if not any(self.u_fb[i] or self.u_ff[i] or self.u_d[i] for i in range(n)):
            return list(u[:n])
        return [v if math.isfinite(v) else u[i] for i, v in enumerate(sums)]

    def write(self, c, u, m, n, law_r):
        """Command ``u[:n]`` for ``m`` and the parts last taken into ``c``."""
        if self.plain:
            for i in range(n):
                c.u[i] = c.u_fb[i] = u[i]
                c.u_ff[i] = c.u_d[i] = 0.0
            r_given = e_given = False
        else:
            fb, ff, d = self.u_fb, self.u_ff, self.u_d
            for i in range(n):
                c.u[i] = u[i]
                c.u_fb[i] = fb[i]
                c.u_ff[i] = ff[i]
                c.u_d[i] = d[i]
            r_given, e_given = self.r_given, self.e_given
        r = self.r if r_given else law_r
        e_meas, y = self.e_meas, m.y
        for i in range(m.n_outputs):
            c.r[i] = r[i]
            c.e_meas[i] = e_meas[i] if e_given else r[i] - y[i]


def _fill(value, n, dest, zero_rest):
    """Copies ``value`` (a float for the first entry, or a sequence of at
    least ``n``) into ``dest[:n]``; False (and zeros) when it is None.
    With ``zero_rest`` a float fills the first entry and zeros the rest;
    without, a float is only for ``n`` 1."""
    if value is None:
        for i in range(n):
            dest[i] = 0.0
        return False
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if n != 1 and not zero_rest:
            raise ValueError(f"one float where {n} are due")
        dest[0] = float(value)
        for i in range(1, n):
            dest[i] = 0.0
        return True
    if len(value) < n:
        raise IndexError(f"{len(value)} values where {n} are due")
    for i in range(n):
        dest[i] = float(value[i])
    return True
