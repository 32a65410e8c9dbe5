"""Equivalence check: the same command sequence through ``ExcavatorMujoco-v0`` and
``ExcavatorSurrogate-v0``, scored with the CBE metrics (paper Sec. V-A).

Both environments start at rest at the same pose and receive identical commands
``u[0..n_step-2]`` (``u[k]`` acts during ``[t_k, t_{k+1})``; the last command is never
applied, as in the datasets).  Sample 0 is the shared start and is excluded from the
metrics; every later sample counts (the surrogate's warm-up is the at-rest fill, not data).
The MuJoCo trajectory is the reference.

Command sources (:func:`load_commands`):

- a CSV file with a header and one ``u_<joint>`` column per joint (extra columns ignored;
  ``theta_<joint>`` columns, if complete, give the start pose from their first row);
- an episode Parquet file (its ``u`` and its first ``theta`` as the start pose);
- a named excitation ``KIND[:key=value,...]`` from :mod:`excavator_surrogate.simulate.excitation`
  (``steps``, ``multisine``, ``chirp``, ``prbs``, ``work_cycle``), keys ``seed`` (default 0),
  ``n_step`` or ``seconds`` (default 90 s, the paper's test length), e.g. ``steps:seed=1``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..config import dumps_toml
from ..errors import ConfigError, DataError
from ..io_utils import atomic_files, write_json, write_text
from ..spec import MachineSpec
from ..surrogate.model import Surrogate
from .base import ExcavatorEnv
from .plants import checkpoint_plant
from .safety import GuardConfig
from .starts import check_theta0

DEFAULT_SECONDS = 90.0
MAX_SECONDS = 24 * 3600.0
"""Longest named excitation [s] (a day of machine time): longer is a typo (``seconds=1e9``
asked for 596 GiB of commands)."""
"""Length of named excitations unless given (the paper's 1800-step test)."""

_NAMED = re.compile(r"^([a-z_]+)(?::(.*))?$")


@dataclass
class Commands:
    """A command sequence to replay: ``u`` (n_step, n_joint) [command units] and an optional
    start pose ``theta0`` (n_joint,) [rad]."""

    u: np.ndarray
    theta0: np.ndarray | None
    name: str


@dataclass
class CompareResult:
    """Trajectories of both environments (sample 0 = the shared start) and the CBE metrics."""

    time: np.ndarray
    """(n_step,) [s]."""
    u: np.ndarray
    """(n_step, n_joint) commands."""
    theta_ref: np.ndarray
    """(n_step, n_joint) MuJoCo angles [rad], unwrapped."""
    omega_ref: np.ndarray
    """(n_step, n_joint) MuJoCo mean velocities [rad/s]."""
    theta_hat: np.ndarray
    """(n_step, n_joint) surrogate angles [rad], unwrapped (NaN after a divergence)."""
    omega_hat: np.ndarray
    """(n_step, n_joint) surrogate velocities [rad/s]."""
    metrics: dict[str, Any]
    """``{"omega": {joint: {rmse, mae, r2}}, "theta": {...}, "run": {...}}``."""
    warmup: int = 1
    names: tuple[str, ...] = field(default_factory=tuple)


def _named_excitation(
    text: str, spec: MachineSpec, theta0: np.ndarray, omega_max: np.ndarray | None
) -> Commands:
    from ..simulate.excitation import SIGNALS, generate

    m = _NAMED.match(text)
    if m is None or m.group(1) not in SIGNALS:
        raise ConfigError(
            f"commands '{text}': not a file and not a named excitation; give a .csv / .parquet file "
            f"or KIND[:seed=N,seconds=S] with KIND one of {', '.join(SIGNALS)}"
        )
    kind, opts = m.group(1), m.group(2) or ""
    kv: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in opts.split(","))):
        if "=" not in part:
            raise ConfigError(
                f"commands '{text}': option '{part}' must be key=value (seed, n_step, seconds)"
            )
        k, v = (s.strip() for s in part.split("=", 1))
        kv[k] = v
    unknown = sorted(set(kv) - {"seed", "n_step", "seconds"})
    if unknown:
        raise ConfigError(
            f"commands '{text}': unknown option(s) {unknown}; use seed, n_step or seconds"
        )

    def number(key: str, kind: type, default: float) -> float:
        try:
            v = kind(kv.get(key, default))
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise ConfigError(f"commands '{text}': {key} must be {what}, got '{kv[key]}'") from None
        if not math.isfinite(v):
            raise ConfigError(f"commands '{text}': {key} must be a finite number, got {v}")
        return v

    seed = int(number("seed", int, 0))
    if "n_step" in kv:
        n_step = int(number("n_step", int, 0))
    else:
        n_step = round(number("seconds", float, DEFAULT_SECONDS) * spec.rate_hz) + 1
    if seed < 0:
        raise ConfigError(f"commands '{text}': seed must be >= 0, got {seed}")
    which = f"n_step={n_step}" if "n_step" in kv else f"seconds={kv.get('seconds')}"
    if n_step < 2:
        raise ConfigError(
            f"commands '{text}': need at least 2 samples ({2 / spec.rate_hz:g} s), got {which}"
        )
    if n_step > MAX_SECONDS * spec.rate_hz + 1:
        raise ConfigError(
            f"commands '{text}': {which} is more than a day of machine time (at most "
            f"seconds={MAX_SECONDS:g}, n_step={round(MAX_SECONDS * spec.rate_hz) + 1}); "
            "give a shorter run"
        )
    u = generate(kind, seed, n_step, spec, theta0=theta0, omega_max=omega_max)
    return Commands(u=np.asarray(u, dtype=np.float64), theta0=theta0, name=text.replace(":", "_"))


