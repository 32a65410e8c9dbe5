"""Simulate stage: MuJoCo excavator (Stage I ideal, Stage II hydraulic stand-in), excitation
signals, soil contact, sensor faults, dataset generation.

See docs/plant.md and docs/hydraulics.md.  Main entry points:

- :class:`~.plant.MujocoExcavator` / :class:`~.plant.PlantConfig`: the plant
  (``reset``/``step`` Python loop, batched ``rollout``).
- :class:`~.hydraulics.HydraulicTransform` / :class:`~.hydraulics.HydraulicConfig`: the
  hydraulic command transform (dead zones, valve curve, lag, delay, pump sharing, relief ...);
  :class:`~.relief.ReliefAntiWindup`: force hook against servo wind-up at relief.
- :class:`~.soil.SoilHook` / :class:`~.soil.SoilConfig`: soil resistance and payload
  (compound operation); :class:`~.soil.ChainHook` combines force hooks.
- :mod:`.excitation`: command signals (``multisine``, ``steps``, ``chirp``, ``prbs``,
  ``work_cycle``) and the closed-loop digging operator (``dig_cycle``,
  :class:`~.dig_operator.DigOperator`).
- :func:`~.generate.simulate_dataset` / :class:`~.generate.SimulateConfig`: datasets.
- :mod:`.hooks`: command-transform and force hooks.
"""

from __future__ import annotations

from .config import SimulateConfig
from .excitation import CLOSED_LOOP, SIGNALS, DigOperator, ExcitationConfig, NominalModel, generate
from .generate import build_plant, simulate_dataset
from .hooks import CommandTransform, ForceHook, ZeroOrderHold
from .hydraulics import HydraulicConfig, HydraulicTransform
from .plant import MujocoExcavator, PlantConfig
from .relief import ReliefAntiWindup
from .soil import ChainHook, SoilConfig, SoilHook

__all__ = [
    "CLOSED_LOOP",
    "SIGNALS",
    "ChainHook",
    "CommandTransform",
    "DigOperator",
    "ExcitationConfig",
    "ForceHook",
    "HydraulicConfig",
    "HydraulicTransform",
    "MujocoExcavator",
    "NominalModel",
    "PlantConfig",
    "ReliefAntiWindup",
    "SimulateConfig",
    "SoilConfig",
    "SoilHook",
    "ZeroOrderHold",
    "build_plant",
    "generate",
    "simulate_dataset",
]
