"""Cleaning episodes and datasets, and scoring the result against ground truth."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..config import to_dict
from ..data.dataset import SPLITS, load_dataset, write_dataset
from ..data.episode import Episode
from ..data.jumps import jump_mask_of
from ..data.plausible import velocity_scale
from ..errors import ConfigError, DataError
from .config import CleanConfig
from .kalman import backward_difference, fuse

_log = logging.getLogger(__name__)

_BATCH_FILL = 0.8
"""Episodes are batched with others at least this fraction of the batch's longest one."""


def _unwrapped_theta(ep: Episode, config: CleanConfig) -> np.ndarray:
    theta = np.array(ep.theta, dtype=np.float64)
    if config.unwrap_periodic:
        for k, periodic in enumerate(ep.spec.periodic):
            if periodic:
                theta[:, k] = np.unwrap(theta[:, k])
    return theta


def clean_episodes(
    episodes: Sequence[Episode],
    *,
    config: CleanConfig | None = None,
    sources: Sequence[str | Path] | None = None,
) -> list[Episode]:
    """Clean many episodes, vectorised over episodes of similar length.

    Episodes are grouped by sample rate and joint count, sorted by length, and batched
    (padded to the longest in the batch); results are identical to cleaning one by one.

    Args:
        episodes: episodes with measured ``theta`` and gyro ``omega``.
        config: filter parameters (default :class:`CleanConfig`).
        sources: the file each episode was read from, named in errors (default: its name).

    Returns:
        The cleaned episodes in input order (see :func:`clean_episode`).

    Raises:
        DataError: an episode whose gyro disagrees with its angle by a unit (deg/s in a
            rad/s column) or a sign: the filter would fuse them into nonsense.
    """
    cfg = config or CleanConfig()
    thetas = [_unwrapped_theta(ep, cfg) for ep in episodes]
    for i, ep in enumerate(episodes):
        _check_gyro_scale(ep, thetas[i], ep.name if sources is None else sources[i])
    out: list[Episode | None] = [None] * len(episodes)
    groups: dict[tuple[float, int], list[int]] = {}
    for i, ep in enumerate(episodes):
        groups.setdefault((ep.spec.dt, ep.spec.n_joint), []).append(i)
    for (dt, n_joint), idx in groups.items():
        idx = sorted(idx, key=lambda i: -episodes[i].n_step)
        start = 0
        while start < len(idx):
            longest = episodes[idx[start]].n_step
            stop = start + 1
            while stop < len(idx) and episodes[idx[stop]].n_step >= _BATCH_FILL * longest:
                stop += 1
            batch = idx[start:stop]
            nv = np.array([episodes[i].n_step for i in batch])
            theta = np.zeros((len(batch), longest, n_joint))
            omega = np.zeros((len(batch), longest, n_joint))
            # a linear joint is filtered in units of linear_m_per_rad, so the thresholds
            # written in rad apply to it as that many m per rad: x_filter = x / scale
            scale = np.ones((len(batch), 1, n_joint))
            for b, i in enumerate(batch):
                n = nv[b]
                scale[b, 0] = _filter_scale(episodes[i], cfg)
                theta[b, :n] = thetas[i]
                _warn_if_no_gyro(episodes[i], theta[b, :n], cfg)
                omega[b, :n] = episodes[i].omega
                theta[b, n:] = theta[b, n - 1]
            res = fuse(theta / scale, omega / scale, dt=dt, config=cfg, n_valid=nv)
            for b, i in enumerate(batch):
                n = nv[b]
                out[i] = _finish(
                    episodes[i],
                    theta_raw=theta[b, :n],
                    theta_hat=res.theta[b, :n] * scale[b],
                    trusted=res.trusted[b, :n],
                    bias=None if res.bias is None else res.bias[b, :n] * scale[b],
                    config=cfg,
                )
            start = stop
    return [ep for ep in out if ep is not None]


def _filter_scale(ep: Episode, config: CleanConfig) -> np.ndarray:
    """Per joint, the size of the filter's unit: ``linear_m_per_rad`` [m] for a linear joint,
    1 for a revolute one [rad].  Shape ``(n_joint,)``."""
    return np.array([config.linear_m_per_rad if j.linear else 1.0 for j in ep.spec.joints])


