"""Controllers built on the surrogate and checked on the plant (docs/control.md).

- :class:`MPPI` (:mod:`.mppi`): sampling-based MPC; every control step rolls ``K``
  candidate command sequences over ``N`` samples out in ONE batched call of a predictor:
  :class:`SurrogatePredictor` (the surrogate, synced to the machine's measured history) or
  :class:`PlantPredictor` (``mujoco.rollout`` on a copy of the plant: the oracle).
- :func:`dig_reference`: a digging-like joint-space reference (approach, penetrate, curl,
  lift, swing, dump, return); :func:`compare_tracking` tracks it with MPPI (surrogate and
  oracle) and the PI baseline :class:`JointPI` on ``ExcavatorMujoco-v0``;
  :func:`prediction_error` says how far the surrogate's own horizon predictions miss a run.
- :func:`compare_rl` (:mod:`.rl`, needs the ``[control]`` extra): PPO from Stable-Baselines3
  trained on :class:`~excavator_surrogate.env.vector.SurrogateVectorEnv` and on the plant,
  both evaluated on the plant.
- :func:`run_control`: both, written as a report folder (``exsur control``).

Names are imported lazily: ``import excavator_surrogate.control`` loads neither torch,
MuJoCo nor Stable-Baselines3.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "MPPI": ".mppi",
    "MPPIConfig": ".mppi",
    "Predictor": ".predict",
    "SurrogatePredictor": ".predict",
    "PlantPredictor": ".predict",
    "JointPI": ".pi",
    "dig_reference": ".reference",
    "compare_tracking": ".tracking",
    "track": ".tracking",
    "prediction_error": ".tracking",
    "RLConfig": ".rl",
    "compare_rl": ".rl",
    "run_control": ".report",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_LAZY)
