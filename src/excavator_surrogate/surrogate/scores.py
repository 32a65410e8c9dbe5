"""What a free run is scored on, and the scores: RMSE, MAE and R^2 per joint.

Shared by training's validation (:mod:`.validation`, which selects models on it) and the
CBE report (:mod:`..evaluate.metrics`), so the two score the same thing:

- The warm-up (the first ``W`` recorded samples that start the run) is excluded.
- A periodic joint's reference is unwrapped on the turn of the free run where scoring
  begins, so a swing stored in ``[-pi, pi)`` is scored as it moves, even when it crosses
  ``+-pi`` in the warm-up.
- Pooled over episodes, each episode of a periodic joint is taken on the ``2 pi`` branch
  nearest the pooled reference's circular mean: ``theta`` and ``theta + 2 pi`` are one pose,
  so R^2 does not depend on which turn a log's angle was written in.
- A joint whose reference is constant in every episode has no R^2 (NaN): it has no variance
  to explain, even when its episodes hold it at different poses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from ..spec import MachineSpec
from .angles import unwrap_periodic

CONSTANT = 1e-9
"""A reference column whose range (max - min) is at most this times ``max(1, max |ref|)`` is
constant: its R^2 is undefined (NaN, ``None`` in JSON), not ``1 - SS_res / rounding noise``."""


TURN = 2 * math.pi
"""One turn of a periodic joint [rad]."""


class RunLike(Protocol):
    """What scoring needs from a free run (see :class:`~.rollout.EpisodeRollout`)."""

    theta_hat: np.ndarray
    omega_hat: np.ndarray
    theta_ref: np.ndarray
    omega_ref: np.ndarray
    warmup: int


def moving(ref: np.ndarray) -> np.ndarray:
    """``(n_joint,)`` bool: the columns of ``ref`` ``(n_sample, n_joint)`` that move, i.e.
    whose range is above :data:`CONSTANT` times ``max(1, max |ref|)`` (none when empty)."""
    ref = np.asarray(ref, dtype=np.float64)
    if not len(ref):
        return np.zeros(ref.shape[1], dtype=bool)
    scale = np.maximum(1.0, np.max(np.abs(ref), axis=0))
    with np.errstate(invalid="ignore"):
        return np.ptp(ref, axis=0) > CONSTANT * scale


def regression_metrics(
    pred: np.ndarray, ref: np.ndarray, *, still: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """Per-column RMSE, MAE and R^2.

    Args:
        pred: (n_sample, n_joint) predictions.
        ref: (n_sample, n_joint) reference.
        still: (n_joint,) bool, columns whose R^2 is undefined whatever ``ref`` holds (a joint
            held at a different pose in each pooled episode; see :func:`scored_angles`).

    Returns:
        ``{"rmse", "mae", "r2"}``, each (n_joint,); ``r2`` is NaN where ``ref`` is constant (up
        to rounding, :func:`moving`) or ``still``, and every metric is NaN/inf if ``pred`` is
        not finite.
    """
    pred = np.asarray(pred, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if pred.shape != ref.shape or pred.ndim != 2:
        raise ValueError(f"pred {pred.shape} and ref {ref.shape} must be equal (n_sample, n_joint)")
    err = pred - ref
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        ss_res = np.sum(err**2, axis=0)
        ss_tot = np.sum((ref - ref.mean(axis=0)) ** 2, axis=0)
        # constant up to rounding: SS_tot is rounding noise and 1 - SS_res / SS_tot a
        # meaningless -1e11, so R^2 is undefined (NaN)
        ok = moving(ref) & (ss_tot > 0)
        if still is not None:
            ok &= ~np.asarray(still, dtype=bool)
        r2 = np.where(ok, 1.0 - ss_res / np.where(ok, ss_tot, 1.0), np.nan)
        return {
            "rmse": np.sqrt(np.mean(err**2, axis=0)),
            "mae": np.mean(np.abs(err), axis=0),
            "r2": r2,
        }


def branch_reference(run: RunLike, spec: MachineSpec) -> np.ndarray:
    """``(n_step, n_joint)`` reference angle [rad] of one free run, each periodic joint
    unwrapped and put on the turn of the free run where scoring begins (sample ``W``)::

        ref = unwrap(theta_ref) + 2 pi round((theta_hat[W] - unwrap(theta_ref)[W]) / 2 pi)

    The free run starts from the stored (possibly wrapped) warm-up, so a swing that crosses
    ``+-pi`` in the warm-up is compared on the free run's turn, not a turn away.
    """
    ref = unwrap_periodic(run.theta_ref, spec)
    w = run.warmup
    if w < len(ref):
        with np.errstate(invalid="ignore"):
            turns = np.round((np.asarray(run.theta_hat[w], dtype=np.float64) - ref[w]) / TURN)
        periodic = np.asarray(spec.periodic, dtype=bool) & np.isfinite(turns)
        ref += TURN * np.where(periodic, turns, 0.0)
    return ref


def run_angles(run: RunLike, spec: MachineSpec) -> tuple[np.ndarray, np.ndarray]:
    """``(theta_hat, theta_ref)`` of one free run after its warm-up, each ``(n_scored,
    n_joint)`` [rad] (copies), the reference on the free run's branch
    (:func:`branch_reference`)."""
    w = run.warmup
    return np.array(run.theta_hat, dtype=np.float64)[w:], branch_reference(run, spec)[w:]


def scored_angles(
    runs: Sequence[RunLike], spec: MachineSpec, *, align_turns: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angles ``runs`` are scored on, pooled (module docstring).

    Args:
        runs: the free runs.
        spec: the machine (its periodic joints).
        align_turns: put each episode of a periodic joint on the turn nearest the others'
            (False: each on its own, as stored; training's validation, see
            :func:`~.validation.score_runs`).

    Returns:
        ``theta_hat`` and ``theta_ref``, each ``(n_scored, n_joint)`` [rad], with
        ``align_turns`` every periodic joint's episode shifted by the whole turns ``2 pi k_e``
        that put its reference's mean ``m_e`` nearest the pooled circular mean ``c``, ``k_e =
        round((m_e - c) / 2 pi)``; and ``still`` ``(n_joint,)``: the joints constant in every
        episode.
    """
    pairs = [run_angles(r, spec) for r in runs]
    if not pairs:
        empty = np.zeros((0, spec.n_joint))
        return empty, empty, np.ones(spec.n_joint, dtype=bool)
    moves = np.zeros(spec.n_joint, dtype=bool)
    for _, ref in pairs:
        moves |= moving(ref)
    pred_all = np.concatenate([p for p, _ in pairs])
    ref_all = np.concatenate([q for _, q in pairs])
    for j, periodic in enumerate(spec.periodic):
        if not (periodic and align_turns and len(ref_all) and np.isfinite(ref_all[:, j]).all()):
            continue
        # c = arg( mean_k exp(i theta_ref[k]) )
        c = math.atan2(np.mean(np.sin(ref_all[:, j])), np.mean(np.cos(ref_all[:, j])))
        start = 0
        for _, ref in pairs:
            # k_e = round((m_e - c) / 2 pi);  theta <- theta - 2 pi k_e  (both, episode e)
            stop = start + len(ref)
            if stop > start:
                k = round((float(np.mean(ref[:, j])) - c) / TURN)
                pred_all[start:stop, j] -= TURN * k
                ref_all[start:stop, j] -= TURN * k
            start = stop
    return pred_all, ref_all, ~moves


def worst_r2(r2: Sequence[float]) -> float:
    """The smallest defined (non-NaN) of the per-joint ``r2``; NaN when none is defined (a
    diverged joint's ``-inf`` counts)."""
    defined = [float(v) for v in r2 if not math.isnan(v)]
    return min(defined) if defined else math.nan
