"""The validation rules of one log, each failing as one line (file, column, row, fix).

Time bases (:func:`check_time`, :func:`check_rate`), missing values
(:func:`apply_nan_policy`), angle and velocity units (:func:`check_angle_unit`,
:func:`check_velocity_unit`) and commands (:func:`command_of`: channels -> command in the
joint's range).  :mod:`.convert` runs them in that order.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..data.plausible import velocity_scale
from ..errors import DataError
from .mapping import (
    TIME_UNIT_S,
    Channel,
    CommandMap,
    ImportOptions,
    InputMap,
    JointMap,
    Mapping,
)
from .sources import Series

MAX_PLAUSIBLE_SPEED = 10.0
"""Joint speed [rad/s] above which a 'rad' angle column is taken to hold degrees."""


def fmt_time(x: float) -> str:
    """A time [s] for a message: microseconds for ordinary values, ``:.6g`` for huge ones
    (1e308 would print 300 digits) and ``inf``/``nan`` as such."""
    x = float(x)
    return f"{x:.6f}" if math.isfinite(x) and abs(x) < 1e9 else f"{x:.6g}"


def check_time(path: Path, s: Series) -> float:
    """Strictly increasing time; returns the typical step [s] (mean of the steps that are not gaps)."""
    t = s.time
    if t.shape[0] < 2:
        raise DataError(
            path,
            f"only {t.shape[0]} sample(s)",
            column=s.time_label,
            fix="a log needs many samples; remove the file",
        )
    d = np.diff(t)
    bad = ~(d > 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0]) + 1
        if d[i - 1] == 0:
            raise DataError(
                path,
                f"duplicate timestamp {fmt_time(t[i])} s (same as row {i - 1})",
                column=s.time_label,
                row=i,
                fix="drop the duplicated rows; exsur does not guess which one is right",
            )
        raise DataError(
            path,
            f"time goes backwards ({fmt_time(t[i - 1])} s -> {fmt_time(t[i])} s)",
            column=s.time_label,
            row=i,
            fix="sort the log by time",
        )
    med = float(np.median(d))
    normal = d[d <= 1.5 * med]
    return float(np.mean(normal)) if normal.size else med


def check_rate(path: Path, s: Series, dt_in: float, mapping: Mapping) -> None:
    """A typical step ``dt_in`` [s] outside 0.5-20000 Hz is an error (naming a likelier time unit)."""
    rate = 1.0 / dt_in
    if 0.5 <= rate <= 20000:
        return
    fix = "check the time column"
    unit = mapping.time.unit
    if s.name == "table" and unit in TIME_UNIT_S:
        for cand, f in TIME_UNIT_S.items():
            r = rate * TIME_UNIT_S[unit] / f
            if cand != unit and 5 <= r <= 1000:
                fix = f'the time unit looks wrong: set [time] unit = "{cand}" ({r:.4g} Hz)'
                break
    raise DataError(
        path,
        f"typical time step {dt_in:.6g} s means {rate:.4g} Hz, outside 0.5-20000 Hz",
        column=s.time_label,
        fix=fix,
    )


def check_upsampling(
    path: Path, series: list[Series], dt_in: dict[str, float], rate_hz: float, max_upsample: float
) -> None:
    """A target rate above ``max_upsample`` x the log's own rate (its fastest series; a slow
    topic may be held) is an error: a typo in ``--rate`` would write gigabytes."""
    s = min(series, key=lambda x: dt_in[x.name])
    own = 1.0 / dt_in[s.name]
    if rate_hz <= max_upsample * own:
        return
    what = "the log" if len(series) == 1 else f"its fastest topic {s.name}"
    raise DataError(
        path,
        f"target rate {rate_hz:.6g} Hz is {rate_hz / own:.3g}x the {own:.4g} Hz of {what}, "
        f"above the upsampling bound {max_upsample:g}x",
        column=s.time_label,
        fix="check --rate; to upsample this much anyway raise --max-upsample "
        "([import] max_upsample)",
    )


def apply_nan_policy(
    path: Path,
    t: np.ndarray,
    x: np.ndarray,
    label: str,
    *,
    options: ImportOptions,
    period: float | None = None,
) -> tuple[np.ndarray, int, int]:
    """Apply the NaN policy to one channel; returns ``(values, n_filled, n_runs)``.

    Args:
        t: (n,) sample times [s].
        x: (n,) raw values (NaN/inf where missing).
        period: a periodic joint's turn in the channel's raw unit (360 for deg): a gap is
            filled on the unwrapped angle, the short way through the ±180° wrap, each value
            on the branch of the sample before the gap.
    """
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, 0, 0
    first = int(np.flatnonzero(bad)[0])
    if options.nan == "fail":
        raise DataError(
            path,
            f"missing or non-finite value ({float(x[first]):.6g})",
            column=label,
            row=first,
            fix=f"clean the log, or use --nan fill to interpolate gaps of up to {options.max_fill} samples",
        )
    if bad.all():
        raise DataError(
            path, "every value is missing", column=label, fix="map a column that holds data"
        )
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    lengths = ends - starts
    long = lengths > options.max_fill
    if long.any():
        k = int(np.flatnonzero(long)[0])
        raise DataError(
            path,
            f"{int(lengths[k])} consecutive missing values, more than --max-fill {options.max_fill}",
            column=label,
            row=int(starts[k]),
            fix="raise --max-fill, or cut the log at this gap",
        )
    good = ~bad
    x = x.copy()
    if period is None:
        x[bad] = np.interp(t[bad], t[good], x[good])
    else:
        xu = np.unwrap(x[good], period=period)
        before = np.maximum(np.searchsorted(np.flatnonzero(good), np.flatnonzero(bad)) - 1, 0)
        x[bad] = np.interp(t[bad], t[good], xu) - (xu - x[good])[before]
    return x, int(bad.sum()), int(starts.shape[0])


LOG_UNITS: dict[str, str] = {
    **dict.fromkeys(("rad", "radian", "radians"), "rad"),
    **dict.fromkeys(("deg", "°", "degree", "degrees"), "deg"),
    **dict.fromkeys(("m", "meter", "metre", "meters", "metres"), "m"),
    **dict.fromkeys(("cm", "centimeter", "centimetre", "centimeters", "centimetres"), "cm"),
    **dict.fromkeys(("mm", "millimeter", "millimetre", "millimeters", "millimetres"), "mm"),
}
"""The unit labels a log may give a position, as the mapping's unit names (a velocity is
one of them per second; compared after :func:`log_unit_name`; anything else is not
compared: ``Grad`` may be degrees or gradians)."""


def log_unit_name(label: str) -> str | None:
    """The mapping's unit name for a log's unit label, or None for a label not known.

    Case, spaces and one pair of enclosing brackets do not count (``[Deg]``, ``(mm)``), and
    per second is written any of the usual ways: ``deg/s``, ``deg/sec``, ``deg s^-1``,
    ``deg*s^-1``, ``deg s-1``, ``deg/second``."""
    s = label.strip().lower()
    if len(s) > 2 and (s[0], s[-1]) in (("[", "]"), ("(", ")")):
        s = s[1:-1].strip()
    for per_s in ("/second", "/sec", "*s^-1", " s^-1", "s^-1", "*s-1", " s-1", "/s"):
        if s.endswith(per_s):
            base = LOG_UNITS.get(s[: -len(per_s)].strip())
            return None if base is None else f"{base}/s"
    return LOG_UNITS.get(s)


_LENGTHS = {"m", "cm", "mm", "m/s", "cm/s", "mm/s"}


def check_log_unit(
    path: Path, log_unit: str, mapped: str, *, label: str, what: str, where: str
) -> None:
    """The unit the log gives a channel (``log_unit``: an MDF channel's, a dSPACE trace's)
    against the mapping's (``mapped``), for ``what`` (``the angle of joint 'boom'``): both
    known and different is an error naming both and the fix (a label the log gets wrong:
    ``[import] log_units = "ignore"``)."""
    theirs = log_unit_name(log_unit)
    if theirs is None or theirs == mapped:
        return
    if (theirs in _LENGTHS) == (mapped in _LENGTHS):
        fix = f'set unit = "{theirs}" in {what} in {where}'
    elif theirs in _LENGTHS:
        fix = (
            f"the log measures a length: map {what.replace('the angle', 'the position')} as a "
            f'linear joint (position = {{ ..., unit = "{theirs}" }}) in {where}'
        )
    else:
        fix = f'the log measures an angle: set unit = "{theirs}" in {what} in {where}'
    raise DataError(
        path,
        f"the log gives this channel the unit {log_unit.strip()!r}, the mapping {mapped!r}",
        column=label,
        fix=f'{fix}; if the log\'s label is wrong, set [import] log_units = "ignore"',
    )


def check_angle_unit(
    path: Path, t: np.ndarray, th: np.ndarray, j: JointMap, label: str, where: str
) -> None:
    """A 'rad' angle beyond ±2π (or moving implausibly fast) holds degrees."""
    if j.angle.unit != "rad":
        return
    big = np.abs(th) > 2 * math.pi + 1e-6
    if not big.any():
        return
    row = int(np.flatnonzero(big)[0])
    if j.periodic:
        jumps = np.abs(np.diff(th)) > math.pi
        step = max(1, round(0.1 / float(np.median(np.diff(t)))))
        v = np.abs(np.diff(th[::step]) / np.diff(t[::step])) if th.shape[0] > step else np.zeros(1)
        if not jumps.any() and float(np.percentile(v, 99)) <= MAX_PLAUSIBLE_SPEED:
            return  # an unwrapped periodic angle in rad
    raise DataError(
        path,
        f"angle {th[row]:.6g} is beyond ±2π in a rad column: looks like degrees",
        column=label,
        row=row,
        fix=f"set unit = \"deg\" in the angle of joint '{j.name}' in {where}",
    )


def check_linkage_reach(
    path: Path, stroke: np.ndarray, j: JointMap, label: str, where: str
) -> None:
    """A linear joint's strokes ``stroke`` [m] all lie within its linkage's reach (a
    triangle given in m for a position in mm reaches none of them, and every angle it gave
    would be the same clipped end)."""
    if j.linkage is None or stroke.size == 0:
        return
    lo, hi = float(np.min(stroke)), float(np.max(stroke))
    misfit = j.linkage.misfit(lo, hi, str(j.angle.unit), what="the log's strokes")
    if misfit is None:
        return
    bad = ~j.linkage.reachable(stroke)
    raise DataError(
        path,
        f"joint '{j.name}', {int(bad.sum())} of {stroke.size} samples: {misfit}",
        column=label,
        row=int(np.flatnonzero(bad)[0]),
        fix=f"the linkage of joint '{j.name}' is in {where}; docs/import.md, Linear joints",
    )


def _to_command(x: np.ndarray, c: CommandMap) -> np.ndarray:
    """Signed channel value (after scale/offset) -> command in ``c.range``."""
    lo, hi = c.range
    if c.unit == "%":
        return 0.5 * (lo + hi) + x / 100.0 * 0.5 * (hi - lo)
    if c.unit == "raw":
        rlo, rhi = c.raw_range  # type: ignore[misc]
        return lo + (x - rlo) / (rhi - rlo) * (hi - lo)
    return x


def _full_scale(c: CommandMap) -> tuple[float, float]:
    """The channel values (after scale/offset) that :func:`_to_command` maps onto
    ``c.range``'s ends: ``(x at u_min, x at u_max)``."""
    lo, hi = c.range
    if c.unit == "%":
        return -100.0, 100.0
    if c.unit == "raw":
        rlo, rhi = c.raw_range  # type: ignore[misc]
        return float(rlo), float(rhi)
    return float(lo), float(hi)


