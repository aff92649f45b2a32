"""What the supervisor hands a controller or observer process: its command
line and the parts of the scenario a law in Python is made from.

The command line is the one every loop process shares (shared/node args.rs
and overrides.rs): ``[--generation N] [--join|--restart|--standby]
--scenario FILE --prefix P --run-dir DIR [--rate HZ] [--duration S]
[--mode realtime|lockstep] [--no-realtime] [--tick WAIT]``. The scenario was
validated by the supervisor before it started this process; what is read
here is checked again as shared/scenario checks it, with errors naming the
file and the field (``scenario FILE: field `FIELD`: REASON``).
"""

import argparse
import json
import math
import os
import tomllib
from dataclasses import dataclass, field

from .errors import ScenarioError, display, number
from .reference import Reference

__all__ = [
    "AT_START",
    "REPLACEMENT",
    "RESTART",
    "STANDBY",
    "Args",
    "Params",
    "Reference",
    "ScenarioError",
    "Settings",
    "Setup",
    "UsageError",
    "load_settings",
    "parse_args",
]


class UsageError(Exception):
    """A command line this process cannot serve."""


#: How a process enters the loop (shared/protocol joining.rs).
AT_START = "at-start"
REPLACEMENT = "replacement"
RESTART = "restart"
STANDBY = "standby"

#: The roles a program of one's own serves.
CONTROLLER = "controller"
OBSERVER = "observer"
ROLES = (CONTROLLER, OBSERVER)

