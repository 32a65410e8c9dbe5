"""Angle outliers in raw logs: spikes, impossible samples and values beyond the joint limits.

Spikes (corrupt runs of up to three samples), impossible samples (magnitudes no sensor
reads, and bursts of any length entered and left at speeds no joint reaches; see
:mod:`.bursts`, no limits needed) and angles beyond the declared joint limits are all found
on the input samples, before resampling (the anti-alias filter would smear one corrupt
sample over hundreds of output samples).  ``[import] outliers`` decides:

- ``fail`` (default): the first one is an error naming the file, row, column and joint;
- ``drop``: their rows are removed (short holes are bridged by the resampler, holes longer
  than ``max_gap`` split the episode);
- ``clip``: spike and impossible rows are removed, out-of-limit angles are clipped to the
  limits, with the rest of their excursion beyond the limit (the samples within the margin
  too), so the clipped path has no step.

Counts go to the import report (``outliers`` per joint).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import DataError
from ..spec import JointSpec
from .bursts import MAX_TURNS, MAX_TURNS_PERIODIC, Burst, find_impossible
from .mapping import Channel, JointMap, Mapping
from .sources import RawLog
from .units import to_si

SPIKE_HALF_WINDOW = 3
"""A spike is at most this many samples long (Hampel window of 2k+1 samples)."""
SPIKE_MAD = 8.0
"""A sample further than this many robust standard deviations from its window's median ..."""
SPIKE_SPEED = 10.0
"""... and further than this speed [rad/s] times k sample steps is a spike (m/s for a
linear joint, whose values are stored in m: no cylinder moves at 10 m/s either)."""
LIMIT_MARGIN = 0.05
"""Input angles may exceed the declared limits by this fraction of the joint range."""


def find_spikes(x: np.ndarray, dt_in: float) -> np.ndarray:
    """(n,) bool: samples of ``x`` [rad] that jump away from their neighbours and back (Hampel).

    A sample is a spike when it lies more than ``max(SPIKE_MAD * 1.4826 * MAD,
    SPIKE_SPEED * k * dt_in)`` from the median of the ``2k + 1`` samples around it, with
    ``k = SPIKE_HALF_WINDOW``: no joint moves that far in ``k`` steps.  Steps (a joint that
    moves and stays) are never spikes.
    """
    k = SPIKE_HALF_WINDOW
    n = x.shape[0]
    spikes = np.zeros(n, dtype=bool)
    if n < 2 * k + 1:
        return spikes
    floor = SPIKE_SPEED * k * dt_in
    xp = np.pad(x, k, mode="reflect")  # a spike in the first sample is still one
    # Only a sample further than `floor` from some neighbour can be a spike: find those
    # cheaply (window max/min), then take medians of their windows only.
    hi, lo = xp[:n].copy(), xp[:n].copy()
    for s in range(1, 2 * k + 1):
        np.maximum(hi, xp[s : s + n], out=hi)
        np.minimum(lo, xp[s : s + n], out=lo)
    idx = np.flatnonzero((hi - x > floor) | (x - lo > floor))
    if idx.size == 0:
        return spikes
    w = sliding_window_view(xp, 2 * k + 1)[idx]
    med = np.median(w, axis=1)
    mad = np.median(np.abs(w - med[:, None]), axis=1)
    spikes[idx] = np.abs(x[idx] - med) > np.maximum(SPIKE_MAD * 1.4826 * mad, floor)
    return spikes


def _angle(vals: np.ndarray, j: JointMap, *, unwrap: bool = True) -> np.ndarray:
    """Raw channel -> angle [rad] or a linear joint's stroke [m] (periodic joints unwrapped
    unless ``unwrap`` is False)."""
    with np.errstate(over="ignore", invalid="ignore"):
        th = vals * j.angle.scale + j.angle.offset
        th = th * to_si(j.angle.unit)
        return np.unwrap(th) if j.periodic and unwrap else th