def _read_csv(path: Path, spec: MachineSpec) -> Commands:
    import pyarrow.csv as pcsv

    try:
        table = pcsv.read_csv(path)
    except Exception as e:
        raise DataError(
            path,
            f"cannot read CSV ({type(e).__name__}: {str(e).splitlines()[0][:120]})",
            fix="give a CSV with a header row and one u_<joint> column per joint",
        ) from e
    names = table.column_names

    def col(c: str) -> np.ndarray:
        from ..ingest.columns import numeric_column  # names the first cell that is not a number

        try:
            return numeric_column(path, table.column(c), c)
        except DataError as e:  # the import's advice (--nan, [csv]) is not this file's
            raise DataError(
                path, e.problem, column=e.column, row=e.row, fix="store numbers only"
            ) from None

    cols_u = [f"u_{j}" for j in spec.names]
    for c in cols_u:
        if c not in names:
            other = next((d for d in ";\t|" if any(d in n for n in names)), None)
            split = f"; its header is split by {other!r}: separate the fields by ','"
            raise DataError(
                path,
                "required column is missing",
                column=c,
                fix=f"the commands CSV needs columns {cols_u}" + (split if other else ""),
            )
    u = np.stack([col(c) for c in cols_u], axis=1)
    cols_th = [f"theta_{j}" for j in spec.names]
    theta0 = (
        np.array([col(c)[0] for c in cols_th])
        if all(c in names for c in cols_th) and len(u)
        else None
    )
    return Commands(u=u, theta0=theta0, name=path.stem)


def load_commands(
    source: str | Path,
    spec: MachineSpec,
    *,
    theta0: np.ndarray | None = None,
    omega_max: np.ndarray | None = None,
) -> Commands:
    """Read or generate a command sequence for ``spec`` (see the module docstring).

    Raises:
        DataError: unreadable file, missing column, non-finite or out-of-range command (one
            line naming the file, column and row).
        ConfigError: unknown excitation name or option.
    """
    path = Path(str(source))
    if path.is_file():
        if path.suffix.lower() == ".csv":
            cmds = _read_csv(path, spec)
        elif path.suffix.lower() in (".parquet", ".pq"):
            from ..data.episode import read_episode

            ep = read_episode(path, spec=spec)
            cmds = Commands(u=ep.u, theta0=ep.theta[0].copy(), name=ep.name)
        else:
            raise DataError(
                path,
                f"unsupported file type '{path.suffix}'",
                fix="give a .csv with u_<joint> columns or an episode .parquet",
            )
    elif path.suffix.lower() in (".csv", ".parquet", ".pq") or "/" in str(source):
        raise DataError(path, "file not found", fix="check the path")
    else:
        start = theta0 if theta0 is not None else _mid_pose(spec)
        cmds = _named_excitation(str(source), spec, start, omega_max)
    _validate(cmds.u, spec, where=path if path.is_file() else None)
    if theta0 is not None:
        cmds.theta0 = np.asarray(theta0, dtype=np.float64)
    return cmds


