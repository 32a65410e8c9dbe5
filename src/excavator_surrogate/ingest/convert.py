"""From raw logs to a dataset: validate, convert units, split at gaps, resample, assign splits.

:func:`convert_log` turns one log into episodes (plus a report entry); :func:`import_logs`
runs it over every source, assigns splits by file and writes the dataset atomically
together with ``import_report.json`` and ``import_report.md``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import to_dict
from ..data import Episode, write_dataset
from ..errors import ConfigError, DataError
from ..io_utils import atomic_dir, log, progress, write_json, write_text
from ..outdir import check_out_dir, replace_allowed
from ..spec import MachineSpec
from .mapping import (
    DEG,
    Channel,
    CommandMap,
    ImportOptions,
    InputMap,
    JointMap,
    Mapping,
    SplitOptions,
)
from .outliers import screen_angles
from .readers import expand_sources, log_stem, read_log
from .report import render_markdown
from .resample import (
    antialias_sos,
    cumulative_trapezoid,
    decimation_factor,
    interval_mean,
    resample_smooth,
)
from .sources import RawLog, Series
from .split import assign_splits

REPORT_JSON = "import_report.json"
REPORT_MD = "import_report.md"
MAX_PLAUSIBLE_SPEED = 10.0
"""Joint speed [rad/s] above which a 'rad' angle column is taken to hold degrees."""


@dataclass
class FileResult:
    """Episodes cut from one log and its report entry."""

    path: Path
    episodes: list[Episode]
    entry: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------------------
# checks


def _check_time(path: Path, s: Series) -> float:
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
                f"duplicate timestamp {t[i]:.6f} s (same as row {i - 1})",
                column=s.time_label,
                row=i,
                fix="drop the duplicated rows; exsur does not guess which one is right",
            )
        raise DataError(
            path,
            f"time goes backwards ({t[i - 1]:.6f} s -> {t[i]:.6f} s)",
            column=s.time_label,
            row=i,
            fix="sort the log by time",
        )
    med = float(np.median(d))
    normal = d[d <= 1.5 * med]
    return float(np.mean(normal)) if normal.size else med


def _check_rate(path: Path, s: Series, dt_in: float, mapping: Mapping) -> None:
    rate = 1.0 / dt_in
    if 0.5 <= rate <= 20000:
        return
    fix = "check the time column"
    unit = mapping.time.unit
    if s.name == "table" and unit in ("s", "ms", "us", "ns"):
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
        for cand, f in scale.items():
            r = rate * scale[unit] / f
            if cand != unit and 5 <= r <= 1000:
                fix = f'the time unit looks wrong: set [time] unit = "{cand}" ({r:.4g} Hz)'
                break
    raise DataError(
        path,
        f"typical time step {dt_in:.6g} s means {rate:.4g} Hz, outside 0.5-20000 Hz",
        column=s.time_label,
        fix=fix,
    )


def _nan_policy(
    path: Path, t: np.ndarray, x: np.ndarray, label: str, *, options: ImportOptions
) -> tuple[np.ndarray, int, int]:
    """Apply the NaN policy; returns ``(values, n_filled, n_runs)``."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, 0, 0
    first = int(np.flatnonzero(bad)[0])
    if options.nan == "fail":
        raise DataError(
            path,
            f"missing or non-finite value ({float(x[first])!r})",
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
    x[bad] = np.interp(t[bad], t[good], x[good])
    return x, int(bad.sum()), int(starts.shape[0])


def _check_angle_unit(
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


def _to_command(x: np.ndarray, c: CommandMap) -> np.ndarray:
    """Signed channel value (after scale/offset) -> command in ``c.range``."""
    lo, hi = c.range
    if c.unit == "%":
        return 0.5 * (lo + hi) + x / 100.0 * 0.5 * (hi - lo)
    if c.unit == "raw":
        rlo, rhi = c.raw_range  # type: ignore[misc]
        return lo + (x - rlo) / (rhi - rlo) * (hi - lo)
    return x


def _command(
    path: Path,
    j: JointMap | InputMap,
    chans: tuple[Channel, ...],
    vals: dict[Channel, np.ndarray],
    *,
    options: ImportOptions,
    where: str,
    entry: dict[str, Any],
) -> np.ndarray:
    c = j.command
    what = f"joint '{j.name}' command" if isinstance(j, JointMap) else f"input '{j.name}'"
    span = c.range[1] - c.range[0]
    tol = 1e-9 * span
    raw = [vals[ch] * c.scale + c.offset for ch in chans]
    if c.two_channel:
        for ch, x in zip(chans, raw):
            neg = x < -tol
            if neg.any():
                row = int(np.flatnonzero(neg)[0])
                if options.clip_commands:
                    continue
                raise DataError(
                    path,
                    f"one-way command channel is negative ({x[row]:.6g})",
                    column=ch.label,
                    row=row,
                    fix=f"up/down channels must be >= 0; check scale/offset of {what} in {where}",
                )
        x = (
            np.maximum(raw[0], 0.0) - np.maximum(raw[1], 0.0)
            if options.clip_commands
            else raw[0] - raw[1]
        )
        label = f"{chans[0].label} - {chans[1].label}"
    else:
        x = raw[0]
        label = chans[0].label
    u = _to_command(x, c)
    out = (u < c.range[0] - tol) | (u > c.range[1] + tol)
    if out.any():
        row = int(np.flatnonzero(out)[0])
        if not options.clip_commands:
            raise DataError(
                path,
                f"command {u[row]:.6g} (log value {x[row]:.6g} {c.unit}) is outside "
                f"[{c.range[0]:g}, {c.range[1]:g}] after scaling",
                column=label,
                row=row,
                fix=f"check unit/scale/range of {what} in {where}, or use --clip-commands",
            )
        entry["clipped"][j.name] = int(out.sum())
        u = np.clip(u, c.range[0], c.range[1])
    return u


def _check_velocity_unit(
    path: Path, omega_m: np.ndarray, omega_d: np.ndarray, j: JointMap, label: str, where: str
) -> None:
    """Measured velocity vs the angle's rate of change: catches deg/s vs rad/s and sign errors."""
    nd = float(np.dot(omega_d, omega_d))
    nm = float(np.dot(omega_m, omega_m))
    if omega_d.shape[0] < 10 or nd / omega_d.shape[0] < 1e-4 or nm == 0:
        return  # the joint hardly moves: nothing to compare
    corr = float(np.dot(omega_m, omega_d)) / math.sqrt(nd * nm)
    ratio = float(np.dot(omega_m, omega_d)) / nd
    if corr < -0.8:
        raise DataError(
            path,
            "measured velocity has the opposite sign of the angle's rate of change",
            column=label,
            fix=f"set scale = -1 in the velocity of joint '{j.name}' in {where}",
        )
    if corr > 0.8 and 0.5 / DEG < ratio < 2.0 / DEG:
        raise DataError(
            path,
            f"measured velocity is {ratio:.3g}x the angle's rate of change: looks like deg/s",
            column=label,
            fix=f"set unit = \"deg/s\" in the velocity of joint '{j.name}' in {where}",
        )
    if corr > 0.8 and 0.5 * DEG < ratio < 2.0 * DEG:
        raise DataError(
            path,
            f"measured velocity is {ratio:.3g}x the angle's rate of change: looks like rad/s",
            column=label,
            fix=f"set unit = \"rad/s\" in the velocity of joint '{j.name}' in {where}",
        )


# --------------------------------------------------------------------------------------
# segments


def _intervals(t: np.ndarray, max_gap: float) -> list[tuple[float, float, int, int]]:
    """Runs of ``t`` without a step longer than ``max_gap``: ``(t_start, t_end, row0, row1)``."""
    gaps = np.flatnonzero(np.diff(t) > max_gap)
    starts = np.concatenate([[0], gaps + 1])
    ends = np.concatenate([gaps, [t.shape[0] - 1]])
    return [(float(t[a]), float(t[b]), int(a), int(b)) for a, b in zip(starts, ends)]


def _intersect(
    a: list[tuple[float, float]], b: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    out = []
    i = k = 0
    while i < len(a) and k < len(b):
        lo, hi = max(a[i][0], b[k][0]), min(a[i][1], b[k][1])
        if hi > lo:
            out.append((lo, hi))
        if a[i][1] < b[k][1]:
            i += 1
        else:
            k += 1
    return out


def kalman_fuse(ep: Episode) -> Episode:
    """Angle-only Kalman filtering of ``ep`` for logs without a velocity channel.

    Uses the paper's constant-velocity filter with the jump test and no integration
    consistency test (there is no gyro to integrate): ``method="paper"``, ``tau_cons=inf``.
    Returns the cleaned episode (fused ``theta``, ``omega`` = backward difference of it).

    Raises:
        ConfigError: the cleaning stage is not available.
    """
    fn = _clean_episode()
    from ..clean import CleanConfig

    return fn(ep, config=CleanConfig(method="paper", tau_cons=float("inf")))


def kalman_velocity(ep: Episode) -> np.ndarray:
    """(n_step, n_joint) velocities [rad/s] from angle-only Kalman filtering (:func:`kalman_fuse`)."""
    return np.asarray(kalman_fuse(ep).omega, dtype=np.float64)


def _clean_episode() -> Callable[[Episode], Episode]:
    try:
        from ..clean import clean_episode  # type: ignore[attr-defined]
    except ImportError as e:
        raise ConfigError(
            "velocity = 'kalman' needs excavator_surrogate.clean.clean_episode, which is not "
            "available in this version; use --velocity diff"
        ) from e
    return clean_episode


# --------------------------------------------------------------------------------------
# one log


def convert_log(
    path: str | Path,
    mapping: Mapping,
    *,
    options: ImportOptions | None = None,
    spec: MachineSpec | None = None,
) -> FileResult:
    """Validate one log and turn it into resampled episodes (one per gap-free segment).

    Args:
        path: CSV/Parquet file, ROS bag folder or MCAP file.
        mapping: the parsed mapping.
        options: import options (default: the mapping's ``[import]`` table).
        spec: machine spec at the target rate (default: from the mapping).

    Returns:
        The episodes (named ``<file stem>`` or ``<file stem>_s<k>``, not yet unique across
        files) and the report entry (rows, input rate, fills, drops with reasons).

    Raises:
        DataError: the first validation failure, as one line naming file, column/row and fix.
    """
    path = Path(path)
    options = options or mapping.options
    spec = spec or mapping.spec(options.rate_hz)
    raw: RawLog = read_log(path, mapping)
    where = mapping.path.name if mapping.path is not None else "the mapping"
    rate, dt = spec.rate_hz, spec.dt
    entry: dict[str, Any] = {
        "file": str(path),
        "kind": raw.kind,
        "rows": raw.n_rows,
        "origin": raw.origin,
        "status": "imported",
        "series": {},
        "filled": {},
        "clipped": {},
        "outliers": {},
        "velocity": {},
        "notes": [],
        "segments": [],
    }

    # time bases
    dt_in: dict[str, float] = {}
    for s in raw.series.values():
        dt_in[s.name] = _check_time(path, s)
        _check_rate(path, s, dt_in[s.name], mapping)
        steps = np.diff(s.time)
        steps = steps[steps <= 1.5 * float(np.median(steps))]  # jitter without the gaps
        entry["series"][s.name] = {
            "rows": int(s.time.shape[0]),
            "rate_hz": round(1.0 / dt_in[s.name], 4),
            "jitter_ms": round(float(np.std(steps)) * 1e3, 4) if steps.size else 0.0,
            "duration_s": round(float(s.time[-1] - s.time[0]), 4),
        }
        if 1.0 / dt_in[s.name] < rate * 0.98:
            entry["notes"].append(
                f"{s.name}: logged at {1.0 / dt_in[s.name]:.4g} Hz, upsampled to {rate:g} Hz"
            )

    # missing values
    vals: dict[Channel, np.ndarray] = {}
    for ch in mapping.channels():
        s = raw.series[ch.series]
        x, n_fill, n_runs = _nan_policy(path, s.time, s.values[ch.key], ch.label, options=options)
        if n_fill:
            entry["filled"][ch.label] = {"values": n_fill, "runs": n_runs}
        vals[ch] = x

    # spikes and joint limits, on the input samples (before the anti-alias filter)
    screen_angles(
        path,
        raw,
        vals,
        mapping,
        spec.joints,
        dt_in,
        policy=options.outliers,
        entry=entry,
        check_unit=lambda t, th, j, label: _check_angle_unit(path, t, th, j, label, where),
    )

    # units
    theta_in: list[np.ndarray] = []
    omega_in: list[np.ndarray | None] = []
    u_in: list[np.ndarray] = []
    for j in mapping.joints:
        ach = mapping.angle_channel(j)
        t = raw.series[ach.series].time
        th = vals[ach] * j.angle.scale + j.angle.offset
        _check_angle_unit(path, t, th, j, ach.label, where)
        th = th * DEG if j.angle.unit == "deg" else th
        theta_in.append(np.unwrap(th) if j.periodic else th)
        vch = mapping.velocity_channel(j)
        if vch is not None and j.velocity is not None:
            v = vals[vch] * j.velocity.scale + j.velocity.offset
            omega_in.append(v * DEG if j.velocity.unit == "deg/s" else v)
            entry["velocity"][j.name] = "measured"
        else:
            omega_in.append(None)
            entry["velocity"][j.name] = options.velocity
        u_in.append(
            _command(
                path,
                j,
                mapping.command_channels(j),
                vals,
                options=options,
                where=where,
                entry=entry,
            )
        )
    for inp in mapping.inputs:  # exogenous inputs: the command columns after the joints'
        u_in.append(
            _command(
                path,
                inp,
                mapping.command_channels(inp),
                vals,
                options=options,
                where=where,
                entry=entry,
            )
        )

    # gap-free segments common to all series
    common: list[tuple[float, float]] | None = None
    for s in raw.series.values():
        gap = options.max_gap_s if options.max_gap_s is not None else max(5 * dt_in[s.name], 2 * dt)
        runs = _intervals(s.time, gap)
        for (_, end, _, r1), (nxt, _, _, _) in itertools.pairwise(runs):
            entry["notes"].append(
                f"{s.name}: gap of {nxt - end:.3g} s after row {r1} (t = {end:.3f} s) "
                f"> max_gap {gap:.3g} s: split"
            )
        iv = [(a, b) for a, b, _, _ in runs]
        common = iv if common is None else _intersect(common, iv)

    # resample each segment
    factors = {name: decimation_factor(1.0 / d, rate) for name, d in dt_in.items()}
    sos = {name: antialias_sos(rate, f, lowpass=options.lowpass) for name, f in factors.items()}
    episodes: list[Episode] = []
    segs = common or []
    stem = _stem(path)
    if not segs:
        entry["segments"].append(
            {
                "episode": stem,
                "t_start_s": 0.0,
                "t_end_s": 0.0,
                "status": "dropped",
                "n_step": 0,
                "reason": "the topics share no gap-free time span",
            }
        )
    for k, (a, b) in enumerate(segs):
        name = stem if len(segs) == 1 else f"{stem}_s{k}"
        n = math.floor((b - a) / dt + 1e-9) - 1
        seg_entry: dict[str, Any] = {
            "episode": name,
            "t_start_s": round(a, 6),
            "t_end_s": round(b, 6),
        }
        if n < options.min_steps:
            seg_entry.update(
                status="dropped",
                n_step=max(n, 0),
                reason=f"{max(n, 0)} samples after resampling < min_steps {options.min_steps} "
                f"({b - a:.3g} s at {rate:g} Hz)",
            )
            entry["segments"].append(seg_entry)
            continue
        ep = _resample_segment(
            path,
            mapping,
            raw,
            a,
            b,
            n,
            spec=spec,
            factors=factors,
            sos=sos,
            theta_in=theta_in,
            omega_in=omega_in,
            u_in=u_in,
            where=where,
        )
        ep = ep.replace(
            name=name,
            condition=mapping.machine.condition,
            generator={"stage": "import", "mapping": where, "options": to_dict(options)},
            extra={
                "import": {
                    "file": str(path),
                    "segment": k,
                    "t_start_s": a,
                    "t_end_s": b,
                    "origin": raw.origin,
                    "rate_in_hz": {s: 1.0 / d for s, d in dt_in.items()},
                    "velocity": dict(entry["velocity"]),
                    "filled": dict(entry["filled"]),
                    "clipped": dict(entry["clipped"]),
                    "outliers": dict(entry["outliers"]),
                }
            },
        )
        seg_entry.update(status="imported", n_step=ep.n_step)
        entry["segments"].append(seg_entry)
        episodes.append(ep)
    if options.velocity == "kalman" and episodes and any(o is None for o in omega_in):
        derived = [i for i, o in enumerate(omega_in) if o is None]
        for i, ep in enumerate(episodes):
            # Angle-only filtering: fused theta and omega = backward difference of it, so
            # the pair stays kinematically consistent (theta[k+1] = theta[k] + T_s*omega[k+1]).
            fused = kalman_fuse(ep)
            th, om = ep.theta.copy(), ep.omega.copy()
            th[:, derived] = fused.theta[:, derived]
            om[:, derived] = fused.omega[:, derived]
            episodes[i] = ep.replace(theta=th, omega=om)
    if not episodes:
        entry["status"] = "dropped"
    return FileResult(path, episodes, entry)


def _resample_segment(
    path: Path,
    mapping: Mapping,
    raw: RawLog,
    a: float,
    b: float,
    n: int,
    *,
    spec: MachineSpec,
    factors: dict[str, int],
    sos: dict[str, np.ndarray | None],
    theta_in: list[np.ndarray],
    omega_in: list[np.ndarray | None],
    u_in: list[np.ndarray],
    where: str,
) -> Episode:
    """Samples ``t_k = a + (k + 1) dt``, k = 0..n-1; the grid point ``a`` only anchors omega[0]."""
    rate, dt = spec.rate_hz, spec.dt
    nj = spec.n_joint
    theta_grid = np.empty((n + 1, nj))
    phi_grid: dict[int, np.ndarray] = {}
    u = np.empty((n, spec.n_u))
    edges = a + dt * np.arange(1, n + 2)
    rows: dict[str, slice] = {}
    for name, s in raw.series.items():
        i0 = max(int(np.searchsorted(s.time, a, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(s.time, b, side="left")), s.time.shape[0] - 1)
        rows[name] = slice(i0, i1 + 1)
    for i, j in enumerate(mapping.joints):
        sname = mapping.angle_channel(j).series
        sl = rows[sname]
        t = raw.series[sname].time[sl]
        theta_grid[:, i] = resample_smooth(
            t,
            theta_in[i][sl],
            t0=a,
            n_out=n + 1,
            rate_hz=rate,
            factor=factors[sname],
            sos=sos[sname],
            t_end=b,
        )
        om = omega_in[i]
        vch = mapping.velocity_channel(j)
        if om is not None and vch is not None:
            vs = rows[vch.series]
            tv = raw.series[vch.series].time[vs]
            phi = cumulative_trapezoid(tv, om[vs])
            phi_grid[i] = resample_smooth(
                tv,
                phi,
                t0=a,
                n_out=n + 1,
                rate_hz=rate,
                factor=factors[vch.series],
                sos=sos[vch.series],
                t_end=b,
            )
    for i, src in enumerate(mapping.u_sources()):
        cname = mapping.command_channels(src)[0].series
        cs = rows[cname]
        u[:, i] = interval_mean(raw.series[cname].time[cs], u_in[i][cs], edges)
    lo = np.array([c.u_min for c in spec.u_specs])
    hi = np.array([c.u_max for c in spec.u_specs])
    u = np.clip(u, lo, hi)  # the means lie in range; this only removes rounding error
    theta = theta_grid[1:]
    omega = np.diff(theta_grid, axis=0) / dt
    for i, j in enumerate(mapping.joints):
        if i in phi_grid:
            measured = np.diff(phi_grid[i]) / dt
            vch = mapping.velocity_channel(j)
            _check_velocity_unit(
                path, measured, omega[:, i], j, vch.label if vch else j.name, where
            )
            omega[:, i] = measured
    time = a + dt * np.arange(1, n + 1)
    return Episode(spec=spec, time=time, u=u, theta=theta, omega=omega, source="import")


_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def _stem(path: Path) -> str:
    return _SAFE.sub("_", log_stem(path)).strip("_.") or "log"


# --------------------------------------------------------------------------------------
# many logs -> dataset


def _check_out(out: Path, inputs: list[Path], *, overwrite: bool) -> None:
    """The output-folder rule (:mod:`excavator_surrogate.outdir`): no input (a log, the
    mapping) inside ``out``; a folder exsur did not write only with ``overwrite``."""
    check_out_dir(out, overwrite=overwrite, inputs=inputs)


def import_logs(
    sources: Sequence[str | Path],
    mapping: Mapping,
    *,
    out: str | Path | None,
    options: ImportOptions | None = None,
    split: SplitOptions | None = None,
    quiet: bool = False,
    overwrite: bool = False,
    inputs: Sequence[str | Path] = (),
) -> dict[str, Any]:
    """Import logs into a dataset folder (atomically) and return the report.

    Args:
        sources: files, folders or glob patterns (see :func:`expand_sources`).
        mapping: the parsed mapping file.
        out: dataset folder, replaced only when complete; None: validate only (dry run).
        options: import options (default: the mapping's ``[import]``).
        split: split options (default: the mapping's ``[split]``).
        quiet: no progress lines on stderr.
        overwrite: ``out`` may be replaced even if exsur did not write it (``--overwrite``).
        inputs: other files read (split file); like the logs and the mapping, none may lie
            inside ``out``.

    Returns:
        The report (also written to ``out/import_report.json``).

    Raises:
        DataError: a log breaks a validation rule (nothing is written), or nothing remains.
        ConfigError: bad options, or ``out`` is not a dataset folder.
    """
    options = options or mapping.options
    split = split or mapping.split
    paths = expand_sources(sources)
    outp = Path(out) if out is not None else None
    if outp is not None:
        mapping_file = [mapping.path] if mapping.path is not None else []
        _check_out(outp, [*paths, *mapping_file, *map(Path, inputs)], overwrite=overwrite)
    if options.velocity == "kalman":
        _clean_episode()
    spec = mapping.spec(options.rate_hz)
    results: list[FileResult] = []
    failed: list[dict[str, Any]] = []
    for p in progress(paths, total=len(paths), desc="import", disable=True if quiet else None):
        try:
            res = convert_log(p, mapping, options=options, spec=spec)
            results.append(res)
            if not quiet:
                n_out = sum(e.n_step for e in res.episodes)
                log(
                    f"{p}: {res.entry['rows']} rows -> {len(res.episodes)} episode(s), {n_out} samples"
                )
        except DataError as e:
            if options.on_error != "skip":
                raise
            failed.append({"file": str(p), "status": "failed", "error": str(e), "segments": []})
            if not quiet:
                log(f"skipped {p}: {e}")
    # unique episode names across files
    used: set[str] = set()
    for r in results:
        for i, ep in enumerate(r.episodes):
            name, k = ep.name, 2
            while name in used:
                name, k = f"{ep.name}_{k}", k + 1
            used.add(name)
            if name != ep.name:
                for seg in r.entry["segments"]:
                    if seg.get("episode") == ep.name:
                        seg["episode"] = name
                r.episodes[i] = ep.replace(name=name)
    kept = [r for r in results if r.episodes]
    if not kept:
        reasons = [s["reason"] for r in results for s in r.entry["segments"] if s.get("reason")]
        why = reasons[0] if reasons else (failed[0]["error"] if failed else "no segments")
        raise DataError(
            outp or (paths[0] if paths else None),
            f"nothing to import: every episode was dropped (e.g. {why})",
            fix="lower --min-steps, raise --max-gap, or check the logs",
        )
    splits, warnings = assign_splits(
        [str(r.path) for r in kept], [sum(e.n_step for e in r.episodes) for r in kept], split
    )
    items: list[tuple[Episode, str]] = []
    for r in kept:
        s = splits[str(r.path)]
        r.entry["split"] = s
        for seg in r.entry["segments"]:
            if seg["status"] == "imported":
                seg["split"] = s
        items.extend((ep, s) for ep in r.episodes)
    report = _report(mapping, spec, options, split, results, failed, items, warnings, outp)
    md = render_markdown(report)
    if outp is not None:
        config = {
            "import": {**to_dict(options), "sources": [str(p) for p in paths]},
            "split": to_dict(split),
            "mapping": mapping.raw,
        }
        extra = {
            "source": "import",
            "import": {"mapping": report["mapping"], "totals": report["totals"]},
        }
        with (
            replace_allowed(outp) if overwrite else contextlib.nullcontext(),
            atomic_dir(outp) as tmp,
        ):
            write_dataset(tmp, items, config=config, extra=extra)
            write_json(tmp / REPORT_JSON, report)
            write_text(tmp / REPORT_MD, md)
        if not quiet:
            log(f"wrote {len(items)} episodes to {outp}")
    return report


def _report(
    mapping: Mapping,
    spec: MachineSpec,
    options: ImportOptions,
    split: SplitOptions,
    results: list[FileResult],
    failed: list[dict[str, Any]],
    items: list[tuple[Episode, str]],
    warnings: list[str],
    out: Path | None,
) -> dict[str, Any]:
    files = [r.entry for r in results] + failed
    dropped = [
        {"file": e["file"], **s}
        for e in files
        for s in e.get("segments", [])
        if s["status"] == "dropped"
    ]
    n_samples = {s: sum(ep.n_step for ep, sp in items if sp == s) for s in ("train", "val", "test")}
    return {
        "report_version": 1,
        "out": str(out) if out is not None else None,
        "mapping": str(mapping.path) if mapping.path is not None else None,
        "spec": spec.to_dict(),
        "options": to_dict(options),
        "split": to_dict(split),
        "totals": {
            "files": len(files),
            "files_imported": sum(1 for e in files if e["status"] == "imported"),
            "files_dropped": sum(1 for e in files if e["status"] == "dropped"),
            "files_failed": len(failed),
            "rows_in": sum(int(e.get("rows", 0)) for e in files),
            "episodes": len(items),
            "segments_dropped": len(dropped),
            "episodes_per_split": {
                s: sum(1 for _, sp in items if sp == s) for s in ("train", "val", "test")
            },
            "samples_per_split": n_samples,
        },
        "files": files,
        "dropped": dropped,
        "warnings": warnings,
    }


def options_with(base: ImportOptions, **changes: Any) -> ImportOptions:
    """``base`` with the non-None ``changes`` applied (CLI overrides)."""
    return dataclasses.replace(base, **{k: v for k, v in changes.items() if v is not None})
