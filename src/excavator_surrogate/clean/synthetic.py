"""Synthetic excavator-like joint motion for testing and benchmarking the cleaning stage.

Independent of the MuJoCo plant: each joint alternates holds and moves whose target
speeds are up to ``omega_max``, smoothed by two first-order lags (finite acceleration),
and kept inside an angle range.  Follows the data convention
``theta[k] = theta[k-1] + dt * omega[k]``.
"""

from __future__ import annotations

import numpy as np

from ..data.episode import Episode
from ..simulate.sensors import SensorConfig, apply_sensors_episode, ar1_filter
from ..spec import MachineSpec


def smooth_random_motion(
    n_step: int,
    n_joint: int,
    *,
    dt: float,
    rng: np.random.Generator,
    omega_max: float = 1.0,
    hold_prob: float = 0.3,
    segment_s: tuple[float, float] = (1.0, 6.0),
    tau_s: float = 0.25,
    theta_range: tuple[float, float] = (-1.2, 1.2),
) -> tuple[np.ndarray, np.ndarray]:
    """Random hold/move joint motion.

    Args:
        n_step: samples.
        n_joint: joints.
        dt: sample period [s].
        rng: random generator.
        omega_max: largest target speed [rad/s] (the smoothed speed never exceeds it).
        hold_prob: probability that a segment is a hold (zero speed).
        segment_s: range of segment durations [s].
        tau_s: time constant of each of the two smoothing lags [s].
        theta_range: segments are steered to keep the angle in this range [rad].

    Returns:
        ``(theta_true, omega_true)``, each (n_step, n_joint) [rad], [rad/s].
    """
    lo, hi = theta_range
    target = np.zeros((n_step, n_joint))
    theta0 = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), size=n_joint)
    for j in range(n_joint):
        k, pos = 0, float(theta0[j])
        while k < n_step:
            n = max(1, round(rng.uniform(*segment_s) / dt))
            v = 0.0 if rng.random() < hold_prob else float(rng.uniform(-omega_max, omega_max))
            if not lo <= pos + v * n * dt <= hi:
                v = -v
                if not lo <= pos + v * n * dt <= hi:
                    v = 0.0
            target[k : k + n, j] = v
            pos += v * min(n, n_step - k) * dt
            k += n
    alpha = 1.0 - float(np.exp(-dt / tau_s))
    # two first-order lags y_k = y_{k-1} + alpha (x_k - y_{k-1}), starting at rest
    omega = ar1_filter(alpha * target, 1.0 - alpha)
    omega = ar1_filter(alpha * omega, 1.0 - alpha)
    theta = theta0 + np.concatenate([np.zeros((1, n_joint)), np.cumsum(dt * omega[1:], axis=0)])
    return theta, omega


def synthetic_episode(
    n_step: int,
    *,
    spec: MachineSpec,
    rng: np.random.Generator,
    sensor: SensorConfig | None = None,
    omega_max: float = 1.0,
    name: str = "synthetic",
) -> Episode:
    """An episode of :func:`smooth_random_motion` with commands 0, measured through ``sensor``.

    With ``sensor=None`` the measurements are the truth (an ideal episode, no ``_true`` columns).
    """
    theta, omega = smooth_random_motion(
        n_step, spec.n_joint, dt=spec.dt, rng=rng, omega_max=omega_max
    )
    ep = Episode(
        spec=spec,
        time=np.arange(n_step) * spec.dt,
        u=np.zeros((n_step, spec.n_joint)),
        theta=theta,
        omega=omega,
        source="synthetic",
        name=name,
    )
    if sensor is not None:
        ep = apply_sensors_episode(ep, config=sensor, rng=rng)
    return ep


def noisy_batch(
    n_batch: int,
    n_step: int,
    n_joint: int,
    *,
    dt: float,
    seed: int,
    sensor: SensorConfig | None = None,
) -> dict[str, np.ndarray]:
    """Smooth random motion seen through the sensor model, for tests and benchmarks.

    Args:
        sensor: the sensor model (default config if None).

    Returns:
        ``theta_true``, ``omega_true``, ``theta``, ``omega`` and ``mask`` (the jump mask),
        each (n_batch, n_step, n_joint); angles [rad], velocities [rad/s].
    """
    from ..simulate.sensors import apply_sensors

    rng = np.random.default_rng(seed)
    out: dict[str, list[np.ndarray]] = {
        k: [] for k in ("theta_true", "omega_true", "theta", "omega", "mask")
    }
    for _ in range(n_batch):
        th, om = smooth_random_motion(n_step, n_joint, dt=dt, rng=rng)
        tm, omm, info = apply_sensors(th, om, dt=dt, config=sensor or SensorConfig(), rng=rng)
        for k, v in (
            ("theta_true", th),
            ("omega_true", om),
            ("theta", tm),
            ("omega", omm),
            ("mask", info["jump_mask"]),
        ):
            out[k].append(v)
    return {k: np.stack(v) for k, v in out.items()}
