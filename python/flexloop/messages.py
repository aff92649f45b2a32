"""The loop's messages as ctypes structures, laid out as shared/protocol's.

Each structure carries the iceoryx2 type name of its Rust twin
(``#[type_name(...)]`` in shared/protocol), so that iceoryx2 opens the Rust
services with it: it compares type name, size and alignment. The field
names, offsets and sizes are checked against shared/protocol's own tables
(``wire.json``, which a Rust test keeps current) by
``python/tests/test_wire.py``, and sizes once more at import
(:func:`check_against_wire`): a message written here that drifted from the
Rust one fails loudly instead of corrupting samples.
"""

import ctypes
import json
from importlib import resources

MAX_OUTPUTS = 8
MAX_INPUTS = 8
MAX_STATES = 128
MAX_OBSERVER_OUTPUTS = MAX_OUTPUTS + MAX_INPUTS
MAX_OBSERVER_INPUTS = MAX_OUTPUTS + 2 * MAX_INPUTS
MAX_HANDOVER_STATES = 128

#: Sequence number meaning "none".
NO_SEQ = 2**64 - 1

u64 = ctypes.c_uint64
u32 = ctypes.c_uint32
f64 = ctypes.c_double


class Flags:
    """Bits of the messages' ``flags`` field (shared/protocol messages.rs)."""

    END_OF_RUN = 1 << 0
    HELD_INPUT = 1 << 1
    STALLED_TICK = 1 << 2
    STALE_ESTIMATE = 1 << 3
    LOCKSTEP = 1 << 4
    CLAMPED = 1 << 5
    FALLBACK = 1 << 6
    OBSERVER_FALLBACK = 1 << 7
    STANDBY = 1 << 8
    CONVERGING = 1 << 9
    EXCITING = 1 << 10
    EXCITING_REFERENCE = 1 << 11
    ANSWERED_LATE = 1 << 12


class HandoverMark:
    """:attr:`Handover.shadow`: how the publishing instance stands."""

    ACTIVE = 0
    FOLLOWING = 1
    CATCHING_UP = 2


class _Message(ctypes.Structure):
    """A fixed-size message; ``TYPE_NAME`` is its iceoryx2 type name."""

    TYPE_NAME = ""

    @classmethod
    def type_name(cls):
        # iceoryx2's Python binding asks the payload type for its name here.
        return cls.TYPE_NAME


class Measurement(_Message):
    """y(k) from the plant, published at tick k."""

    TYPE_NAME = "flexloop.Measurement.v4"
    _fields_ = [
        ("seq", u64),
        ("tick_ns", u64),
        ("woke_ns", u64),
        ("published_ns", u64),
        ("command_seq", u64),
        ("misses", u64),
        ("late_commands", u64),
        ("stalled_ticks", u64),
        ("stall_misses", u64),
        ("fallback_ticks", u64),
        ("rejected_commands", u64),
        ("flags", u32),
        ("generation", u32),
        ("n_outputs", u32),
        ("n_inputs", u32),
        ("y", f64 * MAX_OUTPUTS),
        ("y_true", f64 * MAX_OUTPUTS),
        ("u_applied", f64 * MAX_INPUTS),
        ("u_pending", f64 * MAX_INPUTS),
        ("excitation", f64),
    ]


class Estimate(_Message):
    """The observer's contribution for tick ``seq``, from measurement seq-1."""

    TYPE_NAME = "flexloop.Estimate.v3"
    _fields_ = [
        ("seq", u64),
        ("source_tick_ns", u64),
        ("source_published_ns", u64),
        ("received_ns", u64),
        ("published_ns", u64),
        ("flags", u32),
        ("generation", u32),
        ("n_outputs", u32),
        ("n_inputs", u32),
        ("n_states", u32),
        ("reserved", u32),
        ("free", f64 * MAX_OBSERVER_OUTPUTS),
        ("direct", f64 * (MAX_OBSERVER_OUTPUTS * MAX_OBSERVER_INPUTS)),
        ("x_hat", f64 * MAX_STATES),
        ("innovation", f64 * MAX_OUTPUTS),
    ]


class Command(_Message):
    """u_c(k), computed from y(k), held by the plant over [t_k+1, t_k+2)."""

    TYPE_NAME = "flexloop.Command.v1"
    _fields_ = [
        ("seq", u64),
        ("tick_ns", u64),
        ("measurement_published_ns", u64),
        ("received_ns", u64),
        ("published_ns", u64),
        ("estimate_seq", u64),
        ("estimate_published_ns", u64),
        ("flags", u32),
        ("generation", u32),
        ("n_inputs", u32),
        ("n_outputs", u32),
        ("u", f64 * MAX_INPUTS),
        ("u_fb", f64 * MAX_INPUTS),
        ("u_ff", f64 * MAX_INPUTS),
        ("u_d", f64 * MAX_INPUTS),
        ("r", f64 * MAX_OUTPUTS),
        ("e_meas", f64 * MAX_OUTPUTS),
    ]


class Handover(_Message):
    """A component's state after it processed measurement ``seq``."""

    TYPE_NAME = "flexloop.Handover.v2"
    _fields_ = [
        ("seq", u64),
        ("design_hash", u64),
        ("generation", u32),
        ("shadow", u32),
        ("n_states", u32),
        ("n_inputs", u32),
        ("carried_hash", u64),
        ("carried_at", u32),
        ("carried_len", u32),
        ("state", f64 * MAX_HANDOVER_STATES),
        ("u", f64 * MAX_INPUTS),
    ]


class Activation(_Message):
    """Which controller and observer generation owns which samples."""

    TYPE_NAME = "flexloop.Activation.v1"
    _fields_ = [
        ("published_ns", u64),
        ("controller_from_seq", u64),
        ("observer_from_seq", u64),
        ("controller_generation", u32),
        ("previous_controller_generation", u32),
        ("observer_generation", u32),
        ("previous_observer_generation", u32),
    ]

    def controller_for(self, seq):
        """The controller generation whose command for ``seq`` counts."""
        if seq >= self.controller_from_seq:
            return self.controller_generation
        return self.previous_controller_generation

    def observer_for(self, seq):
        """The observer generation whose estimate for ``seq`` counts."""
        if seq >= self.observer_from_seq:
            return self.observer_generation
        return self.previous_observer_generation


#: Every message, by the name shared/protocol's wire description uses.
MESSAGES = {
    "Measurement": Measurement,
    "Estimate": Estimate,
    "Command": Command,
    "Handover": Handover,
    "Activation": Activation,
}


def wire_description():
    """shared/protocol's contract (``wire.json``, shipped with the package)."""
    text = resources.files(__package__).joinpath("wire.json").read_text()
    return json.loads(text)


class WireMismatch(Exception):
    """A definition here disagrees with shared/protocol's."""


def check_against_wire(description=None):
    """Raises :class:`WireMismatch` naming the first message whose type
    name, size or alignment differs from shared/protocol's."""
    description = description or wire_description()
    for m in description["messages"]:
        cls = MESSAGES.get(m["name"])
        if cls is None:
            raise WireMismatch(f"wire.json: message {m['name']} has no Python definition")
        got = (cls.TYPE_NAME, ctypes.sizeof(cls), ctypes.alignment(cls))
        want = (m["iceoryx2_type_name"], m["size"], m["align"])
        if got != want:
            raise WireMismatch(
                f"{m['name']}: Python has (type name, size, alignment) {got}, "
                f"shared/protocol {want}"
            )
