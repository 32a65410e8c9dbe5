"""A digging-like joint-space reference: approach, penetrate, curl, lift, swing, dump, return.

Waypoints are fractions of each limited joint's range (so any machine with the excavator's
joint order works) and radians for the periodic swing; segments between them are smooth
(cosine blends: zero velocity at every waypoint, peak speed ``π/2 · Δθ / T``).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.sizes import check_fits

DIG_CYCLE: tuple[tuple[str, float, tuple[float, ...]], ...] = (
    ("start", 0.0, (0.0, 0.55, 0.35, 0.35)),
    ("approach", 2.0, (0.0, 0.40, 0.25, 0.25)),
    ("penetrate", 2.5, (0.0, 0.25, 0.45, 0.30)),
    ("curl", 4.0, (0.0, 0.25, 0.65, 0.75)),
    ("lift", 4.5, (0.0, 0.65, 0.60, 0.80)),
    ("swing", 4.0, (0.7, 0.65, 0.60, 0.80)),
    ("dump", 5.0, (0.7, 0.65, 0.40, 0.20)),
    ("return", 4.0, (0.0, 0.55, 0.35, 0.35)),
)
"""(phase, duration [s], pose) of one cycle (26 s); pose: radians for periodic joints,
fractions of the range for limited ones, in the excavator's joint order (swing, boom, arm,
bucket).  Durations keep every joint's peak speed within 70 % of the hydraulic plant's top
speed in that direction, and the swing's acceleration within its limit (0.24 rad/s²)."""


def pose(spec: MachineSpec, values: tuple[float, ...]) -> np.ndarray:
    """Angles (n_joint,) [rad] from ``values``: radians for periodic (or unlimited) joints,
    fractions of the range for limited ones."""
    if len(values) != spec.n_joint:
        raise ConfigError(f"pose: need {spec.n_joint} values, got {len(values)}")
    out = np.empty(spec.n_joint)
    for k, j in enumerate(spec.joints):
        if j.periodic or j.theta_min is None or j.theta_max is None:
            out[k] = values[k]
        else:
            out[k] = j.theta_min + values[k] * (j.theta_max - j.theta_min)
    return out


REFERENCE_BYTES_PER_SAMPLE = 128
"""Peak memory of :func:`dig_reference` per sample [bytes]: the segments and their
concatenation, (n_step, 4) float64 each, the time axis and the blends' temporaries."""


def reference_samples(spec: MachineSpec, *, time_scale: float = 1.0, hold_s: float = 0.5) -> int:
    """Length (n_step) of :func:`dig_reference`'s reference at the machine's rate, computed
    without making it (``time_scale`` > 0 and ``hold_s`` >= 0 finite, checked by the caller)."""
    n_hold = round(hold_s / spec.dt)
    moves = sum(max(1, round(dur * time_scale / spec.dt)) for _, dur, _ in DIG_CYCLE[1:])
    return 2 * n_hold + 1 + moves


def dig_reference(
    spec: MachineSpec, *, time_scale: float = 1.0, hold_s: float = 0.5
) -> tuple[np.ndarray, np.ndarray, list[tuple[str, float]]]:
    """The digging cycle :data:`DIG_CYCLE` sampled at the machine's rate.

    Args:
        spec: the machine (4 joints in the excavator's order).
        time_scale: multiplies every segment duration (> 1: slower).
        hold_s: rest at the start pose before the cycle and at its end [s].

    Returns:
        ``theta_ref`` (n_step, n_joint) [rad] with ``theta_ref[0]`` the start pose (at rest),
        ``time`` (n_step,) [s] and the phases as (name, start time [s]).
    """
    if spec.n_joint != len(DIG_CYCLE[0][2]):
        raise ConfigError(
            f"dig_reference: the digging cycle is written for {len(DIG_CYCLE[0][2])} joints "
            f"(swing, boom, arm, bucket), the machine has {spec.n_joint}"
        )
    if not (time_scale > 0 and math.isfinite(time_scale)) or not (
        hold_s >= 0 and math.isfinite(hold_s)
    ):
        raise ConfigError(
            f"dig_reference: need finite time_scale > 0 and hold_s >= 0, got {time_scale}, {hold_s}"
        )
    n_step = reference_samples(spec, time_scale=time_scale, hold_s=hold_s)
    check_fits(  # time_scale = 1e9: a 298-GiB array, numpy's _ArrayMemoryError
        n_step * REFERENCE_BYTES_PER_SAMPLE,
        what=f"dig_reference: time_scale {time_scale:g} makes {n_step} samples, which",
        fix="lower time_scale",
    )
    dt = spec.dt
    poses = [pose(spec, p) for _, _, p in DIG_CYCLE]
    n_hold = round(hold_s / dt)
    rows = [np.repeat(poses[0][None], n_hold + 1, axis=0)]
    phases = [("hold", 0.0)]
    for (name, dur, _), a, b in zip(DIG_CYCLE[1:], poses[:-1], poses[1:]):
        phases.append((name, len(np.concatenate(rows)) * dt - dt))
        n = max(1, round(dur * time_scale / dt))
        s = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, n + 1) / n)  # 0 -> 1, zero end slopes
        rows.append(a[None] + s[:, None] * (b - a)[None])
    rows.append(np.repeat(poses[-1][None], n_hold, axis=0))
    theta = np.concatenate(rows)
    return theta, np.arange(len(theta)) * dt, phases


def horizon_window(theta_ref: np.ndarray, k: int, n: int) -> np.ndarray:
    """Reference samples ``k+1 .. k+n`` (n, n_joint), the last sample repeated past the end."""
    idx = np.minimum(np.arange(k + 1, k + n + 1), len(theta_ref) - 1)
    return theta_ref[idx]