#: shared/scenario limits.rs.
RATE_HZ = (1.0, 100_000.0)


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def _parser(role):
    p = _Parser(prog=f"flexloop-{role}", add_help=False, allow_abbrev=False)
    p.add_argument("--scenario", required=True)
    p.add_argument("--prefix", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--generation", type=int, default=0)
    joining = p.add_mutually_exclusive_group()
    joining.add_argument("--join", action="store_true")
    joining.add_argument("--restart", action="store_true")
    joining.add_argument("--standby", action="store_true")
    joining.add_argument("--spare", action="store_true")
    p.add_argument("--rate", type=float)
    p.add_argument("--duration", type=float)
    p.add_argument("--mode", choices=["realtime", "lockstep"])
    p.add_argument("--no-realtime", action="store_true")
    p.add_argument("--tick", choices=["sleep", "sleep-then-spin"])
    return p


@dataclass
class Args:
    #: The program's own arguments (before the ``--``).
    own: list
    scenario: str
    prefix: str
    run_dir: str
    generation: int
    joining: str
    rate_hz: float | None
    duration_s: float | None
    mode: str | None
    no_realtime: bool
    role: str = CONTROLLER

    @property
    def late(self):
        """Joins a running loop (a replacement, a restart, a standby)."""
        return self.joining != AT_START


def split_args(argv):
    """(the program's own arguments, flexloop's): the supervisor starts a
    program as ``program its-args… -- flexloop's-flags`` (shared/node
    lib.rs ``flexloop_args``); without a ``--`` all are flexloop's."""
    argv = list(argv)
    at = max((i for i, a in enumerate(argv) if a == "--"), default=None)
    if at is None:
        return [], argv
    return argv[:at], argv[at + 1 :]


def parse_args(argv, role=CONTROLLER):
    """flexloop's part of the command line (without the program name)."""
    own, argv = split_args(argv)
    a = _parser(role).parse_args(argv)
    if a.spare:
        raise UsageError(f"--spare: a {role} program serves its own law only and is never a spare")
    if a.standby and role != CONTROLLER:
        raise UsageError(f"--standby: only a controller stands by, not the {role}")
    if a.generation < 0 or a.generation >= 2**32:
        raise UsageError(f"--generation {a.generation}: not a generation (0 to 2^32-1)")
    if a.rate is not None and not (math.isfinite(a.rate) and a.rate > 0):
        raise UsageError(f"--rate {a.rate}: must be a positive number of Hz")
    joining = (
        REPLACEMENT if a.join else RESTART if a.restart else STANDBY if a.standby else AT_START
    )
    return Args(
        own=own,
        scenario=a.scenario,
        prefix=a.prefix,
        run_dir=a.run_dir,
        generation=a.generation,
        joining=joining,
        rate_hz=a.rate,
        duration_s=a.duration,
        mode=a.mode,
        no_realtime=a.no_realtime,
        role=role,
    )


@dataclass
class Realtime:
    """A loop process's real-time set-up (shared/node args.rs realtime_settings)."""

    priority: int | None = None
    cpu: int | None = None
    lock_memory: bool = False
    timer_slack_ns: int = 1
    #: The plant's CPU: start-up work stays off it.
    avoid_cpu: int | None = None


@dataclass
class Settings:
    """What a law in Python and its process need of the scenario, overrides
    applied."""

    path: str
    rate_hz: float
    mode: str
    #: The role's ``[<role>.params]``.
    params: dict = field(default_factory=dict)
    realtime: Realtime = field(default_factory=Realtime)
    #: The plant's |u| limit (``plant.input_limit``).
    input_limit: float = 1000.0
    #: The scenario's ``[reference]`` table as written.
    reference: dict = field(default_factory=dict)
    #: ``loop.command_deadline_us`` (None: one whole sample of delay).
    command_deadline_us: float | None = None
    #: ``controller.extra_delay_samples``.
    extra_delay_samples: int = 0
    role: str = CONTROLLER
    #: ``plant.model``, and its inputs and outputs where the scenario alone
    #: says how many (None for a model from a file).
    model: str = "double-integrator"
    n_inputs: int | None = None
    n_outputs: int | None = None
    #: ``supervision.warm_spares``, ``logger.enabled``.
    warm_spares: bool = True
    logger: bool = True
    #: The whole file as parsed (TOML tables as dicts).
    document: dict = field(default_factory=dict)

    @property
    def period_ns(self):
        return round(1e9 / self.rate_hz)

    @property
    def lockstep(self):
        return self.mode == "lockstep"


def _table(path, doc, name):
    value = doc.get(name, {})
    if not isinstance(value, dict):
        raise ScenarioError(path, name, "must be a table")
    return value


def _process_realtime(path, table, role):
    value = table.get(role, {})
    if not isinstance(value, dict):
        raise ScenarioError(path, f"realtime.{role}", "must be a table")
    priority = value.get("priority")
    if priority is not None and not (
        isinstance(priority, int) and not isinstance(priority, bool) and 1 <= priority <= 99
    ):
        raise ScenarioError(
            path, f"realtime.{role}.priority", f"SCHED_FIFO priority must be 1..=99, got {priority}"
        )
    cpu = value.get("cpu")
    if cpu is not None and not (isinstance(cpu, int) and not isinstance(cpu, bool) and cpu >= 0):
        raise ScenarioError(path, f"realtime.{role}.cpu", "must be a CPU number")
    return priority, cpu


def _real(path, name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(path, name, f"invalid type: {value!r}, expected f64")
    return float(value)


def _io_counts(path, plant):
    """(model, n_inputs, n_outputs) of ``[plant]``: the counts where the
    scenario alone gives them (shared/design's models), None for a model
    read from a file."""
    model = plant.get("model", "double-integrator")
    if model in ("double-integrator", "thesis-chain", "two-inertia", "uniform-chain"):
        return model, 1, 1
    if model == "mimo-example":
        return model, 2, 2
    if model == "oat-like":
        return model, 3, 3
    if model == "lumped":
        forces, positions = plant.get("forces", []), plant.get("positions", [])
        if isinstance(forces, list) and isinstance(positions, list):
            return model, len(forces), len(positions)
    return model, None, None


def _read(path):
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise ScenarioError(path, None, f"cannot read: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(path, None, f"cannot parse: {e}") from None


def load_settings(args, role=None):
    """Reads the scenario ``args.scenario`` for ``role`` (the command
    line's by default) and applies the overrides."""
    role = role or args.role
    path = args.scenario
    doc = _read(path)
    loop = _table(path, doc, "loop")
    rate = args.rate_hz if args.rate_hz is not None else loop.get("rate_hz", 10_000.0)
    rate = _real(path, "loop.rate_hz", rate)
    lo, hi = RATE_HZ
    if not (math.isfinite(rate) and lo <= rate <= hi):
        raise ScenarioError(
            path, "loop.rate_hz", f"must lie in [{number(lo)}, {number(hi)}] Hz, got {number(rate)}"
        )
    mode = loop.get("mode", "realtime")
    if mode not in ("realtime", "lockstep"):
        raise ScenarioError(
            path, "loop.mode", f"unknown variant `{mode}`, expected `realtime` or `lockstep`"
        )
    deadline = loop.get("command_deadline_us")
    if deadline is not None:
        deadline = _real(path, "loop.command_deadline_us", deadline)
        period_us = 1e6 / rate
        if not (math.isfinite(deadline) and 0.0 < deadline < period_us):
            raise ScenarioError(
                path,
                "loop.command_deadline_us",
                f"must lie strictly between 0 and the sample period {number(period_us)} µs, "
                f"got {number(deadline)}",
            )
    controller = _table(path, doc, "controller")
    extra = controller.get("extra_delay_samples", 0)
    if isinstance(extra, bool) or not isinstance(extra, int) or extra < 0:
        raise ScenarioError(
            path, "controller.extra_delay_samples", f"invalid value: {extra!r}, expected u32"
        )
    if extra > 1:
        raise ScenarioError(path, "controller.extra_delay_samples", "must be 0 or 1")
    if deadline is not None and extra > 0:
        raise ScenarioError(
            path,
            "loop.command_deadline_us",
            "a command applied on arrival cannot also wait an extra sample: "
            "remove controller.extra_delay_samples or the deadline",
        )
    section = _table(path, doc, role)
    params = section.get("params", {})
    if not isinstance(params, dict):
        raise ScenarioError(path, f"{role}.params", "must be a table")
    rt_table = _table(path, doc, "realtime")
    priority, cpu = _process_realtime(path, rt_table, role)
    _, plant_cpu = _process_realtime(path, rt_table, "plant")
    lock_memory = rt_table.get("lock_memory", True)
    slack = rt_table.get("timer_slack_ns", 1)
    if not isinstance(slack, int) or isinstance(slack, bool) or slack < 1:
        raise ScenarioError(path, "realtime.timer_slack_ns", "must be a positive integer")
    plant = _table(path, doc, "plant")
    input_limit = _real(path, "plant.input_limit", plant.get("input_limit", 1000.0))
    if not (math.isfinite(input_limit) and input_limit > 0):
        raise ScenarioError(
            path, "plant.input_limit", f"must be a positive finite number, got {number(input_limit)}"
        )
    model, n_inputs, n_outputs = _io_counts(path, plant)
    supervision = _table(path, doc, "supervision")
    logger = _table(path, doc, "logger")
    settings = Settings(
        path=path,
        rate_hz=rate,
        mode=args.mode or mode,
        params=params,
        input_limit=input_limit,
        reference=_table(path, doc, "reference"),
        command_deadline_us=deadline,
        extra_delay_samples=extra,
        role=role,
        model=model,
        n_inputs=n_inputs,
        n_outputs=n_outputs,
        warm_spares=bool(supervision.get("warm_spares", True)),
        logger=bool(logger.get("enabled", True)),
        document=doc,
    )
    settings.realtime = Realtime(
        # Lockstep runs flat out: under SCHED_FIFO it would starve its CPU.
        priority=None if (args.no_realtime or settings.lockstep) else priority,
        cpu=cpu,
        lock_memory=bool(lock_memory) and not args.no_realtime,
        timer_slack_ns=slack,
        avoid_cpu=plant_cpu,
    )
    # Every process checks the reference, as every Rust process's design does.
    outputs = None if n_outputs is None else (model, n_outputs)
    Reference.from_scenario(path, settings.reference, rate, deadline, outputs)
    return settings


_MISSING = object()


class Params:
    """A law's ``[controller.params]`` (or ``[observer.params]``), read
    with :meth:`number`, :meth:`integer`, :meth:`flag`, :meth:`text` and
    :meth:`numbers`; a parameter the law never read is an error
    (:meth:`check_all_read`). What the law read, with the value it uses
    (the scenario's, or its default), is the run's params record
    (:meth:`record`)."""

    def __init__(self, path, table, role=CONTROLLER):
        self.path = path
        self.role = role
        self._table = table
        #: name -> the value the law uses, in the order it read them.
        self._used = {}
        self._defaulted = set()

    def _name(self, name):
        return f"{self.role}.params.{name}"

    def _error(self, name, reason):
        return ScenarioError(self.path, self._name(name), reason)

    def _lookup(self, name, default, what):
        """The scenario's value, or ``_MISSING`` with the default to use."""
        if not isinstance(name, str):
            raise TypeError(f"a parameter's name is a string, not {name!r}")
        if name in self._table:
            return self._table[name]
        if default is None:
            raise self._error(name, f"missing ({what})")
        return _MISSING

    def _use(self, name, value, defaulted):
        self._used[name] = value
        if defaulted:
            self._defaulted.add(name)
        else:
            self._defaulted.discard(name)
        return value

    def _check_number(self, name, value, minimum, positive, maximum=None):
        if not math.isfinite(value):
            raise self._error(name, "must be finite")
        if positive and value <= 0:
            raise self._error(name, f"must be positive, not {display(value)}")
        if minimum is not None and value < minimum:
            raise self._error(name, f"must be at least {display(minimum)}, not {display(value)}")
        if maximum is not None and value > maximum:
            raise self._error(name, f"must be at most {display(maximum)}, not {display(value)}")

    def number(self, name, default=None, minimum=None, positive=False, maximum=None):
        """The finite number ``name`` (or ``default`` when absent and given)."""
        value = self._lookup(name, default, "a number")
        defaulted = value is _MISSING
        if defaulted:
            value = default
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self._error(name, f"must be a number, not {value!r}")
        value = float(value)
        self._check_number(name, value, minimum, positive, maximum)
        return self._use(name, value, defaulted)

    def integer(self, name, default=None, minimum=None, maximum=None):
        """The integer ``name`` (or ``default``)."""
        value = self._lookup(name, default, "an integer")
        defaulted = value is _MISSING
        if defaulted:
            value = default
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._error(name, f"must be an integer, not {value!r}")
        self._check_number(name, value, minimum, False, maximum)
        return self._use(name, value, defaulted)

    def flag(self, name, default=None):
        """The boolean ``name`` (or ``default``)."""
        value = self._lookup(name, default, "true or false")
        defaulted = value is _MISSING
        if defaulted:
            value = default
        if not isinstance(value, bool):
            raise self._error(name, f"must be true or false, not {value!r}")
        return self._use(name, value, defaulted)

    def text(self, name, default=None, choices=None):
        """The string ``name`` (or ``default``), one of ``choices`` if given."""
        value = self._lookup(name, default, "a string")
        defaulted = value is _MISSING
        if defaulted:
            value = default
        if not isinstance(value, str):
            raise self._error(name, f"must be a string, not {value!r}")
        if choices is not None and value not in choices:
            raise self._error(
                name, f"unknown `{value}` (expected one of {', '.join(map(str, choices))})"
            )
        return self._use(name, value, defaulted)

    def numbers(self, name, default=None, length=None):
        """The list of finite numbers ``name`` (or ``default``), of
        ``length`` entries if given; a tuple of floats."""
        value = self._lookup(name, default, "a list of numbers")
        defaulted = value is _MISSING
        if defaulted:
            value = default
        if not isinstance(value, (list, tuple)) or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) for v in value
        ):
            raise self._error(name, f"must be a list of numbers, not {value!r}")
        value = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in value):
            raise self._error(name, "must be finite")
        if length is not None and len(value) != length:
            raise self._error(name, f"must have {length} entries, not {len(value)}")
        return self._use(name, value, defaulted)

    def check_all_read(self):
        unknown = sorted(set(self._table) - set(self._used))
        if unknown:
            raise ScenarioError(
                self.path,
                self._name(unknown[0]),
                f"unknown parameter (the {self.role} reads "
                + (", ".join(sorted(self._used)) or "none")
                + ")",
            )

    def used(self):
        """Every parameter the law read: name -> the value it uses."""
        return dict(self._used)

    def defaulted(self):
        """The names among :meth:`used` the scenario did not give."""
        return sorted(self._defaulted)

    def record(self, generation):
        """The run's params record of this law (shared/runfiles
        ``ProgramParams``): role, generation, params, defaulted."""
        return {
            "role": self.role,
            "generation": generation,
            "params": {k: _json_value(v) for k, v in sorted(self._used.items())},
            "defaulted": self.defaulted(),
        }

    def canonical(self):
        """The parameters as a stable text, for the design's fingerprint."""
        return repr(sorted((k, repr(v)) for k, v in self._table.items()))


