"""Optional task hooks: reward and termination on top of the excavator dynamics.

An environment without a task returns reward 0 and never terminates (episodes end by
truncation only).  A task is any object with the two methods of :class:`Task`; it works on
*batches* ``(n_envs, n_joint)`` so the same task serves the single environments
(``n_envs = 1``) and :class:`~excavator_surrogate.env.vector.SurrogateVectorEnv`.

A task may also choose the random start poses: when it has a method
``sample_start(rng, *, margin) -> (n_joint,) | None`` (see :meth:`ReachTask.sample_start`),
the environments call it for every reset without ``options["theta0"]`` and use its pose
unless it returns ``None``.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec


@runtime_checkable
class Task(Protocol):
    """Reward/termination hook.

    ``reset`` is called after the environment reset the envs in ``mask`` (for single
    environments ``mask`` is ``[True]``); ``evaluate`` after every step.
    """

    def reset(
        self,
        theta: np.ndarray,
        *,
        mask: np.ndarray,
        rng: np.random.Generator,
        options: dict[str, Any] | None = None,
    ) -> dict[str, np.ndarray]:
        """Start new episodes for the envs in ``mask``.

        Args:
            theta: (n_envs, n_joint) initial angles [rad] (rows outside ``mask`` are stale).
            mask: (n_envs,) bool, which envs start a new episode.
            rng: the environment's generator (seeded by ``reset(seed=...)``).
            options: the ``options`` passed to ``env.reset``.

        Returns:
            Extra ``info`` entries, arrays with leading axis ``n_envs``.
        """
        ...

    def evaluate(
        self, theta: np.ndarray, omega: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward and termination after one step.

        Args:
            theta: (n_envs, n_joint) angles after the step [rad] (unwrapped).
            omega: (n_envs, n_joint) velocities after the step [rad/s].
            u: (n_envs, n_joint) applied (clipped) commands [command units].

        Returns:
            ``reward`` (n_envs,) float, ``terminated`` (n_envs,) bool and extra ``info``
            entries (arrays with leading axis ``n_envs``).
        """
        ...


