"""Simulate stage: the Stage I MuJoCo excavator, excitation signals, dataset generation.

See docs/plant.md.  Main entry points:

- :class:`~.plant.MujocoExcavator` / :class:`~.plant.PlantConfig`: the plant
  (``reset``/``step`` Python loop, batched ``rollout``).
- :mod:`.excitation`: command signals (``multisine``, ``steps``, ``chirp``, ``prbs``,
  ``work_cycle``).
- :func:`~.generate.simulate_dataset` / :class:`~.generate.SimulateConfig`: datasets.
- :mod:`.hooks`: command-transform and force hooks for hydraulics and soil.
"""

from __future__ import annotations

from .excitation import SIGNALS, ExcitationConfig, generate
from .generate import SimulateConfig, simulate_dataset
from .hooks import CommandTransform, ForceHook, ZeroOrderHold
from .plant import MujocoExcavator, PlantConfig

__all__ = [
    "SIGNALS",
    "CommandTransform",
    "ExcitationConfig",
    "ForceHook",
    "MujocoExcavator",
    "PlantConfig",
    "SimulateConfig",
    "ZeroOrderHold",
    "generate",
    "simulate_dataset",
]