def _json_value(v):
    return list(v) if isinstance(v, tuple) else v


def params_record_path(run_dir, role, generation):
    """``<run-dir>/params/<role>.json`` (generation 0) or
    ``<run-dir>/params/<role>.g<N>.json`` (shared/runfiles ``RunDir::program_params``)."""
    name = f"{role}.json" if generation == 0 else f"{role}.g{generation}.json"
    return os.path.join(run_dir, "params", name)


def write_params_record(run_dir, params, generation):
    """Writes ``params``' record atomically (a temporary file in params/,
    then renamed over the record); returns its path."""
    path = params_record_path(run_dir, params.role, generation)
    directory = os.path.dirname(path)
    os.makedirs(directory, exist_ok=True)
    text = json.dumps(params.record(generation), indent=2, allow_nan=False) + "\n"
    temporary = os.path.join(directory, f".{os.path.basename(path)}.{os.getpid()}.tmp")
    try:
        with open(temporary, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise
    return path


class Setup:
    """What a law is made from: its parameters and the loop's facts (the
    Rust SDK's ``ControllerSetup`` / ``ObserverSetup``)."""

    def __init__(self, settings, own_args=(), generation=0):
        self._settings = settings
        #: The program's own arguments: ``exec``'s after the program.
        self.own_args = list(own_args)
        #: ``controller`` or ``observer``: whose law this is.
        self.role = settings.role
        #: The generation this instance serves as.
        self.generation = generation
        #: ``[controller.params]`` (or ``[observer.params]``).
        self.params = Params(settings.path, settings.params, settings.role)
        self.rate_hz = settings.rate_hz
        #: The sample time 1 / rate_hz in s.
        self.ts = 1.0 / settings.rate_hz
        #: The plant's |u| limit (``plant.input_limit``).
        self.input_limit = settings.input_limit
        #: ``plant.model``.
        self.model = settings.model
        #: The plant's inputs and outputs where the scenario alone says how
        #: many (every built-in model, a lumped network); None for a model
        #: from a file: each measurement carries them (``m.n_inputs``,
        #: ``m.n_outputs``).
        self.n_inputs = settings.n_inputs
        self.n_outputs = settings.n_outputs
        #: τ_d in s (``loop.command_deadline_us``), or None. With a
        #: deadline the command for tick k acts from t_k + τ_d, not from
        #: t_{k+1}, and must be published by then (a later one is a miss
        #: and the plant holds the input); the reference is shifted by τ_d
        #: to match (:meth:`reference`).
        self.command_deadline_s = (
            None if settings.command_deadline_us is None else settings.command_deadline_us / 1e6
        )
        #: Samples between y(k) and the tick its command is applied at:
        #: 1 + ``controller.extra_delay_samples``.
        self.loop_delay_samples = 1 + settings.extra_delay_samples
        direction = settings.reference.get("direction")
        #: ``reference.direction``: output i follows direction[i] · r(t);
        #: None: the profile drives the first output only.
        self.reference_direction = (
            None if direction is None else tuple(float(v) for v in direction)
        )
        #: The scenario as parsed (TOML tables as dicts), for what the
        #: setup does not name.
        self.scenario = settings.document
        #: The scenario file.
        self.scenario_path = settings.path

    def actuation_time(self, seq):
        """When the command computed from sample ``seq`` starts to act, in
        s: t_seq + τ_d with a command deadline, else the tick it is applied
        at, t_{seq + loop_delay_samples} (where the built-in controller
        evaluates its feedforward: ``reference().derivatives(t)``)."""
        if self.command_deadline_s is not None:
            return seq * self.ts + self.command_deadline_s
        return (seq + self.loop_delay_samples) * self.ts

    def reference(self):
        """The scenario's set-point (a :class:`flexloop.Reference`), every
        shape, as flexloop's controller computes it: ``.sample(t)`` r at t
        in s, ``.derivatives(t)`` (r, ṙ, r̈, r⃛, snap)."""
        s = self._settings
        outputs = None if s.n_outputs is None else (s.model, s.n_outputs)
        return Reference.from_scenario(
            s.path, s.reference, s.rate_hz, s.command_deadline_us, outputs
        )
