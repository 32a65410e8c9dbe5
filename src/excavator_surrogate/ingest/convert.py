"""One log -> resampled episodes: validate, convert units, split at gaps, resample.

:func:`convert_log` runs the steps in order, each a function below: time bases
(:func:`_time_bases`), missing values (:func:`_fill_missing`), the log's own unit labels
(:func:`_check_log_units`), spikes and joint limits (:func:`~.outliers.screen_angles`),
units (:func:`_to_units`), gap-free segments
(:func:`_common_segments`), resampling (:func:`_cut_episodes`) and, for ``velocity =
"kalman"``, angle-only filtering (:func:`.velocity.kalman_velocities`).  The checks they
run are in :mod:`.checks`; :func:`~.importer.import_logs` runs this over many logs.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import to_dict
from ..data import Episode
from ..spec import MachineSpec
from .checks import (
    apply_nan_policy,
    check_angle_unit,
    check_linkage_reach,
    check_log_unit,
    check_one_way,
    check_rate,
    check_time,
    check_upsampling,
    check_velocity_unit,
    command_of,
)
from .limits import memory_limit, too_big
from .mapping import Channel, ImportOptions, InputMap, JointMap, Mapping
from .outliers import screen_angles
from .readers import log_stem, read_log
from .resample import (
    antialias_sos,
    cumulative_trapezoid,
    decimation_factor,
    hold,
    interval_mean,
    resample_smooth,
    span_rows,
)
from .run_inputs import run_input_value
from .sources import RawLog
from .units import to_si
from .velocity import kalman_velocities


@dataclass
class FileResult:
    """Episodes cut from one log and its report entry."""

    path: Path
    episodes: list[Episode]
    entry: dict[str, Any] = field(default_factory=dict)
    digest: str = ""
    """:meth:`RawLog.digest` of the log: equal for two copies of one recording."""


@dataclass(frozen=True)
class _Signals:
    """A log's signals in SI units, each on its own series' time base (before resampling)."""

    theta: list[np.ndarray]
    """Per joint: angle [rad] (unwrapped if periodic)."""
    omega: list[np.ndarray | None]
    """Per joint: measured velocity [rad/s], or None (derived from the angle)."""
    u: list[np.ndarray]
    """Per command column (joints, then inputs): command in its range; a 0-d array for a
    per-run constant input (``from_name`` / ``from_metadata``)."""
    u_time: list[np.ndarray | None]
    """Per command column: its own time base [s] where its up and down channels lie on two
    topics (the union of their times, both held on it), else None (its channels' series)."""


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
    raw = read_log(path, dataclasses.replace(mapping, options=options))  # the reader's bounds
    where = mapping.path.name if mapping.path is not None else "the mapping"
    entry = _new_entry(path, raw)
    dt_in = _time_bases(path, raw, mapping, rate_hz=spec.rate_hz, options=options, entry=entry)
    vals = _fill_missing(path, raw, mapping, options=options, entry=entry)
    _check_log_units(path, raw, mapping, options=options, where=where)  # before any value
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
        check_unit=lambda t, th, j, label: check_angle_unit(path, t, th, j, label, where),
    )
    sig = _to_units(path, raw, vals, mapping, options=options, where=where, entry=entry)
    segs = _common_segments(raw, dt_in, options=options, dt=spec.dt, entry=entry)
    episodes = _cut_episodes(
        path,
        raw,
        sig,
        segs,
        mapping,
        dt_in=dt_in,
        spec=spec,
        options=options,
        where=where,
        entry=entry,
    )
    if options.velocity == "kalman":
        episodes = kalman_velocities(episodes, sig.omega)
    if not episodes:
        entry["status"] = "dropped"
    return FileResult(path, episodes, entry, digest=raw.digest())