class ReachTask:
    """Reach a target joint configuration and stop there.

    Reward per step: ``-‖e‖₂ - ctrl_cost · ‖(u - u_center) / u_scale‖₂²`` where ``e`` is the
    joint-angle error [rad] (wrapped to ``[-π, π)`` for periodic joints), plus
    ``success_bonus`` on the step that ends the episode.  The episode terminates when every
    ``|e_j| < tol`` and every ``|ω_j| < omega_tol``.

    Args:
        spec: the machine.
        target: (n_joint,) target angles [rad]; ``None`` samples one per episode uniformly
            inside the joint limits (shrunk by ``margin`` of each range).  ``reset(options=
            {"target": ...})`` overrides either for that episode.
        tol: angle tolerance [rad].
        omega_tol: velocity tolerance [rad/s].
        ctrl_cost: weight of the command penalty.
        margin: fraction of each joint range excluded at both ends when sampling targets.
        success_bonus: reward added on the terminating step (reaching and holding still
            then pays more than merely ending the per-step penalty).
        start_radius: with a fixed ``target``, periodic joints (the swing) start within
            ``± start_radius`` [rad] of it (:meth:`sample_start`); ``None``: the
            environment's random poses (anywhere on the circle).
    """

    def __init__(
        self,
        spec: MachineSpec,
        *,
        target: np.ndarray | None = None,
        tol: float = 0.05,
        omega_tol: float = 0.05,
        ctrl_cost: float = 0.0,
        margin: float = 0.15,
        success_bonus: float = 0.0,
        start_radius: float | None = None,
    ) -> None:
        self.spec = spec
        self.fixed_target = None if target is None else self._check(target, "target")
        self.tol = float(tol)
        self.omega_tol = float(omega_tol)
        self.ctrl_cost = float(ctrl_cost)
        self.margin = float(margin)
        self.success_bonus = float(success_bonus)
        if start_radius is not None and (self.fixed_target is None or not start_radius >= 0):
            raise ConfigError(
                "ReachTask: start_radius needs a fixed target and a radius >= 0 [rad], got "
                f"target={target!r}, start_radius={start_radius!r}"
            )
        self.start_radius = None if start_radius is None else float(start_radius)
        self.target = np.zeros((0, spec.n_joint))
        self._periodic = np.asarray(spec.periodic, dtype=bool)
        self._u_center = np.array([j.u_center for j in spec.joints])
        self._u_scale = np.array([j.u_scale for j in spec.joints])

    def _check(self, target: Any, what: str) -> np.ndarray:
        t = np.asarray(target, dtype=np.float64)
        if t.shape != (self.spec.n_joint,) or not np.isfinite(t).all():
            raise ConfigError(
                f"ReachTask: {what} must be {self.spec.n_joint} finite angles "
                f"{list(self.spec.names)} in rad, got {t.tolist()}"
            )
        return t

    def sample_target(self, rng: np.random.Generator) -> np.ndarray:
        """One random target (n_joint,) [rad] inside the joint limits."""
        return sample_pose(self.spec, rng, margin=self.margin)

    def sample_start(self, rng: np.random.Generator, *, margin: float) -> np.ndarray | None:
        """A random start pose (n_joint,) [rad]: the environment's pose (:func:`sample_pose`
        with its reset ``margin``) with every periodic joint moved to ``target ± U(start_radius)``;
        ``None`` without ``start_radius`` (the environment then draws its own pose)."""
        if self.start_radius is None or self.fixed_target is None:
            return None
        pose = sample_pose(self.spec, rng, margin=margin)
        for k in np.flatnonzero(self._periodic):
            pose[k] = self.fixed_target[k] + rng.uniform(-self.start_radius, self.start_radius)
        return pose

    def reset(
        self,
        theta: np.ndarray,
        *,
        mask: np.ndarray,
        rng: np.random.Generator,
        options: dict[str, Any] | None = None,
    ) -> dict[str, np.ndarray]:
        """Set the target of every env in ``mask``; returns ``{"target": (n_envs, n_joint)}``."""
        n = theta.shape[0]
        if self.target.shape[0] != n:
            self.target = np.zeros((n, self.spec.n_joint))
        given = (options or {}).get("target")
        for i in np.flatnonzero(mask):
            if given is not None:
                self.target[i] = self._check(given, "options['target']")
            elif self.fixed_target is not None:
                self.target[i] = self.fixed_target
            else:
                self.target[i] = self.sample_target(rng)
        return {"target": self.target.copy()}

    def error(self, theta: np.ndarray) -> np.ndarray:
        """Joint-angle error ``theta - target`` (n_envs, n_joint) [rad], periodic joints wrapped."""
        e = theta - self.target
        if self._periodic.any():
            e[:, self._periodic] = (e[:, self._periodic] + math.pi) % (2 * math.pi) - math.pi
        return e

    def evaluate(
        self, theta: np.ndarray, omega: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward ``-‖e‖ - ctrl_cost·‖ũ‖² (+ success_bonus on termination)``; terminated when
        within ``tol``/``omega_tol``."""
        e = self.error(theta)
        dist = np.sqrt((e * e).sum(axis=1))
        reward = -dist
        if self.ctrl_cost:
            us = (u - self._u_center) / self._u_scale
            reward = reward - self.ctrl_cost * (us * us).sum(axis=1)
        with np.errstate(invalid="ignore"):
            done = (np.abs(e) < self.tol).all(axis=1) & (np.abs(omega) < self.omega_tol).all(axis=1)
        if self.success_bonus:
            reward = reward + self.success_bonus * done
        return reward, done, {"distance": dist}


def sample_pose(spec: MachineSpec, rng: np.random.Generator, *, margin: float = 0.1) -> np.ndarray:
    """A random pose (n_joint,) [rad]: uniform in ``[-π, π)`` for periodic joints, inside the
    limits shrunk by ``margin`` of the range for limited joints, ``[-0.5, 0.5]`` otherwise."""
    out = np.empty(spec.n_joint)
    for k, j in enumerate(spec.joints):
        if j.periodic:
            lo, hi = -math.pi, math.pi
        elif j.theta_min is not None and j.theta_max is not None:
            span = j.theta_max - j.theta_min
            lo, hi = j.theta_min + margin * span, j.theta_max - margin * span
        elif j.theta_min is not None:
            lo, hi = j.theta_min, j.theta_min + 1.0
        elif j.theta_max is not None:
            lo, hi = j.theta_max - 1.0, j.theta_max
        else:
            lo, hi = -0.5, 0.5
        out[k] = rng.uniform(lo, hi)
    return out


def start_pose(
    spec: MachineSpec, task: Any, rng: np.random.Generator, *, margin: float
) -> np.ndarray:
    """The random start pose (n_joint,) [rad] of an environment reset: the task's
    ``sample_start(rng, margin=margin)`` when it has one that returns a pose, else
    :func:`sample_pose`."""
    sample = getattr(task, "sample_start", None)
    pose = sample(rng, margin=margin) if sample is not None else None
    return sample_pose(spec, rng, margin=margin) if pose is None else np.asarray(pose, float)
