"""Calibrating and scoring the ensemble's bands on episodes; the checkpoint records.

- :func:`fit_scale`: per-joint band scales, the level-quantile of ``|error| / spread`` (a
  split-conformal scale on normalised residuals), with a spread floor (:data:`FLOOR`).
- :func:`predict_episodes`: :func:`.uncertainty.predict_with_uncertainty` over episodes of
  different lengths, with their references; :func:`band_scores` scores it (coverage, width,
  flagged share per joint).
- :func:`calibrate` fits the scales on free runs (:data:`RULE`: validation runs and up to
  :data:`TRAIN_RUNS` training runs, weighed by :data:`PRIOR_RUNS`) and records the training
  data's coverage; :func:`calibrate_checkpoint` adds both to a checkpoint file (training calls it on
  ``best.pt``; ``exsur calibrate`` on any checkpoint).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..data.episode import Episode
from .angles import omega_target, wrap_periodic
from .checkpoint import read_checkpoint, surrogate_from_dict, write_checkpoint_dict
from .coverage import CoverageRecord, fit_coverage
from .ensemble import member_head
from .model import Surrogate
from .rollout import batch_episodes
from .uncertainty import (
    LEVELS,
    Calibration,
    Design,
    UncertainPrediction,
    bands,
    predict_with_uncertainty,
)

FLOOR = 0.1
"""Spread floor of a band, as a fraction of the median spread on the calibration runs."""
NO_SPREAD_FLOOR = 1.0
"""Spread floor of a joint whose members never disagree [one unit: rad, rad/s, m, m/s]: with
it the band's scale is the error's own quantile (a band, not a claim of certainty)."""
TRAIN_RUNS = 32
"""Most training episodes whose free runs join the calibration (evenly spread over the split)."""
HORIZON_EDGES = (0, 25, 50, 100, 200, 400, 800, 1600, 3200)
"""First free-run step of each horizon bin of the angle scale [samples]."""
MIN_BIN = 100
"""Fewest samples (per joint, pooled over the runs of a group) a horizon bin is fitted on;
a bin with fewer takes the previous bin's scale."""
RULE = "train+val mixture"
"""The calibration rule (stored with the scales): per level and joint (and horizon bin for the
angle), the level-quantile of ``|error| / spread`` over the training and validation runs'
free runs together, the validation runs weighing ``n_val / (n_val + PRIOR_RUNS)`` of it
(:data:`PRIOR_RUNS`).  The ratio varies a lot from run to run (per-run 90 % quantiles over
two orders of magnitude), so the few validation runs a dataset has (2 in the presets) give a
noisy, optimistic scale; the training runs give a stable one, but they are the model's own
data (on h1-dev their angle errors are 3-4x smaller than on the held-out duty): each source
weighs by how much it can be trusted.  docs/design.md has the measurements."""
PRIOR_RUNS = 6.0
"""What the training runs weigh in the calibration, in validation runs (with 6: 2 validation
runs weigh 25 %, 24 weigh 80 %)."""


def fit_scale(
    err: np.ndarray,
    spread: np.ndarray,
    levels: Sequence[float] = LEVELS,
    floor: np.ndarray | None = None,
    group: np.ndarray | None = None,
    share: Sequence[float] | None = None,
) -> np.ndarray:
    """Per-joint band scales: the ``level``-quantile of ``|err| / max(spread, floor)``.

    Args:
        err: (n_sample, n_joint) prediction error (NaN samples are skipped).
        spread: (n_sample, n_joint) member spread.
        levels: nominal coverages.
        floor: (n_joint,) smallest spread used (default 0).
        group: (n_sample,) int, the group of each sample (default: one group).
        share: (n_group,) weight of each group in the quantile (each group's samples share
            it equally; default: every sample alike).

    Returns:
        (n_level, n_joint): with half-width ``scale x spread`` the band covers ``level`` of
        the samples it was fitted on (a split-conformal scale on normalised residuals; of
        the groups' mixture with ``share``).
    """
    r = _ratio(err, spread, floor)
    out = np.full((len(levels), err.shape[-1]), np.nan)
    for j in range(err.shape[-1]):
        ok = np.isfinite(r[:, j])
        rj = r[ok, j]
        if not rj.size:
            continue
        if group is None or share is None:
            out[:, j] = np.quantile(rj, levels, method="higher")
            continue
        g = np.asarray(group)[ok]
        n_g = np.bincount(g, minlength=len(share))
        sh = np.where(n_g > 0, np.asarray(share, dtype=np.float64), 0.0)
        w = (sh / np.maximum(n_g, 1))[g]
        order = np.argsort(rj, kind="stable")
        cdf = np.cumsum(w[order]) / w.sum()
        pick = np.searchsorted(cdf, np.asarray(levels) - 1e-12)  # the "higher" sample
        out[:, j] = rj[order][np.minimum(pick, rj.size - 1)]
    return out


