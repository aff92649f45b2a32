"""The scenario's set-point r(t) and its first four derivatives, as flexloop
computes them: shared/design's ``reference.rs`` (``Reference``, its
``from_scenario`` and ``sample``) and shared/control's ``setpoint.rs`` (the
thesis' snap-limited scan, Table 3.6), ported operation for operation so
that both give the same numbers (python_sdk's test compares them to
1e-12 over every shipped scenario, at the switching instants too).

``Reference.derivatives(t)`` is (r, ṙ, r̈, r⃛, snap) at t in s;
``Reference.sample(t)`` is r alone. Both are closed-form and allocate
nothing but their floats (``derivatives(t, out)`` fills a list of five).
"""

import math

from .errors import ScenarioError, display, number

#: Ticks fall exactly on the scan's switching times (every 5 ms); 1 ps
#: forward makes each one resolve to the segment that starts there,
#: whatever the rounding of t (shared/design reference.rs).
SWITCH_NUDGE_S = 1e-12

#: shared/scenario limits.rs.
AMPLITUDE_MAX = 10.0
DIRECTION_MAX = 1e3
DURATION_S_MAX = 86_400.0
#: shared/protocol: outputs a measurement carries.
MAX_OUTPUTS = 8

SHAPES = ("hold", "step", "sine", "scan")
_FIELDS = ("shape", "amplitude", "frequency_hz", "repeat_s", "start_s", "direction")


class SetpointParams:
    """Table 3.6's limits (shared/control setpoint.rs ``SetpointParams``)."""

    def __init__(self, s_max, j_max, a_max, v_max, t_vel, t_settle):
        self.s_max, self.j_max, self.a_max = s_max, j_max, a_max
        self.v_max, self.t_vel, self.t_settle = v_max, t_vel, t_settle

    @classmethod
    def thesis(cls):
        """S 4e6, J 2e4, A 100, V 1, T_vel 0.15, T_settle 0.02."""
        return cls(4e6, 2e4, 100.0, 1.0, 0.15, 0.02)


class SetpointError(ValueError):
    """Limits that make no scan (shared/control ``SetpointError``)."""


class _Segment:
    __slots__ = ("t0", "snap", "r0", "v0", "a0", "j0")

    def __init__(self, t0, snap, r0, v0, a0, j0):
        self.t0, self.snap, self.r0, self.v0, self.a0, self.j0 = t0, snap, r0, v0, a0, j0

    def eval(self, t):
        tau = t - self.t0
        s, j0, a0, v0 = self.snap, self.j0, self.a0, self.v0
        j = j0 + s * tau
        a = a0 + tau * (j0 + tau * s / 2.0)
        v = v0 + tau * (a0 + tau * (j0 / 2.0 + tau * s / 6.0))
        r = self.r0 + tau * (v0 + tau * (a0 / 2.0 + tau * (j0 / 6.0 + tau * s / 24.0)))
        return r, v, a, j


