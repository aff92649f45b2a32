"""What the supervisor hands a controller process: its command line and the
parts of the scenario a controller in Python needs.

The command line is the one every loop process shares (shared/node args.rs
and overrides.rs): ``[--generation N] [--join|--restart|--standby]
--scenario FILE --prefix P --run-dir DIR [--rate HZ] [--duration S]
[--mode realtime|lockstep] [--no-realtime] [--tick WAIT]``. The scenario was
validated by the supervisor before it started this process; what is read
here is checked again, with errors naming the file and the field.
"""

import argparse
import math
import tomllib
from dataclasses import dataclass, field


class UsageError(Exception):
    """A command line this process cannot serve."""


class ScenarioError(Exception):
    """A scenario field this process cannot use: names the file and the field."""

    def __init__(self, path, field_name, reason):
        super().__init__(f"{path}: {field_name}: {reason}")


#: How a process enters the loop (shared/protocol joining.rs).
AT_START = "at-start"
REPLACEMENT = "replacement"
RESTART = "restart"
STANDBY = "standby"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def _parser():
    p = _Parser(prog="flexloop-controller", add_help=False, allow_abbrev=False)
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


def split_args(argv):
    """(the program's own arguments, flexloop's): the supervisor starts a
    program as ``program its-args… -- flexloop's-flags`` (shared/node
    lib.rs ``flexloop_args``); without a ``--`` all are flexloop's."""
    argv = list(argv)
    at = max((i for i, a in enumerate(argv) if a == "--"), default=None)
    if at is None:
        return [], argv
    return argv[:at], argv[at + 1 :]


def parse_args(argv):
    """flexloop's part of the command line (without the program name)."""
    own, argv = split_args(argv)
    a = _parser().parse_args(argv)
    if a.spare:
        raise UsageError("--spare: a controller started from `exec` is never a warm spare")
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
    )


@dataclass
class Realtime:
    """The controller's real-time set-up (shared/node args.rs realtime_settings)."""

    priority: int | None = None
    cpu: int | None = None
    lock_memory: bool = False
    timer_slack_ns: int = 1
    #: The plant's CPU: start-up work stays off it.
    avoid_cpu: int | None = None


@dataclass
class Settings:
    """What a Python controller needs of its scenario, overrides applied."""

    path: str
    rate_hz: float
    mode: str
    params: dict = field(default_factory=dict)
    realtime: Realtime = field(default_factory=Realtime)
    #: The plant's |u| limit (``plant.input_limit``).
    input_limit: float = 1000.0
    #: The scenario's ``[reference]`` table as written.
    reference: dict = field(default_factory=dict)

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
    if priority is not None and not (isinstance(priority, int) and 1 <= priority <= 99):
        raise ScenarioError(path, f"realtime.{role}.priority", "must be an integer 1 to 99")
    cpu = value.get("cpu")
    if cpu is not None and not (isinstance(cpu, int) and cpu >= 0):
        raise ScenarioError(path, f"realtime.{role}.cpu", "must be a CPU number")
    return priority, cpu


def load_settings(args):
    """Reads the scenario ``args.scenario`` and applies the overrides."""
    path = args.scenario
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except OSError as e:
        raise ScenarioError(path, "(file)", e.strerror or str(e)) from e
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(path, "(syntax)", str(e)) from e
    loop = _table(path, doc, "loop")
    rate = loop.get("rate_hz", 10_000.0)
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (
        math.isfinite(rate) and rate > 0
    ):
        raise ScenarioError(path, "loop.rate_hz", "must be a positive number of Hz")
    mode = loop.get("mode", "realtime")
    if mode not in ("realtime", "lockstep"):
        raise ScenarioError(path, "loop.mode", "must be \"realtime\" or \"lockstep\"")
    controller = _table(path, doc, "controller")
    params = controller.get("params", {})
    if not isinstance(params, dict):
        raise ScenarioError(path, "controller.params", "must be a table")
    rt_table = _table(path, doc, "realtime")
    priority, cpu = _process_realtime(path, rt_table, "controller")
    _, plant_cpu = _process_realtime(path, rt_table, "plant")
    lock_memory = rt_table.get("lock_memory", True)
    slack = rt_table.get("timer_slack_ns", 1)
    if not isinstance(slack, int) or isinstance(slack, bool) or slack < 1:
        raise ScenarioError(path, "realtime.timer_slack_ns", "must be a positive integer")
    plant = _table(path, doc, "plant")
    input_limit = plant.get("input_limit", 1000.0)
    if isinstance(input_limit, bool) or not isinstance(input_limit, (int, float)) or not (
        math.isfinite(input_limit) and input_limit > 0
    ):
        raise ScenarioError(path, "plant.input_limit", "must be a positive number of N")
    settings = Settings(
        path=path,
        rate_hz=float(args.rate_hz if args.rate_hz is not None else rate),
        mode=args.mode or mode,
        params=params,
        input_limit=float(input_limit),
        reference=_table(path, doc, "reference"),
    )
    settings.realtime = Realtime(
        # Lockstep runs flat out: under SCHED_FIFO it would starve its CPU.
        priority=None if (args.no_realtime or settings.lockstep) else priority,
        cpu=cpu,
        lock_memory=bool(lock_memory) and not args.no_realtime,
        timer_slack_ns=slack,
        avoid_cpu=plant_cpu,
    )
    return settings


