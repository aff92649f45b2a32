"""Prints the set-point of each scenario named on the command line as a
Python law gets it (``setup.reference()``), with its four derivatives, at
many times, as one JSON document on stdout: every number as the bits of
its f64 (an integer), so that the reader compares exactly what was
computed, at exactly the times it was computed at.

Usage: python reference_samples.py SCENARIO...

Run by tests/integration/python_sdk.rs, which evaluates the Rust
``Reference`` at the same times. The times: every tick k·T_s up to the end
of the motion (a scan's repeats: three) and a stride beyond, the same
ticks shifted by a command deadline (t_k + τ_d, where the controller
evaluates the feedforward), each switching instant of the scan and the
floats either side of it, and pseudo-random times (seeded).
"""

import json
import math
import random
import struct
import sys

from flexloop.launch import Setup, load_settings, parse_args


def bits(v):
    return struct.unpack("<Q", struct.pack("<d", float(v)))[0]


def times(setup, reference):
    ts = setup.ts
    tau = setup.command_deadline_s or 0.0
    if reference.shape == "scan":
        cycles = 3 if reference.repeat_s > 0.0 else 1
        span = reference.start_s + max(reference.repeat_s, reference.setpoint.duration()) * cycles
    elif reference.shape == "sine":
        span = reference.start_s + 2.0 / (reference.omega / (2.0 * math.pi))
    else:
        span = reference.start_s + 0.05
    ticks = min(math.ceil(span / ts) + 20, 20_000)
    out = [k * ts for k in range(ticks)]
    # Beyond: a stride over as long again.
    out += [k * ts for k in range(ticks, 2 * ticks, 7)]
    if tau:
        out += [k * ts + tau for k in range(ticks)]
    if reference.shape == "scan":
        starts = [seg.t0 for seg in reference.setpoint._segs] + [reference.setpoint.duration()]
        repeats = range(3) if reference.repeat_s > 0.0 else range(1)
        for i in repeats:
            for t0 in starts:
                t = reference.start_s + i * reference.repeat_s + t0
                out += [math.nextafter(t, -math.inf), t, math.nextafter(t, math.inf)]
                # The nudge's own edge: 1 ps before the switch.
                out.append(t - 1e-12)
    if reference.shape in ("step", "sine"):
        t = reference.start_s
        out += [math.nextafter(t, -math.inf), t, math.nextafter(t, math.inf)]
    rng = random.Random(20240611)
    out += [rng.uniform(-0.01, 2.0 * span) for _ in range(500)]
    return out


def main():
    report = []
    for path in sys.argv[1:]:
        settings = load_settings(
            parse_args(["--scenario", path, "--prefix", "p", "--run-dir", "."])
        )
        setup = Setup(settings)
        reference = setup.reference()
        out = [0.0] * 5
        samples = []
        for t in times(setup, reference):
            d = reference.derivatives(t)
            # The three ways to ask agree to the bit.
            assert reference.derivatives(t, out) is out and tuple(out) == d, (path, t)
            assert reference.sample(t) == d[0] or (d[0] != d[0]), (path, t, d)
            samples.append([bits(t), *(bits(v) for v in d)])
        report.append(
            {
                "path": path,
                "shape": reference.shape,
                "direction": setup.reference_direction,
                "command_deadline_s": setup.command_deadline_s,
                "loop_delay_samples": setup.loop_delay_samples,
                "samples": samples,
            }
        )
    json.dump(report, sys.stdout)


if __name__ == "__main__":
    main()