def _new_entry(path: Path, raw: RawLog) -> dict[str, Any]:
    """The report entry of one log, before any step fills it in."""
    return {
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


def _time_bases(
    path: Path,
    raw: RawLog,
    mapping: Mapping,
    *,
    rate_hz: float,
    options: ImportOptions,
    entry: dict[str, Any],
) -> dict[str, float]:
    """Check each series' time column and the upsampling; series name -> typical input step [s]."""
    dt_in: dict[str, float] = {}
    for s in raw.series.values():
        dt_in[s.name] = check_time(path, s)
        check_rate(path, s, dt_in[s.name], mapping)
        steps = np.diff(s.time)
        steps = steps[steps <= 1.5 * float(np.median(steps))]  # jitter without the gaps
        entry["series"][s.name] = {
            "rows": int(s.time.shape[0]),
            "rate_hz": round(1.0 / dt_in[s.name], 4),
            "jitter_ms": round(float(np.std(steps)) * 1e3, 4) if steps.size else 0.0,
            "duration_s": round(float(s.time[-1] - s.time[0]), 4),
        }
        if 1.0 / dt_in[s.name] < rate_hz * 0.98:
            entry["notes"].append(
                f"{s.name}: logged at {1.0 / dt_in[s.name]:.4g} Hz, upsampled to {rate_hz:g} Hz"
            )
    check_upsampling(path, list(raw.series.values()), dt_in, rate_hz, options.max_upsample)
    return dt_in


def _fill_missing(
    path: Path, raw: RawLog, mapping: Mapping, *, options: ImportOptions, entry: dict[str, Any]
) -> dict[Channel, np.ndarray]:
    """Every mapped channel's values with the NaN policy applied (fills counted in ``entry``;
    a periodic joint's angle filled through its wrap)."""
    turns = {
        mapping.angle_channel(j): 2 * math.pi / (to_si(j.angle.unit) * abs(j.angle.scale))
        for j in mapping.joints
        if j.periodic and j.angle.scale
    }
    vals: dict[Channel, np.ndarray] = {}
    for ch in mapping.channels():
        s = raw.series_of(ch)
        x, n_fill, n_runs = apply_nan_policy(
            path, s.time, s.values[ch.key], ch.label, options=options, period=turns.get(ch)
        )
        if n_fill:
            entry["filled"][ch.label] = {"values": n_fill, "runs": n_runs}
        vals[ch] = x
    return vals


def _check_log_units(
    path: Path, raw: RawLog, mapping: Mapping, *, options: ImportOptions, where: str
) -> None:
    """The log's own unit of each joint's position and velocity channel (an MDF channel's,
    a dSPACE trace's) is the mapping's: checked before the values are screened, so a log in
    mm mapped as m is named as that, not as impossible values.  Not for a scaled channel,
    whose log unit is not the mapped one (raw counts, volts), nor with ``log_units =
    "ignore"``."""
    if options.log_units == "ignore":
        return
    for j in mapping.joints:
        position = "position" if j.linear else "angle"  # the mapping's word for it
        chans = [(mapping.angle_channel(j), j.angle.unit, j.angle.scale, position)]
        vch = mapping.velocity_channel(j)
        if vch is not None and j.velocity is not None:
            chans.append((vch, j.velocity.unit, j.velocity.scale, "velocity"))
        for ch, mapped, scale, role in chans:
            if mapped is None or scale != 1.0:
                continue
            theirs = raw.series_of(ch).units.get(ch.key, "")
            what = f"the {role} of joint '{j.name}'"
            check_log_unit(path, theirs, mapped, label=ch.label, what=what, where=where)


def _to_units(
    path: Path,
    raw: RawLog,
    vals: dict[Channel, np.ndarray],
    mapping: Mapping,
    *,
    options: ImportOptions,
    where: str,
    entry: dict[str, Any],
) -> _Signals:
    """Angles [rad], measured velocities [rad/s] and commands in range, checked."""
    theta: list[np.ndarray] = []
    omega: list[np.ndarray | None] = []
    u: list[np.ndarray] = []
    u_time: list[np.ndarray | None] = []

    def command(src: JointMap | InputMap) -> None:
        chans = mapping.command_channels(src)
        if len({raw.series_name(ch) for ch in chans}) == 1:
            u.append(command_of(path, src, chans, vals, options=options, where=where, entry=entry))
            u_time.append(None)
            return
        # up and down on two topics (channel groups): each checked on its own messages,
        # then both held on the union of their times, where up - down is the valve's command
        c = src.command
        times = [raw.series_of(ch).time for ch in chans]
        for k, ch in enumerate(chans):
            x = vals[ch] * c.scale + c.offset
            check_one_way(path, src, ch, x, down=k == 1, full=True, options=options, where=where)
        t = np.union1d(*times)
        held = {ch: hold(tk, vals[ch], t) for ch, tk in zip(chans, times)}
        u.append(command_of(path, src, chans, held, options=options, where=where, entry=entry))
        u_time.append(t)

    for j in mapping.joints:
        ach = mapping.angle_channel(j)
        t = raw.series_of(ach).time
        th = vals[ach] * j.angle.scale + j.angle.offset
        check_angle_unit(path, t, th, j, ach.label, where)
        th = th * to_si(j.angle.unit)  # rad, or m for a linear joint
        check_linkage_reach(path, th, j, ach.label, where)
        theta.append(np.unwrap(th) if j.periodic else th)
        vch = mapping.velocity_channel(j)
        if vch is not None and j.velocity is not None:
            v = vals[vch] * j.velocity.scale + j.velocity.offset
            omega.append(v * to_si(j.velocity.unit))
            entry["velocity"][j.name] = "measured"
        else:
            omega.append(None)
            entry["velocity"][j.name] = options.velocity
        command(j)
    for inp in mapping.inputs:  # exogenous inputs: after the joints'
        if inp.run is None:
            command(inp)
            continue
        rng = (float(inp.command.range[0]), float(inp.command.range[1]))
        value, note = run_input_value(
            path, log_stem(path), raw.meta, inp.name, inp.run, rng, where=where
        )
        entry.setdefault("run_inputs", {})[inp.name] = {"value": value, "from": note}
        u.append(np.asarray(value, dtype=np.float64))
        u_time.append(None)
    return _Signals(theta=theta, omega=omega, u=u, u_time=u_time)


def _common_segments(
    raw: RawLog,
    dt_in: dict[str, float],
    *,
    options: ImportOptions,
    dt: float,
    entry: dict[str, Any],
) -> list[tuple[float, float]]:
    """The gap-free time spans ``(t_start, t_end)`` [s] common to all series (gaps noted)."""
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
    return common or []


def _intervals(t: np.ndarray, max_gap: float) -> list[tuple[float, float, int, int]]:
    """Runs of ``t`` without a step longer than ``max_gap``: ``(t_start, t_end, row0, row1)``."""
    gaps = np.flatnonzero(np.diff(t) > max_gap)
    starts = np.concatenate([[0], gaps + 1])
    ends = np.concatenate([gaps, [t.shape[0] - 1]])
    return [(float(t[a]), float(t[b]), int(a), int(b)) for a, b in zip(starts, ends)]


def _intersect(
    a: list[tuple[float, float]], b: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """The overlaps of two sorted lists of disjoint spans."""
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


def _cut_episodes(
    path: Path,
    raw: RawLog,
    sig: _Signals,
    segs: list[tuple[float, float]],
    mapping: Mapping,
    *,
    dt_in: dict[str, float],
    spec: MachineSpec,
    options: ImportOptions,
    where: str,
    entry: dict[str, Any],
) -> list[Episode]:
    """One resampled episode per segment of at least ``options.min_steps`` samples.

    Every segment gets an entry in ``entry["segments"]`` (imported, or dropped with the reason).
    """
    rate, dt = spec.rate_hz, spec.dt
    factors = {name: decimation_factor(1.0 / d, rate) for name, d in dt_in.items()}
    sos = {name: antialias_sos(rate, f, lowpass=options.lowpass) for name, f in factors.items()}
    stem = _stem(path)
    if not segs:
        entry["segments"].append(
            {
                "episode": stem,
                "t_start_s": 0.0,
                "t_end_s": 0.0,
                "status": "dropped",
                "n_step": 0,
                "reason": f"the {'channel groups' if raw.kind == 'mdf' else 'topics'} share no "
                "gap-free time span",
            }
        )
    # estimate the output before resampling (time, u, theta, omega, the grids: 2 copies)
    n_total = sum(max(math.floor((b - a) / dt + 1e-9) - 1, 0) for a, b in segs)
    n_bytes = 2 * 8 * n_total * (1 + spec.n_u + 2 * spec.n_joint)
    limit = memory_limit(options.max_memory_mb)
    if n_bytes > limit:
        raise too_big(path, f"resampling to {rate:.6g} Hz ({n_total} samples)", n_bytes, limit)
    episodes: list[Episode] = []
    for k, (a, b) in enumerate(segs):
        name = stem if len(segs) == 1 else f"{stem}_s{k}"
        n = math.floor((b - a) / dt + 1e-9) - 1
        seg_entry: dict[str, Any] = {
            "episode": name,
            "t_start_s": round(a, 6),
            "t_end_s": round(b, 6),
        }
        entry["segments"].append(seg_entry)
        if n < options.min_steps:
            seg_entry.update(
                status="dropped",
                n_step=max(n, 0),
                reason=f"{max(n, 0)} samples after resampling < min_steps {options.min_steps} "
                f"({b - a:.3g} s at {rate:g} Hz)",
            )
            continue
        ep = _resample_segment(
            path, mapping, raw, sig, a, b, n, spec=spec, factors=factors, sos=sos, where=where
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
                    **({"run_inputs": dict(entry["run_inputs"])} if "run_inputs" in entry else {}),
                }
            },
        )
        seg_entry.update(status="imported", n_step=ep.n_step)
        episodes.append(ep)
    return episodes