class Params:
    """A controller's ``[controller.params]``: read with :meth:`number`;
    a field the controller never read is an error (:meth:`check_all_read`)."""

    def __init__(self, path, table):
        self.path = path
        self._table = table
        self._read = set()

    def _name(self, name):
        return f"controller.params.{name}"

    def number(self, name, default=None, minimum=None, positive=False):
        """The finite number ``name`` (or ``default`` when absent and given)."""
        self._read.add(name)
        if name not in self._table:
            if default is None:
                raise ScenarioError(self.path, self._name(name), "missing (a number)")
            return float(default)
        value = self._table[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ScenarioError(self.path, self._name(name), f"must be a number, not {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ScenarioError(self.path, self._name(name), "must be finite")
        if positive and value <= 0:
            raise ScenarioError(self.path, self._name(name), f"must be positive, not {value}")
        if minimum is not None and value < minimum:
            raise ScenarioError(
                self.path, self._name(name), f"must be at least {minimum}, not {value}"
            )
        return value

    def check_all_read(self):
        unknown = sorted(set(self._table) - self._read)
        if unknown:
            raise ScenarioError(
                self.path,
                self._name(unknown[0]),
                "unknown parameter (the controller reads "
                + (", ".join(sorted(self._read)) or "none")
                + ")",
            )

    def canonical(self):
        """The parameters as a stable text, for the design's fingerprint."""
        return repr(sorted((k, repr(v)) for k, v in self._table.items()))


class Reference:
    """The scenario's set-point r(t) as flexloop's controller samples it
    (shared/design reference.rs), for the shapes that are closed-form here:
    ``hold``, ``step`` and ``sine``. ``sample(t)`` is r at time t in s."""

    def __init__(self, path, table):
        shape = table.get("shape", "hold")

        def number(name, default):
            value = table.get(name, default)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ScenarioError(path, f"reference.{name}", f"must be a number, not {value!r}")
            return float(value)

        self.amplitude = number("amplitude", 0.0)
        self.start_s = number("start_s", 0.0)
        if shape == "hold":
            self.sample = self._hold
        elif shape == "step":
            self.sample = self._step
        elif shape == "sine":
            self.omega = 2.0 * math.pi * number("frequency_hz", 1.0)
            self.sample = self._sine
        else:
            raise ScenarioError(
                path,
                "reference.shape",
                f"`{shape}`: a Python controller has only hold, step and sine",
            )
        if table.get("direction") is not None and shape != "hold":
            raise ScenarioError(
                path, "reference.direction", "a Python controller drives the first output only"
            )

    def _hold(self, t):
        return 0.0

    def _step(self, t):
        return self.amplitude if t >= self.start_s else 0.0

    def _sine(self, t):
        if t < self.start_s:
            return 0.0
        return self.amplitude * math.sin(self.omega * (t - self.start_s))


class Setup:
    """What a controller is made from: its parameters and the loop's facts."""

    def __init__(self, settings, own_args=()):
        self._settings = settings
        #: The program's own arguments: ``exec``'s after the program.
        self.own_args = list(own_args)
        #: ``[controller.params]``.
        self.params = Params(settings.path, settings.params)
        self.rate_hz = settings.rate_hz
        #: The sample time 1 / rate_hz in s.
        self.ts = 1.0 / settings.rate_hz
        #: The plant's |u| limit in N (``plant.input_limit``).
        self.input_limit = settings.input_limit

    def reference(self):
        """The scenario's set-point (a :class:`Reference`); an error naming
        the field for a shape it cannot reproduce."""
        return Reference(self._settings.path, self._settings.reference)
