"""Velocities a log lacks, from its angles alone: ``[import] velocity = "kalman"``.

A joint without a measured velocity gets the backward difference of its resampled angle
(``velocity = "diff"``) or, with ``"kalman"``, that of the angle the paper's
constant-velocity Kalman filter fuses (:mod:`excavator_surrogate.clean`), so the pair stays
kinematically consistent: ``theta[k+1] = theta[k] + T_s * omega[k+1]``.
"""

from __future__ import annotations

import numpy as np

from ..clean import CleanConfig, clean_episode
from ..data import Episode


def kalman_velocities(episodes: list[Episode], omega: list[np.ndarray | None]) -> list[Episode]:
    """Episodes whose joints without a measured velocity (``omega[i] is None``) are
    replaced by angle-only Kalman filtering (:func:`kalman_fuse`)."""
    derived = [i for i, o in enumerate(omega) if o is None]
    if not derived:
        return episodes
    out = []
    for ep in episodes:
        # Angle-only filtering: fused theta and omega = backward difference of it, so
        # the pair stays kinematically consistent (theta[k+1] = theta[k] + T_s*omega[k+1]).
        fused = kalman_fuse(ep)
        th, om = ep.theta.copy(), ep.omega.copy()
        th[:, derived] = fused.theta[:, derived]
        om[:, derived] = fused.omega[:, derived]
        out.append(ep.replace(theta=th, omega=om))
    return out


def kalman_fuse(ep: Episode) -> Episode:
    """Angle-only Kalman filtering of ``ep`` for logs without a velocity channel.

    Uses the paper's constant-velocity filter with the jump test and no integration
    consistency test (there is no gyro to integrate): ``method="paper"``, ``tau_cons=inf``.
    Returns the cleaned episode (fused ``theta``, ``omega`` = backward difference of it).
    """
    return clean_episode(ep, config=CleanConfig(method="paper", tau_cons=float("inf")))


def kalman_velocity(ep: Episode) -> np.ndarray:
    """(n_step, n_joint) velocities [rad/s] from angle-only Kalman filtering (:func:`kalman_fuse`)."""
    return np.asarray(kalman_fuse(ep).omega, dtype=np.float64)