def _impossible_velocity(
    path: Path,
    raw_vals: np.ndarray,
    j: JointMap,
    ch: Channel,
    dt_in: float,
    policy: str,
    fix: str,
) -> np.ndarray:
    """(n,) bool: measured velocities no sensor reads (not finite, or more than ``MAX_TURNS``
    turns in one input step); an error under ``policy = "fail"``."""
    assert j.velocity is not None
    f = to_si(j.velocity.unit)
    with np.errstate(over="ignore", invalid="ignore"):
        v = raw_vals * j.velocity.scale + j.velocity.offset
        bad = ~(np.abs(v * f) <= 2 * np.pi * MAX_TURNS / dt_in)
    if bad.any() and policy == "fail":
        row = int(np.flatnonzero(bad)[0])
        stop = row + int(np.argmin(bad[row:])) if not bad[row:].all() else bad.shape[0]
        rows = f" (rows {row}-{stop - 1}, {stop - row} samples)" if stop - row > 1 else ""
        raise DataError(
            path,
            f"joint '{j.name}': velocity {v[row]:.6g} {j.velocity.unit} is impossible{rows}: no "
            f"sensor reads it (not finite, or more than "
            f"{_in_unit(2 * np.pi * MAX_TURNS, j) if j.linear else f'{MAX_TURNS:g} turns'} in one "
            f"{dt_in:.3g} s input step)",
            column=ch.label,
            row=row,
            fix=fix,
        )
    return bad


def _impossible_error(
    path: Path,
    raw_vals: np.ndarray,
    j: JointMap,
    ch: Channel,
    bursts: list[Burst],
    row: int,
    fix: str,
) -> DataError:
    """The one-line error for the impossible run holding ``row``."""
    b = next(b for b in bursts if b.start <= row < b.stop)
    unit = j.angle.unit or "rad"
    value = raw_vals[row] * j.angle.scale + j.angle.offset
    n = b.stop - b.start
    rows = f" (rows {b.start}-{b.stop - 1}, {n} samples)" if n > 1 else ""
    if b.reason == "magnitude":
        turns = MAX_TURNS_PERIODIC if j.periodic else MAX_TURNS
        bound = f"±{turns:g} turns" if not j.linear else "±" + _in_unit(turns * 2 * np.pi, j)
        why = f"no sensor reads it (not finite, or beyond {bound})"
    else:
        f = 1.0 / to_si(unit)
        why = (
            f"it is entered or left at {b.speed * f:.3g} {unit}/s, far above the log's own "
            f"speeds (99th percentile {b.scale * f:.3g} {unit}/s)"
        )
    return DataError(
        path,
        f"joint '{j.name}': angle {value:.6g} {unit} is impossible{rows}: {why}",
        column=ch.label,
        row=row,
        fix=fix,
    )


def _in_unit(x: float, j: JointMap) -> str:
    unit = j.angle.unit or "rad"
    return f"{x / to_si(unit):.6g} {unit}"


