"""excavator-surrogate: learn system-level LSTM surrogates of hydraulic excavators.

Pipeline: simulate -> clean -> train -> evaluate -> env -> control.  See docs/design.md.

Importing the package registers the Gymnasium environments ``ExcavatorMujoco-v0`` and
``ExcavatorSurrogate-v0`` (as environment packages do), so ``gym.make(...)`` works after a
plain ``import excavator_surrogate``.  Registration imports gymnasium only: torch, MuJoCo
and the environment classes load on first use.
"""

from __future__ import annotations

import logging

from . import numerics as _numerics

_numerics.prepare_environment()  # EXSUR_NUMERICS=portable reaches torch before torch loads

from . import env as _env  # noqa: E402, F401  (registers the Gymnasium environments)
from .errors import CheckpointError, ConfigError, DataError, ExsurError  # noqa: E402
from .spec import EXCAVATOR, InputSpec, JointSpec, MachineSpec, excavator_spec  # noqa: E402
from .version import __version__  # noqa: E402

# a library logs, the application decides what is shown (the CLI: io_utils.setup_logging)
logging.getLogger(__name__).addHandler(logging.NullHandler())

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
