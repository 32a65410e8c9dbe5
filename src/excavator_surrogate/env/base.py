"""Shared machinery of the single excavator environments (spaces, resets, safety, tasks).

Subclasses provide the dynamics through two methods acting on one machine:

- ``_dyn_reset(theta0)``: put the machine at rest at ``theta0`` (n_joint,) [rad];
- ``_dyn_step(u)``: apply ``u`` (n_u,) for one control period ``T_s`` (the joints' commands,
  then the exogenous inputs', see :mod:`.inputs`); return
  ``(theta[k+1], omega[k+1])`` (n_joint,) float64 [rad], [rad/s] with ``theta`` unwrapped.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..errors import ConfigError
from ..spec import MachineSpec
from .inputs import ActionLayout
from .safety import (
    GUARD_NAMES,
    GUARD_OK,
    ActionChecker,
    ActionMode,
    DivergenceGuard,
    GuardConfig,
)
from .tasks import Task, start_pose


def action_space(spec: MachineSpec, layout: ActionLayout | None = None) -> spaces.Box:
    """``Box(u_min, u_max, (n_action,), float32)`` from the command ranges of the action's
    columns (default: every command column, ``n_action = spec.n_u``)."""
    cols = (layout or ActionLayout(spec)).columns
    lo = np.array([c.u_min for c in cols], dtype=np.float32)
    hi = np.array([c.u_max for c in cols], dtype=np.float32)
    return spaces.Box(lo, hi, dtype=np.float32)


def observation_space(spec: MachineSpec, *, wrap: bool = True) -> spaces.Box:
    """``Box((2 n_joint,), float32)``: θ per joint then ω per joint.

    Periodic joints' θ lies in ``[-π, π]`` when ``wrap`` is True; every other entry is unbounded
    (the surrogate may leave the joint limits; the divergence guard reports it).
    """
    n = spec.n_joint
    lo = np.full(2 * n, -np.inf, dtype=np.float32)
    hi = np.full(2 * n, np.inf, dtype=np.float32)
    if wrap:
        for k, j in enumerate(spec.joints):
            if j.periodic:
                lo[k], hi[k] = -math.pi, math.pi
    return spaces.Box(lo, hi, dtype=np.float32)


def check_theta0(spec: MachineSpec, theta0: Any, *, where: str) -> np.ndarray:
    """Validate a start pose: (n_joint,) finite, limited joints inside their limits."""
    th = np.asarray(theta0, dtype=np.float64).reshape(-1)
    if th.shape != (spec.n_joint,) or not np.isfinite(th).all():
        raise ConfigError(
            f"{where}: theta0 must be {spec.n_joint} finite angles in rad for joints "
            f"{list(spec.names)}, got {np.asarray(theta0).tolist()}"
        )
    for k, j in enumerate(spec.joints):
        if j.periodic:
            continue
        if (j.theta_min is not None and th[k] < j.theta_min - 1e-9) or (
            j.theta_max is not None and th[k] > j.theta_max + 1e-9
        ):
            raise ConfigError(
                f"{where}: theta0[{k}] ({j.name}) = {th[k]:.4g} rad is outside the joint limits "
                f"[{j.theta_min}, {j.theta_max}]"
            )
    return th


class ExcavatorEnv(gym.Env[np.ndarray, np.ndarray]):
    """Base class of ``ExcavatorMujoco-v0`` and ``ExcavatorSurrogate-v0`` (see their docstrings).

    Args (keyword-only, shared by both environments):
        spec: the machine.
        task: optional reward/termination hook (:class:`~.tasks.Task`); None -> reward 0.
        action_mode: ``"clip"`` or ``"reject"`` out-of-range commands.
        guard: divergence-guard thresholds.
        wrap_theta: wrap periodic joints' θ to ``[-π, π)`` in the observation.
        reset_margin: fraction of each joint range avoided when sampling random start poses.
        inputs: exogenous inputs held fixed (``{"engine_rpm": 1800.0}``), left out of the
            action; the others are part of it (:mod:`.inputs`).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "render_fps": 20}
    env_id: ClassVar[str] = "Excavator"

    def __init__(
        self,
        *,
        spec: MachineSpec,
        task: Task | None = None,
        action_mode: ActionMode = "clip",
        guard: GuardConfig | None = None,
        wrap_theta: bool = True,
        reset_margin: float = 0.1,
        inputs: dict[str, float] | None = None,
    ) -> None:
        self.machine = spec
        """The machine (joints, command ranges, rate); ``self.spec`` is gymnasium's EnvSpec."""
        self.task = task
        self.action_mode = action_mode
        self.wrap_theta = bool(wrap_theta)
        self.reset_margin = float(reset_margin)
        self.metadata = {**type(self).metadata, "render_fps": spec.rate_hz}
        self.layout = ActionLayout.make(spec, inputs, where=self.env_id)
        """The action's columns and the fixed exogenous inputs."""
        self.action_space = action_space(spec, self.layout)
        self.observation_space = observation_space(spec, wrap=self.wrap_theta)
        self._check_action = ActionChecker(
            spec, env_name=self.env_id, action_mode=action_mode, layout=self.layout
        )
        self._guard = DivergenceGuard(spec, guard)
        self._periodic = np.asarray(spec.periodic, dtype=bool)
        self._wrap = self.wrap_theta and bool(self._periodic.any())
        n = spec.n_joint
        self.theta = np.zeros(n)
        """Current angles (n_joint,) [rad], unwrapped."""
        self.omega = np.zeros(n)
        """Current angular velocities (n_joint,) [rad/s]."""
        self._last_obs = np.zeros(2 * n, dtype=np.float32)
        self._n_step = 0

    # ---- to implement -------------------------------------------------------------------------

    def _dyn_reset(self, theta0: np.ndarray) -> None:
        raise NotImplementedError

    def _dyn_step(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    # ---- gymnasium API ------------------------------------------------------------------------

    def _obs(self) -> np.ndarray:
        th = self.theta
        if self._wrap:
            th = th.copy()
            p = self._periodic
            th[p] = (th[p] + math.pi) % (2.0 * math.pi) - math.pi
        return np.concatenate([th, self.omega]).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start at rest at ``options["theta0"]`` (n_joint,) [rad] or at a random pose.

        Random poses are uniform in ``[-π, π)`` for periodic joints and inside the joint limits
        (shrunk by ``reset_margin`` of the range) otherwise, drawn from ``self.np_random``; a
        task with ``sample_start`` (e.g. ``ReachTask(start_radius=...)``) chooses them instead.
        """
        super().reset(seed=seed)
        options = options or {}
        if options.get("theta0") is not None:
            theta0 = check_theta0(self.machine, options["theta0"], where=f"{self.env_id}.reset")
        else:
            theta0 = start_pose(self.machine, self.task, self.np_random, margin=self.reset_margin)
        self._dyn_reset(theta0)
        self.theta = theta0.copy()
        self.omega = np.zeros(self.machine.n_joint)
        self._n_step = 0
        info: dict[str, Any] = {"theta": self.theta.copy()}
        if self.task is not None:
            extra = self.task.reset(
                self.theta[None], mask=np.ones(1, dtype=bool), rng=self.np_random, options=options
            )
            info.update({k: v[0] for k, v in extra.items()})
        self._last_obs = self._obs()
        return self._last_obs.copy(), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply one command vector for ``T_s``; see the class docstring for the tables.

        Raises:
            ActionError: non-finite action, wrong shape, or out of range with ``action_mode="reject"``.
        """
        u = self.layout.full(self._check_action(action))
        theta, omega = self._dyn_step(u)
        self._n_step += 1
        code, violation = self._guard.check(theta[None], omega[None])
        c = int(code[0])
        info: dict[str, Any] = {
            "guard": GUARD_NAMES[c],
            "limit_violation": violation[0],
            "u": u,
        }
        truncated = c != GUARD_OK
        finite = bool(np.isfinite(theta).all() and np.isfinite(omega).all())
        if finite:
            self.theta = np.asarray(theta, dtype=np.float64)
            self.omega = np.asarray(omega, dtype=np.float64)
            self._last_obs = self._obs()
        # else: the observation keeps the last finite state (and the episode is truncated)
        reward, terminated = 0.0, False
        if self.task is not None and finite:
            u_joint = u[None, : self.machine.n_joint]
            r, done, extra = self.task.evaluate(self.theta[None], self.omega[None], u_joint)
            reward, terminated = float(r[0]), bool(done[0])
            info.update({k: v[0] for k, v in extra.items()})
        return self._last_obs.copy(), reward, terminated, truncated, info