def _mid_pose(spec: MachineSpec) -> np.ndarray:
    out = np.zeros(spec.n_joint)
    for k, j in enumerate(spec.joints):
        if j.theta_min is not None and j.theta_max is not None:
            out[k] = 0.5 * (j.theta_min + j.theta_max)
    return out


def _validate(u: np.ndarray, spec: MachineSpec, *, where: Path | None) -> None:
    cols = [f"u_{j}" for j in spec.u_names]
    if u.ndim != 2 or u.shape[1] != spec.n_u or u.shape[0] < 2:
        raise DataError(where, f"commands have shape {u.shape}, need (n_step >= 2, {spec.n_u})")
    bad = ~np.isfinite(u)
    if bad.any():
        row, k = (int(x) for x in np.argwhere(bad)[0])
        raise DataError(
            where,
            f"non-finite command {float(u[row, k])}",
            column=cols[k],
            row=row,
            fix="fill or drop the gap",
        )
    for k, j in enumerate(spec.u_specs):
        out = (u[:, k] < j.u_min - 1e-9) | (u[:, k] > j.u_max + 1e-9)
        if out.any():
            row = int(np.flatnonzero(out)[0])
            raise DataError(
                where,
                f"command {u[row, k]:.6g} outside [{j.u_min:g}, {j.u_max:g}]",
                column=cols[k],
                row=row,
                fix="clip the commands to the joint's range",
            )


