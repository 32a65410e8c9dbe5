"""Stable-Baselines3 view of a Gymnasium 1.x vector environment (needs the ``[control]`` extra).

SB3 steps its own ``VecEnv`` interface; :class:`GymnasiumVecEnv` adapts any
``gymnasium.vector.VectorEnv`` in ``SAME_STEP`` autoreset mode to it -- the batched
:class:`~excavator_surrogate.env.vector.SurrogateVectorEnv` (one torch batch) as well as a
``SyncVectorEnv`` of ``ExcavatorMujoco-v0`` plants -- so the same SB3 algorithm trains on
either without copies of the environment.  Actions are exposed in ``[-1, 1]`` per joint and
mapped linearly onto each joint's command range (SB3's Gaussian policies start with unit
standard deviation).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from stable_baselines3.common.vec_env import VecEnv

from ..errors import ConfigError


def unit_to_command(a: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Commands ``(..., n_joint)`` [command units] from actions ``a`` in ``[-1, 1]`` (clipped),
    mapped linearly onto ``[low, high]``."""
    a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
    return low + 0.5 * (a + 1.0) * (high - low)


class GymnasiumVecEnv(VecEnv):
    """SB3 ``VecEnv`` over a Gymnasium ``VectorEnv`` with ``autoreset_mode=SAME_STEP``.

    Args:
        env: the vector environment (``metadata["autoreset_mode"]`` must be ``SAME_STEP``).

    ``infos[i]`` carries SB3's ``terminal_observation`` and ``TimeLimit.truncated`` for the
    envs that ended in the step (taken from gymnasium's ``final_obs``).
    """

    def __init__(self, env: VectorEnv) -> None:
        mode = env.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise ConfigError(
                f"GymnasiumVecEnv: the vector env must use autoreset_mode=SAME_STEP, got {mode}"
            )
        self.env = env
        box = env.single_action_space
        assert isinstance(box, spaces.Box)
        self.low = box.low.astype(np.float64)
        self.high = box.high.astype(np.float64)
        unit = spaces.Box(-1.0, 1.0, box.shape, dtype=np.float32)
        self.render_mode = None
        super().__init__(env.num_envs, env.single_observation_space, unit)
        self._actions = np.zeros((env.num_envs, *box.shape))

    def command(self, a: np.ndarray) -> np.ndarray:
        """Commands (n_envs, n_joint) [command units] from actions in ``[-1, 1]``."""
        return unit_to_command(a, self.low, self.high)

    def reset(self) -> np.ndarray:
        """Reset all envs (with the seeds of :meth:`seed`, if any); returns (n_envs, n_obs)."""
        seeds = self._seeds
        seed: Any = None if all(s is None for s in seeds) else list(seeds)
        obs, _ = self.env.reset(seed=seed)
        self._reset_seeds()
        return np.asarray(obs, dtype=np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        """Remember the actions for :meth:`step_wait`."""
        self._actions = self.command(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Step every env; finished envs are already reset (their final obs in ``infos``)."""
        obs, reward, terminated, truncated, info = self.env.step(self._actions.astype(np.float32))
        done = np.asarray(terminated) | np.asarray(truncated)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if done.any():
            final = info.get("final_obs")
            for i in np.flatnonzero(done):
                infos[i]["terminal_observation"] = np.asarray(final[i], dtype=np.float32)
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                infos[i]["is_success"] = bool(terminated[i])
        return (
            np.asarray(obs, dtype=np.float32),
            np.asarray(reward, dtype=np.float32),
            done,
            infos,
        )

    def close(self) -> None:
        """Close the vector env."""
        self.env.close()

    # ---- SB3 bookkeeping: attributes of the (single) wrapped env ----------------------------

    def _indices(self, indices: Any) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        """The vector env's attribute, once per index (``render_mode`` is None)."""
        if attr_name == "render_mode":
            return [None for _ in self._indices(indices)]
        return [getattr(self.env, attr_name) for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        """Set an attribute of the vector env."""
        setattr(self.env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of the vector env once."""
        return [getattr(self.env, method_name)(*method_args, **method_kwargs)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: Any = None) -> list[bool]:
        """Never wrapped (the vector env is used as is)."""
        return [False for _ in self._indices(indices)]
