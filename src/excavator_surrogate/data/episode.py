"""The episode data contract: one Parquet file per episode.

Columns (``<j>`` is each joint name from the :class:`~excavator_surrogate.spec.MachineSpec`):

=====================  ===============  ==========================================================
column                 unit             meaning
=====================  ===============  ==========================================================
``time``               s                sample time, strictly increasing at ``rate_hz``
``u_<j>``              command units    joint command applied from this sample on; then
``u_<input>``          input unit       each exogenous input (spec.inputs), same timing
``theta_<j>``          rad              measured joint angle (periodic joints may be unwrapped)
``omega_<j>``          rad/s            measured angular velocity
``theta_<j>_true``     rad              optional: ground-truth angle (simulated data)
``omega_<j>_true``     rad/s            optional: ground-truth mean velocity over the last sample
``trusted_<j>``        bool             optional: measurement trusted by the cleaning stage
=====================  ===============  ==========================================================

The Arrow schema metadata key ``exsur`` holds JSON: ``schema_version``, ``rate_hz``,
``spec`` (the joint spec), ``source`` (e.g. ``mujoco-ideal``), ``condition``, ``seed``,
``generator`` (the config that produced it), ``units`` and free ``extra``.

:func:`read_episode` validates every file against the contract and raises
:class:`~excavator_surrogate.errors.DataError` with a one-line message naming the file,
the column or row, and what to do.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..errors import DataError
from ..io_utils import atomic_path
from ..spec import MachineSpec
from .plausible import check_plausible

SCHEMA_VERSION = 1
"""Version of the episode contract written by this package."""
META_KEY = b"exsur"
RATE_RTOL = 0.05
"""Tolerated relative deviation of each time step from ``1 / rate_hz``."""

UNITS = {
    "time": "s",
    "u": "command units (see spec.joints[].u_unit)",
    "theta": "rad",
    "omega": "rad/s",
    "trusted": "bool",
}


def columns_for(spec: MachineSpec) -> dict[str, list[str]]:
    """Column names per role for ``spec``: keys ``u``, ``theta``, ``omega``, ``theta_true``,
    ``omega_true``, ``trusted``."""
    n = spec.names
    return {
        "u": [f"u_{j}" for j in spec.u_names],
        "theta": [f"theta_{j}" for j in n],
        "omega": [f"omega_{j}" for j in n],
        "theta_true": [f"theta_{j}_true" for j in n],
        "omega_true": [f"omega_{j}_true" for j in n],
        "trusted": [f"trusted_{j}" for j in n],
    }


@dataclass
class Episode:
    """One recorded (or simulated) run of a machine.

    Arrays are ``(n_step,)`` or ``(n_step, n_joint)`` with joints ordered as ``spec.joints``.

    - ``time``: (n_step,) [s]
    - ``u``: (n_step, n_u) commands (the joints', then the exogenous inputs'; ``n_u =
      spec.n_u``), each within its ``[u_min, u_max]``
    - ``theta``: (n_step, n_joint) measured angles [rad]
    - ``omega``: (n_step, n_joint) measured angular velocities [rad/s]
    - ``theta_true`` / ``omega_true``: optional ground truth, same shape
    - ``trusted``: optional (n_step, n_joint) bool flags from the cleaning stage
    """

    spec: MachineSpec
    time: np.ndarray
    u: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    theta_true: np.ndarray | None = None
    omega_true: np.ndarray | None = None
    trusted: np.ndarray | None = None
    source: str = "unknown"
    """Where the data came from: ``mujoco-ideal``, ``mujoco-hydraulic``, ``import`` ..."""
    condition: str = "default"
    """Operating condition: ``noload``, ``compound`` ..."""
    seed: int | None = None
    """Seed that generated the episode (simulated data)."""
    generator: dict[str, Any] = field(default_factory=dict)
    """Config that produced the episode."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Free-form metadata (e.g. cleaning statistics, import provenance)."""
    name: str = "episode"
    """Episode name (file stem)."""

    @property
    def n_step(self) -> int:
        """Number of samples."""
        return int(self.time.shape[0])

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return self.spec.dt

    def replace(self, **changes: Any) -> Episode:
        """Copy with fields replaced."""
        return replace(self, **changes)

    def slice(self, start: int, stop: int) -> Episode:
        """Samples ``[start, stop)`` as a new episode.

        Sample-indexed metadata follows the cut: the sensor model's jump runs
        (``extra["sensor"]["jump_runs"]``, ``[[joint, a, b), ...]``) are clipped to the part
        and counted from its first sample.
        """
        start, stop, _ = slice(start, stop).indices(self.n_step)
        sl = slice(start, stop)

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[sl]

        extra = self.extra
        sensor = extra.get("sensor") if isinstance(extra, dict) else None
        if isinstance(sensor, dict) and "jump_runs" in sensor:
            runs = [
                [int(j), max(int(a), start) - start, min(int(b), stop) - start]
                for j, a, b in sensor["jump_runs"]
                if min(int(b), stop) > max(int(a), start)
            ]
            extra = {**extra, "sensor": {**sensor, "jump_runs": runs}}
        return replace(
            self,
            time=self.time[sl],
            u=self.u[sl],
            theta=self.theta[sl],
            omega=self.omega[sl],
            theta_true=cut(self.theta_true),
            omega_true=cut(self.omega_true),
            trusted=cut(self.trusted),
            extra=extra,
        )

    def metadata(self) -> dict[str, Any]:
        """The JSON metadata stored under the ``exsur`` key."""
        return {
            "schema_version": SCHEMA_VERSION,
            "rate_hz": self.spec.rate_hz,
            "spec": self.spec.to_dict(),
            "source": self.source,
            "condition": self.condition,
            "seed": self.seed,
            "generator": self.generator,
            "units": UNITS,
            "extra": self.extra,
            "name": self.name,
        }

    def to_table(self) -> pa.Table:
        """Arrow table with the contract's columns and metadata."""
        cols = columns_for(self.spec)
        data: dict[str, Any] = {"time": np.asarray(self.time, dtype=np.float64)}
        for role in ("u", "theta", "omega", "theta_true", "omega_true"):
            arr = getattr(self, role)
            if arr is None:
                continue
            arr = np.asarray(arr, dtype=np.float64)
            for k, c in enumerate(cols[role]):
                data[c] = arr[:, k]
        if self.trusted is not None:
            tr = np.asarray(self.trusted, dtype=bool)
            for k, c in enumerate(cols["trusted"]):
                data[c] = tr[:, k]
        table = pa.table(data)
        meta = json.dumps(self.metadata(), default=_json_default).encode()
        return table.replace_schema_metadata({META_KEY: meta})


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


