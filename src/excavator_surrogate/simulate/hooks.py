"""Extension points of the MuJoCo plant: command transforms and external forces.

The Stage I plant is ideal: the command sequence at the control rate is held constant over
each control period (zero-order hold) and fed straight to the MJCF actuators.  Later stages
(hydraulics, soil) plug in here without touching :mod:`.plant`:

- a :class:`CommandTransform` maps commands at the CONTROL rate to actuator demands at the
  PHYSICS rate (dead zone, valve lag, transport delay, flow sharing ...) before MuJoCo sees
  them.  It is used by both the Python loop and the batched ``mujoco.rollout`` path.
- a :class:`ForceHook` is called before every physics step of the Python-loop path and may
  write external forces into ``data.qfrc_applied`` / ``data.xfrc_applied`` (soil, payload).
  The batched path cannot call Python per physics step and refuses plants with a force hook.

See docs/plant.md ("Hooks").
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import mujoco
import numpy as np


@runtime_checkable
class CommandTransform(Protocol):
    """Maps control-rate commands to physics-rate actuator demands (stateful, streaming).

    Contract:

    - :meth:`reset` is called at the start of every episode (or batch of episodes).
    - :meth:`__call__` receives consecutive chunks of the command sequence,
      ``u: (n_batch, n_step, n_joint)`` in command units, and returns the actuator demand
      ``(n_batch, n_step * substeps, n_joint)`` at the physics rate, joints in spec order,
      in the MJCF's ``ctrl`` units (command units for the packaged model).
    - It must be causal and streaming-consistent: feeding a sequence in one chunk or in
      several consecutive chunks (down to one step at a time) gives identical output.
      The Python loop calls it one step at a time, the batched rollout in chunks, and the
      two paths are tested to agree.
    """

    def reset(self, *, n_batch: int, substeps: int, timestep: float) -> None:
        """Start new episodes: ``n_batch`` parallel sequences, ``substeps`` physics steps of
        ``timestep`` seconds per control step."""
        ...

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """``u: (n_batch, n_step, n_joint)`` -> ``(n_batch, n_step * substeps, n_joint)``."""
        ...


class ZeroOrderHold:
    """Identity transform of the ideal Stage I plant: hold each command for one control period."""

    def __init__(self) -> None:
        self.substeps = 1

    def reset(self, *, n_batch: int, substeps: int, timestep: float) -> None:
        """Remember the number of physics steps per control step (stateless otherwise)."""
        del n_batch, timestep
        self.substeps = int(substeps)

    def tiled(self, n_batch: int) -> ZeroOrderHold:
        """A copy for ``n_batch`` parallel sequences (stateless: the same transform)."""
        del n_batch
        out = ZeroOrderHold()
        out.substeps = self.substeps
        return out

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """``u: (n_batch, n_step, n_joint)`` -> ``(n_batch, n_step * substeps, n_joint)``."""
        return np.repeat(np.asarray(u, dtype=np.float64), self.substeps, axis=1)


@runtime_checkable
class ForceHook(Protocol):
    """Called before every physics step of the Python-loop path (e.g. soil forces).

    Write forces into ``data.qfrc_applied`` (generalised, N m for hinges) or
    ``data.xfrc_applied`` (Cartesian, per body); read the state from ``data``.
    """

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Apply external forces for the coming physics step."""
        ...