def check_one_way(
    path: Path,
    j: JointMap | InputMap,
    ch: Channel,
    x: np.ndarray,
    *,
    down: bool,
    full: bool,
    options: ImportOptions,
    where: str,
) -> None:
    """One one-way command channel ``x`` (its own rows, after scale/offset) is never negative
    and, with ``full``, never beyond its direction's end of the command range (the check of a
    channel on a topic of its own, whose rows the other direction's do not share).

    Raises:
        DataError: naming the channel and its row (not with ``options.clip_commands``, where
            :func:`command_of` clips instead).
    """
    if options.clip_commands:
        return
    c = j.command
    what = f"joint '{j.name}' command" if isinstance(j, JointMap) else f"input '{j.name}'"
    tol = 1e-9 * (c.range[1] - c.range[0])
    checks = [
        (
            x < -tol,
            "is negative ({:.6g})",
            f"up/down channels must be >= 0; check scale/offset of {what} in {where}",
        )
    ]
    if full:
        x_lo, x_hi = _full_scale(c)
        top = -x_lo if down else x_hi
        checks.append(
            (
                x > top + 1e-9 * (x_hi - x_lo),
                f"{{:.6g}} {_log_unit(j)} is beyond full command ({top:g})",
                f"check unit/scale/range of {what} in {where}, or use --clip-commands",
            )
        )
    for bad, problem, fix in checks:
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise DataError(
                path,
                "one-way command channel " + problem.format(x[row]),
                column=ch.label,
                row=row,
                fix=fix,
            )