def _ratio(err: np.ndarray, spread: np.ndarray, floor: np.ndarray | None) -> np.ndarray:
    """(n_sample, n_joint) normalised residual (NaN where ``err`` or ``spread`` is)::

    r = |err| / max(spread, floor, tiny)
    """
    tiny = np.finfo(np.float64).tiny
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.abs(err) / np.maximum(spread, np.maximum(tiny, 0.0 if floor is None else floor))


def fit_horizon_scale(
    err: np.ndarray,
    spread: np.ndarray,
    horizon: np.ndarray,
    levels: Sequence[float] = LEVELS,
    floor: np.ndarray | None = None,
    edges: Sequence[int] = HORIZON_EDGES,
    min_bin: int = MIN_BIN,
    group: np.ndarray | None = None,
    share: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_scale` per horizon bin.

    Args:
        err, spread: (n_sample, n_joint) as in :func:`fit_scale`.
        horizon: (n_sample,) int, samples since the free run began.
        levels, floor, group, share: as in :func:`fit_scale` (the shares hold in every bin).
        edges: (n_bin,) first horizon of each bin (increasing, from 0).
        min_bin: fewest samples a bin is fitted on (else NaN): those with a finite
            ``|err| / max(spread, floor)``, the ratio :func:`fit_scale` takes its quantile of
            (a sample whose members agree exactly counts).

    Returns:
        ``(scales, counts)``: (n_level, n_bin, n_joint) scales, NaN where a bin has fewer
        than ``min_bin`` samples, and (n_bin, n_joint) the samples of each bin.
    """
    e = np.asarray(edges)
    b = np.searchsorted(e, horizon, side="right") - 1
    out = np.full((len(levels), len(e), err.shape[-1]), np.nan)
    counts = np.zeros((len(e), err.shape[-1]), dtype=np.int64)
    for i in range(len(e)):
        m = b == i
        if not m.any():
            continue
        g = None if group is None else np.asarray(group)[m]
        k = fit_scale(err[m], spread[m], levels, floor, g, share)
        counts[i] = np.isfinite(_ratio(err[m], spread[m], floor)).sum(0)
        out[:, i] = np.where(counts[i] >= min_bin, k, np.nan)
    return out, counts


def monotone_bins(k: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
    """(n_level, n_bin, n_joint) scales made non-decreasing along the horizon: the isotonic
    (least-squares, weighted by ``counts`` (n_bin, n_joint)) fit of the fitted bins, empty
    (NaN) bins taking the nearest fitted bin before them (or, leading, after them)."""
    from scipy.optimize import isotonic_regression

    out = np.full_like(k, np.nan)
    w = np.ones(k.shape[1:]) if counts is None else np.maximum(counts, 1).astype(np.float64)
    for lv in range(k.shape[0]):
        for j in range(k.shape[2]):
            m = np.isfinite(k[lv, :, j])
            if not m.any():
                continue
            out[lv, m, j] = isotonic_regression(k[lv, m, j], weights=w[m, j]).x
            idx = np.flatnonzero(m)
            fill = idx[
                np.clip(np.searchsorted(idx, np.arange(k.shape[1]), side="right") - 1, 0, None)
            ]
            out[lv, :, j] = out[lv, fill, j]
    return out


def _error(
    pred: np.ndarray, ref: np.ndarray, spec_periodic: np.ndarray, *, angle: bool
) -> np.ndarray:
    err = pred - ref
    if angle and spec_periodic.any():  # periodic joints: the shorter way round
        err = wrap_periodic(err, spec_periodic)
    return err


@dataclass
class EpisodePrediction:
    """One episode's :class:`UncertainPrediction` (batch axis dropped) and its reference."""

    name: str
    time: np.ndarray
    """(n_step,) [s]."""
    pred: UncertainPrediction
    theta_ref: np.ndarray
    """(n_step, n_joint) [rad]."""
    omega_ref: np.ndarray
    """(n_step, n_joint) [rad/s]."""


def predict_episodes(
    sur: Surrogate,
    episodes: Sequence[Episode],
    *,
    reference: Literal["measured", "true"] = "measured",
    max_steps: int | None = None,
    design: Design | None = None,
    calibration: Calibration | None = None,
    coverage: CoverageRecord | None = None,
    read_calibration: bool = True,
) -> list[EpisodePrediction]:
    """:func:`predict_with_uncertainty` over episodes of different lengths in one batch
    (shorter ones padded with their last command; causal, so padding changes nothing before;
    ``read_calibration`` False: the checkpoint's calibration is not read, no bands)."""
    if not episodes:
        return []
    warmup = sur.window
    thetas, lengths, th0, u = batch_episodes(
        episodes, reference=reference, warmup=warmup, max_steps=max_steps
    )
    full = predict_with_uncertainty(
        sur,
        th0,
        u,
        warmup=warmup,
        design=design,
        calibration=calibration,
        coverage=coverage,
        read_calibration=read_calibration,
    )
    out = []
    for i, ep in enumerate(episodes):
        n = lengths[i]

        def cut(a: np.ndarray | None, axis: int = 0, i: int = i, n: int = n) -> Any:
            if a is None:
                return None
            return a[:, i, :n] if axis == 1 else a[i, :n]

        p = UncertainPrediction(
            theta=cut(full.theta),
            omega=cut(full.omega),
            warmup=warmup,
            theta_members=cut(full.theta_members, 1),
            omega_members=cut(full.omega_members, 1),
            theta_spread=cut(full.theta_spread),
            omega_spread=cut(full.omega_spread),
            bands=None
            if full.bands is None
            else {
                lv: {q: (cut(lo), cut(hi)) for q, (lo, hi) in d.items()}
                for lv, d in full.bands.items()
            },
            ood=cut(full.ood),
            notes=list(full.notes),
        )
        out.append(
            EpisodePrediction(ep.name, ep.time[:n], p, thetas[i], omega_target(thetas[i], sur.spec))
        )
    return out


def _pooled(
    runs: Sequence[EpisodePrediction], periodic: np.ndarray
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Scored steps of every run: quantity -> (error, spread), each (n_sample, n_joint)."""
    out: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {
        "theta": ([], []),
        "omega": ([], []),
    }
    for r in runs:
        p, w = r.pred, r.pred.warmup
        assert p.theta_spread is not None and p.omega_spread is not None
        for q, c, ref, s in (
            ("theta", p.theta, r.theta_ref, p.theta_spread),
            ("omega", p.omega, r.omega_ref, p.omega_spread),
        ):
            out[q][0].append(_error(c[w:], ref[w:], periodic, angle=q == "theta"))
            out[q][1].append(s[w:])
    return {q: (np.concatenate(e), np.concatenate(s)) for q, (e, s) in out.items()}


def _horizons(runs: Sequence[EpisodePrediction]) -> np.ndarray:
    """(n_sample,) samples since the free run began, in :func:`_pooled`'s order."""
    return np.concatenate([np.arange(len(r.time) - r.pred.warmup) for r in runs])


def band_scores(
    runs: Sequence[EpisodePrediction], names: Sequence[str], periodic: Sequence[bool]
) -> dict[str, Any]:
    """Per joint: coverage and mean width of every band, mean spread, share of flagged steps.

    Returns ``{"available", "notes", "levels", "theta": {joint: {"coverage_50", "width_50",
    ..., "spread"}}, "omega": {...}, "ood": {joint: share, "any": share} | None}``
    (scored steps only: after the warm-up).
    """
    first = runs[0].pred
    per = np.asarray(periodic, dtype=bool)
    res: dict[str, Any] = {"available": first.bands is not None, "notes": list(first.notes)}
    if first.bands is not None:
        levels = sorted(first.bands)
        res["levels"] = levels
        pooled = _pooled(runs, per)
        for q in ("theta", "omega"):
            err, spread = pooled[q]
            d: dict[str, dict[str, float | None]] = {n: {} for n in names}
            for lv in levels:
                tag = f"{round(100 * lv)}"
                half = np.concatenate(
                    [
                        (r.pred.bands[lv][q][1] - r.pred.bands[lv][q][0])[r.pred.warmup :] / 2  # type: ignore[index]
                        for r in runs
                    ]
                )
                with np.errstate(invalid="ignore"):
                    inside = np.abs(err) <= half
                ok = np.isfinite(err) & np.isfinite(half)
                for j, n in enumerate(names):
                    m = ok[:, j]
                    d[n][f"coverage_{tag}"] = float(inside[m, j].mean()) if m.any() else None
                    d[n][f"width_{tag}"] = float(2 * half[m, j].mean()) if m.any() else None
            for j, n in enumerate(names):
                s = spread[:, j][np.isfinite(spread[:, j])]
                d[n]["spread"] = float(s.mean()) if s.size else None
            res[q] = d
    if first.ood is None:
        res["ood"] = None
    else:
        flags = np.concatenate([r.pred.ood[r.pred.warmup :] for r in runs])  # type: ignore[index]
        res["ood"] = {n: float(flags[:, j].mean()) for j, n in enumerate(names)}
        res["ood"]["any"] = float(flags.any(-1).mean())
    return res


def calibrate(
    sur: Surrogate,
    val: Sequence[Episode],
    train: Sequence[Episode],
    *,
    design: Design = "shared",
    levels: Sequence[float] = LEVELS,
    max_steps: int | None = None,
    train_runs: int = TRAIN_RUNS,
) -> tuple[Calibration | None, CoverageRecord]:
    """Fit the band scales on free runs (:data:`RULE`) and record what ``train`` covered.

    Args:
        sur: the surrogate (without members: no calibration, only the coverage record).
        val: validation episodes (measured angles are the reference).
        train: training episodes (the coverage record; up to ``train_runs`` of them, evenly
            spread over the list, are free-run for the scales too).
        design: how the members run.
        levels: band levels.
        max_steps: truncate the episodes (None: whole episodes, the long horizon the bands
            are for).
        train_runs: most training episodes free-run for the scales (0: validation only, the
            rule of checkpoints calibrated before the rule existed).

    Returns:
        ``(calibration or None, coverage record)``.
    """
    coverage = fit_coverage(train, sur.spec)
    picked = _evenly(train, train_runs)
    if member_head(sur) is None or not (val or picked):
        return None, coverage
    per = np.array([j.periodic for j in sur.spec.joints])
    runs = [
        # the stored calibration is the one being replaced: not read (it may be malformed)
        predict_episodes(
            sur, eps, max_steps=max_steps, design=design, coverage=coverage, read_calibration=False
        )
        for eps in (val, picked)
    ]
    cal = fit_calibration(*runs, per, levels=levels, design=design)
    return cal, coverage


def fit_calibration(
    val: Sequence[EpisodePrediction],
    train: Sequence[EpisodePrediction],
    periodic: Sequence[bool],
    *,
    levels: Sequence[float] = LEVELS,
    design: Design = "shared",
) -> Calibration:
    """The band scales of :data:`RULE` from free runs already made (no bands needed).

    Args:
        val: validation free runs (:func:`predict_episodes`); may be empty.
        train: training free runs; may be empty (not both).
        periodic: (n_joint,) which joints wrap.
        levels: band levels.
        design: how the members ran (recorded).
    """
    per = np.asarray(periodic, dtype=bool)
    groups = {g: r for g, r in (("val", val), ("train", train)) if r}
    if not groups:
        raise ValueError("fit_calibration needs validation or training free runs")
    pooled = {g: _pooled(r, per) for g, r in groups.items()}
    floors = {
        q: spread_floor(np.concatenate([p[q][1] for p in pooled.values()]))
        for q in ("theta", "omega")
    }
    # validation (group 0) weighs n_val / (n_val + PRIOR_RUNS), training (group 1) the rest
    w_val = len(val) / (len(val) + PRIOR_RUNS) if train else 1.0
    share = (w_val, 1.0 - w_val)
    scales, group, joint = {}, {}, {}
    for q in ("theta", "omega"):
        group[q] = np.concatenate(
            [np.full(len(pooled[g][q][0]), int(g == "train")) for g in groups]
        )
        joint[q] = tuple(np.concatenate([pooled[g][q][i] for g in groups]) for i in (0, 1))
        scales[q] = fit_scale(*joint[q], levels, floors[q], group[q], share)
    horizon = np.concatenate([_horizons(groups[g]) for g in groups])
    k_bins, counts = fit_horizon_scale(
        *joint["theta"], horizon, levels, floors["theta"], group=group["theta"], share=share
    )
    k_bins = monotone_bins(k_bins, counts)
    # a joint without a fitted bin (tiny data): one scale at every horizon
    k_bins = np.where(np.isnan(k_bins), scales["theta"][:, None, :], k_bins)
    return Calibration(
        levels=tuple(float(v) for v in levels),
        theta=scales["theta"],
        omega=scales["omega"],
        n_step=sum(int(p["theta"][0].shape[0]) for p in pooled.values()),
        design=design,
        theta_floor=floors["theta"],
        omega_floor=floors["omega"],
        rule=RULE if len(groups) == 2 else next(iter(groups)),
        n_run=len(val),
        n_train_run=len(train),
        horizon_edges=np.asarray(HORIZON_EDGES, dtype=np.int64),
        theta_horizon=k_bins,
    )


def with_bands(runs: Sequence[EpisodePrediction], cal: Calibration) -> list[EpisodePrediction]:
    """``runs`` with their bands recomputed for ``cal`` (copies; no network run)."""
    out = []
    for r in runs:
        p = copy.copy(r.pred)
        p.bands = bands(p, cal)
        out.append(copy.copy(r))
        out[-1].pred = p
    return out


def _evenly(episodes: Sequence[Episode], n: int) -> list[Episode]:
    """At most ``n`` of ``episodes``, evenly spread over the list (all if fewer)."""
    if len(episodes) <= n:
        return list(episodes)
    if n <= 0:
        return []
    idx = np.unique(np.linspace(0, len(episodes) - 1, n).round().astype(int))
    return [episodes[i] for i in idx]


def spread_floor(spread: np.ndarray) -> np.ndarray:
    """(n_joint,) the floor of each joint's spread in a band: :data:`FLOOR` x its median
    positive spread; :data:`NO_SPREAD_FLOOR` for a joint whose members never disagree (it
    follows the static valve map), so its band is the quantile of its error itself (per
    horizon bin for angles) instead of zero width."""
    med = _median_spread(spread)
    return np.where(med > 0, FLOOR * med, NO_SPREAD_FLOOR)


def _median_spread(spread: np.ndarray) -> np.ndarray:
    """(n_joint,) median of the positive finite spreads per joint (0 if none)."""
    out = np.zeros(spread.shape[-1])
    for j in range(spread.shape[-1]):
        s = spread[:, j][np.isfinite(spread[:, j]) & (spread[:, j] > 0)]
        out[j] = float(np.median(s)) if s.size else 0.0
    return out


def calibrate_checkpoint(
    path: str | Path,
    val: Sequence[Episode],
    train: Sequence[Episode],
    *,
    design: Design = "shared",
    max_steps: int | None = None,
    train_runs: int = TRAIN_RUNS,
    calibrated_on: Mapping[str, Any] | None = None,
) -> tuple[Calibration | None, CoverageRecord]:
    """Add the calibration and the coverage record to the checkpoint at ``path`` (in its
    ``metrics``; everything else in the file is kept), rewritten atomically.

    ``calibrated_on``: what they were computed from, stored as ``metrics["calibrated_on"]``
    (``exsur calibrate``: the dataset and its options); None (training's own calibration,
    on the data its config records) removes an earlier one.

    Raises:
        CheckpointError: unreadable checkpoint.  DataError: no training episodes.
    """
    path = Path(path)
    ckpt = read_checkpoint(path)
    sur = surrogate_from_dict(ckpt, where=str(path))
    cal, cov = calibrate(sur, val, train, design=design, max_steps=max_steps, train_runs=train_runs)
    metrics = dict(ckpt.get("metrics") or {})
    metrics["coverage"] = cov.to_dict()
    if cal is None:
        metrics.pop("uncertainty", None)
    else:
        metrics["uncertainty"] = cal.to_dict()
    if calibrated_on is None:
        metrics.pop("calibrated_on", None)
    else:
        metrics["calibrated_on"] = dict(calibrated_on)
    ckpt["metrics"] = metrics
    write_checkpoint_dict(path, ckpt)  # same dict, same bytes
    return cal, cov
