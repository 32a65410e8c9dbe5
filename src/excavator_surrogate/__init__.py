"""excavator-surrogate: learn system-level LSTM surrogates of hydraulic excavators.

Pipeline: simulate -> clean -> train -> evaluate -> env.  See docs/design.md.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .errors import CheckpointError, ConfigError, DataError, ExsurError
from .spec import EXCAVATOR, InputSpec, JointSpec, MachineSpec, excavator_spec

__all__ = [
    "EXCAVATOR",
    "CheckpointError",
    "ConfigError",
    "DataError",
    "ExsurError",
    "InputSpec",
    "JointSpec",
    "MachineSpec",
    "__version__",
    "excavator_spec",
]
