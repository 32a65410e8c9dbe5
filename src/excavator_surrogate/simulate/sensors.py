"""Sensor-fault model of a dynamic inclinometer with a built-in gyro (HDA437T class).

Turns ground-truth joint angles and angular velocities into the imperfect signals the
paper describes (Sec. V-A / IV): inclinometer angles with white noise, vibration-correlated
coloured noise and transient jumps (single-sample spikes and short offsets), and gyro
angular velocities with white noise and a drifting (random-walk) bias.

Sampling convention (same as the episode contract): ``omega[k]`` is the mean velocity over
``[t_{k-1}, t_k]``, so ``theta_true[k] = theta_true[k-1] + dt * omega_true[k]``.

Every magnitude is a scalar (same for every joint) or a tuple with one value per joint.
The defaults are *plausible* values for a MEMS dynamic inclinometer on a vibrating 75 t
excavator, chosen by us (see docs/cleaning.md); they are not datasheet figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import to_dict
from ..data.episode import Episode
from ..data.jumps import mask_to_runs
from ..errors import ConfigError, DataError

PerJoint = float | tuple[float, ...]
"""A scalar applied to every joint, or one value per joint."""


@dataclass(frozen=True)
class SensorConfig:
    """Noise and fault magnitudes of the angle (inclinometer) and velocity (gyro) channels."""

    theta_white_std: PerJoint = 0.0015
    """Std of white angle noise [rad] (~0.09 deg)."""
    theta_vib_std: PerJoint = 0.001
    """Std of vibration-correlated angle noise with the joint at rest (engine running) [rad]."""
    theta_vib_gain: PerJoint = 0.004
    """Extra vibration-noise std per unit joint speed [rad per rad/s]; std = vib_std + gain*|omega|."""
    theta_vib_tau: float = 0.15
    """Correlation time of the vibration noise (first-order Gauss-Markov) [s]."""
    spike_rate: PerJoint = 0.05
    """Mean rate of single-sample angle spikes [1/s] (Poisson)."""
    offset_rate: PerJoint = 0.03
    """Mean rate of short angle offsets (steps that return) [1/s] (Poisson)."""
    jump_min: float = 0.05
    """Smallest jump (spike or offset) magnitude [rad]; magnitudes are log-uniform."""
    jump_max: float = 0.35
    """Largest magnitude of one jump [rad]; overlapping jumps add (up to 0.42 rad measured)."""
    offset_min_s: float = 0.1
    """Shortest offset duration [s] (at least one sample)."""
    offset_max_s: float = 1.5
    """Longest offset duration [s]."""
    gyro_white_std: PerJoint = 0.005
    """Std of white gyro noise per sample [rad/s] (~0.3 deg/s)."""
    gyro_bias_std: PerJoint = 0.005
    """Std of the initial gyro bias [rad/s] (~0.3 deg/s)."""
    gyro_bias_walk: PerJoint = 2e-4
    """Gyro bias random walk [rad/s per sqrt(s)]."""

    def __post_init__(self) -> None:
        if not 0 < self.jump_min <= self.jump_max:
            raise ConfigError(
                f"sensor: need 0 < jump_min <= jump_max, got {self.jump_min}, {self.jump_max}"
            )
        if not 0 < self.offset_min_s <= self.offset_max_s:
            raise ConfigError(
                f"sensor: need 0 < offset_min_s <= offset_max_s, got {self.offset_min_s}, {self.offset_max_s}"
            )
        if not self.theta_vib_tau > 0:
            raise ConfigError(f"sensor: theta_vib_tau must be positive, got {self.theta_vib_tau}")


def per_joint(value: PerJoint, n_joint: int, name: str) -> np.ndarray:
    """Broadcast a scalar-or-tuple config value to ``(n_joint,)`` float64; negative values are an error."""
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        arr = np.full(n_joint, float(arr[0]))
    elif arr.size != n_joint:
        raise ConfigError(
            f"sensor.{name}: got {arr.size} values for {n_joint} joints; give one value or one per joint"
        )
    if (arr < 0).any():
        raise ConfigError(f"sensor.{name}: values must be >= 0, got {arr.tolist()}")
    return arr


def ar1_filter(e: np.ndarray, rho: float) -> np.ndarray:
    """``x_k = rho * x_{k-1} + e_k`` along axis 0 with ``x_{-1} = 0`` (0 <= rho <= 1).

    Vectorised (no Python loop over samples): blocks of scaled cumulative sums, with the
    block length chosen so that ``rho**-L`` stays below 1e100.
    """
    e = np.asarray(e, dtype=np.float64)
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho must be in [0, 1], got {rho}")
    if rho == 0.0:
        return e.copy()
    n = e.shape[0]
    block = n if rho == 1.0 else max(1, min(n, int(100.0 / -math.log10(rho))))
    out = np.empty_like(e)
    carry = np.zeros(e.shape[1:])
    extra = (1,) * (e.ndim - 1)
    for start in range(0, n, block):
        blk = e[start : start + block]
        k = np.arange(blk.shape[0], dtype=np.float64).reshape(-1, *extra)
        pw = rho**k
        x = pw * np.cumsum(blk / pw, axis=0) + rho * pw * carry
        out[start : start + block] = x
        carry = x[-1]
    return out


def apply_sensors(
    theta_true: np.ndarray,
    omega_true: np.ndarray,
    *,
    dt: float,
    config: SensorConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Simulate inclinometer angles and gyro velocities from ground truth.

    Args:
        theta_true: (n_step, n_joint) true angles [rad].
        omega_true: (n_step, n_joint) true mean velocities over the last sample [rad/s].
        dt: sample period [s].
        config: noise and fault magnitudes.
        rng: random generator (the only source of randomness).

    Returns:
        ``(theta_meas, omega_meas, info)``; the arrays are (n_step, n_joint).  ``info`` has
        ``jump_mask`` (n_step, n_joint) bool, True where a spike or offset falls (ground truth
        for detection; events are drawn independently, so overlapping ones add: the sum can
        leave [jump_min, jump_max] or, with opposite signs, nearly cancel on a masked
        sample, and merged runs can outlast ``offset_max_s``); ``jump_runs`` (its compact form, see
        :func:`mask_to_runs`); ``gyro_bias`` (n_step, n_joint) [rad/s]; ``theta_noise``
        (n_step, n_joint) white + vibration angle noise [rad].  Jumps never start at row 0.
    """
    theta_true = np.asarray(theta_true, dtype=np.float64)
    omega_true = np.asarray(omega_true, dtype=np.float64)
    if theta_true.ndim != 2 or theta_true.shape != omega_true.shape:
        raise DataError(
            None,
            f"theta_true {theta_true.shape} and omega_true {omega_true.shape} must both be (n_step, n_joint)",
        )
    if not dt > 0:
        raise ConfigError(f"sensor: dt must be positive, got {dt}")
    n_step, n_joint = theta_true.shape
    c = config

    def pj(name: str) -> np.ndarray:
        return per_joint(getattr(c, name), n_joint, name)

    # --- angle: white + vibration-correlated coloured noise (AR(1), unit variance, scaled by envelope)
    white = rng.standard_normal((n_step, n_joint)) * pj("theta_white_std")
    rho = float(np.exp(-dt / c.theta_vib_tau))
    e = rng.standard_normal((n_step, n_joint)) * np.sqrt(1.0 - rho * rho)
    e[0] = rng.standard_normal(n_joint)  # start in the stationary distribution
    ar = ar1_filter(e, rho)
    envelope = pj("theta_vib_std") + pj("theta_vib_gain") * np.abs(omega_true)
    theta_noise = white + envelope * ar

    # --- angle: transient jumps (spikes = 1 sample, offsets = a few to tens of samples)
    jumps = np.zeros((n_step, n_joint))
    mask = np.zeros((n_step, n_joint), dtype=bool)
    duration_s = n_step * dt
    log_lo, log_hi = np.log(c.jump_min), np.log(c.jump_max)
    spike_rate, offset_rate = pj("spike_rate"), pj("offset_rate")
    lo_len = max(1, round(c.offset_min_s / dt))
    hi_len = max(lo_len, round(c.offset_max_s / dt))
    if n_step > 1:
        for j in range(n_joint):
            for kind, rate in (("spike", spike_rate[j]), ("offset", offset_rate[j])):
                n_ev = int(rng.poisson(rate * duration_s))
                if n_ev == 0:
                    continue
                start = rng.integers(1, n_step, size=n_ev)
                amp = np.exp(rng.uniform(log_lo, log_hi, size=n_ev)) * rng.choice(
                    [-1.0, 1.0], size=n_ev
                )
                length = (
                    np.ones(n_ev, dtype=int)
                    if kind == "spike"
                    else rng.integers(lo_len, hi_len + 1, size=n_ev)
                )
                # events are independent: overlapping ones add (docs/cleaning.md, Known gaps)
                for a, n, v in zip(start, length, amp):
                    jumps[a : a + n, j] += v
                    mask[a : a + n, j] = True

    # --- gyro: white noise + random-walk bias
    bias0 = rng.standard_normal(n_joint) * pj("gyro_bias_std")
    steps = rng.standard_normal((n_step, n_joint)) * (pj("gyro_bias_walk") * np.sqrt(dt))
    steps[0] = 0.0
    bias = bias0 + np.cumsum(steps, axis=0)
    gyro_white = rng.standard_normal((n_step, n_joint)) * pj("gyro_white_std")

    theta_meas = theta_true + theta_noise + jumps
    omega_meas = omega_true + bias + gyro_white
    info = {
        "jump_mask": mask,
        "jump_runs": mask_to_runs(mask),
        "gyro_bias": bias,
        "theta_noise": theta_noise,
    }
    return theta_meas, omega_meas, info


