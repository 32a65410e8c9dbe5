"""Gymnasium drop-in: ``ExcavatorMujoco-v0`` (the MuJoCo plant) and ``ExcavatorSurrogate-v0``
(a trained checkpoint) with one interface, the batched :class:`SurrogateVectorEnv`, and
ONNX export of the single-step model.  See docs/env.md.

Importing this package registers both environments with gymnasium::

    import gymnasium as gym
    import excavator_surrogate.env  # noqa: F401  (registers the ids)

    env = gym.make("ExcavatorSurrogate-v0", ckpt="runs/quick/model/best.pt")
    envs = gym.make_vec("ExcavatorSurrogate-v0", num_envs=1024,
                        vectorization_mode="vector_entry_point", ckpt="...")

``render_mode="rgb_array"`` (headless frames) and ``action_scale="normalized"`` (``[-1, 1]``
actions, for Stable-Baselines3) work on both; ``render`` draws them, ``plants`` holds the
machine check of every command that runs a checkpoint against the plant.

Classes are imported lazily (``from excavator_surrogate.env import SurrogateVectorEnv``), so
registering does not import torch or MuJoCo.  The equivalence check lives in
:mod:`excavator_surrogate.env.compare` (``compare.compare``).
"""

from __future__ import annotations

import importlib
from typing import Any

MUJOCO_ID = "ExcavatorMujoco-v0"
SURROGATE_ID = "ExcavatorSurrogate-v0"
MAX_EPISODE_STEPS = 1000
"""Registered time limit: 1000 control steps (50 s at 20 Hz)."""

_LAZY = {
    "ExcavatorEnv": ".base",
    "ExcavatorMujocoEnv": ".mujoco_env",
    "ExcavatorSurrogateEnv": ".surrogate_env",
    "SurrogateVectorEnv": ".vector",
    "SurrogateEngine": ".engine",
    "FusedStep": ".engine",
    "Task": ".tasks",
    "ReachTask": ".tasks",
    "RecordedStarts": ".starts",
    "ActionError": ".safety",
    "GuardConfig": ".safety",
    "export_onnx": ".export",
    "OnnxStepper": ".onnx_stepper",
    "RenderError": ".render",
    "side_by_side": ".render",
    "checkpoint_plant": ".plants",
}


def _make_vector(
    ckpt: Any, num_envs: int = 1, *, render_mode: str | None = None, **kwargs: Any
) -> Any:
    """``vector_entry_point`` of ``ExcavatorSurrogate-v0``: a :class:`SurrogateVectorEnv`.

    It does not render: a ``render_mode`` other than None raises a one-line
    :class:`~excavator_surrogate.errors.ConfigError` (``vectorization_mode="sync"`` renders).
    """
    from ..errors import ConfigError
    from .vector import SurrogateVectorEnv

    if render_mode is not None:
        raise ConfigError(
            f"{SURROGATE_ID}: vectorization_mode='vector_entry_point' does not render "
            f"(render_mode={render_mode!r}); use vectorization_mode='sync' for frames"
        )
    kwargs.setdefault("max_episode_steps", MAX_EPISODE_STEPS)
    return SurrogateVectorEnv(ckpt, num_envs, **kwargs)


def register_envs() -> None:
    """Register ``ExcavatorMujoco-v0`` and ``ExcavatorSurrogate-v0`` (idempotent)."""
    import gymnasium

    registry = gymnasium.envs.registration.registry
    if MUJOCO_ID not in registry:
        gymnasium.register(
            id=MUJOCO_ID,
            entry_point="excavator_surrogate.env.mujoco_env:ExcavatorMujocoEnv",
            max_episode_steps=MAX_EPISODE_STEPS,
        )
    if SURROGATE_ID not in registry:
        gymnasium.register(
            id=SURROGATE_ID,
            entry_point="excavator_surrogate.env.surrogate_env:ExcavatorSurrogateEnv",
            vector_entry_point="excavator_surrogate.env:_make_vector",
            max_episode_steps=MAX_EPISODE_STEPS,
        )


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


register_envs()

__all__ = [
    "MAX_EPISODE_STEPS",
    "MUJOCO_ID",
    "SURROGATE_ID",
    "ActionError",
    "ExcavatorEnv",
    "ExcavatorMujocoEnv",
    "ExcavatorSurrogateEnv",
    "FusedStep",
    "GuardConfig",
    "OnnxStepper",
    "ReachTask",
    "RecordedStarts",
    "RenderError",
    "SurrogateEngine",
    "SurrogateVectorEnv",
    "Task",
    "checkpoint_plant",
    "export_onnx",
    "register_envs",
    "side_by_side",
]
