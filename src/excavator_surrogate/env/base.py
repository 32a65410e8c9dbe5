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
import mujoco
import numpy as np
from gymnasium import spaces

from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.angles import joint_limits
from .inputs import ActionLayout
from .render import (
    RENDER_MODES,
    RENDER_SIZE,
    FrameRenderer,
    Viewer,
    check_render_mode,
    check_size,
)
from .safety import (
    GUARD_NAMES,
    GUARD_OK,
    ActionChecker,
    ActionMode,
    ActionScale,
    DivergenceGuard,
    GuardConfig,
    check_action_scale,
)
from .tasks import Task, start_pose


def action_space(
    spec: MachineSpec, layout: ActionLayout | None = None, *, scale: ActionScale = "raw"
) -> spaces.Box:
    """The action's Box, float32, ``(n_action,)`` over the action's columns (default: every
    command column, ``n_action = spec.n_u``): ``[u_min, u_max]`` per column with
    ``scale="raw"``, ``[-1, 1]`` with ``scale="normalized"``."""
    cols = (layout or ActionLayout(spec)).columns
    if check_action_scale(scale) == "normalized":
        return spaces.Box(-1.0, 1.0, (len(cols),), dtype=np.float32)
    lo = np.array([c.u_min for c in cols], dtype=np.float32)
    hi = np.array([c.u_max for c in cols], dtype=np.float32)
    return spaces.Box(lo, hi, dtype=np.float32)


def observation_space(
    spec: MachineSpec, *, wrap: bool = True, guard: GuardConfig | None = None
) -> spaces.Box:
    """``Box((2 n_joint,), float32)``: θ per joint then ω per joint, finite where the
    envelope gives a bound.

    - θ of a periodic joint: ``[-π, π]`` when ``wrap`` is True, else unbounded;
    - θ of a limited joint: its limits widened by the guard's ``limit_margin`` (the
      divergence guard truncates beyond); unbounded without a limit or a margin;
    - ω: ``±guard.omega_max`` (truncation beyond); unbounded if that check is off.

    Observations are clipped into these bounds; they differ from the state only on a step
    the guard truncates (``env.unwrapped.theta`` / ``omega`` hold the unclipped values).
    """
    guard = guard or GuardConfig()
    n = spec.n_joint
    lo = np.full(2 * n, -np.inf, dtype=np.float32)
    hi = np.full(2 * n, np.inf, dtype=np.float32)
    for k, j in enumerate(spec.joints):
        if j.periodic:
            if wrap:
                lo[k], hi[k] = -math.pi, math.pi
        elif guard.limit_margin is not None:
            if j.theta_min is not None:
                lo[k] = j.theta_min - guard.limit_margin
            if j.theta_max is not None:
                hi[k] = j.theta_max + guard.limit_margin
    if guard.omega_max is not None:
        lo[n:], hi[n:] = -guard.omega_max, guard.omega_max
    return spaces.Box(lo, hi, dtype=np.float32)


THETA0_SLACK = 0.02
"""A given start pose may lie this fraction of a joint's range beyond its end stop: it starts
at the stop, and a warning says so (a pose read off a log at a stop, plus sensor noise, or
a model whose stops are its training data's range).  Farther out is an error."""