UNTRUSTED_WARN = 0.2
"""``exsur clean`` warns when it distrusts more than this share of a joint's angle samples."""
GYRO_CHECK_S = 0.25
"""The gyro's scale is checked on displacements over this interval [s] (less noise than a
sample's difference of the raw angle)."""


def _check_gyro_scale(ep: Episode, theta: np.ndarray, where: str | Path) -> None:
    """Refuse a gyro off by a unit or a sign against its angle
    (:func:`~..data.plausible.velocity_scale` on displacements over :data:`GYRO_CHECK_S`)::

        d_k = (theta[k s] - theta[(k-1) s]) / (s Ts),   m_k = sum of omega over the same s samples / s
    """
    s = max(1, round(GYRO_CHECK_S / ep.dt))
    if ep.n_step <= s:
        return
    # integrated gyro G_t = Ts * sum_{i<=t} omega_i (omega_i: the mean rate over (t_{i-1}, t_i])
    g = np.cumsum(ep.omega, axis=0) * ep.dt
    for k, joint in enumerate(ep.spec.joints):
        found = velocity_scale(
            np.diff(g[::s, k]) / (s * ep.dt),
            np.diff(theta[::s, k]) / (s * ep.dt),
            linear=joint.linear,
        )
        if found is None:
            continue
        kind, ratio = found
        unit = "m/s" if joint.linear else "rad/s"
        problem = (
            "has the opposite sign of the angle's rate of change"
            if kind == "sign"
            else f"is {ratio:.3g}x the {'stroke' if joint.linear else 'angle'}'s rate of change"
            + (f" (looks like {kind})" if kind != "length" else " (a length unit off)")
        )
        raise DataError(
            where,
            f"joint '{joint.name}': the gyro {problem}; cleaning would fuse them into nonsense",
            column=f"omega_{joint.name}",
            fix=f"the episode's omega must be in {unit} with the angle's sign: re-import the log "
            "with the velocity's unit and scale set in the mapping",
        )


def _warn_if_no_gyro(ep: Episode, theta: np.ndarray, config: CleanConfig) -> None:
    """Log a warning when ``omega`` is just the backward difference of ``theta`` (no gyro)."""
    if config.method == "paper" or ep.n_step < 3:
        return
    derived = [
        name
        for k, name in enumerate(ep.spec.names)
        if np.allclose(ep.omega[1:, k], np.diff(theta[:, k]) / ep.dt, rtol=1e-6, atol=1e-9)
    ]
    if derived:
        _log.warning(
            f"clean: episode '{ep.name}': omega of {derived} is the backward difference of theta "
            f"(no gyro?); method '{config.method}' cannot detect jumps there, use method='paper' "
            "with tau_cons=inf"
        )


def clean_episode(ep: Episode, *, config: CleanConfig | None = None) -> Episode:
    """Replace an episode's measured angles/velocities with the fused, consistent ones.

    The result has ``theta`` = fused angle (periodic joints unwrapped if
    ``config.unwrap_periodic``), ``omega`` = its backward difference (paper eq.), ``trusted``
    = the consistency flags ``c_t``, the ``_true`` columns unchanged, and cleaning
    statistics in ``extra["cleaning"]`` (method, config, per-joint untrusted fraction, RMS of
    fused minus raw angle [rad], mean estimated gyro bias [rad/s] if any).

    Args:
        ep: episode with measured ``theta`` [rad] and gyro ``omega`` [rad/s].
        config: filter parameters (default :class:`CleanConfig`).
    """
    return clean_episodes([ep], config=config)[0]


def _finish(
    ep: Episode,
    *,
    theta_raw: np.ndarray,
    theta_hat: np.ndarray,
    trusted: np.ndarray,
    bias: np.ndarray | None,
    config: CleanConfig,
) -> Episode:
    omega_hat = backward_difference(theta_hat, ep.spec.dt)
    stats: dict[str, Any] = {
        "method": config.method,
        "config": to_dict(config),
        "untrusted_frac": [round(float(x), 6) for x in (~trusted).mean(axis=0)],
        "rms_fused_minus_raw": [
            round(float(x), 6) for x in np.sqrt(np.mean((theta_hat - theta_raw) ** 2, axis=0))
        ],
    }
    if bias is not None:
        stats["gyro_bias_mean"] = [round(float(x), 6) for x in bias.mean(axis=0)]
    extra = dict(ep.extra)
    extra["cleaning"] = stats
    return ep.replace(
        theta=np.ascontiguousarray(theta_hat),
        omega=omega_hat,
        trusted=np.ascontiguousarray(trusted, dtype=bool),
        extra=extra,
    )