def _log_unit(j: JointMap | InputMap) -> str:
    """The unit a command's log values are in, as the mapping names it (``%``, ``raw`` or
    the physical unit, e.g. ``bar``)."""
    if isinstance(j, InputMap):
        return j.unit  # an input's % is stored as raw
    c = j.command
    return c.physical_unit if c.unit == "physical" else str(c.unit)


def command_of(
    path: Path,
    j: JointMap | InputMap,
    chans: tuple[Channel, ...],
    vals: dict[Channel, np.ndarray],
    *,
    options: ImportOptions,
    where: str,
    entry: dict[str, Any],
) -> np.ndarray:
    """(n_row,) command of joint or input ``j`` in its range, from its ``chans`` in ``vals``
    (all on the same rows).

    A two-channel command is ``up - down``; out-of-range values (and negative one-way
    channels) are an error, or clipped (their rows counted in ``entry["clipped"]``) with
    ``options.clip_commands``.
    """
    c = j.command
    what = f"joint '{j.name}' command" if isinstance(j, JointMap) else f"input '{j.name}'"
    span = c.range[1] - c.range[0]
    tol = 1e-9 * span
    raw = [vals[ch] * c.scale + c.offset for ch in chans]
    clamped = np.zeros(raw[0].shape, dtype=bool)  # a one-way channel clamped at 0 (clip only)
    if c.two_channel:
        for k, (ch, x) in enumerate(zip(chans, raw)):
            check_one_way(path, j, ch, x, down=k == 1, full=False, options=options, where=where)
        if options.clip_commands:
            clamped = (raw[0] < -tol) | (raw[1] < -tol)
            x = np.maximum(raw[0], 0.0) - np.maximum(raw[1], 0.0)
        else:
            x = raw[0] - raw[1]
        label = f"{chans[0].label} - {chans[1].label}"
    else:
        x = raw[0]
        label = chans[0].label
    u = _to_command(x, c)
    out = clamped | (u < c.range[0] - tol) | (u > c.range[1] + tol)
    if out.any():
        row = int(np.flatnonzero(out)[0])
        if not options.clip_commands:
            raise DataError(
                path,
                f"command {u[row]:.6g} (log value {x[row]:.6g} {_log_unit(j)}) is outside "
                f"[{c.range[0]:g}, {c.range[1]:g}] after scaling",
                column=label,
                row=row,
                fix=f"check unit/scale/range of {what} in {where}, or use --clip-commands",
            )
        entry["clipped"][j.name] = int(out.sum())
        u = np.clip(u, c.range[0], c.range[1])
    return u