_JSON_KINDS: dict[type, str] = {
    str: "string",
    list: "array",
    int: "number",
    float: "number",
    bool: "boolean",
    type(None): "null",
}
"""The JSON name of each type ``json.loads`` returns besides an object."""


def _first_null(col: pa.ChunkedArray) -> int:
    """Row of the first null of ``col`` (an Arrow null, not a float NaN)."""
    return int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])


def write_episode(path: str | Path, episode: Episode, *, validate: bool = True) -> Path:
    """Write ``episode`` to ``path`` (Parquet, zstd), atomically.  Returns the path."""
    path = Path(path)
    if validate:
        validate_episode(episode, where=path)
    table = episode.to_table()
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return path


def read_metadata(path: str | Path) -> dict[str, Any]:
    """Read only the ``exsur`` metadata of an episode file (no data)."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "file not found", fix="check the path or the dataset manifest")
    if path.is_dir():
        files = sorted(path.glob("episodes/*.parquet")) or sorted(path.glob("*.parquet"))
        example = f" such as {files[0]}" if files else ""
        raise DataError(
            path,
            "is a folder, not an episode file",
            fix=f"give one of its episode files{example}",
        )
    try:
        schema = pq.read_schema(path)
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise DataError(
            path,
            f"not a readable Parquet file ({type(e).__name__})",
            fix="re-export the episode as Parquet, or use 'exsur import' for CSV logs",
        ) from e
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise DataError(
            path,
            "no 'exsur' metadata in the Parquet schema",
            fix="this is not an exsur episode; convert logs with 'exsur import'",
        )
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as e:
        raise DataError(
            path, "the 'exsur' metadata is not valid JSON", fix="re-write the episode with exsur"
        ) from e
    if not isinstance(meta, dict):
        kind = _JSON_KINDS.get(type(meta), "value")
        raise DataError(
            path,
            f"the 'exsur' metadata is a JSON {kind}, not an object",
            fix="re-write the episode with exsur",
        )
    return meta


def read_episode(
    path: str | Path,
    *,
    min_steps: int = 1,
    spec: MachineSpec | None = None,
    validate: bool = True,
) -> Episode:
    """Read and validate one episode file.

    Args:
        path: the Parquet file.
        min_steps: reject episodes shorter than this (use the model window + 1).
        spec: if given, the file's machine must be this one (:meth:`MachineSpec.mismatch`:
            joints, periodic flags, kinds, command ranges, rate and exogenous inputs).
        validate: run :func:`validate_episode` (always on for user data).

    Raises:
        DataError: one line naming the file, column/row, and the fix.
    """
    path = Path(path)
    meta = read_metadata(path)
    version = meta.get("schema_version")
    if version != SCHEMA_VERSION:
        raise DataError(
            path,
            f"schema_version {version!r} is not supported (this exsur reads {SCHEMA_VERSION})",
            fix="re-create the dataset with this version of exsur",
        )
    try:
        file_spec = MachineSpec.from_dict(meta["spec"])
    except Exception as e:
        raise DataError(
            path, f"metadata 'spec' is malformed ({e})", fix="re-write the episode with exsur"
        ) from e
    rate = meta.get("rate_hz")
    if not isinstance(rate, int | float) or abs(float(rate) - file_spec.rate_hz) > 1e-9:
        raise DataError(
            path,
            f"metadata rate_hz {rate!r} disagrees with the spec's {file_spec.rate_hz}",
            fix="re-write the episode with exsur",
        )
    diff = None if spec is None else spec.mismatch(file_spec)
    if diff is not None:
        raise DataError(
            path,
            f"the episode is of another machine ({diff}, expected vs episode)",
            fix="use data recorded for the same machine, at the same rate and command scale",
        )
    names = pq.read_schema(path).names  # before reading: pyarrow fails on them with its schema
    dup = sorted({c for c in names if names.count(c) > 1})
    if dup:
        raise DataError(path, "duplicated column", column=dup[0], fix="each column may appear once")
    try:
        table = pq.read_table(path)
    except Exception as e:
        raise DataError(
            path,
            f"cannot read Parquet data ({type(e).__name__}: {str(e).splitlines()[0][:160]})",
            fix="the file is corrupt; regenerate or re-import it",
        ) from e
    names = table.column_names
    cols = columns_for(file_spec)
    required = ["time", *cols["u"], *cols["theta"], *cols["omega"]]
    for c in required:
        if c not in names:
            raise DataError(
                path,
                "required column is missing",
                column=c,
                fix=f"an episode for joints {list(file_spec.names)} needs time, u_*, theta_*, omega_*",
            )

    def num(c: str) -> np.ndarray:
        col = table.column(c)
        if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type)):
            raise DataError(
                path,
                f"values are of type {col.type}, not numeric",
                column=c,
                fix="store numbers only",
            )
        if col.null_count:
            raise DataError(
                path,
                "contains a null value",
                column=c,
                row=_first_null(col),
                fix="fill or drop the gap",
            )
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)

    def flag(c: str) -> np.ndarray:
        col = table.column(c)
        fix = "store true/false (or 1/0) in every row, or drop all trusted_* columns"
        if not (pa.types.is_boolean(col.type) or pa.types.is_integer(col.type)):
            raise DataError(path, f"values are of type {col.type}, not bool", column=c, fix=fix)
        if col.null_count:
            raise DataError(path, "contains a null value", column=c, row=_first_null(col), fix=fix)
        arr = col.to_numpy(zero_copy_only=False)
        bad = (arr != 0) & (arr != 1)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise DataError(path, f"flag {arr[row]} is not true/false", column=c, row=row, fix=fix)
        return np.asarray(arr, dtype=bool)

    def stack(role: str) -> np.ndarray | None:
        cs = cols[role]
        present = [c in names for c in cs]
        if not any(present):
            return None
        if not all(present):
            missing = cs[present.index(False)]
            raise DataError(
                path,
                f"optional '{role}' columns must be given for every joint",
                column=missing,
                fix=f"add it, or drop all {role.replace('_', '_*_')} columns",
            )
        return np.stack([num(c) for c in cs], axis=1)

    trusted = None
    if any(c in names for c in cols["trusted"]):
        if not all(c in names for c in cols["trusted"]):
            missing = next(c for c in cols["trusted"] if c not in names)
            raise DataError(
                path,
                "trusted flags must be given for every joint",
                column=missing,
                fix="add it, or drop all trusted_* columns",
            )
        trusted = np.stack([flag(c) for c in cols["trusted"]], axis=1)

    ep = Episode(
        spec=file_spec,
        time=num("time"),
        u=np.stack([num(c) for c in cols["u"]], axis=1),
        theta=np.stack([num(c) for c in cols["theta"]], axis=1),
        omega=np.stack([num(c) for c in cols["omega"]], axis=1),
        theta_true=stack("theta_true"),
        omega_true=stack("omega_true"),
        trusted=trusted,
        source=str(meta.get("source", "unknown")),
        condition=str(meta.get("condition", "default")),
        seed=meta.get("seed"),
        generator=dict(meta.get("generator") or {}),
        extra=dict(meta.get("extra") or {}),
        name=str(meta.get("name", path.stem)),
    )
    if validate:
        validate_episode(ep, where=path, min_steps=min_steps)
    return ep


def validate_episode(ep: Episode, *, where: str | Path | None = None, min_steps: int = 1) -> None:
    """Check an in-memory episode against the contract.

    Checks: shapes, finite values, strictly increasing time at ``spec.rate_hz`` (within
    :data:`RATE_RTOL`), commands within each joint's range, ``n_step >= min_steps`` and
    plausible angles and velocities (:func:`check_plausible`).

    Raises:
        DataError: naming ``where``, the column and the first offending row.
    """
    spec = ep.spec
    n = ep.time.shape[0] if ep.time.ndim == 1 else -1
    if ep.time.ndim != 1:
        raise DataError(
            where,
            f"time must be 1-D, got shape {ep.time.shape}",
            column="time",
            fix="give one timestamp per sample",
        )
    cols = columns_for(spec)
    for role in ("u", "theta", "omega", "theta_true", "omega_true", "trusted"):
        arr = getattr(ep, role)
        if arr is None:
            continue
        width, per = (spec.n_u, "command") if role == "u" else (spec.n_joint, "joint")
        if arr.shape != (n, width):
            raise DataError(
                where,
                f"'{role}' has shape {arr.shape}, expected ({n}, {width})",
                column=cols[role][0],
                fix=f"give one row per sample and one column per {per} of the spec",
            )
    if n < min_steps:
        raise DataError(
            where,
            f"episode has {n} samples, fewer than the {min_steps} required by the model window",
            fix="drop it, join it with its neighbours, or use a smaller window",
        )
    for role in ("u", "theta", "omega", "theta_true", "omega_true"):
        arr = getattr(ep, role)
        if arr is None:
            continue
        bad = ~np.isfinite(arr)
        if bad.any():
            row, k = (int(x) for x in np.argwhere(bad)[0])
            raise DataError(
                where,
                f"non-finite value {float(arr[row, k])!r}",
                column=cols[role][k],
                row=row,
                fix="fill or drop the gap ('exsur import --nan fill' can fill short gaps)",
            )
    bad_t = ~np.isfinite(ep.time)
    if bad_t.any():
        raise DataError(
            where,
            "non-finite time",
            column="time",
            row=int(np.flatnonzero(bad_t)[0]),
            fix="drop rows with missing timestamps",
        )
    if n >= 2:
        dts = np.diff(ep.time)
        nonmono = dts <= 0
        if nonmono.any():
            row = int(np.flatnonzero(nonmono)[0]) + 1
            raise DataError(
                where,
                f"time is not strictly increasing ({float(ep.time[row - 1]):.12g} -> {float(ep.time[row]):.12g})",
                column="time",
                row=row,
                fix="sort by time and drop duplicate timestamps",
            )
        off = np.abs(dts - spec.dt) > RATE_RTOL * spec.dt
        if off.any():
            row = int(np.flatnonzero(off)[0]) + 1
            raise DataError(
                where,
                f"time step {dts[row - 1]:.6g} s differs from 1/rate_hz = {spec.dt:.6g} s",
                column="time",
                row=row,
                fix="resample to the declared rate with 'exsur import --rate'",
            )
    for k, j in enumerate(spec.u_specs):
        col = ep.u[:, k]
        out = (col < j.u_min - 1e-9) | (col > j.u_max + 1e-9)
        if out.any():
            row = int(np.flatnonzero(out)[0])
            raise DataError(
                where,
                f"command {col[row]:.6g} outside [{j.u_min:g}, {j.u_max:g}]",
                column=cols["u"][k],
                row=row,
                fix="clip commands to the range or fix the command scale in the import mapping",
            )
    roles = ("theta", "theta_true", "omega", "omega_true")
    check_plausible(spec, {r: getattr(ep, r) for r in roles}, cols, where=where)