def apply_sensors_episode(
    ep: Episode, *, config: SensorConfig, rng: np.random.Generator
) -> Episode:
    """Episode with simulated sensor signals; ground truth kept in ``theta_true``/``omega_true``.

    The truth is ``ep.theta_true``/``ep.omega_true`` if present (re-applying replaces the
    previous noise), else ``ep.theta``/``ep.omega`` (an ideal simulation).  The jump mask is
    stored compactly as ``ep.extra["sensor"]["jump_runs"]`` (``[[joint, start, stop), ...]``,
    see :func:`runs_to_mask`) together with the sensor config.

    Args:
        ep: the episode.
        config: noise and fault magnitudes.
        rng: random generator.

    Returns:
        A new episode; ``ep`` is not modified.
    """
    theta_true = ep.theta if ep.theta_true is None else ep.theta_true
    omega_true = ep.omega if ep.omega_true is None else ep.omega_true
    theta, omega, info = apply_sensors(theta_true, omega_true, dt=ep.dt, config=config, rng=rng)
    extra = dict(ep.extra)
    extra["sensor"] = {
        "model": "inclinometer+gyro (HDA437T class)",
        "config": to_dict(config),
        "jump_runs": info["jump_runs"],
    }
    return ep.replace(
        theta=theta,
        omega=omega,
        theta_true=np.array(theta_true, dtype=np.float64),
        omega_true=np.array(omega_true, dtype=np.float64),
        extra=extra,
    )
