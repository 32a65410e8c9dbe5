"""Closed-loop behavioural-equivalence (CBE) metrics: RMSE, MAE, R^2 per joint for omega and theta.

Samples of every episode's warm-up (the first ``W`` recorded samples that start the rollout)
are excluded; the remaining samples of all episodes are pooled.  Angles of periodic joints are
compared unwrapped (the rollout integrates continuously).  ``R^2 = 1 - SS_res / SS_tot`` about
the reference's mean; it is ``None`` in JSON when the reference is constant (up to rounding,
:data:`CONSTANT`): a joint that never moves has no variance to explain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from ..spec import MachineSpec
from ..surrogate.angles import unwrap_periodic


class RunLike(Protocol):
    """What :func:`cbe_metrics` needs from a rollout (see :class:`~..surrogate.rollout.EpisodeRollout`)."""

    theta_hat: np.ndarray
    omega_hat: np.ndarray
    theta_ref: np.ndarray
    omega_ref: np.ndarray
    warmup: int


CONSTANT = 1e-9
"""A reference column whose range (max - min) is at most this times ``max(1, max |ref|)`` is
constant: its R^2 is undefined (NaN, ``None`` in JSON), not ``1 - SS_res / rounding noise``."""


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def regression_metrics(pred: np.ndarray, ref: np.ndarray) -> dict[str, np.ndarray]:
    """Per-column RMSE, MAE and R^2.

    Args:
        pred: (n_sample, n_joint) predictions.
        ref: (n_sample, n_joint) reference.

    Returns:
        ``{"rmse", "mae", "r2"}``, each (n_joint,); ``r2`` is NaN where ``ref`` is constant (up
        to rounding: its range is at most :data:`CONSTANT` times its magnitude) and
        every metric is NaN/inf if ``pred`` is not finite.
    """
    pred = np.asarray(pred, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if pred.shape != ref.shape or pred.ndim != 2:
        raise ValueError(f"pred {pred.shape} and ref {ref.shape} must be equal (n_sample, n_joint)")
    err = pred - ref
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        ss_res = np.sum(err**2, axis=0)
        ss_tot = np.sum((ref - ref.mean(axis=0)) ** 2, axis=0)
        # constant up to rounding (range <= CONSTANT x magnitude): SS_tot is rounding noise
        # and 1 - SS_res / SS_tot a meaningless -1e11, so R^2 is undefined (NaN)
        scale = np.maximum(1.0, np.max(np.abs(ref), axis=0, initial=0.0))
        moves = np.ptp(ref, axis=0) > CONSTANT * scale if len(ref) else np.zeros(ref.shape[1], bool)
        ok = moves & (ss_tot > 0)
        r2 = np.where(ok, 1.0 - ss_res / np.where(ok, ss_tot, 1.0), np.nan)
        return {
            "rmse": np.sqrt(np.mean(err**2, axis=0)),
            "mae": np.mean(np.abs(err), axis=0),
            "r2": r2,
        }


def cbe_metrics(runs: Sequence[RunLike], spec: MachineSpec) -> dict[str, Any]:
    """CBE metrics pooled over episodes, warm-up excluded.

    Returns:
        ``{"omega": {joint: {"rmse", "mae", "r2"}}, "theta": {...}}`` with plain floats
        (``None`` for undefined values), joints in ``spec`` order.
    """
    if not runs:
        raise ValueError("no rollouts to score")
    om_hat, om_ref, th_hat, th_ref = [], [], [], []
    for r in runs:
        w = r.warmup
        om_hat.append(r.omega_hat[w:])
        om_ref.append(r.omega_ref[w:])
        th_hat.append(r.theta_hat[w:])
        th_ref.append(unwrap_periodic(r.theta_ref, spec)[w:])
    out: dict[str, Any] = {}
    for key, pred, ref in (
        ("omega", np.concatenate(om_hat), np.concatenate(om_ref)),
        ("theta", np.concatenate(th_hat), np.concatenate(th_ref)),
    ):
        m = regression_metrics(pred, ref)
        out[key] = {
            name: {k: _finite(m[k][j]) for k in ("rmse", "mae", "r2")}
            for j, name in enumerate(spec.names)
        }
    return out


def undefined_r2(metrics: Mapping[str, Any], key: str = "theta") -> list[str]:
    """Joints of ``metrics[key]`` whose R^2 is undefined (constant reference, or a non-finite
    prediction)."""
    return [j for j, v in metrics[key].items() if v.get("r2") is None]


def worst_r2_text(metrics: Mapping[str, Any], key: str = "theta") -> str:
    """The worst defined R^2 of ``metrics[key]`` to 4 decimals, with the joints whose R^2 is
    undefined named (``"undefined"`` when none is defined): the run's headline."""
    bad = undefined_r2(metrics, key)
    vals = [v["r2"] for j, v in metrics[key].items() if j not in bad]
    text = f"{min(vals):.4f}" if vals else "undefined"
    if bad:
        text += f" (undefined for {', '.join(bad)}: constant reference or non-finite prediction)"
    return text


def min_r2(metrics: dict[str, Any], key: str = "theta") -> float:
    """Smallest R^2 over joints of ``metrics[key]`` (``-inf`` if any is undefined)."""
    vals = [v["r2"] for v in metrics[key].values()]
    return min((v if v is not None else -math.inf) for v in vals)


def episode_errors(runs: Sequence[RunLike], spec: MachineSpec) -> list[dict[str, Any]]:
    """Where the angle error is: each episode's own angle RMSE per joint, and its share of
    the joint's squared error pooled over ``runs`` (warm-up excluded, periodic joints
    unwrapped, as :func:`cbe_metrics` scores them)::

        share[e, j] = SSE[e, j] / sum_e SSE[e, j],  SSE[e, j] = sum_k (theta_hat - theta)^2

    The pooled RMSE of joint ``j`` is ``sqrt(sum_e SSE[e, j] / sum_e n_e)`` (``n_e`` scored
    samples of episode ``e``), so its shares sum to 1 and say which episodes hold it.

    Returns:
        One ``{"theta_rmse": {joint: float | None}, "theta_share": {joint: float | None}}``
        per run, in order (``None``: no scored sample, no error at all, or a non-finite one).
    """
    sse, count = [], []
    for r in runs:
        w = r.warmup
        err = r.theta_hat[w:] - unwrap_periodic(r.theta_ref, spec)[w:]
        with np.errstate(invalid="ignore", over="ignore"):
            sse.append(np.sum(np.asarray(err, dtype=np.float64) ** 2, axis=0))
        count.append(len(err))
    sse_a = np.array(sse).reshape(len(runs), spec.n_joint)
    total = sse_a.sum(axis=0)
    out = []
    for e, n in enumerate(count):
        rmse = np.sqrt(sse_a[e] / n) if n else np.full(spec.n_joint, np.nan)
        out.append(
            {
                "theta_rmse": {name: _finite(rmse[j]) for j, name in enumerate(spec.names)},
                "theta_share": {
                    name: (
                        _finite(sse_a[e, j] / total[j])
                        if np.isfinite(total[j]) and total[j] > 0
                        else None
                    )
                    for j, name in enumerate(spec.names)
                },
            }
        )
    return out