def run_commands(
    env: ExcavatorEnv, u: np.ndarray, theta0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Drive ``env`` from rest at ``theta0`` with ``u[0..n_step-2]``.

    Returns:
        ``theta`` and ``omega`` (n_step, n_joint) float64, unwrapped, sample 0 = start; and
        the first sample index at which the env truncated on a NaN state (rows from there on
        are NaN), else None.
    """
    n_step, n_joint = u.shape[0], env.machine.n_joint
    theta = np.full((n_step, n_joint), np.nan)
    omega = np.full((n_step, n_joint), np.nan)
    env.reset(options={"theta0": theta0})
    theta[0], omega[0] = env.theta, env.omega
    for k in range(n_step - 1):
        _, _, _, _, info = env.step(u[k])
        if info["guard"] == "nan":
            return theta, omega, k + 1
        theta[k + 1], omega[k + 1] = env.theta, env.omega
    return theta, omega, None


def compare(
    ckpt: str | Path | Surrogate,
    commands: str | Path | Commands,
    *,
    theta0: np.ndarray | None = None,
    out: str | Path | None = None,
    plant: str | None = None,
    device: str = "cpu",
    mode: str | None = None,
) -> CompareResult:
    """Replay ``commands`` through both environments and score the surrogate against MuJoCo.

    Args:
        ckpt: checkpoint path or loaded surrogate.
        commands: a source for :func:`load_commands` or a :class:`Commands`.
        theta0: start pose (n_joint,) [rad]; default: the source's, else mid-range.
        out: if given, write ``metrics.json``, ``table.md``, ``compare.png`` and
            ``trajectories.npz`` into this folder.
        plant: ``ideal`` or ``hydraulic`` MuJoCo plant; default: the one the checkpoint was
            trained on (``ideal`` if it does not record it).  Another machine or plant than
            the checkpoint's raises :class:`~excavator_surrogate.errors.CheckpointError`
            (:func:`~.plants.checkpoint_plant`).
        device: torch device of the surrogate.
        mode: surrogate rollout mode (default: the checkpoint's).

    Returns:
        The trajectories and metrics.
    """
    from ..evaluate.metrics import cbe_metrics
    from .mujoco_env import ExcavatorMujocoEnv
    from .surrogate_env import ExcavatorSurrogateEnv

    no_guard = GuardConfig(limit_margin=None, omega_max=None)  # only NaN stops the replay
    sur_env = ExcavatorSurrogateEnv(
        ckpt,
        device=device,
        mode=mode,
        guard=no_guard,  # type: ignore[arg-type]
        action_mode="reject",
    )
    spec = sur_env.machine
    label = ckpt if not isinstance(ckpt, Surrogate) else f"surrogate '{sur_env.surrogate.name}'"
    plant = checkpoint_plant(spec, plant, ckpt=label, default="ideal")
    mj_env = ExcavatorMujocoEnv(plant=plant, spec=spec, guard=no_guard, action_mode="reject")  # type: ignore[arg-type]
    if theta0 is not None:  # before a named excitation is generated from it
        theta0 = check_theta0(spec, np.asarray(theta0).tolist(), where="compare --theta0")
    source = commands.name if isinstance(commands, Commands) else str(commands)
    if not isinstance(commands, Commands):
        commands = load_commands(commands, spec, theta0=theta0, omega_max=mj_env.plant.omega_max)
    start = theta0 if theta0 is not None else commands.theta0
    start = _mid_pose(spec) if start is None else start
    start = check_theta0(spec, start, where="compare")
    u = commands.u
    th_ref, om_ref, _ = run_commands(mj_env, u, start)
    th_hat, om_hat, diverged = run_commands(sur_env, u, start)
    mj_env.close()

    run = SimpleNamespace(
        theta_hat=th_hat, omega_hat=om_hat, theta_ref=th_ref, omega_ref=om_ref, warmup=1
    )
    metrics = cbe_metrics([run], spec)
    sur = sur_env.surrogate
    metrics["run"] = {
        "checkpoint": str(ckpt) if not isinstance(ckpt, Surrogate) else sur.name,
        "commands": commands.name,
        "source": source,
        "plant": plant,
        "device": str(device),
        "reference": f"ExcavatorMujoco-v0 (plant={plant})",
        "mode": sur_env.engine.mode,
        "n_step": int(u.shape[0]),
        "n_step_scored": int(u.shape[0] - 1),
        "dt": spec.dt,
        "theta0": start.tolist(),
        "diverged_at": diverged,
    }
    result = CompareResult(
        time=np.arange(u.shape[0]) * spec.dt,
        u=u,
        theta_ref=th_ref,
        omega_ref=om_ref,
        theta_hat=th_hat,
        omega_hat=om_hat,
        metrics=metrics,
        names=spec.names,
    )
    if out is not None:
        write_outputs(result, out)
    return result


def write_outputs(result: CompareResult, out: str | Path) -> Path:
    """Write ``metrics.json``, ``table.md``, ``compare.png``, ``trajectories.npz`` and the
    ``config.toml`` record (``[command]``: the checkpoint, the commands' source, the start,
    the plant, the mode and the device that repeat the replay) to ``out``."""
    from ..evaluate.report import markdown_table
    from ..plotting.cbe import plot_cbe

    out = Path(out)
    with atomic_files(out, kind="compare") as tmp:  # all files or none
        run = result.metrics["run"]
        write_json(tmp / "metrics.json", result.metrics)
        keys = ("checkpoint", "source", "theta0", "plant", "mode", "device")
        command = {"name": "compare", **{k: run[k] for k in keys if run.get(k) is not None}}
        write_text(tmp / "config.toml", dumps_toml({"command": command}))
        lines = [
            "# Equivalence check: ExcavatorSurrogate-v0 vs ExcavatorMujoco-v0",
            "",
            *(f"- {k}: {v}" for k, v in run.items()),
            "",
            "Closed-loop behavioural equivalence, MuJoCo as reference (paper Table II layout):",
            "",
            markdown_table({k: result.metrics[k] for k in ("omega", "theta")}),
        ]
        write_text(tmp / "table.md", "\n".join(lines))
        r2 = {
            key: [result.metrics[key][n]["r2"] for n in result.names] for key in ("omega", "theta")
        }
        plot_cbe(
            tmp / "compare.png",
            time=result.time,
            omega_ref=result.omega_ref,
            theta_ref=result.theta_ref,
            predictions={"surrogate": (result.omega_hat, result.theta_hat)},
            names=result.names,
            warmup=0,
            title=f"{run['commands']}: ExcavatorSurrogate-v0 vs ExcavatorMujoco-v0 (same commands)",
            ref_label="MuJoCo",
            scores={"surrogate": (r2["omega"], r2["theta"])},
        )
        np.savez_compressed(
            tmp / "trajectories.npz",
            time=result.time,
            u=result.u,
            theta_mujoco=result.theta_ref,
            omega_mujoco=result.omega_ref,
            theta_surrogate=result.theta_hat,
            omega_surrogate=result.omega_hat,
        )
    return out
