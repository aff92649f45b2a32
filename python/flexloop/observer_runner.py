"""An observer process's life, as shared/node's observer and instance
modules live it, around a user's :class:`flexloop.Observer`.

- Start-up: load the scenario and the law, lock memory, open the ports
  (the measurements, woken by the plant's observer wake-up; the activation;
  states in and out; a restart's measurement replay), wait for the plant,
  open the estimate port. The first instance publishes the estimate for
  tick 0 (``initial``) once the controller and the logger read it (the
  start-up handshake: the controller takes it as the sign that the
  observer is ready).
- Each measurement, in order (a predictor must not skip one): the
  activation says which generation owns the estimate it yields
  (``Activation.observer_for(seq + 1)``). The active instance publishes
  the estimate for tick k+1 and its state marked ACTIVE; a shadow copies
  the active instance's state (same design) or steps its own law, and
  publishes its state marked FOLLOWING once it has seen a handed-over one
  (the supervisor announces a boundary then); named, it moves to the
  loop's CPU and priority.
- A restart takes its dead predecessor's last state (the supervisor hands
  it on) and steps through the supervisor's replay of the measurements
  since, merged with the live ones held meanwhile, reporting its progress
  (CATCHING_UP); in lockstep it publishes the estimates it owns as it goes.
- It ends when another generation owns the estimates (replaced: it exits),
  with the plant's end of run, or on SIGTERM or SIGINT.
"""

import ctypes
import sys
import time