def _angle_error(a: np.ndarray, b: np.ndarray, periodic: Sequence[bool]) -> np.ndarray:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    for k, p in enumerate(periodic):
        if p:
            d[:, k] = (d[:, k] + math.pi) % (2.0 * math.pi) - math.pi
    return d


def _sums(raw: Episode, cleaned: Episode) -> dict[str, np.ndarray]:
    """Per-joint sums that pool across episodes."""
    if raw.spec.names != cleaned.spec.names or raw.n_step != cleaned.n_step:
        raise DataError(
            None,
            f"raw episode '{raw.name}' ({raw.n_step} samples, joints {list(raw.spec.names)}) does not "
            f"match cleaned '{cleaned.name}' ({cleaned.n_step} samples, joints {list(cleaned.spec.names)})",
            fix="pass the episode and its own cleaned version",
        )
    periodic = raw.spec.periodic
    n_joint = raw.spec.n_joint
    s: dict[str, np.ndarray] = {
        "n": np.full(n_joint, float(raw.n_step)),
        "sq_fused_raw": np.sum(_angle_error(cleaned.theta, raw.theta, periodic) ** 2, axis=0),
    }
    flagged = ~cleaned.trusted if cleaned.trusted is not None else np.zeros(raw.theta.shape, bool)
    s["flagged"] = flagged.sum(axis=0).astype(float)
    truth = raw.theta_true if raw.theta_true is not None else cleaned.theta_true
    if truth is not None:
        s["sq_raw"] = np.sum(_angle_error(raw.theta, truth, periodic) ** 2, axis=0)
        s["sq_fused"] = np.sum(_angle_error(cleaned.theta, truth, periodic) ** 2, axis=0)
    om_true = raw.omega_true if raw.omega_true is not None else cleaned.omega_true
    if om_true is not None:
        s["sq_om_raw"] = np.sum((raw.omega - om_true) ** 2, axis=0)
        s["sq_om_fused"] = np.sum((cleaned.omega - om_true) ** 2, axis=0)
    mask = jump_mask_of(raw)
    if mask is None:
        mask = jump_mask_of(cleaned)
    if mask is not None:
        s["tp"] = (flagged & mask).sum(axis=0).astype(float)
        s["pos"] = mask.sum(axis=0).astype(float)
    return s


def _ratio(num: float, den: float) -> float | None:
    return None if den == 0 else float(num / den)


