"""Shared machinery of the single excavator environments (spaces, resets, safety, tasks).

Subclasses provide the dynamics through two methods acting on one machine:

- ``_dyn_reset(theta0)``: put the machine at rest at ``theta0`` (n_joint,) [rad];
- ``_dyn_step(u)``: apply ``u`` (n_u,) for one control period ``T_s`` (the joints' commands,
  then the exogenous inputs', see :mod:`.inputs`); return
  ``(theta[k+1], omega[k+1])`` (n_joint,) float64 [rad], [rad/s] with ``theta`` unwrapped.
"""

from __future__ import annotations

import copy
import math
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from ..errors import ConfigError
from ..spec import MachineSpec
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
from .starts import RecordedStarts, check_history, check_theta0, last_velocity
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


class ExcavatorEnv(gym.Env[np.ndarray, np.ndarray]):
    """Base class of ``ExcavatorMujoco-v0`` and ``ExcavatorSurrogate-v0`` (see their docstrings).

    Args (keyword-only, shared by both environments):
        spec: the machine.
        task: optional reward/termination hook (:class:`~.tasks.Task`), copied (``self.task``);
            None -> reward 0.
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
        self.task = copy.deepcopy(task)
        """The env's own copy of ``task`` (a task keeps its episodes' state, e.g.
        :class:`~.tasks.ReachTask`'s targets: the envs ``gym.make_vec`` builds from one
        ``task=`` argument never share it)."""
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

    recorded: RecordedStarts | None = None
    """Random resets start at recorded moments of these logs (the surrogate's
    ``recorded_starts``), not at rest; None: at rest at a random pose."""

    def _dyn_reset(self, theta0: np.ndarray) -> None:
        raise NotImplementedError

    def _dyn_reset_history(self, theta: np.ndarray, u: np.ndarray) -> None:
        """Warm up on a recorded history ``theta`` (n_hist, n_joint) [rad], ``u`` (n_hist - 1,
        n_u); dynamics that cannot (the plant) refuse it."""
        raise ConfigError(
            f"{self.env_id}: options['history'] starts only a surrogate from a recorded "
            "history (a log does not hold this model's hidden state); start it at rest with "
            "options['theta0']"
        )

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
        """Start at rest at ``options["theta0"]`` (n_joint,) [rad], at a random pose, or (the
        surrogate) after a recorded history ``options["history"]`` (:mod:`.starts`); without
        either, a surrogate made with ``recorded_starts`` starts at a random recorded moment.

        Random poses are uniform in ``[-π, π)`` for periodic joints and inside the joint limits
        (shrunk by ``reset_margin`` of the range) otherwise, drawn from ``self.np_random``; a
        task with ``sample_start`` (e.g. ``ReachTask(start_radius=...)``) chooses them instead.
        """
        super().reset(seed=seed)
        options = options or {}
        where = f"{self.env_id}.reset"
        history = options.get("history")
        if history is not None and options.get("theta0") is not None:
            raise ConfigError(f"{where}: give options['theta0'] or options['history'], not both")
        drawn = history is None and options.get("theta0") is None and self.recorded is not None
        if drawn:
            assert self.recorded is not None
            theta_rec, u_rec = self.recorded.draw(self.np_random)
            history = {"theta": theta_rec, "u": u_rec}
        if history is not None:
            theta_hist, u_hist = check_history(
                self.machine,
                history,
                where=where,
                # a recorded moment is the machine's own state: a hair past a stop starts at
                # it silently, and a glitch the import let through ends the episode (guard)
                omega_max=None if drawn else self._guard.config.omega_max,
                warn=not drawn,
            )
            self._dyn_reset_history(theta_hist, u_hist)
            self.theta = theta_hist[-1].copy()
            self.omega = last_velocity(self.machine, theta_hist)
        else:
            if options.get("theta0") is not None:
                theta0 = check_theta0(self.machine, options["theta0"], where=where)
            else:
                theta0 = start_pose(
                    self.machine, self.task, self.np_random, margin=self.reset_margin
                )
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
