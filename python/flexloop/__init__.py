"""flexloop: write the loop's controller in Python.

Derive from :class:`Controller`, implement ``step``, and hand the class to
:func:`run`; a scenario's ``[controller] exec = ["python3", "my_law.py"]``
makes flexloop start it for the controller role (or ``flexloop swap
controller`` swaps it into a running loop). See python/README.md.
"""

from .controller import Controller
from .launch import Params, Reference, ScenarioError, Setup
from .messages import Activation, Command, Estimate, Flags, Handover, Measurement
from .runner import run

__all__ = [
    "Activation",
    "Command",
    "Controller",
    "Estimate",
    "Flags",
    "Handover",
    "Measurement",
    "Params",
    "Reference",
    "ScenarioError",
    "Setup",
    "run",
]