from . import messages as msg
from . import realtime, transport
from .launch import RESTART
from .observer import Estimated
from .process import (
    InstanceProcess,
    ActivationView,
    HandoverRing,
    LawError,
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

_MEASUREMENT = transport.channel("flexloop/measurement")
_REPLAY = transport.channel("flexloop/measurement-replay")
_WAKEUP = transport.channel("flexloop/measurement-observer")
_ESTIMATE = transport.channel("flexloop/estimate")
_STATE = transport.channel("flexloop/observer-state")

#: How long a restart waits for its dead predecessor's state while the
#: loop runs (shared/node observer.rs RESTART_STATE_WAIT).
RESTART_STATE_WAIT_S = 1.0
#: How long a restart waits for the next replayed measurement before it
#: goes on from where it got (CATCH_UP_TIMEOUT).
CATCH_UP_TIMEOUT_S = 1.0
#: Live samples a catching-up observer holds back (replay.rs STASH).
STASH = 1024

_MEASUREMENT_SIZE = ctypes.sizeof(msg.Measurement)
_ESTIMATE_SIZE = ctypes.sizeof(msg.Estimate)


def run_observer(observer_class, argv=None):
    """Runs ``observer_class`` as the loop's observer, with the command
    line the supervisor gives (``sys.argv[1:]`` by default); exits the
    process with 0 on a clean end, 1 on an error, 2 on a usage error."""
    sys.exit(main(observer_class, sys.argv[1:] if argv is None else argv))


def main(observer_class, argv):
    """:func:`run_observer` without the exit: the exit code."""
    return main_for("observer", observer_class, argv, _Process)


def _copy(dst, src):
    ctypes.memmove(ctypes.addressof(dst), ctypes.addressof(src), _MEASUREMENT_SIZE)


class _CatchUp:
    """The merge of replayed and live measurements after a handed-over
    state (shared/node replay.rs ``CatchUp``), in preallocated slots."""

    STEP, SKIP, GAP = "step", "skip", "gap"

    def __init__(self, state_seq, stash):
        self.next = state_seq + 1
        self.stash = stash
        self.head = 0
        self.len = 0

    def replayed(self, m):
        if m.seq < self.next:
            return self.SKIP
        if m.seq > self.next:
            return self.GAP
        self.next += 1
        return self.STEP

    def hold_live(self, m):
        if self.len == STASH:
            # The replay is slower than the loop: the oldest held sample
            # goes, and the replay brings it instead.
            self.head = (self.head + 1) % STASH
            self.len -= 1
        _copy(self.stash[(self.head + self.len) % STASH], m)
        self.len += 1

    def reached_live(self):
        while self.len > 0 and self.stash[self.head].seq < self.next:
            self.head = (self.head + 1) % STASH
            self.len -= 1
        return self.len > 0 and self.stash[self.head].seq == self.next

    def take_held(self):
        if self.len == 0:
            return None
        m = self.stash[self.head]
        self.head = (self.head + 1) % STASH
        self.len -= 1
        self.next = max(self.next, m.seq + 1)
        return m


class _CaughtUp:
    """What a catch-up did, for the stderr file."""

    def __init__(self, state_seq, replayed, last_seq, incomplete, end_of_run):
        self.state_seq, self.replayed, self.last_seq = state_seq, replayed, last_seq
        self.incomplete, self.end_of_run = incomplete, end_of_run

    def __str__(self):
        if self.incomplete is None:
            return (
                f"took over the state after sample {self.state_seq} and replayed "
                f"{self.replayed} measurements up to the live sample {self.last_seq}"
            )
        return (
            f"took over the state after sample {self.state_seq}, replayed {self.replayed} "
            f"measurements, then {self.incomplete}: going on from sample {self.last_seq} "
            "with a hole in between"
        )


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _Process(InstanceProcess):
    PORTS = ("estimates", "states_out", "states_in", "replay", "measurements")

    def __init__(self, program, observer_class, args):
        self.program = program
        self.args = args
        self.generation = args.generation
        self.late = args.late
        self.restart = args.joining == RESTART
        self.settings, self.setup, self.law = make_law(program, observer_class, args)
        self.lockstep = self.settings.lockstep
        self.design_hash = fingerprint(observer_class, self.setup.params, self.settings.rate_hz)
        self.standing = Standing(self.generation, self.late)
        self.handovers = HandoverRing()
        # Whether the law holds a state handed over (not its initial one).
        self.copied = False
        # After a restart without a continuous state: estimates for ticks
        # before this one are flagged converging (None: none are).
        self.converging_until = None
        self.converging_for = None
        self.joined_running_loop = False
        # A restart (or a loop with warm spares, as the built-in observer)
        # queues what arrives while it catches up, and reads the replay.
        self.may_restart = self.restart or self.settings.warm_spares
        # The controller, its warm spare and the logger.
        self.expected_readers = 1 + int(self.settings.warm_spares) + int(self.settings.logger)
        self.estimate = msg.Estimate()
        self.shadow_estimate = msg.Estimate()
        self.m = msg.Measurement()
        self.replayed_m = msg.Measurement()
        self.live_m = msg.Measurement()
        self.stash = None
        self.end_of_run = False
        self.first_stepped = None
        self.stepped = 0
        self.published = 0
        self.replay = None

    # ---- start-up ----

    def _open(self):
        rt = self.settings.realtime
        # Locked before the ports exist, so their memory is populated now.
        realtime.lock_memory(rt)
        realtime.set_timer_slack(rt)
        domain = transport.Domain(self.args.prefix)
        self.node = domain.node("observer")
        # A restart's queue holds what arrives while it catches up: 51 ms
        # at 10 kHz.
        depth = _MEASUREMENT["logger_buffer_size" if self.may_restart else "loop_buffer_size"]
        self.measurements = transport.Inlet(
            self.node, _MEASUREMENT, msg.Measurement, depth, listen=False, woken_by=_WAKEUP
        )
        self.activation = ActivationView(self.node)
        self.states_in = transport.Inlet(
            self.node, _STATE, msg.Handover, _STATE["loop_buffer_size"], listen=False
        )
        self.states_out = StateOut(self.node, _STATE, self.generation, self.design_hash)
        if self.may_restart:
            self.replay = transport.Inlet(
                self.node, _REPLAY, msg.Measurement, _REPLAY["loop_buffer_size"], listen=False
            )
        if not await_peers(
            lambda: self.measurements.publishers() >= 1,
            lambda: "no measurement publisher (plant)",
        ):
            return False
        freeze_collector()
        # Opened only now: the controller takes the first estimate as the
        # sign that the observer is connected and ready.
        self.estimates = transport.Outlet(self.node, _ESTIMATE, msg.Estimate)
        self.estimates.connect()
        self.states_out.connect()
        return True

    def _drop_stale(self):
        """A late joiner drops what queued up before it joined (a restart
        keeps the states: its dead predecessor's last ones are among them)."""
        self.measurements.clear_events()
        while self.measurements.receive_into(self.m):
            pass
        if not self.restart:
            while self.states_in.receive_into(self.handovers.scratch):
                pass

    def _measured_within(self, wait_s):
        """Whether a measurement arrives within ``wait_s``."""
        until = time.monotonic() + wait_s
        while True:
            if self.measurements.has_samples():
                return True
            if time.monotonic() >= until or stop_requested():
                return False
            time.sleep(0.001)

    def _enter(self):
        """The rest of the handshake. A replacement for an observer that
        died before tick 0 starts the loop as the first one does: no
        measurement for 200 ms means the loop has not started. A restart
        also knows it by the state the supervisor hands on. False: a
        shutdown came first."""
        loop_running = False
        if self.late:
            since = time.monotonic()
            measured = False
            while True:
                if self.restart:
                    self.handovers.take(self.states_in, self.generation)
                    if self.handovers.newest() is not None:
                        loop_running = True
                        break
                if measured:
                    time.sleep(0.001)
                else:
                    measured = self._measured_within(0.005 if self.restart else 0.2)
                waited = time.monotonic() - since
                if measured and (not self.restart or waited >= RESTART_STATE_WAIT_S):
                    loop_running = True
                    break
                if (not measured and waited >= 0.2) or stop_requested():
                    break
        self.joined_running_loop = loop_running
        if loop_running:
            return True
        estimates, readers = self.estimates, self.expected_readers
        if not await_peers(
            lambda: estimates.subscribers() >= readers,
            lambda: f"{estimates.subscribers()} of {readers} estimate readers "
            "(controller, its spare, logger)",
        ):
            return False
        # The estimate for tick 0 is the initial state; history keeps it
        # for a controller that connects later.
        e = self.estimate
        self._write(self._call("initial"), e, None)
        e.generation = self.generation
        e.published_ns = time.monotonic_ns()
        estimates.publish(e)
        estimates.notify()
        return True

    def _resume(self):
        """A restart owns the estimates its dead predecessor left unserved
        at once: it takes over the predecessor's last state and steps
        through the measurements since, without waiting for a live one (in
        lockstep none comes: the loop waits for the estimate it owes). In
        lockstep it publishes the estimates it owns as it goes."""
        if not self.restart or self.replay is None:
            return
        h = self.handovers.newest()
        if h is None or not self._load(h):
            # Nothing of its predecessor to go on from: its own initial
            # state, on a loop that has moved since tick 0.
            if self.joined_running_loop:
                self._start_converging()
            return
        self.copied = True
        published = [False]

        def stepped(m, e):
            if self.lockstep and (
                self.activation.refresh().observer_for(m.seq + 1) == self.generation
            ):
                now = time.monotonic_ns()
                e.generation = self.generation
                e.received_ns = now
                e.published_ns = now
                self.estimates.publish(e)
                self.estimates.notify()
                self.published += 1
                published[0] = True

        self.standing.replaying()
        caught = self._catch_up(h.seq, None, stepped)
        self.program.say(str(caught))
        if caught.incomplete is not None:
            self._start_converging()
        self.standing.replayed(
            caught.last_seq, Standing.ACTIVE if published[0] else Standing.SHADOW
        )
        self.end_of_run |= caught.end_of_run
        self._publish_state(caught.last_seq)

    def _report(self):
        if self.stepped:
            cpu_s = time.process_time() - self.cpu_at_start
            self.program.say(
                f"generation {self.generation}: {self.stepped} measurements stepped, "
                f"{self.published} estimates published, "
                f"{cpu_s / self.stepped * 1e6:.1f} µs of CPU per measurement"
            )
        skipped = self.standing.skipped
        if skipped > 0:
            self.program.say(
                f"generation {self.generation}: {skipped} measurements never arrived"
            )

    # ---- each measurement ----

    def _on_wakeup(self):
        m = self.m
        # Every measurement, in order: a predictor must not skip one.
        while self.measurements.receive_into(m):
            received_ns = time.monotonic_ns()
            activation = self.activation.refresh()
            duty, _, raise_priority = self.standing.on_sample(
                m.seq,
                m.seq,
                activation.observer_for(m.seq + 1),
                activation.observer_generation,
                True,
            )
            if raise_priority:
                realtime.raise_priority(self.settings.realtime)
            if duty == Standing.RETIRING:
                # Replaced: the new instance publishes from here on.
                return
            if duty == Standing.ACTIVE:
                e = self.estimate
                self._step(m, e)
                e.generation = self.generation
                e.received_ns = received_ns
                e.published_ns = time.monotonic_ns()
                self.estimates.publish(e)
                self.estimates.notify()
                self.published += 1
                self._publish_state(m.seq)
            else:
                self._follow(m)
            self.end_of_run |= bool(m.flags & msg.Flags.END_OF_RUN)

    def _follow(self, m):
        """Shadow: follow the active instance's state through measurement
        ``m``, publish no estimate."""
        self.handovers.take(self.states_in, self.generation)
        h = self.handovers.find(m.seq - 1)
        if h is not None:
            self.copied |= self._load(h)
        elif not self.copied:
            h = self.handovers.newest()
            if h is not None and h.seq < m.seq and self._load(h):
                self.copied = True
                if h.seq + 1 < m.seq and self.restart and self.replay is not None:
                    # A restart: the dead predecessor's last state is
                    # samples old; step through every one since.
                    self.standing.replaying()
                    caught = self._catch_up(h.seq, m, None)
                    self.program.say(str(caught))
                    if caught.incomplete is not None:
                        self._start_converging()
                    self.standing.replayed(caught.last_seq, Standing.SHADOW)
                    self.end_of_run |= caught.end_of_run
                    self._publish_state(caught.last_seq)
                    return
        self._step(m, self.shadow_estimate)
        # Following only once a handed-over state is there: the active
        # instance's (a swap) or, after a crash, the one the supervisor
        # keeps handing on until it sees this instance follow.
        if self.handovers.newest() is not None:
            self._publish_state(m.seq)

    def _catch_up(self, state_seq, first_live, stepped):
        """Steps through the supervisor's replay of the measurements after
        ``state_seq`` (reporting its progress: the first report opens the
        replay for this generation, the others pace it)
        while the live queue fills, then through the live samples held
        meanwhile; bounded by :data:`CATCH_UP_TIMEOUT_S` without progress."""
        if self.stash is None:
            self.stash = [msg.Measurement() for _ in range(STASH)]
        merge = _CatchUp(state_seq, self.stash)
        if first_live is not None:
            merge.hold_live(first_live)
        # Says it is catching up from ``state_seq`` (the supervisor paces
        # the replay by these reports).
        self._publish_state(state_seq)
        scratch, r, live = self.shadow_estimate, self.replayed_m, self.live_m
        last_progress = time.monotonic()
        replayed, reported, incomplete = 0, state_seq, None
        while True:
            gap = None
            while self.replay.receive_into(r):
                verdict = merge.replayed(r)
                if verdict == _CatchUp.STEP:
                    last_progress = time.monotonic()
                    self._step(r, scratch)
                    if stepped is not None:
                        stepped(r, scratch)
                    replayed += 1
                elif verdict == _CatchUp.GAP:
                    gap = (merge.next, r.seq)
                    break
            if gap is not None:
                # The supervisor's ring lost these; this observer's live
                # queue, subscribed before the replay began, may hold them.
                while self.measurements.receive_into(live):
                    merge.hold_live(live)
                if not merge.reached_live():
                    incomplete = f"the replay had lost samples {gap[0]} to {gap[1] - 1}"
                break
            if merge.next - 1 > reported:
                reported = merge.next - 1
                self._publish_state(reported)
            while self.measurements.receive_into(live):
                merge.hold_live(live)
            if merge.reached_live():
                break
            if time.monotonic() - last_progress > CATCH_UP_TIMEOUT_S or stop_requested():
                incomplete = (
                    f"no replayed measurement after sample {merge.next - 1} for "
                    f"{CATCH_UP_TIMEOUT_S:g}s"
                )
                break
            time.sleep(200e-6)
        # Drops held samples the replay already covered.
        merge.reached_live()
        last_seq, end_of_run = merge.next - 1, False
        while True:
            m = merge.take_held()
            if m is None:
                break
            self._step(m, scratch)
            if stepped is not None:
                stepped(m, scratch)
            last_seq = m.seq
            end_of_run |= bool(m.flags & msg.Flags.END_OF_RUN)
        return _CaughtUp(state_seq, replayed, last_seq, incomplete, end_of_run)

    # ---- the law ----

    def _call(self, name, *args):
        try:
            return getattr(self.law, name)(*args)
        except Exception as e:
            at = f" at measurement {args[0].seq}" if args and hasattr(args[0], "seq") else ""
            raise LawError(f"{type(self.law).__qualname__}.{name}{at} raised {e!r}") from e

    def _step(self, m, e):
        """The law's estimate for tick ``m.seq`` + 1 into ``e``."""
        if self.first_stepped is None:
            self.first_stepped = m.seq
            # The measurement the law's history starts at (tests recompute
            # the law from here).
            self.program.say(f"generation {self.generation}: law stepped from measurement {m.seq}")
        self.stepped += 1
        self._write(self._call("step", m), e, m)
        if self.converging_for is not None:
            self.converging_until = e.seq + self.converging_for
            self.converging_for = None
        if self.converging_until is not None and e.seq >= self.converging_until:
            self.converging_until = None
        # The estimate is reused from sample to sample: the bit is set or cleared.
        if self.converging_until is not None:
            e.flags |= msg.Flags.CONVERGING
        else:
            e.flags &= ~msg.Flags.CONVERGING

    def _start_converging(self):
        """Its state is not the loop's: the estimates from the next on are
        flagged converging for the law's settling samples (observer.rs
        ``start_converging``)."""
        n = self._call("settling_samples")
        if n is not None:
            self.converging_for = int(n)
            self.program.say(
                f"started without a continuous state: its next {int(n)} estimates are "
                "flagged converging (the controller leaves out their corrections)"
            )

    def _write(self, result, e, m):
        """What the law returned into ``e``, stamped."""
        try:
            write_estimate(
                result, e, m, self.settings.n_outputs or 0, self.settings.n_inputs or 0
            )
        except (TypeError, ValueError, IndexError) as error:
            what = "initial" if m is None else f"step at measurement {m.seq}"
            raise LawError(
                f"{type(self.law).__qualname__}.{what} returned {result!r}: {error}"
            ) from error

    def _publish_state(self, seq):
        self.states_out.publish(seq, self.standing.mark(), self._call("save_state"))

    def _load(self, h):
        """Copies ``h`` into the law if it is of this design."""
        values = saved_state(h, self.design_hash)
        if values is None:
            return False
        return self._call("load_state", values) is not False



def write_estimate(result, e, m, n_outputs=0, n_inputs=0):
    """What a law returned (x̂, (x̂, innovation) or an :class:`Estimated`)
    into the estimate ``e``, stamped with the tick it is for and the
    measurement ``m`` it came from (None for the initial estimate, which
    gets ``n_outputs`` and ``n_inputs``; a step's are the measurement's).
    Every field the law does not give is zero. TypeError, IndexError or
    ValueError for what is no estimate."""
    ctypes.memset(ctypes.addressof(e), 0, _ESTIMATE_SIZE)
    innovation = free = direct = None
    if isinstance(result, Estimated):
        x_hat, innovation, free, direct = (
            result.x_hat,
            result.innovation,
            result.free,
            result.direct,
        )
    elif (
        isinstance(result, tuple)
        and len(result) == 2
        and result[0] is not None
        and not _is_number(result[0])
    ):
        x_hat, innovation = result
    else:
        x_hat = result
    if x_hat is None or isinstance(x_hat, (str, bytes)) or _is_number(x_hat):
        raise TypeError("x̂ is a sequence of floats")
    n = len(x_hat)
    if n > msg.MAX_STATES:
        raise ValueError(f"{n} states, at most {msg.MAX_STATES}")
    xs = e.x_hat
    for i in range(n):
        xs[i] = x_hat[i]
    e.n_states = n
    if innovation is not None:
        _write_values(innovation, e.innovation, msg.MAX_OUTPUTS)
    if free is not None:
        _write_values(free, e.free, msg.MAX_OBSERVER_OUTPUTS)
    if direct is not None:
        _write_values(direct, e.direct, msg.MAX_OBSERVER_OUTPUTS * msg.MAX_OBSERVER_INPUTS)
    if m is None:
        e.seq = 0
        e.n_outputs = n_outputs
        e.n_inputs = n_inputs
    else:
        e.seq = m.seq + 1
        e.source_tick_ns = m.tick_ns
        e.source_published_ns = m.published_ns
        e.n_outputs = m.n_outputs
        e.n_inputs = m.n_inputs

def _write_values(values, dest, limit):
    if _is_number(values):
        dest[0] = values
        return
    n = len(values)
    if n > limit:
        raise ValueError(f"{n} values, at most {limit}")
    for i in range(n):
        dest[i] = values[i]