def _metrics_from_sums(s: dict[str, np.ndarray], names: Sequence[str]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for k, name in enumerate(names):
        n = s["n"][k]
        m: dict[str, Any] = {
            "rmse_raw": None,
            "rmse_fused": None,
            "jump_precision": None,
            "jump_recall": None,
        }
        if "sq_raw" in s:
            m["rmse_raw"] = float(np.sqrt(s["sq_raw"][k] / n))
            m["rmse_fused"] = float(np.sqrt(s["sq_fused"][k] / n))
            m["rmse_ratio"] = _ratio(m["rmse_fused"], m["rmse_raw"])
        if "sq_om_raw" in s:
            m["rmse_omega_raw"] = float(np.sqrt(s["sq_om_raw"][k] / n))
            m["rmse_omega_fused"] = float(np.sqrt(s["sq_om_fused"][k] / n))
        if "tp" in s:
            m["jump_precision"] = _ratio(s["tp"][k], s["flagged"][k])
            m["jump_recall"] = _ratio(s["tp"][k], s["pos"][k])
        m["rms_fused_minus_raw"] = float(np.sqrt(s["sq_fused_raw"][k] / n))
        m["untrusted_frac"] = float(s["flagged"][k] / n)
        out[name] = m
    return out


def cleaning_metrics(raw: Episode, cleaned: Episode) -> dict[str, dict[str, Any]]:
    """Score a cleaned episode against ground truth, per joint.

    Args:
        raw: the measured episode (with ``theta_true``/``omega_true`` and, from
            :func:`~excavator_surrogate.simulate.sensors.apply_sensors_episode`, the jump
            mask in ``extra["sensor"]["jump_runs"]``).
        cleaned: ``clean_episode(raw)``.

    Returns:
        ``{joint: {"rmse_raw", "rmse_fused", "rmse_ratio", "jump_precision", "jump_recall",
        "rmse_omega_raw", "rmse_omega_fused", "rms_fused_minus_raw", "untrusted_frac"}}``;
        angles in rad, velocities in rad/s.  Truth-based values are None (or absent) when the
        truth or the jump mask is missing; precision is None when nothing was flagged.
        Periodic joints' angle errors are wrapped to [-pi, pi).
    """
    return _metrics_from_sums(_sums(raw, cleaned), raw.spec.names)


def pooled_cleaning_metrics(pairs: Iterable[tuple[Episode, Episode]]) -> dict[str, dict[str, Any]]:
    """:func:`cleaning_metrics` pooled over many ``(raw, cleaned)`` pairs (sample-weighted)."""
    total: dict[str, np.ndarray] | None = None
    names: Sequence[str] = ()
    for raw, cleaned in pairs:
        s = _sums(raw, cleaned)
        names = raw.spec.names
        if total is None:
            total = s
        else:
            keys = set(total) & set(s)
            total = {k: total[k] + s[k] for k in keys}
    if total is None:
        return {}
    return _metrics_from_sums(total, names)


def _relative_source(src: Path, out: Path) -> str:
    """``src`` as recorded in ``out``'s manifest: ``"../<name>"`` for a sibling folder, else absolute."""
    s, o = src.resolve(), out.resolve()
    return f"../{s.name}" if s.parent == o.parent else str(s)


def clean_dataset(src: str | Path, out: str | Path, *, config: CleanConfig | None = None) -> Path:
    """Clean every episode of dataset ``src`` into a new dataset folder ``out``.

    Splits, names and the manifest layout are kept (written atomically by
    :func:`~excavator_surrogate.data.write_dataset`); the manifest records the cleaning
    config, the source folder and the pooled per-joint statistics under ``cleaning``.

    Raises:
        ConfigError: if ``out`` is ``src``.
        DataError: if ``src`` is not a valid dataset.
    """
    cfg = config or CleanConfig()
    src, out = Path(src), Path(out)
    if out.resolve() == src.resolve():
        raise ConfigError(f"{out}: the output folder is the input dataset; choose another --out")
    ds = load_dataset(src)
    items = [(ep, split) for split in SPLITS for ep in ds.split(split)]
    _log.info(f"clean: {len(items)} episodes, {ds.n_samples()} samples, method {cfg.method}")
    files = [f or ep.name for split in SPLITS for ep, f in zip(ds.split(split), ds.paths(split))]
    cleaned = clean_episodes([ep for ep, _ in items], config=cfg, sources=files)
    summary = pooled_cleaning_metrics((ep, c) for (ep, _), c in zip(items, cleaned))
    doubted = {
        j: m["untrusted_frac"] for j, m in summary.items() if m["untrusted_frac"] > UNTRUSTED_WARN
    }
    if doubted:
        _log.warning(
            "clean: the filter distrusted "
            + ", ".join(f"{j}'s angle in {f:.0%}" for j, f in doubted.items())
            + " of the samples: the angle and the gyro disagree there (a gyro fault or drift, "
            "a wrong unit or scale?); see --plot's figures before training on it"
        )
    path = write_dataset(
        out,
        [(c, split) for c, (_, split) in zip(cleaned, items)],
        config={"clean": to_dict(cfg)},
        extra={
            # relative to this dataset folder when both sit in one folder ("../data"), so a
            # run folder can be renamed into place; otherwise absolute
            "cleaned_from": _relative_source(src, out),
            "source_config": ds.manifest.get("config", {}),
            "cleaning": summary,
        },
    )
    _log.info(f"clean: wrote {path}")
    return path