def _resample_segment(
    path: Path,
    mapping: Mapping,
    raw: RawLog,
    sig: _Signals,
    a: float,
    b: float,
    n: int,
    *,
    spec: MachineSpec,
    factors: dict[str, int],
    sos: dict[str, np.ndarray | None],
    where: str,
) -> Episode:
    """Samples ``t_k = a + (k + 1) dt``, k = 0..n-1; the grid point ``a`` only anchors omega[0]."""
    rate, dt = spec.rate_hz, spec.dt
    nj = spec.n_joint
    theta_grid = np.empty((n + 1, nj))
    phi_grid: dict[int, tuple[np.ndarray, str]] = {}
    u = np.empty((n, spec.n_u))
    edges = a + dt * np.arange(1, n + 2)
    rows = {name: span_rows(s.time, a, b) for name, s in raw.series.items()}
    for i, j in enumerate(mapping.joints):
        sname = raw.series_name(mapping.angle_channel(j))
        sl = rows[sname]
        t = raw.series[sname].time[sl]
        theta_grid[:, i] = resample_smooth(
            t,
            sig.theta[i][sl],
            t0=a,
            n_out=n + 1,
            rate_hz=rate,
            factor=factors[sname],
            sos=sos[sname],
            t_end=b,
        )
        om = sig.omega[i]
        vch = mapping.velocity_channel(j)
        if om is not None and vch is not None:
            # resample the integrated velocity, so its difference is the interval mean
            vname = raw.series_name(vch)
            vs = rows[vname]
            tv = raw.series[vname].time[vs]
            phi = cumulative_trapezoid(tv, om[vs])
            phi_grid[i] = (
                resample_smooth(
                    tv,
                    phi,
                    t0=a,
                    n_out=n + 1,
                    rate_hz=rate,
                    factor=factors[vname],
                    sos=sos[vname],
                    t_end=b,
                ),
                vch.label,
            )
    for i, src in enumerate(mapping.u_sources()):
        if sig.u[i].ndim == 0:  # a per-run constant input
            u[:, i] = sig.u[i]
            continue
        tu = sig.u_time[i]
        if tu is None:  # on its channel's series
            tu = raw.series_of(mapping.command_channels(src)[0]).time
        cs = span_rows(tu, a, b)
        u[:, i] = interval_mean(tu[cs], sig.u[i][cs], edges)
    lo = np.array([c.u_min for c in spec.u_specs])
    hi = np.array([c.u_max for c in spec.u_specs])
    u = np.clip(u, lo, hi)  # the means lie in range; this only removes rounding error
    theta = theta_grid[1:]
    omega = np.diff(theta_grid, axis=0) / dt
    for i, (phi, label) in phi_grid.items():
        measured = np.diff(phi) / dt
        check_velocity_unit(path, measured, omega[:, i], mapping.joints[i], label, where)
        omega[:, i] = measured
    time = a + dt * np.arange(1, n + 1)
    return Episode(spec=spec, time=time, u=u, theta=theta, omega=omega, source="import")


_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def _stem(path: Path) -> str:
    """The log's name, safe as an episode name."""
    return _SAFE.sub("_", log_stem(path)).strip("_.") or "log"
