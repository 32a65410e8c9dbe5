"""Plausibility bounds of the episode contract: values no joint and no sensor produce.

No joint limits are needed: an angle beyond ±:data:`MAX_TURNS` turns, an end-stopped
joint's angle more than one turn outside the range it keeps between the
:data:`LEVEL_QUANTILE` quantiles, a velocity of more than :data:`MAX_TURNS` turns per sample
step.  :func:`~.episode.validate_episode` runs :func:`check_plausible`; the import uses the
same turn bounds on raw logs (``ingest/bursts.py``).

A linear joint's values are stored in m and get the same numbers in m (a "turn" is 2π m):
no cylinder strokes 63 m or moves 63 m in one step, and messages print its own unit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError
from ..spec import MachineSpec

MAX_TURNS = 10.0
"""An angle beyond this many turns [2π rad] of a joint with end stops is impossible."""
MAX_TURNS_PERIODIC = 1e4
"""The same bound for a periodic joint (its stored angle may be unwrapped and count turns)."""
LEVEL_QUANTILE = 0.01
"""An end-stopped joint's angle is implausible more than one turn outside the range
``[q, 1 - q]`` quantiles of its own column (no limits needed)."""

_FIX = "re-import the log: exsur import finds impossible samples in the raw log (docs/import.md)"


def check_plausible(
    spec: MachineSpec,
    arrays: dict[str, np.ndarray | None],
    columns: dict[str, list[str]],
    *,
    where: str | Path | None = None,
) -> None:
    """Angles and velocities that no joint and no sensor produce, without declared limits.

    Per joint: ``|theta|`` beyond :data:`MAX_TURNS` turns (:data:`MAX_TURNS_PERIODIC` for a
    periodic joint); a joint with end stops more than one turn outside the range its angle
    keeps between the :data:`LEVEL_QUANTILE` quantiles; ``|omega|`` moving more than
    :data:`MAX_TURNS` turns in one sample step.  Simulated sensor jumps and real end stops
    stay far inside these bounds; bursts of any size in raw logs are found by the import.

    Args:
        spec: the episode's machine.
        arrays: role (``theta``, ``theta_true``, ``omega``, ``omega_true``) -> (n_step,
            n_joint) values [rad, rad/s], or None when absent.
        columns: role -> the column name of each joint (for messages).
        where: the file (for messages).

    Raises:
        DataError: naming ``where``, the column and the first offending row.
    """
    turn = 2.0 * np.pi

    def show(x: float, k: int) -> str:  # a value of joint k in its printed unit
        j = spec.joints[k]
        return f"{x * j.display_factor:.6g} {j.display_unit}"

    for role in ("theta", "theta_true"):
        arr = arrays.get(role)
        if arr is None or arr.shape[0] == 0:
            continue
        for k, j in enumerate(spec.joints):
            x = arr[:, k]
            turns = MAX_TURNS_PERIODIC if j.periodic else MAX_TURNS
            bad = np.abs(x) > turns * turn
            which = "joint" if j.periodic else "joint with end stops"
            why = f"beyond ±{turns:g} turns, which no {which} reaches"
            if j.linear:
                why = f"beyond ±{show(turns * turn, k)}, which no cylinder reaches"
            if not bad.any() and not j.periodic:
                lo, hi = np.quantile(x, [LEVEL_QUANTILE, 1.0 - LEVEL_QUANTILE])
                bad = (x < lo - turn) | (x > hi + turn)
                span = show(turn, k) if j.linear else "one turn"
                why = (
                    f"more than {span} outside [{show(lo, k)}, {show(hi, k)}], where the joint "
                    f"stays {1 - 2 * LEVEL_QUANTILE:.0%} of the time"
                )
            if bad.any():
                row = int(np.flatnonzero(bad)[0])
                what = "stroke" if j.linear else "angle"
                raise DataError(
                    where,
                    f"joint '{j.name}': {what} {show(x[row], k)} is impossible ({why}) "
                    f"in {int(bad.sum())} sample(s)",
                    column=columns[role][k],
                    row=row,
                    fix=_FIX,
                )
    max_speed = MAX_TURNS * turn / spec.dt
    for role in ("omega", "omega_true"):
        arr = arrays.get(role)
        if arr is None:
            continue
        bad = np.abs(arr) > max_speed
        if bad.any():
            row, k = (int(x) for x in np.argwhere(bad)[0])
            j = spec.joints[k]
            far = show(MAX_TURNS * turn, k) if j.linear else f"{MAX_TURNS:g} turns"
            raise DataError(
                where,
                f"velocity {show(arr[row, k], k)}/s is impossible (more than {far} "
                f"in one {spec.dt:.6g} s step) in {int(bad[:, k].sum())} sample(s)",
                column=columns[role][k],
                row=row,
                fix=_FIX,
            )


def velocity_scale(
    omega_m: np.ndarray, omega_d: np.ndarray, *, linear: bool
) -> tuple[str, float] | None:
    """A measured velocity that disagrees with the position's rate of change by a unit.

    Args:
        omega_m: (n,) measured velocity (a gyro, a stroke-rate sensor).
        omega_d: (n,) the position's rate of change over the same intervals, in the
            position's unit per second.
        linear: a linear joint (its units differ by powers of 10, not by 180/π).

    Returns:
        None when they agree, or the joint hardly moves; else ``(kind, ratio)``, ``ratio`` the
        least-squares factor ``omega_m ≈ ratio * omega_d`` and ``kind`` one of ``"sign"``
        (opposite sign), ``"deg/s"`` (``ratio`` near 180/π), ``"rad/s"`` (near π/180) or
        ``"length"`` (a linear joint's velocity off by 10, 100 or 1000)::

            corr  = <m, d> / (|m| |d|),   ratio = <m, d> / <d, d>
    """
    nd = float(np.dot(omega_d, omega_d))
    nm = float(np.dot(omega_m, omega_m))
    if omega_d.shape[0] < 10 or nd / omega_d.shape[0] < 1e-4 or nm == 0:
        return None  # the joint hardly moves: nothing to compare
    corr = float(np.dot(omega_m, omega_d)) / np.sqrt(nd * nm)
    ratio = float(np.dot(omega_m, omega_d)) / nd
    if corr < -0.8:
        return "sign", ratio
    if corr <= 0.8:
        return None
    if linear:
        if not 0.5 < ratio < 2.0 and any(
            0.5 < ratio / 10.0**k < 2.0 for k in (-3, -2, -1, 1, 2, 3)
        ):
            return "length", ratio
        return None
    deg = np.pi / 180.0
    if 0.5 / deg < ratio < 2.0 / deg:
        return "deg/s", ratio
    if 0.5 * deg < ratio < 2.0 * deg:
        return "rad/s", ratio
    return None
