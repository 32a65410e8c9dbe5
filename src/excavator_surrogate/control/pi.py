"""Independent joint PI controllers (the baseline of examples/pi_controller.py)."""

from __future__ import annotations

import math

import numpy as np

from ..spec import MachineSpec

KP_GRID = (500.0, 1000.0, 2000.0, 4000.0, 8000.0, 16000.0, 32000.0)
"""Candidate proportional gains [command units per rad]."""
TI = 2.0
"""Integral time [s]: ki = kp / TI."""


class JointPI:
    """Independent PI controller per joint with anti-windup (conditional integration).

    ``u = clip(kp·e + ki·∫e dt, u_min, u_max)`` with ``e = θ* - θ`` wrapped to ``[-π, π)``
    for periodic joints.  ``kp``, ``ki`` are (n_joint,) [command units per rad (per s)].
    """

    def __init__(self, spec: MachineSpec, *, kp: np.ndarray, ki: np.ndarray) -> None:
        self.spec = spec
        self.kp = np.asarray(kp, dtype=np.float64)
        self.ki = np.asarray(ki, dtype=np.float64)
        self.dt = spec.dt
        self.periodic = np.asarray(spec.periodic, dtype=bool)
        self.u_min = np.array([j.u_min for j in spec.joints])
        self.u_max = np.array([j.u_max for j in spec.joints])
        self.integral = np.zeros(spec.n_joint)

    def reset(self) -> None:
        """Clear the integrator."""
        self.integral[:] = 0.0

    def error(self, theta: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``target - theta`` [rad], periodic joints wrapped."""
        e = target - theta
        e[self.periodic] = (e[self.periodic] + math.pi) % (2 * math.pi) - math.pi
        return e

    def __call__(self, obs: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Command (n_joint,) from the observation ``[θ (n_joint), ω (n_joint)]``."""
        n = self.spec.n_joint
        e = self.error(obs[:n].astype(np.float64), target)
        u_free = self.kp * e + self.ki * self.integral
        saturated = ((u_free >= self.u_max) & (e > 0)) | ((u_free <= self.u_min) & (e < 0))
        self.integral += np.where(saturated, 0.0, e * self.dt)
        return np.clip(self.kp * e + self.ki * self.integral, self.u_min, self.u_max)