def screen_angles(
    path: Path,
    raw: RawLog,
    vals: dict[Channel, np.ndarray],
    mapping: Mapping,
    joints: tuple[JointSpec, ...],
    dt_in: dict[str, float],
    *,
    policy: str,
    entry: dict[str, Any],
    check_unit: Callable[[np.ndarray, np.ndarray, JointMap, str], None] | None = None,
) -> None:
    """Find spikes and out-of-limit angles and apply ``policy`` in place (``raw``, ``vals``).

    Args:
        path: the log (for messages).
        raw: the log as read; rows are removed from its series under ``drop``/``clip``.
        vals: channel -> values after the NaN policy, aligned with the series' time.
        mapping: the mapping (joints, channels).
        joints: the spec's joints (limits in rad), in mapping order.
        dt_in: series name -> typical input step [s].
        policy: ``fail``, ``drop`` or ``clip``.
        entry: the file's report entry; ``entry["outliers"][joint]`` gets the counts.
        check_unit: ``(t, angle_in_unit, joint, label)`` called on the samples without spikes
            before the limits are checked (a degree value in a rad column is a unit error).

    Raises:
        DataError: ``policy = "fail"`` and a spike or an out-of-limit angle was found.
    """
    drop: dict[str, np.ndarray] = {}
    fix = (
        f'fix the log, or set [import] outliers = "drop" or "clip" in {mapping.where} '
        "(docs/import.md)"
    )
    for j, js in zip(mapping.joints, joints):
        ch = mapping.angle_channel(j)
        th = _angle(vals[ch], j)
        spikes = find_spikes(th, dt_in[raw.series_name(ch)])
        t_in = raw.series_of(ch).time
        impossible, bursts = find_impossible(
            _angle(vals[ch], j, unwrap=False), t_in, periodic=j.periodic
        )
        out = np.zeros_like(spikes)
        lo, hi = js.theta_min, js.theta_max
        if not j.periodic and lo is not None and hi is not None:
            margin = LIMIT_MARGIN * (hi - lo)
            out = ~spikes & ((th < lo - margin) | (th > hi + margin))
        impossible &= ~(spikes | out)  # the declared limits name it better
        first = [
            int(np.flatnonzero(m)[0]) if m.any() else len(th) for m in (spikes, out, impossible)
        ]
        if spikes.any() and policy == "fail" and first[0] <= min(first[1:]):
            row = first[0]
            raise DataError(
                path,
                f"joint '{j.name}': angle {_in_unit(th[row], j)} is a spike (its neighbours "
                f"read about {_in_unit(float(np.median(th[max(row - 3, 0) : row + 4])), j)})",
                column=ch.label,
                row=row,
                fix=fix,
            )
        if check_unit is not None:
            # most samples impossible or out of limits: a unit or scale mistake, first
            keep = ~spikes if (impossible | out).mean() > 0.5 else ~(spikes | impossible)
            th_unit = vals[ch][keep] * j.angle.scale + j.angle.offset
            check_unit(t_in[keep], th_unit, j, ch.label)
        if out.any() and policy == "fail" and first[1] <= first[2]:
            row = first[1]
            raise DataError(
                path,
                f"joint '{j.name}': angle {_in_unit(th[row], j)} is outside the declared "
                f"limits [{_in_unit(lo, j)}, {_in_unit(hi, j)}] (+{LIMIT_MARGIN:.0%} of the "
                f"range); {int(out.sum())} sample(s) are",
                column=ch.label,
                row=row,
                fix=f"check the angle's unit/scale/offset and limits of joint '{j.name}', or {fix}",
            )
        if impossible.any() and policy == "fail":
            raise _impossible_error(path, vals[ch], j, ch, bursts, first[2], fix)
        counts: dict[str, int] = {}
        if spikes.any():
            counts["spikes_dropped"] = int(spikes.sum())
        if impossible.any():
            counts["impossible_dropped"] = int(impossible.sum())
        if out.any() and policy == "clip":
            # the whole excursion beyond the limit that holds an outlier, so that a path
            # through the margin meets the limit where it crosses it, without a step
            beyond = (th < lo) | (th > hi)
            run = np.cumsum(beyond & ~np.concatenate([[False], beyond[:-1]]))
            out = beyond & np.isin(run, run[out]) & ~(spikes | impossible)
            counts["clipped"] = int(out.sum())
            clipped = np.clip(th, lo, hi) / to_si(j.angle.unit)
            vals[ch] = np.where(out, (clipped - j.angle.offset) / j.angle.scale, vals[ch])
            out = np.zeros_like(out)
        elif out.any():
            counts["out_of_limits_dropped"] = int(out.sum())
        vch = mapping.velocity_channel(j)
        if vch is not None and j.velocity is not None:
            vname = raw.series_name(vch)
            vbad = _impossible_velocity(path, vals[vch], j, vch, dt_in[vname], policy, fix)
            if vbad.any():
                counts["impossible_velocity_dropped"] = int(vbad.sum())
                prev = drop.get(vname)
                drop[vname] = vbad if prev is None else prev | vbad
        if counts:
            entry["outliers"][j.name] = counts
        bad = spikes | impossible | out
        if bad.any():
            home = raw.series_name(ch)
            prev = drop.get(home)
            drop[home] = bad if prev is None else prev | bad
    for name, bad in drop.items():
        keep = ~bad
        s = raw.series[name]
        if int(keep.sum()) < 2:
            raise DataError(
                path,
                f'{int(bad.sum())} of {bad.shape[0]} rows are outliers (outliers = "{policy}"): '
                "nothing is left",
                column=s.time_label,
                fix=f"check the angles' unit/scale/offset and the joint limits in {mapping.where}",
            )
        raw.series[name] = dataclasses.replace(  # keeps the log's own units
            s, time=s.time[keep], values={k: v[keep] for k, v in s.values.items()}
        )
        for ch in list(vals):
            if raw.series_name(ch) == name:
                vals[ch] = vals[ch][keep]
        entry["notes"].append(
            f'{name}: removed {int(bad.sum())} outlier row(s) (outliers = "{policy}")'
        )


def limit_excursions(theta: np.ndarray, joints: tuple[JointSpec, ...], margin: float) -> Any:
    """First sample beyond a joint's limits by more than ``margin`` x its range.

    Args:
        theta: (n_step, n_joint) angles [rad].
        joints: the spec's joints.
        margin: allowed excursion as a fraction of each joint's range.

    Returns:
        ``(row, joint_index, value, lo, hi, n_bad)`` of the first violation, or None.
    """
    for k, js in enumerate(joints):
        lo, hi = js.theta_min, js.theta_max
        if js.periodic or lo is None or hi is None:
            continue
        m = margin * (hi - lo)
        bad = (theta[:, k] < lo - m) | (theta[:, k] > hi + m)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            return row, k, float(theta[row, k]), lo, hi, int(bad.sum())
    return None
