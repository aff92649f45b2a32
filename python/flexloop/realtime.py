"""A loop process's real-time set-up, as shared/runtime's realtime.rs does it:
memory locked before the ports exist, CPU and SCHED_FIFO priority once they
are open. A refusal is said once on stderr and the process runs on, as the
Rust processes do."""

import ctypes
import ctypes.util
import os
import sys

_MCL_CURRENT = 1
_MCL_FUTURE = 2
_PR_SET_TIMERSLACK = 29

#: The process's name on its stderr lines (set by the runner for its role).
PROGRAM = "flexloop-controller"

_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _say(what):
    print(f"{PROGRAM}: {what}; running on", file=sys.stderr, flush=True)


def lock_memory(rt):
    if not rt.lock_memory:
        return
    if _libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        _say(f"mlockall refused ({os.strerror(ctypes.get_errno())})")


def set_timer_slack(rt):
    if _libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(rt.timer_slack_ns), 0, 0, 0) != 0:
        _say(f"timer slack {rt.timer_slack_ns} ns refused")


def avoid_loop_cpu(rt):
    """Off the plant's CPU (a shadow's start-up and following)."""
    if rt.avoid_cpu is None:
        return
    cpus = os.sched_getaffinity(0) - {rt.avoid_cpu}
    if cpus:
        try:
            os.sched_setaffinity(0, cpus)
        except OSError as e:
            _say(f"cpus {sorted(cpus)} refused ({e.strerror})")


def raise_priority(rt, cpu=True):
    """Onto the loop's CPU at the role's priority (when named for a
    boundary, or at once at the start); the priority alone without ``cpu``
    (a standby, off the loop's CPU)."""
    if cpu and rt.cpu is not None:
        try:
            os.sched_setaffinity(0, {rt.cpu})
        except OSError as e:
            _say(f"cpu {rt.cpu} refused ({e.strerror})")
    if rt.priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt.priority))
        except OSError as e:
            _say(f"priority {rt.priority} refused ({e.strerror})")


def step_down():
    """Back to ordinary scheduling for the exit (never delay the loop)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pass
