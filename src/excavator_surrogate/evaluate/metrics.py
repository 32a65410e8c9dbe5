"""Closed-loop behavioural-equivalence (CBE) metrics: RMSE, MAE, R^2 per joint for omega and theta.

Samples of every episode's warm-up (the first ``W`` recorded samples that start the rollout)
are excluded; the remaining samples of all episodes are pooled.  Angles of periodic joints are
compared unwrapped, on the branch the free run starts from, each episode on the turn nearest
the others' (:mod:`..surrogate.scores`, which training's validation shares).  ``R^2 = 1 -
SS_res / SS_tot`` about the pooled reference's mean; it is ``None`` in JSON when the reference
is constant in every episode (up to rounding, :data:`CONSTANT`): a joint that never moves has
no variance to explain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..spec import MachineSpec
from ..surrogate.scores import CONSTANT as CONSTANT  # re-exported: the CBE report's rule
from ..surrogate.scores import RunLike, run_angles, scored_angles
from ..surrogate.scores import regression_metrics as regression_metrics


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def cbe_metrics(runs: Sequence[RunLike], spec: MachineSpec) -> dict[str, Any]:
    """CBE metrics pooled over episodes, warm-up excluded.

    Returns:
        ``{"omega": {joint: {"rmse", "mae", "r2"}}, "theta": {...}}`` with plain floats
        (``None`` for undefined values), joints in ``spec`` order.
    """
    if not runs:
        raise ValueError("no rollouts to score")
    om_hat = np.concatenate([r.omega_hat[r.warmup :] for r in runs])
    om_ref = np.concatenate([r.omega_ref[r.warmup :] for r in runs])
    th_hat, th_ref, still = scored_angles(runs, spec)
    out: dict[str, Any] = {}
    for key, pred, ref in (("omega", om_hat, om_ref), ("theta", th_hat, th_ref)):
        m = regression_metrics(pred, ref, still=still)
        out[key] = {
            name: {k: _finite(m[k][j]) for k in ("rmse", "mae", "r2")}
            for j, name in enumerate(spec.names)
        }
    return out


def undefined_r2(metrics: Mapping[str, Any], key: str = "theta") -> list[str]:
    """Joints of ``metrics[key]`` whose R^2 is undefined (constant reference, or a non-finite
    prediction)."""
    return [j for j, v in metrics[key].items() if v.get("r2") is None]


def worst_defined_r2(
    metrics: Mapping[str, Any], key: str = "theta"
) -> tuple[float | None, list[str]]:
    """``(worst, undefined)``: the smallest defined R^2 of ``metrics[key]`` (None when none is
    defined) and the joints whose R^2 is undefined (:func:`undefined_r2`)."""
    bad = undefined_r2(metrics, key)
    vals = [v["r2"] for j, v in metrics[key].items() if j not in bad]
    return (min(vals) if vals else None), bad


def worst_r2_text(metrics: Mapping[str, Any], key: str = "theta") -> str:
    """The worst defined R^2 of ``metrics[key]`` to 4 decimals, with the joints whose R^2 is
    undefined named (``"undefined"`` when none is defined): the run's headline."""
    worst, bad = worst_defined_r2(metrics, key)
    text = f"{worst:.4f}" if worst is not None else "undefined"
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
        pred, ref = run_angles(r, spec)
        err = pred - ref
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