def check_theta0(spec: MachineSpec, theta0: Any, *, where: str, warn: bool = True) -> np.ndarray:
    """Validate a start pose: (n_joint,) finite, limited joints inside their limits.

    A limited joint up to :data:`THETA0_SLACK` of its range beyond a limit starts at that
    limit, with one warning naming the joint and the distance (``warn=False``: no warning,
    the caller says it); farther out raises.

    Returns:
        The pose (n_joint,) [rad], float64, clipped into the limits.
    """
    try:
        th = np.asarray(theta0, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):  # text, ragged lists, None entries
        th = np.full(0, np.nan)
    if th.shape != (spec.n_joint,) or not np.isfinite(th).all():
        raise ConfigError(
            f"{where}: theta0 must be {spec.n_joint} finite angles in rad for joints "
            f"{list(spec.names)}, got {theta0!r:.200}"
        )
    th = th.copy()
    for k, (j, lo, hi) in enumerate(zip(spec.joints, *joint_limits(spec))):
        # lo, hi = -inf, +inf for a periodic joint or an open limit: never beyond
        span = hi - lo
        slack = THETA0_SLACK * span if math.isfinite(span) else 0.0
        beyond = max(lo - th[k], th[k] - hi)
        if beyond <= 1e-9:
            continue
        if beyond > slack + 1e-9:
            raise ConfigError(
                f"{where}: theta0[{k}] ({j.name}) = {th[k]:.4g} rad is outside the joint limits "
                f"[{j.theta_min}, {j.theta_max}] by {math.degrees(beyond):.3g} deg, more than "
                f"{THETA0_SLACK:.0%} of the range: give a start pose inside them"
            )
        stop = lo if th[k] < lo else hi
        if warn:
            gym.logger.warn(
                f"{where}: theta0[{k}] ({j.name}) = {th[k]:.4g} rad is "
                f"{math.degrees(beyond):.3g} deg beyond its end stop {stop:.4g} rad: it starts "
                "at the stop"
            )
        th[k] = stop
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
        action_scale: ``"raw"`` (actions in command units, ``[u_min, u_max]``) or
            ``"normalized"`` (``[-1, 1]`` per column, mapped linearly onto the range: what
            Stable-Baselines3 and Gymnasium's checkers expect).
        render_mode: None, ``"rgb_array"`` (headless frames, :meth:`render`) or ``"human"``
            (MuJoCo's viewer, needs a display); see :mod:`.render`.
        render_size: ``(width, height)`` of ``rgb_array`` frames [pixels].

    Subclasses provide the scene to draw with ``_scene() -> (MjModel, MjData)``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": list(RENDER_MODES), "render_fps": 20}
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
        action_scale: ActionScale = "raw",
        render_mode: str | None = None,
        render_size: tuple[int, int] = RENDER_SIZE,
    ) -> None:
        self.render_mode = check_render_mode(render_mode, where=self.env_id)
        self.render_size = check_size(render_size, where=self.env_id)
        self._renderer: FrameRenderer | None = None
        self._viewer: Viewer | None = None
        self.machine = spec
        """The machine (joints, command ranges, rate); ``self.spec`` is gymnasium's EnvSpec."""
        self.task = task
        self.action_mode = action_mode
        self.wrap_theta = bool(wrap_theta)
        self.reset_margin = float(reset_margin)
        self.metadata = {**type(self).metadata, "render_fps": spec.rate_hz}
        self.layout = ActionLayout.make(spec, inputs, where=self.env_id)
        """The action's columns and the fixed exogenous inputs."""
        self.action_scale = check_action_scale(action_scale)
        self.action_space = action_space(spec, self.layout, scale=action_scale)
        self.observation_space = observation_space(spec, wrap=self.wrap_theta, guard=guard)
        self._obs_lo = self.observation_space.low
        self._obs_hi = self.observation_space.high
        self._check_action = ActionChecker(
            spec,
            env_name=self.env_id,
            action_mode=action_mode,
            layout=self.layout,
            scale=action_scale,
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

    def _dyn_info(self) -> dict[str, Any]:
        """Extra step ``info`` entries of the dynamics (the surrogate's uncertainty)."""
        return {}

    def _scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The MJCF model and the data posed at the current state, for rendering."""
        raise NotImplementedError

    # ---- rendering ----------------------------------------------------------------------------

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the current pose as an ``(height, width, 3)`` uint8 frame;
        ``human``: draw it in the viewer (returns None); no render mode: None.

        Raises:
            RenderError: no OpenGL backend / no display (one line saying what to do).
        """
        if self.render_mode is None:
            gym.logger.warn(
                f"{self.env_id}: render() without a render_mode; pass render_mode='rgb_array' "
                "to gym.make"
            )
            return None
        model, data = self._scene()
        if self.render_mode == "human":
            if self._viewer is None:
                self._viewer = Viewer(model, data, where=self.env_id)
            self._viewer.show()
            return None
        if self._renderer is None:
            self._renderer = FrameRenderer(model, size=self.render_size, where=self.env_id)
        return self._renderer.frame(data)

    def close(self) -> None:
        """Release the renderer and the viewer, if any."""
        for obj in (self._renderer, self._viewer):
            if obj is not None:
                obj.close()
        self._renderer = self._viewer = None
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the renderer and the viewer (recreated on the next frame)."""
        state = self.__dict__.copy()
        state["_renderer"] = state["_viewer"] = None
        return state

    # ---- gymnasium API ------------------------------------------------------------------------

    def _obs(self) -> np.ndarray:
        th = self.theta
        if self._wrap:
            th = th.copy()
            p = self._periodic
            th[p] = (th[p] + math.pi) % (2.0 * math.pi) - math.pi
        obs = np.concatenate([th, self.omega]).astype(np.float32)
        return np.clip(obs, self._obs_lo, self._obs_hi)

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
        if self.render_mode == "human":
            self.render()
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
            "theta": np.array(theta, dtype=np.float64),
            **self._dyn_info(),
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
        if self.render_mode == "human":
            self.render()
        return self._last_obs.copy(), reward, terminated, truncated, info
