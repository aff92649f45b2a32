"""flexloop: write the loop's controller or observer in Python.

Derive from :class:`Controller`, implement ``step``, and hand the class to
:func:`run`; or derive from :class:`Observer`, implement ``initial`` and
``step``, and hand it to :func:`run_observer`. A scenario's
``[controller] exec = ["/path/to/venv/bin/python", "my_law.py"]`` (or
``[observer] exec = …``) makes flexloop start it for the role (or ``flexloop
swap controller|observer`` swaps it into a running loop). See
python/README.md.
"""

from .controller import Controller, Output
from .errors import ScenarioError, SetupError
from .launch import Params, Setup
from .messages import Activation, Command, Estimate, Flags, Handover, Measurement
from .observer import Estimated, Observer
from .observer_runner import run_observer
from .reference import Reference, Setpoint, SetpointParams
from .runner import run

__all__ = [
    "Activation",
    "Command",
    "Controller",
    "Estimate",
    "Estimated",
    "Flags",
    "Handover",
    "Measurement",
    "Observer",
    "Output",
    "Params",
    "Reference",
    "ScenarioError",
    "Setpoint",
    "SetpointParams",
    "Setup",
    "SetupError",
    "run",
    "run_observer",
]
