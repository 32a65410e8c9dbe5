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


def info_rows(info: dict[str, Any], n_envs: int) -> list[dict[str, Any]]:
    """Per-env dicts (``n_envs`` of them) from a Gymnasium vector ``info``: env ``i`` gets
    ``info[k][i]`` for every key ``k`` whose mask ``info["_" + k]`` is set for it (every env
    without a mask), nested dicts likewise; mask keys (``_k``) are dropped, as in
    ``gymnasium.wrappers.vector.DictInfoToList``.  Array rows are copies (the env may reuse
    its arrays)."""
    rows: list[dict[str, Any]] = [{} for _ in range(n_envs)]
    for key, value in info.items():
        if key.startswith("_"):
            continue
        mask = info.get(f"_{key}")
        which = range(n_envs) if mask is None else np.flatnonzero(mask)
        if isinstance(value, dict):
            sub = info_rows(value, n_envs)
            for i in which:
                rows[i][key] = sub[i]
        else:
            values = np.array(value, copy=True)
            for i in which:
                rows[i][key] = values[i]
    return rows


def _same(a: Any, b: Any) -> bool:
    """Whether two option values are equal (dicts key by key, arrays element by element)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    try:
        return bool(np.array_equal(a, b))
    except (TypeError, ValueError):  # ragged sequences: not provably equal
        return False


class GymnasiumVecEnv(VecEnv):
    """SB3 ``VecEnv`` over a Gymnasium ``VectorEnv`` with ``autoreset_mode=SAME_STEP``.

    Args:
        env: the vector environment (``metadata["autoreset_mode"]`` must be ``SAME_STEP``).

    As SB3's ``DummyVecEnv``: ``infos[i]`` is env ``i``'s step info (Gymnasium's dict info
    split by its ``_key`` masks, :func:`info_rows`; for an env that ended in the step, its
    final step's ``final_info``) with ``TimeLimit.truncated``, and for an env that ended
    ``terminal_observation`` (Gymnasium's ``final_obs``) and ``is_success`` (terminated,
    unless the env gives its own); ``reset_infos[i]`` is env ``i``'s last reset info.
    ``set_options`` reaches the next :meth:`reset` (one dict for all envs: a Gymnasium vector
    env takes one).  The vector env is one object: ``get_attr``, ``set_attr`` and
    ``env_method`` act on it once and repeat the result for each index.
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
        """Reset all envs with the seeds of :meth:`seed` and the options of
        :meth:`set_options`, if any (both used once); returns (n_envs, n_obs).

        Raises:
            ConfigError: ``set_options`` gave different options per env (a Gymnasium vector
                env takes one dict for all; per-env values go inside it, e.g.
                ``SurrogateVectorEnv``'s ``theta0`` of shape (n_envs, n_joint)).
        """
        seeds, options = self._seeds, self._options
        seed: Any = None if all(s is None for s in seeds) else list(seeds)
        differ = [i for i, o in enumerate(options) if not _same(o, options[0])]
        if differ:
            raise ConfigError(
                f"GymnasiumVecEnv.reset: set_options gave env {differ[0]} other options than "
                "env 0; a Gymnasium vector env takes one options dict for all envs: pass one "
                "dict (per-env values inside it, e.g. theta0 of shape (n_envs, n_joint))"
            )
        obs, info = self.env.reset(seed=seed, options=options[0] or None)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = info_rows(info, self.num_envs)
        return np.asarray(obs, dtype=np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        """Remember the actions for :meth:`step_wait`."""
        self._actions = self.command(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Step every env; finished envs are already reset (their final obs in ``infos``)."""
        obs, reward, terminated, truncated, info = self.env.step(self._actions.astype(np.float32))
        terminated, truncated = np.asarray(terminated), np.asarray(truncated)
        done = terminated | truncated
        final_obs, final_info = info.get("final_obs"), info.get("final_info", {})
        step = {k: v for k, v in info.items() if k.lstrip("_") not in ("final_obs", "final_info")}
        infos = info_rows(step, self.num_envs)
        if done.any():
            finals = info_rows(final_info, self.num_envs)
            for i in np.flatnonzero(done):
                self.reset_infos[i] = infos[i]  # the autoreset's info; the step's is final_info
                infos[i] = finals[i]
                infos[i]["terminal_observation"] = np.asarray(final_obs[i], dtype=np.float32)
                infos[i].setdefault("is_success", bool(terminated[i]))
        for i, row in enumerate(infos):
            row["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
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
        """Set an attribute of the vector env (once, whatever ``indices``)."""
        setattr(self.env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of the vector env once; its result once per index (SB3 reads one
        result per index, e.g. HER's ``compute_reward`` with ``indices=[0]``)."""
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: Any = None) -> list[bool]:
        """Never wrapped (the vector env is used as is)."""
        return [False for _ in self._indices(indices)]