def check_velocity_unit(
    path: Path, omega_m: np.ndarray, omega_d: np.ndarray, j: JointMap, label: str, where: str
) -> None:
    """Measured velocity vs the angle's rate of change: catches deg/s vs rad/s (m/s vs cm/s
    or mm/s for a linear joint) and sign errors (:func:`~..data.plausible.velocity_scale`)."""
    found = velocity_scale(omega_m, omega_d, linear=j.linear)
    if found is None:
        return
    kind, ratio = found
    if kind == "sign":
        scale = j.velocity.scale if j.velocity is not None else 1.0
        raise DataError(
            path,
            "measured velocity has the opposite sign of the angle's rate of change",
            column=label,
            fix=f"set scale = {-scale:g} in the velocity of joint '{j.name}' in {where}",
        )
    if kind == "length":
        raise DataError(
            path,
            f"measured velocity is {ratio:.3g}x the position's rate of change: its "
            "length unit looks wrong",
            column=label,
            fix=f"set the velocity unit (m/s, cm/s or mm/s) of joint '{j.name}' in "
            f"{where} to the position's unit per second",
        )
    raise DataError(
        path,
        f"measured velocity is {ratio:.3g}x the angle's rate of change: looks like {kind}",
        column=label,
        fix=f"set unit = \"{kind}\" in the velocity of joint '{j.name}' in {where}",
    )
