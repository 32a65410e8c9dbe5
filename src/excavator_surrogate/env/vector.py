"""``SurrogateVectorEnv``: ``n_envs`` surrogate excavators in ONE torch batch.

Equivalent to ``gymnasium.vector.SyncVectorEnv`` over ``n_envs`` copies of
``ExcavatorSurrogate-v0`` (each wrapped in a ``TimeLimit``), with sub-environment ``i``
seeded ``seed + i`` -- the tests check exactly that -- but stepped as one batch:

- stateful checkpoints carry ``(h, c)`` of shape (n_layer, n_envs, hidden), one sample per
  step; windowed checkpoints re-run their ``W``-sample window from a ring buffer;
- per-env resets are *masked*: only the finished envs get a new pose and a fresh at-rest
  warm-up state, the others continue untouched;
- autoreset mode (``metadata["autoreset_mode"]``): ``NEXT_STEP`` (gymnasium's default: the
  step after an episode ends returns the reset observation, reward 0, and ignores that
  env's action), ``SAME_STEP`` (reset within the step; ``info["final_obs"]`` /
  ``info["final_info"]`` hold the last observation/info) or ``DISABLED`` (reset yourself with
  ``reset(options={"reset_mask": mask})``).

Observations (n_envs, 2·n_joint) float32 and actions (n_envs, n_joint) follow the tables of
:class:`~excavator_surrogate.env.surrogate_env.ExcavatorSurrogateEnv`.  ``info`` holds
``guard`` (n_envs,) int8 (``safety.GUARD_*``: 0 fine, 1 joint limit, 2 speed, 3 NaN/inf),
``limit_violation`` (n_envs, n_joint) bool, ``u`` (n_envs, n_u) the applied commands
[command units], ``theta`` (n_envs, n_joint) unwrapped angles [rad] and the task's
entries, each with gymnasium's ``_key`` mask: the keys of the single environments' step
``info`` (whose ``guard`` is the name, ``safety.GUARD_NAMES[code]``), including the
surrogate's uncertainty (:func:`~.uncertainty.step_info`: ``theta_band`` / ``omega_band``
(n_envs, n_joint), or (n_envs,) object arrays of None for a single network, ``ood``
(n_envs, n_joint) bool, ``uncertainty``, ``band_calibrated``, ``ood_any``, ``ood_checked``
(n_envs,) bool).  On a step that autoresets an env (either
mode) that env holds a single env's reset info, as in ``SyncVectorEnv``: ``theta`` and the
task's reset entries; every step entry's mask (``_u``, ``_guard``, ``_limit_violation``, ...)
is False for it (SAME_STEP: the step's own are in ``final_info``).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import logger
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..data.episode import Episode
from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.model import Surrogate
from .base import action_space, observation_space
from .engine import Mode, SurrogateEngine
from .inputs import ActionLayout
from .kernels import Impl
from .safety import (
    GUARD_NAN,
    GUARD_OK,
    ActionChecker,
    ActionMode,
    ActionScale,
    DivergenceGuard,
    GuardConfig,
    check_action_scale,
)
from .starts import (
    RecordedStarts,
    check_history,
    check_theta0,
    last_velocity,
    overshoot,
    warn_short_history,
)
from .surrogate_env import load_surrogate, recorded_starts_of
from .tasks import Task, start_pose
from .uncertainty import notes, step_info, wanted


class SurrogateVectorEnv(VectorEnv):
    """A batched :class:`gymnasium.vector.VectorEnv` over one surrogate checkpoint.

    Args:
        ckpt: checkpoint path or loaded :class:`~excavator_surrogate.surrogate.model.Surrogate`.
        n_envs: number of sub-environments (one torch batch).
        device: torch device.
        mode: ``stateful`` / ``windowed``; default: the checkpoint's training mode.
        impl: stateful kernel, ``auto`` (cell ops below 256 envs, folded ``nn.LSTM`` above),
            ``cell`` or ``module``.
        task: batched reward/termination hook, copied (``self.task``); None -> reward 0, no
            termination.
        action_mode: ``clip`` or ``reject`` out-of-range commands.
        guard: divergence-guard thresholds (truncate on NaN, limits, speed).
        wrap_theta: wrap periodic joints' θ to ``[-π, π)`` in observations.
        reset_margin: fraction of joint ranges avoided by random start poses.
        max_episode_steps: truncate episodes after this many steps (None: never).
        autoreset_mode: ``AutoresetMode`` (or its string value).
        spec: the machine the caller expects; a checkpoint of other joints, command ranges or
            rate raises :class:`~excavator_surrogate.errors.CheckpointError`.
        inputs: exogenous inputs held fixed (``{"engine_rpm": 1800.0}``), left out of the
            action; the others are action entries after the joints' (:mod:`.inputs`).
        action_scale: ``"raw"`` (command units) or ``"normalized"`` (``[-1, 1]`` per column,
            mapped linearly onto the command range), as for the single environments.
        uncertainty: track the members' bands and the OOD flags in ``info`` (None: when the
            checkpoint has ensemble members or a training coverage record).
        recorded_starts: random resets (autoresets too) start each env at a recorded moment
            of these logs, drawn from its own generator (a dataset folder: its train split;
            :class:`~.starts.RecordedStarts`), not at rest.
    """

    env_id = "ExcavatorSurrogate-v0 (vector)"

    def __init__(
        self,
        ckpt: str | Path | Surrogate,
        n_envs: int,
        device: str | torch.device = "cpu",
        *,
        mode: Mode | None = None,
        impl: Impl = "auto",
        task: Task | None = None,
        action_mode: ActionMode = "clip",
        guard: GuardConfig | None = None,
        wrap_theta: bool = True,
        reset_margin: float = 0.1,
        max_episode_steps: int | None = 1000,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        spec: MachineSpec | None = None,
        inputs: dict[str, float] | None = None,
        action_scale: ActionScale = "raw",
        uncertainty: bool | None = None,
        recorded_starts: str | Path | Sequence[Episode] | RecordedStarts | None = None,
    ) -> None:
        sur = load_surrogate(ckpt, device=device, spec=spec)
        on = wanted(sur, uncertainty)
        self.engine = SurrogateEngine(
            sur, n_envs=n_envs, device=device, mode=mode, impl=impl, uncertainty=on
        )
        self.surrogate = sur
        self.uncertainty_note = (
            "; ".join(notes(sur)) if uncertainty is not False else "uncertainty=False: not tracked"
        )
        """What the step ``info``'s uncertainty lacks ("": bands and flags)."""
        self.machine = sur.spec
        """The machine (joints, command ranges, rate)."""
        spec = sur.spec
        self.num_envs = int(n_envs)
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {
            "autoreset_mode": self.autoreset_mode,
            "render_modes": [],
            "render_fps": spec.rate_hz,
        }
        self.layout = ActionLayout.make(spec, inputs, where=self.env_id)
        """The action's columns and the fixed exogenous inputs."""
        self.engine.u_rest = self.layout.rest()
        self.recorded = recorded_starts_of(recorded_starts, sur)
        self.action_scale = check_action_scale(action_scale)
        self.single_action_space = action_space(spec, self.layout, scale=action_scale)
        self.single_observation_space = observation_space(spec, wrap=wrap_theta, guard=guard)
        self._obs_lo = self.single_observation_space.low
        self._obs_hi = self.single_observation_space.high
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.task = copy.deepcopy(task)
        """The env's own copy of ``task`` (it keeps the episodes' state, e.g. targets)."""
        self.reset_margin = float(reset_margin)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self._check_action = ActionChecker(
            spec,
            env_name=self.env_id,
            action_mode=action_mode,
            layout=self.layout,
            scale=action_scale,
        )
        self._guard = DivergenceGuard(spec, guard)
        n, j = self.num_envs, spec.n_joint
        self._periodic = np.asarray(spec.periodic, dtype=bool)
        self._wrap = bool(wrap_theta) and bool(self._periodic.any())
        self._rngs: list[np.random.Generator] = []
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._obs = np.zeros((n, 2 * j), dtype=np.float32)
        self._ones = np.ones(n, dtype=bool)

    # ---- helpers ------------------------------------------------------------------------------

    def _seed(self, seed: int | list[int | None] | None, mask: np.ndarray) -> None:
        """Seed the generators of the envs in ``mask`` (n_envs,) bool, as ``SyncVectorEnv``
        seeds only the envs it resets: env ``i`` gets ``seed + i`` (an int) or ``seed[i]``
        (a list; None keeps its generator); the others keep theirs."""
        n = self.num_envs
        if seed is None:
            if not self._rngs:
                self._rngs = [seeding.np_random()[0] for _ in range(n)]
            return
        seeds = [seed + i for i in range(n)] if isinstance(seed, int) else list(seed)
        if len(seeds) != n:
            raise ConfigError(f"{self.env_id}: {len(seeds)} seeds given for {n} envs")
        if isinstance(seed, int):
            self._np_random, self._np_random_seed = seeding.np_random(seed)
        rngs = self._rngs or [None] * n
        self._rngs = [
            seeding.np_random(s)[0] if s is not None and m else (r or seeding.np_random()[0])
            for s, r, m in zip(seeds, rngs, mask)
        ]

    def _theta0(self, mask: np.ndarray, options: dict[str, Any]) -> np.ndarray:
        spec = self.machine
        theta0 = np.zeros((self.num_envs, spec.n_joint))
        given = options.get("theta0")
        if given is not None:
            g = np.asarray(given, dtype=np.float64)
            g = np.broadcast_to(g, (self.num_envs, spec.n_joint)) if g.ndim == 1 else g
            if g.shape != (self.num_envs, spec.n_joint):
                raise ConfigError(
                    f"{self.env_id}: options['theta0'] must be ({spec.n_joint},) or "
                    f"({self.num_envs}, {spec.n_joint}) "
                    f"{'angles in rad' if not spec.any_linear else 'values (strokes in m)'}, "
                    f"got shape {g.shape}"
                )
        clipped = []
        for i in np.flatnonzero(mask):
            if given is not None:
                where = f"{self.env_id}.reset env {i}"
                theta0[i] = check_theta0(spec, g[i], where=where, warn=False)
                if not np.array_equal(theta0[i], g[i]):
                    clipped.append(int(i))
            else:
                theta0[i] = start_pose(spec, self.task, self._rngs[i], margin=self.reset_margin)
        if clipped:  # one warning for all of them
            worst = overshoot(spec, theta0[clipped] - g[clipped])
            logger.warn(
                f"{self.env_id}.reset: the theta0 of {len(clipped)} env(s) (first: env "
                f"{clipped[0]}) lay up to {worst} beyond the end stops: they start at "
                "the stops"
            )
        return theta0

    def _recorded_histories(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One recorded history per env in ``mask``, each from that env's generator, checked
        as a start (a moment a hair past a stop starts at it, silently; a glitch the import
        let through is left to the guard): ``(theta, u)`` (n_envs, W, n_joint), (n_envs,
        W - 1, n_u), the rows of the other envs zero (never read: the resets are masked)."""
        assert self.recorded is not None
        idx = np.flatnonzero(mask)
        drawn = [self.recorded.draw(self._rngs[i]) for i in idx]
        theta, u = check_history(
            self.machine,
            {"theta": np.stack([d[0] for d in drawn]), "u": np.stack([d[1] for d in drawn])},
            where=f"{self.env_id}.reset",
            n_envs=len(idx),
            warn=False,
        )
        full_theta = np.zeros((self.num_envs, *theta.shape[1:]))
        full_u = np.zeros((self.num_envs, *u.shape[1:]))
        full_theta[idx], full_u[idx] = theta, u
        return full_theta, full_u

    def _write_obs(self, theta: np.ndarray, omega: np.ndarray, rows: np.ndarray | None) -> None:
        """Write θ (wrapped) and ω, clipped into the observation bounds, into ``self._obs`` for
        ``rows`` (None: all)."""
        j = self.machine.n_joint
        if rows is None:
            self._obs[:, :j] = theta
            self._obs[:, j:] = omega
            if self._wrap:
                p = self._periodic
                self._obs[:, :j][:, p] = (theta[:, p] + math.pi) % (2.0 * math.pi) - math.pi
            np.clip(self._obs, self._obs_lo, self._obs_hi, out=self._obs)
        else:
            th = theta[rows]
            if self._wrap:
                p = self._periodic
                th = th.copy()
                th[:, p] = (th[:, p] + math.pi) % (2.0 * math.pi) - math.pi
            self._obs[rows, :j] = th
            self._obs[rows, j:] = omega[rows]
            self._obs[rows] = np.clip(self._obs[rows], self._obs_lo, self._obs_hi)

    def _reset_envs(self, mask: np.ndarray, options: dict[str, Any]) -> dict[str, Any]:
        """Reset the envs in ``mask`` (engine, observation rows, counters, task)."""
        history = options.get("history")
        omega = np.zeros((self.num_envs, self.machine.n_joint))
        where = f"{self.env_id}.reset"
        if history is not None and options.get("theta0") is not None:
            raise ConfigError(f"{where}: give options['theta0'] or options['history'], not both")
        if history is None and options.get("theta0") is None and self.recorded is not None:
            theta_hist, u_hist = self._recorded_histories(mask)
        elif history is not None:
            theta_hist, u_hist = check_history(
                self.machine,
                history,
                where=where,
                n_envs=self.num_envs,
                omega_max=self._guard.config.omega_max,
            )
            warn_short_history(theta_hist.shape[1], self.engine.window, where=where)
        else:
            theta_hist = u_hist = None
        if theta_hist is None:
            theta0 = self._theta0(mask, options)
            theta = self.engine.reset(theta0, mask).cpu().numpy()
        else:
            assert u_hist is not None
            theta = self.engine.reset_history(theta_hist, u_hist, mask).cpu().numpy()
            omega[mask] = last_velocity(self.machine, theta_hist[mask])
        self._elapsed[mask] = 0
        self._autoreset[mask] = False
        self._write_obs(theta, omega, mask)
        info: dict[str, Any] = {}
        if self.task is not None:
            # one call per env with that env's generator: identical draws to single envs;
            # row i of each entry from env i's call (a call's other rows are not its own)
            for i in np.flatnonzero(mask):
                one = np.zeros(self.num_envs, dtype=bool)
                one[i] = True
                extra = self.task.reset(theta, mask=one, rng=self._rngs[i], options=options)
                for k, v in extra.items():
                    info.setdefault(k, np.array(v))[i] = v[i]
        return info

    # ---- gymnasium API ------------------------------------------------------------------------

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset all envs, or those in ``options["reset_mask"]`` (n_envs,) bool.

        Args:
            seed: int (env ``i`` gets ``seed + i``), a list of per-env seeds, or None; only
                the envs in ``reset_mask`` are seeded (the others keep their generators).
            options: ``theta0`` ((n_joint,) or (n_envs, n_joint) [rad], at rest), or
                ``history`` (``{"theta": (n_hist, n_joint) or (n_envs, n_hist, n_joint) [rad],
                "u": (n_hist - 1, n_u) or (n_envs, n_hist - 1, n_u)}``, a recorded warm-up:
                :mod:`.starts`), ``reset_mask``, and task options (e.g. ``target``).

        Returns:
            Observations (n_envs, 2·n_joint) float32 and ``info`` (``theta``: (n_envs, n_joint)).
        """
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = self._ones
        else:
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise ConfigError(
                    f"{self.env_id}: options['reset_mask'] must be a bool array of shape "
                    f"({self.num_envs},) with at least one True"
                )
        self._seed(seed, mask)
        info = self._reset_envs(mask, options)
        info["theta"] = self.engine.theta.cpu().numpy().copy()
        return self._obs.copy(), self._with_masks(info, mask)

    def _with_masks(self, info: dict[str, Any], mask: np.ndarray) -> dict[str, Any]:
        for k in list(info):
            if not k.startswith("_"):
                info[f"_{k}"] = mask
        return info

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Apply ``actions`` (n_envs, n_action) for one control period (``n_action = n_u`` less
        the fixed exogenous inputs).

        Returns:
            ``obs`` (n_envs, 2·n_joint) float32, ``reward`` (n_envs,) float64, ``terminated``
            and ``truncated`` (n_envs,) bool, ``info`` (see the module docstring).

        Raises:
            ActionError: non-finite actions, wrong shape, or out of range with ``action_mode="reject"``.
        """
        if not self._rngs:
            raise RuntimeError(f"{self.env_id}: call reset() before step()")
        u = self.layout.full(self._check_action(actions, n_envs=self.num_envs))
        theta_t, omega_t = self.engine.step(u)
        theta = theta_t.cpu().numpy()
        omega = omega_t.cpu().numpy()
        self._elapsed += 1
        code, violation = self._guard.check(theta, omega)
        nan = code == GUARD_NAN
        truncated = code != GUARD_OK
        if self.max_episode_steps is not None:
            truncated |= self._elapsed >= self.max_episode_steps
        if nan.any():
            ok = ~nan
            self._write_obs(theta, omega, ok)
        else:
            self._write_obs(theta, omega, None)
        reward = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        info: dict[str, Any] = {"guard": code, "limit_violation": violation, "u": u.copy()}
        info.update(step_info(self.engine.unc, self.num_envs, self.machine.n_joint))
        if self.task is not None:
            r, done, extra = self.task.evaluate(theta, omega, u[:, : self.machine.n_joint])
            reward = np.where(nan, 0.0, r)
            terminated = done & ~nan
            info.update(extra)
        info["theta"] = theta.copy()
        info = self._with_masks(info, self._ones)

        mode = self.autoreset_mode
        if mode == AutoresetMode.NEXT_STEP:
            was_done = self._autoreset.copy()
            if was_done.any():
                reward[was_done] = 0.0
                terminated[was_done] = False
                truncated[was_done] = False
                code[was_done] = GUARD_OK
                violation[was_done] = False
                self._reset_in_step(was_done, info)
            self._autoreset = terminated | truncated
        elif mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            if done.any():
                final_obs = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(done):
                    final_obs[i] = self._obs[i].copy()
                final_info = {
                    k: (v.copy() if isinstance(v, np.ndarray) else v)
                    for k, v in info.items()
                    if not k.startswith("_")
                }
                info["final_info"] = self._with_masks(final_info, done)
                info["_final_info"] = done
                info["final_obs"] = final_obs
                info["_final_obs"] = done
                self._reset_in_step(done.copy(), info)
        return self._obs.copy(), reward, terminated, truncated, info

    def _reset_in_step(self, mask: np.ndarray, info: dict[str, Any]) -> None:
        """Reset the envs ``mask`` (n_envs,) within a step (autoreset): in ``info`` they then
        hold a single env's reset info, as in ``SyncVectorEnv``: the angles and the task's
        reset entries, whose masks (``_target``, ...) are True for them only; every step
        entry's mask (``_u``, ``_guard``, ...) is False for them (an entry both the step and
        the reset give holds the reset's rows there)."""
        extra = self._reset_envs(mask, {})
        info["theta"][mask] = self.engine.theta.cpu().numpy()[mask]
        for k in list(info):
            if not k.startswith(("_", "final_")) and k != "theta":
                info[f"_{k}"] = info[f"_{k}"] & ~mask
        for k, v in extra.items():
            if k in info:  # a step entry too
                rows = mask.reshape(-1, *[1] * (np.ndim(v) - 1))
                info[k], info[f"_{k}"] = np.where(rows, v, info[k]), info[f"_{k}"] | mask
            else:
                info[k], info[f"_{k}"] = v, mask.copy()