class Setpoint:
    """The 4th-order scan profile: accelerate, settle, scan at constant
    velocity, decelerate, rest (at most 16 polynomial segments)."""

    def __init__(self, p):
        for value, name in (
            (p.s_max, "s_max"),
            (p.j_max, "j_max"),
            (p.a_max, "a_max"),
            (p.v_max, "v_max"),
            (p.t_vel, "t_vel"),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise SetpointError(f"set-point parameter {name} must be positive and finite")
        if not (math.isfinite(p.t_settle) and 0.0 <= p.t_settle <= p.t_vel):
            raise SetpointError("set-point parameter t_settle must be positive and finite")
        ts = p.j_max / p.s_max
        tj = p.a_max / p.j_max - ts
        ta = p.v_max / p.a_max - 2.0 * ts - tj
        eps = 1e-12 * (ts + p.v_max / p.a_max)
        if tj < -eps or ta < -eps:
            raise SetpointError(
                f"inconsistent set-point limits: constant-jerk time {display(tj)} s, "
                f"constant-acceleration time {display(ta)} s"
            )
        tj = max(tj, 0.0)
        ta = max(ta, 0.0)
        s = p.s_max
        accel = [(s, ts), (0.0, tj), (-s, ts), (0.0, ta), (-s, ts), (0.0, tj), (s, ts)]
        plan = accel + [(0.0, p.t_vel)] + [(-sn, d) for sn, d in accel]
        segs = []
        t, st = 0.0, (0.0, 0.0, 0.0, 0.0)
        for snap, dur in plan:
            if dur <= 0.0:
                continue
            seg = _Segment(t, snap, st[0], st[1], st[2], st[3])
            t += dur
            st = seg.eval(t)
            segs.append(seg)
        self._segs = tuple(segs)
        self._starts = tuple(seg.t0 for seg in segs)
        self.t_acc = 4.0 * ts + 2.0 * tj + ta
        self.t_settle = p.t_settle
        self.t_vel = p.t_vel
        self.t_end = t
        # Exact rest values: velocity and below are zero by construction.
        self.end_r = st[0]

    def duration(self):
        """Total duration of the motion in s (0.19 s for Table 3.6)."""
        return self.t_end

    def scan_window(self):
        """Start and end of the constant-velocity scan in s."""
        return (self.t_acc + self.t_settle, self.t_acc + self.t_vel)

    def _segment(self, t):
        starts, k, n = self._starts, 0, len(self._starts)
        while k + 1 < n and t >= starts[k + 1]:
            k += 1
        return self._segs[k]

    def evaluate(self, t):
        """(r, v, a, j, s) at ``t`` in s; at rest before 0 and after the end."""
        if t != t or t < 0.0:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        if t >= self.t_end:
            return self.end_r, 0.0, 0.0, 0.0, 0.0
        seg = self._segment(t)
        r, v, a, j = seg.eval(t)
        return r, v, a, j, seg.snap

    def position(self, t):
        """r alone at ``t`` (what :meth:`evaluate` gives first)."""
        if t != t or t < 0.0:
            return 0.0
        if t >= self.t_end:
            return self.end_r
        seg = self._segment(t)
        tau = t - seg.t0
        s, j0, a0, v0 = seg.snap, seg.j0, seg.a0, seg.v0
        return seg.r0 + tau * (v0 + tau * (a0 / 2.0 + tau * (j0 / 6.0 + tau * s / 24.0)))


def _scan_index(t, repeat_s):
    """Which scan a time falls in, and the time within it."""
    if repeat_s <= 0.0 or t < 0.0:
        return 0, t
    index = math.floor(t / repeat_s)
    return index, t - float(index) * repeat_s


class Reference:
    """The set-point profile: ``hold`` (r = 0), ``step``, ``sine`` or
    ``scan`` (the thesis' snap-limited scan, back and forth every
    ``repeat_s``, scaled to ``amplitude``). Made by :meth:`from_scenario`
    (``setup.reference()``); output i follows ``direction_i · r(t)``
    (``setup.reference_direction``)."""

    HOLD, STEP, SINE, SCAN = SHAPES

    def __init__(self, shape, amplitude=0.0, omega=0.0, start_s=0.0, setpoint=None,
                 repeat_s=0.0, scale=1.0):
        self.shape = shape
        self.amplitude = amplitude
        self.omega = omega
        #: When the motion starts in s (with a command deadline, τ_d later
        #: than the scenario's ``reference.start_s``).
        self.start_s = start_s
        self.setpoint = setpoint
        self.repeat_s = repeat_s
        self.scale = scale
        self.sample = getattr(self, "_sample_" + shape)
        self._derivatives = getattr(self, "_derivatives_" + shape)
        if setpoint is not None:
            self._end = setpoint.evaluate(setpoint.duration())[0]

    def derivatives(self, t, out=None):
        """(r, ṙ, r̈, r⃛, snap) at ``t`` in s, as shared/design's
        ``Reference::sample``; with ``out`` (a list of five) written there
        and ``out`` returned."""
        d = self._derivatives(t)
        if out is None:
            return d
        out[0], out[1], out[2], out[3], out[4] = d
        return out

    # r(t) alone: ``sample`` is bound to one of these.

    def _sample_hold(self, t):
        return 0.0

    def _sample_step(self, t):
        return self.amplitude if t >= self.start_s else 0.0

    def _sample_sine(self, t):
        if t < self.start_s:
            return 0.0
        return self.amplitude * math.sin(self.omega * (t - self.start_s))

    def _sample_scan(self, t):
        index, local = _scan_index(t - self.start_s + SWITCH_NUDGE_S, self.repeat_s)
        r = self.setpoint.position(local)
        if index % 2 != 0:
            r = self._end - r
        return r if self.scale == 1.0 else self.scale * r

    # (r, ṙ, r̈, r⃛, snap) at t.

    def _derivatives_hold(self, t):
        return 0.0, 0.0, 0.0, 0.0, 0.0

    def _derivatives_step(self, t):
        return (self.amplitude if t >= self.start_s else 0.0), 0.0, 0.0, 0.0, 0.0

    def _derivatives_sine(self, t):
        if t < self.start_s:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        omega = self.omega
        phase = omega * (t - self.start_s)
        s, c = math.sin(phase), math.cos(phase)
        a = self.amplitude
        # omega.powi(n) as Rust computes it (repeated squaring).
        w2 = omega * omega
        w3 = omega * w2
        w4 = w2 * w2
        return a * s, a * omega * c, -a * w2 * s, -a * w3 * c, a * w4 * s

    def _derivatives_scan(self, t):
        index, local = _scan_index(t - self.start_s + SWITCH_NUDGE_S, self.repeat_s)
        r, v, a, j, s = self.setpoint.evaluate(local)
        if index % 2 != 0:
            # Back: from the end position to the start.
            r, v, a, j, s = self._end - r, -v, -a, -j, -s
        k = self.scale
        if k == 1.0:
            return r, v, a, j, s
        return k * r, k * v, k * a, k * j, k * s

    def end_s(self):
        """When the motion is over (None: it never ends)."""
        if self.shape == self.HOLD:
            return 0.0
        if self.shape == self.STEP:
            return self.start_s
        if self.shape == self.SINE or self.repeat_s > 0.0:
            return None
        return self.start_s + self.setpoint.duration()

    @classmethod
    def from_scenario(cls, path, table, rate_hz, command_deadline_us=None, outputs=None):
        """The profile of the scenario ``path``'s ``[reference]`` table
        (parsed TOML), with the loop's rate and command deadline, checked
        as shared/scenario and shared/design check it (errors name the
        file and the field; ``outputs``: the plant's model and number of
        outputs where known, for ``reference.direction``)."""
        check(path, table, rate_hz)
        reference = cls._from_checked(path, table, rate_hz, command_deadline_us)
        check_outputs(path, table, outputs)
        return reference

    @classmethod
    def _from_checked(cls, path, table, rate_hz, command_deadline_us):
        shape = table.get("shape", "hold")
        amplitude = _float(table.get("amplitude", 0.0))
        start = _float(table.get("start_s", 0.0))
        deadline_s = None if command_deadline_us is None else _float(command_deadline_us) / 1e6
        start_s = start + (deadline_s if deadline_s is not None else 0.0)
        if shape == "hold":
            return cls("hold")
        if shape == "step":
            return cls("step", amplitude=amplitude, start_s=start_s)
        if shape == "sine":
            omega = 2.0 * math.pi * _float(table.get("frequency_hz", 1.0))
            return cls("sine", amplitude=amplitude, omega=omega, start_s=start_s)
        ts = 1.0 / rate_hz
        if start < ts:
            raise ScenarioError(
                path,
                "reference.start_s",
                f"a scan must start at least one sample ({display(ts)} s) after the run, "
                "so that its feedforward can be issued ahead of the motion; "
                f"got {display(start)}",
            )
        try:
            setpoint = Setpoint(SetpointParams.thesis())
        except SetpointError as e:
            raise ScenarioError(path, "reference", f"set-point: {e}") from None
        repeat_s = _float(table.get("repeat_s", 0.0))
        if repeat_s > 0.0 and repeat_s < setpoint.duration():
            raise ScenarioError(
                path,
                "reference.repeat_s",
                f"a scan lasts {display(setpoint.duration())} s; "
                f"it cannot repeat every {display(repeat_s)} s",
            )
        # `amplitude` 0: the thesis' stroke, as the profile has it.
        stroke = setpoint.evaluate(setpoint.duration())[0]
        scale = 1.0 if amplitude == 0.0 else amplitude / stroke
        return cls("scan", start_s=start_s, setpoint=setpoint, repeat_s=repeat_s, scale=scale)


def _float(v):
    return float(v)


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _within(path, field, v, lo, hi, unit):
    if math.isfinite(v) and lo <= v <= hi:
        return
    unit = f" {unit}" if unit else ""
    raise ScenarioError(
        path, field, f"must lie in [{number(lo)}, {number(hi)}]{unit}, got {number(v)}"
    )


def _invalid_type(path, field, value, expected):
    kind = {bool: "boolean", str: "string", list: "sequence", dict: "map"}.get(
        type(value), type(value).__name__
    )
    shown = f' "{value}"' if isinstance(value, str) else (
        f" `{str(value).lower()}`" if isinstance(value, bool) else ""
    )
    raise ScenarioError(path, field, f"invalid type: {kind}{shown}, expected {expected}")


def check_outputs(path, table, outputs):
    """shared/design's check of ``reference.direction`` against the
    plant's outputs: ``outputs`` is (model, n_outputs), None where the
    number is not known from the scenario alone."""
    direction = table.get("direction")
    model, n_outputs = outputs or (None, None)
    if direction is not None and n_outputs is not None and len(direction) != n_outputs:
        raise ScenarioError(
            path,
            "reference.direction",
            f"has {len(direction)} entries, the plant `{model}` has {n_outputs} "
            f"output{'' if n_outputs == 1 else 's'}",
        )


def check(path, table, rate_hz):
    """``[reference]`` as shared/scenario validates it: types, names,
    what applies to the shape, ranges."""
    if not isinstance(table, dict):
        _invalid_type(path, "reference", table, "struct ReferenceSection")
    for key in table:
        if key not in _FIELDS:
            raise ScenarioError(
                path,
                f"reference.{key}",
                f"unknown field `{key}`, expected one of "
                + ", ".join(f"`{f}`" for f in _FIELDS),
            )
    shape = table.get("shape", "hold")
    if not isinstance(shape, str):
        _invalid_type(path, "reference.shape", shape, "a string")
    for name in ("amplitude", "frequency_hz", "repeat_s", "start_s"):
        if name in table and not _is_number(table[name]):
            _invalid_type(path, f"reference.{name}", table[name], "f64")
    direction = table.get("direction")
    if direction is not None:
        if not isinstance(direction, list):
            _invalid_type(path, "reference.direction", direction, "a sequence")
        for i, v in enumerate(direction):
            if not _is_number(v):
                _invalid_type(path, f"reference.direction[{i}]", v, "f64")
    if shape not in SHAPES:
        raise ScenarioError(
            path, "reference.shape", f"unknown `{shape}` (expected one of {', '.join(SHAPES)})"
        )
    applies = {
        "amplitude": shape != "hold",
        "start_s": shape != "hold",
        "direction": shape != "hold",
        "frequency_hz": shape == "sine",
        "repeat_s": shape == "scan",
    }
    for name, ok in applies.items():
        if not ok and name in table:
            raise ScenarioError(
                path, f"reference.{name}", f"does not apply to reference.shape `{shape}`"
            )
    frequency = float(table.get("frequency_hz", 1.0))
    nyquist = rate_hz / 2.0
    if frequency >= nyquist:
        raise ScenarioError(
            path,
            "reference.frequency_hz",
            f"{number(frequency)} Hz is not below the Nyquist frequency {number(nyquist)} Hz",
        )
    amplitude = float(table.get("amplitude", 0.0))
    if not (math.isfinite(amplitude) and abs(amplitude) <= AMPLITUDE_MAX):
        raise ScenarioError(
            path,
            "reference.amplitude",
            f"must lie in [-{display(AMPLITUDE_MAX)}, {display(AMPLITUDE_MAX)}] m (or rad), "
            f"got {number(amplitude)}",
        )
    if not (math.isfinite(frequency) and frequency > 0.0):
        raise ScenarioError(
            path,
            "reference.frequency_hz",
            f"must be a positive finite number, got {number(frequency)}",
        )
    _within(path, "reference.start_s", float(table.get("start_s", 0.0)), 0.0, DURATION_S_MAX, "s")
    _within(
        path, "reference.repeat_s", float(table.get("repeat_s", 0.0)), 0.0, DURATION_S_MAX, "s"
    )
    if direction is not None:
        if len(direction) > MAX_OUTPUTS:
            raise ScenarioError(
                path,
                "reference.direction",
                f"has {len(direction)} entries; the loop carries at most {MAX_OUTPUTS} outputs",
            )
        for i, v in enumerate(direction):
            _within(
                path,
                f"reference.direction[{i}]",
                abs(float(v)),
                0.0,
                DIRECTION_MAX,
                "in absolute value",
            )
        if all(float(v) == 0.0 for v in direction):
            raise ScenarioError(
                path,
                "reference.direction",
                "needs at least one non-zero entry (the profile drives no output)",
            )
